"""The Dahl model (Dahl 1968), as summarised in worden2007 §1 and parlitz2004 §II-A."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._constraints import Fixed, Parameter, ParamLike, SidedParameter, model_dtype, positive, real, unwrap
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact, is_concrete
from .._base import AbstractFrictionModel
from .._state_maps import AffineMaps, shaped_like
from ._stribeck import side, sided_positive


class DahlState(eqx.Module):
    """Dahl state: friction force `F` [N]."""

    F: Array


def dahl_distance_update(u: Array, distance: Array, rate: Array, alpha: Array) -> Array:
    """Exact solution of `du/ds = -rate |u|^alpha sgn(u)` after travelled distance `s = distance >= 0`.

    alpha = 1: `u exp(-rate s)`; otherwise `|u|^(1-alpha)` changes linearly in s, with `u` reaching 0 in finite
    distance for alpha < 1 (and staying there).
    """
    q = 1.0 - alpha
    near_one = jnp.abs(q) < 1e-5
    au = jnp.abs(u)
    nonzero = au > 0
    log_au = jnp.log(jnp.where(nonzero, au, 1.0))
    travelled = rate * distance
    safe_q = jnp.where(near_one, 1.0, q)
    base = jnp.exp(safe_q * log_au) - safe_q * travelled  # |u|^q - q rate s
    positive_base = base > 0
    power = jnp.exp(jnp.log(jnp.where(positive_base, base, 1.0)) / safe_q)
    general = jnp.where(positive_base, power, 0.0)
    # near alpha = 1: the expansion to first order in q keeps the derivative with respect to alpha right
    expansion = jnp.exp(log_au - travelled + 0.5 * q * travelled * (2.0 * log_au - travelled))
    magnitude = jnp.where(near_one, expansion, general)
    return jnp.where(nonzero, jnp.sign(u) * magnitude, 0.0)


class UnitExponent(Fixed):
    """Dahl's exponent held at exactly 1, the classical model: what `alpha=fj.Fixed(1.0)` builds. Its value is 1
    whatever its leaf holds (`unwrap` gives ones), so no change of leaves can make `step` and the time-parallel
    form (`Dahl.classical`) disagree."""

    def unwrap(self) -> Array:
        return jnp.ones_like(self.value)


class Dahl(AbstractFrictionModel):
    """The Dahl model: a rate-independent bristle law in the displacement domain.

    `dF/dx = sigma0 |1 - F sgn(dx) / Fc|^alpha sgn(1 - F sgn(dx) / Fc)` (+ `offset`).

    For the displacement increment of a sample the equation is solved exactly (`dahl_distance_update`), so
    the model is a function of the displacement path only and stays stable for any stiffness. In the smooth
    mode the direction sgn(dx) is blended: the updates for both directions are weighted by the smooth step of
    the step velocity dx / dt, and the distance travelled in each direction is a smooth ramp of it (eps in
    m/s).

    **Arguments:**

    - `sigma0`: rest stiffness [N/m] (> 0); pre-sliding force ≈ sigma0 · x.
    - `Fc`: Coulomb force [N] (> 0), the asymptote in sliding; a (+, -) pair for asymmetric friction: `Fc+`
      while dx > 0 (the force tends to +Fc+), `Fc-` while dx < 0 (to -Fc-), the rest stiffness sigma0 in both.
    - `alpha`: shape exponent (> 0; 1 is the classical Dahl model). `fj.Fixed(1.0)` holds the classical model
      (not trained; `classical`) and gives it a time-parallel form (`fj.simulate(..., scan="parallel")`): with
      alpha = 1 the update of a sample is affine in the force, `F_k = e_k F_k-1 + Fc (1 - e_k) sgn(dx)`,
      `e_k = exp(-sigma0 |dx| / Fc)`. (Its structure differs from another fixed exponent's: `fj.stack_models`
      stacks classical models with classical ones.)
    - `offset`: constant force offset [N]. `F0`: initial force [N].
    - `smoothing`: `Exact()` or `Smooth(eps)`, eps in m/s.
    """

    sigma0: Parameter
    Fc: SidedParameter
    alpha: Parameter
    offset: Parameter
    F0: Parameter
    smoothing: AbstractSmoothing
    # the exponent is a `UnitExponent` (exactly 1): the update is affine in the force (`parallel_maps`); static, so
    # that the unwrapped model still says so; `check_inputs` refuses a model whose `alpha` was replaced since
    classical: bool = eqx.field(static=True, default=False)

    requires: ClassVar[frozenset[str]] = frozenset({"x"})
    initial_state_fields: ClassVar[frozenset[str]] = frozenset({"F0"})

    presliding: ClassVar[bool] = True

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[Dahl]:
        s = reader.scales
        return [cls(sigma0=s.stiffness, Fc=s.Fc, offset=s.offset, smoothing=smoothing)]

    def __init__(
        self,
        sigma0: ParamLike,
        Fc: ParamLike,
        alpha: ParamLike = 1.0,
        *,
        offset: ParamLike = 0.0,
        F0: ParamLike = 0.0,
        smoothing: AbstractSmoothing = Exact(),
    ):
        dtype = model_dtype(sigma0, Fc, alpha, offset, F0)
        self.sigma0 = positive(sigma0, "sigma0", dtype, scalar=True)
        self.Fc = sided_positive(Fc, "Fc", dtype)
        self.alpha = positive(alpha, "alpha", dtype, scalar=True)
        fixed = unwrap(self.alpha) if isinstance(self.alpha, Fixed) else None
        if fixed is not None and is_concrete(fixed) and float(np.asarray(fixed)) == 1.0:
            self.alpha = UnitExponent(jnp.asarray(1.0, dtype))
        self.classical = isinstance(self.alpha, UnitExponent)
        self.offset = real(offset, "offset", dtype, scalar=True)
        self.F0 = real(F0, "F0", dtype, scalar=True)
        self.smoothing = smoothing

    def parameter_ranges(self) -> dict[str, float]:
        level = float(np.max(np.abs(np.asarray(unwrap(self.Fc)))))
        return {"offset": level, "F0": level}  # N

    def breakaway_displacement(self) -> float:
        """`Fc / sigma0` [m]."""
        p = unwrap(self)
        return float(p.Fc / p.sigma0)

    def breakaway_force(self) -> float:
        """`Fc` [N]: Dahl's force saturates at the Coulomb level."""
        return float(unwrap(self).Fc)

    def init_state(self) -> DahlState:
        return DahlState(F=jnp.asarray(unwrap(self.F0)))

    def check_inputs(self, inputs: Any) -> None:
        super().check_inputs(inputs)
        if self.classical != isinstance(self.alpha, UnitExponent):
            raise ValueError(
                f"Dahl: `alpha` ({type(self.alpha).__name__}) no longer matches how the model was built "
                f"(classical={self.classical}): build a new fj.Dahl(...) with the exponent you want instead of "
                "replacing the field (alpha=fj.Fixed(1.0) is the classical model)."
            )

    def parallel_maps(self, samples: MotionSample) -> Any:
        """With the exponent fixed at 1 (`classical`), the update of a sample is affine in the force for either
        direction, and so is its smooth blend of the two: `F -> (up e+ + (1 - up) e-) F + up Fc+ (1 - e+) -
        (1 - up) Fc- (1 - e-)`, `e+- = exp(-sigma0 d+- / Fc+-)`, `d+-` the distance moved each way (the
        time-parallel free run). `None` otherwise (a trained exponent: no such form)."""
        if not self.classical:
            return None
        p = unwrap(self)
        v_step = samples.dx / samples.dt
        up = p.smoothing.step(v_step)

        def decay(direction: float, Fc: Array) -> Array:
            return jnp.exp(-p.sigma0 / Fc * _travelled(p, direction, v_step, samples.dt))

        Fc_up, Fc_down = side(p.Fc, 0), side(p.Fc, 1)
        e_up, e_down = decay(1.0, Fc_up), decay(-1.0, Fc_down)
        scale = up * e_up + (1.0 - up) * e_down
        shift = up * Fc_up * (1.0 - e_up) - (1.0 - up) * Fc_down * (1.0 - e_down)
        return shaped_like(self.init_state(), [AffineMaps(scale, shift)])

    def step(self, state: DahlState, sample: MotionSample) -> tuple[DahlState, Array]:
        p = unwrap(self)
        F = state.F
        v_step = sample.dx / sample.dt  # the velocity held over the step

        def moved(direction: float, Fc: Array) -> Array:
            rate = p.sigma0 / Fc  # 1/m
            u = 1.0 - direction * F / Fc
            u = dahl_distance_update(u, _travelled(p, direction, v_step, sample.dt), rate, p.alpha)
            return direction * Fc * (1.0 - u)

        up = p.smoothing.step(v_step)  # direction of motion (exact: dx > 0)
        F = up * moved(1.0, side(p.Fc, 0)) + (1.0 - up) * moved(-1.0, side(p.Fc, 1))
        return DahlState(F=F), F + p.offset


def _travelled(p: Dahl, direction: float, v_step: Array, dt: Array) -> Array:
    """The distance [m] an unwrapped Dahl model `p` moves in `direction` over a sample held at `v_step` (a smooth
    ramp of it in smooth mode)."""
    return p.smoothing.relu(direction * v_step) * dt
