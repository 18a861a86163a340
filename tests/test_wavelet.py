"""Wavelet-network NARX (MATLAB's `wavenet`, the emps-ensemble paper's `nlarx` estimator): `fj.WaveletNARX` and
`fj.identify_wavelet_narx`.

1. NumPy oracles: the network's equation written out; free run and one-step (teacher-forced) prediction by
   `fj.simulate` against a NumPy loop over the regressors; the exposed linear-in-parameters columns.
2. Identification: the least-squares coefficients equal `numpy.linalg.lstsq` on the same rows and columns; the
   PCA projection and the candidate units are those documented; a known wavelet network (on play operators and
   the velocity) is recovered from its own data (same units, same coefficients).
3. The battery for this model: jit == no jit, vmap == loop, masks, finite-difference gradients of the
   output-error (NOE) loss with respect to every parameter kind, model files, errors.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

SIGNALS = ("dx", "v")
N_U, N_Y = 1, 2
INPUT_MEAN, INPUT_SCALE = np.array([0.001, 0.05]), np.array([0.01, 0.5])
OUTPUT_MEAN, OUTPUT_SCALE = 0.2, 3.0
M = len(SIGNALS) * (N_U + 1) + N_Y  # 6 regressors
Q_DIM = 3
T = 300


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


def parameters(scale=1.0):
    """A network with 3 wavelets and 2 scaling functions on a random 3-dimensional projection; the linear part
    0.6 y_{k-1} - 0.2 y_{k-2} + inputs keeps the free run stable."""
    rng = np.random.default_rng(3)
    return dict(
        center=0.1 * rng.standard_normal(M),
        Q=0.5 * rng.standard_normal((M, Q_DIM)),
        L=np.array([0.3, 0.5, 0.1, -0.1, 0.6, -0.2]),
        a=scale * np.array([0.2, -0.15, 0.1]),
        b=np.array([0.8, 1.5, 2.5]),
        c=0.5 * rng.standard_normal((3, Q_DIM)),
        s=scale * np.array([0.3, -0.25]),
        beta=np.array([0.7, 1.2]),
        gamma=0.5 * rng.standard_normal((2, Q_DIM)),
        d=0.05,
    )


def true_model(**overrides):
    return fj.WaveletNARX(regressors(), **{**parameters(), **overrides})


@pytest.fixture(scope="module")
def record():
    """Independent displacement increments and velocities (multisines), the network's clean free run and a
    noisy measurement of it."""
    rng = np.random.default_rng(1)
    t = np.arange(T) * 1e-3
    dx = INPUT_MEAN[0] + sum(0.01 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (3.0, 17.0, 61.0))
    v = INPUT_MEAN[1] + sum(0.5 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (2.0, 11.0, 43.0))
    x = np.cumsum(dx)
    motion = fj.Motion(x=x, v=v, dt=1e-3)
    u = np.column_stack([np.diff(x, prepend=x[0]), v])  # dx_0 = 0 (the motion's convention)
    clean = numpy_free_run(parameters(), u)
    noisy = clean + 0.05 * np.std(clean) * rng.standard_normal(T)
    return u, motion, clean, noisy


# ----------------------------------------------------------------------------------------------------------------
# 1. NumPy oracles
# ----------------------------------------------------------------------------------------------------------------


def numpy_network(p, x):
    """MATLAB's wavenet, written out: (x - r) L + sum a f(b ((x - r) Q - c)) + sum s g(beta ((x - r) Q - gamma)) + d
    with f(z) = (q - |z|^2) exp(-|z|^2 / 2), g(z) = exp(-|z|^2 / 2), P the identity."""
    centred = x - p["center"]
    z = centred @ p["Q"]
    q = len(z)
    out = centred @ p["L"] + p["d"]
    for a, b, c in zip(p["a"], p["b"], p["c"], strict=True):
        r2 = float(np.sum((b * (z - c)) ** 2))
        out += a * (q - r2) * np.exp(-r2 / 2)
    for s, beta, gamma in zip(p["s"], p["beta"], p["gamma"], strict=True):
        out += s * np.exp(-float(np.sum((beta * (z - gamma)) ** 2)) / 2)
    return out


def numpy_regressor(u, y, k):
    """x_k: normalised inputs at lags 0..N_U (lag-major) and outputs at lags 1..N_Y, at rest before the record."""
    inputs = [(u[k - i] if k - i >= 0 else np.zeros(2)) for i in range(N_U + 1)]
    outputs = [(y[k - j] if k - j >= 0 else 0.0) for j in range(1, N_Y + 1)]
    normalised = [(ui - INPUT_MEAN) / INPUT_SCALE for ui in inputs]
    return np.concatenate([*normalised, (np.array(outputs) - OUTPUT_MEAN) / OUTPUT_SCALE])


def numpy_free_run(p, u, measured=None):
    y, past = np.zeros(len(u)), np.zeros(len(u))
    for k in range(len(u)):
        y[k] = OUTPUT_MEAN + OUTPUT_SCALE * numpy_network(p, numpy_regressor(u, past, k))
        past[k] = y[k] if measured is None else measured[k]
    return y


def test_free_run_matches_numpy(record):
    _, motion, clean, _ = record
    assert np.std(clean) > 0.3  # the units matter: the record is not a linear ARX's
    np.testing.assert_allclose(fj.simulate(true_model(), motion), clean, rtol=0, atol=1e-12)


def test_one_step_matches_numpy(record):
    u, motion, clean, noisy = record
    predicted = np.asarray(fj.simulate(true_model(), motion, measured=noisy))
    np.testing.assert_allclose(predicted, numpy_free_run(parameters(), u, measured=noisy), rtol=0, atol=1e-12)
    assert np.max(np.abs(predicted - clean)) > 0.01 * np.std(clean)  # teacher forcing is not a no-op here


def test_units_change_the_output(record):
    """Without its units (a = s = 0) the model is a linear ARX: the units' share of the record is not small."""
    _, motion, clean, _ = record
    linear = np.asarray(fj.simulate(true_model(a=np.zeros(3), s=np.zeros(2)), motion))
    assert float(fj.nmse(clean, linear)) > 1.0


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the same check runs fast for polynomial NARX
def test_regressor_matrix_is_the_one_step_regression(record):
    """The exposed columns: `regressor_matrix` (teacher forcing) holds `(x - r) P` and every unit along the
    record, and the one-step prediction of `fj.simulate` is linear in them."""
    u, motion, _, noisy = record
    model, p = true_model(), parameters()
    matrix = np.asarray(model.regressor_matrix(motion, noisy))
    assert matrix.shape == (T, M + 5)
    one_step = OUTPUT_MEAN + OUTPUT_SCALE * (p["d"] + matrix @ np.concatenate([p["L"], p["a"], p["s"]]))
    np.testing.assert_allclose(one_step, fj.simulate(model, motion, measured=noisy), rtol=0, atol=1e-12)
    x = numpy_regressor(u, noisy, 7)
    z = (x - p["center"]) @ p["Q"]
    r2 = (p["b"][1] ** 2) * np.sum((z - p["c"][1]) ** 2)
    np.testing.assert_allclose(matrix[7, M + 1], (Q_DIM - r2) * np.exp(-r2 / 2), rtol=1e-12)


