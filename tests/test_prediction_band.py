"""Confidence bands of a simulated output (issue 55, item 2): `fj.prediction_band` propagates the Gauss-Newton
covariance of the fitted parameters through the simulation; for a model linear in its parameters it is the textbook
band of a linear regression, `z s sqrt(x^T (X^T X)^-1 x)`."""

from __future__ import annotations

import numpy as np
import pytest

import fricjax as fj


def test_the_band_of_a_model_linear_in_its_parameters_is_the_regression_band():
    rng = np.random.default_rng(0)
    t = np.arange(800) * 1e-3
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 2 * t) + 2e-4 * np.sin(2 * np.pi * 7 * t), dt=1e-3)
    truth = fj.CoulombViscous(Fc=1.0, Fv=30.0, offset=0.1, smoothing=fj.Smooth(1e-3))
    force = np.asarray(fj.simulate(truth, motion)) + 0.05 * rng.standard_normal(t.size)
    data = fj.FrictionData(motion, force)
    fitted = fj.fit(truth, data, solver=fj.levenberg_marquardt(), steps=30).model
    other = fj.Motion.from_position(2e-3 * np.sin(2 * np.pi * 3 * t), dt=1e-3)
    band = fj.prediction_band(fitted, other, data, level=0.95)

    def regressors(on):  # [1, s(v), v]: the force is offset + Fc s(v) + Fv v
        unit = fj.CoulombViscous(Fc=1.0, Fv=0.0, smoothing=fj.Smooth(1e-3))
        return np.c_[np.ones(on.length), np.asarray(fj.simulate(unit, on)), np.asarray(on.samples().v)]

    X, Z = regressors(motion), regressors(other)
    residual = np.asarray(fj.simulate(fitted, motion)) - force
    s2 = residual @ residual / (t.size - 3)
    expected = 1.959964 * np.sqrt(s2 * np.einsum("tp,pq,tq->t", Z, np.linalg.inv(X.T @ X), Z))
    np.testing.assert_allclose(band.half_width, expected, rtol=1e-6)
    np.testing.assert_allclose(band.prediction, np.asarray(fj.simulate(fitted, other)), rtol=1e-12)
    assert np.all(band.lower <= band.prediction) and np.all(band.upper >= band.prediction)


def test_fixed_parameters_carry_no_uncertainty_and_bad_arguments_are_named():
    motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 12, 400)), dt=1e-3)
    model = fj.CoulombViscous(Fc=1.0, Fv=fj.Fixed(30.0), smoothing=fj.Smooth(1e-3))
    data = fj.FrictionData(motion, np.asarray(fj.simulate(model, motion)) + 0.01)
    band = fj.prediction_band(model, motion, data)
    assert band.parameter_std.size == 2  # offset and Fc; Fv is fixed
    with pytest.raises(ValueError, match="level"):
        fj.prediction_band(model, motion, data, level=99)
    with pytest.raises(TypeError, match="training"):
        fj.prediction_band(model, motion, motion)
