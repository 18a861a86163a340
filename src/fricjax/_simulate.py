"""`simulate`: the one driver that runs any friction model over a motion record as a `lax.scan`."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._constraints import unwrap
from ._inputs import Motion, MotionSample, position_from_velocity, velocity_from_position
from ._models._base import AbstractFrictionModel

# Loop unrolling of the scan: measured by benchmarks/simulate.py on the 2-core CPU (see benchmarks/README.md).
DEFAULT_UNROLL = 2


def simulate(
    model: AbstractFrictionModel, motion: Motion, state0: Any = None, *, unroll: int = DEFAULT_UNROLL
) -> Float[Array, "T"]:
    """Simulate the friction force [N] of `model` along `motion`: one jit-compiled `lax.scan`.

    Works under `jax.vmap` / `eqx.filter_vmap` over batches of models (parameter sets) and of motions, and is
    differentiable with respect to every parameter. Structure is checked on every call; values (NaN, `dt`) are
    checked when `Motion` is built.

    **Arguments:**

    - `model`: any fricjax friction model (`LuGre`, `GMS`, `MaxwellSlip`, `Dahl`, a static curve, ...).
    - `motion`: a `Motion`; the signals the model needs are derived when missing (velocity from displacement by
      central differences, displacement from velocity under zero-order hold, both need `motion.dt`).
    - `state0`: the initial state; `None` means `model.init_state()` (at rest).
    - `unroll`: scan unrolling (performance only).

    **Returns:** the friction force, shape `(T,)`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> model = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4)
    >>> motion = fj.Motion.from_position(1e-4 * np.sin(np.linspace(0, 6.28, 500)), dt=1e-3)
    >>> fj.simulate(model, motion).shape
    (500,)
    ```
    """
    _check_structure(model, motion)
    return _simulate(model, motion, state0, unroll)


def _check_structure(model: Any, motion: Any) -> None:
    if not isinstance(model, AbstractFrictionModel):
        raise TypeError(f"simulate: `model` must be a fricjax friction model, got {type(model).__name__}.")
    if not isinstance(motion, Motion):
        raise TypeError(
            f"simulate: `motion` must be a fricjax.Motion, got {type(motion).__name__}; "
            "wrap your arrays as fj.Motion(x=..., v=..., dt=...)."
        )
    name = type(model).__name__
    needs = model.requires
    if "dt" in needs and motion.dt is None:
        raise ValueError(f"simulate: {name} integrates in time and needs the sample time; pass Motion(..., dt=...).")
    if "x" in needs and motion.x is None and motion.dt is None:
        raise ValueError(
            f"simulate: {name} needs the displacement `x`; the motion has only `v` and no `dt` to integrate it. "
            "Pass Motion(x=...) or Motion(v=..., dt=...)."
        )
    if "v" in needs and motion.v is None and motion.dt is None:
        raise ValueError(
            f"simulate: {name} needs the velocity `v`; the motion has only `x` and no `dt` to differentiate it. "
            "Pass Motion(v=...) or Motion(x=..., dt=...)."
        )


def motion_samples(motion: Motion) -> MotionSample:
    """The per-step signals (x, v, dx) of `motion`, shape `(..., T)` each, deriving what is missing."""
    dt = motion.dt
    x, v = motion.x, motion.v
    if v is None:
        assert x is not None  # Motion guarantees one of the two
        v = velocity_from_position(x, dt) if dt is not None else jnp.zeros_like(x)
    if x is None:
        x = position_from_velocity(v, dt) if dt is not None else jnp.zeros_like(v)
    dx = jnp.diff(x, axis=-1, prepend=x[..., :1])
    dt_array = jnp.ones((), x.dtype) if dt is None else dt
    return MotionSample(x=x, v=v, dx=dx, dt=dt_array)


def scan_samples(
    model: AbstractFrictionModel, samples: MotionSample, state: Any, unroll: int = DEFAULT_UNROLL
) -> tuple[Any, Array]:
    """Run `model.step` over per-step signals `samples` (x, v, dx of shape (T,), scalar dt) from `state`.

    The building block of `simulate`, of the fitting losses (multiple-shooting segments) and of the system
    simulators; `model` must be unwrapped (`fj.unwrap`). **Returns:** `(final_state, force (T,))`.
    """
    dt = samples.dt

    def body(carry: Any, xs: tuple[Array, Array, Array]) -> tuple[Any, Array]:
        x, v, dx = xs
        return model.step(carry, MotionSample(x=x, v=v, dx=dx, dt=dt))

    return jax.lax.scan(body, state, (samples.x, samples.v, samples.dx), unroll=unroll)


@eqx.filter_jit
def _simulate(model: AbstractFrictionModel, motion: Motion, state0: Any, unroll: int) -> Array:
    model = unwrap(model)
    samples = motion_samples(motion)
    if samples.x.ndim != 1:
        raise ValueError(
            f"simulate: the motion's signals must have shape (T,), got {samples.x.shape}; "
            "for a batch of motions use jax.vmap(lambda m: fj.simulate(model, m))(motions)."
        )
    state = model.init_state() if state0 is None else state0
    _, force = scan_samples(model, samples, state, unroll)
    return force
