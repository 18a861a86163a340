"""Polynomial NARX (parlitz2004 §III-D, worden2007 §5.1): `fj.PolynomialNARX` and `fj.identify_polynomial_narx`.

1. NumPy oracles: free run, one-step-ahead (teacher forcing) and k-step-ahead prediction by `fj.simulate` against
   an independent NumPy loop over the regressors (normalisation, lags and monomials written out here).
2. Identification: FROLS with PRESS recovers the exact terms and coefficients of a known polynomial NARX from
   its clean free run.
3. SysIdentPy oracle: the same selection (terms, order, coefficients) as SysIdentPy's FROLS on the same data.
4. The battery for this model: jit == no jit, vmap over coefficients == loop, finite-difference gradients of
   the output-error (NOE) loss, a short NOE refinement, model files, and errors.
"""

from __future__ import annotations

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

# ----------------------------------------------------------------------------------------------------------------
# a known polynomial NARX on [dx_k, v_k, dx_{k-1}, v_{k-1}, F_{k-1}, F_{k-2}] (normalised)
# ----------------------------------------------------------------------------------------------------------------

SIGNALS = ("dx", "v")
N_U, N_Y = 1, 2
INPUT_MEAN, INPUT_SCALE = np.array([0.001, 0.05]), np.array([0.01, 0.5])
OUTPUT_MEAN, OUTPUT_SCALE = 0.2, 3.0
# exponents over (dx_k, v_k, dx_k-1, v_k-1, y_k-1, y_k-2); the linear AR part 1.2 y1 - 0.5 y2 has poles of
# modulus sqrt(0.5); with the v_k y1 term the y1 coefficient is 1.2 + 0.1 v_k, stable for |v_k| < 3
TERMS = (
    (0, 1, 0, 0, 0, 0),
    (0, 0, 1, 0, 0, 0),
    (0, 0, 0, 0, 1, 0),
    (0, 0, 0, 0, 0, 1),
    (0, 2, 0, 0, 0, 0),
    (0, 1, 0, 0, 1, 0),
    (1, 0, 0, 2, 0, 0),
)
THETA = np.array([0.8, 0.3, 1.2, -0.5, -0.3, 0.1, 0.05])
THETA0 = 0.05
T = 400


def regressors(**kwargs):
    return fj.NARXRegressors(
        SIGNALS,
        N_U,
        N_Y,
        input_mean=INPUT_MEAN,
        input_scale=INPUT_SCALE,
        output_mean=OUTPUT_MEAN,
        output_scale=OUTPUT_SCALE,
        **kwargs,
    )


def true_model(theta=THETA, theta0=THETA0):
    return fj.PolynomialNARX(regressors(), TERMS, jnp.asarray(theta), theta0)


def multisine(rng, t, amplitude, freqs):
    phases = rng.uniform(0, 2 * np.pi, len(freqs))
    return sum(amplitude * np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True))


@pytest.fixture(scope="module")
def record():
    """Independent displacement increments and velocities (multisines about the normalisation's means), the
    model's clean free run and a noisy measurement of it."""
    rng = np.random.default_rng(1)
    t = np.arange(T) * 1e-3
    dx = INPUT_MEAN[0] + multisine(rng, t, 0.005, [3.0, 11.0, 29.0, 71.0, 130.0])
    v = INPUT_MEAN[1] + multisine(rng, t, 0.25, [2.0, 7.0, 19.0, 53.0, 97.0])
    x = np.cumsum(dx)
    motion = fj.Motion(x=x, v=v, dt=1e-3)
    u = np.column_stack([np.diff(x, prepend=x[0]), v])  # dx_0 = 0 (the motion's convention)
    clean = numpy_free_run(THETA, THETA0, u)
    noisy = clean + 0.02 * np.std(clean) * rng.standard_normal(T)
    return u, motion, clean, noisy


# ----------------------------------------------------------------------------------------------------------------
# 1. NumPy oracles
# ----------------------------------------------------------------------------------------------------------------


