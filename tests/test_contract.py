"""The v2 model contract, exercised through public names only with models written here, not in the library.

1. A polynomial NARX (about 20 lines below) against independent NumPy loops: one-step-ahead (teacher forcing
   through `feedback`), k-step-ahead and free-run prediction by `fj.simulate`; its identification by `fj.fit`
   with `fj.OneStepLoss()` and `fj.SimulationLoss()`.
2. The MLP-NARX probe: a 1,249-parameter network trained by `fj.fit` with its defaults (Adam 1e-2, no
   parameter scaling) must train as well as a plain optax loop from the same start; `freeze=` by dotted path.
3. A system model (`fj.EMPSOpenLoop`) through the same `fj.simulate`, and the error for the wrong input kind.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import fricjax as fj

# ----------------------------------------------------------------------------------------------------------------
# a polynomial NARX written against the contract
# ----------------------------------------------------------------------------------------------------------------


def monomials(v, y1, y2):
    """The NARX regressors phi(v_k, y_{k-1}, y_{k-2}): 1, v, v^2, y1, y2, v*y1 (NumPy or JAX scalars)."""
    return (v * 0.0 + 1.0, v, v * v, y1, y2, v * y1)


class PolyNARX(fj.AbstractFrictionModel):
    """`y_k = theta . phi(v_k, y_{k-1}, y_{k-2})`; state `(y_{k-1}, y_{k-2})`."""

    theta: jax.Array

    requires: ClassVar[frozenset[str]] = frozenset({"v"})

    def init_state(self):
        zero = jnp.zeros((), self.theta.dtype)
        return zero, zero

    def step(self, state, sample):
        y1, y2 = state
        y = jnp.dot(self.theta, jnp.stack(monomials(sample.v, y1, y2)))
        return (y, y1), y

    def feedback(self, state, y_measured):
        # after step k the state is (yhat_k, y_{k-1}): the newest entry is the prediction and is replaced by the
        # measurement; y_{k-1} in the second slot was itself put there by the previous feedback (measured)
        _, y1 = state
        return y_measured, y1


# Linear part y_k = 1.2 y_{k-1} - 0.5 y_{k-2} (poles of modulus sqrt(0.5)); with the v*y1 term the effective
# y_{k-1} coefficient is 1.2 + 0.1 v, inside the stability triangle |a1| < 1.5 for |v| < 3 (here |v| < 1.3).
THETA = np.array([0.05, 0.8, -0.3, 1.2, -0.5, 0.1])
T_NARX = 1500
NOISE = 0.01  # measurement noise on y, as a fraction of std(y)


def numpy_free_run(theta, v, y1=0.0, y2=0.0):
    y = np.empty(len(v))
    for k, vk in enumerate(v):
        y[k] = theta @ np.array(monomials(vk, y1, y2))
        y1, y2 = y[k], y1
    return y


def numpy_one_step(theta, v, measured):
    past = np.concatenate([[0.0, 0.0], measured])  # past[k + 1] = y_{k-1}, past[k] = y_{k-2}
    return np.array([theta @ np.array(monomials(v[k], past[k + 1], past[k])) for k in range(len(v))])


def numpy_k_step(theta, v, measured, k):
    """Sample t: a free run of k steps from the state built from the measurements up to t - k (zeros before
    the record), so samples 0 .. k-1 are the free run from rest."""
    past = np.concatenate([[0.0, 0.0], measured])
    out = np.empty(len(v))
    for t in range(len(v)):
        start = t - k + 1  # first sample of the window; its state holds y_{start-1}, y_{start-2}
        if start <= 0:
            y1 = y2 = 0.0
            start = 0
        else:
            y1, y2 = past[start + 1], past[start]
        out[t] = numpy_free_run(theta, v[start : t + 1], y1, y2)[-1]
    return out


@pytest.fixture(scope="module")
def narx():
    """A multisine velocity record, the NARX's clean free-run output and a noisy measurement of it."""
    rng = np.random.default_rng(0)
    t = np.arange(T_NARX) * 1e-3
    freqs = np.array([1.3, 3.1, 7.7, 17.0, 41.0])  # Hz
    v = sum(0.3 * np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, rng.uniform(0, 2 * np.pi, 5), strict=True))
    motion = fj.Motion.from_velocity(v, dt=1e-3)
    clean = numpy_free_run(THETA, v)
    noisy = clean + NOISE * np.std(clean) * rng.normal(size=T_NARX)
    return v, motion, clean, noisy


