"""The Bouc-Wen hysteresis benchmark's protocol, as a public namespace: `fj.boucwen.score_boucwen(...)`.

The scoring of the nonlinear-benchmark Bouc-Wen test records (`score_boucwen`, `boucwen_rmse`, `BoucWenScores`,
the steady periods it scores after: `BOUCWEN_STEADY_PERIODS`) and the loss it is fitted with (`BoucWenLoss`). The
system (`fj.BoucWen`, `fj.boucwen_inputs`) and the records (`fj.load_boucwen`) are models and data, in `fj` itself.
(Until 2026-12 these names were in `fj` too; reading them there still works, with a `DeprecationWarning`.)
"""

from ._protocols._boucwen import BOUCWEN_STEADY_PERIODS as BOUCWEN_STEADY_PERIODS
from ._protocols._boucwen import BoucWenLoss as BoucWenLoss
from ._protocols._boucwen import BoucWenScores as BoucWenScores
from ._protocols._boucwen import boucwen_rmse as boucwen_rmse
from ._protocols._boucwen import score_boucwen as score_boucwen