def numpy_regressor(u, y, k):
    """x_k: normalised inputs at lags 0..N_U (lag-major, signals in order) and outputs at lags 1..N_Y; the
    record at rest before its start (raw inputs and outputs 0)."""
    inputs = [(u[k - i] if k - i >= 0 else np.zeros(2)) for i in range(N_U + 1)]
    outputs = [(y[k - j] if k - j >= 0 else 0.0) for j in range(1, N_Y + 1)]
    normalised = [(ui - INPUT_MEAN) / INPUT_SCALE for ui in inputs]
    return np.concatenate([*normalised, (np.array(outputs) - OUTPUT_MEAN) / OUTPUT_SCALE])


def numpy_force(theta, theta0, x):
    monomials = np.array([np.prod(x ** np.array(term)) for term in TERMS])
    return OUTPUT_MEAN + OUTPUT_SCALE * (theta0 + theta @ monomials)


def numpy_free_run(theta, theta0, u):
    y = np.zeros(len(u))
    for k in range(len(u)):
        y[k] = numpy_force(theta, theta0, numpy_regressor(u, y, k))
    return y


def numpy_predict(theta, theta0, u, measured, start):
    """Sample t predicted by a free run from `start(t)` on, with measured outputs before it."""
    out = np.empty(len(u))
    for t in range(len(u)):
        y = np.array(measured, dtype=float)
        for k in range(max(start(t), 0), t + 1):
            y[k] = numpy_force(theta, theta0, numpy_regressor(u, y, k))
        out[t] = y[t]
    return out


def test_free_run_matches_numpy(record):
    _, motion, clean, _ = record
    np.testing.assert_allclose(fj.simulate(true_model(), motion), clean, rtol=0, atol=1e-12)


def test_one_step_matches_numpy(record):
    u, motion, clean, noisy = record
    predicted = np.asarray(fj.simulate(true_model(), motion, measured=noisy))
    expected = numpy_predict(THETA, THETA0, u, noisy, start=lambda t: t)
    np.testing.assert_allclose(predicted, expected, rtol=0, atol=1e-12)
    assert np.max(np.abs(predicted - clean)) > 0.01 * np.std(clean)  # teacher forcing is not a no-op here


def test_k_step_matches_numpy(record):
    u, motion, _, noisy = record
    k = 3
    predicted = np.asarray(fj.simulate(true_model(), motion, measured=noisy, horizon=k))
    expected = numpy_predict(THETA, THETA0, u, noisy, start=lambda t: t - k + 1)
    np.testing.assert_allclose(predicted, expected, rtol=0, atol=1e-12)


def test_regressor_matrix_is_the_one_step_regression(record):
    """The exposed regressors: `regressor_matrix` (teacher forcing, by shifting) reproduces the NumPy
    monomials row by row, and the one-step prediction of `fj.simulate` is linear in them."""
    u, motion, _, noisy = record
    model = true_model()
    matrix = np.asarray(model.regressor_matrix(motion, noisy))
    rows = [numpy_regressor(u, noisy, k) for k in range(T)]
    expected = np.array([[np.prod(x ** np.array(term)) for term in TERMS] for x in rows])
    np.testing.assert_allclose(matrix, expected, rtol=1e-13, atol=1e-13)
    one_step = OUTPUT_MEAN + OUTPUT_SCALE * (THETA0 + matrix @ THETA)
    np.testing.assert_allclose(one_step, fj.simulate(model, motion, measured=noisy), rtol=0, atol=1e-12)


