"""NARX regressors: normalised input signals and their lags, and the model's own lagged outputs.

A NARX model (worden2007 §5-6, parlitz2004 §IV) predicts `y_k = f(phi_k)` from the regressor vector

`phi_k = [u_k, u_{k-1}, ..., u_{k-n_u}, y_{k-1}, ..., y_{k-n_y}]`

where `u` holds the input signals (displacement, velocity, acceleration: any fields of `fj.MotionSample`) and
`y` the model's past outputs (its predictions in a free run, the measurements under teacher forcing). Each
signal is normalised by a fixed mean and scale read off the training record, so that one set of network
weights suits records in metres and newtons alike.

Optionally, the regressors include a bank of play operators of the displacement (`plays=` thresholds [m]):
`p_i(k) = clip(p_i(k-1) + dx_k / Delta_i, -1, 1)`, the rate-independent memory elements of Maxwell-slip and
Prandtl-Ishlinskii hysteresis models (parlitz2004 §III-B: one element per threshold). A NARX with a few lags
cannot hold the state of a hysteretic system with non-local memory (nested loops after each reversal); the
play states carry it, so the network becomes a static map of the play states and the current inputs. This is
an extension of the papers' NARX networks (their memory was the lags alone), not part of them. The bank of play
operators alone is the model `PlayOperators`: `fj.simulate(regressors.play_operators, motion)` gives their states
along a record, which the teacher-forced regressor rows (`NARXRegressors.teacher_forced`) take as an argument
(a recursion over time runs in `fj.simulate` only; this module builds the rest of the rows by shifts).

Sweeps over orders compare models of one maximal shape: `input_mask` (one entry per input lag 0..n_u) and
`output_mask` (one per output lag 1..n_y) multiply the regressors, so a mask of zeros removes a lag without
changing a shape (and so without recompiling). The masks are fixed (never trained).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import Fixed, FixedScalar, as_float_array, unwrap
from ..._inputs import MotionSample
from ..._metrics import numpy_std
from ..._smoothing import AbstractSmoothing, Exact, is_concrete
from ..._validation import nonnegative_int
from .._base import AbstractFrictionModel
from .._state_maps import ClampMaps, held

SIGNALS = ("x", "v", "a", "dx")
"""The `MotionSample` signals a NARX may take as inputs: displacement [m], velocity [m/s], acceleration
[m/s^2], the step's displacement increment [m]."""


class NARXState(eqx.Module):
    """The regressor history: `inputs` the last `n_u` normalised input vectors (newest first, shape
    `(n_u, S)`), `outputs` the last `n_y` outputs [N] (newest first, shape `(n_y,)`), `plays` the play-operator
    states (dimensionless, in [-1, 1], shape `(K,)`; empty without plays)."""

    inputs: Float[Array, "L S"]
    outputs: Float[Array, " Y"]
    plays: Float[Array, " K"]


def advance_plays(plays: Array, dx: Any, thresholds: Array, smoothing: AbstractSmoothing) -> Array:
    """One step of a bank of play operators: `p_i(k) = clip(p_i(k-1) + dx_k / Delta_i, -1, 1)`, the clip exact or
    smoothed by `smoothing` (the one implementation, for `PlayOperators` and `NARXRegressors` alike)."""
    return smoothing.clip(plays + jnp.asarray(dx, plays.dtype) / thresholds, 1.0)


