"""LuGre behind a linkage with backlash (`fj.LuGreBacklash`): the dead-zone bristle law against a fine-step NumPy
integration, the zero-force plateau of width `gap` after a reversal, steady sliding, the limit gap -> 0 (LuGre)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

DT = 1e-3


def _stribeck(Fc=1.0, Fs=1.5, vs=2e-3, delta=2.0):
    return fj.ExponentialStribeck(Fc=Fc, Fs=Fs, vs=vs, delta=delta)


def _reference(x, dt, Fc, Fs, vs, delta, sigma0, gap, substeps=400):
    """Explicit Euler in displacement, `substeps` per sample, of LuGre's bristle law on the total deflection `w`
    (slack crossed + elastic deflection): `dw = du - |du| z(w) sigma0 / s(v)`, `z(w) = sign(w) max(|w| - gap/2, 0)`,
    F = sigma0 z(w); the velocity held over each sample is `dx / dt` (as the model's)."""
    w, half, out = 0.0, gap / 2, [0.0]
    for k in range(1, len(x)):
        dx = x[k] - x[k - 1]
        v = dx / dt
        s = Fc + (Fs - Fc) * np.exp(-(abs(v / vs) ** delta))
        du = dx / substeps
        for _ in range(substeps):
            z = np.sign(w) * max(abs(w) - half, 0.0)
            w += du - abs(du) * z * sigma0 / s
        out.append(sigma0 * np.sign(w) * max(abs(w) - half, 0.0))
    return np.array(out)


def test_matches_a_fine_step_integration_of_the_dead_zone_bristle_law():
    t = np.arange(500) * DT
    x = (3e-4 * np.sin(2 * np.pi * 3 * t) + 8e-5 * np.sin(2 * np.pi * 17 * t)) * np.minimum(1.0, 3 * t)  # minor loops
    model = fj.LuGreBacklash(_stribeck(), sigma0=1e5, sigma1=0.0, sigma2=0.0, gap=1e-4)
    force = np.asarray(fj.simulate(model, fj.Motion.from_position(x, dt=DT)))
    reference = _reference(x, DT, 1.0, 1.5, 2e-3, 2.0, 1e5, 1e-4)
    assert np.max(np.abs(reference)) > 1.0  # the record slides ...
    assert np.mean(np.abs(reference) < 1e-12) > 0.05  # ... and crosses the gap
    np.testing.assert_allclose(force, reference, atol=5e-3)


def test_after_a_reversal_the_force_unloads_then_stays_zero_across_the_gap_then_loads():
    gap, length, step = 1e-3, 1e-5, 1e-6  # bristle relaxation length Fc / sigma0 = 10 um; 1 um per sample
    model = fj.LuGreBacklash(_stribeck(Fc=1.0, Fs=1.0), sigma0=1.0 / length, sigma1=0.0, sigma2=0.0, gap=gap)
    x = np.concatenate([np.linspace(0.0, 2e-3, 2001), np.linspace(2e-3, -1e-3, 3001)[1:]])  # 1 um per sample
    force = np.asarray(fj.simulate(model, fj.Motion.from_position(x, dt=DT)))
    turn = int(np.argmax(x))
    assert force[turn] == pytest.approx(1.0, abs=1e-12)  # steady sliding: s(v) = Fc
    back = force[turn:]
    opened = int(np.argmax(back <= 0.0))  # the bristles unload over length * ln 2 (from +length to 0)
    assert opened * step == pytest.approx(length * np.log(2.0), abs=step)
    closed = opened + int(np.argmax(back[opened:] < 0.0))
    assert np.all(back[opened:closed] == 0.0)
    assert (closed - opened) * step == pytest.approx(gap, abs=step)  # the whole gap at zero force
    assert back[-1] == pytest.approx(-1.0, abs=1e-9)


@pytest.mark.parametrize("speed", [5e-4, 2e-2])
def test_steady_sliding_force_is_the_stribeck_curve_plus_viscous(speed):
    stribeck = _stribeck()
    model = fj.LuGreBacklash(stribeck, sigma0=1e5, sigma1=200.0, sigma2=40.0, gap=2e-4, offset=0.1)
    x = speed * np.arange(2000) * DT
    force = np.asarray(fj.simulate(model, fj.Motion.from_position(x, dt=DT)))
    expected = float(stribeck(speed, 1.0)) + 40.0 * speed + 0.1
    assert force[-1] == pytest.approx(expected, rel=1e-9)


def test_a_vanishing_gap_is_lugre():
    t = np.arange(400) * DT
    motion = fj.Motion.from_position(2e-4 * np.sin(2 * np.pi * 4 * t) * (t / t[-1]), dt=DT)
    stribeck = fj.ExponentialStribeck(Fc=(1.0, 0.8), Fs=(1.5, 1.1), vs=1e-3, delta=2.0)
    lugre = fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=40.0, offset=0.05, z0=2e-6)
    backlash = fj.LuGreBacklash(stribeck, 1e5, 300.0, 40.0, gap=1e-13, offset=0.05, w0=2e-6 + 5e-14)
    np.testing.assert_allclose(fj.simulate(backlash, motion), fj.simulate(lugre, motion), atol=1e-7)


