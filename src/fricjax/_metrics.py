"""Error metrics of the friction-identification literature; all jittable and vmappable (reduce the last axis).

`nmse` is the papers' normalised MSE in percent (worden2007 eq. 1, parlitz2004 eq. 9): 100 means "as good as
predicting the mean", < 5 good, < 1 excellent.

Every metric scales before it squares (`scaled_std`, `_norm`: divide by the largest magnitude first), so forces of
1e200 N or 1e-200 N give the same scores as the record in newtons, instead of inf / 0 from overflowing squares.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike


def _pair(y: ArrayLike, yhat: ArrayLike) -> tuple[Array, Array]:
    y, yhat = jnp.asarray(y), jnp.asarray(yhat)
    if y.shape != yhat.shape:
        raise ValueError(f"metrics: `y` and `yhat` must have the same shape, got {y.shape} and {yhat.shape}.")
    return y, yhat


def scaled_std(y: ArrayLike, axis: int = -1) -> Array:
    """`std(y)` along `axis`, computed as `m * std(y / m)` with `m = max|y|`: no overflow of the squares for
    |y| ~ 1e200, no underflow for |y| ~ 1e-200 (0 for an all-zero `y`, as `jnp.std`). The normalisation of
    the losses and metrics."""
    y = jnp.asarray(y)
    m = _magnitude(y, axis)
    return jnp.squeeze(m, axis) * jnp.std(y / m, axis=axis)


def _magnitude(y: Array, axis: int) -> Array:
    """`max|y|` along `axis` (kept), or 1 where that is 0: the divisor that makes `y` of order one."""
    m = jnp.max(jnp.abs(y), axis=axis, keepdims=True) if y.size else jnp.ones_like(jnp.sum(y, axis, keepdims=True))
    return jnp.where(m > 0, m, jnp.ones_like(m))


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
