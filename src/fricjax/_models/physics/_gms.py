"""The Generalized Maxwell-Slip (GMS) model (Lampaert, Al-Bender & Swevers 2003; worden2007 §3.3 eqs. 6-7)."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import (
    Parameter,
    ParameterVector,
    ParamLike,
    Simplex,
    as_float_array,
    model_dtype,
    positive,
    real,
    unwrap,
)
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact, is_concrete
from .._base import NEGLIGIBLE, AbstractFrictionModel
from ._stribeck import AbstractStribeck, ExponentialStribeck, checked_stribeck


class GMSState(eqx.Module):
    """GMS state: element forces `F` [N] and slip indicators `slipping` in [0, 1] (exactly 0/1 in exact mode)."""

    F: Float[Array, "N"]
    slipping: Float[Array, "N"]


class GMS(AbstractFrictionModel):
    """Generalized Maxwell-Slip friction: N elements sharing a Stribeck curve, plus a viscous term.

    Each element i obeys (worden2007 eqs. 6-7; Lampaert et al. 2003):

    - sticking: `dF_i/dt = k_i v`, until `|F_i|` reaches `alpha_i s(v)`, where it starts slipping;
    - slipping: `dF_i/dt = C (alpha_i sgn(v) - F_i / s(v))` (worden2007 eq. 7 with the sign convention that
      makes `F_i -> alpha_i s(v) sgn(v)`), until the velocity reverses (or is zero), where it sticks again.

    `F = sum_i F_i + sigma2 v + offset`. With `sum alpha_i = 1` the steady sliding force is `s(v) + sigma2 v`,
    and small displacements give `sum k_i x` (pre-sliding), with non-local memory through the elements.

    Discrete update for a sample, with the velocity held over the step `(t_{k-1}, t_k]` equal to the step's
    mean velocity `dx / dt` (`dx` the displacement increment; sgn(v) is sgn(dx)): sticking elements move by
    `k_i dx` and are clipped to `+/- alpha_i s(dx/dt)` (the clip starts slipping); slipping elements relax
    exactly towards `alpha_i s(dx/dt) sgn(dx)` with rate `C / s(dx/dt)` (stable for any C dt). The viscous
    term uses the sample's velocity `v_k`.

    Smooth mode (`Smooth(eps)`, eps in metres): the stick/slip decisions become smooth steps of lengths
    (`dx` for the direction, `(|F_i| - alpha_i s) / k_i` for the threshold, `F_i / k_i` for the reversal),
    the clip a smooth clip, and `slipping` a continuous weight; it converges to the exact switching as eps -> 0.

    Asymmetric dynamic friction: with a Stribeck curve of (+, -) pairs, elements slip towards `+alpha_i s+(v)`
    (dx > 0) or `-alpha_i s-(v)` (dx < 0) and stick inside `[-alpha_i s-(v), alpha_i s+(v)]`; steady sliding
    gives `s+(v)` and `-s-(|v|)` (plus the viscous term). The branch follows the smooth step of `dx` in smooth mode.

    **Arguments:**

    - `stribeck`: the shared Stribeck curve s(v) [N].
    - `k`: element stiffnesses [N/m] (> 0), shape (N,).
    - `alpha`: element fractions (> 0, summing to 1), shape (N,).
    - `C`: attraction rate [N/s] (> 0) of the slip dynamics.
    - `sigma2`: viscous coefficient [N·s/m] (>= 0). `offset`: force offset [N].
    - `smoothing`: `Exact()` or `Smooth(eps)`.

    ```python
    >>> import fricjax as fj
    >>> gms = fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=[2e4, 1e4], alpha=[0.6, 0.4], C=20.0)
    >>> gms.init_state().F.shape
    (2,)
    ```
    """

    stribeck: AbstractStribeck
    k: ParameterVector
    alpha: ParameterVector
    C: Parameter
    sigma2: Parameter
    offset: Parameter
    smoothing: AbstractSmoothing

    requires: ClassVar[frozenset[str]] = frozenset({"x", "v", "dt"})
    packed_unroll: ClassVar[int | None] = (
        1  # packed, unroll 1: ~110 ns per step against ~430 plain (benchmarks/README.md)
    )
    nonnegative_fields: ClassVar[frozenset[str]] = frozenset({"sigma2"})

    presliding: ClassVar[bool] = True
    has_elements: ClassVar[bool] = True
    replaces_small_elements: ClassVar[bool] = True

    @classmethod
    def start_from_scales(
        cls, reader: Any, *, elements: int, smoothing: Any, without_small_elements: bool = False
    ) -> list[GMS]:
        """The elements of a Maxwell-slip model of the records (stiffnesses and force shares), the sliding law screened
        on a small grid; without elements to regress on, `elements` equal shares of the static force. With
        `without_small_elements`, also the start whose small elements are replaced, where that changes it."""
        s = reader.scales
        stribeck = ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)
        found = reader.maxwell_elements(elements, viscous=True)
        if found is not None:
            thresholds, k, offset, Fv = found
            sets = [(thresholds, k)]
            if without_small_elements:
                replaced = reader.replace_small_elements(thresholds, k)
                sets += [] if np.array_equal(replaced[1], k) else [replaced]
            return [
                reader.screen_gms_sliding_law(
                    cls(
                        stribeck,
                        k=k_i,
                        alpha=t_i * k_i / np.sum(t_i * k_i),
                        C=10.0 * s.Fs,
                        sigma2=Fv,
                        offset=offset,
                        smoothing=smoothing,
                    )
                )
                for t_i, k_i in sets
            ]
        shares = np.arange(elements, 0, -1, dtype=float)  # stiffer elements first
        return [
            cls(
                stribeck,
                k=s.stiffness * shares / shares.sum(),
                alpha=np.full(elements, 1.0 / elements),
                C=10.0 * s.Fs,
                sigma2=s.Fv,
                offset=s.offset,
                smoothing=smoothing,
            )
        ]

    def __init__(
        self,
        stribeck: AbstractStribeck,
        k: ParamLike,
        alpha: ParamLike,
        C: ParamLike,
        sigma2: ParamLike = 0.0,
        *,
        offset: ParamLike = 0.0,
        smoothing: AbstractSmoothing = Exact(),
    ):
        dtype = model_dtype(*jax.tree_util.tree_leaves(stribeck), k, alpha, C, sigma2, offset)
        checked_stribeck(stribeck, "GMS")
        k = as_float_array(k)
        if k.ndim != 1:
            raise ValueError(f"GMS: `k` must have shape (N,), one stiffness per element, got shape {k.shape}.")
        if k.shape[0] == 0:
            raise ValueError("GMS: `k` and `alpha` are empty; give at least one element (N >= 1).")
        self.stribeck = stribeck
        self.k = positive(k, "k", dtype)
        alpha = as_float_array(alpha).astype(k.dtype)
        if alpha.shape != k.shape:
            raise ValueError(f"GMS: `alpha` must have the shape of `k` {k.shape}, got {alpha.shape}.")
        self.alpha = Simplex(alpha, name="alpha", dtype=dtype)
        self.C = positive(C, "C", dtype, scalar=True)
        sigma2 = real(sigma2, "sigma2", dtype, scalar=True)
        if is_concrete(unwrap(sigma2)) and bool(np.any(np.asarray(unwrap(sigma2)) < 0)):
            raise ValueError(f"GMS: `sigma2` must be >= 0 (N·s/m), got {sigma2!r}.")
        self.sigma2 = sigma2
        self.offset = real(offset, "offset", dtype, scalar=True)
        self.smoothing = smoothing

    def parameter_ranges(self) -> dict[str, float]:
        return {"offset": float(np.max(np.abs(np.asarray(unwrap(self.stribeck).Fc))))}  # N

    @property
    def num_elements(self) -> int:
        return int(self.k.raw.shape[0]) if hasattr(self.k, "raw") else int(jnp.shape(self.k)[0])

    def breakaway_displacement(self) -> float:
        """`max_i alpha_i s(0) / k_i` [m]: the weakest element's breakaway."""
        p = unwrap(self)
        return float(jnp.max(p.alpha * p.stribeck(0.0) / p.k))

    def breakaway_force(self) -> float:
        """`s(0)` [N]: the Stribeck curve at standstill."""
        return float(unwrap(self).stribeck(0.0))

    def slipping(self, state: GMSState, new_state: GMSState, sample: MotionSample) -> Array:
        """Each element's slip indicator after the step."""
        return new_state.slipping

    def smoothing_scale(self) -> float:
        return 1e-11  # metres: GMS smooths its elements' stick / slip switch in displacement

    def implausible(self, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
        p = unwrap(self)
        notes = AbstractFrictionModel.implausible(p, record_excursion, bounds=bounds) + p.held_at_zero(
            ("sigma2",), bounds
        )
        alpha = np.asarray(p.alpha)
        idle = int(np.sum(alpha < NEGLIGIBLE))
        if idle:
            notes.append(f"{idle} of {alpha.size} GMS elements carry < {NEGLIGIBLE:g} of the force")
        return notes

    def init_state(self) -> GMSState:
        k = unwrap(self.k)
        zeros = jnp.zeros_like(k)
        return GMSState(F=zeros, slipping=zeros)

    def step(self, state: GMSState, sample: MotionSample) -> tuple[GMSState, Array]:
        p = unwrap(self)
        sm = p.smoothing
        # every per-step scalar is broadcast to the elements first: XLA:CPU then builds the step from a few
        # element-wise kernels instead of scalar kernels feeding vector ones (measured ~5x fewer ns per step)
        dx = jnp.broadcast_to(sample.dx, jnp.shape(state.F))
        direction = sm.sign(dx)
        # continue slipping while the motion keeps the direction of the element force; a rest (dx = 0,
        # direction 0) ends the slip in both modes (direction**2 is 0 there)
        keeps_slipping = state.slipping * sm.step(direction * state.F / p.k) * direction**2
        F_trial = state.F + p.k * dx
        if p.stribeck.asymmetric:
            # separate branches: slip towards +alpha s+ (dx > 0) or -alpha s- (dx < 0); stick inside
            # [-alpha s-, alpha s+], written as a clip of half-width `width` around `centre`
            up = sm.step(dx)
            s_plus, s_minus = p.stribeck.branches(dx / sample.dt)
            s = up * s_plus + (1.0 - up) * s_minus
            centre, width = 0.5 * p.alpha * (s_plus - s_minus), 0.5 * p.alpha * (s_plus + s_minus)
            target = p.alpha * (up * s_plus - (1.0 - up) * s_minus)
            starts_slipping = (1.0 - keeps_slipping) * sm.step((sm.abs(F_trial - centre) - width) / p.k)
            F_stick = sm.clip(F_trial - centre, width) + centre
        else:
            s = p.stribeck(dx / sample.dt)  # at the velocity held over the step, as the slip law
            bound = p.alpha * s
            target = bound * direction
            starts_slipping = (1.0 - keeps_slipping) * sm.step((sm.abs(F_trial) - bound) / p.k)
            F_stick = sm.clip(F_trial, bound)
        # exact relaxation towards alpha s sgn(dx) at rate C / s: relax(F, C / s, C alpha sgn, dt) written as
        # F e + alpha s sgn (1 - e), e = exp(-C dt / s), which needs no small-rate branch (C / s > 0)
        decay = jnp.exp(-p.C * sample.dt / s)
        F_slip = state.F * decay + target * (1.0 - decay)
        F = keeps_slipping * F_slip + (1.0 - keeps_slipping) * F_stick
        slipping = keeps_slipping + starts_slipping
        force = jnp.sum(F) + p.sigma2 * sample.v + p.offset
        return GMSState(F=F, slipping=slipping), force