@pytest.mark.parametrize("smoothing", [fj.Exact(), fj.Smooth(0.05)])
def test_regressor_matrix_with_play_operators(record, smoothing):
    """With play operators among the regressors, the teacher-forced rows hold their states along the record (one
    recursion of the displacement, exact or smoothed as the model's step, run by `fj.simulate` and passed in) and
    the one-step prediction of `fj.simulate` is linear in them; the play states match a NumPy loop."""
    u, motion, _, noisy = record
    thresholds = np.array([2e-3, 1e-2])
    base = regressors(plays=thresholds, smoothing=smoothing)
    terms = fj.monomial_terms(base.size, 2)
    theta = 0.01 * np.cos(np.arange(len(terms)))
    model = fj.PolynomialNARX(base, terms, theta, 0.1)
    states = fj.simulate(base.play_operators, motion)
    matrix = np.asarray(model.regressor_matrix(motion, noisy, states))
    one_step = OUTPUT_MEAN + OUTPUT_SCALE * (0.1 + matrix @ theta)
    np.testing.assert_allclose(one_step, fj.simulate(model, motion, measured=noisy), rtol=0, atol=1e-12)
    dx = u[:, 0]  # dx_0 = 0 (the motion's convention)
    plays, expected = np.zeros(2), []
    for step in dx:
        z = plays + step / thresholds
        if isinstance(smoothing, fj.Exact):
            plays = np.clip(z, -1, 1)
        else:  # (|z + 1| - |z - 1|) / 2 with |s| = s tanh(s / eps)
            plays = 0.5 * ((z + 1) * np.tanh((z + 1) / 0.05) - (z - 1) * np.tanh((z - 1) / 0.05))
        expected.append(plays)
    rows = np.asarray(base.teacher_forced(motion.samples(base.requires), noisy, states))
    np.testing.assert_allclose(rows[:, 4:6], expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(states, rows[:, 4:6])
    with pytest.raises(ValueError, match=r"2 play operators.*play_states=fj.simulate\(regressors.play_operators"):
        model.regressor_matrix(motion, noisy)
    with pytest.raises(ValueError, match=r"`play_states` must .* shape \(400, 2\)"):
        base.teacher_forced(motion.samples(base.requires), noisy, states[:, :1])


def test_monomial_terms_are_every_monomial_once():
    terms = fj.monomial_terms(4, 3)
    assert len(terms) == len(set(terms)) == 34  # binom(4 + 3, 3) - 1
    assert all(1 <= sum(t) <= 3 for t in terms) and [sum(t) for t in terms] == sorted(sum(t) for t in terms)
    assert fj.monomial_terms(2, 2, constant=True)[0] == (0, 0)


# ----------------------------------------------------------------------------------------------------------------
# 2. identification
# ----------------------------------------------------------------------------------------------------------------


def test_identification_recovers_a_known_model(record):
    """Clean free-run data of the known model; candidates: all 83 monomials of degree <= 3 of the same 6
    regressors. FROLS with PRESS selects exactly the 7 true terms (in some order) and stops; the least-squares
    coefficients are the true ones to 1e-8."""
    _, motion, clean, _ = record
    result = fj.identify_polynomial_narx(fj.FrictionData(motion, clean), regressors=regressors(), degree=3)
    assert isinstance(result, fj.Solution) and result.code == "successful" and "7 of 83" in result.message
    assert result.summary().startswith("Solution (PolynomialNARXSelection): successful")
    assert len(result.candidates) == 83
    model = result.model
    assert sorted(model.terms) == sorted(TERMS), model.describe()
    order = [model.terms.index(term) for term in TERMS]
    np.testing.assert_allclose(np.asarray(model.theta)[order], THETA, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(model.theta0, THETA0, rtol=1e-8, atol=1e-10)
    # the PRESS trace falls at every selected term, to round-off after the last
    assert len(result.selection.press) == 8 and np.all(np.diff(result.selection.press) < 0)
    assert result.selection.press[-1] < 1e-16 * result.selection.press[0]
    assert "v[k]*F[k-1]" in model.describe() and "dx[k]*v[k-1]^2" in model.describe()


@pytest.mark.parametrize("drift", ["linear", 0.2])
def test_identification_with_a_sensor_drift(record, drift):
    """A static polynomial of the velocity and two play operators (no fed-back outputs), read by a drifting
    sensor (linear, or leaky with tau = 0.2 s): with `drift=`, FROLS selects the true terms, and the coefficients
    and the drift rate are recovered; the model comes back as `fj.SensorDrift`, its free run the record's."""
    _, motion, _, _ = record
    base = fj.NARXRegressors(("v",), 0, 0, input_scale=[0.5], plays=[2e-3, 1e-2])
    terms = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 0, 2))
    theta = np.array([0.7, 1.5, 0.8, -0.3, 0.2])
    tau = None if drift == "linear" else drift
    truth = fj.SensorDrift(fj.PolynomialNARX(base, terms, theta, 0.1), rate=-0.4, tau=tau)
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    result = fj.identify_polynomial_narx(data, regressors=base, degree=2, drift=drift)
    model = result.model
    assert isinstance(model, fj.SensorDrift)
    assert model.tau is None if tau is None else float(fj.unwrap(model).tau) == pytest.approx(tau)
    assert sorted(model.model.terms) == sorted(terms)
    order = [model.model.terms.index(term) for term in terms]
    np.testing.assert_allclose(np.asarray(model.model.theta)[order], theta, rtol=1e-8)
    np.testing.assert_allclose(float(model.rate), -0.4, rtol=1e-8)
    np.testing.assert_allclose(fj.simulate(model, motion), data.force, rtol=0, atol=1e-10)
    # without the drift column the trend leaks into the terms
    plain = fj.identify_polynomial_narx(data, regressors=base, degree=2).model
    assert float(fj.nmse(data.force, fj.simulate(plain, motion))) > 1e-6


