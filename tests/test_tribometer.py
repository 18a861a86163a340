"""The synthetic tribometer (`make_tribometer`) and the Al-Alaoui differentiator."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal as ss

import fricjax as fj
from fricjax import (
    MotionSample,
    TribometerData,
    al_alaoui_coefficients,
    al_alaoui_derivative,
    default_tribometer_model,
    make_tribometer,
)

REGIMES = ("presliding", "mixed", "sliding")


@pytest.fixture(scope="module")
def datasets() -> dict[str, TribometerData]:
    return {regime: make_tribometer(regime, seed=0) for regime in REGIMES}


def _slipping(model: fj.GMS, motion: fj.Motion) -> np.ndarray:
    """Independent re-simulation of the GMS slip indicators along `motion` (a scan over `GMS.step`)."""
    p = fj.unwrap(model)
    x = jnp.asarray(motion.x)
    dx = jnp.diff(x, prepend=x[:1])
    dt = jnp.asarray(motion.dt)

    def body(state, xs):
        xk, vk, dxk = xs
        state, _ = p.step(state, MotionSample(x=xk, v=vk, dx=dxk, dt=dt))
        return state, state.slipping

    _, slipping = jax.lax.scan(body, p.init_state(), (x, jnp.asarray(motion.v), dx))
    return np.asarray(slipping) > 0.5


# ---------------------------------------------------------------------------------------------------------------
# determinism, sizes, card


@pytest.mark.slow  # fast tier trimmed (2026-11-27): a seeding property
def test_deterministic_for_a_seed(datasets):
    again = make_tribometer("mixed", seed=0)
    first = datasets["mixed"]
    np.testing.assert_array_equal(np.asarray(again.full.force), np.asarray(first.full.force))
    np.testing.assert_array_equal(np.asarray(again.full.motion.x), np.asarray(first.full.motion.x))
    np.testing.assert_array_equal(np.asarray(again.clean_force), np.asarray(first.clean_force))
    assert again.card == first.card
    other = make_tribometer("mixed", seed=1)
    assert not np.allclose(np.asarray(other.full.motion.x), np.asarray(first.full.motion.x))
    assert not np.allclose(np.asarray(other.full.force), np.asarray(first.full.force))


def test_noise_streams_are_independent_of_the_switches(datasets):
    """Switching the force noise off leaves the excitation and the position noise unchanged."""
    quiet = make_tribometer("mixed", seed=0, force_noise_std=0.0)
    np.testing.assert_array_equal(np.asarray(quiet.full.motion.x), np.asarray(datasets["mixed"].full.motion.x))
    np.testing.assert_array_equal(np.asarray(quiet.clean_force), np.asarray(datasets["mixed"].clean_force))


def test_split_sizes(datasets):
    data = datasets["presliding"]
    assert (data.full.length, data.train.length, data.validation.length, data.test.length) == (8000, 4800, 1600, 1600)
    assert data.card["samples"] == {"full": 8000, "train": 4800, "validation": 1600, "test": 1600}
    joined = fj.concatenate([data.train, data.validation, data.test])
    np.testing.assert_array_equal(np.asarray(joined.force), np.asarray(data.full.force))
    np.testing.assert_array_equal(np.asarray(joined.motion.x), np.asarray(data.full.motion.x))
    custom = make_tribometer("sliding", duration=3.0, sample_rate=1000.0, splits=(0.5, 0.75))
    assert (custom.train.length, custom.validation.length, custom.test.length) == (1500, 750, 750)
    assert float(custom.full.motion.dt) == pytest.approx(1e-3)


def test_card_is_json_and_complete(datasets, tmp_path):
    for regime, data in datasets.items():
        card = data.card
        assert json.loads(json.dumps(card)) == card
        assert card["regime"] == regime and card["seed"] == 0 and card["sample_rate_hz"] == 2000.0
        for key in ("force_noise_std_N", "drift_N", "position_quantisation_m", "position_noise_std_m"):
            assert isinstance(card["sensor"][key], float)
        params = card["model_parameters"]
        assert params["k"] == [1.4e5, 1.12e5, 8.4e4, 5.6e4]
        assert params["alpha"] == pytest.approx([0.1, 0.2, 0.3, 0.4], rel=1e-10)
        assert params["stribeck.Fs"] == pytest.approx(1.4)
        assert card["breakaway_displacement_m"] == pytest.approx(1e-5)
        assert card["breakaway_force_N"] == pytest.approx(1.4)
        assert 0 <= card["sticking"]["all_sticking_fraction"] <= 1
    data = datasets["mixed"]
    path = data.save_card(tmp_path / "card.json")
    assert json.loads(path.read_text()) == data.card
    text = data.card_text()
    assert "regime: mixed" in text and "all_sticking_fraction" in text and "force_noise_std_N" in text


# ---------------------------------------------------------------------------------------------------------------
# the regimes


def test_regimes_are_what_they_say(datasets):
    fractions = {}
    for regime, data in datasets.items():
        slipping = _slipping(data.true_model, data.true_motion)
        all_stick = float(np.mean(~slipping.any(axis=1)))
        gross = float(np.mean(slipping.all(axis=1)))
        assert data.card["sticking"]["all_sticking_fraction"] == pytest.approx(all_stick)
        assert data.card["sticking"]["gross_sliding_fraction"] == pytest.approx(gross)
        peak = float(np.max(np.abs(np.asarray(data.clean_force)))) / 1.4
        assert data.card["peak_over_breakaway_force"] == pytest.approx(peak)
        fractions[regime] = (all_stick, gross, peak)
    stick, gross, peak = fractions["presliding"]
    assert stick > 0.6 and gross == 0.0 and peak < 0.85  # pre-sliding: mostly sticking, never gross sliding
    assert 0.8 * 1e-5 > np.max(np.abs(np.asarray(datasets["presliding"].true_motion.x)))  # below x_b
    stick, gross, peak = fractions["mixed"]
    assert 0.2 < stick < 0.7 and 0.05 < gross < 0.4 and peak > 0.9  # both regimes present
    stick, gross, peak = fractions["sliding"]
    assert stick < 0.15 and gross > 0.7  # gross sliding most of the time
    assert fractions["presliding"][0] > fractions["mixed"][0] > fractions["sliding"][0]
    assert fractions["presliding"][1] < fractions["mixed"][1] < fractions["sliding"][1]


def test_regimes_hold_for_other_seeds():
    for seed in (3, 7):
        cards = {r: make_tribometer(r, seed=seed, noise=False).card["sticking"] for r in REGIMES}
        sticking = [cards[r]["all_sticking_fraction"] for r in REGIMES]
        assert sticking[0] > 0.6 and sticking[0] > sticking[1] > sticking[2]
        assert cards["presliding"]["gross_sliding_fraction"] == 0.0


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the tribometer is checked fast on its default model
def test_other_true_models():
    lugre = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.4, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=10.0)
    data = make_tribometer("mixed", model=lugre, duration=1.0)
    assert data.true_model is lugre
    assert data.card["breakaway_displacement_m"] == pytest.approx(1.4e-5)
    assert "note" in data.card["sticking"]
    np.testing.assert_allclose(np.asarray(data.clean_force), np.asarray(fj.simulate(lugre, data.true_motion)))
    nlr = fj.MaxwellSlip.nlr(k=[2e5, 1e5, 5e4], thresholds=[2e-6, 6e-6, 2e-5])
    card = make_tribometer("presliding", model=nlr, duration=1.0).card
    assert card["breakaway_displacement_m"] == pytest.approx(2e-5)
    assert card["sticking"]["gross_sliding_fraction"] == 0.0
    coulomb = make_tribometer("sliding", model=fj.Coulomb(Fc=1.0), breakaway_displacement=1e-5, duration=1.0)
    assert np.max(np.abs(np.asarray(coulomb.clean_force))) == pytest.approx(1.0)


# ---------------------------------------------------------------------------------------------------------------
# sensor effects


def test_noise_false_is_exact():
    data = make_tribometer("mixed", seed=2, noise=False)
    np.testing.assert_array_equal(np.asarray(data.full.force), np.asarray(data.clean_force))
    np.testing.assert_array_equal(np.asarray(data.full.motion.x), np.asarray(data.true_motion.x))
    sensor = data.card["sensor"]
    assert sensor["force_noise_std_N"] == sensor["drift_N"] == sensor["position_quantisation_m"] == 0.0
    assert sensor["position_noise_std_m"] == 0.0
    # the force is simulated from the true motion
    np.testing.assert_allclose(
        np.asarray(data.clean_force), np.asarray(fj.simulate(default_tribometer_model(), data.true_motion))
    )


def test_drift_and_force_noise(datasets):
    data = make_tribometer("presliding", seed=0, force_noise_std=0.0, position_noise_std=0.0)
    trend = np.asarray(data.full.force) - np.asarray(data.clean_force)
    card = data.card["sensor"]
    assert card["drift_N"] == pytest.approx(-0.03 * data.card["force_range_N"])
    assert trend[0] == 0.0 and trend[-1] == pytest.approx(card["drift_N"])
    assert np.all(np.diff(trend) < 0)  # a slow monotone trend (charge leakage)
    t = np.arange(data.full.length) / 2000.0
    tau, end = card["drift_time_constant_s"], t[-1]
    np.testing.assert_allclose(trend, card["drift_N"] * np.expm1(-t / tau) / np.expm1(-end / tau), atol=1e-12)

    noisy = datasets["presliding"]
    residual = np.asarray(noisy.full.force) - np.asarray(noisy.clean_force) - trend
    std = noisy.card["sensor"]["force_noise_std_N"]
    assert std == pytest.approx(0.0075 * noisy.card["force_range_N"])
    assert np.std(residual) == pytest.approx(std, rel=0.05)
    assert abs(np.mean(residual)) < 4 * std / np.sqrt(residual.size)

    flat = make_tribometer("presliding", seed=0, drift=0.0, force_noise_std=0.01)
    residual = np.asarray(flat.full.force) - np.asarray(flat.clean_force)
    assert np.std(residual) == pytest.approx(0.01, rel=0.05)
    custom = make_tribometer("presliding", seed=0, drift=0.2, force_noise_std=0.0, drift_time_constant=1.0)
    assert float(custom.full.force[-1] - custom.clean_force[-1]) == pytest.approx(0.2)


def test_position_quantisation_and_noise(datasets):
    quantum = 1e-9
    data = make_tribometer("presliding", seed=0, position_noise_std=0.0, position_quantisation=quantum)
    x, x_true = np.asarray(data.full.motion.x), np.asarray(data.true_motion.x)
    np.testing.assert_allclose(x / quantum, np.round(x / quantum), atol=1e-6)
    assert np.max(np.abs(x - x_true)) <= 0.5 * quantum * (1 + 1e-9)
    noisy = datasets["presliding"]
    error = np.asarray(noisy.full.motion.x) - np.asarray(noisy.true_motion.x)
    assert np.std(error) == pytest.approx(np.sqrt(1e-18 + quantum**2 / 12), rel=0.1)
    # the record's velocity is derived from the measured displacement by central differences
    np.testing.assert_allclose(np.asarray(noisy.full.motion.v), np.gradient(np.asarray(noisy.full.motion.x)) * 2000)
    smooth = make_tribometer("presliding", seed=0, velocity="al-alaoui")
    v_true = np.asarray(smooth.true_motion.v)
    assert np.max(np.abs(np.asarray(smooth.full.motion.v) - v_true)) < 0.1 * np.max(np.abs(v_true))


# ---------------------------------------------------------------------------------------------------------------
# errors


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"regime": "stick-slip"}, "unknown `regime`"),
        ({"seed": -1}, "`seed`"),
        ({"seed": 1.5}, "`seed`"),
        ({"duration": -1.0}, "`duration`"),
        ({"duration": 0.01}, "at least 100"),
        ({"sample_rate": float("nan")}, "`sample_rate`"),
        ({"splits": (0.8, 0.6)}, "`splits`"),
        ({"splits": (0.6,)}, "`splits`"),
        ({"force_noise_std": -0.1}, "`force_noise_std`"),
        ({"drift_time_constant": 0.0}, "`drift_time_constant`"),
        ({"noise": False, "force_noise_std": 0.1}, "noise=False"),
        ({"velocity": "spline"}, "`velocity`"),
        ({"model": fj.Coulomb(Fc=1.0)}, "breakaway_displacement"),
        ({"breakaway_displacement": 0.0}, "`breakaway_displacement`"),
    ],
)
def test_errors(kwargs, match):
    kwargs = {"regime": "mixed", **kwargs}
    with pytest.raises(ValueError, match=match):
        make_tribometer(**kwargs)


def test_type_errors():
    with pytest.raises(TypeError, match="`model`"):
        make_tribometer("mixed", model="gms")
    with pytest.raises(TypeError, match="`splits`"):
        make_tribometer("mixed", splits=0.6)


# ---------------------------------------------------------------------------------------------------------------
# the Al-Alaoui differentiator


def test_al_alaoui_coefficients_by_hand():
    dt = 5e-4
    b, a = al_alaoui_coefficients(dt)
    np.testing.assert_allclose(b, [8 / (7 * dt), -8 / (7 * dt)])
    np.testing.assert_allclose(a, [1.0, 1 / 7])
    # the recursion y_k = -y_{k-1} / 7 + 8 / (7 T) (x_k - x_{k-1}), from rest at the first sample
    x = np.random.default_rng(0).standard_normal(200).cumsum()
    y = np.zeros_like(x)
    for k in range(1, x.size):
        y[k] = -y[k - 1] / 7 + 8 / (7 * dt) * (x[k] - x[k - 1])
    np.testing.assert_allclose(al_alaoui_derivative(x, dt), y, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(ss.lfilter(b, a, x - x[0]), y, rtol=1e-12, atol=1e-9)
    # frequency response: H(z) = (8 / (7 T)) (1 - z^-1) / (1 + z^-1 / 7)
    w, h = ss.freqz(b, a, worN=[0.3])
    z = np.exp(1j * w)
    np.testing.assert_allclose(h, 8 / (7 * dt) * (1 - 1 / z) / (1 + 1 / (7 * z)))


def _amplitude(signal: np.ndarray, omega: float, t: np.ndarray) -> float:
    """Least-squares amplitude of the sinusoid of angular frequency `omega` in `signal`."""
    basis = np.stack([np.sin(omega * t), np.cos(omega * t)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, signal, rcond=None)
    return float(np.hypot(*coef))


@pytest.mark.parametrize("fraction", [0.01, 0.1])
def test_al_alaoui_accuracy(fraction):
    dt = 1e-3
    omega = fraction * np.pi / dt  # `fraction` of the Nyquist frequency
    t = np.arange(20000) * dt
    x = np.sin(omega * t)
    inner = slice(500, -500)
    causal = al_alaoui_derivative(x, dt)
    error = abs(_amplitude(causal[inner], omega, t[inner]) / omega - 1)
    assert error < (1e-4 if fraction == 0.01 else 2e-3)  # magnitude, 1.3e-5 at 1 % of Nyquist
    zero_phase = al_alaoui_derivative(x, dt, zero_phase=True)
    reference = omega * np.cos(omega * t)
    assert np.max(np.abs(zero_phase - reference)[inner]) < (1e-3 if fraction == 0.01 else 1e-2) * omega
    # the causal filter lags by 3/8 of a sample
    lagged = omega * np.cos(omega * (t - 3 * dt / 8))
    assert np.max(np.abs(causal - lagged)[inner]) < 3e-3 * omega


def test_al_alaoui_stable_step_and_constants():
    dt = 1e-3
    step = np.r_[np.zeros(10), np.ones(500)]
    y = al_alaoui_derivative(step, dt)
    assert np.all(np.isfinite(y))
    assert np.max(np.abs(y)) == pytest.approx(8 / (7 * dt))  # bounded: the first response sample
    k = np.arange(500)
    np.testing.assert_allclose(y[10:], 8 / (7 * dt) * (-1 / 7) ** k, rtol=1e-10, atol=1e-9)  # pole at -1/7
    np.testing.assert_array_equal(y[:10], 0.0)
    assert abs(y[-1]) < 1e-12
    assert np.max(np.abs(al_alaoui_derivative(np.full(50, 3.0), dt, zero_phase=True))) == 0.0
    batch = np.stack([np.linspace(0, 1, 100), 2 * np.linspace(0, 1, 100)])
    np.testing.assert_allclose(al_alaoui_derivative(batch, 0.01)[1], 2 * al_alaoui_derivative(batch[0], 0.01))
    np.testing.assert_allclose(al_alaoui_derivative(batch.T, 0.01, axis=0), al_alaoui_derivative(batch, 0.01).T)
    with pytest.raises(ValueError, match="dt"):
        al_alaoui_derivative(step, 0.0)
    with pytest.raises(ValueError, match="NaN"):
        al_alaoui_derivative(np.r_[step, np.nan], dt)
