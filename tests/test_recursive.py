"""Recursive least squares (`fj.RecursiveLeastSquares`, amthor §III-C): the U-D factorised update (Bierman) run by
`fj.simulate` equals batch least squares with forgetting factor 1 after every sample, equals the plain covariance
update where that one is well conditioned, tracks a parameter change with forgetting, and stays finite and
accurate in float32 where the plain update loses positive-definiteness and diverges."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj


def regression(T=300, P=4, noise=0.1, seed=0):
    rng = np.random.default_rng(seed)
    Phi = rng.standard_normal((T, P))
    theta = np.array([1.0, -2.0, 0.5, 3.0])[:P]
    return Phi, Phi @ theta + noise * rng.standard_normal(T), theta


def test_forgetting_one_is_batch_least_squares_after_every_sample():
    """With lambda = 1, P0 = p0 I and theta0, theta_k is the regularised batch solution of samples 0..k:
    (Phi^T Phi + I / p0)^-1 (Phi^T y + theta0 / p0), to 1e-9 relative; the covariance is (Phi^T Phi + I/p0)^-1."""
    Phi, y, _ = regression()
    theta0, p0 = np.array([0.1, 0.0, -0.2, 0.3]), 50.0
    out = fj.simulate(fj.RecursiveLeastSquares(theta0, p0), fj.RegressionData(Phi, y))
    assert out["theta"].shape == (300, 4) and out["prediction"].shape == (300,)
    for k in (0, 3, 10, 100, 299):
        A = Phi[: k + 1].T @ Phi[: k + 1] + np.eye(4) / p0
        reference = np.linalg.solve(A, Phi[: k + 1].T @ y[: k + 1] + theta0 / p0)
        np.testing.assert_allclose(out["theta"][k], reference, rtol=1e-9, atol=1e-12)
    # the prediction is a priori: phi_k^T theta_{k-1}
    np.testing.assert_allclose(out["prediction"][1:], np.sum(Phi[1:] * np.asarray(out["theta"][:-1]), axis=1))
    rls = fj.RecursiveLeastSquares(theta0, p0)
    final = _final_state(rls, fj.RegressionData(Phi, y))
    covariance = fj.RecursiveLeastSquares.covariance(final)
    np.testing.assert_allclose(covariance, np.linalg.inv(Phi.T @ Phi + np.eye(4) / p0), rtol=1e-9, atol=1e-15)
    assert np.all(np.asarray(final.d) > 0) and np.allclose(np.tril(np.asarray(final.U), -1), 0)
    np.testing.assert_allclose(np.diag(np.asarray(final.U)), 1.0)


def _final_state(rls, data):
    """The state after the record (`simulate` returns the outputs only): the step, jitted, in a Python loop."""
    state = rls.init_state()
    step = eqx.filter_jit(lambda s, x: rls.step(s, x))
    samples = rls.samples(data)
    for k in range(data.length):
        state, _ = step(state, {name: value[k] for name, value in samples.items()})
    return state


@pytest.mark.parametrize("forgetting", [1.0, 0.97])
def test_ud_equals_the_plain_update_when_well_conditioned(forgetting):
    Phi, y, _ = regression(T=200)
    ud = fj.simulate(fj.RecursiveLeastSquares(np.zeros(4), 1e3, forgetting), fj.RegressionData(Phi, y))
    plain = fj.simulate(
        fj.RecursiveLeastSquares(np.zeros(4), 1e3, forgetting, method="plain"), fj.RegressionData(Phi, y)
    )
    np.testing.assert_allclose(ud["theta"], plain["theta"], rtol=1e-9, atol=1e-9)
    # one U-D update against the covariance form, written out
    rng = np.random.default_rng(3)
    M = rng.standard_normal((4, 4))
    P = M @ M.T + np.eye(4)
    U_full = np.linalg.cholesky(P[::-1, ::-1])[::-1, ::-1]  # P = U_full U_full^T, U_full upper triangular
    d = np.diag(U_full) ** 2
    U = U_full / np.diag(U_full)
    phi = rng.standard_normal(4)
    gain, U_new, d_new = fj.ud_update(jnp.asarray(U), jnp.asarray(d), jnp.asarray(phi), 0.9)
    K = P @ phi / (0.9 + phi @ P @ phi)
    np.testing.assert_allclose(gain, K, rtol=1e-12)
    np.testing.assert_allclose(
        (np.asarray(U_new) * np.asarray(d_new)) @ np.asarray(U_new).T, (P - np.outer(K, phi @ P)) / 0.9, rtol=1e-11
    )


def test_forgetting_tracks_a_parameter_change():
    """A step in the true parameters at mid-record: with lambda = 0.95 the estimate reaches the new values within
    a few hundred samples; without forgetting it stays between the old and the new."""
    Phi, _, theta = regression(T=1000, noise=0.0)
    changed = theta * np.array([1.2, 0.8, 1.0, 1.1])
    y = np.where(np.arange(1000) < 500, Phi @ theta, Phi @ changed)
    fast = fj.simulate(fj.RecursiveLeastSquares(np.zeros(4), 1e3, 0.95), fj.RegressionData(Phi, y))
    slow = fj.simulate(fj.RecursiveLeastSquares(np.zeros(4), 1e3, 1.0), fj.RegressionData(Phi, y))
    np.testing.assert_allclose(fast["theta"][-1], changed, rtol=1e-6)
    assert np.max(np.abs(np.asarray(slow["theta"][-1]) - changed)) > 0.1


def test_ud_stays_positive_definite_where_plain_rls_diverges():
    """amthor's observation: float32, forgetting 0.99, two almost collinear regressors (P ill-conditioned):
    the plain covariance update loses positive-definiteness and its estimate becomes non-finite; the U-D
    factorised one keeps every d_j > 0 and predicts the record to float32 round-off."""
    T = 8000
    t = np.arange(T)
    base = np.sin(0.01 * t)
    Phi = np.column_stack([base, base + 1e-3 * np.sin(0.003 * t), np.ones(T), 0.01 * np.cos(0.01 * t)])
    Phi = Phi.astype(np.float32)
    y = (Phi @ np.array([1.0, 1.0, 0.3, 2.0])).astype(np.float32)
    data = fj.RegressionData(Phi, y)
    outputs = {}
    for method in ("plain", "ud"):
        rls = fj.RecursiveLeastSquares(np.zeros(4, np.float32), np.float32(1e2), np.float32(0.99), method=method)
        outputs[method] = np.asarray(fj.simulate(rls, data)["prediction"])
        assert outputs[method].dtype == np.float32
    assert not np.all(np.isfinite(outputs["plain"]))
    assert np.all(np.isfinite(outputs["ud"]))
    assert np.max(np.abs(outputs["ud"][-1000:] - y[-1000:])) < 1e-5 * np.max(np.abs(y))


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the recursive fit is checked fast
def test_vmap_over_forgetting_factors_and_errors():
    Phi, y, _ = regression(T=100)
    data = fj.RegressionData(Phi, y)
    batch = jax.vmap(lambda lam: fj.simulate(fj.RecursiveLeastSquares(jnp.zeros(4), 1e3, lam), data)["theta"][-1])
    thetas = batch(jnp.asarray([1.0, 0.98]))
    for i, lam in enumerate((1.0, 0.98)):
        single = fj.simulate(fj.RecursiveLeastSquares(np.zeros(4), 1e3, lam), data)["theta"][-1]
        np.testing.assert_allclose(thetas[i], single, rtol=1e-12)
    with pytest.raises(ValueError, match="`forgetting`"):
        fj.RecursiveLeastSquares(np.zeros(4), 1e3, 1.5)
    with pytest.raises(ValueError, match="`p0`"):
        fj.RecursiveLeastSquares(np.zeros(4), -1.0)
    with pytest.raises(ValueError, match="`method`"):
        fj.RecursiveLeastSquares(np.zeros(4), method="qr")
    with pytest.raises(ValueError, match="columns"):
        fj.simulate(fj.RecursiveLeastSquares(np.zeros(3)), data)
    with pytest.raises(TypeError, match="RegressionData"):
        fj.simulate(fj.RecursiveLeastSquares(np.zeros(4)), Phi)
    with pytest.raises(ValueError, match="finite"):
        fj.RegressionData(np.full((3, 2), np.nan), np.zeros(3))


# ----------------------------------------------------------------------------------------------------------------
# recursive_fit: the linear parameters of any friction model, online
# ----------------------------------------------------------------------------------------------------------------


def _dnlrx(theta, c=(0.0, 0.0)):
    return fj.MaxwellSlip.dnlrx(thresholds=[2e-5, 1e-4, 4e-4], theta=theta, c=list(c), offset=0.05)


def _motion(T=1500):
    t = np.arange(T) * 1e-3
    x = 1e-3 * np.sin(2 * np.pi * 1.3 * t) * np.sin(2 * np.pi * 0.21 * t) + 2e-4 * np.sin(2 * np.pi * 7.0 * t)
    return fj.Motion.from_position(x, dt=1e-3)


@pytest.mark.slow  # about 8 s
def test_recursive_fit_equals_batch_least_squares_and_tracks_a_change():
    """DNLRX(3, 1, 1): with forgetting 1 and a weak prior the recursive estimate of the force map (FIR band,
    displacement FIR) equals `fj.solve_linear`'s batch solution; with forgetting 0.99 it follows the force map of
    a second model after mid-record."""
    motion = _motion()
    theta_a = np.array([[0.3, 0.5, 0.2], [0.1, -0.05, 0.02]])
    truth = _dnlrx(theta_a, c=(20.0, -15.0))
    rng = np.random.default_rng(0)
    force = np.asarray(fj.simulate(truth, motion)) + 0.002 * rng.standard_normal(motion.length)
    data = fj.FrictionData(motion, force)
    start = _dnlrx(np.zeros((2, 3)))
    paths = ("force_map.theta", "force_map.c")
    result = fj.recursive_fit(start, data, paths, p0=1e14)
    assert isinstance(result, fj.Solution) and result.code == "successful" and result.message
    batch = fj.solve_linear(
        start,
        eqx.tree_at(
            lambda m: (m.force_map.theta, m.force_map.c), jax.tree_util.tree_map(lambda _: False, start), (True, True)
        ),
        data,
    )
    np.testing.assert_allclose(result.model.force_map.theta, batch.force_map.theta, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(result.model.force_map.c, batch.force_map.c, rtol=1e-5)  # nearly collinear lags
    assert result.theta.shape == (motion.length, 8) and result.prediction.shape == (motion.length,)
    # a change of the force map at mid-record: forgetting follows it
    theta_b = 1.3 * theta_a
    second = np.asarray(fj.simulate(_dnlrx(theta_b, c=(20.0, -15.0)), motion))
    half = motion.length // 2
    changed = fj.FrictionData(motion, np.concatenate([force[:half], second[half:]]))
    tracking = fj.recursive_fit(start, changed, paths, forgetting=0.99, p0=1e10)
    np.testing.assert_allclose(tracking.model.force_map.theta, theta_b, rtol=0.02, atol=0.01)
    late = slice(3 * motion.length // 4, None)
    fixed = fj.recursive_fit(start, changed, paths, forgetting=1.0, p0=1e10)
    rms = lambda r: np.sqrt(np.mean((r.prediction[late] - second[late]) ** 2))  # noqa: E731
    assert rms(tracking) < 0.01 < rms(fixed), (rms(tracking), rms(fixed))
    with pytest.raises(ValueError, match="linearly"):
        fj.recursive_fit(truth, data, "thresholds")


@pytest.mark.slow  # about 6 s
def test_recursive_fit_of_a_polynomial_narx_under_teacher_forcing():
    """A polynomial NARX with past forces is linear in its coefficients under teacher forcing: `one_step=True`
    with forgetting 1 ends at the batch least-squares coefficients of the teacher-forced regression over the
    whole record (`regressor_matrix`), for the terms FROLS selected."""
    motion = _motion(800)
    truth = _dnlrx(np.array([[0.3, 0.5, 0.2], [0.1, -0.05, 0.02]]), c=(20.0, -15.0))
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    identified = fj.identify_polynomial_narx(data, signals=("dx", "v"), input_lags=1, output_lags=2, degree=2)
    model = identified.model
    start = eqx.tree_at(lambda m: (m.theta, m.theta0), model, (jnp.zeros_like(model.theta), jnp.zeros(())))
    online = fj.recursive_fit(start, data, ("theta", "theta0"), p0=1e12, one_step=True)
    rows = np.asarray(model.regressor_matrix(motion, data.force))
    scales = fj.unwrap(model.regressors)
    target = (np.asarray(data.force) - float(scales.output_mean)) / float(scales.output_scale)
    reference, *_ = np.linalg.lstsq(np.column_stack([rows, np.ones(len(rows))]), target, rcond=None)
    np.testing.assert_allclose(online.model.theta, reference[:-1], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(online.model.theta0, reference[-1], rtol=1e-6, atol=1e-9)
    assert any("F[k-" in term for term in model.describe())  # past forces among the terms
    with pytest.raises(ValueError, match="linearly"):
        fj.recursive_fit(model, data, "theta")  # so the free run is not linear in the coefficients
