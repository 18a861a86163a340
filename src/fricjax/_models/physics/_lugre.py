"""The LuGre model (Canudas de Wit et al. 1995; worden2007 §3.2 eqs. 3-5 and §4.2 eqs. 10-12)."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._constraints import Parameter, ParamLike, model_dtype, positive, real, unwrap
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact, is_concrete
from .._base import AbstractFrictionModel
from .._state_maps import AffineMaps, shaped_like
from ._stribeck import AbstractStribeck, ExponentialStribeck, checked_stribeck


def phi1(h: Array) -> Array:
    """(1 - exp(-h)) / h for h >= 0, with the limit 1 at h = 0 (finite value and gradient)."""
    small = h < 1e-6
    safe_h = jnp.where(small, 1.0, h)
    return jnp.where(small, 1.0 - 0.5 * h, -jnp.expm1(-safe_h) / safe_h)


def relax(state: Array, rate: Array, forcing: Array, dt: Array) -> Array:
    """Exact solution after `dt` of `dy/dt = forcing - rate * y` with constant `rate >= 0` and `forcing`.

    `y(dt) = y exp(-rate dt) + forcing dt (1 - exp(-rate dt)) / (rate dt)`: unconditionally stable, so stiff
    bristles (rate dt >> 1) need no sub-stepping, and exact for a velocity held over the step.
    """
    h = rate * dt
    return state * jnp.exp(-h) + forcing * dt * phi1(h)


class LuGreState(eqx.Module):
    """LuGre state: mean bristle deflection `z` [m]."""

    z: Array


class LuGre(AbstractFrictionModel):
    """The LuGre dynamic friction model.

    `dz/dt = v - sigma0 |v| z / s(v)`,  `F = sigma0 z + sigma1 dz/dt + sigma2 v + offset`,

    with `s(v)` a Stribeck curve in newtons (`ExponentialStribeck`, worden2007 eq. 5, or `RationalStribeck`,
    eq. 10: worden2007 writes s in units of z, i.e. s / sigma0). The bristle equation is linear in `z` for the
    velocity held over a sample, and is advanced by its exact solution (`relax`), which stays stable for
    sigma0 = 1e8 N/m at 1 kHz. The velocity held over the step `(t_{k-1}, t_k]` is the step's mean velocity
    `dx_k / dt`, so the bristle follows the recorded displacement exactly (`z = x` in pre-sliding from rest);
    `dz/dt` is evaluated at the end of the step, and the viscous term uses the sample's velocity `v_k`.

    Asymmetric dynamic friction: a Stribeck curve with (+, -) pairs of coefficients gives separate branches for
    the two directions of motion, chosen by the sign of `dx / dt` (smoothly, by the smoothing's step, in smooth
    mode); steady sliding then gives `s+(v) + sigma2 v` for v > 0 and `-s-(|v|) + sigma2 v` for v < 0.

    **Arguments:**

    - `stribeck`: the Stribeck curve s(v) [N].
    - `sigma0`: bristle stiffness [N/m] (> 0; 1e4-1e8).
    - `sigma1`: micro-viscous (bristle damping) coefficient [N·s/m] (>= 0; typically ~ sqrt(sigma0 * mass)).
    - `sigma2`: viscous coefficient [N·s/m] (>= 0).
    - `offset`: constant force offset b [N] (worden2007 eq. 11).
    - `z0`: bristle deflection at the first sample z(1) [m], a parameter as in worden2007 eq. 12 (the first
      sample has `dx_0 = 0`, so the state is `z0` there).
    - `smoothing`: `Exact()` or `Smooth(eps)`, eps in m/s smoothing |v|.

    ```python
    >>> import fricjax as fj
    >>> model = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4)
    >>> model.init_state().z.shape
    ()
    ```
    """

    stribeck: AbstractStribeck
    sigma0: Parameter
    sigma1: Parameter
    sigma2: Parameter
    offset: Parameter
    z0: Parameter
    smoothing: AbstractSmoothing

    requires: ClassVar[frozenset[str]] = frozenset({"v", "dt"})
    initial_state_fields: ClassVar[frozenset[str]] = frozenset({"z0"})
    nonnegative_fields: ClassVar[frozenset[str]] = frozenset({"sigma1", "sigma2"})

    presliding: ClassVar[bool] = True

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[LuGre]:
        s = reader.scales
        stribeck = ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)
        return [cls(stribeck, sigma0=s.stiffness, sigma1=0.0, sigma2=s.Fv, offset=s.offset, smoothing=smoothing)]

    def __init__(
        self,
        stribeck: AbstractStribeck,
        sigma0: ParamLike,
        sigma1: ParamLike,
        sigma2: ParamLike,
        *,
        offset: ParamLike = 0.0,
        z0: ParamLike = 0.0,
        smoothing: AbstractSmoothing = Exact(),
    ):
        dtype = model_dtype(*jax.tree_util.tree_leaves(stribeck), sigma0, sigma1, sigma2, offset, z0)
        self.stribeck = checked_stribeck(stribeck, "LuGre")
        self.sigma0 = positive(sigma0, "sigma0", dtype, scalar=True)
        self.sigma1 = _nonnegative(sigma1, "sigma1", dtype)
        self.sigma2 = _nonnegative(sigma2, "sigma2", dtype)
        self.offset = real(offset, "offset", dtype, scalar=True)
        self.z0 = real(z0, "z0", dtype, scalar=True)
        self.smoothing = smoothing

    def parameter_ranges(self) -> dict[str, float]:
        p = unwrap(self)
        level = float(np.max(np.abs(np.asarray(p.stribeck.Fc))))
        return {"offset": level, "z0": level / float(np.max(np.asarray(p.sigma0)))}  # N, m (pre-sliding range)

    def batch_minor(self) -> bool:
        """Under vmap, the batch-minor free run, its rows written in the loop (1024 models sharded over two
        devices: 5.4-5.5x a numba trajectory's throughput; benchmarks/README.md)."""
        return True

    def parallel_maps(self, samples: MotionSample) -> Any:
        """The bristle update is affine in `z` for the velocity held over a sample (`relax`), with any smoothing:
        `z_k = exp(-h_k) z_k-1 + v_k dt phi1(h_k)`, `h_k = rate_k dt` (the time-parallel free run)."""
        p = unwrap(self)
        v_step = samples.dx / samples.dt
        s = p.stribeck(v_step, p.smoothing.step(v_step))
        h = p.sigma0 * p.smoothing.abs(v_step) / s * samples.dt
        return shaped_like(self.init_state(), [AffineMaps(jnp.exp(-h), v_step * samples.dt * phi1(h))])

    def breakaway_displacement(self) -> float:
        """`s(0) / sigma0` [m]: the bristle deflection at the static force."""
        p = unwrap(self)
        return float(p.stribeck(0.0) / p.sigma0)

    def breakaway_force(self) -> float:
        """`s(0)` [N]: the Stribeck curve at standstill."""
        return float(unwrap(self).stribeck(0.0))

    def implausible(self, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
        p = unwrap(self)
        return AbstractFrictionModel.implausible(p, record_excursion, bounds=bounds) + p.held_at_zero(
            ("sigma1", "sigma2"), bounds
        )

    def init_state(self) -> LuGreState:
        return LuGreState(z=jnp.asarray(unwrap(self.z0)))

    def step(self, state: LuGreState, sample: MotionSample) -> tuple[LuGreState, Array]:
        p = unwrap(self)
        v_step = sample.dx / sample.dt  # the velocity held over (t_{k-1}, t_k]: consistent with x
        s = p.stribeck(v_step, p.smoothing.step(v_step))  # the branch of the direction of motion
        rate = p.sigma0 * p.smoothing.abs(v_step) / s  # 1/s
        z = relax(state.z, rate, v_step, sample.dt)
        dz = v_step - rate * z
        force = p.sigma0 * z + p.sigma1 * dz + p.sigma2 * sample.v + p.offset
        return LuGreState(z=z), force


def _nonnegative(value: ParamLike, name: str, dtype: Any = None) -> Array:
    array = real(value, name, dtype, scalar=True)
    if is_concrete(unwrap(array)) and bool(np.any(np.asarray(unwrap(array)) < 0)):
        raise ValueError(f"`{name}` must be >= 0 (a damping coefficient, N·s/m), got {value!r}.")
    return array