@pytest.mark.parametrize("smoothing", [fj.Exact(), fj.Smooth(1e-4)])
def test_gradients_equal_central_differences(smoothing):
    """Every parameter, asymmetric levels, a start engaged with the bristles loaded, a record with reversals inside
    and beyond the gap; steps of 1e-7 of each parameter's magnitude."""
    jax.config.update("jax_enable_x64", True)
    t = np.arange(300) * DT
    x = np.r_[np.zeros(10), 6e-4 * np.sin(2 * np.pi * 5 * t) * (t / t[-1]) + 2e-5 * np.sin(2 * np.pi * 40 * t)]
    motion = fj.Motion.from_position(x, dt=DT)
    stribeck = fj.ExponentialStribeck(Fc=(1.0, 0.8), Fs=(1.5, 1.2), vs=1e-3, delta=2.0)
    model = fj.LuGreBacklash(stribeck, 1e5, 300.0, 40.0, gap=2e-4, offset=0.05, w0=1.03e-4, smoothing=smoothing)
    target = fj.simulate(model, motion) * 1.05 + 0.01
    params, static = eqx.partition(model, fj.trainable_filter(model))
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    loss = jax.jit(lambda f: jnp.mean((fj.simulate(eqx.combine(unravel(f), static), motion) - target) ** 2))
    grad = np.asarray(jax.grad(loss)(flat))
    assert np.all(np.isfinite(grad))
    for i, value in enumerate(np.asarray(flat)):
        h = 1e-7 * max(abs(value), 1e-5)
        step = jnp.zeros_like(flat).at[i].set(h)
        central = (float(loss(flat + step)) - float(loss(flat - step))) / (2 * h)
        assert grad[i] == pytest.approx(central, rel=1e-5, abs=1e-12 * float(loss(flat)) / h), (i, grad[i], central)


@pytest.mark.parametrize("w0", [1e-4, -1e-4])
def test_at_the_edge_of_the_gap_the_gradient_is_one_sides_derivative(w0):
    """A start engaged with the bristles unloaded (`w0 = +-gap / 2`, a natural start) is a kink of the loss in `w0`:
    its gradient is one side's derivative there, not the mean of the two (as a `clip` / `maximum` tie would give)."""
    jax.config.update("jax_enable_x64", True)
    t = np.arange(300) * DT
    motion = fj.Motion.from_position(np.r_[np.zeros(5), 6e-4 * np.sin(2 * np.pi * 5 * t) * (t / t[-1])], dt=DT)
    model = fj.LuGreBacklash(_stribeck(vs=1e-3), 1e5, 0.0, 40.0, gap=2e-4)
    target = fj.simulate(model, motion) * 1.05 + 0.01

    def loss(w):
        return jnp.mean((fj.simulate(eqx.tree_at(lambda m: m.w0, model, w), motion) - target) ** 2)

    grad, h = float(jax.grad(loss)(jnp.asarray(w0))), 1e-10
    sides = ((float(loss(w0 + h)) - float(loss(w0))) / h, (float(loss(w0)) - float(loss(w0 - h))) / h)
    assert abs(sides[0] - sides[1]) > 1e-2 * abs(grad)  # a kink indeed
    assert min(abs(grad - side) for side in sides) < 1e-4 * abs(grad), (grad, sides)


def test_fit_recovers_the_gap_and_the_friction_levels():
    jax.config.update("jax_enable_x64", True)
    t = np.arange(1500) * DT
    x = 2e-3 * np.sin(2 * np.pi * 2 * t) * np.minimum(1.0, 2 * t)
    truth = fj.LuGreBacklash(
        fj.ExponentialStribeck(Fc=(1.0, 0.8), Fs=(1.4, 1.1), vs=5e-3, delta=2.0), 1e4, 0.0, 5.0, gap=5e-4
    )
    motion = fj.Motion.from_position(x, dt=DT)
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    start = fj.LuGreBacklash(
        fj.ExponentialStribeck(Fc=(0.8, 0.8), Fs=(1.2, 1.2), vs=5e-3, delta=2.0),
        2e4,
        0.0,
        1.0,
        gap=1e-3,
        smoothing=fj.Smooth(1e-5),
    )
    solution = fj.fit(
        start,
        data,
        solver=fj.levenberg_marquardt(),
        steps=60,
        scaling=fj.ParameterScaling(),
        freeze=("w0", "sigma1", "stribeck.vs", "stribeck.delta"),
        progress=False,
    )
    fitted = fj.unwrap(solution.model)
    assert float(fitted.gap) == pytest.approx(5e-4, rel=1e-3)
    np.testing.assert_allclose(np.asarray(fitted.stribeck.Fc), [1.0, 0.8], rtol=1e-3)
    assert solution.train_loss < 1e-8
