"""Multi-start as one vmap-ed program with screening (`fj.MultiStart(count, keep=...)`) and log-uniform draws."""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
import pytest

import fricjax as fj

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def record() -> fj.FrictionData:
    t = np.arange(600) * 1e-3
    motion = fj.Motion.from_position(2e-3 * np.sin(2 * np.pi * 2 * t), dt=1e-3)
    truth = fj.Tustin(Fc=1.0, Fs=1.5, vs=2e-3, Fv=30.0, smoothing=fj.Smooth(1e-4))
    return fj.FrictionData(motion, fj.simulate(truth, motion))


def test_log_uniform_draws_stay_in_their_band():
    model = fj.Tustin(Fc=1.0, Fs=1.5, vs=2e-3, Fv=30.0, offset=0.5)
    params, static = eqx.partition(model, eqx.is_inexact_array)
    starts = fj.MultiStart(200, spread=np.log(3.0), distribution="log-uniform").draw(params, seed=1)
    vs = np.asarray(jax.vmap(lambda p: fj.unwrap(eqx.combine(p, static)).vs)(starts))
    assert vs[0] == pytest.approx(2e-3)  # the first start is the model itself
    assert np.all(vs >= 2e-3 / 3 * (1 - 1e-12)) and np.all(vs <= 2e-3 * 3 * (1 + 1e-12))
    assert vs.min() < 2e-3 / 2 and vs.max() > 2e-3 * 2  # spread over the band, not clustered
    offsets = np.asarray(jax.vmap(lambda p: fj.unwrap(eqx.combine(p, static)).offset)(starts))
    assert np.all(np.abs(offsets - 0.5) <= np.log(3.0) * 0.5 + 1e-12)


def test_screening_keeps_the_best_and_reports_it(record):
    start = fj.Tustin(Fc=0.5, Fs=3.0, vs=1e-3, Fv=10.0, smoothing=fj.Smooth(1e-4))
    common = {"solver": fj.levenberg_marquardt(), "steps": 40, "eval_every": 5, "tolerance": 1e-12}
    screened = fj.fit(start, record, multistart=fj.MultiStart(8, spread=1.0, keep=2, screen=0.25), **common)
    assert screened.num_starts == 8
    assert "all 8 starts screened, the best" in screened.message
    assert 0 <= screened.best_start < 8
    assert screened.history["train_loss"].shape == screened.history["step"].shape
    assert np.all(np.isfinite(screened.history["train_loss"]))  # the chosen start's row never dropped
    single = fj.fit(start, record, **common)
    assert screened.train_loss <= single.train_loss * (1 + 1e-9)


def test_multistart_options_are_checked():
    with pytest.raises(ValueError, match="`distribution` must be"):
        fj.MultiStart(4, distribution="uniform")
    with pytest.raises(ValueError, match="`screen` must be a fraction"):
        fj.MultiStart(4, keep=2, screen=1.0)
    with pytest.raises(ValueError, match="keep"):
        fj.MultiStart(4, keep=0)
