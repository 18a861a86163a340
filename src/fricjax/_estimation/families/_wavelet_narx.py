"""Identification of a wavelet-network NARX model (the emps-ensemble paper's `nlarx` with MATLAB's `wavenet`).

MATLAB initialises a wavelet network from the data (Zhang 1997, "Using wavelet network in nonparametric
estimation"): the regressors are projected by a principal-component analysis, a library of candidate units is
built on a dyadic grid of dilations and translations restricted to where the data lie, a subset of units is
chosen by orthogonal least squares, and the coefficients that enter linearly are solved by least squares; the
network is then refined by an iterative search. `identify_wavelet_narx` does the same, in the one-step
(teacher-forced) regression of the NARX model; the refinement by output error is `fj.fit(...,
loss=fj.SimulationLoss())` (see its docstring).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import equinox as eqx
import numpy as np

from ..._constraints import unwrap
from ..._models.blackbox._regressors import NARXRegressors
from ..._models.blackbox._wavelet import WaveletNARX
from ..._smoothing import AbstractSmoothing
from ..._validation import nonnegative_int, optional, positive_int
from ..linear._lstsq import LstsqResult, lstsq
from ..linear._regressor_rows import teacher_forced_rows
from ..linear._term_selection import TermSelection, select_terms
from ..loop._solution import Solution


class WaveletNARXSelection(eqx.Module):
    """What `identify_wavelet_narx` returns besides the model, as its `fj.Solution`'s typed `aux` (the fields read
    through: `solution.selection` is `solution.aux.selection`):

    - `selection`: the `TermSelection` of the orthogonal-least-squares choice of units (`select_terms`, with the
      linear part and the offset in the model from the start); its `indices` index the candidate units: index
      `i < C * levels` is the wavelet at centre `i % C` with dilation `i // C`, index `C * levels + i` the scaling
      function at the same (centre, dilation) pair (`C = len(centres)`).
    - `centres`: the candidate centres `(C, q)`, in the projected coordinates `(x - r) Q`.
    - `dilations`: the candidate dilations `(levels,)`, `2^j / sqrt(q)`.
    - `fit`: the least-squares solve of `(L, a, s, d)` (an `fj.LstsqResult`, columns in the order of
      `model.features` and then the offset).
    """

    selection: TermSelection
    centres: np.ndarray
    dilations: np.ndarray
    fit: LstsqResult


def identify_wavelet_narx(
    data: Any,
    *,
    signals: Sequence[str] = ("dx", "v"),
    input_lags: int = 2,
    output_lags: int = 2,
    units: int = 10,
    levels: int = 4,
    candidates: int = 100,
    components: int | None = None,
    nonlinear: Sequence[int] | None = None,
    whiten: bool = False,
    criterion: Literal["err", "press"] = "err",
    plays: Any = None,
    smoothing: AbstractSmoothing | None = None,
    regressors: NARXRegressors | None = None,
    burn_in: int | None = None,
) -> Solution:
    """Identify a wavelet-network NARX model (`fj.WaveletNARX`, MATLAB's `wavenet`) from a record.

    1. Regressors: `x_k = [u_k, ..., u_{k-n_u}, (plays), F_{k-1}, ..., F_{k-n_y}]`, the input `signals` and the
       measured force (teacher forcing: `regressors.teacher_forced`), each normalised by the record's mean and
       standard deviation (`NARXRegressors.from_data`), or the given `regressors`; the first `burn_in` rows are
       dropped.
    2. Projection (PCA): `r` = the rows' mean; `Q` = the principal directions of the `nonlinear` regressors
       (those with a singular value above `1e-8` of the largest, at most `components` of them), all divided by
       one common scale so that the mean squared radius of the projected rows is `q` (the principal axes keep
       their relative spreads), or each by its own standard deviation with `whiten=True` (every projected
       coordinate of unit variance; this blows the small principal components, differences of lagged signals and
       their noise, up to the size of the large ones, and gave worse free runs on the tribometer records).
       `P` = the identity: the linear part `L` acts on every regressor.
    3. Candidate units: `candidates` centres chosen among the projected rows by farthest-point sampling (the row
       nearest the mean first, then each time the row farthest from those chosen: a uniform cover of the region
       the data occupy, the data-driven counterpart of Zhang's dyadic grid restricted to cells holding data),
       crossed with the dyadic dilations `2^j / sqrt(q)`, `j = 0..levels-1` (the coarsest unit spans the data
       cloud, whose radius is about `sqrt(q)` in these coordinates), each as a wavelet and as a scaling function:
       `2 * candidates * levels` candidate columns.
    4. Selection by orthogonal least squares (`fj.select_terms` on the candidates and the target made orthogonal
       to the linear part and the offset, which are in the model from the start): with `criterion="err"` the
       `units` candidates of largest error-reduction ratio (MATLAB's fixed number of units); with `"press"` at
       most `units`, stopping when the leave-one-out error no longer falls (its leverages are those of the units,
       not of the linear part: a slight underestimate of PRESS that changes no ranking).
    5. Coefficients: `(L, a, s, d)` by least squares (`fj.lstsq`) of the normalised force on the columns
       `[(x_k - r) P, the selected wavelets, the selected scaling functions, 1]`.

    The model minimises the one-step (equation) error; refine its free run by output error (all parameters,
    dilations and centres included), as MATLAB's iterative search does on the prediction error:

        fj.fit(result.model, data, loss=fj.SimulationLoss(), solver=optax.adam(...), steps=..., validation=...)

    With no fed-back outputs (`output_lags=0`, e.g. on play operators) the free run is linear in `(L, a, s, d)`:
    add `separable=("L", "a", "s", "d")` to solve them exactly inside every evaluation.

    **Arguments:**

    - `data`: the training record, `fj.FrictionData`.
    - `signals`: the input signals (`"x"`, `"dx"`, `"v"`, `"a"`); default the displacement increment and velocity.
    - `input_lags`, `output_lags`: `n_u >= 0` (lags 0..n_u of each input), `n_y >= 0` (past forces 1..n_y).
    - `units`: the number of units (wavelets and scaling functions together) to select, >= 0 (0: a linear ARX).
    - `levels`: the number of dyadic dilation levels, >= 1.
    - `candidates`: the number of candidate centres, >= 1 (at most the number of rows).
    - `components`: the most principal components the units see (default: every non-degenerate one).
    - `nonlinear`: indices into the regressor vector `x_k` of the regressors the units see (MATLAB's choice of
      nonlinear regressors; default all). The order of `x_k`: the inputs lag by lag (signals in order within a
      lag), the play operators, the past forces; e.g. `(0,)` for the velocity alone in
      `NARXRegressors(("v",), 0, 0, plays=...)`. The others enter the linear part only (their rows of `Q` are 0).
    - `whiten`: scale each principal component to unit variance, or all by one scale (default).
    - `criterion`: `"err"` (default: exactly `units`) or `"press"` (at most `units`).
    - `plays`, `smoothing`: play-operator thresholds [m] and their smoothing, passed to
      `NARXRegressors.from_data` (not with `regressors`).
    - `regressors`: an `fj.NARXRegressors` to use as it is (its normalisation included) instead of `signals` /
      `input_lags` / `output_lags` / `plays` and the record's normalisation.
    - `burn_in`: samples at the start of the record not used as equations; default `max(n_u, n_y)`.

    **Returns:** a `fj.Solution`: its `model` is the identified `WaveletNARX` (wavelets, then scaling functions,
    each in the order selected); its `aux` a `WaveletNARXSelection` (selection, centres, dilations, fit).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> rng = np.random.default_rng(0)
    >>> v = rng.standard_normal(600)
    >>> F = np.zeros(600)
    >>> for k in range(1, 600):
    ...     F[k] = 0.5 * F[k - 1] + np.tanh(2 * v[k])
    >>> data = fj.FrictionData(fj.Motion.from_velocity(v, dt=1e-3), F)
    >>> result = fj.identify_wavelet_narx(data, signals=("v",), input_lags=0, output_lags=1, units=12)
    >>> model = result.model
    >>> (model.num_wavelets + model.num_scaling, bool(fj.nmse(F, fj.simulate(model, data.motion)) < 1.0))
    (12, True)
    ```
    """
    where = "identify_wavelet_narx"
    if regressors is None:
        regressors = NARXRegressors.from_data(data, signals, input_lags, output_lags, plays=plays, smoothing=smoothing)
    elif not isinstance(regressors, NARXRegressors):
        raise TypeError(f"{where}: `regressors` must be an fj.NARXRegressors or None, got {type(regressors).__name__}.")
    elif plays is not None or smoothing is not None:
        raise ValueError(f"{where}: give `plays` / `smoothing` to the `regressors` you pass, not separately.")
    units = nonnegative_int(units, "units", where, hint="(the number of units to select)")
    levels = positive_int(levels, "levels", where, hint="(the number of dyadic dilation levels)")
    candidates = positive_int(candidates, "candidates", where, hint="(the number of candidate centres)")
    components = optional(positive_int, components, "components", where, hint="(the most principal components)")
    m = regressors.size
    chosen_inputs = _nonlinear_indices(nonlinear, m, where)
    if not isinstance(whiten, bool):
        raise TypeError(f"{where}: `whiten` must be True or False, got {whiten!r}.")
    if criterion not in ("err", "press"):
        raise ValueError(f"{where}: `criterion` must be 'err' or 'press', got {criterion!r}.")
    lag = max(regressors.input_lags, regressors.output_lags)
    burn_in = lag if burn_in is None else nonnegative_int(burn_in, "burn_in", where, hint="(samples)")
    rows_count = data.length - burn_in
    needed = m + units + 2
    if rows_count < max(needed, candidates):
        raise ValueError(
            f"{where}: too few samples: {data.length} in the record, {rows_count} after the burn-in of {burn_in}, "
            f"for {m} regressors, {units} units and {candidates} candidate centres; at least "
            f"{max(needed, candidates)} are needed. Pass a longer record, or lower `units`, `candidates` or the lags."
        )

    probe = _template(regressors, 1)
    probe.check_inputs(data.motion)
    samples = data.motion.samples(regressors.requires)
    rows = np.asarray(_teacher_forced(regressors, samples, data.force), np.float64)[burn_in:]
    scales = unwrap(regressors)
    force = np.asarray(data.force, np.float64)[burn_in:]
    target = (force - float(scales.output_mean)) / float(scales.output_scale)

    center = rows.mean(axis=0)
    Q_part = _projection(rows[:, chosen_inputs] - center[chosen_inputs], components, whiten)
    Q = np.zeros((m, Q_part.shape[1]))
    Q[chosen_inputs] = Q_part
    q = Q.shape[1]
    projected = (rows - center) @ Q
    centres = projected[_farthest_points(projected, candidates)]
    dilations = 2.0 ** np.arange(levels) / np.sqrt(q)
    library = _candidate_units(projected, centres, dilations)

    linear = np.column_stack([np.ones(len(rows)), rows - center])
    basis = _orthonormal_basis(linear)
    orthogonal = library - basis @ (basis.T @ library)
    spanned = np.linalg.norm(orthogonal, axis=0) <= 1e-8 * np.linalg.norm(library, axis=0)
    orthogonal[:, spanned] = 0.0  # a unit the linear part already spans (e.g. flat over the data) is no candidate
    residual = target - basis @ (basis.T @ target)
    if units:
        selection = select_terms(orthogonal, residual, criterion=criterion, max_terms=units, intercept=False)
    else:
        selection = TermSelection((), np.zeros(0), 0.0, np.zeros(0), np.zeros(1), np.zeros(1))
    count = len(centres)
    per_kind = count * levels
    chosen = np.asarray(selection.indices, dtype=int)
    wavelets, scaling = chosen[chosen < per_kind], chosen[chosen >= per_kind] - per_kind

    def units_of(index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return dilations[index // count], centres[index % count].reshape(-1, q)

    b, c = units_of(wavelets)
    beta, gamma = units_of(scaling)
    # the columns of the model's `features` (P = I), then the offset: the selected units are library columns
    selected = np.concatenate([wavelets, per_kind + scaling])
    design = np.column_stack([rows - center, library[:, selected], np.ones(len(rows))])
    solution = lstsq(design, target)
    coefficients = np.asarray(solution.x)
    kw = len(b)
    model = WaveletNARX(
        regressors, center=center, Q=Q, L=coefficients[:m], a=coefficients[m : m + kw], b=b, c=c,
        s=coefficients[m + kw : -1], beta=beta, gamma=gamma, d=coefficients[-1],
    )  # fmt: skip
    return Solution(
        model=model,
        message=f"{len(selected)} units chosen by orthogonal least squares; every linear coefficient by least squares",
        aux=WaveletNARXSelection(
            selection=selection,
            centres=centres,
            dilations=dilations,
            fit=solution,
        ),
    )


@eqx.filter_jit
def _teacher_forced(regressors: NARXRegressors, samples: Any, force: Any) -> Any:
    """The teacher-forced regressor rows, compiled as one program (not op by op)."""
    return teacher_forced_rows(regressors, samples, force)


def _template(regressors: NARXRegressors, q: int) -> WaveletNARX:
    m = regressors.size
    empty = np.zeros(0)
    return WaveletNARX(
        regressors, center=np.zeros(m), Q=np.eye(m, q), L=np.zeros(m), a=empty, b=empty, c=np.zeros((0, q)),
        s=empty, beta=empty, gamma=np.zeros((0, q)),
    )  # fmt: skip


def _projection(centred: np.ndarray, components: int | None, whiten: bool) -> np.ndarray:
    """The PCA projection `(k, q)` of centred rows `(N, k)`: whitened, or scaled to a mean squared radius q."""
    _, singular, vt = np.linalg.svd(centred, full_matrices=False)
    keep = singular > 1e-8 * singular[0] if singular.size and singular[0] > 0 else np.zeros(singular.shape, bool)
    q = int(np.sum(keep)) if components is None else min(int(np.sum(keep)), components)
    if q == 0:
        raise ValueError(
            "identify_wavelet_narx: the regressors the units see do not vary over the record (every principal "
            "component is 0); pass a record with motion, or other `nonlinear` regressors."
        )
    std = singular[:q] / np.sqrt(len(centred))
    scale = std if whiten else np.full(q, np.sqrt(np.mean(std**2)))
    return vt[:q].T / scale


def _nonlinear_indices(nonlinear: Any, size: int, where: str) -> np.ndarray:
    if nonlinear is None:
        return np.arange(size)
    try:
        indices = [int(i) for i in nonlinear if not isinstance(i, bool) and int(i) == i]
        ok = len(indices) == len(nonlinear)
    except (TypeError, ValueError):
        ok = False
    if not ok or not indices or len(set(indices)) != len(indices) or not all(0 <= i < size for i in indices):
        raise ValueError(
            f"{where}: `nonlinear` must be distinct indices into the regressor vector (0..{size - 1}: "
            f"regressors.size = {size}), at least one, got {nonlinear!r}."
        )
    return np.asarray(sorted(indices))


def _farthest_points(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of `count` rows of `points` by farthest-point sampling, from the row nearest the origin (the mean)."""
    first = int(np.argmin(np.sum(points**2, axis=1)))
    chosen = [first]
    distance = np.sum((points - points[first]) ** 2, axis=1)
    for _ in range(count - 1):
        index = int(np.argmax(distance))
        if distance[index] <= 0:  # fewer distinct rows than `count`
            break
        chosen.append(index)
        distance = np.minimum(distance, np.sum((points - points[index]) ** 2, axis=1))
    return np.asarray(chosen)


def _candidate_units(projected: np.ndarray, centres: np.ndarray, dilations: np.ndarray) -> np.ndarray:
    """The candidate columns `(N, 2 C J)`: wavelets at every (dilation j, centre i), column `j C + i`, then the
    scaling functions in the same order (the model's functions, evaluated in NumPy)."""
    q = projected.shape[1]
    squared = np.sum((projected[:, None, :] - centres[None]) ** 2, axis=-1)  # (N, C)
    z2 = (dilations[:, None, None] ** 2) * squared[None]  # (J, N, C)
    gauss = np.exp(-0.5 * z2)
    wavelets = ((q - z2) * gauss).transpose(1, 0, 2).reshape(len(projected), -1)
    scaling = gauss.transpose(1, 0, 2).reshape(len(projected), -1)
    return np.concatenate([wavelets, scaling], axis=1)


def _orthonormal_basis(matrix: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the column span of `matrix` (rank-revealing: zero or repeated columns dropped)."""
    u, singular, _ = np.linalg.svd(matrix, full_matrices=False)
    return u[:, singular > 1e-10 * singular[0]]