def test_unit_mask_removes_units(record):
    """A 0/1 mask over the units (wavelets, then scaling functions) equals the network without them."""
    _, motion, _, _ = record
    p = parameters()
    masked = true_model(unit_mask=[1, 0, 1, 0, 1])
    smaller = true_model(a=p["a"][[0, 2]], b=p["b"][[0, 2]], c=p["c"][[0, 2]], s=p["s"][1:], beta=p["beta"][1:],
                         gamma=p["gamma"][1:])  # fmt: skip
    np.testing.assert_allclose(fj.simulate(masked, motion), fj.simulate(smaller, motion), rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------------------------------------
# 2. identification
# ----------------------------------------------------------------------------------------------------------------


def test_least_squares_equals_numpy_lstsq(record):
    """The linear coefficients (L, a, s, d) are `numpy.linalg.lstsq` of the normalised force on the columns
    `[(x - r), units, 1]` over the teacher-forced rows after the burn-in (rows and units written out here); the
    projection is the documented PCA, and each selected unit is the candidate its index names."""
    u, motion, _, noisy = record
    data = fj.FrictionData(motion, noisy)
    result = fj.identify_wavelet_narx(data, regressors=regressors(), units=6, levels=3, candidates=20, whiten=False)
    model = fj.unwrap(result.model)
    rows = np.array([numpy_regressor(u, noisy, k) for k in range(T)])[N_Y:]  # burn-in max(n_u, n_y) = 2
    target = (noisy[N_Y:] - OUTPUT_MEAN) / OUTPUT_SCALE
    # the projection: the rows' mean, their principal directions scaled to a mean squared radius q
    center = rows.mean(axis=0)
    _, sv, vt = np.linalg.svd(rows - center, full_matrices=False)
    np.testing.assert_allclose(model.center, center, rtol=1e-12, atol=1e-14)
    q = model.dim
    assert q == M  # no degenerate direction here
    scale = np.sqrt(np.mean(sv**2) / len(rows))
    np.testing.assert_allclose(np.abs(model.Q), np.abs(vt.T / scale), rtol=1e-8, atol=1e-10)  # up to sign
    # the units are candidates: centres among the projected rows, dilations 2^j / sqrt(q)
    np.testing.assert_allclose(result.dilations, 2.0 ** np.arange(3) / np.sqrt(q))
    projected = (rows - center) @ np.asarray(model.Q)
    assert all(np.min(np.abs(projected - c).sum(axis=1)) < 1e-12 for c in result.centres)
    count = len(result.centres)
    kinds = ["wavelet" if i < 3 * count else "scaling" for i in result.selection.indices]
    assert kinds.count("wavelet") == model.num_wavelets and kinds.count(
        "scaling"
    ) == model.num_scaling == 6 - kinds.count("wavelet")
    first = result.selection.indices[0] % (3 * count)
    unit_centres = np.asarray(model.c if kinds[0] == "wavelet" else model.gamma)[0]
    np.testing.assert_allclose(unit_centres, result.centres[first % count], rtol=0, atol=0)
    # the least squares on the same rows, by NumPy
    p = {k: np.asarray(getattr(model, k)) for k in ("center", "Q", "L", "a", "b", "c", "s", "beta", "gamma")}
    columns = []
    for x in rows:
        z = (x - p["center"]) @ p["Q"]
        r2w = p["b"] ** 2 * np.sum((z - p["c"]) ** 2, axis=1)
        r2s = p["beta"] ** 2 * np.sum((z - p["gamma"]) ** 2, axis=1)
        columns.append(np.concatenate([x - p["center"], (q - r2w) * np.exp(-r2w / 2), np.exp(-r2s / 2), [1.0]]))
    expected = np.linalg.lstsq(np.array(columns), target, rcond=None)[0]
    got = np.concatenate([p["L"], p["a"], p["s"], [float(model.d)]])
    np.testing.assert_allclose(got, expected, rtol=1e-8, atol=1e-10)


def test_known_network_is_recovered():
    """A known wavelet network on the velocity and 4 play operators (no fed-back force: the regressors depend on
    the motion only, so the projection and the candidate units are the same whatever the force). Its 4 units are
    candidates (2 wavelets, 2 scaling functions, at 3 dilations); from its clean output, orthogonal least squares
    selects exactly those 4 and least squares returns its coefficients. (Greedy selection is not exact for every
    set of true units: units coherent with others can be passed over for a mix of them.)"""
    t = np.arange(400) * 1e-3
    x = 1e-4 * (np.sin(2 * np.pi * 3 * t) + 0.5 * np.sin(2 * np.pi * 11 * t + 1.0) + 0.2 * np.sin(2 * np.pi * 37 * t))
    motion = fj.Motion.from_position(x, dt=1e-3)
    reg = fj.NARXRegressors(("v",), 0, 0, input_scale=[float(np.std(motion.samples().v))],
                            plays=[5e-6, 2e-5, 6e-5, 1.5e-4])  # fmt: skip
    probe = fj.FrictionData(motion, np.cos(t))  # any force: the library depends on the motion only
    library = fj.identify_wavelet_narx(probe, regressors=reg, units=0, levels=3, candidates=30)
    start, centres, dilations = fj.unwrap(library.model), library.centres, library.dilations
    wavelets, scaling = [(0, 1), (7, 2)], [(3, 2), (12, 1)]  # (centre, dilation level)
    truth = fj.WaveletNARX(
        reg, center=start.center, Q=start.Q, L=np.linspace(-1, 1, 5), a=[1.5, -1.0],
        b=[dilations[j] for _, j in wavelets], c=[centres[i] for i, _ in wavelets], s=[-2.0, 0.7],
        beta=[dilations[j] for _, j in scaling], gamma=[centres[i] for i, _ in scaling], d=0.3,
    )  # fmt: skip
    force = np.asarray(fj.simulate(truth, motion))
    result = fj.identify_wavelet_narx(fj.FrictionData(motion, force), regressors=reg, units=4, levels=3, candidates=30)
    n = len(centres)  # candidate i < 3n: wavelet at centre i % n, level i // n; then the scaling functions
    assert sorted(result.selection.indices) == sorted(
        [j * n + i for i, j in wavelets] + [3 * n + j * n + i for i, j in scaling]
    )
    found, truth = fj.unwrap(result.model), fj.unwrap(truth)
    order_w = np.argsort(np.asarray(found.b))  # the truth's units are in order of dilation
    order_s = np.argsort(-np.asarray(found.beta))
    for ours, theirs, order in (
        ("a", "a", order_w),
        ("c", "c", order_w),
        ("s", "s", order_s),
        ("gamma", "gamma", order_s),
    ):
        np.testing.assert_allclose(
            np.asarray(getattr(found, ours))[order], getattr(truth, theirs), rtol=1e-8, atol=1e-9
        )
    np.testing.assert_allclose(found.L, truth.L, rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(found.d, truth.d, rtol=1e-8)
    np.testing.assert_allclose(fj.simulate(found, motion), force, rtol=0, atol=1e-9)


@pytest.mark.slow  # about 3 s
def test_identification_with_fed_back_forces_predicts_the_record(record):
    """The paper's structure (lags of the inputs and of the force): from the clean record of the known network,
    the identified network's one-step prediction is within 1 % (NMSE) and its free run within 5 %."""
    _, motion, clean, _ = record
    data = fj.FrictionData(motion, clean)
    model = fj.identify_wavelet_narx(data, signals=SIGNALS, input_lags=N_U, output_lags=N_Y, units=10).model
    assert float(fj.nmse(clean, fj.simulate(model, motion, measured=clean))) < 1.0
    assert float(fj.nmse(clean, fj.simulate(model, motion))) < 5.0


def test_units_see_only_the_nonlinear_regressors(record):
    """`nonlinear=` (MATLAB's nonlinear regressors): the units see the chosen regressors only (the other rows of
    `Q` are 0), the linear part sees every regressor."""
    _, motion, _, noisy = record
    data = fj.FrictionData(motion, noisy)
    model = fj.identify_wavelet_narx(data, regressors=regressors(), units=3, candidates=20, nonlinear=(1, 3)).model
    Q = np.asarray(fj.unwrap(model.Q))
    assert model.dim == 2 and np.all(Q[[0, 2, 4, 5]] == 0) and np.linalg.matrix_rank(Q[[1, 3]]) == 2
    assert np.all(np.asarray(model.L) != 0)


def test_zero_units_is_a_linear_arx(record):
    _, motion, _, noisy = record
    result = fj.identify_wavelet_narx(fj.FrictionData(motion, noisy), regressors=regressors(), units=0)
    assert result.model.num_wavelets == result.model.num_scaling == 0 and result.selection.indices == ()
    matrix = np.asarray(result.model.regressor_matrix(motion, noisy))[N_Y:]
    target = (noisy[N_Y:] - OUTPUT_MEAN) / OUTPUT_SCALE
    expected = np.linalg.lstsq(np.column_stack([matrix, np.ones(len(matrix))]), target, rcond=None)[0]
    np.testing.assert_allclose(result.model.L, expected[:-1], rtol=1e-8, atol=1e-10)


@pytest.mark.slow
def test_output_error_refinement_improves_the_free_run(record):
    """The recipe: least squares under teacher forcing on a short noisy record, then output error (Adam through
    the free run, every parameter) lowers the free-run error on the training record."""
    import optax

    _, motion, _, noisy = record
    data = fj.FrictionData(motion, noisy)
    start = fj.identify_wavelet_narx(data, signals=SIGNALS, input_lags=N_U, output_lags=N_Y, units=6).model
    before = float(fj.nmse(noisy, fj.simulate(start, motion)))
    fitted = fj.fit(start, data, loss=fj.SimulationLoss(), solver=optax.adam(3e-3), steps=150)
    assert fitted.code in ("max_steps", "successful"), fitted.message
    assert float(fj.nmse(noisy, fj.simulate(fitted.model, motion))) < 0.9 * before


# ----------------------------------------------------------------------------------------------------------------
# 3. battery
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.slow  # about 4 s (the no-jit run dispatches op by op)
def test_jit_equals_no_jit(record):
    _, motion, _, noisy = record
    part = fj.FrictionData(motion, noisy).slice(0, 6)
    model = true_model()
    jitted = jax.jit(lambda m: fj.simulate(m, part.motion, measured=part.force))(model)
    with jax.disable_jit():
        plain = fj.simulate(model, part.motion, measured=part.force)
    np.testing.assert_allclose(jitted, plain, rtol=0, atol=1e-12)


@pytest.mark.slow  # fast tier trimmed (2026-11-27): vmap over models is checked fast in test_battery.py
def test_vmap_over_parameters_equals_loop(record):
    _, motion, _, _ = record
    models = [true_model(a=parameters(1 + 0.2 * i)["a"], b=parameters()["b"] * (1 + 0.1 * i)) for i in range(3)]
    stacked = jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *models)
    forces = eqx.filter_vmap(lambda m: fj.simulate(m, motion))(stacked)
    for model, force in zip(models, forces, strict=True):
        np.testing.assert_allclose(force, fj.simulate(model, motion), rtol=0, atol=1e-12)


@pytest.mark.slow  # about 3 s
def test_noe_gradient_matches_finite_differences(record):
    """The output-error loss's gradient with respect to each kind of parameter (linear weights, wavelet and
    scaling coefficients, dilations through their log storage, centres, offset) against central differences."""
    _, motion, _, noisy = record
    data = fj.FrictionData(motion, noisy).slice(0, 40)
    loss = fj.SimulationLoss()
    model = true_model()
    value = jax.jit(lambda m: loss(m, None, data))
    grads = jax.grad(value)(model)
    leaves = {
        "L": (lambda m: m.L, 4),
        "a": (lambda m: m.a, 1),
        "b": (lambda m: m.b.raw, 2),
        "c": (lambda m: m.c, (0, 1)),
        "s": (lambda m: m.s, 0),
        "beta": (lambda m: m.beta.raw, 1),
        "gamma": (lambda m: m.gamma, (1, 2)),
        "d": (lambda m: m.d, ()),
    }
    h = 1e-6
    for name, (where, index) in leaves.items():
        analytic = float(where(grads)[index])
        shifted = [eqx.tree_at(where, model, where(model).at[index].add(sign * h)) for sign in (1, -1)]
        fd = float((value(shifted[0]) - value(shifted[1])) / (2 * h))
        assert np.isfinite(analytic), name
        np.testing.assert_allclose(analytic, fd, rtol=1e-5, atol=1e-9, err_msg=name)


def test_fixed_fields_are_not_trained():
    """The projection, the centre r and the mask are fixed (`fj.Fixed`): no gradient reaches them."""
    spec = fj.trainable_filter(true_model())
    assert not any(jax.tree_util.tree_leaves((spec.center, spec.Q, spec.P, spec.unit_mask)))
    assert all(jax.tree_util.tree_leaves((spec.L, spec.a, spec.b, spec.c, spec.s, spec.beta, spec.gamma, spec.d)))


def test_model_file_round_trip(tmp_path, record):
    _, motion, _, _ = record
    model = true_model(unit_mask=[1, 1, 0, 1, 1])
    fj.save_model(tmp_path / "wavelet.eqx", model)
    loaded = fj.load_model(tmp_path / "wavelet.eqx")
    assert isinstance(loaded, fj.WaveletNARX) and loaded.dim == Q_DIM
    np.testing.assert_array_equal(fj.simulate(loaded, motion), fj.simulate(model, motion))


def test_errors(record):
    _, motion, clean, _ = record
    data = fj.FrictionData(motion, clean)
    p = parameters()
    with pytest.raises(ValueError, match=r"`Q` .* shape \(6, q\)"):
        true_model(Q=np.ones((5, 2)))
    with pytest.raises(ValueError, match=r"`L` must have shape \(6,\)"):
        true_model(L=np.ones(4))
    with pytest.raises(ValueError, match=r"`b` must have shape \(3,\)"):
        true_model(b=np.ones(2))
    with pytest.raises(ValueError, match="`beta` must be positive"):
        true_model(beta=[1.0, -1.0])
    with pytest.raises(ValueError, match=r"`c` must have shape \(3, 3\)"):
        true_model(c=p["c"][:, :2])
    with pytest.raises(ValueError, match="`a` must be finite"):
        true_model(a=[np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="one entry per unit"):
        true_model(unit_mask=[1, 1])
    with pytest.raises(TypeError, match="NARXRegressors"):
        fj.WaveletNARX("v", **p)
    for name, bad in (("units", -1), ("levels", 0), ("candidates", 1.5), ("components", True)):
        with pytest.raises(ValueError, match=f"`{name}`"):
            fj.identify_wavelet_narx(data, **{name: bad})
    with pytest.raises(ValueError, match="criterion"):
        fj.identify_wavelet_narx(data, criterion="aic")
    for bad in ((), (0, 0), (9,), (0.5,), "v"):
        with pytest.raises(ValueError, match="`nonlinear`"):
            fj.identify_wavelet_narx(data, nonlinear=bad)
    with pytest.raises(ValueError, match="unknown signals"):
        fj.identify_wavelet_narx(data, signals=("v", "jerk"))
    with pytest.raises(ValueError, match="too few samples"):
        fj.identify_wavelet_narx(data.slice(0, 40), candidates=50)
    with pytest.raises(ValueError, match="give `plays`"):
        fj.identify_wavelet_narx(data, regressors=regressors(), plays=[1e-5])
    with pytest.raises(TypeError, match="`regressors`"):
        fj.identify_wavelet_narx(data, regressors=("v",))
    still = fj.FrictionData(fj.Motion.from_velocity(np.zeros(100), dt=1e-3), np.zeros(100))
    with pytest.raises(ValueError, match="do not vary"):
        fj.identify_wavelet_narx(still, signals=("v",), input_lags=0, output_lags=1, candidates=10)
