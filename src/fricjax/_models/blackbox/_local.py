"""Local models: k-nearest-neighbour predictors on delay vectors (parlitz2004 §III-F, eqs. 22-25).

A local model keeps its training set, pairs `(z_n, F_n)` of delay vectors and forces, and builds a small model
only when queried: at sample k it forms the delay vector `z_k` of the displacement history (embedding dimension
`m`, delay `tau`: `z_k = [x_k, x_{k-tau}, ..., x_{k-(m-1) tau}]`, optionally past forces, other signals and play
operators), finds the `K` training vectors nearest to it (Euclidean metric, optionally weighted per coordinate)
and predicts

- locally constant (eq. 22): the (weighted) mean of the neighbours' forces;
- locally linear (eqs. 23-25): a linear function fitted to the neighbours by least squares, regularised by
  truncated principal component regression (TPCR): singular values of the neighbourhood below a relative
  threshold `rcond`, or beyond a fixed `rank`, are set to zero in the pseudoinverse.

The neighbour search is exact and brute force (distances to every training vector, then a two-stage `top_k`,
see `nearest`): O(N) per step for N training vectors, no Python loop, so the model runs under `jit`, `vmap` and
inside `fj.simulate`'s scan. On 2 CPU cores with N = 4800 a free-run step costs about 0.3-0.6 ms with a few
dozen neighbours and 1.5-2 ms for a locally linear fit over 300 (benchmarks/local.py). parlitz2004 used the
ATRIA search tree, which finds the same neighbours faster on a CPU but does not vectorise.

parlitz2004's structure is the delay vector of the displacement (their nonuniform embedding also took past
forces: `output_embedding`). On the built-in tribometer records it stays 20-200x above the noise floor, as the
delay vectors cannot hold the non-local memory of pre-sliding hysteresis; play-operator states as coordinates
(`plays=`, an extension) and a fitted sensor drift (`fj.identify_local_model(..., drift=True)`) bring it to
3-17x (benchmarks/README.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..._constraints import Fixed, FixedScalar, unwrap
from ..._inputs import MotionSample
from ..._lapack_threads import thin_svd
from ..._smoothing import is_concrete
from ..._validation import integer, nonnegative_int, optional, positive_int
from .._base import AbstractFrictionModel
from ._regressors import NARXRegressors, NARXState, fixed_array

KINDS = ("constant", "linear")


class LocalModel(AbstractFrictionModel):
    """A local (k-nearest-neighbour) friction model on delay vectors (parlitz2004 §III-F, eqs. 22-25).

    At sample k the query is `z_k = phi_k[columns]`, chosen entries of the NARX regressor vector `phi_k` of
    `regressors` (`fj.NARXRegressors`: the normalised input signals at lags 0..n_u, play-operator states, past
    forces at lags 1..n_y). For the delay embedding of the displacement with dimension `m` and delay `tau`
    (`LocalModel.from_data(..., embedding=m, delay=tau)`) these are `x_k, x_{k-tau}, ..., x_{k-(m-1) tau}`,
    each normalised by the training record's mean and standard deviation. With the training set `(z_n, F_n)`,
    `n = 1..N`, the squared distance is `d_n^2 = sum_j (metric_j (z_kj - z_nj))^2`, the `K = neighbours`
    nearest `nn_1..nn_K` (exact search; ties to the lower index) carry the weights `w_i = neighbour_mask_i`
    (the paper's results used constant weights), and the force [N] is

    - `kind="constant"` (eq. 22): `F_k = sum_i w_i F_{nn_i} / sum_i w_i`;
    - `kind="linear"` (eqs. 23-25): `F_k = Fbar + a . (metric * z_k - zbar)`, where `zbar`, `Fbar` are the
      neighbours' means (weights `w_i^2`, as eq. 24 weights the squared errors) in metric-scaled coordinates
      and `a` solves the weighted least-squares problem `min sum_i w_i^2 (F_nn_i - Fbar - a . (z_nn_i - zbar))^2`
      by the truncated SVD of the centred neighbourhood `W (Z - zbar) = U S V^T`:
      `a = V S^+ U^T W (F - Fbar)`, keeping the singular values `s_j > max(rcond, eps max(K, D)) s_1` with
      `j <= rank` (TPCR). Without truncation this is eq. 25's least-squares fit of `[z; 1]`; centring makes the
      truncation act on the principal components of the neighbourhood (truncated principal component
      regression), independently of how far the neighbourhood lies from the origin.

    State: the regressor history (`fj.NARXState`: the delay buffer of normalised inputs, the play states, the
    past forces). A model with past forces among its coordinates feeds back its own output: `feedback` replaces
    the newest by the measurement (teacher forcing: `fj.simulate(model, motion, measured=force)`).

    The prediction is piecewise smooth in the query: it jumps where the set of nearest neighbours changes. There
    is no smooth mode, and nothing to train: the training set, normalisation, metric and masks are fixed
    leaves (`Fixed`); `fj.exact(model)` only sets the play operators (if any) to exact.

    **Arguments:**

    - `regressors`: an `fj.NARXRegressors` (signals, lags, normalisation, plays, fed-back forces).
    - `points`: the training delay vectors `z_n`, shape `(N, D)`, in the coordinates of `columns` (normalised,
      metric not applied).
    - `forces`: their forces `F_n` [N], shape `(N,)`.
    - `columns`: the `D` entries of the regressor vector that form the delay vector (integers; default all).
      Entry `i * S + s` is signal `s` at lag `i` (S signals, lags 0..n_u), then the `K` play states, then the
      past forces `F_{k-1}, ..., F_{k-n_y}`.
    - `neighbours`: `K`, the number of nearest neighbours searched (static), `1 <= K <= N`.
    - `kind`: `"constant"` (default) or `"linear"`.
    - `rank`: the most principal components kept by the locally linear fit (default `D`: no limit).
    - `rcond`: the relative singular-value threshold of TPCR (default 1e-3; 0 keeps every non-negligible one).
    - `metric`: non-negative weights of the coordinates in the distance and the local fit, shape `(D,)`
      (default ones; a 0 switches a coordinate off).
    - `neighbour_mask`: 0/1 weights of the neighbours by rank, shape `(K,)` (default ones): `[1]*k + [0]*(K-k)`
      is the model with `k` neighbours, so sweeps over `k` share one shape (see `fj.identify_local_model`).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> x = 1e-5 * np.sin(np.linspace(0, 12, 600))
    >>> data = fj.FrictionData(fj.Motion.from_position(x, dt=1e-3), np.tanh(1e5 * x))
    >>> model = fj.LocalModel.from_data(data, embedding=3, delay=2, neighbours=4)
    >>> model.describe()
    ['x[k]', 'x[k-2]', 'x[k-4]']
    >>> fj.simulate(model, data.motion).shape
    (600,)
    ```
    """

    units: ClassVar[dict[str, str] | None] = {"forces": "N"}  # the training points are normalised

    regressors: NARXRegressors
    points: Fixed[Float[Array, "N D"]]
    forces: Fixed[Float[Array, " N"]]
    columns: Fixed[Int[Array, " D"]]
    metric: Fixed[Float[Array, " D"]]
    neighbour_mask: Fixed[Float[Array, " K"]]
    rank: Fixed[Int[Array, ""]]
    rcond: FixedScalar
    neighbours: int = eqx.field(static=True)
    kind: str = eqx.field(static=True)

    def __init__(
        self,
        regressors: NARXRegressors,
        points: Any,
        forces: Any,
        *,
        columns: Any = None,
        neighbours: int = 10,
        kind: Literal["constant", "linear"] = "constant",
        rank: int | None = None,
        rcond: float = 1e-3,
        metric: Any = None,
        neighbour_mask: Any = None,
    ):
        owner = "LocalModel"
        if not isinstance(regressors, NARXRegressors):
            raise TypeError(f"{owner}: `regressors` must be an fj.NARXRegressors, got {type(regressors).__name__}.")
        if kind not in KINDS:
            raise ValueError(f"{owner}: `kind` must be 'constant' or 'linear', got {kind!r}.")
        self.regressors, self.kind = regressors, kind
        index = _columns(columns, regressors.size)
        dims = index.shape[0]
        points_array = points.value if isinstance(points, Fixed) else points
        if np.ndim(points_array) != 2 or np.shape(points_array)[1] != dims:
            raise ValueError(
                f"{owner}: `points` must have shape (N, {dims}) (one delay vector of the {dims} columns per row), "
                f"got {np.shape(points_array)}."
            )
        count = int(np.shape(points_array)[0])
        self.points = fixed_array(points_array, (count, dims), "points", owner)
        self.forces = fixed_array(forces, (count,), "forces", owner)
        self.neighbours = integer(
            neighbours, "neighbours", owner, minimum=1, maximum=count, hint="(the training points)"
        )
        self.columns = Fixed(jnp.asarray(index, jnp.int32))
        self.metric = _weights(np.ones(dims) if metric is None else metric, (dims,), "metric", owner)
        mask = np.ones(self.neighbours) if neighbour_mask is None else neighbour_mask
        self.neighbour_mask = _weights(mask, (self.neighbours,), "neighbour_mask", owner, nonzero=True)
        rank = optional(nonnegative_int, rank, "rank", owner, hint="(no limit)")
        self.rank = Fixed(jnp.asarray(dims if rank is None else rank, jnp.int32))
        if is_concrete(rcond) and not (np.ndim(rcond) == 0 and np.isfinite(rcond) and 0 <= rcond < 1):
            raise ValueError(
                f"{owner}: `rcond` (the relative singular-value threshold) must be in [0, 1), got {rcond!r}."
            )
        self.rcond = fixed_array(rcond, (), "rcond", owner)

    @classmethod
    def from_data(
        cls,
        data: Any,
        *,
        embedding: int = 4,
        delay: int = 1,
        signals: Sequence[str] = ("x",),
        output_embedding: int = 0,
        output_delay: int = 1,
        plays: Any = None,
        play_states: Any = None,
        neighbours: int = 10,
        kind: Literal["constant", "linear"] = "constant",
        rank: int | None = None,
        rcond: float = 1e-3,
        metric: Any = None,
        burn_in: int | None = None,
    ) -> LocalModel:
        """A local model whose training set is the record `data` (`fj.FrictionData`), on a uniform delay embedding.

        Coordinates: each of `signals` (default the displacement; `"v"`, `"a"`, `"dx"` too) at lags
        `0, delay, ..., (embedding - 1) delay` (parlitz2004 eq. 7 with the delay tau; signal-major within a lag),
        then the play operators of the displacement with thresholds `plays` [m] (their states, in [-1, 1]; an
        extension, see `fj.NARXRegressors(plays=)`), then the past forces at lags
        `1, 1 + output_delay, ..., 1 + (output_embedding - 1) output_delay` (eq. 8: parlitz2004's local models
        took six past forces besides nine displacements). Signals and forces are normalised by the record's
        mean and standard deviation. Training pairs are the record's teacher-forced delay vectors (measured past
        forces) and forces, from sample `burn_in` on (default: the largest lag, so that no vector reaches before
        the record). With `plays`, `play_states` are the play operators' states along `data` (a recursion over
        time, which runs in `fj.simulate` only): `fj.simulate(fj.PlayOperators(plays), data.motion)`, `(T, K)`. The
        other arguments are the constructor's.
        """
        where = "LocalModel.from_data"
        embedding = positive_int(embedding, "embedding", where)
        delay = positive_int(delay, "delay", where)
        output_delay = positive_int(output_delay, "output_delay", where)
        output_embedding = nonnegative_int(output_embedding, "output_embedding", where)
        input_lags = (embedding - 1) * delay
        output_lags = 1 + (output_embedding - 1) * output_delay if output_embedding else 0
        regressors = NARXRegressors.from_data(data, signals, input_lags, output_lags, plays=plays)
        columns = delay_columns(regressors, embedding, delay, output_embedding, output_delay)
        burn_in = max(input_lags, output_lags) if burn_in is None else burn_in
        burn_in = integer(burn_in, "burn_in", where, minimum=0, maximum=data.length - 1, hint="(samples of the record)")
        if regressors.num_plays and play_states is None:
            raise ValueError(
                f"{where}: with `plays`, pass the play operators' states along `data` (a recursion over time, which "
                "runs in fj.simulate only): play_states=fj.simulate(fj.PlayOperators(plays), data.motion)."
            )
        points, forces = training_set(regressors, data, columns, burn_in, play_states)
        return cls(
            regressors,
            points,
            forces,
            columns=columns,
            neighbours=neighbours,
            kind=kind,
            rank=rank,
            rcond=rcond,
            metric=metric,
        )

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return self.regressors.requires

    @property
    def dimension(self) -> int:
        """`D`, the number of coordinates of a delay vector."""
        return int(jnp.shape(unwrap(self.points))[1])

    @property
    def size(self) -> int:
        """`N`, the number of training points."""
        return int(jnp.shape(unwrap(self.points))[0])

    def init_state(self) -> NARXState:
        return self.regressors.init_state(jnp.result_type(unwrap(self.points)))

    def step(self, state: NARXState, sample: MotionSample) -> tuple[NARXState, Array]:
        p = unwrap(self)
        phi, partial = p.regressors(state, sample)
        y = p._predict_one(phi[p.columns], p.forces[:, None])[0]
        return p.regressors.advance(partial, y), y

    def feedback(self, state: NARXState, y_measured: Array) -> NARXState:
        return self.regressors.feedback(state, y_measured)

    def predict(self, query: Float[Array, "... D"], targets: Any = None, *, batch_size: int = 256) -> Array:
        """The force [N] the model predicts for delay vectors `query` (shape `(..., D)`: the coordinates of
        `columns`, normalised; metric not applied): one neighbour search and one local fit per vector.

        `targets`, shape `(N,)` or `(N, C)`: values attached to the training points to predict in place of the
        forces, with the same neighbours and local fits (the prediction is linear in the training forces: a
        local model is a linear smoother). `fj.identify_local_model` predicts the training points' times with it
        to fit the sensor drift. Queries are processed `batch_size` at a time (memory: about `batch_size x N`
        distances). **Returns:** shape `query.shape[:-1]` (`+ (C,)` for targets `(N, C)`)."""
        p = unwrap(self)
        dims, count = self.dimension, self.size
        query = jnp.asarray(query, p.points.dtype)
        if query.shape[-1:] != (dims,):
            raise ValueError(f"LocalModel.predict: `query` must have shape (..., {dims}), got {query.shape}.")
        values = p.forces if targets is None else jnp.asarray(targets, p.points.dtype)
        if values.shape[:1] != (count,) or values.ndim > 2:
            raise ValueError(
                f"LocalModel.predict: `targets` must have shape ({count},) or ({count}, C), one row per training "
                f"point, got {values.shape}."
            )
        batch_size = positive_int(batch_size, "batch_size", "LocalModel.predict")
        flat = query.reshape(-1, dims)
        batch = min(batch_size, max(flat.shape[0], 1))
        out = _predict_many(p, flat, values.reshape(count, -1), batch)
        return out.reshape(query.shape[:-1] + values.shape[1:])

    def _predict_one(self, query: Float[Array, " D"], targets: Float[Array, "N C"]) -> Array:
        """One query, parameters unwrapped: the `C` predictions of the targets' columns."""
        p = unwrap(self)
        distance = jnp.sum(jnp.square((p.points.T - query[:, None]) * p.metric[:, None]), axis=0)
        index = nearest(distance, self.neighbours)
        values, w = targets[index], p.neighbour_mask  # (K, C), (K,)
        if self.kind == "constant":
            return w @ values / jnp.sum(w)
        z = p.points[index] * p.metric  # (K, D), metric-scaled
        w2 = jnp.square(w) / jnp.sum(jnp.square(w))
        zbar, vbar = w2 @ z, w2 @ values
        slope = tpcr(w[:, None] * (z - zbar), w[:, None] * (values - vbar), p.rank, p.rcond)  # (D, C)
        return vbar + (query * p.metric - zbar) @ slope

    def describe(self) -> list[str]:
        """The coordinates of the delay vector, in order: `"x[k-4]"`, `"play[2]"`, `"F[k-1]"`."""
        names = _regressor_names(self.regressors)
        return [names[int(i)] for i in np.asarray(unwrap(self.columns))]


@eqx.filter_jit
def _predict_many(model: LocalModel, queries: Array, targets: Array, batch_size: int) -> Array:
    """`predict`'s loop over queries, `batch_size` at a time (compiled once per shape, as a driver)."""
    return jax.lax.map(lambda q: model._predict_one(q, targets), queries, batch_size=batch_size)


def nearest(distance: Float[Array, " N"], k: int) -> Array:
    """The indices of the `k` smallest entries of `distance`, smallest first, ties to the lower index: exactly
    `lax.top_k(-distance, k)[1]`, computed in two stages because XLA's CPU `top_k` sorts the whole vector (about
    1 ms for 5000 entries, 10 x the distance computation). The entries are cut into `B` blocks of `b ~
    sqrt(N / k)`; the `k` nearest lie in the `k` blocks with the smallest minima (a block holding one of them has
    its minimum at most the k-th distance, and fewer than `k` blocks lie below it; ties go to lower blocks as to
    lower indices), so `top_k` runs over `B` minima and then over the `k b` entries of those blocks."""
    n = distance.shape[0]
    b = max(1, int(np.sqrt(n / k)))
    if b == 1:
        return jax.lax.top_k(-distance, k)[1]
    blocks = -(-n // b)
    padded = jnp.pad(distance, (0, blocks * b - n), constant_values=jnp.inf).reshape(blocks, b)
    chosen = jnp.sort(jax.lax.top_k(-jnp.min(padded, axis=1), k)[1])  # in index order: ties to lower indices
    _, position = jax.lax.top_k(-padded[chosen].reshape(-1), k)
    return chosen[position // b] * b + position % b


def tpcr(matrix: Float[Array, "K D"], target: Float[Array, "K C"], rank: Any, rcond: Any) -> Float[Array, "D C"]:
    """Truncated principal component regression: the least-squares solution `a` of `matrix a ~ target` through
    the SVD `matrix = U S V^T`, keeping the singular values `s_j > max(rcond, eps max(K, D)) s_1` with index
    `j < rank` (others set to zero in the pseudoinverse, parlitz2004 §III-F). The SVD is LAPACK's, one
    neighbourhood per call however the queries are batched (`thin_svd`: batched calls can deadlock XLA's CPU
    thread pool)."""
    u, s, vt = thin_svd(matrix)
    floor = jnp.maximum(rcond, jnp.finfo(matrix.dtype).eps * max(matrix.shape)) * s[0]
    keep = (s > floor) & (jnp.arange(s.shape[0]) < rank)
    inverse = jnp.where(keep, 1.0 / jnp.where(keep, s, 1.0), 0.0)
    return vt.T @ (inverse[:, None] * (u.T @ target))


def delay_columns(
    regressors: NARXRegressors, embedding: int, delay: int, output_embedding: int = 0, output_delay: int = 1
) -> np.ndarray:
    """The regressor-vector entries of a uniform delay embedding: every signal at lags `0, delay, ...,
    (embedding - 1) delay`, every play state, the past forces at lags `1, 1 + output_delay, ...` (output_embedding
    of them)."""
    s = len(regressors.signals)
    inputs = [lag * s + j for lag in range(0, embedding * delay, delay) for j in range(s)]
    start = s * (regressors.input_lags + 1)
    plays = list(range(start, start + regressors.num_plays))
    start += regressors.num_plays
    outputs = [start + lag - 1 for lag in range(1, 1 + output_embedding * output_delay, output_delay)]
    return np.asarray(inputs + plays + outputs, dtype=np.int32)


def training_set(
    regressors: NARXRegressors, data: Any, columns: Any, burn_in: int, play_states: Any = None
) -> tuple[Array, Array]:
    """The training pairs of a record: the teacher-forced delay vectors (rows `burn_in..T-1`, `columns` of the
    regressor vectors; `play_states` the play operators' states along the record, if any) and the measured forces
    [N]."""
    rows = regressors.teacher_forced(data.motion.samples(regressors.requires), data.force, play_states)
    return rows[burn_in:, np.asarray(columns)], jnp.asarray(data.force, rows.dtype)[burn_in:]


def _columns(columns: Any, size: int) -> np.ndarray:
    if isinstance(columns, Fixed):
        columns = columns.value
    index = np.arange(size) if columns is None else np.asarray(columns)
    if index.ndim != 1 or index.size == 0 or not np.issubdtype(index.dtype, np.integer):
        raise ValueError(
            f"LocalModel: `columns` must be a non-empty sequence of integers (entries of the regressor vector), got "
            f"{columns!r}."
        )
    if index.min() < 0 or index.max() >= size:
        raise ValueError(
            f"LocalModel: `columns` must index the regressor vector (0..{size - 1}: regressors.size = {size}), got "
            f"{index.tolist()}."
        )
    return index.astype(np.int32)


def _weights(value: Any, shape: tuple[int, ...], name: str, owner: str, nonzero: bool = False) -> Fixed:
    fixed = fixed_array(value, shape, name, owner)
    if not is_concrete(fixed.value):
        return fixed
    concrete = np.asarray(fixed.value)
    if np.any(concrete < 0) or (nonzero and not np.any(concrete > 0)):
        raise ValueError(
            f"{owner}: `{name}` must be >= 0{' with at least one entry > 0' if nonzero else ''}, got {concrete!r}."
        )
    return fixed


def _regressor_names(regressors: NARXRegressors) -> list[str]:
    lags = [
        f"{s}[k]" if i == 0 else f"{s}[k-{i}]" for i in range(regressors.input_lags + 1) for s in regressors.signals
    ]
    plays = [f"play[{j}]" for j in range(regressors.num_plays)]
    return lags + plays + [f"F[k-{j}]" for j in range(1, regressors.output_lags + 1)]