def test_narx_one_step_matches_numpy(narx):
    v, motion, _, noisy = narx
    model = PolyNARX(jnp.asarray(THETA))
    predicted = np.asarray(fj.simulate(model, motion, measured=noisy))
    np.testing.assert_allclose(predicted, numpy_one_step(THETA, v, noisy), rtol=0, atol=1e-12)
    # teacher forcing is not a no-op here: the measurement noise moves the prediction away from the free run
    assert np.max(np.abs(predicted - np.asarray(fj.simulate(model, motion)))) > NOISE * np.std(noisy)


@pytest.mark.parametrize("k", [1, 3])
def test_narx_k_step_matches_numpy(narx, k):
    v, motion, _, noisy = narx
    model = PolyNARX(jnp.asarray(THETA))
    predicted = np.asarray(fj.simulate(model, motion, measured=noisy, horizon=k))
    np.testing.assert_allclose(predicted, numpy_k_step(THETA, v, noisy, k), rtol=0, atol=1e-12)
    if k == 1:
        np.testing.assert_array_equal(predicted, np.asarray(fj.simulate(model, motion, measured=noisy)))


def test_narx_long_horizon_is_free_run(narx):
    _, motion, _, noisy = narx
    model = PolyNARX(jnp.asarray(THETA))
    free = np.asarray(fj.simulate(model, motion))
    for k in (T_NARX, T_NARX + 7):
        np.testing.assert_allclose(fj.simulate(model, motion, measured=noisy, horizon=k), free, rtol=0, atol=1e-12)


def test_narx_free_run_matches_numpy(narx):
    v, motion, clean, _ = narx  # clean = numpy_free_run(THETA, v)
    model = PolyNARX(jnp.asarray(THETA))
    np.testing.assert_allclose(fj.simulate(model, motion), clean, rtol=0, atol=1e-12)
    # a state at rest is not special: the free run from any state0 follows the NumPy loop from it
    state0 = (jnp.asarray(0.4), jnp.asarray(-0.2))
    expected = numpy_free_run(THETA, v, 0.4, -0.2)
    np.testing.assert_allclose(fj.simulate(model, motion, state0), expected, rtol=0, atol=1e-12)


def test_narx_fit_one_step(narx):
    """The one-step loss is quadratic in theta, so its minimiser is the linear least-squares solution of the
    regression on measured outputs: Levenberg-Marquardt must reach it to solver precision (1e-8 relative),
    from a start 30 % off. On clean data that solution is the true theta itself; on noisy data it is not (the
    regressors y_{k-1}, y_{k-2} carry the noise: the equation-error bias, about 10 % here), so the noisy fit is
    checked against the least-squares oracle, not against the truth."""
    v, motion, clean, noisy = narx
    start = PolyNARX(jnp.asarray(THETA * np.array([1.3, 0.7, 1.3, 0.7, 1.3, 0.7])))
    past = np.concatenate([[0.0, 0.0], noisy])
    regressors = np.array([monomials(v[k], past[k + 1], past[k]) for k in range(T_NARX)])
    lstsq = np.linalg.lstsq(regressors, noisy, rcond=None)[0]
    for force, expected in ((noisy, lstsq), (clean, THETA)):
        data = fj.FrictionData(motion, force)
        result = fj.fit(start, data, loss=fj.OneStepLoss(), solver=fj.levenberg_marquardt(), steps=50)  # ~23 used
        assert result.code == "successful", result.message
        np.testing.assert_allclose(result.model.theta, expected, rtol=1e-8, atol=1e-10)


