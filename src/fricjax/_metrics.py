"""Error metrics of the friction-identification literature; all jittable and vmappable (reduce the last axis).

`nmse` is the papers' normalised MSE in percent (worden2007 eq. 1, parlitz2004 eq. 9): 100 means "as good as
predicting the mean", < 5 good, < 1 excellent.

Every metric scales before it squares (`scaled_std`, `_norm`: divide by the largest magnitude first), so forces of
1e200 N or 1e-200 N give the same scores as the record in newtons, instead of inf / 0 from overflowing squares.
`numpy_std`, `numpy_rmse` and `numpy_nmse` do the same in NumPy, in float64 whatever `jax_enable_x64` says, for
the estimators that score their candidates on the host (kernel NARX, local models, record statistics).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike


def _pair(y: ArrayLike, yhat: ArrayLike) -> tuple[Array, Array]:
    y, yhat = jnp.asarray(y), jnp.asarray(yhat)
    if y.shape != yhat.shape:
        raise ValueError(f"metrics: `y` and `yhat` must have the same shape, got {y.shape} and {yhat.shape}.")
    return y, yhat


def scaled_std(y: ArrayLike, axis: int = -1) -> Array:
    """`std(y)` along `axis`, computed as `m * std(y / m)` with `m = max|y|`: no overflow of the squares for
    |y| ~ 1e200, no underflow for |y| ~ 1e-200 (0 for an all-zero `y`, as `jnp.std`). The normalisation of
    the losses and metrics. A NumPy array is measured in NumPy (no compilation), anything else in JAX."""
    xp: Any = np if isinstance(y, np.ndarray) else jnp
    values: Any = xp.asarray(y)
    m = _magnitude(values, axis, xp)
    return xp.squeeze(m, axis) * xp.std(values / m, axis=axis)


def _magnitude(y: Array, axis: int, xp: Any = jnp) -> Array:
    """`max|y|` along `axis` (kept), or 1 where that is 0: the divisor that makes `y` of order one."""
    m = xp.max(xp.abs(y), axis=axis, keepdims=True) if y.size else xp.ones_like(xp.sum(y, axis, keepdims=True))
    return xp.where(m > 0, m, xp.ones_like(m))


def _norm(x: Array) -> Array:
    """`||x||` over the last axis, scaled before squaring (no overflow / underflow)."""
    m = _magnitude(x, -1)
    return jnp.squeeze(m, -1) * jnp.linalg.norm(x / m, axis=-1)


def rmse(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Root-mean-square error `sqrt(mean((y - yhat)^2))`, in the units of y."""
    y, yhat = _pair(y, yhat)
    error = y - yhat
    m = _magnitude(error, -1)
    return jnp.squeeze(m, -1) * jnp.sqrt(jnp.mean((error / m) ** 2, axis=-1))


def nmse(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Normalised MSE in percent: `100 * mean((y - yhat)^2) / var(y)` (worden2007 eq. 1)."""
    y, yhat = _pair(y, yhat)
    m = _magnitude(y, -1)  # both scaled by max|y| before squaring
    return 100.0 * jnp.mean(((y - yhat) / m) ** 2, axis=-1) / jnp.var(y / m, axis=-1)


def nrmse(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Normalised RMSE (a fraction): `rmse / std(y)`."""
    y, yhat = _pair(y, yhat)
    return rmse(y, yhat) / scaled_std(y)


def max_error(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Normalised maximum error `max|y - yhat| / std(y)` (worden2007 eq. 2, parlitz2004 eq. 10)."""
    y, yhat = _pair(y, yhat)
    return jnp.max(jnp.abs(y - yhat), axis=-1) / scaled_std(y)


def relative_error(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Relative error in percent: `100 * ||y - yhat|| / ||y||` (the EMPS description's criterion)."""
    y, yhat = _pair(y, yhat)
    return 100.0 * _norm(y - yhat) / _norm(y)


def fit_percent(y: ArrayLike, yhat: ArrayLike) -> Array:
    """The system-identification FIT in percent: `100 * (1 - ||y - yhat|| / ||y - mean(y)||)`."""
    y, yhat = _pair(y, yhat)
    centred = y - jnp.mean(y, axis=-1, keepdims=True)
    return 100.0 * (1.0 - _norm(y - yhat) / _norm(centred))


def _numpy_magnitude(y: np.ndarray, axis: int | tuple[int, ...] | None) -> np.ndarray:
    """`max|y|` along `axis` (kept), or 1 where that is 0 or `y` is empty: `_magnitude` in NumPy."""
    if not y.size:
        return np.ones_like(np.sum(y, axis=axis, keepdims=True))
    m = np.max(np.abs(y), axis=axis, keepdims=True)
    return np.where(m > 0, m, 1.0)


def numpy_std(y: ArrayLike, axis: int | tuple[int, ...] | None = None) -> np.ndarray:
    """`np.std(y, axis)` in float64, scaled before squaring (`scaled_std` in NumPy): finite for |y| ~ 1e200,
    nonzero for |y| ~ 1e-200."""
    y = np.asarray(y, np.float64)
    m = _numpy_magnitude(y, axis)
    with np.errstate(invalid="ignore"):
        return np.squeeze(m, axis) * np.std(y / m, axis=axis)


def numpy_rmse(error: ArrayLike, axis: int | None = None) -> np.ndarray:
    """`sqrt(mean(error^2))` along `axis` in float64, scaled before squaring (`rmse` in NumPy)."""
    error = np.asarray(error, np.float64)
    m = _numpy_magnitude(error, axis)
    with np.errstate(invalid="ignore"):
        return np.squeeze(m, axis) * np.sqrt(np.mean((error / m) ** 2, axis=axis))


def numpy_nmse(y: ArrayLike, yhat: ArrayLike, axis: int = -1) -> np.ndarray:
    """`100 * mean((y - yhat)^2) / var(y)` [%] along `axis` in float64 (`nmse` in NumPy), both scaled by
    `max|y|` before squaring; `yhat` may hold several predictions of the one `y` (broadcast). A constant `y`
    divides by the smallest normal float instead of 0; a prediction that is not finite scores inf or NaN
    (silently: the callers map those to inf)."""
    y, yhat = np.asarray(y, np.float64), np.asarray(yhat, np.float64)
    m = _numpy_magnitude(y, axis)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        error = np.mean(((yhat - y) / m) ** 2, axis=axis)
        return 100.0 * error / np.maximum(np.var(y / m, axis=axis), np.finfo(np.float64).tiny)
