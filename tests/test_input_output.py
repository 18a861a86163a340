"""`fj.InputOutputModel`: a friction model driven by a named signal of an `fj.InputRecord` (Bouc-Wen black boxes)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

DT = 1e-3


@pytest.fixture(scope="module")
def signals():
    rng = np.random.default_rng(0)
    u = np.cumsum(rng.normal(size=200)) * 0.1
    y = np.sin(np.arange(200) / 9.0) + 0.05 * rng.normal(size=200)
    return u, y


@pytest.fixture(scope="module")
def narx(signals):
    u, y = signals
    regressors = fj.NARXRegressors.from_data(fj.input_output_data(u, y, DT), ("x", "v"), input_lags=2, output_lags=3)
    return fj.MLPNARX.init(regressors, 5, key=jax.random.PRNGKey(1), linear=True)


@pytest.mark.slow  # fast tier trimmed (2026-11-27): its gradients test runs the same wrapper fast
def test_runs_the_model_on_the_signal_as_its_displacement(narx, signals):
    u, y = signals
    system = fj.InputOutputModel(narx, "force_in")
    record = fj.InputRecord(dt=DT, force_in=u)
    motion = fj.Motion(x=u, dt=DT)
    np.testing.assert_array_equal(fj.simulate(system, record), fj.simulate(narx, motion))
    # teacher forcing reaches the wrapped NARX's fed-back outputs
    one_step = fj.simulate(system, record, measured=y, horizon=1)
    np.testing.assert_array_equal(one_step, fj.simulate(narx, motion, measured=y, horizon=1))
    assert not np.allclose(one_step, fj.simulate(system, record))


def test_gradients_equal_the_wrapped_models(narx, signals):
    u, y = signals
    record, motion = fj.InputRecord(dt=DT, u=u), fj.Motion(x=u, dt=DT)

    def loss(model, run):
        return jnp.mean((run(model) - y) ** 2)

    wrapped = eqx.filter_grad(lambda m: loss(m, lambda m: fj.simulate(fj.InputOutputModel(m), record)))(narx)
    direct = eqx.filter_grad(lambda m: loss(m, lambda m: fj.simulate(m, motion)))(narx)
    np.testing.assert_allclose(wrapped.W, direct.W, rtol=1e-12, atol=1e-15)
    assert np.all(np.isfinite(wrapped.W)) and np.any(wrapped.W != 0)


def test_a_physics_model_also_runs_on_a_signal(signals):
    u, _ = signals
    model = fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 0.1), sigma0=1e3, sigma1=1.0, sigma2=0.1)
    record = fj.InputRecord(dt=DT, u=u * 1e-3)
    np.testing.assert_array_equal(
        fj.simulate(fj.InputOutputModel(model), record), fj.simulate(model, fj.Motion(x=u * 1e-3, dt=DT))
    )


def test_bad_input_is_named(narx, signals):
    u, y = signals
    with pytest.raises(TypeError, match="friction model"):
        fj.InputOutputModel(fj.BoucWen.benchmark(), "u")
    with pytest.raises(ValueError, match="`signal`"):
        fj.InputOutputModel(narx, "dt")
    with pytest.raises(ValueError, match=r"needs the input signals \['u'\]"):
        fj.simulate(fj.InputOutputModel(narx, "u"), fj.InputRecord(dt=DT, w=u))
    with pytest.raises(ValueError, match="one shape"):
        fj.input_output_data(u, y[:-1], DT)
