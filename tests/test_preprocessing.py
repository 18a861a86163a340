"""Preprocessing: each step against SciPy / NumPy or a hand-computed case, and the bad-input errors."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal as ss

from fricjax import Normaliser, butter_filtfilt, central_difference, decimate, detrend_linear, normalise

DT = 1e-3


def _noisy(rng: np.random.Generator, n: int = 3000) -> np.ndarray:
    t = np.arange(n) * DT
    return np.sin(2 * np.pi * 3 * t) + 0.2 * rng.standard_normal(n)


# --- butter_filtfilt ----------------------------------------------------------------------------------------------


def test_butter_filtfilt_matches_scipy_with_matlab_padding(rng):
    x = _noisy(rng)
    b, a = ss.butter(4, 100.0 / 500.0)
    expected = ss.filtfilt(b, a, x, padlen=12)  # MATLAB filtfilt pads 3 * (max(len(a), len(b)) - 1) = 12
    np.testing.assert_allclose(butter_filtfilt(x, DT, 100.0), expected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(butter_filtfilt(x, DT, 100.0, padlen=15), ss.filtfilt(b, a, x), rtol=0, atol=1e-13)


def test_butter_filtfilt_is_zero_phase():
    # a delayed sine well inside the pass band comes out with no delay (a one-pass filter would lag ~2 ms)
    t = np.arange(4000) * DT
    delay = 0.0123
    x = np.sin(2 * np.pi * 5.0 * (t - delay))
    y = butter_filtfilt(x, DT, 100.0)
    inner = slice(200, -200)
    np.testing.assert_allclose(y[inner], x[inner], atol=1e-6)
    lags = np.arange(-20, 21)
    xc = [np.dot(y[inner], np.roll(x, lag)[inner]) for lag in lags]
    assert lags[int(np.argmax(xc))] == 0
    # and it removes what lies above the cut-off
    noisy = x + 0.5 * np.sin(2 * np.pi * 400.0 * t)
    assert np.max(np.abs(butter_filtfilt(noisy, DT, 100.0) - x)[inner]) < 1e-3


def test_butter_filtfilt_along_axis(rng):
    x = np.stack([_noisy(rng), _noisy(rng)])
    y = butter_filtfilt(x.T, DT, 50.0, axis=0)
    np.testing.assert_allclose(y.T[1], butter_filtfilt(x[1], DT, 50.0), atol=1e-13)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cutoff_hz": 500.0}, "Nyquist"),
        ({"cutoff_hz": 800.0}, "Nyquist"),
        ({"cutoff_hz": -1.0}, "cutoff_hz"),
        ({"dt": 0.0}, "dt"),
        ({"dt": float("nan")}, "dt"),
        ({"order": 0}, "order"),
    ],
)
def test_butter_filtfilt_bad_arguments(kwargs, match):
    args = {"dt": DT, "cutoff_hz": 100.0} | kwargs
    with pytest.raises(ValueError, match=match):
        butter_filtfilt(np.zeros(100), **args)


def test_butter_filtfilt_bad_signals():
    with pytest.raises(ValueError, match="NaN or inf"):
        butter_filtfilt(np.array([0.0, 1.0, np.nan] + [0.0] * 50), DT, 100.0)
    with pytest.raises(ValueError, match="at least 13"):
        butter_filtfilt(np.zeros(12), DT, 100.0)
    with pytest.raises(TypeError, match="order"):
        butter_filtfilt(np.zeros(100), DT, 100.0, order=2.5)
    with pytest.raises(TypeError, match="numbers"):
        butter_filtfilt(np.array(["a"] * 100), DT, 100.0)


# --- central_difference -------------------------------------------------------------------------------------------


def test_central_difference_of_a_quadratic_is_exact():
    dt = 0.01
    t = np.arange(50) * dt
    y = 3.0 * t**2 - 2.0 * t + 1.0
    d = central_difference(y, dt)
    np.testing.assert_allclose(d[1:-1], 6.0 * t[1:-1] - 2.0, atol=1e-10)
    # one-sided at the ends: the slope of the first / last chord
    np.testing.assert_allclose(d[0], (y[1] - y[0]) / dt)
    np.testing.assert_allclose(d[-1], (y[-1] - y[-2]) / dt)


def test_central_difference_matches_numpy_gradient(rng):
    x = rng.standard_normal((3, 40))
    np.testing.assert_allclose(central_difference(x, 0.5), np.gradient(x, axis=-1) / 0.5)
    np.testing.assert_allclose(central_difference(x.T, 0.5, axis=0), np.gradient(x.T, axis=0) / 0.5)


def test_central_difference_errors():
    with pytest.raises(ValueError, match="at least 2"):
        central_difference(np.array([1.0]), DT)
    with pytest.raises(ValueError, match="dt"):
        central_difference(np.zeros(5), -1.0)


# --- decimate -----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("length", [100, 101, 109, 110, 24792])
def test_decimate_length(length):
    assert decimate(np.zeros(length), 10).shape == (math.ceil(length / 10),)
    assert decimate(np.zeros(length), 10, align="start").shape == (math.ceil(length / 10),)


def test_decimate_is_matlab_decimate(rng):
    # MATLAB: cheby1(8, 0.05, 0.8/r), filtfilt (padding 3 * 8 = 24), keep odata(nbeg:r:nd) with
    # nbeg = r - (r * nout - nd) (1-based), i.e. the kept samples end on the last one
    x = _noisy(rng, 24792)
    b, a = ss.cheby1(8, 0.05, 0.8 / 10)
    filtered = ss.filtfilt(b, a, x, padlen=24)
    nout = math.ceil(24792 / 10)
    nbeg = 10 - (10 * nout - 24792)
    np.testing.assert_allclose(decimate(x, 10), filtered[nbeg - 1 :: 10], rtol=0, atol=1e-12)
    assert nbeg - 1 == 1


def test_decimate_start_alignment_matches_scipy_inside(rng):
    x = _noisy(rng, 3001)
    ours, theirs = decimate(x, 10, align="start"), ss.decimate(x, 10)
    assert ours.shape == theirs.shape
    # the padding differs (MATLAB 24 samples, SciPy's sosfiltfilt more), which changes the ends (the transient
    # of this narrow filter lasts ~60 output samples); inside, only the rounding of the tf vs sos forms differs
    np.testing.assert_allclose(ours[80:-80], theirs[80:-80], atol=1e-6)
    assert np.max(np.abs(ours[:3] - theirs[:3])) > 1e-4


def test_decimate_gain_and_alignment():
    # a slow ramp passes with the Chebyshev-I DC gain squared (even order: -0.05 dB each pass)
    x = np.linspace(0.0, 1.0, 5005)
    gain = 10 ** (-2 * 0.05 / 20)
    end, start = decimate(x, 10), decimate(x, 10, align="start")
    # the filter's edge transients ring for a few hundred raw samples; one raw sample of misalignment is 2e-4
    np.testing.assert_allclose(end[50:-50], gain * x[4::10][50:-50], atol=2e-6)
    np.testing.assert_allclose(start[50:-50], gain * x[0::10][50:-50], atol=2e-6)


def test_decimate_containers_and_factor_one(rng):
    x, y = _noisy(rng, 500), _noisy(rng, 500)
    out = decimate({"x": x, "y": y}, 5)
    np.testing.assert_allclose(out["y"], decimate(y, 5))
    pair = decimate((x, y), 5)
    assert isinstance(pair, tuple) and len(pair) == 2
    np.testing.assert_allclose(pair[0], decimate(x, 5))
    assert isinstance(decimate([x, y], 5), list)
    same = decimate(x, 1)
    np.testing.assert_array_equal(same, x)
    assert same is not x
    np.testing.assert_allclose(decimate(np.stack([x, y]), 5)[1], decimate(y, 5))


def test_decimate_errors():
    with pytest.raises(ValueError, match="factor"):
        decimate(np.zeros(100), 0)
    with pytest.raises(TypeError, match="factor"):
        decimate(np.zeros(100), 2.5)
    with pytest.raises(ValueError, match="align"):
        decimate(np.zeros(100), 2, align="middle")
    with pytest.raises(ValueError, match="at least 25"):
        decimate(np.zeros(20), 2)
    with pytest.raises(ValueError, match="NaN or inf"):
        decimate(np.full(100, np.inf), 2)


# --- detrend_linear, normalise ------------------------------------------------------------------------------------


def test_detrend_linear(rng):
    t = np.arange(200) * DT
    wiggle = np.sin(2 * np.pi * 10 * t)
    wiggle -= np.polyval(np.polyfit(t, wiggle, 1), t)  # make it exactly orthogonal to a line
    x = wiggle + 2.0 + 5.0 * t
    detrended, trend = detrend_linear(x, return_trend=True)
    np.testing.assert_allclose(detrended, wiggle, atol=1e-10)
    np.testing.assert_allclose(trend, 2.0 + 5.0 * t, atol=1e-10)
    np.testing.assert_allclose(detrend_linear(np.stack([x, x]).T, axis=0)[:, 1], wiggle, atol=1e-10)
    with pytest.raises(ValueError, match="at least 2"):
        detrend_linear(np.array([1.0]))


def test_normalise_round_trip(rng):
    x = 3.0 + 0.5 * rng.standard_normal((2, 300))
    z, norm = normalise(x)
    assert isinstance(norm, Normaliser)
    np.testing.assert_allclose(z.mean(axis=-1), 0.0, atol=1e-12)
    np.testing.assert_allclose(z.std(axis=-1), 1.0)
    np.testing.assert_allclose(norm.inverse(z), x)
    np.testing.assert_allclose(norm(x), z)
    # one scale for everything
    z_all, norm_all = normalise(x, axis=None)
    assert norm_all.scale.size == 1
    np.testing.assert_allclose(norm_all.inverse(z_all), x)
    # the normaliser works on JAX arrays (e.g. a model's output inside jit)
    np.testing.assert_allclose(np.asarray(norm.inverse(jnp.asarray(z))), x)


def test_normalise_errors():
    with pytest.raises(ValueError, match="constant"):
        normalise(np.full(10, 2.0))
    with pytest.raises(ValueError, match="at least 2"):
        normalise(np.array([1.0]))
    with pytest.raises(ValueError, match="NaN or inf"):
        normalise(np.array([1.0, np.nan]))
