"""The Bouc-Wen benchmark protocol (Noël & Schoukens 2016): output-error loss and the official test scores.

Train on `load_boucwen().train` (5 periods x 8192 samples; hold out the last period for validation / model
selection); never fit or select on the test records. Test: free-run simulation RMSE [m] on the multisine
(`BOUCWEN_STEADY_PERIODS` repeated periods simulated from rest, the last one scored: the benchmark's test
record is one steady-state period) and on the sine sweep (from rest). The model is any fricjax system that
`fj.simulate` runs on `fj.boucwen_inputs(u)` with the displacement as its output (`fj.BoucWen` with free
parameters is the grey-box model).
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._data._boucwen import BoucWenRecord
from .._estimation.problem._losses import AbstractLoss
from .._metrics import numpy_rmse, scaled_std
from .._simulate import simulate
from .._systems._boucwen import boucwen_inputs
from .._validation import nonnegative_int, optional, positive_int

BOUCWEN_STEADY_PERIODS = 3
"""Periods of the test multisine simulated before (and including) the scored one."""


class BoucWenLoss(AbstractLoss):
    """Output error on a Bouc-Wen record: the model simulated from rest on the record's force, residuals
    `(y_sim - y) / std(y)` after `burn_in` samples (so `sqrt(loss) * std(y)` is the RMSE in metres).

    **Arguments:** `burn_in` samples simulated but not scored (default 0); `validation_burn_in` the same for
    the validation record of `fj.fit` (default: `burn_in`). For the benchmark's hold-out, pass the whole
    training record as `validation` with `validation_burn_in = 4 * 8192` (the validation period is then entered
    in the state its history gives). Data: a `BoucWenRecord`.
    """

    data_type: ClassVar[type] = BoucWenRecord

    burn_in: int = eqx.field(static=True, default=0)
    validation_burn_in: int | None = eqx.field(static=True, default=None)

    def __check_init__(self) -> None:
        hint = "(samples not scored)"
        nonnegative_int(self.burn_in, "burn_in", "BoucWenLoss", hint=hint)
        optional(nonnegative_int, self.validation_burn_in, "validation_burn_in", "BoucWenLoss", hint=hint)

    def validation_loss(self) -> BoucWenLoss:
        """Free run scored after `validation_burn_in` samples."""
        burn = self.burn_in if self.validation_burn_in is None else self.validation_burn_in
        return BoucWenLoss(burn_in=burn)

    def residuals(self, model: Any, extra: Any, data: BoucWenRecord) -> Float[Array, " R"]:
        if not isinstance(data, BoucWenRecord):
            raise TypeError(
                f"BoucWenLoss: `data` must be a BoucWenRecord (fj.load_boucwen), got {type(data).__name__}."
            )
        if self.burn_in >= data.length:
            raise ValueError(
                f"BoucWenLoss: `burn_in` = {self.burn_in} leaves nothing to score in a record of {data.length} samples."
            )
        y = jnp.asarray(data.y)
        predicted = simulate(model, boucwen_inputs(jnp.asarray(data.u, y.dtype), data.dt))
        return ((predicted - y) / scaled_std(y))[self.burn_in :]  # scaled before squaring


class BoucWenScores(NamedTuple):
    """Free-run simulation RMSE [m]: `multisine` (the official test: the last of `BOUCWEN_STEADY_PERIODS`
    periods), `sinesweep` (from rest); `multisine_prediction`, `sinesweep_prediction` the simulated outputs."""

    multisine: float
    sinesweep: float
    multisine_prediction: np.ndarray
    sinesweep_prediction: np.ndarray


def boucwen_rmse(model: Any, record: BoucWenRecord, *, periods: int = 1) -> tuple[float, np.ndarray]:
    """Free-run RMSE [m] of `model` on `record`: the force repeated `periods` times from rest, the last repeat
    scored (`periods=1`: the record as it is, from rest). Returns `(rmse, prediction of the scored part)`."""
    periods = positive_int(periods, "periods", "boucwen_rmse")
    u = np.tile(np.asarray(record.u), periods)
    predicted = np.asarray(simulate(model, boucwen_inputs(u, record.dt, periodic=periods > 1)))[-record.length :]
    return float(numpy_rmse(predicted - np.asarray(record.y))), predicted


def score_boucwen(model: Any, multisine: BoucWenRecord, sinesweep: BoucWenRecord) -> BoucWenScores:
    """The benchmark's test figures of `model` (Noël & Schoukens 2016): free-run simulation RMSE [m] on the
    multisine (steady state: `BOUCWEN_STEADY_PERIODS` periods from rest, the last scored) and the sine sweep
    (from rest). Anchors: PNLSS 1.87e-5 m, dynoNet 4.52e-5 m (multisine).

    ```python
    >>> import fricjax as fj
    >>> data = fj.load_boucwen()  # doctest: +SKIP
    >>> scores = fj.boucwen.score_boucwen(fj.BoucWen.benchmark(), data.multisine, data.sinesweep)  # doctest: +SKIP
    >>> scores.multisine < 1e-5, scores.sinesweep < 1e-5  # doctest: +SKIP
    (True, True)
    ```
    """
    ms, ms_pred = boucwen_rmse(model, multisine, periods=BOUCWEN_STEADY_PERIODS)
    sw, sw_pred = boucwen_rmse(model, sinesweep)
    return BoucWenScores(ms, sw, ms_pred, sw_pred)
