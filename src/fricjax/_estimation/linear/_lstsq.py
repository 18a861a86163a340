"""Linear least squares: `lstsq(A, b)`, `min_x ||A x - b||^2 (+ ridge)` on column-scaled `A` by a truncated SVD,
optionally with `x_j >= 0` on a mask of physically signed parameters (Lawson-Hanson active set); differentiable in
`A`, `b`.

The one linear-algebra kernel that the ensembles, the EMPS inverse dynamic model, separable least squares,
Gauss-Newton standard deviations (`_covariance`) and (polynomial NARX) term selection (`_term_selection`) share:
its dispatch, checks, column scaling and truncated / damped SVD solve serve those modules too.

Arrays: the regression matrix `A` has N rows (samples, or residuals) and P columns (parameters). NumPy inputs are
solved in NumPy, in float64, without compilation; JAX inputs (or tracers) in JAX, in their own dtype, jit-, vmap-
and grad-able.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, ArrayLike, Bool, Float

from ..._lapack_threads import thin_svd
from ..._smoothing import is_concrete

# ----------------------------------------------------------------------------------------------------------------
# shared pieces: dispatch, checks, column scaling, the truncated / damped SVD solve
# ----------------------------------------------------------------------------------------------------------------


def _is_jax(*values: Any) -> bool:
    """JAX path when any input is a JAX array or a tracer (tracers are `jax.Array`s), else NumPy."""
    return any(isinstance(v, jax.Array) for v in values)


def _matmul(xp: Any) -> Callable[[Any, Any], Any]:
    # full float32 / float64 accuracy on accelerators too (the default may use reduced-precision passes)
    return np.matmul if xp is np else functools.partial(jnp.matmul, precision=jax.lax.Precision.HIGHEST)


def _as_arrays(where: str, A: Any, b: Any, b_name: str, a_name: str = "A") -> tuple[Any, Any, Any]:
    """`A` (N, P) and `b` (N,) / (N, K) as floating arrays of one dtype, plus the namespace that solves them."""
    xp = jnp if _is_jax(A, b) else np
    A, b = xp.asarray(A), xp.asarray(b)
    if xp is np:
        dtype = np.result_type(A, b, np.float64)
    else:
        dtype = jnp.result_type(A, b)
        dtype = dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)
    A, b = A.astype(dtype), b.astype(dtype)
    if A.ndim != 2 or 0 in A.shape:
        raise ValueError(
            f"{where}: `{a_name}` must be a non-empty 2-D array (N samples, P columns), got shape {A.shape}."
        )
    if b.ndim not in (1, 2) or b.shape[0] != A.shape[0]:
        raise ValueError(
            f"{where}: `{b_name}` must have shape ({A.shape[0]},) (one entry per row of `{a_name}`) or "
            f"({A.shape[0]}, K), "
            f"got {b.shape}."
        )
    for name, value in ((a_name, A), (b_name, b)):
        if is_concrete(value) and not bool(np.all(np.isfinite(np.asarray(value)))):
            raise ValueError(f"{where}: `{name}` contains NaN or inf; remove or repair those samples first.")
    return A, b, xp


def _default_rcond(shape: tuple[int, ...], dtype: Any, rcond: Any) -> Any:
    """`rcond` or the LAPACK / NumPy default `eps * max(N, P)`."""
    return float(np.finfo(dtype).eps) * max(shape) if rcond is None else rcond


def _column_norms(A: Any, xp: Any) -> Any:
    """Euclidean norms of the columns of `A`, 1 for zero columns (a double `where`: no NaN gradient at 0)."""
    squares = xp.sum(A * A, axis=0)
    positive = squares > 0
    return xp.where(positive, xp.sqrt(xp.where(positive, squares, 1.0)), 1.0)


def _svd(As: Any, rcond: Any, xp: Any) -> tuple[Any, Any, Any, Any]:
    """Thin SVD `As = U diag(s) Vt` and the mask of the singular values kept: `s > 0` and `s >= rcond * s_max`.
    JAX: LAPACK's, one matrix per call however the solve is vmapped (`thin_svd`: multi-start fits with separable
    parameters vmap it, and batched LAPACK calls can deadlock XLA's CPU thread pool)."""
    U, s, Vt = thin_svd(As) if xp is jnp else _svd_numpy(As)
    keep = (s > 0) & (s >= rcond * s[0])
    return U, s, Vt, keep