def test_narx_fit_simulation(narx):
    """Output-error fit on clean data: the true theta is a zero-residual minimum, so Levenberg-Marquardt
    converges to it to solver precision from a start 5 % off (close enough for a stable free run)."""
    _, motion, clean, _ = narx
    start = PolyNARX(jnp.asarray(THETA * np.array([1.05, 0.95, 1.05, 0.95, 1.05, 0.95])))
    data = fj.FrictionData(motion, clean)
    result = fj.fit(start, data, loss=fj.SimulationLoss(), solver=fj.levenberg_marquardt(), steps=50)
    assert result.code == "successful", result.message
    np.testing.assert_allclose(result.model.theta, THETA, rtol=1e-6, atol=1e-8)
    assert result.train_loss < 1e-12


def test_one_step_loss_refuses_physics_model(narx):
    _, motion, clean, _ = narx
    data = fj.FrictionData(motion, clean)
    physics = fj.CoulombViscous(Fc=1.0, Fv=0.5, smoothing=fj.Smooth(1e-2))
    with pytest.raises(TypeError, match="feeds back no outputs"):
        fj.OneStepLoss()(physics, None, data)
    with pytest.raises(TypeError, match="feeds back no outputs"):
        fj.fit(physics, data, loss=fj.OneStepLoss(), steps=2)


# ----------------------------------------------------------------------------------------------------------------
# the MLP-NARX probe: fj.fit's defaults against a plain optax loop
# ----------------------------------------------------------------------------------------------------------------

MLP_STEPS = 300
MLP_SAMPLES = 1000


class MLPNARX(fj.AbstractFrictionModel):
    """`y_k = mlp(x_k, v_k, y_{k-1}, y_{k-2})` in normalised units; state `(y_{k-1}, y_{k-2})`."""

    mlp: eqx.nn.MLP

    requires: ClassVar[frozenset[str]] = frozenset({"x", "v"})

    def init_state(self):
        zero = jnp.zeros((), self.mlp.layers[0].weight.dtype)
        return zero, zero

    def step(self, state, sample):
        y1, y2 = state
        y = self.mlp(jnp.stack([sample.x, sample.v, y1, y2]))
        return (y, y1), y

    def feedback(self, state, y_measured):
        _, y1 = state
        return y_measured, y1


@pytest.fixture(scope="module")
def friction_record():
    """The first 1000 samples of the sliding tribometer's training split, each signal scaled to unit std."""
    train = fj.make_tribometer("sliding", seed=0).train.slice(0, MLP_SAMPLES)
    x, v, force = (np.asarray(a) for a in (train.motion.x, train.motion.v, train.force))
    motion = fj.Motion(x=(x - x.mean()) / x.std(), v=v / v.std(), dt=train.motion.dt)
    return fj.FrictionData(motion, (force - force.mean()) / force.std())


@pytest.fixture(scope="module")
def mlp_start():
    model = MLPNARX(eqx.nn.MLP(in_size=4, out_size="scalar", width_size=32, depth=2, key=jax.random.PRNGKey(0)))
    params = eqx.filter(model, eqx.is_inexact_array)
    assert sum(leaf.size for leaf in jax.tree_util.tree_leaves(params)) == 1249
    return model


def one_step_loss(model, data):
    """Written from the contract, not from fj.OneStepLoss: NMSE (as a fraction) of the one-step prediction."""
    predicted = fj.simulate(model, data.motion, measured=data.force)
    return jnp.mean((predicted - data.force) ** 2) / jnp.var(data.force)