class PlayOperators(AbstractFrictionModel):
    """A bank of play operators of the displacement, `p_i(k) = clip(p_i(k-1) + dx_k / Delta_i, -1, 1)`: the
    rate-independent memory elements of Maxwell-slip and Prandtl-Ishlinskii hysteresis models (parlitz2004 §III-B,
    one element per threshold), here the play states that `fj.NARXRegressors(plays=)` adds to a NARX's regressors.

    Its output is not a force but the K play states after each sample (dimensionless, in [-1, 1]): run by
    `fj.simulate(operators, motion)`, shape `(T, K)`, from rest (all states 0). `NARXRegressors.play_operators` is
    the bank of a regressor map; the teacher-forced regressor rows (`NARXRegressors.teacher_forced`,
    `regressor_matrix` of the linear-in-parameters models, `fj.LocalModel.from_data`) take these states.

    **Arguments:**

    - `thresholds`: the K thresholds `Delta_i > 0` [m] (typically 0.03-3 times the breakaway displacement).
    - `smoothing`: the saturation, `Exact()` (default) or `Smooth(eps)` (`eps` dimensionless).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion(x=np.array([0.0, 1e-3, 3e-3, 2e-3]))
    >>> np.asarray(fj.simulate(fj.PlayOperators([2e-3]), motion))[:, 0].round(6).tolist()
    [0.0, 0.5, 1.0, 0.5]
    ```
    """

    thresholds: Fixed[Float[Array, " K"]]
    smoothing: AbstractSmoothing
    requires: ClassVar[frozenset[str]] = frozenset({"x"})

    def __init__(self, thresholds: Any, smoothing: AbstractSmoothing | None = None):
        raw = thresholds.value if isinstance(thresholds, Fixed) else thresholds
        self.thresholds = fixed_array(raw, (int(np.size(raw)),), "thresholds", "PlayOperators", True)
        self.smoothing = Exact() if smoothing is None else smoothing

    @property
    def num_plays(self) -> int:
        """The number K of play operators."""
        return int(np.shape(unwrap(self.thresholds))[0])

    def init_state(self) -> Array:
        thresholds = unwrap(self.thresholds)
        return jnp.zeros((self.num_plays,), thresholds.dtype)

    def parallel_maps(self, samples: MotionSample) -> ClampMaps | None:
        """Exact play operators: `p_i -> clip(p_i + dx / Delta_i, -1, 1)`, a clamp map (the time-parallel free
        run); None for the smooth clip."""
        if not isinstance(self.smoothing, Exact):
            return None
        thresholds = unwrap(self.thresholds)
        length = samples.dx.shape[0]
        return ClampMaps(
            jnp.asarray(samples.dx, thresholds.dtype)[:, None] / thresholds,
            held(-jnp.ones_like(thresholds), length),
            held(jnp.ones_like(thresholds), length),
        )

    def step(self, state: Array, sample: MotionSample) -> tuple[Array, Array]:
        state = advance_plays(state, sample.dx, unwrap(self.thresholds), self.smoothing)
        return state, state


