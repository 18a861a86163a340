"""LuGre behind a linkage with backlash: a play in series with the bristles, in the load path (a friction damper's
linkage; LuGre: Canudas de Wit et al. 1995, worden2007 §3.2 eqs. 3-5; the device: Downey et al., Eng. Struct.
113:287-298, 2016, `shared/data/README.md` §3)."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._constraints import Parameter, ParamLike, model_dtype, positive, real, unwrap
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact
from .._base import AbstractFrictionModel
from ._lugre import _nonnegative
from ._stribeck import AbstractStribeck, ExponentialStribeck, checked_stribeck


class LuGreBacklashState(eqx.Module):
    """The total deflection `w` [m]: the linkage's slack crossed plus the bristles' elastic deflection. The bristles'
    deflection is `z = sign(w) max(|w| - gap / 2, 0)` (`LuGreBacklash.bristles`); `|w| <= gap / 2`: the linkage is
    open, at `w / (gap / 2)` in the gap (-1..1)."""

    w: Array


class LuGreBacklash(AbstractFrictionModel):
    """LuGre driven through a linkage with backlash: a play of total width `gap` [m] in series with the bristles.

    The measured displacement `x` drives the linkage; the linkage pushes the bristles only while it is engaged. With
    the total deflection `w` (the slack crossed plus the bristles' elastic deflection `z`) and the dead zone
    `z = sign(w) max(|w| - gap / 2, 0)` the model is LuGre's bristle law on `w`,

    `dw/dt = v - sigma0 |v| z / s(v)`,  `F = sigma0 z + sigma1 dz/dt + sigma2 v + offset`,

    so after a reversal from sliding the bristles unload to 0 (the contact opens), the friction force stays 0 while
    `x` crosses the gap (no force can be held across an open linkage; the measured force is `sigma2 v + offset`
    there), then builds up in the other direction: the loops of a friction damper with a worn linkage (the damper
    records of `shared/data`). In steady sliding the force is LuGre's `s(v) + sigma2 v`. `fj.Backlash(fj.LuGre(...),
    gap)` puts the play in the *motion* path instead: there the friction element holds its force while the gap is
    crossed. As `gap -> 0` the model is the exact LuGre (in smooth mode LuGre also smooths `|v|`, this model does not).

    Each sample is advanced exactly for the velocity `dx / dt` held over the step, in up to three phases: the bristles
    unload to 0 (LuGre's exponential approach, in displacement), the slack is crossed, the bristles load again.
    `dz/dt` is evaluated at the end of the step, as in `fj.LuGre`: 0 in the gap, `v` as the contact closes, so with
    `sigma1 > 0` the force steps by `sigma1 |v|` where the contact opens and closes (as the bristles' rate does), and
    a fit's loss then steps with `gap` too; with `sigma1 = 0` the force is continuous in the input and in the
    parameters, its stiffness changing where the contact opens and closes. Smooth mode (`Smooth(eps)`, eps in m/s)
    chooses the Stribeck branch of an asymmetric curve by the smoothing's step, as LuGre does; the phases need no
    smoothing.

    **Arguments:**

    - `stribeck`: the Stribeck curve s(v) [N] (pairs of coefficients: asymmetric friction).
    - `sigma0`: bristle stiffness [N/m] (> 0); `sigma1`: bristle damping [N·s/m] (>= 0, on `dz/dt`, 0 in the gap);
      `sigma2`: viscous coefficient [N·s/m] (>= 0).
    - `gap`: the linkage's total play [m] (> 0; the displacement crossed at zero friction force after each
      reversal).
    - `offset`: constant force offset [N].
    - `w0`: the total deflection at the first sample [m] (0: centred in the gap, at rest; `gap / 2 + z`: engaged,
      the bristles deflected by `z`). It only sets the state at rest: a fit to several records estimates each
      record's.
    - `smoothing`: `Exact()` or `Smooth(eps)`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> model = fj.LuGreBacklash(fj.ExponentialStribeck(Fc=1.0, Fs=1.0, vs=1e-3), 1e4, 0.0, 0.0, gap=2e-3)
    >>> x = np.concatenate([np.linspace(0.0, 4e-3, 41), np.linspace(4e-3, 0.0, 41)[1:]])
    >>> force = np.asarray(fj.simulate(model, fj.Motion.from_position(x, dt=1e-3)))
    >>> np.round(force[[40, 41, 55, 61, 63]], 3).tolist()  # sliding; opened; in the gap; loading the other way
    [1.0, 0.0, 0.0, -0.264, -0.9]
    ```
    """

    stribeck: AbstractStribeck
    sigma0: Parameter
    sigma1: Parameter
    sigma2: Parameter
    gap: Parameter
    offset: Parameter
    w0: Parameter
    smoothing: AbstractSmoothing

    requires: ClassVar[frozenset[str]] = frozenset({"v", "dt"})
    initial_state_fields: ClassVar[frozenset[str]] = frozenset({"w0"})
    nonnegative_fields: ClassVar[frozenset[str]] = frozenset({"sigma1", "sigma2"})

    presliding: ClassVar[bool] = True

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[LuGreBacklash]:
        s = reader.scales
        stribeck = ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)
        gap, sigma0 = reader.linkage_gap()
        return [cls(stribeck, sigma0=sigma0, sigma1=0.0, sigma2=s.Fv, gap=gap, offset=s.offset, smoothing=smoothing)]

    def __init__(
        self,
        stribeck: AbstractStribeck,
        sigma0: ParamLike,
        sigma1: ParamLike,
        sigma2: ParamLike,
        gap: ParamLike,
        *,
        offset: ParamLike = 0.0,
        w0: ParamLike = 0.0,
        smoothing: AbstractSmoothing = Exact(),
    ):
        dtype = model_dtype(*jax.tree_util.tree_leaves(stribeck), sigma0, sigma1, sigma2, gap, offset, w0)
        self.stribeck = checked_stribeck(stribeck, "LuGreBacklash")
        self.sigma0 = positive(sigma0, "sigma0", dtype, scalar=True)
        self.sigma1 = _nonnegative(sigma1, "sigma1", dtype)
        self.sigma2 = _nonnegative(sigma2, "sigma2", dtype)
        self.gap = positive(gap, "gap", dtype, scalar=True)
        self.offset = real(offset, "offset", dtype, scalar=True)
        self.w0 = real(w0, "w0", dtype, scalar=True)
        self.smoothing = smoothing

    def parameter_ranges(self) -> dict[str, float]:
        p = unwrap(self)
        level = float(np.max(np.abs(np.asarray(p.stribeck.Fc))))
        return {"offset": level, "w0": float(p.gap)}  # N, m

    def init_state(self) -> LuGreBacklashState:
        return LuGreBacklashState(w=jnp.asarray(unwrap(self.w0)))

    def bristles(self, state: LuGreBacklashState) -> Array:
        """The bristles' elastic deflection `z` [m] of a state (0 while the linkage is open)."""
        return _dead_zone(state.w, 0.5 * unwrap(self.gap))

    def step(self, state: LuGreBacklashState, sample: MotionSample) -> tuple[LuGreBacklashState, Array]:
        p = unwrap(self)
        v_step = sample.dx / sample.dt  # the velocity held over (t_{k-1}, t_k]
        s = p.stribeck(v_step, p.smoothing.step(v_step))  # the branch of the direction of motion [N]
        length = s / p.sigma0  # the bristles' relaxation length [m]: z approaches +-length in sliding
        half = 0.5 * p.gap
        direction = jnp.sign(sample.dx)
        travel = jnp.abs(sample.dx)
        along = direction * state.w  # the total deflection along the motion
        load = _dead_zone(along, half)  # the bristles' deflection along the motion: < 0 while they unload
        play = _clip(along / half)  # the slack along the motion: 1 engaged, pushing
        # 1. unloading: the deflection decays towards +length along the motion and reaches 0 after `to_zero`
        unloading = load < 0
        to_zero = length * jnp.log1p(jnp.maximum(-load, 0.0) / length)
        opens = unloading & (travel >= to_zero)
        first = jnp.where(unloading, jnp.minimum(travel, to_zero), 0.0)
        load = jnp.where(opens, 0.0, jnp.where(unloading, _approach(load, length, first), load))
        rest = travel - first
        # 2. the slack, crossed at zero force (only once the bristles are unloaded and the linkage is open)
        crossing = (load <= 0.0) & (play < 1.0)
        slack = jnp.where(crossing, jnp.minimum(rest, half * (1.0 - play)), 0.0)
        play = jnp.where(crossing, play + slack / half, jnp.where(load > 0.0, 1.0, play))
        rest = rest - slack
        # 3. loading: the linkage engaged, the bristles follow LuGre's law along the motion
        load = jnp.where(rest > 0.0, _approach(load, length, rest), load)  # load >= 0 here: 0 once opened
        moved = travel > 0
        z = jnp.where(moved, direction * load, _dead_zone(state.w, half))
        w = jnp.where(moved, direction * (half * play + load), state.w)
        dz = jnp.where(moved & (z != 0.0), v_step - jnp.abs(v_step) * z / length, 0.0)
        force = p.sigma0 * z + p.sigma1 * dz + p.sigma2 * sample.v + p.offset
        return LuGreBacklashState(w=w), force


def _dead_zone(total: Array, half: Array) -> Array:
    """The bristles' deflection [m] of a total deflection `total` [m] behind a play of half-width `half` [m]: what
    the slack does not take up, exactly 0 inside the gap (`total - half * _clip(total / half)` would leave round-off
    there, which the phases of `step` read as a loaded or unloading contact), the ties resolved as in `_clip`."""
    return jnp.where(total > half, total - half, jnp.where(total < -half, total + half, 0.0))


def _clip(value: Array) -> Array:
    """`value` clipped to [-1, 1], the ties resolved by `where` (not `jnp.clip`, whose derivative at a tie is the
    mean of both sides'), so that a derivative at the edge of the gap is one side's."""
    return jnp.where(value > 1.0, 1.0, jnp.where(value < -1.0, -1.0, value))


def _approach(load: Array, length: Array, travel: Array) -> Array:
    """LuGre's bristle law along the motion over `travel` [m]: `d load / d travel = 1 - load / length`, exactly."""
    return length + (load - length) * jnp.exp(-travel / length)
