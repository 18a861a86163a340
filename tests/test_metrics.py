"""Metrics against hand-computed values, and jit / vmap behaviour."""

import jax
import numpy as np
import pytest

import fricjax as fj

Y = np.array([1.0, 2.0, 3.0, 4.0])
YHAT = np.array([1.0, 2.5, 2.5, 4.0])  # errors 0, .5, -.5, 0 -> mse 0.125; var(Y) = 1.25; std = 1.1180


def test_hand_computed_values():
    assert float(fj.rmse(Y, YHAT)) == pytest.approx(np.sqrt(0.125))
    assert float(fj.nmse(Y, YHAT)) == pytest.approx(100 * 0.125 / 1.25)
    assert float(fj.nrmse(Y, YHAT)) == pytest.approx(np.sqrt(0.125) / np.sqrt(1.25))
    assert float(fj.max_error(Y, YHAT)) == pytest.approx(0.5 / np.sqrt(1.25))
    assert float(fj.relative_error(Y, YHAT)) == pytest.approx(100 * np.sqrt(0.5) / np.sqrt(30.0))
    assert float(fj.fit_percent(Y, YHAT)) == pytest.approx(100 * (1 - np.sqrt(0.5) / np.sqrt(5.0)))


def test_mean_predictor_scores_100_percent_nmse():
    y = np.random.default_rng(1).normal(size=100)
    assert float(fj.nmse(y, np.full_like(y, y.mean()))) == pytest.approx(100.0)
    assert float(fj.fit_percent(y, np.full_like(y, y.mean()))) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("metric", [fj.rmse, fj.nmse, fj.nrmse, fj.max_error, fj.relative_error, fj.fit_percent])
def test_jit_and_vmap(metric):
    batch_y = np.stack([Y, 2 * Y, Y + 1])
    batch_yhat = np.stack([YHAT, 2 * YHAT, YHAT + 1])
    vmapped = jax.vmap(metric)(batch_y, batch_yhat)
    looped = [metric(a, b) for a, b in zip(batch_y, batch_yhat, strict=True)]
    np.testing.assert_allclose(vmapped, looped, rtol=1e-12)
    np.testing.assert_allclose(jax.jit(metric)(Y, YHAT), metric(Y, YHAT), rtol=1e-12)
    np.testing.assert_allclose(metric(batch_y, batch_yhat), looped, rtol=1e-12)
