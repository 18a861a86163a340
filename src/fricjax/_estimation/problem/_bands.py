"""Confidence bands of a simulated output from the Gauss-Newton covariance of the fitted parameters (MATLAB's
`sim` with the parameter covariance, `simsd`): the first-order propagation `var F_hat(t) = s(t)^T C s(t)`, `s(t)`
the sensitivity of the simulated force to the parameters and `C` their covariance on the training record."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ..._constraints import trainable_filter, unwrap
from ..._data._record import FrictionData
from ..._inputs import Motion
from ..._simulate import simulate
from ..linear._covariance import covariance
from ._problem import physical_spec


class PredictionBand(eqx.Module):
    """A simulated force with its confidence band: `prediction` [N] (T,), `half_width` [N] (T,) (the band is
    `prediction +- half_width`), `std` [N] (T,) the standard deviation of the prediction from the parameters'
    uncertainty, `level` the band's two-sided confidence level, `parameter_std` the standard deviations of the
    parameters the band propagates (flat, in the order of `fj.unwrap(model)`'s trained leaves)."""

    prediction: np.ndarray
    half_width: np.ndarray
    std: np.ndarray
    level: float
    parameter_std: np.ndarray

    @property
    def lower(self) -> np.ndarray:
        return self.prediction - self.half_width

    @property
    def upper(self) -> np.ndarray:
        return self.prediction + self.half_width


def prediction_band(model: Any, motion: Motion | FrictionData, training: FrictionData, *, level: float = 0.99) -> Any:
    """The free-run prediction of `model` on `motion` (a `fj.Motion`, or a record whose motion is used) with a
    confidence band from the uncertainty of its parameters: their Gauss-Newton covariance on the `training` record
    (`s^2 (J^T J)^+`, J the Jacobian of the simulated force on `training` with respect to the trained physical
    parameters, `s^2` the residual variance; `fj.covariance`), propagated to first order through the simulation
    (`std(t)^2 = s(t)^T C s(t)`, `s(t) = dF_hat(t) / d theta`). The band is `prediction +- z std` with `z` the normal
    quantile of `level` (0.99: 2.58). Derivatives are those of the model as given: pass it in smooth mode, as fitted
    (an exact model's switching has no derivative). `fj.Fixed` parameters are not uncertain.

    **Returns:** a `fj.PredictionBand` (`prediction`, `half_width`, `std`, `lower`, `upper`, `parameter_std`).

    The band is the parameters' share of the uncertainty (the model class assumed right); the measurement noise and
    the model's error are not in it, so on a new record the measured force may well lie outside it.
    """
    from scipy.stats import norm

    if not 0 < float(level) < 1:
        raise ValueError(f"prediction_band: `level` must be in (0, 1), e.g. 0.99; got {level!r}.")
    if not isinstance(training, FrictionData):
        raise TypeError(
            "prediction_band: `training` must be the fj.FrictionData the model was fitted on, got "
            f"{type(training).__name__}."
        )
    target = motion.motion if isinstance(motion, FrictionData) else motion
    physical = unwrap(model)
    params, rest = eqx.partition(physical, physical_spec(trainable_filter(model)))
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    if flat.size == 0:
        raise ValueError("prediction_band: the model has no trained parameters (every one is fj.Fixed): no band.")

    def force(theta: jax.Array, on: Motion) -> jax.Array:
        return simulate(eqx.combine(unravel(theta), rest), on)

    residuals = force(flat, training.motion) - jnp.asarray(training.force)
    jacobian = jax.jacfwd(force)(flat, training.motion)
    cov = np.asarray(covariance(np.asarray(jacobian), np.asarray(residuals)))
    prediction = np.asarray(force(flat, target))
    sensitivity = np.asarray(jax.jacfwd(force)(flat, target))
    variance = np.einsum("tp,pq,tq->t", sensitivity, cov, sensitivity)
    std = np.sqrt(np.maximum(variance, 0.0))
    z = float(norm.ppf(0.5 + float(level) / 2))
    return PredictionBand(prediction, z * std, std, float(level), np.sqrt(np.maximum(np.diag(cov), 0.0)))