@pytest.fixture(scope="module")
def plain_loop(mlp_start, friction_record):
    """300 Adam(1e-2) steps of `eqx.filter_value_and_grad` over the inexact arrays; the final training loss."""
    optimiser = optax.adam(1e-2)
    params, static = eqx.partition(mlp_start, eqx.is_inexact_array)

    @eqx.filter_jit
    def update(params, opt_state):
        value, grads = eqx.filter_value_and_grad(lambda p: one_step_loss(eqx.combine(p, static), friction_record))(
            params
        )
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return eqx.apply_updates(params, updates), opt_state, value

    opt_state = optimiser.init(params)
    for _ in range(MLP_STEPS):
        params, opt_state, _ = update(params, opt_state)
    model = eqx.combine(params, static)
    return model, float(one_step_loss(model, friction_record))


@pytest.mark.slow
def test_mlp_narx_fit_matches_plain_optax(mlp_start, friction_record, plain_loop):
    start_loss = float(one_step_loss(mlp_start, friction_record))
    result = fj.fit(mlp_start, friction_record, loss=fj.OneStepLoss(), steps=MLP_STEPS)
    _, plain_loss = plain_loop
    print(f"MLP-NARX one-step loss: start {start_loss:.4g}, fj.fit {result.train_loss:.4g}, plain {plain_loss:.4g}")
    assert result.success, result.message
    assert plain_loss < 0.1 * start_loss  # the probe is meaningful: the plain loop does train
    assert result.train_loss <= 1.1 * plain_loss
    # fj.fit's loss is the same quantity (force has unit std and zero mean, so std-normalised = var-normalised)
    assert result.train_loss == pytest.approx(float(one_step_loss(result.model, friction_record)), rel=1e-9)


@pytest.mark.slow
def test_mlp_narx_freeze_by_path(mlp_start, friction_record):
    result = fj.fit(mlp_start, friction_record, loss=fj.OneStepLoss(), steps=30, freeze="mlp.layers.0")
    before, after = mlp_start.mlp.layers, result.model.mlp.layers
    np.testing.assert_array_equal(after[0].weight, before[0].weight)
    np.testing.assert_array_equal(after[0].bias, before[0].bias)
    for i in (1, 2):
        assert not np.array_equal(after[i].weight, before[i].weight)
        assert not np.array_equal(after[i].bias, before[i].bias)
    assert result.train_loss < float(one_step_loss(mlp_start, friction_record))
    lines = result.summary().splitlines()
    assert len(lines) < 30, result.summary()


# ----------------------------------------------------------------------------------------------------------------
# a system model through the same driver
# ----------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def emps():
    plant = fj.EMPSPlant(95.1, fj.CoulombViscous(Fc=20.4, Fv=203.5, offset=-3.2, smoothing=fj.Smooth(1e-3)))
    t = np.arange(2000) * 1e-3
    vir = 1.5 * np.sin(2 * np.pi * 0.7 * t) + 0.4 * np.sin(2 * np.pi * 5.3 * t + 1.0)
    return plant, vir


