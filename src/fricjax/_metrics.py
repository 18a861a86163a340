"""Error metrics of the friction-identification literature; all jittable and vmappable (reduce the last axis).

`nmse` is the papers' normalised MSE in percent (worden2007 eq. 1, parlitz2004 eq. 9): 100 means "as good as
predicting the mean", < 5 good, < 1 excellent.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike


def _pair(y: ArrayLike, yhat: ArrayLike) -> tuple[Array, Array]:
    y, yhat = jnp.asarray(y), jnp.asarray(yhat)
    if y.shape != yhat.shape:
        raise ValueError(f"metrics: `y` and `yhat` must have the same shape, got {y.shape} and {yhat.shape}.")
    return y, yhat


def rmse(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Root-mean-square error `sqrt(mean((y - yhat)^2))`, in the units of y."""
    y, yhat = _pair(y, yhat)
    return jnp.sqrt(jnp.mean((y - yhat) ** 2, axis=-1))


def nmse(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Normalised MSE in percent: `100 * mean((y - yhat)^2) / var(y)` (worden2007 eq. 1)."""
    y, yhat = _pair(y, yhat)
    return 100.0 * jnp.mean((y - yhat) ** 2, axis=-1) / jnp.var(y, axis=-1)


def nrmse(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Normalised RMSE (a fraction): `rmse / std(y)`."""
    y, yhat = _pair(y, yhat)
    return rmse(y, yhat) / jnp.std(y, axis=-1)


def max_error(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Normalised maximum error `max|y - yhat| / std(y)` (worden2007 eq. 2, parlitz2004 eq. 10)."""
    y, yhat = _pair(y, yhat)
    return jnp.max(jnp.abs(y - yhat), axis=-1) / jnp.std(y, axis=-1)


def relative_error(y: ArrayLike, yhat: ArrayLike) -> Array:
    """Relative error in percent: `100 * ||y - yhat|| / ||y||` (the EMPS description's criterion)."""
    y, yhat = _pair(y, yhat)
    return 100.0 * jnp.linalg.norm(y - yhat, axis=-1) / jnp.linalg.norm(y, axis=-1)


def fit_percent(y: ArrayLike, yhat: ArrayLike) -> Array:
    """The system-identification FIT in percent: `100 * (1 - ||y - yhat|| / ||y - mean(y)||)`."""
    y, yhat = _pair(y, yhat)
    centred = y - jnp.mean(y, axis=-1, keepdims=True)
    return 100.0 * (1.0 - jnp.linalg.norm(y - yhat, axis=-1) / jnp.linalg.norm(centred, axis=-1))