def test_identification_with_data_normalisation_predicts_the_record(record):
    """Default path: regressors normalised by the record itself (`NARXRegressors.from_data`). In these
    coordinates the truth has 11 terms (its products of shifted regressors expand: `(dx - m)(v - m')^2` gives
    `dx v^2`, `dx v`, `dx`, `v^2`, `v`, so 4 more than the 7, the constant being the intercept); FROLS finds
    exactly those and the free run is the record's."""
    _, motion, clean, _ = record
    data = fj.FrictionData(motion, clean)
    result = fj.identify_polynomial_narx(data, signals=SIGNALS, input_lags=N_U, output_lags=N_Y, degree=3)
    assert len(result.model.terms) == 11
    assert float(fj.nmse(clean, fj.simulate(result.model, motion))) < 1e-12


@pytest.mark.slow
def test_noe_refinement_recovers_the_truth(record):
    """Output-error refinement of perturbed selected coefficients (the NOE step after selection): Levenberg-
    Marquardt through the free run returns to the true coefficients."""
    _, motion, clean, _ = record
    start = true_model(THETA * (1 + 0.03 * np.cos(np.arange(7))), THETA0 * 1.1)
    data = fj.FrictionData(motion, clean).slice(0, 150)
    fitted = fj.fit(start, data, loss=fj.SimulationLoss(), solver=fj.levenberg_marquardt(), steps=30)
    assert fitted.code == "successful", fitted.message
    np.testing.assert_allclose(fitted.model.theta, THETA, rtol=1e-6, atol=1e-8)


# ----------------------------------------------------------------------------------------------------------------
# 3. SysIdentPy oracle
# ----------------------------------------------------------------------------------------------------------------


