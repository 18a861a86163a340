"""Identification of a polynomial NARX model by forward orthogonal least squares (FROLS) with PRESS.

parlitz2004 §III-D and worden2007 §5.1: the candidate monomials of the teacher-forced regressors are ranked by
their error-reduction ratio and kept while the leave-one-out error falls (`select_terms`, the one FROLS
implementation of the package), and the coefficients are their least-squares solution.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import equinox as eqx
import numpy as np

from ..._constraints import unwrap
from ..._data._record import FrictionData
from ..._models.blackbox._polynomial import PolynomialNARX, Terms, evaluate_monomials, monomial_terms
from ..._models.blackbox._regressors import NARXRegressors
from ..._models.combine._sensor import SensorDrift
from ..._validation import is_real, nonnegative_int, positive_int
from ..linear._regressor_rows import teacher_forced_rows
from ..linear._term_selection import TermSelection, select_terms
from ..loop._solution import Solution


class PolynomialNARXSelection(eqx.Module):
    """What `identify_polynomial_narx` returns besides the model, as its `fj.Solution`'s typed `aux` (the fields read
    through: `solution.selection` is `solution.aux.selection`):

    - `selection`: the `TermSelection` of `select_terms` (ERR of each term, PRESS and RSS traces, ...); its
      `indices` index `candidates`.
    - `candidates`: every candidate monomial, as exponent tuples over the regressor vector.
    """

    selection: TermSelection
    candidates: Terms


def identify_polynomial_narx(
    data: Any,
    *,
    signals: Sequence[str] = ("dx", "v"),
    input_lags: int = 2,
    output_lags: int = 2,
    degree: int = 3,
    criterion: Literal["press", "err"] = "press",
    max_terms: int | None = None,
    intercept: bool = True,
    regressors: NARXRegressors | None = None,
    burn_in: int | None = None,
    drift: Literal["linear"] | float | None = None,
) -> Solution:
    """Identify a polynomial NARX model (`fj.PolynomialNARX`) from a record by FROLS term selection.

    1. Regressors: `x_k = [u_k, ..., u_{k-n_u}, F_{k-1}, ..., F_{k-n_y}]`, the input `signals` and the
       measured force (teacher forcing), each normalised by the record's mean and standard deviation
       (`NARXRegressors.from_data`), or the given `regressors`.
    2. Candidates: every monomial of `x_k` of total degree 1..`degree` (`fj.monomial_terms`), evaluated along
       the record: a `(T, M)` matrix, of which the first `burn_in` rows (whose lags reach before the record) are
       dropped.
    3. Selection (`fj.select_terms`): forward orthogonal least squares ranks the candidates by error-reduction
       ratio; with `criterion="press"` a term is added only while the leave-one-out error (PRESS) falls, with
       `"err"` until `max_terms` (or round-off).
    4. Coefficients: least squares of the normalised force on the selected monomials (and a constant).

    With `drift`, the force sensor's slow drift (`fj.SensorDrift`: `rate * t`, or the leaky
    `rate * tau * (1 - exp(-t / tau))`, t from the record's first sample) is a column of the regression from the
    start, never selected or dropped (`select_terms(fixed=)`), so the trend of the record does not bias the
    choice of terms; the model comes back wrapped in `fj.SensorDrift` with the estimated rate.

    The model minimises the one-step (equation) error; its free run may be refined by output error:
    `fj.fit(result.model, data, loss=fj.SimulationLoss())` (optionally wrapped in `fj.SensorDrift`).

    **Arguments:**

    - `data`: the training record, `fj.FrictionData`.
    - `signals`: the input signals (`"x"`, `"dx"`, `"v"`, `"a"`); default the displacement increment and velocity.
    - `input_lags`, `output_lags`: `n_u >= 0` (lags 0..n_u of each input), `n_y >= 0` (past forces 1..n_y).
    - `degree`: the largest total degree of a monomial, >= 1.
    - `criterion`: `"press"` (default: stop when PRESS no longer falls) or `"err"` (give `max_terms`).
    - `max_terms`: the most terms to select (default: all candidates).
    - `intercept`: a constant term from the start (default). With `False` the constant monomial is a candidate
      like the others (SysIdentPy's convention) and `theta0` is 0.
    - `regressors`: an `fj.NARXRegressors` to use as it is (its normalisation included) instead of
      `signals` / `input_lags` / `output_lags` and the record's normalisation.
    - `burn_in`: samples at the start of the record not used as equations; default `max(n_u, n_y)`.
    - `drift`: `None` (default: no sensor drift), `"linear"`, or the leaky integrator's time constant `tau` [s]
      (e.g. the record's duration).

    **Returns:** a `fj.Solution`: its `model` is the identified `PolynomialNARX` (its terms in the order they were
    selected), wrapped in `fj.SensorDrift` when a `drift` was identified with it; its `aux` a
    `PolynomialNARXSelection` (selection, candidates).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> rng = np.random.default_rng(0)
    >>> v = rng.standard_normal(400)
    >>> F = np.zeros(400)
    >>> for k in range(1, 400):
    ...     F[k] = 0.5 * v[k] + 0.7 * F[k - 1] - 0.2 * v[k] ** 2 * F[k - 1]
    >>> data = fj.FrictionData(fj.Motion.from_velocity(v, dt=1e-3), F)
    >>> regressors = fj.NARXRegressors(("v",), input_lags=0, output_lags=1)
    >>> result = fj.identify_polynomial_narx(data, regressors=regressors, degree=3)
    >>> result.model.describe(), [round(float(t), 6) for t in result.model.theta]
    (['v[k]', 'F[k-1]', 'v[k]^2*F[k-1]'], [0.5, 0.7, -0.2])
    ```
    """
    where = "identify_polynomial_narx"
    if not isinstance(data, FrictionData):
        raise TypeError(
            f"{where}: `data` must be one fj.FrictionData record, got {type(data).__name__}"
            + (
                " (join records end to end with fj.concatenate, or identify on each)."
                if isinstance(data, (list, tuple))
                else "."
            )
        )
    if regressors is None:
        regressors = NARXRegressors.from_data(data, signals, input_lags, output_lags)
    elif not isinstance(regressors, NARXRegressors):
        raise TypeError(f"{where}: `regressors` must be an fj.NARXRegressors or None, got {type(regressors).__name__}.")
    degree = positive_int(degree, "degree", where, hint="(the largest total degree of a monomial)")
    if not isinstance(intercept, bool):
        raise TypeError(f"{where}: `intercept` must be True or False, got {intercept!r}.")
    lag = max(regressors.input_lags, regressors.output_lags)
    burn_in = lag if burn_in is None else nonnegative_int(burn_in, "burn_in", where, hint="(samples)")
    candidates = monomial_terms(regressors.size, degree, constant=not intercept)
    wanted = len(candidates) if max_terms is None else min(int(max_terms), len(candidates))
    rows = data.length - burn_in
    if rows <= wanted + 1:
        raise ValueError(
            f"{where}: too few samples: {data.length} in the record, {rows} after the burn-in of {burn_in}, for up to "
            f"{wanted} terms (of {len(candidates)} candidates: {regressors.size} regressors, degree {degree}); "
            f"more than {wanted + 1} are needed. Pass a longer record, or lower `degree`, the lags or `max_terms`."
        )

    if drift is not None and drift != "linear" and not (is_real(drift) and drift > 0):
        raise ValueError(
            f"{where}: `drift` must be None, 'linear' or a positive time constant tau [s] (leaky drift), got {drift!r}."
        )
    template = PolynomialNARX(regressors, candidates, np.zeros(len(candidates)))
    template.check_inputs(data.motion)
    phi = np.asarray(teacher_forced_rows(regressors, data.motion.samples(regressors.requires), data.force), np.float64)
    matrix = evaluate_monomials(phi[burn_in:], candidates)
    scales = unwrap(regressors)
    force = np.asarray(data.force, np.float64)[burn_in:]
    target = (force - float(scales.output_mean)) / float(scales.output_scale)
    tau = None if drift in (None, "linear") else float(drift)  # type: ignore[arg-type]
    fixed = None
    if drift is not None:
        dt = np.broadcast_to(np.asarray(data.motion.samples(frozenset({"dt"})).dt, np.float64), (data.length,))
        t = np.concatenate([[0.0], np.cumsum(dt)[:-1]])  # SensorDrift's clock: 0 at the record's first sample
        column = t if tau is None else tau * -np.expm1(-t / tau)
        fixed = column[burn_in:] / float(scales.output_scale)
    selection = select_terms(matrix, target, criterion=criterion, max_terms=max_terms, intercept=intercept, fixed=fixed)
    terms = tuple(candidates[i] for i in selection.indices)
    model: PolynomialNARX | SensorDrift = PolynomialNARX(regressors, terms, selection.coefficients, selection.intercept)
    if drift is not None:
        model = SensorDrift(model, float(selection.fixed_coefficients[0]), tau)
    return Solution(
        model=model,
        message=f"{len(terms)} of {len(candidates)} candidate terms chosen by forward orthogonal regression "
        f"({criterion}); coefficients by least squares",
        aux=PolynomialNARXSelection(
            selection=selection,
            candidates=candidates,
        ),
    )