_CHOLESKY_QR2_MAX_COND = 1e6


def _svd_numpy(As: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thin SVD of a tall `As`, through CholeskyQR2 when `cond(As) <= 1e6`, else LAPACK's.

    CholeskyQR2 (Yamamoto, Nakatsukasa, Yanagisawa & Fukaya 2015): `R1 = chol(As^T As)`, `Q1 = As R1^-1`, once
    more on `Q1`, gives `As = Q R` with `Q` orthonormal and `Q R - As` both at round-off as long as
    `cond(As) << eps^-1/2 ~ 1e8`, i.e. as accurate as Householder QR; then `R = U_r S V^T` (P x P). It needs
    only matrix products, which stay fast when LAPACK's threaded SVD of a tall matrix does not (many small
    solves, e.g. a separable least-squares search, on a busy machine: 0.2 ms against 2-4 ms for 2480 x 6).
    """
    n, p = As.shape
    if n >= p:
        try:
            R1 = np.linalg.cholesky(As.T @ As).T
            Q1 = As @ np.linalg.inv(R1)
            R2 = np.linalg.cholesky(Q1.T @ Q1).T
            Ur, s, Vt = np.linalg.svd(R2 @ R1)
            if np.all(np.isfinite(s)) and s[-1] > 0 and s[0] <= _CHOLESKY_QR2_MAX_COND * s[-1]:
                return Q1 @ (np.linalg.inv(R2) @ Ur), s, Vt
        except np.linalg.LinAlgError:  # not numerically positive definite: rank deficient or nearly so
            pass
    return np.linalg.svd(As, full_matrices=False)


def _filter_solve(U: Any, s: Any, Vt: Any, keep: Any, b: Any, ridge: Any, xp: Any) -> Any:
    """`z = V diag(phi(s)) U^T b`, `phi = s / (s^2 + ridge)` on the kept singular values, 0 on the others."""
    mm = _matmul(xp)
    safe = xp.where(keep, s, 1.0)
    phi = xp.where(keep, safe / (safe * safe + ridge), 0.0)
    return mm(Vt.T, phi[:, None] * mm(U.T, b))


@jax.custom_jvp
def _solve_scaled(As: Array, b: Array, ridge: Array, rcond: Array) -> Array:
    """The truncated, damped SVD solve of the column-scaled problem (JAX), with the derivative below.

    `jnp.linalg.lstsq` differentiates through the SVD, whose derivative divides by `s_i^2 - s_j^2`: NaN for
    repeated singular values, which column scaling makes common (orthogonal columns of equal norm). The
    least-squares solution itself is smooth there, so its derivative is written out instead.
    """
    return _filter_solve(*_svd(As, rcond, jnp), b, ridge, jnp)


@_solve_scaled.defjvp
def _solve_scaled_jvp(primals: tuple[Array, ...], tangents: tuple[Array, ...]) -> tuple[Array, Array]:
    # z = (A^T A + l I)^+ A^T b on the kept singular directions. Differentiating A^T A z + l z = A^T b:
    #   dz = F (dA^T r - A^T dA z + A^T db - dl z) + (I - V_k V_k^T) dA^T (A_k^+)^T z,  r = b - A z,
    # F = V_k diag(1 / (s^2 + l)) V_k^T. The last term (Golub & Pereyra 1973) moves the minimum-norm solution
    # when A is rank deficient (or P > N); it is zero when A has full column rank.
    As, b, ridge, rcond = primals
    dA, db, dridge, _ = tangents
    mm = _matmul(jnp)
    U, s, Vt, keep = _svd(As, rcond, jnp)
    z = _filter_solve(U, s, Vt, keep, b, ridge, jnp)
    r = b - mm(As, z)
    safe = jnp.where(keep, s, 1.0)
    inverse_gram = jnp.where(keep, 1.0 / (safe * safe + ridge), 0.0)
    rhs = mm(dA.T, r) - mm(As.T, mm(dA, z)) + mm(As.T, db) - dridge * z
    dz = mm(Vt.T, inverse_gram[:, None] * mm(Vt, rhs))
    Vk = jnp.where(keep[:, None], Vt, 0.0)
    dual = mm(U, jnp.where(keep, 1.0 / safe, 0.0)[:, None] * mm(Vt, z))  # (A_k^+)^T z
    null = mm(dA.T, dual)
    dz = dz + null - mm(Vk.T, mm(Vk, null))
    return z, dz


# ----------------------------------------------------------------------------------------------------------------
# lstsq
# ----------------------------------------------------------------------------------------------------------------


class LstsqResult(NamedTuple):
    """What `lstsq` returns (NumPy arrays and Python numbers on the NumPy path, JAX arrays on the JAX path).

    - `x`: the solution, shape `(P,)` (or `(P, K)` for `b` of shape `(N, K)`), in the units of `b` / column.
    - `residual`: `b - A x`, shape of `b`.
    - `rank`: the numerical rank of the column-scaled `A` (singular values kept by `rcond`).
    - `cond`: the 2-norm condition number `s_max / s_min` of the column-scaled `A` (`inf` when singular).
    """

    x: Any
    residual: Any
    rank: Any
    cond: Any


def lstsq(
    A: Float[ArrayLike, "N P"],
    b: Float[ArrayLike, "N"] | Float[ArrayLike, "N K"],
    *,
    ridge: float | Float[ArrayLike, ""] = 0.0,
    nonnegative: bool | Bool[ArrayLike, "P"] | None = None,
    rcond: float | None = None,
) -> LstsqResult:
    """Linear least squares `min_x ||A x - b||^2 + ridge * sum_j ||a_j||^2 x_j^2`, optionally with `x_j >= 0`.

    **Method.** The columns `a_j` of `A` are scaled to unit norm, `A_s = A D^-1`, `D = diag(||a_j||)` (a regressor
    in newtons and one in newton-seconds per metre weigh alike; zero columns are left as they are and get
    `x_j = 0`), and the scaled problem is solved by a thin SVD `A_s = U diag(s) V^T`:

        z = V diag(s / (s^2 + ridge)) U^T b   over the s_i >= rcond * s_max,   x = D^-1 z.

    Singular values below `rcond * s_max` are dropped (truncated SVD: the minimum-norm solution of a rank-deficient
    problem, as `numpy.linalg.lstsq`); `ridge >= 0` is Tikhonov damping in the scaled coordinates, so it is
    dimensionless and independent of each parameter's units (e.g. `1e-12`: a guard against exact singularity that
    leaves well-posed solutions unchanged to ~1e-12). The SVD, not the normal equations, keeps the error at
    `eps * cond(A_s)` instead of `eps * cond(A_s)^2`. (On the NumPy path, when `cond(A_s) <= 1e6`, the SVD is
    taken of the triangular factor of a CholeskyQR2 factorisation, as accurate and faster for the many small
    solves of a separable least-squares search.)

    **Bounds.** `nonnegative` (`True` for all parameters, or a boolean mask of shape `(P,)`) constrains the
    marked parameters to `x_j >= 0` (stiffnesses, masses, friction amplitudes); the others stay free. The active
    set is found by the Lawson-Hanson algorithm (Lawson & Hanson 1974, ch. 23) on the scaled problem: on the
    NumPy path by `scipy.optimize.nnls` after the free columns are projected out; on the JAX path by a
    Lawson-Hanson loop in `lax.while_loop` (at most `3 P` iterations, jit- and vmap-able). The solution is then
    the (unconstrained) solve above on the final free set, with the bound parameters at 0.

    **Derivatives** (JAX path) with respect to `A`, `b` and `ridge` are written out, not traced through the
    SVD: exact where `A` has full column rank, else those of the minimum-norm solution at constant rank
    (Golub & Pereyra 1973). With bounds, the active set is held fixed (the derivative of the solution on the
    free set). Value checks (finite inputs) run only outside `jit`.

    **Arguments:**

    - `A`: the regression matrix, shape `(N, P)` (N samples, P parameters).
    - `b`: the target, shape `(N,)`, or `(N, K)` for K right-hand sides (not with `nonnegative`).
    - `ridge`: damping >= 0 (dimensionless, relative to unit-norm columns); default 0.
    - `nonnegative`: `None` / `False` (no bounds), `True` (all `x >= 0`) or a boolean mask `(P,)`.
    - `rcond`: relative cut-off for small singular values of the scaled `A`; default `eps * max(N, P)` (as
      `numpy.linalg.lstsq` and `jnp.linalg.lstsq`). A Python float.

    **Returns:** an `LstsqResult(x, residual, rank, cond)`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> v = np.linspace(-0.1, 0.1, 41)                          # velocity [m/s]
    >>> A = np.column_stack([np.sign(v), v])                    # Coulomb [N] and viscous [N s/m] regressors
    >>> force = 20.0 * np.sign(v) + 200.0 * v
    >>> fj.lstsq(A, force).x.round(6).tolist()
    [20.0, 200.0]
    >>> A = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    >>> b = np.array([2.0, 1.0, -1.0])
    >>> fj.lstsq(A, b).x.round(6).tolist(), fj.lstsq(A, b, nonnegative=[False, True]).x.round(6).tolist()
    ([1.5, -1.0], [1.5, 0.0])
    ```
    """
    matrix, rhs, xp = _as_arrays("lstsq", A, b, "b")
    mask = _nonnegative_mask(nonnegative, matrix.shape[1], rhs)
    if is_concrete(ridge) and not (np.ndim(ridge) == 0 and np.isfinite(ridge) and np.asarray(ridge) >= 0):
        raise ValueError(f"lstsq: `ridge` must be a finite scalar >= 0, got {ridge!r}.")
    if rcond is not None and not (isinstance(rcond, (int, float)) and np.isfinite(rcond)):
        raise ValueError(f"lstsq: `rcond` must be a finite Python float (or None), got {rcond!r}.")
    cutoff = float(_default_rcond(matrix.shape, matrix.dtype, rcond))
    if xp is np:
        return _lstsq_numpy(matrix, rhs, float(np.asarray(ridge)), cutoff, mask)
    return _lstsq_jax(matrix, rhs, jnp.asarray(ridge, matrix.dtype), cutoff, mask)


def _nonnegative_mask(nonnegative: Any, p: int, b: Any) -> np.ndarray | None:
    if nonnegative is None or nonnegative is False:
        return None
    if nonnegative is True:
        mask = np.ones(p, bool)
    else:
        if not is_concrete(nonnegative):
            raise ValueError("lstsq: `nonnegative` must be a concrete boolean mask (it selects the algorithm).")
        mask = np.asarray(nonnegative)
        if mask.dtype != np.bool_ or mask.shape != (p,):
            raise ValueError(
                f"lstsq: `nonnegative` must be True, None or a boolean mask of shape ({p},) (one entry per column "
                f"of `A`), got {mask.dtype} array of shape {mask.shape}."
            )
    if b.ndim != 1:
        raise ValueError(
            f"lstsq: bounds (`nonnegative`) need a single right-hand side `b` of shape (N,), got {b.shape}."
        )
    return mask if mask.any() else None


def _lstsq_numpy(A: np.ndarray, b: np.ndarray, ridge: float, rcond: float, mask: np.ndarray | None) -> LstsqResult:
    norms = _column_norms(A, np)
    As = A / norms
    U, s, Vt, keep = _svd(As, rcond, np)
    b2 = b.reshape(b.shape[0], -1)
    if mask is None:
        z = _filter_solve(U, s, Vt, keep, b2, ridge, np)
    else:
        free = _passive_set_numpy(As, b, ridge, rcond, mask)
        z = _filter_solve(*_svd(As * free, rcond, np), b2, ridge, np)
        z[mask, 0] = np.maximum(z[mask, 0], 0.0)
    x = (z / norms[:, None]).reshape((A.shape[1], *b.shape[1:]))
    with np.errstate(over="ignore"):  # a singular value near the smallest double: the condition number is inf
        cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    return LstsqResult(x=x, residual=b - A @ x, rank=int(keep.sum()), cond=cond)


def _passive_set_numpy(As: np.ndarray, b: np.ndarray, ridge: float, rcond: float, mask: np.ndarray) -> np.ndarray:
    """Lawson-Hanson by `scipy.optimize.nnls`: the free columns are projected out (`x_free` is the least-squares
    value for any `x_bound`), the ridge is appended as rows `sqrt(ridge) I`. Returns the final free set."""
    p = As.shape[1]
    if ridge > 0:
        As = np.vstack([As, np.sqrt(ridge) * np.eye(p)])
        b = np.concatenate([b, np.zeros(p)])
    bound, rhs = As[:, mask], b
    if not mask.all():
        F = As[:, ~mask]
        coef = _filter_solve(*_svd(F, rcond, np), np.column_stack([bound, b]), 0.0, np)
        bound, rhs = bound - F @ coef[:, :-1], b - F @ coef[:, -1]
    x_bound, _ = scipy.optimize.nnls(bound, rhs)
    free = ~mask
    free[mask] = x_bound > 0
    return free


@eqx.filter_jit
def _lstsq_jax(A: Array, b: Array, ridge: Array, rcond: float, mask: np.ndarray | None) -> LstsqResult:
    norms = _column_norms(A, jnp)
    As = A / norms
    U, s, Vt, keep = _svd(As, rcond, jnp)
    b2 = b.reshape(b.shape[0], -1)
    rcond_array = jnp.asarray(rcond, A.dtype)
    if mask is None:
        z = _solve_scaled(As, b2, ridge, rcond_array)
    else:
        bound = jnp.asarray(mask)
        R, c = s[:, None] * Vt, jax.lax.stop_gradient(_matmul(jnp)(U.T, b))  # ||A_s z - b|| = ||R z - c|| + const
        # dual feasibility tolerance, as LAPACK-style cut-offs: round-off of A_s^T r is ~ eps max(N, P) ||b||
        tol = 10.0 * jnp.finfo(A.dtype).eps * max(A.shape) * jnp.linalg.norm(jax.lax.stop_gradient(b))
        free = _passive_set_jax(jax.lax.stop_gradient(R), c, jax.lax.stop_gradient(ridge), rcond_array, bound, tol)
        z = _solve_scaled(As * free, b2, ridge, rcond_array)
        z = jnp.where(bound[:, None], jnp.maximum(z, 0.0), z)
    x = (z / norms[:, None]).reshape((A.shape[1], *b.shape[1:]))
    cond = jnp.where(s[-1] > 0, s[0] / jnp.where(s[-1] > 0, s[-1], 1.0), jnp.inf)
    return LstsqResult(x=x, residual=b - _matmul(jnp)(A, x), rank=jnp.sum(keep), cond=cond)


def _passive_set_jax(R: Array, c: Array, ridge: Array, rcond: Array, bound: Array, tol: Array) -> Array:
    """Lawson-Hanson active set for `min ||R z - c||^2 + ridge ||z||^2`, `z_j >= 0` where `bound`: the free set.

    Outer loop: move the bound parameter with the largest positive dual `w = R^T (c - R z) - ridge z` into the
    free set. Inner loop: solve on the free set; while that solution breaks a bound, step from the current
    feasible point towards it as far as feasibility allows and return the parameters that reach 0 to the bound
    set. At most `3 P` iterations in all (as `scipy.optimize.nnls`).
    """
    p = R.shape[1]
    mm = _matmul(jnp)
    max_iter = 3 * p

    def solve_on(free: Array) -> Array:
        return _filter_solve(*_svd(R * free, rcond, jnp), c[:, None], ridge, jnp)[:, 0]

    def dual(z: Array) -> Array:
        return mm(R.T, c - mm(R, z)) - ridge * z

    def inner_cond(carry: tuple[Array, Array, Array, Array]) -> Array:
        _, z, free, it = carry
        return jnp.any(bound & free & (z <= 0)) & (it < max_iter)

    def inner_body(carry: tuple[Array, Array, Array, Array]) -> tuple[Array, Array, Array, Array]:
        x, z, free, it = carry
        broken = bound & free & (z <= 0)
        gap = x - z  # > 0 where broken, except 0 for a parameter already at its bound (x = z = 0): step 0
        step = jnp.where(broken, x / jnp.where(broken & (gap > 0), gap, 1.0), jnp.inf)
        first = jnp.argmin(step)
        x = x + step[first] * (z - x)
        leave = bound & free & ((x <= 0) | (jnp.arange(p) == first))
        x = jnp.where(leave, 0.0, x)
        free = free & ~leave
        return x, solve_on(free), free, it + 1

    def outer_cond(carry: tuple[Array, Array, Array]) -> Array:
        x, free, it = carry
        return jnp.any(bound & ~free & (dual(x) > tol)) & (it < max_iter)

    def outer_body(carry: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        x, free, it = carry
        entering = jnp.argmax(jnp.where(bound & ~free, dual(x), -jnp.inf))
        free = free.at[entering].set(True)
        _, z, free, it = jax.lax.while_loop(inner_cond, inner_body, (x, solve_on(free), free, it + 1))
        return z, free, it

    free0 = ~bound
    _, free, _ = jax.lax.while_loop(outer_cond, outer_body, (solve_on(free0), free0, jnp.asarray(0)))
    return free