class NARXRegressors(eqx.Module):
    """The regressor map of a NARX model: which signals, how many lags, their normalisation and masks.

    `phi_k = [((u_{k-i} - mean) / scale) * input_mask_i for i = 0..n_u,
    p_1(k), ..., p_K(k), ((y_{k-j} - output_mean) / output_scale) * output_mask_j for j = 1..n_y]`, of length
    `S (n_u + 1) + K + n_y` (`K` play operators, 0 by default).

    **Arguments:**

    - `signals`: the input signals, names of `fj.MotionSample` fields (`"x"`, `"v"`, `"a"`, `"dx"`).
    - `input_lags`: `n_u >= 0`, past samples of each input (0: the current sample only).
    - `output_lags`: `n_y >= 0`, past outputs fed back (0: a static map of the inputs, no feedback).
    - `input_mean`, `input_scale`: per signal, in its units (default 0 and 1); see `from_data`.
    - `output_mean`, `output_scale`: the force's [N] (default 0 and 1).
    - `input_mask`, `output_mask`: 0/1 per lag (default ones), for masked sweeps over orders.
    - `plays`: thresholds `Delta_i > 0` [m] of play operators on the displacement (default none).
    - `smoothing`: the play operators' saturation, `Exact()` (default, evaluation) or `Smooth(eps)` (training;
      `eps` dimensionless). Without plays the regressors are smooth and it has no effect.
    """

    signals: tuple[str, ...] = eqx.field(static=True)
    input_lags: int = eqx.field(static=True)
    output_lags: int = eqx.field(static=True)
    input_mean: Fixed[Float[Array, " S"]]
    input_scale: Fixed[Float[Array, " S"]]
    output_mean: FixedScalar
    output_scale: FixedScalar
    input_mask: Fixed[Float[Array, " L+1"]]
    output_mask: Fixed[Float[Array, " Y"]]
    plays: Fixed[Float[Array, " K"]]
    smoothing: AbstractSmoothing

    def __init__(
        self,
        signals: Sequence[str] = ("x", "v", "a"),
        input_lags: int = 0,
        output_lags: int = 4,
        *,
        input_mean: Any = None,
        input_scale: Any = None,
        output_mean: Any = 0.0,
        output_scale: Any = 1.0,
        input_mask: Any = None,
        output_mask: Any = None,
        plays: Any = None,
        smoothing: AbstractSmoothing | None = None,
    ):
        signals = tuple(signals)
        if not signals:
            raise ValueError("NARXRegressors: give at least one input signal, e.g. signals=('x', 'v', 'a').")
        unknown = [s for s in signals if s not in SIGNALS]
        if unknown:
            raise ValueError(f"NARXRegressors: unknown signals {unknown}; choose from {list(SIGNALS)}.")
        if len(set(signals)) != len(signals):
            raise ValueError(f"NARXRegressors: `signals` repeats a name: {signals}.")
        n = len(signals)
        self.signals = signals
        self.input_lags = nonnegative_int(input_lags, "input_lags", "NARXRegressors")
        self.output_lags = nonnegative_int(output_lags, "output_lags", "NARXRegressors")
        self.input_mean = _fixed(np.zeros(n) if input_mean is None else input_mean, (n,), "input_mean")
        self.input_scale = _fixed(np.ones(n) if input_scale is None else input_scale, (n,), "input_scale", True)
        self.output_mean = _fixed(output_mean, (), "output_mean")
        self.output_scale = _fixed(output_scale, (), "output_scale", True)
        mask_in = np.ones(self.input_lags + 1) if input_mask is None else input_mask
        mask_out = np.ones(self.output_lags) if output_mask is None else output_mask
        self.input_mask = _fixed(mask_in, (self.input_lags + 1,), "input_mask")
        self.output_mask = _fixed(mask_out, (self.output_lags,), "output_mask")
        thresholds = np.zeros(0) if plays is None else (plays.value if isinstance(plays, Fixed) else plays)
        self.plays = _fixed(thresholds, (int(np.size(thresholds)),), "plays", True)
        self.smoothing = Exact() if smoothing is None else smoothing

    @classmethod
    def from_data(
        cls,
        data: Any,
        signals: Sequence[str] = ("x", "v", "a"),
        input_lags: int = 0,
        output_lags: int = 4,
        *,
        plays: Any = None,
        smoothing: AbstractSmoothing | None = None,
    ) -> NARXRegressors:
        """Regressors normalised by a training record (`fj.FrictionData`): each signal by its mean and standard
        deviation, the force likewise; `plays` and `smoothing` as in the constructor."""
        cls(signals, input_lags, output_lags)  # the structure's checks first (signal names, lags)
        means, scales, force_mean, force_scale = record_statistics(data, signals)
        return cls(
            signals,
            input_lags,
            output_lags,
            input_mean=means,
            input_scale=scales,
            output_mean=force_mean,
            output_scale=force_scale,
            plays=plays,
            smoothing=smoothing,
        )

    @property
    def size(self) -> int:
        """The length of the regressor vector: `S (n_u + 1) + K + n_y`."""
        return len(self.signals) * (self.input_lags + 1) + self.num_plays + self.output_lags

    @property
    def num_plays(self) -> int:
        """The number K of play operators."""
        return int(np.shape(unwrap(self.plays))[0])

    @property
    def play_operators(self) -> PlayOperators:
        """The bank of play operators of these regressors (thresholds `plays`, this `smoothing`; empty without
        plays): `fj.simulate(regressors.play_operators, motion)` gives the play states `teacher_forced` takes."""
        return PlayOperators(self.plays, self.smoothing)

    @property
    def requires(self) -> frozenset[str]:
        return frozenset(s for s in self.signals if s in ("x", "v", "a")) | (
            frozenset({"x"}) if "dx" in self.signals or self.num_plays else frozenset()
        )

    def init_state(self, dtype: Any) -> NARXState:
        p = unwrap(self)
        # at rest: every input at 0 (normalised: -mean / scale), every past output 0
        rest = jnp.broadcast_to(-p.input_mean / p.input_scale, (self.input_lags, len(self.signals)))
        return NARXState(
            jnp.asarray(rest, dtype), jnp.zeros((self.output_lags,), dtype), jnp.zeros((self.num_plays,), dtype)
        )

    def __call__(self, state: NARXState, sample: MotionSample) -> tuple[Array, NARXState]:
        """`(phi_k, partial)`: the regressor vector and the history with the inputs of sample k pushed (window
        `[u_k, ..., u_{k-n_u}]`) and the play operators advanced; `advance` then pushes the output."""
        p = unwrap(self)
        u = jnp.stack([jnp.asarray(getattr(sample, s)) for s in self.signals])
        u = (u - p.input_mean) / p.input_scale
        window = jnp.concatenate([u[None].astype(state.inputs.dtype), state.inputs], axis=0)
        plays = state.plays
        if self.num_plays:  # a play operator per threshold, driven by the displacement step
            plays = advance_plays(plays, sample.dx, p.plays, self.smoothing)
        past = (state.outputs - p.output_mean) / p.output_scale
        phi = jnp.concatenate([(window * p.input_mask[:, None]).reshape(-1), plays, past * p.output_mask])
        return phi, NARXState(window, state.outputs, plays)

    def advance(self, partial: NARXState, y: Array) -> NARXState:
        """The history after sample k: the newest `n_u` input vectors and `y_k` pushed onto the outputs."""
        outputs = jnp.concatenate([jnp.reshape(y, (1,)).astype(partial.outputs.dtype), partial.outputs])
        return NARXState(partial.inputs[: self.input_lags], outputs[: self.output_lags], partial.plays)

    def feedback(self, state: NARXState, y_measured: Array) -> NARXState:
        if self.output_lags == 0:
            return state
        outputs = state.outputs.at[0].set(jnp.asarray(y_measured, state.outputs.dtype))
        return NARXState(state.inputs, outputs, state.plays)

    def denormalise(self, y_normalised: Array) -> Array:
        p = unwrap(self)
        return p.output_mean + p.output_scale * y_normalised

    def teacher_forced(self, samples: MotionSample, measured: Any, play_states: Any = None) -> Float[Array, "T P"]:
        """The regressor vectors `phi_k` of a whole record under teacher forcing, as rows: `(T, size)`.

        Row k is the `phi_k` that `fj.simulate(model, motion, measured=measured)` feeds the model at sample k:
        inputs `u_k .. u_{k-n_u}`, the play states `p_i(k)` and measured outputs `y_{k-1} .. y_{k-n_y}`, with the
        state at rest before the record (inputs 0, plays 0, outputs 0, as `init_state`). Built by shifting: the
        regressors of a model linear in its parameters (least squares, term selection) without simulating it.
        The play states are a recursion over time, which runs in `fj.simulate` only: give them as `play_states`.

        **Arguments:** `samples`, the record's per-step signals (`motion.samples(regressors.requires)`);
        `measured`, the force [N], shape `(T,)`; `play_states`, the play operators' states along the record,
        `fj.simulate(regressors.play_operators, motion)`, shape `(T, K)` (needed only with play operators).
        """
        p = unwrap(self)
        u = jnp.stack([jnp.asarray(getattr(samples, s)) for s in self.signals], axis=-1)  # (T, S)
        y = jnp.asarray(measured, u.dtype)
        if u.ndim != 2 or y.shape != u.shape[:1]:
            raise ValueError(
                f"NARXRegressors.teacher_forced: `measured` must have shape ({u.shape[0]},) (one force per sample), "
                f"got {y.shape}."
            )
        length, n_u, n_y = u.shape[0], self.input_lags, self.output_lags
        u = (u - p.input_mean) / p.input_scale
        rest = jnp.broadcast_to(-p.input_mean / p.input_scale, (n_u, u.shape[1])).astype(u.dtype)
        inputs = jnp.concatenate([rest, u])  # inputs[n_u + k] = u_k
        window = jnp.stack([inputs[n_u - i : n_u - i + length] for i in range(n_u + 1)], axis=1)  # (T, n_u+1, S)
        window = (window * p.input_mask[:, None]).reshape(length, -1)
        outputs = jnp.concatenate([jnp.zeros((n_y,), y.dtype), y])  # outputs[n_y + k] = y_k
        lagged = [outputs[n_y - j : n_y - j + length] for j in range(1, n_y + 1)]
        past = jnp.stack(lagged, axis=1) if n_y else jnp.zeros((length, 0), y.dtype)  # n_y = 0: a Volterra series
        past = ((past - p.output_mean) / p.output_scale * p.output_mask).reshape(length, n_y)
        plays = checked_play_states(self, play_states, length, "NARXRegressors.teacher_forced")
        return jnp.concatenate([window, plays.astype(u.dtype), past], axis=1)


