"""The EMPS benchmark's protocols, as a public namespace: `fj.emps.fit_emps_idm(...)`.

The electro-mechanical positioning system of the nonlinear-benchmark series (emps-ensemble, emps-idm): the inverse
dynamic identification model (`emps_idm_data`, `fit_emps_idm`), the open-loop simulation protocol
(`split_emps_record`, `fit_emps_open_loop`, `predict_emps_open_loop`, `score_emps_open_loop`), the velocity plateaus
(`emps_plateau_forces`), the grey + black-box models (`fit_emps_hybrid`, `fit_emps_ensemble`, `fit_emps_bgbm`) and
the closed-loop errors they are scored by. The records (`fj.load_emps`) and the systems (`fj.EMPSPlant`,
`fj.EMPSOpenLoop`, `fj.EMPSClosedLoop`) are models and data, in `fj` itself. (Until 2026-12 these names were in
`fj` too; reading them there still works, with a `DeprecationWarning`.)
"""

from ._protocols._emps_bgbm import EMPSBGBMFit as EMPSBGBMFit
from ._protocols._emps_bgbm import EMPSErrorModel as EMPSErrorModel
from ._protocols._emps_bgbm import fit_emps_bgbm as fit_emps_bgbm
from ._protocols._emps_hybrid import EMPSEnsemble as EMPSEnsemble
from ._protocols._emps_hybrid import EMPSEnsembleFit as EMPSEnsembleFit
from ._protocols._emps_hybrid import EMPSHybridFit as EMPSHybridFit
from ._protocols._emps_hybrid import emps_closed_loop_errors as emps_closed_loop_errors
from ._protocols._emps_hybrid import emps_hybrid_start as emps_hybrid_start
from ._protocols._emps_hybrid import fit_emps_ensemble as fit_emps_ensemble
from ._protocols._emps_hybrid import fit_emps_hybrid as fit_emps_hybrid
from ._protocols._emps_idm import EMPSIDMResult as EMPSIDMResult
from ._protocols._emps_idm import fit_emps_idm as fit_emps_idm
from ._protocols._emps_idm_data import EMPSIDMData as EMPSIDMData
from ._protocols._emps_idm_data import emps_idm_data as emps_idm_data
from ._protocols._emps_open_loop import EMPSOpenLoopFit as EMPSOpenLoopFit
from ._protocols._emps_open_loop import EMPSOpenLoopLoss as EMPSOpenLoopLoss
from ._protocols._emps_open_loop import fit_emps_open_loop as fit_emps_open_loop
from ._protocols._emps_open_loop import predict_emps_open_loop as predict_emps_open_loop
from ._protocols._emps_open_loop import score_emps_open_loop as score_emps_open_loop
from ._protocols._emps_open_loop import split_emps_record as split_emps_record
from ._protocols._emps_plateaus import EMPS_PLATEAU_VELOCITIES as EMPS_PLATEAU_VELOCITIES
from ._protocols._emps_plateaus import EMPSPlateau as EMPSPlateau
from ._protocols._emps_plateaus import emps_plateau_forces as emps_plateau_forces
