"""The recurrent dynamical network of parlitz2004 §III-G (eqs. 26-28) and worden2007 §5.3: leaky elements with
sparse coupling, driven by the displacement and delayed copies of it, read out linearly."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import Fixed, FixedScalar, as_float_array, unwrap
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact
from ..._validation import nonnegative_int, positive_int
from .._base import AbstractFrictionModel
from ._regressors import fixed_array, record_statistics


class RecurrentNetworkState(eqx.Module):
    """`elements`: the element states `x_i` (shape `(N,)`, dimensionless, in [-1, 1]); `history`: the last
    `max(delays)` normalised input vectors, newest first (shape `(D, S)`)."""

    elements: Float[Array, " N"]
    history: Float[Array, "D S"]


class RecurrentNetwork(AbstractFrictionModel):
    """A dynamical network of `N` leaky elements (parlitz2004 eqs. 26-28):

    `x_i(t) = alpha_i x_i(t-1) + (1 - |alpha_i|) sigma(I_i(t))`,
    `I_i(t) = w_i0 + sum_{j != i} w_ij x_j(t-1) + sum_m v_im u_m(t)`,
    `y(t) = sum_i theta_i x_i(t) + theta_0` (in normalised force units),

    `sigma` the piecewise-linear sigmoid `clip(z, -1, 1)` (eq. 28): exact with `Exact()` (evaluation), smooth with
    `Smooth(eps)` (training). The inputs `u_m` are the normalised signals (default the displacement) and their
    copies delayed by `delays` samples (worden2007 §5.4.3: delays of 0, 80 and 160 samples, 45 elements, about
    11 % connectivity). `alpha_i = tanh(alpha_raw_i)` stays in (-1, 1). The coupling `w` is multiplied by a fixed
    0/1 `connectivity` mask (zero diagonal); `unit_mask` switches elements off for sweeps over sizes.

    **Arguments:** `alpha_raw` `(N,)`, `w` `(N, N)`, `w0` `(N,)`, `v` `(N, M)` with `M = len(signals) *
    len(delays)`, `theta` `(N,)`, `theta0`; `connectivity` `(N, N)`; `signals` (names of `fj.MotionSample`
    fields); `delays` (samples, >= 0); `input_mean`, `input_scale` (per signal), `output_mean`, `output_scale`
    [N]; `smoothing`; `unit_mask`. Build a random, echo-state style network with `RecurrentNetwork.init(data, N,
    key=...)`; the readout `(theta, theta0)` is linear: `fj.fit(..., separable=("theta", "theta0"))`.
    """

    units: ClassVar[dict[str, str] | None] = {}  # network weights: no units

    alpha_raw: Array
    w: Array
    w0: Array
    v: Array
    theta: Array
    theta0: Array
    connectivity: Fixed[Float[Array, "N N"]]
    unit_mask: Fixed[Float[Array, " N"]]
    input_mean: Fixed[Float[Array, " S"]]
    input_scale: Fixed[Float[Array, " S"]]
    output_mean: FixedScalar
    output_scale: FixedScalar
    smoothing: AbstractSmoothing
    signals: tuple[str, ...] = eqx.field(static=True)
    delays: tuple[int, ...] = eqx.field(static=True)

    def __init__(
        self,
        alpha_raw: Any,
        w: Any,
        w0: Any,
        v: Any,
        theta: Any,
        theta0: Any = 0.0,
        *,
        connectivity: Any = None,
        signals: Sequence[str] = ("x",),
        delays: Sequence[int] = (0, 80, 160),
        input_mean: Any = None,
        input_scale: Any = None,
        output_mean: Any = 0.0,
        output_scale: Any = 1.0,
        smoothing: AbstractSmoothing | None = None,
        unit_mask: Any = None,
    ):
        self.signals = tuple(signals)
        self.delays = tuple(int(d) for d in delays)
        if not self.signals or any(s not in ("x", "v", "a", "dx") for s in self.signals):
            raise ValueError(f"RecurrentNetwork: `signals` must name 'x', 'v', 'a' or 'dx', got {signals!r}.")
        if not self.delays or min(self.delays) < 0:
            raise ValueError(f"RecurrentNetwork: `delays` must be sample counts >= 0, got {delays!r}.")
        self.alpha_raw, self.w, self.w0, self.v = (as_float_array(t) for t in (alpha_raw, w, w0, v))
        self.theta, self.theta0 = as_float_array(theta), as_float_array(theta0)
        n = self.alpha_raw.shape[0] if self.alpha_raw.ndim == 1 else -1
        m = len(self.signals) * len(self.delays)
        shapes = {"w": self.w.shape, "w0": self.w0.shape, "v": self.v.shape, "theta": self.theta.shape}
        expected = {"w": (n, n), "w0": (n,), "v": (n, m), "theta": (n,)}
        if shapes != expected or self.theta0.shape != ():
            raise ValueError(
                f"RecurrentNetwork: shapes {shapes} do not match {expected} ({n} elements, {m} inputs); use "
                "RecurrentNetwork.init(data, elements, key=...)."
            )
        s = len(self.signals)
        conn = np.ones((n, n)) - np.eye(n) if connectivity is None else connectivity
        self.connectivity = _fixed(conn, (n, n), "connectivity")
        self.unit_mask = _fixed(np.ones(n) if unit_mask is None else unit_mask, (n,), "unit_mask")
        self.input_mean = _fixed(np.zeros(s) if input_mean is None else input_mean, (s,), "input_mean")
        self.input_scale = _fixed(np.ones(s) if input_scale is None else input_scale, (s,), "input_scale")
        self.output_mean = _fixed(output_mean, (), "output_mean")
        self.output_scale = _fixed(output_scale, (), "output_scale")
        self.smoothing = Exact() if smoothing is None else smoothing

    @classmethod
    def init(
        cls,
        data: Any,
        elements: int = 45,
        *,
        key: Array,
        connectivity: float = 0.11,
        spectral_radius: float = 0.8,
        input_weight: float = 1.0,
        signals: Sequence[str] = ("x",),
        delays: Sequence[int] = (0, 80, 160),
        smoothing: AbstractSmoothing | None = None,
    ) -> RecurrentNetwork:
        """A random network normalised by the training record `data` (echo-state style, Jaeger 2001):
        `alpha ~ U(0.3, 0.95)` (long and short memories), a sparse coupling with the given fraction of nonzero
        `w_ij` scaled to `spectral_radius`, biases `N(0, 0.2)`, input weights `N(0, input_weight)`, readout 0.
        Solve the readout by least squares before training: `fj.fit(model, data, train=("theta", "theta0"),
        separable=("theta", "theta0"))`."""
        elements = positive_int(elements, "elements", "RecurrentNetwork.init")
        if not 0 < connectivity <= 1:
            raise ValueError(f"RecurrentNetwork.init: `connectivity` must be in (0, 1], got {connectivity!r}.")
        n, m = int(elements), len(tuple(signals)) * len(tuple(delays))
        keys = jax.random.split(key, 5)
        mask = np.asarray(jax.random.bernoulli(keys[0], connectivity, (n, n))) & ~np.eye(n, dtype=bool)
        w = np.asarray(jax.random.normal(keys[1], (n, n))) * mask
        radius = float(np.max(np.abs(np.linalg.eigvals(w)))) if mask.any() else 0.0
        if radius > 0:
            w *= spectral_radius / radius
        alpha = np.asarray(jax.random.uniform(keys[2], (n,), minval=0.3, maxval=0.95))
        means, scales, force_mean, force_scale = record_statistics(data, signals)
        return cls(
            np.arctanh(alpha),
            w,
            0.2 * np.asarray(jax.random.normal(keys[3], (n,))),
            input_weight * np.asarray(jax.random.normal(keys[4], (n, m))),
            np.zeros(n),
            0.0,
            connectivity=mask.astype(float),
            signals=signals,
            delays=delays,
            input_mean=means,
            input_scale=scales,
            output_mean=force_mean,
            output_scale=force_scale,
            smoothing=smoothing,
        )

    @classmethod
    def hysteretic(
        cls,
        data: Any,
        thresholds: Any,
        static: int = 8,
        *,
        key: Array,
        static_gain: float = 2.0,
        smoothing: AbstractSmoothing | None = None,
    ) -> RecurrentNetwork:
        """A dynamical network of play elements and static velocity elements, normalised by the record `data`.

        parlitz2004 (§III-G) notes that the elements of a dynamical network may be any stable dynamical system.
        With `alpha_i = 0` and a self-connection `w_ii = 1` inside the saturation (eq. 27 sums over `j != i`; the
        constructor accepts any `connectivity`), element i driven by the displacement step is a play (backlash)
        operator, `x_i(t) = clip(x_i(t-1) + dx(t) / Delta_i, -1, 1)`: a Maxwell-slip element of threshold
        `Delta_i` [m], the rate-independent, non-local memory of pre-sliding hysteresis. The `static` further
        elements are uncoupled, `x_i = clip(v_i v(t) / std(v) + w_i0)`: a basis for the velocity-dependent
        (Stribeck, viscous) force. Inputs: `("dx", "v")`, no delays. Train the readout by least squares
        (`separable=("theta", "theta0")`), then, optionally, every weight by output error.

        **Arguments:** `data` (the training record); `thresholds` [m] (one play element each, e.g. log-spaced over
        0.03-3 x the breakaway displacement); `static` elements; `key`; `static_gain` (spread of their input
        weights); `smoothing`.
        """
        thresholds = np.asarray(thresholds, dtype=float).reshape(-1)
        if thresholds.size == 0 or not np.all(thresholds > 0):
            raise ValueError(f"RecurrentNetwork.hysteretic: `thresholds` must be positive [m], got {thresholds!r}.")
        static = nonnegative_int(static, "static", "RecurrentNetwork.hysteretic")
        _, (dx_scale, v_scale), force_mean, force_scale = record_statistics(data, ("dx", "v"))
        k, n = thresholds.size, thresholds.size + int(static)
        connectivity = np.zeros((n, n))
        connectivity[np.arange(k), np.arange(k)] = 1.0
        k1, k2 = jax.random.split(key)
        v = np.zeros((n, 2))
        v[:k, 0] = dx_scale / thresholds  # normalised dx -> dx / Delta_i
        v[k:, 1] = static_gain * np.asarray(jax.random.normal(k1, (int(static),)))
        w0 = np.concatenate([np.zeros(k), 0.5 * np.asarray(jax.random.normal(k2, (int(static),)))])
        return cls(
            np.zeros(n),
            connectivity.copy(),
            w0,
            v,
            np.zeros(n),
            0.0,
            connectivity=connectivity,
            signals=("dx", "v"),
            delays=(0,),
            input_mean=np.zeros(2),
            input_scale=np.array([dx_scale, v_scale]),
            output_mean=force_mean,
            output_scale=force_scale,
            smoothing=smoothing,
        )

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return frozenset("x" if s == "dx" else s for s in self.signals)

    @property
    def alpha(self) -> Array:
        """The element memories `alpha_i` in (-1, 1)."""
        return jnp.tanh(self.alpha_raw)

    def init_state(self) -> RecurrentNetworkState:
        p = unwrap(self)
        dtype = jnp.result_type(self.alpha_raw)
        rest = jnp.broadcast_to(-p.input_mean / p.input_scale, (max(self.delays), len(self.signals)))
        return RecurrentNetworkState(jnp.zeros(self.alpha_raw.shape, dtype), jnp.asarray(rest, dtype))

    def step(self, state: RecurrentNetworkState, sample: MotionSample) -> tuple[RecurrentNetworkState, Array]:
        p = unwrap(self)
        u = jnp.stack([jnp.asarray(getattr(sample, s)) for s in self.signals])
        u = ((u - p.input_mean) / p.input_scale).astype(state.history.dtype)
        window = jnp.concatenate([u[None], state.history], axis=0)  # window[d] = u(t - d)
        inputs = window[jnp.asarray(self.delays)].T.reshape(-1)  # signal-major: u_s(t - d) for s, for d
        alpha = jnp.tanh(p.alpha_raw)
        drive = p.w0 + (p.w * p.connectivity) @ state.elements + p.v @ inputs
        elements = (alpha * state.elements + (1.0 - jnp.abs(alpha)) * p.smoothing.clip(drive, 1.0)) * p.unit_mask
        y = p.output_mean + p.output_scale * (jnp.dot(p.theta, elements) + p.theta0)
        history = window[: max(self.delays)]
        return RecurrentNetworkState(elements, history), y


def _fixed(value: Any, shape: tuple[int, ...], name: str) -> Fixed:
    return fixed_array(value, shape, name, "RecurrentNetwork")
