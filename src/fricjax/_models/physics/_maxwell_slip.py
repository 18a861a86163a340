"""Maxwell-slip models: M elasto-slide elements with the LR / NLR / DLR / DNLRX force maps.

Sources: parlitz2004 §II-A eqs. 3-5 (the element update) and §III-A-C (LR, DLR, NLR); worden2007 §4.3
eqs. 13-16 (the clip form of the update, NLR and DNLRX).
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import (
    Fixed,
    Parameter,
    ParameterVector,
    ParamLike,
    as_float_array,
    model_dtype,
    positive,
    real,
    unwrap,
)
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact
from .._base import NEGLIGIBLE, AbstractFrictionModel
from .._state_maps import AffineMaps, ClampMaps, held, shaped_like


class MaxwellSlipState(eqx.Module):
    """Maxwell-slip state: spring deflections `delta` [m] (M,), the last `n` normalised deflections (n, M)
    (newest first) and the last `nx` displacements [m] (nx,) (newest first) for the FIR force maps."""

    delta: Float[Array, "M"]
    dbar_history: Float[Array, "n M"]
    x_history: Float[Array, " nx"]


class AbstractForceMap(eqx.Module):
    """Maps the normalised deflections `dbar(t)` (and their / the displacement's history) to a force [N]."""

    offset: Parameter

    @property
    def dbar_lags(self) -> int:
        """How many past normalised-deflection vectors the map reads."""
        return 0

    @property
    def x_lags(self) -> int:
        """How many past displacements the map reads."""
        return 0

    @abc.abstractmethod
    def __call__(self, thresholds: Array, dbar: Array, dbar_history: Array, x: Array, x_history: Array) -> Array:
        """Force [N] at this sample."""


class SpringForces(AbstractForceMap):
    """LR / NLR map (parlitz2004 eqs. 13, 15 and 29; worden2007 eq. 14): `F = sum_i k_i Delta_i dbar_i + b`.

    **Arguments:** `k` element stiffnesses [N/m] (> 0), shape (M,); `offset` b [N].
    """

    k: ParameterVector

    def __init__(self, k: ParamLike, offset: ParamLike = 0.0):
        dtype = model_dtype(k, offset)
        self.k = positive(k, "k", dtype)
        self.offset = real(offset, "offset", dtype)

    def __call__(self, thresholds: Array, dbar: Array, dbar_history: Array, x: Array, x_history: Array) -> Array:
        p = unwrap(self)
        return jnp.sum(p.k * (dbar * thresholds)) + p.offset  # k_i delta_i: the deflection the step stores


class FIRForces(AbstractForceMap):
    """DLR / DNLRX map: an M-dimensional FIR band on the normalised deflections, optionally plus an FIR on the
    displacement (parlitz2004 eq. 14, DLR; worden2007 eq. 15, DNLRX):

    `F = sum_{r=0}^{nx} c_r x(t-r) + sum_{r=0}^{n} theta_r . dbar(t-r) + b`.

    **Arguments:** `theta` FIR band [N], shape (n+1, M); `c` displacement FIR [N/m], shape (nx+1,), or `None`
    (DLR); `offset` b [N].
    """

    theta: Float[Array, "n1 M"]
    c: Float[Array, " nx1"] | None

    units: ClassVar[dict[str, str]] = {"theta": "N", "c": "N/m", "offset": "N"}

    def __init__(self, theta: ParamLike, c: ParamLike | None = None, offset: ParamLike = 0.0):
        dtype = model_dtype(theta, c, offset)
        theta = real(theta, "theta", dtype)
        if theta.ndim != 2:
            raise ValueError(f"`theta` must have shape (n + 1, M) (FIR order n, M elements), got {theta.shape}.")
        self.theta = theta
        if c is not None:
            c = real(c, "c", dtype)
            if c.ndim != 1:
                raise ValueError(f"`c` must have shape (nx + 1,) (displacement FIR of order nx), got {c.shape}.")
        self.c = c
        self.offset = real(offset, "offset", dtype)

    @property
    def dbar_lags(self) -> int:
        return int(self.theta.shape[0]) - 1

    @property
    def x_lags(self) -> int:
        return 0 if self.c is None else int(self.c.shape[0]) - 1

    def __call__(self, thresholds: Array, dbar: Array, dbar_history: Array, x: Array, x_history: Array) -> Array:
        p = unwrap(self)
        force = jnp.sum(p.theta[0] * dbar) + jnp.sum(p.theta[1:] * dbar_history) + p.offset
        if p.c is not None:
            force = force + p.c[0] * x + jnp.sum(p.c[1:] * x_history)
        return force


class MaxwellSlip(AbstractFrictionModel):
    """Maxwell-slip model: M massless elasto-slide elements in parallel, driven by the displacement x.

    Element update (worden2007 eq. 13, equivalent to parlitz2004 eqs. 4-5):
    `delta_i(t+1) = clip(delta_i(t) + x(t+1) - x(t), -Delta_i, Delta_i)`, `dbar_i = delta_i / Delta_i`;
    the force is then given by the force map (`SpringForces`: LR / NLR, `FIRForces`: DLR / DNLRX).
    Use the constructors `MaxwellSlip.lr`, `.nlr`, `.dlr`, `.dnlrx` for the four model classes.

    Smooth mode (`Smooth(eps)`, eps dimensionless): the clip is a smooth clip of `delta_i / Delta_i` to
    [-1, 1] with width eps.

    **Arguments:** `thresholds` Delta_i [m] (> 0), shape (M,) (wrap in `Fixed` to preassign them, as LR/DLR
    do); `force_map`; `smoothing`.

    ```python
    >>> import fricjax as fj
    >>> model = fj.MaxwellSlip.nlr(k=[1e5, 5e4], thresholds=[1e-6, 3e-6])
    >>> model.init_state().delta.shape
    (2,)
    ```
    """

    thresholds: ParameterVector
    force_map: AbstractForceMap
    smoothing: AbstractSmoothing

    requires: ClassVar[frozenset[str]] = frozenset({"x"})

    presliding: ClassVar[bool] = True
    has_elements: ClassVar[bool] = True

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[MaxwellSlip]:
        """An NLR model: the elements of the records' Maxwell-slip regression; without motion to regress on,
        `elements` thresholds up to the breakaway sharing the static force."""
        s = reader.scales
        found = reader.maxwell_elements(elements)
        if found is None:
            thresholds = s.thresholds(elements)
            return [
                cls.nlr(k=s.Fs / elements / thresholds, thresholds=thresholds, offset=s.offset, smoothing=smoothing)
            ]
        thresholds, k, offset, _ = found
        return [cls.nlr(k=k, thresholds=thresholds, offset=offset, smoothing=smoothing)]

    def __init__(self, thresholds: Any, force_map: AbstractForceMap, *, smoothing: AbstractSmoothing = Exact()):
        dtype = model_dtype(thresholds.value if isinstance(thresholds, Fixed) else thresholds)
        if not isinstance(force_map, AbstractForceMap):
            raise TypeError(
                f"MaxwellSlip: `force_map` must be SpringForces or FIRForces, got {type(force_map).__name__}."
            )
        if isinstance(thresholds, Fixed):
            self.thresholds = Fixed(positive(thresholds.value, "thresholds", dtype).unwrap())
        else:
            self.thresholds = positive(thresholds, "thresholds", dtype)
        m = self.num_elements
        if jnp.ndim(unwrap(self.thresholds)) != 1:
            raise ValueError(
                f"MaxwellSlip: `thresholds` must have shape (M,), got {jnp.shape(unwrap(self.thresholds))}."
            )
        if m == 0:
            raise ValueError("MaxwellSlip: `thresholds` is empty; give at least one element (M >= 1).")
        if isinstance(force_map, SpringForces) and jnp.shape(unwrap(force_map.k)) != (m,):
            raise ValueError(
                f"MaxwellSlip: `k` must have shape ({m},) like `thresholds`, got {jnp.shape(unwrap(force_map.k))}."
            )
        if isinstance(force_map, FIRForces) and force_map.theta.shape[1] != m:
            raise ValueError(f"MaxwellSlip: `theta` must have shape (n + 1, {m}), got {force_map.theta.shape}.")
        self.force_map = force_map
        self.smoothing = smoothing

    def parameter_ranges(self) -> dict[str, float]:
        if isinstance(self.force_map, SpringForces):  # the sliding force: sum of k_i * Delta_i [N]
            p = unwrap(self)
            level = float(np.sum(np.asarray(p.force_map.k) * np.asarray(p.thresholds)))
            return {"force_map.offset": level}
        return {}

    def batch_minor(self) -> bool:
        """Under vmap, the batch-minor free run for the maps without history (LR / NLR: 1024 NLR(7) models,
        two devices, 4.8 -> 3.1 ns per trajectory-step, benchmarks/vmap_layout.py); the FIR maps' history shift
        moves the batch axis inside the step (slower in a probe), so they keep vmap's own batching."""
        return self.force_map.dbar_lags == 0 and self.force_map.x_lags == 0

    @property
    def num_elements(self) -> int:
        return int(jnp.shape(unwrap(self.thresholds))[-1])

    # --- the four model classes of parlitz2004 / worden2007 ---

    @classmethod
    def lr(cls, k: ParamLike, max_deflection: ParamLike, offset: ParamLike = 0.0, **kwargs: Any) -> MaxwellSlip:
        """LR(M): thresholds preassigned equally spaced, `Delta_i = i * max_deflection / M`; fit `k` (linear)."""
        return cls(Fixed(equally_spaced(np.shape(k)[-1], max_deflection)), SpringForces(k, offset), **kwargs)

    @classmethod
    def nlr(cls, k: ParamLike, thresholds: ParamLike, offset: ParamLike = 0.0, **kwargs: Any) -> MaxwellSlip:
        """NLR(M): stiffnesses and thresholds both estimated."""
        return cls(thresholds, SpringForces(k, offset), **kwargs)

    @classmethod
    def dlr(cls, theta: ParamLike, max_deflection: ParamLike, offset: ParamLike = 0.0, **kwargs: Any) -> MaxwellSlip:
        """DLR(M, n): preassigned equally spaced thresholds, FIR band `theta` (n+1, M) on the deflections."""
        m = np.shape(theta)[-1]
        return cls(Fixed(equally_spaced(m, max_deflection)), FIRForces(theta, None, offset), **kwargs)

    @classmethod
    def dnlrx(
        cls, thresholds: ParamLike, theta: ParamLike, c: ParamLike, offset: ParamLike = 0.0, **kwargs: Any
    ) -> MaxwellSlip:
        """DNLRX(M, n, nx): estimated thresholds, FIR band `theta` (n+1, M), displacement FIR `c` (nx+1,)."""
        return cls(thresholds, FIRForces(theta, c, offset), **kwargs)

    def parallel_maps(self, samples: MotionSample) -> Any:
        """Exact LR / NLR elements: `delta_i -> clip(delta_i + dx, -Delta_i, Delta_i)`, a clamp map (the
        time-parallel free run). None for the smooth clip (not closed under composition) and the FIR maps."""
        if not isinstance(self.smoothing, Exact) or self.force_map.dbar_lags or self.force_map.x_lags:
            return None
        thresholds = unwrap(self.thresholds)
        length = samples.dx.shape[0]
        state = self.init_state()
        delta = ClampMaps(  # the shift as a full (T, M) array: faster than one broadcast column (H100, 1e6 samples,
            # NLR(7) 4.2 against 6.6 ms: benchmarks/README.md)
            jnp.broadcast_to(jnp.asarray(samples.dx, thresholds.dtype)[:, None], (length, *thresholds.shape)),
            held(-thresholds, length),
            held(thresholds, length),
        )
        histories = [  # empty for LR / NLR
            AffineMaps(held(jnp.ones_like(s), length), held(s, length)) for s in (state.dbar_history, state.x_history)
        ]
        return shaped_like(state, [delta, *histories])

    def breakaway_displacement(self) -> float:
        """`max_i Delta_i` [m]: the largest threshold."""
        return float(jnp.max(unwrap(self).thresholds))

    def breakaway_force(self) -> float | None:
        """`sum_i k_i Delta_i` [N] for the spring (LR / NLR) force map; None for the FIR maps."""
        p = unwrap(self)
        if not isinstance(p.force_map, SpringForces):
            return None
        return float(jnp.sum(p.force_map.k * p.thresholds))

    def force_offset(self) -> float:
        return float(unwrap(self).force_map.offset)

    def slipping(self, state: MaxwellSlipState, new_state: MaxwellSlipState, sample: MotionSample) -> Array:
        """Where the element's clip is active (its deflection would pass its threshold)."""
        slipping = jnp.abs(state.delta + sample.dx) > unwrap(self.thresholds)
        return slipping.astype(sample.dx.dtype)

    def smoothing_scale(self) -> float:
        return 1e-3  # a fraction of a threshold: Maxwell-slip smooths its clips relative to each threshold

    def implausible(self, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
        p = unwrap(self)
        notes = AbstractFrictionModel.implausible(p, record_excursion, bounds=bounds)
        if record_excursion is not None:
            stuck = int(np.sum(np.asarray(p.thresholds) >= record_excursion))
            if stuck == p.num_elements:
                notes.append("every Maxwell-slip element stays stuck on this record (a linear spring)")
            elif stuck:
                notes.append(f"{stuck} of {p.num_elements} Maxwell-slip elements never slip on this record")
        if isinstance(p.force_map, SpringForces):
            k = np.asarray(p.force_map.k) * np.asarray(p.thresholds)
            if k.sum() > 0 and np.sum(k < NEGLIGIBLE * k.sum()):
                notes.append(f"{int(np.sum(k < NEGLIGIBLE * k.sum()))} Maxwell-slip elements carry almost no force")
        return notes

    def init_state(self) -> MaxwellSlipState:
        thresholds = unwrap(self.thresholds)
        m = thresholds.shape[-1]
        return MaxwellSlipState(
            delta=jnp.zeros_like(thresholds),
            dbar_history=jnp.zeros((self.force_map.dbar_lags, m), thresholds.dtype),
            x_history=jnp.zeros((self.force_map.x_lags,), thresholds.dtype),
        )

    def step(self, state: MaxwellSlipState, sample: MotionSample) -> tuple[MaxwellSlipState, Array]:
        p = unwrap(self)
        thresholds = p.thresholds
        dbar = p.smoothing.clip((state.delta + sample.dx) / thresholds, 1.0)
        force = p.force_map(thresholds, dbar, state.dbar_history, sample.x, state.x_history)
        new_state = MaxwellSlipState(
            delta=dbar * thresholds,
            dbar_history=jnp.concatenate([dbar[None], state.dbar_history[:-1]], axis=0)[: state.dbar_history.shape[0]],
            x_history=jnp.concatenate([sample.x[None], state.x_history[:-1]])[: state.x_history.shape[0]],
        )
        return new_state, force


def equally_spaced(m: int, max_deflection: ParamLike) -> Array:
    """Preassigned LR/DLR thresholds: `Delta_i = i * max_deflection / m`, i = 1..m (parlitz2004 §III-A)."""
    max_deflection = as_float_array(max_deflection)
    return max_deflection * jnp.arange(1, m + 1, dtype=max_deflection.dtype) / m
