"""`Motion`: a record of displacement and/or velocity with its sample time, and the per-step sample."""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._constraints import as_float_array
from ._smoothing import is_concrete


class MotionSample(NamedTuple):
    """What a model's `step` sees at sample k (all scalars).

    `x` displacement [m]; `v` the velocity at t_k [m/s]; `dx = x_k - x_{k-1}` the displacement increment over
    the step [m] (`dx_0 = 0`); `dt` the sample time [s]. The dynamic models integrate over the step
    `(t_{k-1}, t_k]` with the velocity held at the step's mean `dx / dt` (so a record given as velocity, whose
    displacement is built by zero-order hold, integrates `v_k` itself); `v` enters instantaneous terms
    (viscous friction, static curves).
    """

    x: Array
    v: Array
    dx: Array
    dt: Array


class Motion(eqx.Module):
    """A motion record: displacement `x` [m] and/or velocity `v` [m/s], shape `(T,)`, sample time `dt` [s].

    The sample time belongs to the data, not the model. Values are validated when the record is built from
    concrete arrays (lengths, finiteness, `dt > 0`); inside `jit` / `vmap` only the structure is checked.
    Leading batch axes are allowed (shape `(..., T)`) for `vmap` over motions.

    **Arguments:**

    - `x`: displacement [m], or `None`.
    - `v`: velocity [m/s], or `None`.
    - `dt`: sample time [s], or `None` when only a static velocity curve will be evaluated.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> m = fj.Motion.from_position(1e-5 * np.sin(np.linspace(0, 6.28, 100)), dt=1e-3)
    >>> m.v.shape
    (100,)
    ```
    """

    x: Float[Array, "... T"] | None
    v: Float[Array, "... T"] | None
    dt: Float[Array, ""] | None

    def __init__(self, x: ArrayLike | None = None, v: ArrayLike | None = None, dt: ArrayLike | None = None):
        if x is None and v is None:
            raise ValueError("Motion: give at least one of `x` (displacement, m) or `v` (velocity, m/s).")
        self.x = None if x is None else _as_signal(x, "x")
        self.v = None if v is None else _as_signal(v, "v")
        if self.x is not None and self.v is not None and self.x.shape != self.v.shape:
            raise ValueError(
                f"Motion: `x` and `v` must have the same shape, got {self.x.shape} and {self.v.shape}; "
                "trim or resample one of them."
            )
        if dt is None:
            self.dt = None
        else:
            dtype = (self.x if self.x is not None else self.v).dtype  # type: ignore[union-attr]
            self.dt = jnp.asarray(dt, dtype=dtype)
            if is_concrete(self.dt):
                if self.dt.ndim != 0:
                    raise ValueError(
                        f"Motion: `dt` must be a scalar sample time in seconds, got shape {self.dt.shape}."
                    )
                if not (bool(np.isfinite(np.asarray(self.dt))) and float(np.asarray(self.dt)) > 0):
                    raise ValueError(f"Motion: `dt` must be a positive, finite sample time in seconds, got {dt!r}.")

    @property
    def length(self) -> int:
        """Number of samples T."""
        signal = self.x if self.x is not None else self.v
        return int(signal.shape[-1])  # type: ignore[union-attr]

    @classmethod
    def from_position(cls, x: ArrayLike, dt: ArrayLike) -> Motion:
        """Build a motion from displacement; `v` by central differences (one-sided at the ends)."""
        x = _as_signal(x, "x")
        return cls(x=x, v=velocity_from_position(x, jnp.asarray(dt, x.dtype)), dt=dt)

    @classmethod
    def from_velocity(cls, v: ArrayLike, dt: ArrayLike, x0: ArrayLike = 0.0) -> Motion:
        """Build a motion from velocity; `x_k = x0 + dt * sum_{j=1..k} v_j` (the zero-order hold of `v`)."""
        v = _as_signal(v, "v")
        return cls(x=position_from_velocity(v, jnp.asarray(dt, v.dtype), x0), v=v, dt=dt)


def velocity_from_position(x: Array, dt: Array) -> Array:
    """Central differences (second order inside, first order at the two ends) along the last axis."""
    if x.shape[-1] < 2:
        raise ValueError("Motion: need at least 2 samples of `x` to differentiate it.")
    return jnp.asarray(jnp.gradient(x, axis=-1)) / dt


def position_from_velocity(v: Array, dt: Array, x0: ArrayLike = 0.0) -> Array:
    """Displacement from velocity under zero-order hold: `x_0 = x0`, `x_k = x_{k-1} + v_k * dt`."""
    increments = v.at[..., 0].set(0.0) * dt
    return jnp.asarray(x0, v.dtype) + jnp.cumsum(increments, axis=-1)


def _as_signal(value: ArrayLike, name: str) -> Array:
    array = as_float_array(value)
    if array.ndim < 1:
        raise ValueError(f"Motion: `{name}` must be a 1-D signal of shape (T,), got a scalar.")
    if array.shape[-1] == 0:
        raise ValueError(f"Motion: `{name}` is empty; give at least one sample.")
    if is_concrete(array) and not bool(np.all(np.isfinite(np.asarray(array)))):
        bad = int(np.flatnonzero(~np.isfinite(np.asarray(array).reshape(-1)))[0])
        raise ValueError(
            f"Motion: `{name}` contains NaN or inf (first at flat index {bad}); clean or interpolate the record."
        )
    return array
