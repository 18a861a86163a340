"""Bad input gets a clear ValueError / TypeError naming the argument and the fix."""

import numpy as np
import pytest

import fricjax as fj

from helpers import model_table, stribeck

X = np.linspace(0.0, 1e-3, 20)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"x": X, "v": np.zeros(19), "dt": 1e-3}, "same shape"),
        ({"x": np.r_[X[:5], np.nan, X[6:]], "dt": 1e-3}, "NaN or inf"),
        ({"v": np.r_[X[:5], np.inf, X[6:]], "dt": 1e-3}, "NaN or inf"),
        ({"x": X, "dt": 0.0}, "positive"),
        ({"x": X, "dt": -1e-3}, "positive"),
        ({"x": X, "dt": np.nan}, "positive"),
        ({"x": X, "dt": [1e-3, 1e-3]}, "scalar"),
        ({"dt": 1e-3}, "at least one"),
        ({"x": np.array([]), "dt": 1e-3}, "empty"),
        ({"x": 1.0, "dt": 1e-3}, "1-D"),
    ],
)
def test_motion_rejects_bad_records(kwargs, match):
    with pytest.raises(ValueError, match=match):
        fj.Motion(**kwargs)


def test_model_needing_x_given_only_v_without_dt():
    motion = fj.Motion(v=np.ones(10))
    with pytest.raises(ValueError, match="needs the displacement `x`"):
        fj.simulate(fj.MaxwellSlip.nlr(k=[1e5], thresholds=[1e-6]), motion)
    with pytest.raises(ValueError, match="needs the sample time"):
        fj.simulate(fj.LuGre(stribeck(), 1e5, 300.0, 0.0), motion)
    # a static curve needs only the velocity
    assert fj.simulate(fj.Coulomb(1.0), motion).shape == (10,)


def test_model_needing_v_given_only_x_without_dt():
    with pytest.raises(ValueError, match="needs the velocity `v`"):
        fj.simulate(fj.Coulomb(1.0), fj.Motion(x=X))


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda: fj.LuGre(stribeck(), sigma0=-1e5, sigma1=1.0, sigma2=0.0), "sigma0"),
        (lambda: fj.LuGre(stribeck(), sigma0=1e5, sigma1=-1.0, sigma2=0.0), "sigma1"),
        (lambda: fj.LuGre(stribeck(), sigma0=np.nan, sigma1=1.0, sigma2=0.0), "sigma0"),
        (lambda: fj.ExponentialStribeck(Fc=-1.0, Fs=1.5, vs=1e-3), "Fc"),
        (lambda: fj.RationalStribeck(Fc=1.0, Fs=1.5, vs=0.0), "vs"),
        (lambda: fj.MaxwellSlip.nlr(k=[1e5, 1e5], thresholds=[1e-6, -1e-6]), "thresholds"),
        (lambda: fj.MaxwellSlip.nlr(k=[1e5, -1e5], thresholds=[1e-6, 2e-6]), "k"),
        (lambda: fj.MaxwellSlip.nlr(k=[1e5], thresholds=[1e-6, 2e-6]), "k"),
        (lambda: fj.MaxwellSlip.lr(k=[1e5, 1e5], max_deflection=0.0), "thresholds"),
        (lambda: fj.MaxwellSlip.dnlrx(thresholds=[1e-6], theta=np.ones(3), c=[1.0]), "theta"),
        (lambda: fj.GMS(stribeck(), k=[1e4, -1e4], alpha=[0.5, 0.5], C=10.0), "k"),
        (lambda: fj.GMS(stribeck(), k=[1e4, 1e4], alpha=[0.5, 0.6], C=10.0), "sum to 1"),
        (lambda: fj.GMS(stribeck(), k=[1e4, 1e4], alpha=[0.5], C=10.0), "alpha"),
        (lambda: fj.GMS(stribeck(), k=[1e4, 1e4], alpha=[0.5, 0.5], C=0.0), "C"),
        (lambda: fj.Dahl(sigma0=1e5, Fc=0.0), "Fc"),
        (lambda: fj.Coulomb(Fc=[1.0, 2.0, 3.0]), "pair"),
        (lambda: fj.CoulombViscous(Fc=1.0, Fv=-2.0), "Fv"),
        (lambda: fj.Smooth(0.0), "eps"),
    ],
)
def test_invalid_parameters(build, match):
    with pytest.raises(ValueError, match=match):
        build()


def test_wrong_types():
    motion = fj.Motion.from_position(X, dt=1e-3)
    with pytest.raises(TypeError, match="must be a fricjax model"):
        fj.simulate("lugre", motion)
    with pytest.raises(TypeError, match="fricjax.Motion"):
        fj.simulate(fj.Coulomb(1.0), X)
    with pytest.raises(TypeError, match="Stribeck"):
        fj.LuGre(stribeck=1.0, sigma0=1e5, sigma1=1.0, sigma2=0.0)


def test_metrics_shape_mismatch():
    with pytest.raises(ValueError, match="same shape"):
        fj.nmse(np.ones(3), np.ones(4))


def test_every_model_rejects_nothing_valid():
    """The model table itself constructs without errors (guards the validators against false alarms)."""
    assert len(model_table()) > 10
