"""A friction model used as an input-output black box on any named signal of an `fj.InputRecord`.

The black-box friction models (NARX networks, kernel and polynomial NARX, wavelet networks) map a motion signal
and its history to an output. The same maps identify other input-output systems: the Bouc-Wen benchmark
(Noël & Schoukens 2016) drives a hysteretic oscillator by a force `u` [N] and measures its displacement `y` [m].
`InputOutputModel(model, signal="u")` runs `model` on the record's signal `signal` in place of the
displacement: its `x` is the signal, `dx`, `v` and `a` its increments and finite-difference derivatives (as
`fj.Motion(x=signal, dt=record.dt)` gives them), and its output is the system's output. The model is trained
on an `fj.FrictionData` whose motion is the input signal and whose "force" is the output
(`input_output_data`), and evaluated here on `fj.InputRecord`s, e.g. by `fj.boucwen.score_boucwen`.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike

from .._data._record import FrictionData
from .._inputs import InputRecord, Motion
from .._models._base import AbstractFrictionModel, AbstractSystem


class InputOutputModel(AbstractSystem):
    """A friction model driven by the signal `signal` of an `fj.InputRecord` instead of a motion.

    **Arguments:** `model`, any fricjax friction model (typically a NARX: `fj.MLPNARX`, `fj.GSNN`,
    `fj.PolynomialNARX`, `fj.KernelNARX`, `fj.WaveletNARX`); `signal`, the name of the input signal (default
    `"u"`). The signal is the model's displacement `x` (in the signal's own units), so regressors built with
    `fj.NARXRegressors.from_data(input_output_data(u, y, dt), ("x",), ...)` normalise it. The output is the
    model's output (in the units of the `y` it was trained on).

    ```python
    >>> import jax, numpy as np, fricjax as fj
    >>> narx = fj.MLPNARX.init(fj.NARXRegressors(("x",), 2, 2), width=4, key=jax.random.PRNGKey(0))
    >>> system = fj.InputOutputModel(narx, "u")
    >>> fj.simulate(system, fj.InputRecord(dt=1e-3, u=np.sin(np.arange(100) / 10))).shape
    (100,)
    ```
    """

    model: AbstractFrictionModel
    signal: str = eqx.field(static=True, default="u")

    def __check_init__(self) -> None:
        if not isinstance(self.model, AbstractFrictionModel):
            raise TypeError(
                "InputOutputModel: `model` must be a fricjax friction model (a NARX, kernel or physics model), got "
                f"{type(self.model).__name__}."
            )
        if not isinstance(self.signal, str) or not self.signal or self.signal == "dt":
            raise ValueError(f"InputOutputModel: `signal` must name an input signal such as 'u', got {self.signal!r}.")
        if "normal_force" in self.model.requires:
            raise ValueError(
                f"InputOutputModel: {type(self.model).__name__} needs a normal load, which an input-output record "
                "does not carry; use a model without `normal_force`."
            )

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return frozenset({self.signal})

    @property
    def members(self) -> tuple[AbstractFrictionModel]:
        """The wrapped model (so that `fj.simulate` feeds back measured outputs exactly when it does)."""
        return (self.model,)

    def samples(self, inputs: InputRecord) -> Any:
        return self.model.samples(Motion(x=inputs.signals[self.signal], dt=inputs.dt))

    def init_state(self) -> Any:
        return self.model.init_state()

    def step(self, state: Any, sample: Any) -> tuple[Any, Array]:
        return self.model.step(state, sample)

    def feedback(self, state: Any, y_measured: Array) -> Any:
        return self.model.feedback(state, y_measured)

    def tangent_gradients(self) -> bool:
        return self.model.tangent_gradients()


def input_output_data(u: ArrayLike, y: ArrayLike, dt: float) -> FrictionData:
    """An input-output record as the training data of the model inside `InputOutputModel`: `fj.FrictionData`
    with the input `u` as its displacement (so `v`, `a` its derivatives) and the output `y` as its "force";
    `dt` the sample time [s]. Any loss of `fj.fit` (one-step, simulation, multiple shooting) then trains the
    input-output map."""
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    if u.ndim != 1 or u.shape != y.shape:
        raise ValueError(
            f"input_output_data: `u` and `y` must be signals of one shape (T,), got {u.shape} and {y.shape}."
        )
    return FrictionData(Motion(x=u, dt=dt), y)