def test_selection_matches_sysidentpy(record):
    """fricjax's FROLS against SysIdentPy's (`FROLS(order_selection=False, n_terms=10, estimator=LeastSquares(),
    basis_function=Polynomial(degree=2))`, no information criterion, ERR ranking) on the same regressors.

    The conventions matched (read from sysidentpy 0.9.0's `ofr_base.py`, `_lib/_err.py` and
    `utils/information_matrix.py`):

    - lags: SysIdentPy's inputs enter at lags 1..`xlag` (a delay d = 1), fricjax's at 0..n_u; SysIdentPy gets the
      inputs advanced by one sample (`X[k] = u[k + 1]`), so its `x(k-i)` is fricjax's `u_{k-i+1}`, and
      `xlag = n_u + 1`; outputs at lags 1..`ylag` in both;
    - rows: SysIdentPy drops the first `max(xlag, ylag)` rows (zero-padded history): fricjax's `burn_in`;
    - the constant: SysIdentPy's polynomial basis has a constant column that competes like any other candidate
      (no intercept from the start): fricjax's `intercept=False` (the constant monomial among the candidates);
    - ERR: SysIdentPy's `(w^T y)^2 / (w^T w y^T y)` (+ eps, the same for all) on the raw target, i.e. the term
      that most lowers the residual sum of squares: fricjax's `criterion="err"`;
    - coefficients: `LeastSquares` on the selected columns, in selection order, as fricjax's refit;
    - no normalisation: fricjax's regressors with mean 0 and scale 1.

    SysIdentPy codes regressor `y(k-j)` as `1000 + j` and input i's `x_i(k-j)` as `1000 (i + 1) + j`.
    """
    if not os.environ.get("FRICJAX_REQUIRE_SYSIDENTPY"):  # .ci/run sets it after installing sysidentpy
        pytest.importorskip("sysidentpy")
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    u, motion, _, noisy = record
    n_u, n_y, n_terms = 1, 2, 10
    length = T - 1  # the advanced inputs need u[k + 1]
    data = fj.FrictionData(fj.Motion(x=motion.x[:length], v=motion.v[:length], dt=1e-3), noisy[:length])
    max_lag = max(n_u + 1, n_y)
    plain = fj.NARXRegressors(SIGNALS, n_u, n_y)
    ours = fj.identify_polynomial_narx(
        data, regressors=plain, degree=2, criterion="err", max_terms=n_terms, intercept=False, burn_in=max_lag
    )

    theirs = FROLS(
        order_selection=False,
        n_terms=n_terms,
        ylag=n_y,
        xlag=[list(range(1, n_u + 2))] * len(SIGNALS),
        estimator=LeastSquares(),
        basis_function=Polynomial(degree=2),
    )
    theirs.fit(X=u[1:], y=noisy[:length, None])

    size = plain.size
    n_inputs = len(SIGNALS)

    def exponents(codes):
        term = [0] * size
        for code in codes:
            if code == 0:
                continue
            group, lag = divmod(int(code), 1000)
            index = n_inputs * (n_u + 1) + lag - 1 if group == 1 else (lag - 1) * n_inputs + group - 2
            term[index] += 1
        return tuple(term)

    their_terms = [exponents(row) for row in theirs.final_model]
    assert list(ours.model.terms) == their_terms
    np.testing.assert_allclose(ours.model.theta, np.ravel(theirs.theta), rtol=1e-8, atol=1e-10)
    assert float(ours.model.theta0) == 0.0
    # the ERR values agree too (SysIdentPy adds machine epsilon to each)
    np.testing.assert_allclose(ours.selection.err, theirs.err[:n_terms] - np.finfo(float).eps, rtol=1e-8, atol=1e-14)


# ----------------------------------------------------------------------------------------------------------------
# 4. battery
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.slow  # about 3 s
def test_jit_equals_no_jit(record):
    _, motion, _, noisy = record
    part = fj.FrictionData(motion, noisy).slice(0, 30)
    short, measured = part.motion, part.force
    model = true_model()
    jitted = jax.jit(lambda m: fj.simulate(m, short, measured=measured))(model)
    with jax.disable_jit():
        plain = fj.simulate(model, short, measured=measured)
    np.testing.assert_allclose(jitted, plain, rtol=0, atol=1e-12)


def test_vmap_over_coefficients_equals_loop(record):
    _, motion, _, _ = record
    thetas = THETA * (1 + 0.05 * np.arange(4)[:, None] * np.sin(np.arange(7)))
    models = [true_model(theta) for theta in thetas]
    stacked = jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *models)
    forces = eqx.filter_vmap(lambda m: fj.simulate(m, motion))(stacked)
    for model, force in zip(models, forces, strict=True):
        np.testing.assert_allclose(force, fj.simulate(model, motion), rtol=0, atol=1e-12)


def test_term_mask_removes_terms(record):
    """A 0/1 mask over the terms (fixed, for sweeps over structures) equals the model without those terms."""
    _, motion, _, _ = record
    masked = fj.PolynomialNARX(regressors(), TERMS, THETA, THETA0, unit_mask=[1, 1, 1, 1, 0, 1, 0])
    keep = [0, 1, 2, 3, 5]
    smaller = fj.PolynomialNARX(regressors(), [TERMS[i] for i in keep], THETA[keep], THETA0)
    np.testing.assert_allclose(fj.simulate(masked, motion), fj.simulate(smaller, motion), rtol=0, atol=1e-12)


