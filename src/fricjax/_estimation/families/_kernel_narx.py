"""Identification of kernel Volterra series and kernel NARX models by kernel ridge regression.

The kernel-method paper (§2 and footnote 3): the coefficients of `y = sum_i alpha_i k(u_i, .)` on the N
teacher-forced training rows solve `(K + rho I) alpha = y`, `K_ij = k(u_i, u_j)`. Three solvers:

- `"direct"`: the N x N kernel matrix and its Cholesky factor, one per ridge value (the paper's inversion).
- `"cg"`: conjugate gradients (`lineax.CG`) with a matrix-free kernel matvec computed in blocks of rows, so the
  N x N matrix is never formed (memory O(N x block)); preconditioned by a Nyström approximation of K from m
  landmark rows (Frangella, Tropp and Udell 2023, "Randomized Nyström preconditioning": `P = U (L + rho) U^T /
  (l_m + rho) + I - U U^T` for the approximation's eigenpairs `U, L`), which the paper's closing remark (4) asks
  for ("this can be resolved using an iterative algorithm").
- `"nystrom"`: m landmark rows `Z` as the centres, and the reduced ridge problem
  `min ||K_nm alpha - y||^2 + rho alpha^T K_mm alpha` (subset of regressors / Nyström kernel ridge regression),
  solved through the features `Phi = K_nm V L^(-1/2)` of `K_mm = V L V^T`: `(Phi^T Phi + rho I) beta = Phi^T y`,
  `alpha = V L^(-1/2) beta` (by a QR factor of `Phi`, never forming `Phi^T Phi`). With every row a landmark it is
  the direct solution, less the directions of K below round-off (2e-12 x its largest eigenvalue in float64).

Hyperparameters (memory and autoregressive orders, the degree or the width, the ridge) are chosen on a validation
record: every ridge value of one kernel is solved in one vectorised program (one Cholesky factor each for the
direct solver, one factorisation of the m x m Nyström system for all of them, one vmapped CG whose kernel
blocks are shared), the widths in one compiled loop, and all candidates of a structure are simulated side by side
in one vmapped free run. (Widths are looped, not vmapped: batched LAPACK calls on XLA's CPU thread pool deadlock
when two run at once, as a QR's orthogonal factor and the eigendecomposition that needs only its R can; jaxlib
0.10.2 on 2 cores. One width at a time also bounds the memory to one kernel matrix.)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._constraints import unwrap
from ..._data._record import FrictionData
from ..._metrics import numpy_nmse
from ..._models.blackbox._kernel import ExponentialKernel, KernelNARX
from ..._models.blackbox._regressors import NARXRegressors
from ..._simulate import simulate
from ..._smoothing import AbstractSmoothing
from ..._validation import integer as check_integer
from ..._validation import is_integer, optional, positive_float, positive_int
from ..loop._solution import Solution
from ._kernel_solvers import _block, _gram_times_jit, _kernel, _Rows, _solve, _Solved

KERNELS = ("polynomial", "exponential")
SOLVERS = ("direct", "cg", "nystrom")
SELECTIONS = ("free_run", "one_step")


class KernelNARXCandidate(NamedTuple):
    """One point of the hyperparameter grid of `identify_kernel_narx` and its validation scores.

    `input_lags`, `output_lags` (the paper's M - 1 and N_AR), `degree` (polynomial kernel; None for the
    exponential), `width` (exponential kernel; None for the polynomial), `ridge`; `one_step_nmse`: NMSE [%] of the
    one-step (teacher-forced) prediction on the validation part; `free_run_nmse`: NMSE [%] of the free run
    (simulation from the validation record's start, scored after `validation_burn_in`; inf when it diverges).
    Both are NaN without a validation record.
    """

    input_lags: int
    output_lags: int
    degree: int | None
    width: float | None
    ridge: float
    one_step_nmse: float
    free_run_nmse: float


class KernelNARXSearch(eqx.Module):
    """What `identify_kernel_narx` returns besides the model, as its `fj.Solution`'s typed `aux` (the fields read
    through: `solution.ridge` is `solution.aux.ridge`):

    - `ridge`: its ridge (regularisation) parameter rho.
    - `train_nmse`: NMSE [%] of its one-step prediction on the training rows.
    - `validation_nmse`: NMSE [%] of its free run on the validation part (NaN without validation).
    - `candidates`: every grid point with its validation scores (`KernelNARXCandidate`), in evaluation order.
    - `solver_steps`: conjugate-gradient iterations of the chosen solve (None for `"direct"`, `"nystrom"`).
    """

    ridge: float
    train_nmse: float
    validation_nmse: float
    candidates: tuple[KernelNARXCandidate, ...]
    solver_steps: int | None


def identify_kernel_narx(
    data: FrictionData,
    *,
    signals: Sequence[str] = ("x",),
    input_lags: int | Sequence[int] = 10,
    output_lags: int | Sequence[int] = 2,
    kernel: Literal["polynomial", "exponential"] = "polynomial",
    degree: int | Sequence[int] = 3,
    width: float | Sequence[float] = 1.5,
    ridge: float | Sequence[float] = 1e-6,
    solver: Literal["direct", "cg", "nystrom"] = "direct",
    landmarks: int | Sequence[int] | None = None,
    validation: FrictionData | None = None,
    validation_burn_in: int = 0,
    select: Literal["free_run", "one_step"] = "free_run",
    plays: Any = None,
    smoothing: AbstractSmoothing | None = None,
    regressors: NARXRegressors | None = None,
    burn_in: int | None = None,
    tolerance: float = 1e-6,
    max_steps: int = 1000,
    block_size: int | None = None,
    seed: int = 0,
) -> Solution:
    """Identify a kernel Volterra series or kernel NARX model (`fj.KernelNARX`) by kernel ridge regression.

    The kernel-method paper §2-3: the regressor rows `phi_k` of the record under teacher forcing (normalised lags
    `0..input_lags` of the input `signals`, the paper's memory M = `input_lags + 1`, and `output_lags` past
    forces, the paper's N_AR; `output_lags=0` is a Volterra series), the first `burn_in` dropped; the kernel
    `(1 + <u, v>)^degree` (`"polynomial"`, eq. 7, finite degree) or `exp(<u, v> / width)` (`"exponential"`,
    eq. 8, infinite degree); the constant `b` = the mean normalised force of the rows and `alpha` the solution of
    `(K + ridge I) alpha = y - b` (footnote 3), by `solver` (see the module: `"direct"` Cholesky, `"cg"`
    matrix-free Nyström-preconditioned conjugate gradients, `"nystrom"` m landmarks as the centres).

    **Hyperparameters by validation.** `input_lags`, `output_lags`, `degree`, `width` and `ridge` each take one
    value or a sequence; the grid is their product, and with more than one point a `validation` record is
    required. Each candidate is scored on the validation part (samples `validation_burn_in` onwards of
    `validation`, simulated from its start: pass the record up to the end of the validation part and the
    training length, as for `fj.fit`) by its free-run NMSE (`select="free_run"`, default: what a user judges a
    NARX by; its one-step error is small whatever the feedback does, and says nothing of a free run that
    drifts or diverges) or its one-step NMSE (`"one_step"`: cheaper; for a Volterra series the two agree after
    the first samples). All ridge values of a kernel are solved in one program and all candidates of a structure
    are simulated in one vmapped free run.

    The model minimises the one-step error; its free run can be refined by output error:
    `fj.fit(result.model, data, loss=fj.SimulationLoss())` trains `alpha` and `b` (the centres are fixed).

    **Arguments:**

    - `data`: the training record, `fj.FrictionData`.
    - `signals`: input signals (`"x"`, `"dx"`, `"v"`, `"a"`); default the displacement, as in the paper.
    - `input_lags`: `n_u >= 0` (lags 0..n_u, M = n_u + 1), or a sequence (grid).
    - `output_lags`: `n_y >= 0` past forces (N_AR), or a sequence (grid).
    - `kernel`: `"polynomial"` or `"exponential"`.
    - `degree`: D >= 1 of the polynomial kernel, or a sequence. `width`: p > 0 of the exponential, or a sequence.
    - `ridge`: rho > 0 (in the normalised units of `K`), or a sequence.
    - `solver`: `"direct"`, `"cg"` or `"nystrom"`.
    - `landmarks`: for `"nystrom"` the centres, for `"cg"` the preconditioner's rank: a count m (rows drawn at
      random by `seed`; default min(N, 1000) for `"nystrom"`, min(N, 500) for `"cg"`, 0 = no preconditioner) or
      the row indices (into the rows after `burn_in`).
    - `validation`, `validation_burn_in`: the validation record and the samples of it not scored.
    - `select`: `"free_run"` (default) or `"one_step"`, the validation score that chooses the candidate.
    - `plays`, `smoothing`: play-operator thresholds [m] added to the regressors (`fj.NARXRegressors(plays=)`:
      an extension of the paper's lag-only regressors, for hysteresis with non-local memory), and their
      smoothing (default exact).
    - `regressors`: an `fj.NARXRegressors` to use as it is (its normalisation included) instead of `signals`,
      the lags, `plays` and the record's normalisation (no lag grid then).
    - `burn_in`: first samples not used as rows; default `max(input_lags, output_lags)`.
    - `tolerance`, `max_steps`: conjugate gradients' relative tolerance and iteration limit (`"cg"`).
    - `block_size`: rows per block of the kernel matvec (default: blocks of about 32 MB).
    - `seed`: for the random landmarks.

    **Returns:** a `fj.Solution`: its `model` is the identified `fj.KernelNARX` (the chosen candidate); its `aux` a
    `KernelNARXSearch` (ridge, train_nmse, validation_nmse, candidates, solver_steps).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> x = np.random.default_rng(0).standard_normal(300)
    >>> x1 = np.concatenate([[0.0], x[:-1]])                                 # x_{k-1}
    >>> F = 0.5 * x + 0.2 * x**2 - 0.1 * x * x1                              # a Volterra series of degree 2
    >>> data = fj.FrictionData(fj.Motion.from_position(x, dt=1e-3), F)
    >>> regressors = fj.NARXRegressors(("x",), input_lags=1, output_lags=0)
    >>> result = fj.identify_kernel_narx(
    ...     data, regressors=regressors, degree=2, ridge=1e-6, solver="nystrom", landmarks=50
    ... )
    >>> h0, h1, h2 = fj.volterra_kernels(result.model, 2, physical=True)
    >>> rounded = lambda h: (np.round(np.asarray(h, float), 3) + 0.0).tolist()
    >>> rounded(h1), rounded(h2 + h2.T)                                     # h2 is symmetric
    ([0.5, 0.0], [[0.4, -0.1], [-0.1, 0.0]])
    ```
    """
    where = "identify_kernel_narx"
    if not isinstance(data, FrictionData):
        raise TypeError(f"{where}: `data` must be an fj.FrictionData (motion and force), got {type(data).__name__}.")
    if kernel not in KERNELS:
        raise ValueError(f"{where}: `kernel` must be one of {list(KERNELS)}, got {kernel!r}.")
    if solver not in SOLVERS:
        raise ValueError(f"{where}: `solver` must be one of {list(SOLVERS)}, got {solver!r}.")
    if select not in SELECTIONS:
        raise ValueError(f"{where}: `select` must be one of {list(SELECTIONS)}, got {select!r}.")
    degrees = _grid(degree, "degree", where, integer=True, minimum=1)
    widths = _grid(width, "width", where)
    ridges = _grid(ridge, "ridge", where)
    if regressors is not None:
        if not isinstance(regressors, NARXRegressors):
            raise TypeError(
                f"{where}: `regressors` must be an fj.NARXRegressors or None, got {type(regressors).__name__}."
            )
        structures = [(regressors.input_lags, regressors.output_lags)]
    else:
        structures = [
            (n_u, n_y)
            for n_u in _grid(input_lags, "input_lags", where, integer=True, minimum=0)
            for n_y in _grid(output_lags, "output_lags", where, integer=True, minimum=0)
        ]
    if not (isinstance(tolerance, (int, float)) and np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"{where}: `tolerance` (conjugate gradients, relative) must be > 0, got {tolerance!r}.")
    max_steps = positive_int(max_steps, "max_steps", where, hint="(conjugate-gradient iterations)")
    block_size = optional(positive_int, block_size, "block_size", where, hint="(rows per block)")
    kernel_params = list(degrees) if kernel == "polynomial" else [None]
    count = len(structures) * len(kernel_params) * (1 if kernel == "polynomial" else len(widths)) * len(ridges)
    if validation is None and count > 1:
        raise ValueError(
            f"{where}: a grid of {count} candidates needs a `validation` record to choose among them; pass "
            "validation=split.until_validation_end, validation_burn_in=split.train_end (or give one value each)."
        )
    if validation is not None:
        if not isinstance(validation, FrictionData):
            raise TypeError(f"{where}: `validation` must be an fj.FrictionData, got {type(validation).__name__}.")
        validation_burn_in = check_integer(
            validation_burn_in, "validation_burn_in", where, minimum=0, maximum=validation.length - 1,
            hint="(samples of the validation record simulated but not scored)",
        )  # fmt: skip

    best: tuple[float, Any] | None = None
    candidates: list[KernelNARXCandidate] = []
    for n_u, n_y in structures:
        regs = regressors
        if regs is None:
            regs = NARXRegressors.from_data(data, signals, n_u, n_y, plays=plays, smoothing=smoothing)
        fit = _Rows.build(data, regs, burn_in, where)
        landmark_rows = _landmarks(landmarks, solver, fit.rows.shape[0], seed, where)
        val = (
            None if validation is None else _Rows.build(validation, regs, validation_burn_in, where, burn_default=False)
        )
        for param in kernel_params:
            batch = np.asarray(widths if kernel == "exponential" else [1.0])
            solved = _solve(
                kernel, param, batch, fit, np.asarray(ridges), solver, landmark_rows, tolerance, max_steps, block_size
            )
            template = KernelNARX(
                regs, _kernel(kernel, param, batch[0]), solved.centres, np.zeros(solved.centres.shape[0]), fit.offset
            )
            free_runs = select == "free_run"
            one_step, free_run = _scores(
                template, kernel, param, batch, solved, val, validation, validation_burn_in, free_runs
            )
            for w, width_value in enumerate(batch):
                for r, ridge_value in enumerate(ridges):
                    candidate = KernelNARXCandidate(
                        n_u,
                        n_y,
                        param if kernel == "polynomial" else None,
                        float(width_value) if kernel == "exponential" else None,
                        float(ridge_value),
                        float(one_step[w, r]),
                        float(free_run[w, r]),
                    )
                    candidates.append(candidate)
                    score = candidate.free_run_nmse if select == "free_run" else candidate.one_step_nmse
                    score = np.inf if np.isnan(score) else score
                    if best is None or score < best[0]:
                        alpha = solved.alphas[w, r]
                        steps = None if solved.steps is None else int(solved.steps[w, r])
                        best = (score, (template, kernel, param, width_value, alpha, len(candidates) - 1, fit, steps))
    assert best is not None
    template, kind, param, width_value, alpha, chosen, fit, steps = best[1]
    candidate = candidates[chosen]
    if not np.all(np.isfinite(alpha)):
        raise ValueError(
            f"{where}: the kernel ridge solution is not finite (ridge {candidate.ridge:g}: the system is too "
            "ill-conditioned for float64); raise `ridge`, or use solver='nystrom'."
        )
    model = eqx.tree_at(
        lambda m: (m.alpha, m.kernel), template, (jnp.asarray(alpha), _kernel(kind, param, width_value))
    )
    block = _block(fit.rows.shape[0], model.num_centres, block_size)
    width_array = jnp.asarray(width_value, fit.rows.dtype)
    centres = jnp.asarray(unwrap(model.centres))
    fitted = np.asarray(
        _gram_times_jit(kind, param, width_array, jnp.asarray(fit.rows), centres, jnp.asarray(alpha), block)
    )
    train_nmse = float(numpy_nmse(fit.target, fit.offset + fitted))
    if validation is not None and select == "one_step":  # the chosen candidate's free run, for the record
        prediction = np.asarray(simulate(model, validation.motion))[validation_burn_in:]
        measured = np.asarray(validation.force, np.float64)[validation_burn_in:]
        score = float(numpy_nmse(measured, prediction))  # scaled before squaring: forces of 1e200 N score too
        candidate = candidates[chosen] = candidate._replace(free_run_nmse=score if np.isfinite(score) else np.inf)
    return Solution(
        model=model,
        message=f"the candidate with the lowest validation score of {len(candidates)} (ridge {candidate.ridge:g}); "
        "its coefficients by regularised least squares",
        train_loss=train_nmse / 100.0,
        val_loss=candidate.free_run_nmse / 100.0,
        aux=KernelNARXSearch(
            ridge=candidate.ridge,
            train_nmse=train_nmse,
            validation_nmse=candidate.free_run_nmse,
            candidates=tuple(candidates),
            solver_steps=steps,
        ),
    )


# ----------------------------------------------------------------------------------------------------------------
# grids, landmarks
# ----------------------------------------------------------------------------------------------------------------


def _grid(value: Any, name: str, where: str, *, integer: bool = False, minimum: float = 0.0) -> tuple[Any, ...]:
    values = tuple(value) if isinstance(value, (list, tuple, np.ndarray)) else (value,)
    if not values:
        raise ValueError(f"{where}: `{name}` is an empty sequence; give one value or a grid of them.")
    for v in values:
        if integer:
            check_integer(v, name, where, minimum=int(minimum), hint="(or a sequence of them)")
        else:
            positive_float(v, name, where, hint="(or a sequence of them)")
    return tuple(int(v) for v in values) if integer else tuple(float(v) for v in values)


def _landmarks(landmarks: Any, solver: str, rows: int, seed: int, where: str) -> np.ndarray | None:
    """Row indices of the Nyström landmarks (sorted), or None (direct solver; CG without a preconditioner)."""
    if solver == "direct":
        return None
    if landmarks is None:
        landmarks = min(rows, 1000 if solver == "nystrom" else 500)
    if is_integer(landmarks):
        count = int(landmarks)
        if count == 0 and solver == "cg":
            return None
        if not 1 <= count <= rows:
            raise ValueError(
                f"{where}: `landmarks` must be a count in [1, {rows}] (the training rows after the burn-in), "
                f"got {count}."
            )
        if count == rows:
            return np.arange(rows)
        return np.sort(np.random.default_rng(seed).choice(rows, count, replace=False))
    indices = np.asarray(landmarks)
    if (
        indices.ndim != 1
        or indices.size == 0
        or not np.issubdtype(indices.dtype, np.integer)
        or np.any(indices < 0)
        or np.any(indices >= rows)
        or np.unique(indices).size != indices.size
    ):
        raise ValueError(
            f"{where}: `landmarks` must be a count, or distinct row indices in [0, {rows}) (the training rows after "
            "the burn-in)."
        )
    return np.asarray(indices, dtype=np.int64)


# ----------------------------------------------------------------------------------------------------------------
# validation scores
# ----------------------------------------------------------------------------------------------------------------


def _scores(
    template: KernelNARX,
    kind: str,
    degree: Any,
    widths: np.ndarray,
    solved: _Solved,
    val: _Rows | None,
    validation: FrictionData | None,
    burn_in: int,
    free_runs: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """`(one-step NMSE, free-run NMSE)` [%] on the validation part, shape `(W, R)`; NaN without validation (and
    the free runs NaN unless `free_runs`), inf where a free run is not finite."""
    shape = solved.alphas.shape[:2]
    if val is None or validation is None:
        return np.full(shape, np.nan), np.full(shape, np.nan)
    rows, target = jnp.asarray(val.rows), val.target
    centres = jnp.asarray(solved.centres)
    block = _block(rows.shape[0], centres.shape[0], None)
    one_step = np.empty(shape)
    for w, width in enumerate(widths):
        alphas = jnp.asarray(solved.alphas[w]).T  # (m, R)
        predicted = np.asarray(_gram_times_jit(kind, degree, jnp.asarray(width), rows, centres, alphas, block))
        one_step[w] = numpy_nmse(target[:, None], template.b + predicted, axis=0)
    one_step = np.where(np.isfinite(one_step), one_step, np.inf)
    if not free_runs:
        return one_step, np.full(shape, np.nan)
    if template.regressors.output_lags == 0:  # nothing fed back: the free run is the one-step prediction
        return one_step, one_step.copy()
    widths_all = np.repeat(widths, shape[1])
    runs = np.asarray(
        _free_runs(
            template,
            jnp.asarray(solved.alphas.reshape(-1, centres.shape[0])),
            jnp.asarray(widths_all),
            validation.motion,
        )
    )
    measured = np.asarray(validation.force, np.float64)[burn_in:]
    free_run = numpy_nmse(measured, runs[:, burn_in:])  # scaled before squaring: forces of 1e200 N score too
    free_run = np.where(np.isfinite(free_run), free_run, np.inf)
    return one_step, free_run.reshape(shape)


@eqx.filter_jit
def _free_runs(template: KernelNARX, alphas: Any, widths: Any, motion: Any) -> Any:
    """Free runs of the template with each row of `alphas` (and, for the exponential kernel, each width), side
    by side in one vmapped simulation."""
    exponential = isinstance(template.kernel, ExponentialKernel)

    def run(alpha: Any, width: Any) -> Any:
        kernel = ExponentialKernel(width) if exponential else template.kernel
        model = eqx.tree_at(lambda m: (m.alpha, m.kernel), template, (alpha, kernel))
        return simulate(model, motion)

    return jax.vmap(run)(alphas, widths)
