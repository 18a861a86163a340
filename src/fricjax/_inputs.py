"""Model inputs: `Motion` (displacement, velocity, acceleration, normal load, sample time), `InputRecord` (the
input signals of a system model), the per-step samples a model's `step` sees, and the derived signals."""

from __future__ import annotations

import pathlib
import sys
import warnings
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._constraints import as_float_array
from ._smoothing import is_concrete


class MotionSample(NamedTuple):
    """What a friction model's `step` sees at sample k (all scalars).

    `x` displacement [m]; `v` the velocity at t_k [m/s]; `dx = x_k - x_{k-1}` the displacement increment over
    the step [m] (`dx_0 = 0`); `dt` the sample time [s]. The dynamic models integrate over the step
    `(t_{k-1}, t_k]` with the velocity held at the step's mean `dx / dt` (so a record given as velocity, whose
    displacement is built by zero-order hold, integrates `v_k` itself); `v` enters instantaneous terms
    (viscous friction, static curves). `a` acceleration [m/s^2] and `normal_force` [N] are present (not `None`)
    only for models that declare them in `requires` ("a", "normal_force").

    Stacked along time (every signal of shape `(T,)`; `dt`, constant over the record, stays a scalar) it is
    what `simulate` scans over: `Motion.samples(requires)`; `samples.at(k)` is sample k.
    """

    x: Array
    v: Array
    dx: Array
    dt: Array
    a: Array | None = None
    normal_force: Array | None = None

    def at(self, k: int) -> MotionSample:
        """Sample `k` of stacked samples (signals indexed along time, the scalar `dt` kept)."""
        return MotionSample(*(field if field is None or jnp.ndim(field) == 0 else field[k] for field in self))  # type: ignore[arg-type]


