"""`fj.HystereticOscillator`: a mass-spring-damper with a friction model of its displacement as the restoring force."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import fricjax as fj

DT = 1.0 / 750.0


def numpy_oscillator(m, c, k, element_k, thresholds, offset, u, substeps, dt=DT):
    """Independent loop of the documented scheme with a Maxwell-slip NLR element (exact clip)."""
    element_k, thresholds = np.asarray(element_k, float), np.asarray(thresholds, float)
    u_next = np.concatenate([u[1:], u[-1:]])
    h = dt / substeps
    y = v = 0.0
    delta = np.zeros_like(thresholds)
    F = offset
    out = np.empty(len(u))
    for n in range(len(u)):
        out[n] = y
        for i in range(substeps):
            start = u[n] + i * (u_next[n] - u[n]) / substeps
            end = u[n] + (i + 1) * (u_next[n] - u[n]) / substeps
            v_mean = v + 0.5 * h * (start - c * v - k * y - F) / m
            dy = h * v_mean
            y += dy
            delta = np.clip(delta + dy, -thresholds, thresholds)
            F = float(np.sum(element_k * delta)) + offset
            v = (v_mean + 0.5 * h * (end - k * y - F) / m) / (1 + 0.5 * h * c / m)
    return out


def exact_linear_oscillator(m, c, k, u, dt=DT):
    """`m y'' + c y' + k y = u` with u linear between samples, by the matrix exponential (exact)."""
    A = np.zeros((4, 4))
    A[0, 1] = 1.0
    A[1] = [-k / m, -c / m, 1.0 / m, 0.0]
    A[2, 3] = 1.0
    Phi = scipy.linalg.expm(A * dt)
    u_next = np.concatenate([u[1:], u[-1:]])
    x = np.zeros(4)
    out = np.empty(len(u))
    for n in range(len(u)):
        out[n] = x[0]
        x = Phi @ np.array([x[0], x[1], u[n], (u_next[n] - u[n]) / dt])
    return out


@pytest.fixture(scope="module")
def force():
    rng = np.random.default_rng(0)
    t = np.arange(400) * DT
    return 40 * np.sin(2 * np.pi * 7 * t) + 10 * rng.standard_normal(400)


def test_matches_an_independent_loop(force):
    element_k, thresholds, offset = [3e4, 1e4, 5e3], [2e-5, 1e-4, 4e-4], 0.3
    element = fj.MaxwellSlip.nlr(k=element_k, thresholds=thresholds, offset=offset)
    system = fj.HystereticOscillator(m=2.0, c=10.0, k=4e4, element=element, substeps=5)
    y = np.asarray(fj.simulate(system, fj.boucwen_inputs(force)))
    reference = numpy_oscillator(2.0, 10.0, 4e4, element_k, thresholds, offset, force, 5)
    np.testing.assert_allclose(y, reference, rtol=1e-10, atol=1e-16)
    # the elements slip: the response is not that of the linear oscillator with all the springs stuck
    stuck = exact_linear_oscillator(2.0, 10.0, 4e4 + sum(element_k), force)
    assert np.max(np.abs(y - stuck)) > 0.1 * np.max(np.abs(stuck))


def test_converges_to_the_exact_linear_oscillator(force):
    # an element that never slips is a linear spring: the system is m y'' + c y' + (k + k_e) y = u
    exact = exact_linear_oscillator(2.0, 10.0, 5e4 + 5e4, force)
    errors = []
    for substeps in (4, 16, 64):
        element = fj.MaxwellSlip.nlr(k=[5e4], thresholds=[1.0])
        system = fj.HystereticOscillator(m=2.0, c=10.0, k=5e4, element=element, substeps=substeps)
        y = np.asarray(fj.simulate(system, fj.boucwen_inputs(force)))
        errors.append(np.sqrt(np.mean((y - exact) ** 2)) / np.sqrt(np.mean(exact**2)))
    assert errors[0] < 5e-3
    assert errors[-1] < 2e-5
    assert errors[0] / errors[1] > 12 and errors[1] / errors[2] > 12  # second order: ~16x per 4x substeps


def test_hysteresis_loop_under_slow_cycling():
    # quasi-static force cycles: the displacement lags the force (a loop of nonzero area); a smaller inner cycle
    # returns to the outer branch's turning point (non-local memory of the Maxwell-slip element)
    t = np.arange(3000) * DT
    u = 30 * np.sin(2 * np.pi * 0.5 * t)
    element = fj.MaxwellSlip.nlr(k=[4e4, 4e4], thresholds=[5e-5, 2e-4])
    system = fj.HystereticOscillator(m=2.0, c=10.0, k=1e4, element=element, substeps=4)
    y = np.asarray(fj.simulate(system, fj.boucwen_inputs(u)))
    last = slice(1500, 3000)  # the second period
    area = np.trapezoid(u[last], y[last])
    assert abs(area) > 1e-4  # N m: energy dissipated per cycle by the slipping elements
    stuck = exact_linear_oscillator(2.0, 10.0, 9e4, u)
    assert abs(np.trapezoid(u[last], stuck[last])) < 0.05 * abs(area)


def test_gradient_matches_finite_differences(force):
    u = force[:80]
    target = numpy_oscillator(2.0, 10.0, 4e4, [3e4, 1e4], [2e-5, 1e-4], 0.0, u, 3)
    start = np.array([2.3, 14.0, 3.5e4, 2.5e4, 1.4e4, 3e-5, 1.3e-4])

    @jax.jit
    def loss(theta):
        element = fj.MaxwellSlip.nlr(k=theta[3:5], thresholds=theta[5:7], smoothing=fj.Smooth(1e-2))
        system = fj.HystereticOscillator(m=theta[0], c=theta[1], k=theta[2], element=element, substeps=3)
        return jnp.sum((fj.simulate(system, fj.boucwen_inputs(u)) - target) ** 2) * 1e8

    grad = np.asarray(jax.grad(loss)(jnp.asarray(start)))
    assert np.all(np.isfinite(grad))
    for i in range(len(start)):
        h = 1e-6 * abs(start[i])
        up, down = start.copy(), start.copy()
        up[i] += h
        down[i] -= h
        fd = (float(loss(jnp.asarray(up))) - float(loss(jnp.asarray(down)))) / (2 * h)
        scale = np.max(np.abs(grad * start)) / abs(start[i])
        assert np.isclose(grad[i], fd, rtol=1e-4, atol=1e-7 * scale), i


def test_errors():
    element = fj.MaxwellSlip.nlr(k=[1e4], thresholds=[1e-4])
    with pytest.raises(TypeError, match="`element` must be a fricjax friction model"):
        fj.HystereticOscillator(m=2.0, c=10.0, k=5e4, element=fj.BoucWen.benchmark())  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="substeps"):
        fj.HystereticOscillator(m=2.0, c=10.0, k=5e4, element=element, substeps=0)
    with pytest.raises(ValueError, match="`m`"):
        fj.HystereticOscillator(m=-2.0, c=10.0, k=5e4, element=element)
    with pytest.raises(ValueError, match="u_next"):
        fj.simulate(fj.HystereticOscillator(m=2.0, c=10.0, k=5e4, element=element), fj.InputRecord(dt=DT, u=np.ones(5)))
