"""`fj.SensorDrift`: the force sensor's drift as part of the model (issue 9, the measurement model)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import fricjax as fj

DT = 1e-3
T = np.arange(2000) * DT
MOTION = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 2.0 * T), dt=DT)
INNER = fj.CoulombViscous(Fc=1.0, Fv=20.0, smoothing=fj.Smooth(1e-4))


@pytest.mark.parametrize("tau", [None, 0.7])
def test_drift_is_added_from_the_first_sample_as_documented(tau):
    model = fj.SensorDrift(INNER, rate=-0.3, tau=tau)
    inner = np.asarray(fj.simulate(INNER, MOTION))
    # the NumPy reference: linear rate * t, leaky rate * tau * (1 - exp(-t / tau)), t = k * dt
    drift = -0.3 * T if tau is None else -0.3 * tau * (1.0 - np.exp(-T / tau))
    np.testing.assert_allclose(np.asarray(fj.simulate(model, MOTION)), inner + drift, rtol=1e-6, atol=1e-9)


@pytest.mark.slow  # about 9 s
def test_fit_recovers_offset_and_drift_rate_by_least_squares():
    truth = fj.SensorDrift(fj.CoulombViscous(Fc=1.0, Fv=20.0, offset=0.3, smoothing=fj.Smooth(1e-4)), rate=-0.2)
    noise = 0.01 * np.random.default_rng(0).normal(size=T.size)
    data = fj.FrictionData(MOTION, np.asarray(fj.simulate(truth, MOTION)) + noise)
    start = fj.SensorDrift(fj.CoulombViscous(Fc=0.7, Fv=10.0, smoothing=fj.Smooth(1e-4)))
    result = fj.fit(
        start,
        data,
        solver=fj.levenberg_marquardt(),
        steps=30,
        separable=("model.Fv", "model.offset", "rate"),
        scaling=fj.ParameterScaling(),
    )
    fitted = fj.unwrap(result.model)
    assert abs(float(fitted.rate) + 0.2) < 0.01 and abs(float(fitted.model.offset) - 0.3) < 0.01
    assert abs(float(fitted.model.Fc) - 1.0) < 0.01


def test_gradient_in_tau_matches_finite_differences():

    def total(tau):
        return fj.simulate(fj.SensorDrift(INNER, rate=0.5, tau=tau), MOTION).sum()

    grad = float(jax.grad(total)(0.4))
    h = 1e-5
    finite = (float(total(0.4 + h)) - float(total(0.4 - h))) / (2 * h)
    assert grad == pytest.approx(finite, rel=1e-5)


def test_saved_and_loaded_with_its_drift(tmp_path):
    model = fj.SensorDrift(fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 1e-3), 1e5, 300.0, 0.4), rate=0.1, tau=2.0)
    fj.save_model(tmp_path / "m.eqx", model)
    back = fj.load_model(tmp_path / "m.eqx")
    np.testing.assert_allclose(np.asarray(fj.simulate(back, MOTION)), np.asarray(fj.simulate(model, MOTION)))


def test_bad_arguments_are_named():
    with pytest.raises(TypeError, match="SensorDrift"):
        fj.SensorDrift("lugre")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="tau"):
        fj.SensorDrift(INNER, tau=-1.0)