def checked_play_states(regressors: NARXRegressors, play_states: Any, length: int, where: str) -> Array:
    """`play_states` as a `(T, K)` array for the K play operators of `regressors` along a record of `length`
    samples (`(T, 0)` without plays), or a clear error when they are missing or misshapen."""
    count = regressors.num_plays
    if play_states is None:
        if count:
            raise ValueError(
                f"{where}: the regressors hold {count} play operators, whose states along the record are a recursion "
                "over time that runs in fj.simulate only; pass them as "
                "play_states=fj.simulate(regressors.play_operators, motion)."
            )
        return jnp.zeros((length, 0))
    states = jnp.asarray(play_states)
    if states.shape != (length, count):
        raise ValueError(
            f"{where}: `play_states` must hold the {count} play states at each of the {length} samples, shape "
            f"({length}, {count}) (fj.simulate(regressors.play_operators, motion)), got {states.shape}."
        )
    return states


def fixed_array(value: Any, shape: tuple[int, ...], name: str, owner: str, positive: bool = False) -> Fixed:
    """A fixed (never trained) array field of `owner` with the given shape (normalisations, masks, thresholds),
    checked when concrete: finite, and > 0 with `positive`."""
    if isinstance(value, Fixed):
        value = value.value
    array = as_float_array(value)
    if array.shape != shape:
        raise ValueError(f"{owner}: `{name}` must have shape {shape}, got {array.shape}.")
    if is_concrete(array):
        concrete = np.asarray(array)
        if not np.all(np.isfinite(concrete)) or (positive and not np.all(concrete > 0)):
            raise ValueError(
                f"{owner}: `{name}` must be finite{' and positive' if positive else ''}, got {concrete!r}."
            )
    return Fixed(array)


def _fixed(value: Any, shape: tuple[int, ...], name: str, positive: bool = False) -> Fixed:
    return fixed_array(value, shape, name, "NARXRegressors", positive)


def record_statistics(data: Any, signals: Sequence[str]) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The normalisation a black-box model reads off a training record (`fj.FrictionData`): per input signal its
    mean (the displacement's; 0 for the zero-mean v, a, dx) and standard deviation, then the force's mean and
    standard deviation [N] (a zero deviation becomes 1; scaled before squaring: forces of 1e200 N give 1e200, not
    inf)."""
    samples = data.motion.samples(frozenset("x" if s == "dx" else s for s in signals))
    means, scales = [], []
    for name in signals:
        signal = np.asarray(getattr(samples, name), dtype=float)
        means.append(float(np.mean(signal)) if name == "x" else 0.0)
        scales.append(float(numpy_std(signal)) or 1.0)
    force = np.asarray(data.force, dtype=float)
    return np.asarray(means), np.asarray(scales), float(np.mean(force)), float(numpy_std(force)) or 1.0
