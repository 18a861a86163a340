"""Ensembles: simple average (parlitz2004 §IV-H), least-squares weights with intercept (emps-ensemble §3.3) and
PRESS orthogonal forward selection (worden2007 §7); an ensemble is a friction model that `simulate` runs in one
scan."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj
from fricjax import AverageEnsemble, WeightedEnsemble, fit_weighted_ensemble, select_forward

DT = 1e-3
N_SAMPLES = 1200


class Playback(fj.AbstractFrictionModel):
    """A test member that replays a fixed force record (noise, zeros, NaN), reading no signal."""

    signal: jax.Array
    requires: ClassVar[frozenset[str]] = frozenset()

    def init_state(self) -> jax.Array:
        return jnp.zeros((), jnp.int32)

    def step(self, state, sample):
        return state + 1, self.signal[state]


def _motion(n: int = N_SAMPLES) -> fj.Motion:
    """Three stationary tones: gross sliding (1.5 mm), reversals inside it and a pre-sliding ripple (20 um)."""
    t = np.arange(n) * DT
    x = 1.5e-3 * np.sin(2 * np.pi * 3 * t) + 3e-4 * np.sin(2 * np.pi * 11 * t + 0.3) + 2e-5 * np.sin(2 * np.pi * 37 * t)
    return fj.Motion.from_position(x, dt=DT)


def _members() -> list[fj.AbstractFrictionModel]:
    """Four imperfect models of the GMS truth below, of four families reading different signals."""
    return [
        fj.LuGre(fj.ExponentialStribeck(Fc=0.9, Fs=1.6, vs=1.5e-3, delta=2.0), sigma0=5e4, sigma1=200.0, sigma2=35.0),
        fj.Dahl(sigma0=3e4, Fc=1.1),
        fj.MaxwellSlip.nlr(k=[2e5, 1e5, 5e4], thresholds=[2e-6, 6e-6, 2e-5]),
        fj.Tustin(Fc=1.0, Fs=1.4, vs=1e-3, Fv=45.0, smoothing=fj.Smooth(1e-4)),
    ]


@pytest.fixture(scope="module")
def setup():
    motion = _motion()
    truth = fj.GMS(
        fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0),
        k=[4e4, 2e4, 1e4, 5e3],
        alpha=[0.4, 0.3, 0.2, 0.1],
        C=20.0,
        sigma2=40.0,
    )
    noise = 0.02 * np.random.default_rng(0).standard_normal(motion.length)
    data = fj.FrictionData(motion, fj.simulate(truth, motion) + noise)
    members = _members()
    predictions = np.stack([np.asarray(fj.simulate(m, motion)) for m in members])
    return motion, data, members, predictions


def test_average_equals_mean_of_member_simulations(setup):
    motion, _, members, predictions = setup
    ensemble = AverageEnsemble(members)
    assert ensemble.requires == frozenset({"x", "v", "dt"})  # Dahl x, LuGre v + dt, Tustin v
    np.testing.assert_allclose(fj.simulate(ensemble, motion), predictions.mean(axis=0), rtol=1e-12, atol=1e-14)


def test_weighted_simulate_equals_combination_and_step_loop(setup):
    motion, _, members, predictions = setup
    weights, intercept = np.array([0.5, -0.25, 1.5, 0.125]), 0.3
    ensemble = WeightedEnsemble(members, weights, intercept)
    expected = intercept + weights @ predictions
    force = fj.simulate(ensemble, motion)
    np.testing.assert_allclose(force, expected, rtol=1e-12, atol=1e-13)
    # the state is the tuple of the members' states; a Python loop over `step` gives the scan's result
    samples = motion.samples(ensemble.requires)
    step = eqx.filter_jit(ensemble.step)  # one compile instead of 50 eager steps
    state, looped = ensemble.init_state(), []
    for k in range(50):
        sample = samples.at(k)
        state, f = step(state, sample)
        looped.append(f)
    assert len(state) == len(members)
    np.testing.assert_allclose(np.asarray(looped), force[:50], rtol=1e-12, atol=1e-13)


def test_weighted_fit_recovers_known_weights_and_intercept(setup):
    motion, _, members, predictions = setup
    weights, intercept = np.array([0.7, -0.3, 1.5, 0.2]), -0.4
    data = fj.FrictionData(motion, intercept + weights @ predictions)
    fitted = fit_weighted_ensemble(members, data)  # simulates the members (compiled by the fixture already)
    np.testing.assert_allclose(fitted.weights, weights, rtol=1e-9)
    np.testing.assert_allclose(fitted.intercept, intercept, rtol=1e-9)
    # precomputed predictions give the same fit without re-simulating
    again = fit_weighted_ensemble(members, data, predictions=predictions)
    np.testing.assert_allclose(again.weights, fitted.weights, rtol=1e-12)
    np.testing.assert_allclose(again.intercept, fitted.intercept, rtol=1e-12)
    np.testing.assert_allclose(fj.simulate(fitted, motion), data.force, rtol=1e-9, atol=1e-9)
    # the old spelling still works, with a deprecation warning, and gives the same ensemble
    with pytest.warns(DeprecationWarning, match="fj.fit_weighted_ensemble"):
        old = WeightedEnsemble.fit(members, data, predictions=predictions)
    np.testing.assert_array_equal(old.weights, again.weights)
    np.testing.assert_array_equal(old.intercept, again.intercept)


def test_weighted_fit_collinear_members_share_the_weight(setup):
    motion, _, members, predictions = setup
    # two copies of one member and a constant member (spanned by the intercept): min-norm, still exact
    data = fj.FrictionData(motion, 0.2 + predictions[0])
    constant = Playback(jnp.full(motion.length, 3.0))
    forces = np.stack([predictions[0], predictions[0], np.full(motion.length, 3.0)])
    fitted = fit_weighted_ensemble([members[0], members[0], constant], data, predictions=forces)
    np.testing.assert_allclose(fitted.weights, [0.5, 0.5, 0.0], atol=1e-9)
    np.testing.assert_allclose(fitted.intercept, 0.2, atol=1e-9)


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the ensemble fit is checked fast
def test_fitted_ensemble_no_worse_than_best_member(setup):
    motion, data, members, predictions = setup
    validation, test = data.split(0.5)
    t_val = validation.length
    ensemble = fit_weighted_ensemble(members, validation, predictions=predictions[:, :t_val])
    force = np.asarray(fj.simulate(ensemble, motion))  # the fitted ensemble, simulated over both splits
    ens_val = float(fj.nmse(validation.force, force[:t_val]))
    ens_test = float(fj.nmse(test.force, force[t_val:]))
    single_val = [float(fj.nmse(validation.force, p[:t_val])) for p in predictions]
    single_test = [float(fj.nmse(test.force, p[t_val:])) for p in predictions]
    # On the fitting data this is exact: each member alone (weight 1, intercept 0) and each member with its own
    # LS weight + intercept are special cases of the joint least-squares problem.
    assert ens_val <= min(single_val) * (1 + 1e-12)
    for i in range(len(members)):
        alone = fit_weighted_ensemble([members[i]], validation, predictions=predictions[i : i + 1, :t_val])
        alone_force = alone.intercept + alone.weights[0] * predictions[i, :t_val]
        assert ens_val <= float(fj.nmse(validation.force, alone_force)) * (1 + 1e-12)
    # On held-out data it is not a theorem: least squares is optimistic on its own data by about
    # p / T_val of the residual (p = N + 1 fitted coefficients), so over a record of the same stationary motion
    # the ensemble may lose at most a few times that to the best member. (Here it wins by far.)
    p = len(members) + 1
    assert ens_test <= min(single_test) + 3 * ens_val * p / t_val
    assert ens_test < 0.5 * min(single_test)
    average = predictions.mean(axis=0)
    assert ens_test < float(fj.nmse(test.force, average[t_val:]))


def _press_oracle(columns: np.ndarray, y: np.ndarray) -> float:
    """Leave-one-out by refitting T times: the definition of PRESS."""
    design = np.column_stack([np.ones_like(y), *columns])
    errors = []
    for k in range(y.size):
        keep = np.arange(y.size) != k
        theta, *_ = np.linalg.lstsq(design[keep], y[keep], rcond=None)
        errors.append(y[k] - design[k] @ theta)
    return float(np.sum(np.square(errors)))


def test_select_forward_picks_informative_members_and_skips_useless_ones(setup):
    motion, _, members, predictions = setup
    rng = np.random.default_rng(0)
    target = 0.3 + 0.8 * predictions[0] + 0.5 * predictions[2] + 0.05 * rng.standard_normal(motion.length)
    data = fj.FrictionData(motion, target)
    candidates = [
        members[0],
        Playback(jnp.zeros(motion.length)),  # constant zero: adds nothing
        Playback(jnp.asarray(rng.standard_normal(motion.length))),  # pure noise
        members[2],
        Playback(jnp.full(motion.length, 2.0)),  # a constant: spanned by the intercept
    ]
    selection = select_forward(candidates, data)
    # A pure-noise regressor lowers the residual sum of squares by sigma^2 chi^2_1 but raises PRESS by about
    # 2 sigma^2, so PRESS rejects it unless chi^2_1 > 2 (about 1 draw in 7); this seed draws a typical noise record.
    assert selection.indices == (0, 3)
    assert len(selection.press) == 3 and selection.press[0] > selection.press[1] > selection.press[2]
    np.testing.assert_allclose(selection.ensemble.weights, [0.8, 0.5], rtol=2e-2)
    np.testing.assert_allclose(selection.ensemble.intercept, 0.3, atol=2e-2)
    assert selection.ensemble.members == (members[0], members[2])


@pytest.mark.slow  # fast tier trimmed (2026-11-27): forward selection is checked fast
def test_select_forward_press_equals_leave_one_out_refits(setup):
    _, _, members, predictions = setup
    n = 120  # the oracle refits n times
    rng = np.random.default_rng(1)
    candidates = np.stack([predictions[0][:n], predictions[1][:n], rng.standard_normal(n), predictions[3][:n]])
    target = 0.1 + candidates[0] - 0.4 * candidates[1] + 0.3 * candidates[3] + 0.02 * rng.standard_normal(n)
    motion = _motion(n)
    data = fj.FrictionData(motion, target)
    selection = select_forward(members, data, predictions=candidates)
    assert sorted(selection.indices) == [0, 1, 3]  # the noise column (2) is left out
    assert selection.press[0] == pytest.approx(_press_oracle(candidates[:0], target), rel=1e-9)
    for size in range(1, len(selection.indices) + 1):
        chosen = candidates[list(selection.indices[:size])]
        assert selection.press[size] == pytest.approx(_press_oracle(chosen, target), rel=1e-9)
    # and it is the greedy choice: no other member would have given a lower PRESS at the first step
    first = min(range(4), key=lambda i: _press_oracle(candidates[[i]], target))
    assert selection.indices[0] == first


def test_select_forward_noise_free_max_members_and_rss(setup):
    motion, noisy, members, predictions = setup
    data = fj.FrictionData(motion, 0.3 + 0.8 * predictions[0] + 0.5 * predictions[2])
    noise = Playback(jnp.asarray(np.random.default_rng(2).standard_normal(motion.length)))
    candidates = [*members, noise]
    # exact combination: PRESS drops to round-off after the two true members, then nothing counts as a decrease
    forces = np.concatenate([predictions, np.asarray(noise.signal)[None]])
    selection = select_forward(candidates, data, predictions=forces)
    assert sorted(selection.indices) == [0, 2]
    np.testing.assert_allclose(selection.ensemble.weights, [0.8, 0.5][:: 1 if selection.indices[0] == 0 else -1])
    np.testing.assert_allclose(fj.simulate(selection.ensemble, motion), data.force, rtol=1e-9, atol=1e-9)
    assert select_forward(candidates, data, max_members=1, predictions=forces).indices == selection.indices[:1]
    # the residual sum of squares only stops at round-off: on noisy data it ranks every member
    ranked = select_forward(candidates, noisy, criterion="rss", predictions=forces)
    assert len(ranked.indices) == len(candidates)
    assert all(a >= b for a, b in zip(ranked.press[:-1], ranked.press[1:], strict=True))


def test_jit_vmap_and_gradient():
    motion = _motion(300)
    members = [fj.Tustin(Fc=1.0, Fs=1.4, vs=1e-3, Fv=45.0, smoothing=fj.Smooth(1e-4)), fj.Dahl(sigma0=3e4, Fc=1.1)]
    predictions = np.stack([np.asarray(fj.simulate(m, motion)) for m in members])
    ensemble = WeightedEnsemble(members, [0.75, 0.25], 0.1)
    reference = fj.simulate(ensemble, motion)
    # vmap over a batch of weights (an eqx.filter_vmap over constructors) and over motions
    batch = jnp.array([[1.0, 0.0], [0.0, 1.0], [0.2, 0.8]])
    forces = eqx.filter_vmap(lambda w: fj.simulate(WeightedEnsemble(members, w, 0.0), motion))(batch)
    np.testing.assert_allclose(forces, np.asarray(batch) @ predictions, rtol=1e-10, atol=1e-12)
    half = fj.Motion.from_position(0.5 * np.asarray(motion.x), dt=DT)
    motions = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), motion, half)
    batched = jax.vmap(lambda m: fj.simulate(ensemble, m))(motions)
    np.testing.assert_allclose(batched[0], reference, rtol=1e-12)
    np.testing.assert_allclose(batched[1], fj.simulate(ensemble, half), rtol=1e-12)
    # the gradient of the MSE with respect to the weights is (2 / T) F (yhat - y), through the scan
    y = jnp.asarray(predictions[0] ** 2)

    def loss(w):
        return jnp.mean((fj.simulate(WeightedEnsemble(members, w, 0.1), motion) - y) ** 2)

    grad = jax.jit(jax.grad(loss))(ensemble.weights)  # a user-side jit around simulate
    expected = 2.0 / motion.length * predictions @ (np.asarray(reference) - np.asarray(y))
    np.testing.assert_allclose(grad, expected, rtol=1e-9)


def test_exact_and_smoothing_reach_members(setup):
    _, _, members, _ = setup
    ensemble = AverageEnsemble(members)
    exact = fj.exact(ensemble)
    assert isinstance(exact.members[3].smoothing, fj.Exact)
    smooth = fj.with_smoothing(ensemble, fj.Smooth(1e-3))
    assert all(m.smoothing == fj.Smooth(1e-3) for m in smooth.members if hasattr(m, "smoothing"))


@pytest.mark.slow  # fast tier trimmed (2026-11-27): a dtype check
def test_float32_follows_dtype():
    motion = fj.Motion.from_position(np.float32(1e-3) * np.sin(np.linspace(0, 12, 300, dtype=np.float32)), dt=DT)
    members = [fj.Coulomb(Fc=np.float32(1.0)), fj.CoulombViscous(Fc=np.float32(0.5), Fv=np.float32(20.0))]
    target = 0.5 + 0.3 * fj.simulate(members[0], motion) + 0.8 * fj.simulate(members[1], motion)
    fitted = fit_weighted_ensemble(members, fj.FrictionData(motion, target))
    assert fitted.weights.dtype == jnp.float32
    np.testing.assert_allclose(fitted.weights, [0.3, 0.8], rtol=1e-4)
    assert fj.simulate(fitted, motion).dtype == jnp.float32
    assert fj.simulate(WeightedEnsemble(members, [1.0, 1.0]), motion).dtype == jnp.float32
    assert fj.simulate(AverageEnsemble(members), motion).dtype == jnp.float32


def test_errors(setup):
    motion, data, members, predictions = setup
    with pytest.raises(ValueError, match="`members` is empty"):
        AverageEnsemble([])
    with pytest.raises(TypeError, match="list or tuple"):
        AverageEnsemble(members[0])
    with pytest.raises(TypeError, match="member 1 must be a fricjax friction model"):
        WeightedEnsemble([members[0], "lugre"], [1.0, 1.0])
    with pytest.raises(ValueError, match=r"one entry per member, shape \(2,\)"):
        WeightedEnsemble(members[:2], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="`weights` must be finite"):
        WeightedEnsemble(members[:2], [1.0, np.nan])
    with pytest.raises(TypeError, match="must be a fricjax.FrictionData"):
        fit_weighted_ensemble(members, (motion, data.force))
    with pytest.raises(ValueError, match=r"shape \(4, 1200\), got \(4, 1199\)"):
        fit_weighted_ensemble(members, data, predictions=predictions[:, 1:])
    with pytest.raises(ValueError, match=r"shape \(4, 1200\), got \(3, 1200\)"):
        select_forward(members, data, predictions=predictions[:3])
    broken = Playback(jnp.asarray(predictions[0]).at[7].set(jnp.nan))
    with pytest.raises(ValueError, match=r"member 1 \(Playback\) predicts NaN or inf on `data` \(first at sample 7\)"):
        fit_weighted_ensemble([members[0], broken], data)
    with pytest.raises(ValueError, match="member 0 .* predicts NaN"):
        select_forward([broken], data)
    with pytest.raises(ValueError, match="`criterion` must be 'press' or 'rss'"):
        select_forward(members, data, criterion="aic")
    with pytest.raises(ValueError, match="`max_members` must be a positive integer"):
        select_forward(members, data, max_members=0)
    with pytest.raises(ValueError, match="no member lowers the PRESS"):
        select_forward([Playback(jnp.zeros(motion.length)), Playback(jnp.ones(motion.length))], data)
    with pytest.raises(ValueError, match="3 samples cannot fit 4 weights"):
        fit_weighted_ensemble(members, data.slice(0, 3))
    # simulate names the missing signal for the ensemble
    with pytest.raises(ValueError, match="AverageEnsemble integrates in time"):
        fj.simulate(AverageEnsemble(members), fj.Motion(v=np.ones(10)))