class Motion(eqx.Module):
    """A motion record: displacement `x` [m] and/or velocity `v` [m/s], shape `(T,)`, sample time `dt` [s].

    The sample time belongs to the data, not the model. Values are validated when the record is built from
    concrete arrays (lengths, finiteness, `dt > 0`); inside `jit` / `vmap` only the structure is checked.
    Leading batch axes are allowed (shape `(..., T)`) for `vmap` over motions.

    **Arguments:**

    - `x`: displacement [m], or `None`.
    - `v`: velocity [m/s], or `None`.
    - `dt`: sample time [s], or `None` when only a static velocity curve will be evaluated.
    - `a`: acceleration [m/s^2], or `None` (derived from `v` by central differences for models that need it).
    - `normal_force`: normal load [N], or `None` (required by models that declare it).

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
    a: Float[Array, "... T"] | None
    normal_force: Float[Array, "... T"] | None

    def __init__(
        self,
        x: ArrayLike | None = None,
        v: ArrayLike | None = None,
        dt: ArrayLike | None = None,
        a: ArrayLike | None = None,
        normal_force: ArrayLike | None = None,
    ):
        if x is None and v is None:
            raise ValueError("Motion: give at least one of `x` (displacement, m) or `v` (velocity, m/s).")
        self.x = None if x is None else _as_signal(x, "x")
        self.v = None if v is None else _as_signal(v, "v")
        self.a = None if a is None else _as_signal(a, "a")
        self.normal_force = None if normal_force is None else _as_signal(normal_force, "normal_force")
        shape = (self.x if self.x is not None else self.v).shape  # type: ignore[union-attr]
        for name in ("x", "v", "a", "normal_force"):
            signal = getattr(self, name)
            if signal is not None and signal.shape != shape:
                raise ValueError(
                    f"Motion: every signal must have the same shape; `{name}` has {signal.shape}, the record "
                    f"{shape}. Trim or resample it."
                )
        if dt is None:
            self.dt = None
        else:
            self.dt = _sample_time(dt, (self.x if self.x is not None else self.v).dtype)  # type: ignore[union-attr]

    @property
    def length(self) -> int:
        """Number of samples T."""
        signal = self.x if self.x is not None else self.v
        return int(signal.shape[-1])  # type: ignore[union-attr]

    def samples(self, requires: frozenset[str] | tuple[str, ...] = ()) -> MotionSample:
        """The per-step signals along time: a `MotionSample` whose signals have shape `(..., T)` (`dt` a scalar).

        Missing signals are derived once, before any scan: `v` from `x` by central differences, `x` from `v`
        by zero-order hold, `a` from `v` by central differences (only when `"a"` is in `requires`);
        `normal_force` is included when `"normal_force"` is in `requires` (it cannot be derived).
        """
        x, v, a, normal_force = self._signals(requires, host=False)
        dx = jnp.diff(x, axis=-1, prepend=x[..., :1])
        dt_value = jnp.ones((), x.dtype) if self.dt is None else self.dt
        return MotionSample(x=x, v=v, dx=dx, dt=dt_value, a=a, normal_force=normal_force)

    def host_signals(self, requires: frozenset[str] | tuple[str, ...] = ()) -> tuple[np.ndarray, ...]:
        """`(x, v, a, normal_force)` as NumPy arrays, derived as in `samples` but on the host (no XLA program per
        record length: what padding several records of different lengths into one batch uses); `a` and
        `normal_force` are None unless asked for in `requires`."""
        return self._signals(requires, host=True)

    def _signals(self, requires: frozenset[str] | tuple[str, ...], host: bool) -> tuple[Any, ...]:
        def take(signal: Any) -> Any:  # on the host: NumPy arrays; traced: as they are
            return np.asarray(signal) if host and signal is not None else signal

        dt = take(self.dt)
        x, v = take(self.x), take(self.v)
        zeros = np.zeros_like if host else jnp.zeros_like
        if v is None:
            assert x is not None  # __init__ guarantees one of the two
            v = velocity_from_position(x, dt) if dt is not None else zeros(x)
        if x is None:
            x = position_from_velocity(v, dt) if dt is not None else zeros(v)
        a = None
        if "a" in requires:
            if self.a is not None:
                a = take(self.a)
            elif dt is not None:
                a = velocity_from_position(v, dt)
            else:
                raise ValueError("Motion: the model needs the acceleration `a`; pass Motion(a=...) or `dt`.")
        normal_force = None
        if "normal_force" in requires:
            if self.normal_force is None:
                raise ValueError("Motion: the model needs the normal load; pass Motion(..., normal_force=...) [N].")
            normal_force = take(self.normal_force)
        return x, v, a, normal_force

    @classmethod
    def from_position(cls, x: ArrayLike, dt: ArrayLike) -> Motion:
        """Build a motion from displacement; `v` by central differences (one-sided at the ends)."""
        x = _as_signal(x, "x")
        dt = _sample_time(dt, x.dtype)  # checked before it divides
        return cls(x=x, v=velocity_from_position(x, dt), dt=dt)

    @classmethod
    def from_velocity(cls, v: ArrayLike, dt: ArrayLike, x0: ArrayLike = 0.0) -> Motion:
        """Build a motion from velocity; `x_k = x0 + dt * sum_{j=1..k} v_j` (the zero-order hold of `v`)."""
        v = _as_signal(v, "v")
        dt = _sample_time(dt, v.dtype)
        return cls(x=position_from_velocity(v, dt, x0), v=v, dt=dt)


def _sample_time(dt: ArrayLike, dtype: Any) -> Array:
    """`dt` [s] as a scalar of the signals' `dtype`, checked where concrete (a positive, finite scalar) before
    anything is divided by it."""
    if isinstance(dt, (bool, np.bool_)):
        raise TypeError(f"Motion: `dt` must be a sample time in seconds, got {dt!r}.")
    value = jnp.asarray(dt, dtype=dtype)
    if is_concrete(value):
        if value.ndim != 0:
            raise ValueError(f"Motion: `dt` must be a scalar sample time in seconds, got shape {value.shape}.")
        if not (bool(np.isfinite(np.asarray(value))) and float(np.asarray(value)) > 0):
            raise ValueError(f"Motion: `dt` must be a positive, finite sample time in seconds, got {dt!r}.")
    return value


def velocity_from_position(x: Array, dt: Array) -> Array:
    """Central differences (second order inside, first order at the two ends) along the last axis."""
    if x.shape[-1] < 2:
        column = x.ndim == 2 and x.shape[0] > 1  # a column vector: time along the first axis
        raise ValueError(
            "Motion: need at least 2 samples to differentiate a signal"
            + (
                f"; the signal has shape {tuple(x.shape)} and time is the last axis: pass a 1-D array (np.ravel)."
                if column
                else f", got shape {tuple(x.shape)}."
            )
        )
    if isinstance(x, np.ndarray):  # on the host (NumPy in, NumPy out)
        return np.gradient(x, axis=-1) / np.asarray(dt, x.dtype)
    return jnp.asarray(jnp.gradient(x, axis=-1)) / dt


def position_from_velocity(v: Array, dt: Array, x0: ArrayLike = 0.0) -> Array:
    """Displacement from velocity under zero-order hold: `x_0 = x0`, `x_k = x_{k-1} + v_k * dt`."""
    if isinstance(v, np.ndarray):  # on the host (NumPy in, NumPy out)
        increments = v * np.asarray(dt, v.dtype)
        increments[..., 0] = 0.0
        return np.asarray(x0, v.dtype) + np.cumsum(increments, axis=-1)
    increments = v.at[..., 0].set(0.0) * dt
    return jnp.asarray(x0, v.dtype) + jnp.cumsum(increments, axis=-1)


_WARNED_X64 = False
# the packages a call from the user's code passes through before it reaches `_as_signal`
_LIBRARIES = tuple(str(pathlib.Path(m.__file__).parent) for m in (jax, eqx) if m.__file__) + (
    str(pathlib.Path(__file__).parent),
)


def _caller_level() -> int:
    """The `stacklevel` of a warning raised here that points at the user's line (not at fricjax, equinox or JAX,
    which build a Motion through constructors and loaders)."""
    frame: Any = sys._getframe(1)
    level = 1
    while frame is not None and frame.f_code.co_filename.startswith(_LIBRARIES):
        frame, level = frame.f_back, level + 1
    return level


def _as_signal(value: ArrayLike, name: str, owner: str = "Motion") -> Array:
    global _WARNED_X64
    if isinstance(value, np.ndarray) and value.dtype == np.float64 and not jax.config.read("jax_enable_x64"):
        if not _WARNED_X64:  # once per session
            _WARNED_X64 = True
            warnings.warn(
                f"fricjax: `{name}` is float64 but JAX runs in float32 (x64 off), so records are rounded to float32 "
                "(small motions on large offsets lose accuracy); call jax.config.update('jax_enable_x64', True) "
                "first.",
                UserWarning,
                stacklevel=_caller_level(),
            )
    try:
        array = as_float_array(value)
    except TypeError as err:
        raise TypeError(f"{owner}: `{name}`: {err}") from None
    if array.ndim < 1:
        raise ValueError(f"{owner}: `{name}` must be a 1-D signal of shape (T,), got a scalar.")
    if array.shape[-1] == 0:
        raise ValueError(f"{owner}: `{name}` is empty; give at least one sample.")
    if is_concrete(array) and not bool(np.all(np.isfinite(np.asarray(array)))):
        bad = int(np.flatnonzero(~np.isfinite(np.asarray(array).reshape(-1)))[0])
        raise ValueError(
            f"{owner}: `{name}` contains NaN or inf (first at flat index {bad}); clean or interpolate the record."
        )
    return array


class InputRecord(eqx.Module):
    """The input signals of a system model (a plant with its controller): named signals of shape `(T,)` and the
    sample time `dt` [s]. `simulate` scans over them; each step sees a dict `{name: value_k, ..., "dt": dt}`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> record = fj.InputRecord(dt=1e-3, vir=np.zeros(100))
    >>> record.length
    100
    ```
    """

    signals: dict[str, Array]
    dt: Array

    def __init__(self, dt: ArrayLike, **signals: ArrayLike):
        if not signals:
            raise ValueError("InputRecord: give at least one named signal, e.g. InputRecord(dt=1e-3, vir=...).")
        arrays = {name: _as_signal(value, name, "InputRecord") for name, value in signals.items()}
        for name, array in arrays.items():
            if array.ndim != 1:
                raise ValueError(
                    f"InputRecord: `{name}` must have shape (T,), got {array.shape}; for a batch of records use "
                    "jax.vmap over records built inside the mapped function."
                )
        shapes = {name: array.shape for name, array in arrays.items()}
        if len(set(shapes.values())) != 1:
            raise ValueError(f"InputRecord: every signal must have the same shape (one per sample), got {shapes}.")
        self.signals = arrays
        dtype = next(iter(arrays.values())).dtype
        self.dt = jnp.asarray(dt, dtype)
        if is_concrete(self.dt) and not (self.dt.ndim == 0 and float(self.dt) > 0 and np.isfinite(float(self.dt))):
            raise ValueError(f"InputRecord: `dt` must be a positive, finite scalar sample time in seconds, got {dt!r}.")

    @property
    def length(self) -> int:
        """Number of samples T."""
        return int(next(iter(self.signals.values())).shape[0])

    def samples(self) -> dict[str, Array]:
        """The per-step signals, each `(..., T)`, and the scalar `dt`."""
        return {**self.signals, "dt": self.dt}
