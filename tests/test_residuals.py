"""Residual analysis (issue 55, item 2; MATLAB's `resid`): the autocorrelation of the residual and its
cross-correlation with the input, against a NumPy reference and on residuals whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

import fricjax as fj

N = 4000


def _reference(e, u, lag):
    """corr(e(t), e(t + lag)) and corr(u(t), e(t + lag)) by np.corrcoef-like sums over the overlapping samples / N."""
    e, u = (e - e.mean()) / e.std(), (u - u.mean()) / u.std()
    if lag < 0:
        return None, np.sum(u[-lag:] * e[: N + lag]) / N
    return np.sum(e[: N - lag] * e[lag:]) / N, np.sum(u[: N - lag] * e[lag:]) / N


def test_correlations_match_a_numpy_reference_and_the_band_is_z_over_root_n():
    rng = np.random.default_rng(1)
    u, e = rng.standard_normal(N), rng.standard_normal(N)
    analysis = fj.residual_analysis(e + np.sin(u), np.sin(u), u, max_lag=5)
    for lag in range(-5, 6):
        auto, cross = _reference(e, u, lag)
        if auto is not None:
            assert analysis.autocorrelation[lag] == pytest.approx(auto, abs=1e-12)
        assert analysis.cross_correlation[lag + 5] == pytest.approx(cross, abs=1e-12)
    assert analysis.autocorrelation[0] == pytest.approx(1.0) and analysis.band == pytest.approx(2.5758 / np.sqrt(N))
    assert analysis.white and analysis.independent and "residual white" in analysis.verdict()


def test_a_coloured_residual_is_not_white_and_a_missed_input_term_is_found_at_its_lag():
    rng = np.random.default_rng(2)
    u = rng.standard_normal(N)
    coloured = np.convolve(rng.standard_normal(N), np.ones(8) / 8, mode="same")  # a moving average: correlated
    slow = fj.residual_analysis(coloured, np.zeros(N), u)
    assert not slow.white and slow.independent, slow.verdict()
    missed = fj.residual_analysis(0.3 * np.roll(u, 3) + 0.05 * rng.standard_normal(N), np.zeros(N), u, input_name="v")
    worst = int(missed.cross_lags[np.argmax(np.abs(missed.cross_correlation))])
    assert not missed.independent and worst == 3 and "correlated with v" in missed.verdict()


def test_bad_input_is_refused_with_the_argument_named():
    u = np.arange(100.0)
    with pytest.raises(ValueError, match="one value per sample"):
        fj.residual_analysis(u, u[:-1], u)
    with pytest.raises(ValueError, match="max_lag"):
        fj.residual_analysis(u, 0 * u, u, max_lag=60)
    with pytest.raises(ValueError, match="confidence"):
        fj.residual_analysis(u, 0 * u, u, confidence=0.98)
    with pytest.raises(ValueError, match="must vary"):
        fj.residual_analysis(u, u, u)
    with pytest.raises(ValueError, match="finite"):
        fj.residual_analysis(np.r_[u[:-1], np.nan], 0 * u, u)
    figure = fj.plot_residual_analysis({"a": fj.residual_analysis(np.sin(u), 0 * u, u)}, title="t")
    assert len(figure.axes) == 2
