"""What only a model family knows is asked of the model (DESIGN.md v4, issue 53): the breakaway scales, the force
offset, the elements and where they slip, a small smoothing width, what is implausible in fitted values; wrappers
(sensor drift, normal load, backlash) answer for the model inside them."""

import numpy as np
import pytest

import fricjax as fj


def _lugre(stribeck):
    return fj.LuGre(stribeck, sigma0=1e5, sigma1=0.0, sigma2=40.0)


def test_breakaway_scales_of_each_family():
    s = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3)
    assert fj.unwrap(_lugre(s)).breakaway_displacement() == pytest.approx(1.5 / 1e5)
    assert _lugre(s).breakaway_force() == pytest.approx(1.5)
    assert fj.Dahl(sigma0=1e5, Fc=2.0).breakaway_displacement() == pytest.approx(2e-5)
    nlr = fj.MaxwellSlip.nlr(k=[1e5, 2e5], thresholds=[1e-6, 3e-6], offset=0.25)
    assert nlr.breakaway_displacement() == pytest.approx(3e-6)
    assert nlr.breakaway_force() == pytest.approx(1e5 * 1e-6 + 2e5 * 3e-6)
    assert nlr.force_offset() == pytest.approx(0.25) and nlr.num_elements == 2
    static = fj.Coulomb(Fc=1.0, offset=0.1)
    assert static.breakaway_displacement() is None and static.num_elements is None
    assert static.force_offset() == pytest.approx(0.1)


def test_implausible_values_are_named_by_the_family_and_through_wrappers():
    rational = fj.RationalStribeck(Fc=2.0, Fs=1.0, vs=1e-3)  # Fs < Fc on the rational curve too (was missed)
    notes = fj.unwrap(_lugre(rational)).implausible()
    assert any("Fs < Fc" in note for note in notes) and "sigma1 = 0 (held at its bound)" in notes
    assert "sigma1 = 0 (held at its bound)" not in fj.unwrap(_lugre(rational)).implausible(bounds=False)
    for wrapped in (
        fj.SensorDrift(_lugre(rational), rate=0.1),
        fj.NormalLoad(_lugre(rational), reference=10.0),
        fj.Backlash(_lugre(rational), gap=1e-4),
    ):
        assert fj.unwrap(wrapped).implausible() == notes
    assert fj.SensorDrift(_lugre(rational)).drifts and not _lugre(rational).drifts
    inner = fj.SensorDrift(_lugre(rational)).without_drift()
    assert isinstance(inner, fj.LuGre)


def test_elements_say_where_they_slip():
    nlr = fj.MaxwellSlip.nlr(k=[1e5, 1e5], thresholds=[1e-6, 4e-6])
    state = nlr.init_state()
    sample = fj.Motion.from_position(np.array([0.0, 2e-6]), dt=1e-3).samples(nlr.requires)
    step = type(sample)(*(None if leaf is None or np.ndim(leaf) == 0 else np.asarray(leaf)[-1] for leaf in sample))
    new_state, _ = nlr.step(state, step)
    np.testing.assert_array_equal(np.asarray(nlr.slipping(state, new_state, step)), [1.0, 0.0])
    assert fj.Coulomb(Fc=1.0).slipping(None, None, step) is None