def test_noe_gradient_matches_finite_differences(record):
    _, motion, _, noisy = record
    data = fj.FrictionData(motion, noisy).slice(0, 100)
    loss = fj.SimulationLoss()

    @jax.jit
    def value(theta, theta0):
        return loss(true_model(theta, theta0), None, data)

    grad_theta, grad_theta0 = jax.grad(value, argnums=(0, 1))(jnp.asarray(THETA * 1.01), jnp.asarray(THETA0))
    assert np.all(np.isfinite(grad_theta)) and np.isfinite(grad_theta0)
    h = 1e-6
    for i in range(7):
        step = np.zeros(7)
        step[i] = h
        fd = (value(THETA * 1.01 + step, THETA0) - value(THETA * 1.01 - step, THETA0)) / (2 * h)
        np.testing.assert_allclose(grad_theta[i], fd, rtol=1e-5, atol=1e-9)
    fd0 = (value(THETA * 1.01, THETA0 + h) - value(THETA * 1.01, THETA0 - h)) / (2 * h)
    np.testing.assert_allclose(grad_theta0, fd0, rtol=1e-5, atol=1e-9)


@pytest.mark.slow  # fast tier trimmed (2026-11-27): an edge of the gradients checked fast
def test_gradient_is_finite_at_zero_regressors():
    """The monomials are products, not powers: d(x^2 y)/dx is finite (0) at x = 0, where a power x**p would
    give 0 * inf."""
    model = fj.PolynomialNARX(fj.NARXRegressors(("v",), 0, 1), ((2, 1), (0, 1), (1, 0)), [0.1, 0.5, 1.0])
    motion = fj.Motion.from_velocity(np.zeros(20), dt=1e-3)
    grads = jax.grad(lambda m: jnp.sum(fj.simulate(m, motion) ** 2))(model)
    assert np.all(np.isfinite(grads.theta))


def test_model_file_round_trip(tmp_path, record):
    _, motion, _, _ = record
    model = true_model()
    fj.save_model(tmp_path / "narx.eqx", model)
    loaded = fj.load_model(tmp_path / "narx.eqx")
    assert loaded.terms == model.terms
    np.testing.assert_array_equal(fj.simulate(loaded, motion), fj.simulate(model, motion))


def test_errors(record):
    _, motion, clean, _ = record
    data = fj.FrictionData(motion, clean)
    for degree in (0, 1.5, True):
        with pytest.raises(ValueError, match="`degree`"):
            fj.identify_polynomial_narx(data, degree=degree)
    with pytest.raises(ValueError, match="unknown signals"):
        fj.identify_polynomial_narx(data, signals=("v", "jerk"))
    with pytest.raises(ValueError, match="too few samples"):
        fj.identify_polynomial_narx(data.slice(0, 60), signals=SIGNALS, input_lags=2, output_lags=2, degree=3)
    with pytest.raises(ValueError, match="criterion"):
        fj.identify_polynomial_narx(data, degree=1, criterion="aic")
    for drift in (-1.0, "leaky", True):
        with pytest.raises(ValueError, match="`drift`"):
            fj.identify_polynomial_narx(data, degree=1, drift=drift)
    with pytest.raises(ValueError, match="one coefficient per term"):
        fj.PolynomialNARX(regressors(), TERMS, THETA[:3])
    with pytest.raises(ValueError, match="non-negative exponents"):
        fj.PolynomialNARX(regressors(), ((1, 0),), [1.0])
    with pytest.raises(ValueError, match="repeats a monomial"):
        fj.PolynomialNARX(regressors(), (TERMS[0], TERMS[0]), [1.0, 2.0])
    with pytest.raises(ValueError, match="one entry per term"):
        fj.PolynomialNARX(regressors(), TERMS, THETA, unit_mask=[1.0, 0.0])
    with pytest.raises(ValueError, match="needs the velocity"):
        true_model().regressor_matrix(fj.Motion(x=motion.x), clean)
