"""The force sensor as part of the model: a slow drift added to any friction model's force.

Piezoelectric force cells leak charge, so their reading drifts slowly during a record (parlitz2004 §II-B: the
"slow trend" of Fig. 5, removed there by detrending before identification). Fitting the drift with the model
keeps the trend out of the friction parameters and lets the fitted model carry it to another record. The
record's constant offset is the friction model's own `offset` (or, on a test record, the initialisation
window's estimate in `fricjax compare`).
"""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..._constraints import Parameter, ParamLike, model_dtype, positive, real, unwrap
from ..._inputs import MotionSample
from ..._validation import got_model
from .._base import AbstractFrictionModel
from .._state_maps import AffineMaps
from ._wrapper import AbstractWrapper


class SensorDriftState(eqx.Module):
    """The wrapped model's state, the time of the next sample since the record's first one [s], and the drift
    added to the last output [N]."""

    inner: Any  # the wrapped model's state: any pytree, as its `init_state` returns
    t: Array
    last: Array


class SensorDrift(AbstractWrapper):
    """`model`'s force plus a sensor drift that starts at 0 at each record's first sample (t = 0):

    - linear (`tau=None`): `drift(t) = rate * t`;
    - leaky integrator (charge leakage with time constant `tau` [s]): `drift(t) = rate * tau * (1 - exp(-t/tau))`,
      the same initial slope `rate`, saturating at `rate * tau`.

    `rate` [N/s] enters the force linearly (`fj.fit(..., separable=("rate",))` solves it exactly); `tau` is a
    positive parameter. Sample `k` is at `t = k * dt`.

    **Arguments:** `model` any friction model; `rate` [N/s]; `tau` [s] or None.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(np.zeros(11), dt=0.1)
    >>> drifting = fj.SensorDrift(fj.Coulomb(Fc=1.0), rate=0.5)
    >>> round(float(fj.simulate(drifting, motion)[-1]), 6)  # 1 s later: 0.5 N of drift on a force of 0
    0.5
    ```
    """

    model: AbstractFrictionModel
    rate: Parameter
    tau: Parameter | None
    transparent: ClassVar[bool] = True
    drifts: ClassVar[bool] = True

    def __init__(self, model: AbstractFrictionModel, rate: ParamLike = 0.0, tau: ParamLike | None = None):
        if not isinstance(model, AbstractFrictionModel):
            raise TypeError(f"SensorDrift: `model` must be a fricjax friction model, got {got_model(model)}.")
        dtype = model_dtype(rate, *([] if tau is None else [tau]))
        self.model = model
        self.rate = real(rate, "rate", dtype, scalar=True)
        self.tau = None if tau is None else positive(tau, "tau", dtype, scalar=True)

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return self.model.requires | {"dt"}

    def without_drift(self) -> AbstractFrictionModel:
        return self.model

    def init_state(self) -> SensorDriftState:
        zero = jnp.zeros((), jnp.result_type(float))
        return SensorDriftState(unwrap(self.model).init_state(), zero, zero)

    def drift(self, t: Any) -> Array:
        """The drift [N] at time `t` [s] after the record's first sample."""
        p = unwrap(self)
        if p.tau is None:
            return p.rate * t
        return -p.rate * p.tau * jnp.expm1(-t / p.tau)

    def step(self, state: SensorDriftState, sample: MotionSample) -> tuple[SensorDriftState, Array]:
        inner, force = unwrap(self.model).step(state.inner, sample)
        drift = self.drift(state.t)
        return SensorDriftState(inner, state.t + sample.dt, drift), force + drift

    def parallel_maps(self, samples: MotionSample) -> Any:
        """The wrapped model's maps, the clock advanced by `dt` per sample (the time-parallel free run); the
        drift of the last output does not enter `step`, so its map is the identity."""
        inner = unwrap(self.model).parallel_maps(samples)
        if inner is None:
            return None
        length = next(leaf for leaf in jax.tree_util.tree_leaves(samples) if jnp.ndim(leaf) > 0).shape[0]
        one = jnp.ones((length,), jnp.result_type(float))
        clock, last = AffineMaps(one, one * samples.dt), AffineMaps(one, 0.0 * one)
        return SensorDriftState(inner, clock, last)  # type: ignore[arg-type]  # maps in the state's places

    def tangent_gradients(self) -> bool:
        """As the wrapped model (the drift adds one smooth state)."""
        return self.model.tangent_gradients()

    def feedback(self, state: SensorDriftState, y_measured: Array) -> SensorDriftState:
        """Teacher forcing of the wrapped model with the measurement less the drift of that sample."""
        inner = unwrap(self.model).feedback(state.inner, y_measured - state.last)
        return SensorDriftState(inner, state.t, state.last)
