"""Forward orthogonal term selection: `select_terms(candidates, target)`, forward regression with orthogonal least
squares (FROLS: Billings 2013, ch. 3) ranking candidates by their error-reduction ratio, with the PRESS
(leave-one-out) statistic as selection and stopping rule (Chen, Hong, Harris & Sharkey 2004; worden2007 §7;
parlitz2004 §III-D).

It chooses the terms of polynomial and wavelet NARX models and the members of ensembles. `select_terms` is a
greedy loop on values and always runs in NumPy (float64); the chosen terms are refitted by `lstsq`.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float

from ..._smoothing import is_concrete
from ..._validation import positive_int
from ._lstsq import _as_arrays, lstsq


class TermSelection(NamedTuple):
    """What `select_terms` returns (NumPy, float64).

    - `indices`: the selected candidate columns, in the order they were selected.
    - `coefficients`: their least-squares coefficients (same order), refitted together (with the intercept).
    - `intercept`: the constant term (0.0 with `intercept=False`).
    - `err`: the error-reduction ratio of each selected term, `ERR_k = (q_k^T y)^2 / (y^T y)`; the intercept's own
      share is `1 - rss[0] / (y^T y)`, so `sum(err) = (rss[0] - rss[-1]) / (y^T y) <= 1`.
    - `press`: the PRESS statistic (leave-one-out squared error, units of y^2) of the base model (intercept only,
      or no term), then after each selected term: length `len(indices) + 1`.
    - `rss`: the residual sum of squares at the same steps.
    - `fixed_coefficients`: the coefficients of the `fixed` columns (in the model from the start), refitted
      with the selected terms; empty without them.
    """

    indices: tuple[int, ...]
    coefficients: np.ndarray
    intercept: float
    err: np.ndarray
    press: np.ndarray
    rss: np.ndarray
    fixed_coefficients: np.ndarray = np.zeros(0)


def select_terms(
    candidates: Float[ArrayLike, "N M"],
    target: Float[ArrayLike, "N"],
    *,
    criterion: Literal["press", "err"] = "press",
    max_terms: int | None = None,
    intercept: bool = True,
    fixed: Float[ArrayLike, "N F"] | None = None,
) -> TermSelection:
    """Choose regressors by forward orthogonal least squares (FROLS) with the PRESS statistic.

    The model is `y ~ intercept + sum_{k in S} theta_k phi_k` over a set S of the M candidate columns `phi_j`
    (monomials of lagged inputs and outputs for a polynomial NARX model, parlitz2004 §III-D eqs. 16-18 and
    worden2007 §5.1; the members' simulated forces for an ensemble, worden2007 §7). Each step orthogonalises
    every remaining candidate against the terms chosen so far (modified Gram-Schmidt, repeated once against the
    whole basis so that orthogonality holds to round-off),

        w_j = phi_j - Q Q^T phi_j,   q_j = w_j / ||w_j||,   g_j = q_j^T e,

    with `Q` the orthonormal basis of the chosen terms (and of the constant) and `e` the current residual, and
    scores the model with `q_j` added (Billings 2013, *Nonlinear System Identification*, ch. 3):

    - `"err"`: the error-reduction ratio `ERR_j = g_j^2 / (y^T y)` (`g_j^2 w_j^T w_j / (y^T y)` in Billings'
      unnormalised form), i.e. the largest drop of the residual sum of squares;
    - `"press"`: the leave-one-out error `PRESS = sum_t (e_t - q_jt g_j)^2 / (1 - h_t - q_jt^2)^2`, with the
      leverages `h_t = sum_k q_kt^2` of the chosen basis (Chen, Hong, Harris & Sharkey 2004; worden2007 §7).

    The best candidate is added. Selection stops when no candidate lowers the criterion by more than round-off
    (`100 eps` times its base value), at `max_terms`, or when all are in; a candidate already spanned by the
    chosen ones (`||w_j|| <= sqrt(eps) ||phi_j||`: a copy, a zero or, with the intercept, a constant column) is
    never added. PRESS is a cross-validation error, so it stops by itself once new terms only fit noise; ERR
    (the classical FROLS ranking) stops only at round-off, so give it `max_terms` (or read `press`, which is
    reported for every step whatever the criterion, and cut where it is least).

    **Arguments:**

    - `candidates`: the candidate regressors, shape `(N, M)` (N samples).
    - `target`: the output `y`, shape `(N,)`.
    - `criterion`: `"press"` (default) or `"err"`.
    - `max_terms`: the most terms to select (default: M).
    - `intercept`: include a constant term from the start (default True); with False the base model is empty
      and a constant column among the candidates competes like any other.
    - `fixed`: columns in the model from the start, shape `(N, F)` (e.g. a sensor drift): never selected or
      dropped, their coefficients refitted with the selected terms (`TermSelection.fixed_coefficients`).

    **Returns:** a `TermSelection(indices, coefficients, intercept, err, press, rss, fixed_coefficients)`. Runs in
    NumPy (float64); candidates as columns cost `O(N M)` memory and `O(N M k)` time per step with k terms chosen.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> rng = np.random.default_rng(0)
    >>> phi = rng.standard_normal((300, 8))                       # 8 candidate regressors
    >>> y = 1.0 + 2.0 * phi[:, 5] - 0.5 * phi[:, 2] + 0.01 * rng.standard_normal(300)
    >>> selection = fj.select_terms(phi, y)
    >>> selection.indices, selection.coefficients.round(2).tolist(), round(selection.intercept, 2)
    ((5, 2), [2.0, -0.5], 1.0)
    ```
    """
    if not (is_concrete(candidates) and is_concrete(target)):
        raise ValueError("select_terms: selection is a greedy loop on values; call it outside jit / vmap.")
    X, y, _ = _as_arrays("select_terms", np.asarray(candidates), np.asarray(target), "target", "candidates")
    if y.ndim != 1:
        raise ValueError(f"select_terms: `target` must be a vector of shape ({X.shape[0]},), got {y.shape}.")
    if criterion not in ("press", "err"):
        raise ValueError(f"select_terms: `criterion` must be 'press' or 'err', got {criterion!r}.")
    n, m = X.shape
    if max_terms is None:
        max_terms = m
    max_terms = positive_int(max_terms, "max_terms", "select_terms", hint="or None")
    if not isinstance(intercept, bool):
        raise TypeError(f"select_terms: `intercept` must be True or False, got {intercept!r}.")

    eps = np.finfo(np.float64).eps
    forced = np.zeros((n, 0)) if fixed is None else np.asarray(fixed, dtype=np.float64)
    if forced.ndim == 1:
        forced = forced[:, None]
    if forced.ndim != 2 or forced.shape[0] != n or not np.all(np.isfinite(forced)):
        raise ValueError(
            f"select_terms: `fixed` must be finite columns of shape ({n}, F) (one row per sample), got {forced.shape}."
        )
    if intercept:
        basis = [np.full(n, 1.0 / np.sqrt(n))]
        residual, leverage, remainders = y - y.mean(), np.full(n, 1.0 / n), X - X.mean(axis=0)
    else:
        basis, residual, leverage, remainders = [], y.copy(), np.zeros(n), X.copy()
    for column in forced.T:  # the fixed columns join the base model, orthogonalised like chosen terms
        w = column - (np.column_stack(basis) @ (np.column_stack(basis).T @ column) if basis else 0.0)
        if np.linalg.norm(w) <= np.sqrt(eps) * max(np.linalg.norm(column), np.finfo(float).tiny):
            raise ValueError("select_terms: a `fixed` column is spanned by the others (or the intercept); drop it.")
        q = w / np.linalg.norm(w)
        basis.append(q)
        residual = residual - q * (q @ residual)
        leverage = leverage + q**2
        remainders = remainders - np.outer(q, q @ remainders)
    sizes = np.linalg.norm(X, axis=0)
    available = sizes > 0
    yy = float(y @ y)
    press, rss = [_press(residual, leverage)], [float(residual @ residual)]
    history = press if criterion == "press" else rss
    floor = 100.0 * eps * history[0]
    chosen: list[int] = []
    err: list[float] = []
    block = max(1, 2**20 // n)  # candidates scored per pass: bounds the (N, block) temporaries
    while len(chosen) < max_terms:
        Q = np.column_stack(basis) if basis else np.zeros((n, 0))
        best, best_value, best_q = -1, np.inf, None
        for start in range(0, m, block):
            cols = slice(start, min(start + block, m))
            W = remainders[:, cols]
            W = W - Q @ (Q.T @ W)  # the second Gram-Schmidt pass
            norms = np.linalg.norm(W, axis=0)
            ok = available[cols] & (norms > np.sqrt(eps) * sizes[cols])
            if not ok.any():
                continue
            Qc = W / np.where(ok, norms, 1.0)
            E = residual[:, None] - Qc * (residual @ Qc)
            if criterion == "err":
                values = np.sum(E * E, axis=0)
            else:
                values = _press_columns(E, leverage[:, None] + Qc * Qc)
            values = np.where(ok, values, np.inf)
            i = int(np.argmin(values))
            if values[i] < best_value:
                best, best_value, best_q = start + i, float(values[i]), Qc[:, i].copy()
        if best_q is None or not best_value < history[-1] - floor:
            break
        g = float(best_q @ residual)
        chosen.append(best)
        available[best] = False
        basis.append(best_q)
        residual = residual - best_q * g
        leverage = leverage + best_q**2
        remainders = remainders - np.outer(best_q, best_q @ remainders)
        err.append(g * g / yy if yy > 0 else 0.0)
        press.append(_press(residual, leverage))
        rss.append(float(residual @ residual))

    coefficients, constant = _refit(np.column_stack([X[:, chosen], forced]), y, intercept)
    return TermSelection(
        indices=tuple(chosen),
        coefficients=coefficients[: len(chosen)],
        intercept=constant,
        err=np.asarray(err, dtype=np.float64),
        press=np.asarray(press),
        rss=np.asarray(rss),
        fixed_coefficients=coefficients[len(chosen) :],
    )


def _press_columns(E: np.ndarray, leverage: np.ndarray) -> np.ndarray:
    """PRESS of each column of residuals `E` with leverages `leverage` (inf where a sample has no leave-one-out
    information: 1 - h <= 1e-12, a sample fitted exactly by its own regressor)."""
    denominator = 1.0 - leverage
    degenerate = np.any(denominator <= 1e-12, axis=0)
    values = np.sum((E / np.where(denominator > 1e-12, denominator, 1.0)) ** 2, axis=0)
    return np.where(degenerate, np.inf, values)


def _press(residual: np.ndarray, leverage: np.ndarray) -> float:
    return float(_press_columns(residual[:, None], leverage[:, None])[0])


def _refit(X: np.ndarray, y: np.ndarray, intercept: bool) -> tuple[np.ndarray, float]:
    """Least-squares coefficients of the selected columns (centred when there is an intercept)."""
    if X.shape[1] == 0:
        return np.zeros(0), float(y.mean()) if intercept else 0.0
    if not intercept:
        return lstsq(X, y).x, 0.0
    mean_x, mean_y = X.mean(axis=0), y.mean()
    coefficients = lstsq(X - mean_x, y - mean_y).x
    return coefficients, float(mean_y - mean_x @ coefficients)
