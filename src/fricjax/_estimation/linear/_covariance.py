"""The parameter covariance of least squares: `covariance(A, r)`, `parameter_std(A, r)`: `s^2 (A^T A)^+` with
`s^2 = ||r||^2 / (N - P)`, and its diagonal's square root; `A` is the regression matrix (or the Jacobian of the
residuals at a nonlinear optimum).

Computed from the SVD of the column-scaled `A`, with the kernel of `_lstsq` (its checks, column scaling and SVD).
NumPy inputs are solved in NumPy, in float64, without compilation; JAX inputs (or tracers) in JAX, jit-able.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..._smoothing import is_concrete
from ._lstsq import _as_arrays, _column_norms, _default_rcond, _matmul, _svd


def covariance(
    A: Float[ArrayLike, "N P"],
    residuals: Float[ArrayLike, "N"],
    dof: int | None = None,
    *,
    rcond: float | None = None,
) -> Any:
    """The least-squares parameter covariance `s^2 (A^T A)^+`, `s^2 = ||r||^2 / dof`, `dof = N - P` by default.

    For a linear regression `b ~ A x` with independent errors of equal variance, `A` is the regression matrix
    and `r = b - A x_hat` its residuals; for a nonlinear least-squares fit it is the Gauss-Newton approximation
    with `A = J`, the Jacobian `(N, P)` of the residual vector `r` (N residuals, P parameters) at the optimum.
    Units: `[x_i] [x_j]`, with `s` in the units of `r`.

    Computed from the SVD of the column-scaled `A_s = A D^-1` (`D = diag(||a_j||)`; physical parameters span many
    decades, e.g. a bristle stiffness of 1e8 N/m next to a Stribeck velocity of 1e-3 m/s):

        cov = s^2 D^-1 V diag(1 / s_i^2) V^T D^-1   over the singular values s_i >= rcond * s_max,

    which equals `s^2 (A^T A)^-1` when `A` has full column rank, without forming `A^T A` (whose condition number is
    the square of `A_s`'s). Directions below the cut-off contribute nothing (a pseudo-inverse): their parameters
    are not identifiable from these data, and their variances are not meaningful. A zero column gets variance 0.

    **Arguments:**

    - `A`: the regression matrix or residual Jacobian, shape `(N, P)`.
    - `residuals`: `r`, shape `(N,)`.
    - `dof`: degrees of freedom of `s^2`, default `N - P`; pass `N - P - q` when q further parameters (e.g. the
      nonlinear ones of a separable fit) were fitted to the same residuals. Must be positive.
    - `rcond`: relative singular-value cut-off, default `eps * max(N, P)`. (`sqrt(10 P eps)` reproduces the
      cut-off of `pinv(A_s^T A_s)`.)

    **Returns:** the `(P, P)` covariance matrix (NumPy for NumPy inputs, JAX for JAX inputs; jit-able).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> rng = np.random.default_rng(0)
    >>> A = np.column_stack([np.ones(400), np.linspace(-1.0, 1.0, 400)])
    >>> r = 0.1 * rng.standard_normal(400)                       # residuals with sigma = 0.1
    >>> cov = fj.covariance(A, r)
    >>> bool(np.allclose(cov, (r @ r / 398) * np.linalg.inv(A.T @ A)))
    True
    ```
    """
    matrix, r, xp = _as_arrays("covariance", A, residuals, "residuals")
    n, p = matrix.shape
    if r.ndim != 1:
        raise ValueError(f"covariance: `residuals` must be a vector of shape ({n},), got {r.shape}.")
    if dof is None:
        dof = n - p
    if is_concrete(dof) and not np.all(np.asarray(dof) > 0):
        raise ValueError(
            f"covariance: `dof` must be positive, got {dof!r} (N = {n} residuals, P = {p} parameters); fit "
            "fewer parameters or use more data."
        )
    cutoff = float(_default_rcond(matrix.shape, matrix.dtype, rcond))
    if xp is np:
        return _covariance(matrix, r, dof, cutoff, np)
    return _covariance_jax(matrix, r, jnp.asarray(dof, matrix.dtype), cutoff)


def _covariance(A: Any, r: Any, dof: Any, rcond: Any, xp: Any) -> Any:
    norms = _column_norms(A, xp)
    _, s, Vt, keep = _svd(A / norms, rcond, xp)
    safe = xp.where(keep, s, 1.0)
    inverse_gram = xp.where(keep, 1.0 / (safe * safe), 0.0)
    s2 = xp.sum(r * r) / dof
    return s2 * _matmul(xp)(Vt.T * inverse_gram, Vt) / (norms[:, None] * norms[None, :])


@eqx.filter_jit
def _covariance_jax(A: Array, r: Array, dof: Array, rcond: float) -> Array:
    return _covariance(A, r, dof, rcond, jnp)


def parameter_std(
    A: Float[ArrayLike, "N P"],
    residuals: Float[ArrayLike, "N"],
    dof: int | None = None,
    *,
    rcond: float | None = None,
) -> Any:
    """Standard deviations of least-squares estimates: `sqrt(diag(covariance(A, residuals, dof)))`.

    See `covariance` for the formula, `A` (regression matrix or residual Jacobian, `(N, P)`) and `dof`. Units:
    those of each parameter.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> A = np.column_stack([np.ones(4), [0.0, 1.0, 2.0, 3.0]])
    >>> fj.parameter_std(A, np.array([0.1, -0.1, -0.1, 0.1])).round(6).tolist()
    [0.118322, 0.063246]
    ```
    """
    cov = covariance(A, residuals, dof, rcond=rcond)
    xp = np if isinstance(cov, np.ndarray) else jnp
    return xp.sqrt(xp.clip(xp.diagonal(cov), 0.0, None))