def test_emps_open_loop_system_matches_simulate_open_loop(emps):
    plant, vir = emps
    system = fj.EMPSOpenLoop(plant, jnp.asarray(35.15), 3)
    record = fj.InputRecord(dt=1e-3, vir=vir)
    q, qd = fj.simulate(system, record)
    reference = fj.simulate_open_loop(plant, vir, 35.15, 1e-3, substeps=3)
    assert np.max(np.abs(np.asarray(reference.q))) > 1e-3  # the axis moves
    np.testing.assert_allclose(q, reference.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(qd, reference.qd, rtol=0, atol=1e-12)
    q, qd = fj.simulate(system, record, (jnp.asarray(0.1), jnp.asarray(-0.02)))
    reference = fj.simulate_open_loop(plant, vir, 35.15, 1e-3, q0=0.1, qd0=-0.02, substeps=3)
    np.testing.assert_allclose(q, reference.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(qd, reference.qd, rtol=0, atol=1e-12)


def test_wrong_input_kind_is_a_type_error(emps):
    plant, vir = emps
    system = fj.EMPSOpenLoop(plant, jnp.asarray(35.15), 1)
    motion = fj.Motion.from_velocity(np.zeros(100), dt=1e-3)
    with pytest.raises(TypeError, match="InputRecord"):
        fj.simulate(system, motion)
    with pytest.raises(TypeError, match="Motion"):
        fj.simulate(PolyNARX(jnp.asarray(THETA)), fj.InputRecord(dt=1e-3, vir=vir))


def test_ensemble_of_narx_members_is_teacher_forced(narx):
    v, motion, _, noisy = narx
    model = PolyNARX(jnp.asarray(THETA))
    ensemble = fj.AverageEnsemble([model, model, fj.Coulomb(Fc=1e-9)])  # the physics member ignores feedback
    expected = (2 * numpy_one_step(THETA, v, noisy) + 1e-9 * np.sign(v)) / 3
    np.testing.assert_allclose(fj.simulate(ensemble, motion, measured=noisy), expected, rtol=0, atol=1e-12)
    loss = fj.OneStepLoss()(ensemble, None, fj.FrictionData(motion, noisy))
    assert np.isfinite(float(loss))
    with pytest.raises(TypeError, match="feeds back no outputs"):  # no member feeds back
        fj.OneStepLoss()(fj.AverageEnsemble([fj.Coulomb(Fc=1.0)]), None, fj.FrictionData(motion, noisy))


def test_split_keeps_acceleration_and_normal_load():
    t = np.arange(200) * 1e-3
    motion = fj.Motion(x=np.sin(t), v=np.cos(t), dt=1e-3, a=-np.sin(t), normal_force=10.0 + t)
    head, tail = fj.FrictionData(motion, np.cos(t)).split(0.5)
    np.testing.assert_array_equal(tail.motion.normal_force, 10.0 + t[100:])
    np.testing.assert_array_equal(head.motion.a, -np.sin(t[:100]))


def test_system_substeps_are_checked(emps):
    plant, _ = emps
    with pytest.raises(ValueError, match="substeps"):
        fj.EMPSOpenLoop(plant, jnp.asarray(35.15), 0)
    with pytest.raises(ValueError, match="substeps"):
        fj.EMPSClosedLoop(plant, *(jnp.asarray(g) for g in (35.15, 160.18, 243.45, 10.0)), 0)


def test_float32_model_is_teacher_forced_by_float64_measurements(narx):
    v, _, _, noisy = narx
    motion32 = fj.Motion.from_velocity(np.asarray(v, np.float32), dt=np.float32(1e-3))
    model32 = PolyNARX(jnp.asarray(THETA, jnp.float32))
    predicted = fj.simulate(model32, motion32, measured=np.asarray(noisy))  # float64 measurements
    assert predicted.dtype == jnp.float32
    np.testing.assert_allclose(predicted, numpy_one_step(THETA, v, noisy), rtol=1e-4, atol=1e-4)
    k_step = fj.simulate(model32, motion32, measured=np.asarray(noisy), horizon=3)
    np.testing.assert_allclose(k_step, numpy_k_step(THETA, v, noisy, 3), rtol=1e-4, atol=1e-4)


def test_horizon_of_a_model_without_feedback_is_its_free_run():
    motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6, 300)), dt=1e-3)
    model = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4)
    free = fj.simulate(model, motion)
    np.testing.assert_array_equal(fj.simulate(model, motion, measured=np.zeros(300), horizon=5), free)


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="shape \\(T,\\)"):
        fj.InputRecord(dt=1e-3, vir=np.zeros((3, 40)))
    with pytest.raises(ValueError, match="burn_in"):
        fj.OneStepLoss(burn_in=-1)
    lugre = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4)
    no_dt = fj.FrictionData(fj.Motion(x=np.zeros(50), v=np.zeros(50)), np.zeros(50))
    with pytest.raises(ValueError, match="sample time"):
        fj.fit(lugre, no_dt, steps=1)
    with pytest.raises(ValueError, match="gtau"):
        fj.EMPSOpenLoop(fj.EMPSPlant(95.0, fj.CoulombViscous(Fc=20.0, Fv=200.0)), -1.0)
