"""Neural black-box models (MLP NARX, GSNN, AVD network, recurrent dynamical network) against independent
NumPy loops written from the papers' equations: free run, one-step (teacher forcing) and k-step prediction;
the GSNN denominator bound (worden2007 eq. 32) held by the reparametrisation; masks equal to smaller models;
smooth -> exact for the recurrent network's piecewise-linear sigmoid; errors; model files. The shared battery
(shapes, jit, vmap, finite-difference gradients) runs over these models in test_battery.py."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

from helpers import neural_record, neural_table, presliding_to_sliding

MOTION = presliding_to_sliding(250)


def numpy_signals(motion, names):
    """The normalisation-free input signals, as MotionSample derives them."""
    samples = motion.samples(frozenset(names) | {"a"})
    return {name: np.asarray(getattr(samples, name)) for name in ("x", "v", "a", "dx")}


def numpy_narx(model, motion, measured=None):
    """A NARX network by an explicit loop over the regressor definition (lags newest first, masks, scales)."""
    p = fj.unwrap(model)
    reg = p.regressors
    signals = numpy_signals(motion, reg.signals)
    mean, scale = np.asarray(reg.input_mean), np.asarray(reg.input_scale)
    y_mean, y_scale = float(reg.output_mean), float(reg.output_scale)
    in_mask, out_mask = np.asarray(reg.input_mask), np.asarray(reg.output_mask)
    T = motion.length
    u = np.stack([(signals[s] - mean[i]) / scale[i] for i, s in enumerate(reg.signals)], axis=1)  # (T, S)
    rest = -mean / scale
    y = np.zeros(T)
    past = np.zeros(T)  # what is fed back: predictions (free run) or measurements
    thresholds = np.asarray(reg.plays)
    plays = np.zeros(thresholds.size)
    for k in range(T):
        lags = [u[k - i] if k - i >= 0 else rest for i in range(reg.input_lags + 1)]
        phi_in = np.concatenate([lag * in_mask[i] for i, lag in enumerate(lags)])
        plays = np.clip(plays + signals["dx"][k] / thresholds, -1.0, 1.0)  # play operators (exact)
        outs = np.array([past[k - j] if k - j >= 0 else 0.0 for j in range(1, reg.output_lags + 1)])
        phi = np.concatenate([phi_in, plays, (outs - y_mean) / y_scale * out_mask])
        y[k] = y_mean + y_scale * numpy_network(p, phi)
        past[k] = y[k] if measured is None else measured[k]
    return y


def numpy_network(p, phi):
    mask = np.asarray(p.unit_mask)
    linear = 0.0 if p.theta is None else float(np.asarray(p.theta) @ phi)
    if isinstance(p, fj.MLPNARX):
        hidden = np.tanh(np.asarray(p.W) @ phi + np.asarray(p.b)) * mask
        return float(np.asarray(p.d) @ hidden + float(p.d0)) + linear
    g = {"logsig": lambda z: 1 / (1 + np.exp(-z)), "exp": np.exp, "tanh": np.tanh}[p.denominator]
    numerator = np.asarray(p.b) + np.tanh(np.asarray(p.w) @ phi + np.asarray(p.w0))
    denominator = np.asarray(p.a_excess) + p.bound - {"logsig": 0.0, "exp": 0.0, "tanh": -1.0}[p.denominator]
    denominator = denominator + g(np.asarray(p.c) @ phi + np.asarray(p.c0))
    return float(np.asarray(p.d) @ (numerator / denominator * mask) + float(p.d0)) + linear


def numpy_rnn(model, motion, eps=None):
    """parlitz2004 eqs. 26-28 by a loop; `eps` for the smooth sigmoid (|z+1| - |z-1|) / 2 with smooth |.|."""
    p = fj.unwrap(model)
    signals = numpy_signals(motion, p.signals)
    u = np.stack(
        [(signals[s] - float(p.input_mean[i])) / float(p.input_scale[i]) for i, s in enumerate(p.signals)], axis=1
    )
    rest = -np.asarray(p.input_mean) / np.asarray(p.input_scale)
    alpha = np.tanh(np.asarray(p.alpha_raw))
    w = np.asarray(p.w) * np.asarray(p.connectivity)
    x = np.zeros(len(alpha))
    out = np.empty(motion.length)

    def sigma(z):
        if eps is None:
            return np.clip(z, -1, 1)
        smooth_abs = lambda s: s * np.tanh(s / eps)  # noqa: E731 - fj.Smooth's |x|, as documented there
        return 0.5 * (smooth_abs(z + 1) - smooth_abs(z - 1))

    for k in range(motion.length):
        delayed = [u[k - d] if k - d >= 0 else rest for d in p.delays]  # each (S,)
        inputs = np.array([delayed[j][s] for s in range(len(p.signals)) for j in range(len(p.delays))])
        drive = np.asarray(p.w0) + w @ x + np.asarray(p.v) @ inputs
        x = (alpha * x + (1 - np.abs(alpha)) * sigma(drive)) * np.asarray(p.unit_mask)
        out[k] = float(p.output_mean) + float(p.output_scale) * (np.asarray(p.theta) @ x + float(p.theta0))
    return out


NARX_NAMES = ["mlp_narx", "gsnn", "gsnn_exp", "gsnn_tanh", "avd", "mlp_plays", "gsnn_plays"]


@pytest.mark.parametrize(
    "name",  # the MLP NARX is checked against NumPy in test_battery.py too: its compile here in the slow tier
    [pytest.param(n, marks=pytest.mark.slow) if n in ("mlp_narx", "gsnn") else n for n in NARX_NAMES],  # gsnn: its
    # variants gsnn_exp / gsnn_tanh / gsnn_plays run the same network fast
)
def test_narx_free_run_and_one_step_match_numpy(name):
    model = neural_table()[name]
    free = np.asarray(fj.simulate(model, MOTION))
    np.testing.assert_allclose(free, numpy_narx(model, MOTION), rtol=1e-10, atol=1e-12)
    assert np.ptp(free) > 0.1
    measured = free + 0.3 * np.sin(np.arange(MOTION.length))
    forced = np.asarray(fj.simulate(model, MOTION, measured=measured))
    np.testing.assert_allclose(forced, numpy_narx(model, MOTION, measured), rtol=1e-10, atol=1e-12)
    if model.regressors.output_lags:  # teacher forcing changes the prediction only where outputs are fed back
        assert np.max(np.abs(forced - free)) > 1e-3
    else:
        np.testing.assert_array_equal(forced, free)


def test_narx_k_step_is_free_run_from_forced_states():
    model = neural_table()["gsnn"]
    free = np.asarray(fj.simulate(model, MOTION))
    measured = free + 0.2 * np.cos(0.3 * np.arange(MOTION.length))
    k = 3
    predicted = np.asarray(fj.simulate(model, MOTION, measured=measured, horizon=k))
    for t in (k + 5, 100, MOTION.length - 1):  # from the state forced by measurements up to t - k
        np.testing.assert_allclose(
            predicted[t], numpy_narx_window(model, MOTION, measured, t, k), rtol=1e-10, atol=1e-12
        )


def numpy_narx_window(model, motion, measured, t, k):
    """Prediction of sample t: teacher forcing by `measured` up to sample t - k, then a free run to t."""
    p = fj.unwrap(model)
    reg = p.regressors
    signals = numpy_signals(motion, reg.signals)
    mean, scale = np.asarray(reg.input_mean), np.asarray(reg.input_scale)
    u = np.stack([(signals[s] - mean[i]) / scale[i] for i, s in enumerate(reg.signals)], axis=1)
    rest = -mean / scale
    past = np.zeros(t + 1)
    y = 0.0
    for j in range(t + 1):
        lags = [u[j - i] if j - i >= 0 else rest for i in range(reg.input_lags + 1)]
        phi_in = np.concatenate([lag * float(reg.input_mask[i]) for i, lag in enumerate(lags)])
        outs = np.array([past[j - i] if j - i >= 0 else 0.0 for i in range(1, reg.output_lags + 1)])
        phi = np.concatenate([phi_in, (outs - float(reg.output_mean)) / float(reg.output_scale) * reg.output_mask])
        y = float(reg.output_mean) + float(reg.output_scale) * numpy_network(p, phi)
        past[j] = measured[j] if j <= t - k else y
    return y


@pytest.mark.parametrize("mode", ["exact", "smooth"])
def test_recurrent_network_matches_numpy(mode):
    model = neural_table()["rnn"]
    eps = None if mode == "exact" else 0.05
    if eps is not None:
        model = fj.with_smoothing(model, fj.Smooth(eps))
    out = np.asarray(fj.simulate(model, MOTION))
    np.testing.assert_allclose(out, numpy_rnn(model, MOTION, eps), rtol=1e-10, atol=1e-12)
    assert np.ptp(out) > 0.1
    np.testing.assert_array_equal(fj.simulate(model, MOTION, measured=out + 1.0), out)  # no fed-back output


def test_recurrent_network_smooth_converges_to_exact():
    model = neural_table()["rnn"]
    exact = np.asarray(fj.simulate(model, MOTION))
    errors = [
        float(np.max(np.abs(np.asarray(fj.simulate(fj.with_smoothing(model, fj.Smooth(eps)), MOTION)) - exact)))
        for eps in (1e-1, 1e-2, 1e-3, 1e-4)
    ]
    assert errors[0] > 1e-3  # the sigmoid saturates on this record: smoothing matters
    assert all(b < 0.5 * a for a, b in zip(errors, errors[1:], strict=False)), errors
    assert errors[-1] < 1e-3 * np.ptp(exact)
    np.testing.assert_array_equal(fj.simulate(fj.exact(fj.with_smoothing(model, fj.Smooth(0.1))), MOTION), exact)


def test_recurrent_network_structure():
    model = neural_table()["rnn"]
    conn = np.asarray(fj.unwrap(model).connectivity)
    assert np.all(np.diag(conn) == 0)  # eq. 27: j != i
    assert np.all(np.abs(np.asarray(model.alpha)) < 1)
    big = fj.RecurrentNetwork.init(neural_record(), 60, key=jax.random.PRNGKey(3), connectivity=0.11)
    fraction = float(np.asarray(fj.unwrap(big).connectivity).sum()) / (60 * 59)
    assert 0.07 < fraction < 0.15
    w = np.asarray(fj.unwrap(big).w) * np.asarray(fj.unwrap(big).connectivity)
    assert np.max(np.abs(np.linalg.eigvals(w))) == pytest.approx(0.8, rel=1e-6)  # echo-state scaling


@pytest.mark.slow  # the fast tier stays under 5 minutes
def test_rnn_readout_least_squares_is_the_whole_fit():
    """The readout is linear: a fit of theta and theta0 alone is one least-squares solve, equal to NumPy's."""
    data = neural_record()
    model = fj.RecurrentNetwork.init(data, 6, key=jax.random.PRNGKey(1), delays=(0, 4, 9))
    result = fj.fit(model, data, train=("theta", "theta0"), separable=("theta", "theta0"), steps=1)
    assert result.code == "successful"
    # NumPy: the element states do not depend on the readout; regress the force on [x_i(t), 1]
    p = fj.unwrap(model)
    basis = []
    for i in range(6):
        unit = fj.RecurrentNetwork(
            p.alpha_raw, p.w, p.w0, p.v, np.eye(6)[i], 0.0, connectivity=p.connectivity, signals=p.signals,
            delays=p.delays, input_mean=p.input_mean, input_scale=p.input_scale,
        )  # fmt: skip
        basis.append(np.asarray(fj.simulate(unit, data.motion)))
    A = np.column_stack([*basis, np.ones(data.length)])
    coef = np.linalg.lstsq(A, (np.asarray(data.force) - float(p.output_mean)) / float(p.output_scale), rcond=None)[0]
    np.testing.assert_allclose(result.model.theta, coef[:6], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(result.model.theta0, coef[6], rtol=1e-6, atol=1e-8)


def test_gsnn_denominator_bound_holds_for_any_parameters():
    """eq. 32, a_j + g(.) > p, for every input and every value an optimiser can give the stored parameters."""
    model = neural_table()["gsnn"]
    for denominator, g, g_min in (
        ("logsig", jax.nn.sigmoid, 0.0),
        ("exp", jnp.exp, 0.0),
        ("tanh", jnp.tanh, -1.0),
    ):
        m = fj.GSNN.init(model.regressors, 4, key=jax.random.PRNGKey(0), denominator=denominator, bound=0.2)
        raw = jnp.full((4,), -40.0)  # the most negative excess an optimiser could reach
        m = eqx_set(m, raw)
        a = np.asarray(m.a)
        z = np.linspace(-50, 50, 1001)
        low = a[:, None] + np.asarray(g(z))[None]
        assert np.all(low > 0.2 - 1e-12), denominator
        assert np.all(a >= 0.2 - g_min)  # equality only where exp(raw) underflows against p


def eqx_set(model, raw):
    import equinox as eqx

    return eqx.tree_at(lambda m: m.a_excess.raw, model, raw)


def test_masks_equal_smaller_models():
    """A masked lag or unit is the model without it: the sweep over orders and widths by masking."""
    data = neural_record()
    key = jax.random.PRNGKey(5)
    full = fj.MLPNARX.init(fj.NARXRegressors.from_data(data, ("x", "v"), 2, 4), 6, key=key)
    masked = fj.MLPNARX(
        fj.NARXRegressors(
            ("x", "v"), 2, 4,
            input_mean=full.regressors.input_mean, input_scale=full.regressors.input_scale,
            output_mean=full.regressors.output_mean, output_scale=full.regressors.output_scale,
            input_mask=[1.0, 1.0, 0.0], output_mask=[1.0, 1.0, 0.0, 0.0],
        ),
        full.W, full.b, full.d, full.d0, unit_mask=[1, 1, 1, 1, 0, 0],
    )  # fmt: skip
    keep_cols = [0, 1, 2, 3, 6, 7]  # lags 0, 1 of (x, v) and output lags 1, 2
    small = fj.MLPNARX(
        fj.NARXRegressors(
            ("x", "v"), 1, 2,
            input_mean=full.regressors.input_mean, input_scale=full.regressors.input_scale,
            output_mean=full.regressors.output_mean, output_scale=full.regressors.output_scale,
        ),
        np.asarray(full.W)[:4][:, keep_cols], full.b[:4], full.d[:4], full.d0,
    )  # fmt: skip
    np.testing.assert_allclose(fj.simulate(masked, data.motion), fj.simulate(small, data.motion), rtol=1e-12)
    assert np.max(np.abs(np.asarray(fj.simulate(full, data.motion) - fj.simulate(small, data.motion)))) > 1e-3


def test_errors_name_the_argument():
    data = neural_record()
    reg = fj.NARXRegressors.from_data(data, ("x", "v"), 0, 2)
    with pytest.raises(ValueError, match="unknown signals"):
        fj.NARXRegressors(("x", "force"))
    with pytest.raises(ValueError, match="output_lags"):
        fj.NARXRegressors(("x",), 0, -1)
    with pytest.raises(ValueError, match="input_mask"):
        fj.NARXRegressors(("x",), 1, 1, input_mask=[1.0])
    with pytest.raises(ValueError, match="input_scale"):
        fj.NARXRegressors(("x",), 0, 1, input_scale=[0.0])
    with pytest.raises(ValueError, match="width"):
        fj.MLPNARX.init(reg, 0, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="shapes"):
        fj.MLPNARX(reg, np.zeros((3, 5)), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="denominator"):
        fj.GSNN.init(reg, 2, key=jax.random.PRNGKey(0), denominator="relu")
    with pytest.raises(ValueError, match="bound"):
        fj.GSNN.init(reg, 2, key=jax.random.PRNGKey(0), bound=0.0)
    g = fj.GSNN.init(reg, 2, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="eq. 32"):
        fj.GSNN(reg, g.w, g.w0, g.c, g.c0, g.b, [0.05, 1.0], g.d, g.d0, bound=0.1)
    with pytest.raises(ValueError, match="delays"):
        fj.RecurrentNetwork.init(data, 5, key=jax.random.PRNGKey(0), delays=(-1,))
    with pytest.raises(ValueError, match="connectivity"):
        fj.RecurrentNetwork.init(data, 5, key=jax.random.PRNGKey(0), connectivity=0.0)
    with pytest.raises(ValueError, match="elements"):
        fj.RecurrentNetwork.init(data, 0, key=jax.random.PRNGKey(0))


@pytest.mark.parametrize("name", sorted(["mlp_narx", "gsnn", "avd", "rnn"]))
def test_model_files_round_trip(tmp_path, name):
    model = neural_table()[name]
    fj.save_model(tmp_path / "m.eqx", model)
    loaded = fj.load_model(tmp_path / "m.eqx")
    assert type(loaded) is type(model)
    np.testing.assert_array_equal(fj.simulate(loaded, MOTION), fj.simulate(model, MOTION))


def test_play_regressors_are_maxwell_slip_elements():
    """A play state is a Maxwell-slip element's normalised force: it follows the displacement with unit slope
    (1 / threshold) after a reversal and saturates at +-1 once the displacement has moved 2 thresholds."""
    x = 1e-6 * np.concatenate([np.linspace(0, 5, 51), np.linspace(5, 2, 31)[1:], np.linspace(2, 6, 41)[1:]])
    motion = fj.Motion.from_position(x, dt=1e-3)
    reg = fj.NARXRegressors(("x",), 0, 0, plays=[1e-6, 4e-6])
    model = fj.MLPNARX(reg, np.zeros((1, 3)), np.zeros(1), np.zeros(1), 0.0, theta=[0.0, 1.0, 0.0])
    first = np.asarray(fj.simulate(model, motion))  # theta picks the first play state
    expected = np.clip(np.cumsum(np.r_[0.0, np.diff(x)]) / 1e-6, -1, 1)  # from rest: saturates after 1 um
    np.testing.assert_allclose(first[:51], expected[:51], atol=1e-12)
    reversal = first[50 : 50 + 31]  # back from +1 by (5 - x) / 1 um, saturating at -1 after 2 um
    np.testing.assert_allclose(reversal, np.clip(1.0 - (5e-6 - x[50:81]) / 1e-6, -1, 1), atol=1e-12)
    model4 = fj.MLPNARX(reg, np.zeros((1, 3)), np.zeros(1), np.zeros(1), 0.0, theta=[0.0, 0.0, 1.0])
    second = np.asarray(fj.simulate(model4, motion))
    assert second.max() == pytest.approx(1.0) and second[80] == pytest.approx(1.0 - 3e-6 / 4e-6)


def test_hysteretic_recurrent_network_elements_are_plays_and_static_units():
    data = neural_record()
    thresholds = np.array([2e-6, 1e-5, 5e-5])
    model = fj.RecurrentNetwork.hysteretic(data, thresholds, 2, key=jax.random.PRNGKey(0))
    assert model.signals == ("dx", "v") and model.requires == frozenset({"x", "v"})
    out = np.asarray(fj.simulate(model, MOTION))
    np.testing.assert_allclose(out, numpy_rnn(model, MOTION), rtol=1e-10, atol=1e-12)
    # the readout of element i alone: play i is clip(cumulative dx / Delta_i) with memory, statics are static
    p = fj.unwrap(model)
    dx = np.asarray(MOTION.samples().dx)
    for i, delta in enumerate(thresholds):
        element = fj.RecurrentNetwork(
            p.alpha_raw, p.w, p.w0, p.v, np.eye(5)[i], 0.0, connectivity=p.connectivity, signals=p.signals,
            delays=p.delays, input_mean=p.input_mean, input_scale=p.input_scale,
        )  # fmt: skip
        state, expected = 0.0, []
        for step in dx:
            state = min(1.0, max(-1.0, state + step / delta))
            expected.append(state)
        np.testing.assert_allclose(fj.simulate(element, MOTION), expected, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="thresholds"):
        fj.RecurrentNetwork.hysteretic(data, [1e-6, -1e-6], key=jax.random.PRNGKey(0))


@pytest.mark.slow  # the fast tier stays under 5 minutes
def test_output_layer_is_linear_and_solved_by_least_squares():
    """With the hidden weights fixed, (d, d0, theta) enter the force linearly: a fit of them alone is one
    least-squares solve, reaching the NumPy solution (no fed-back outputs: with them the force is not linear)."""
    data = neural_record()
    regressors = fj.NARXRegressors.from_data(data, ("v",), 0, 0, plays=[2e-6, 1e-5, 5e-5])
    model = fj.GSNN.init(regressors, 3, key=jax.random.PRNGKey(2), linear=True)
    layer = ("d", "d0", "theta")
    result = fj.fit(model, data, train=layer, separable=layer, steps=1)
    assert result.code == "successful"
    basis = []
    p = fj.unwrap(model)
    for vector in np.eye(p.d.size + 1 + p.theta.size):
        probe = fj.GSNN(
            model.regressors, p.w, p.w0, p.c, p.c0, p.b, p.a, vector[: p.d.size], vector[p.d.size],
            denominator=p.denominator, bound=p.bound, theta=vector[p.d.size + 1 :],
        )  # fmt: skip
        basis.append(np.asarray(fj.simulate(probe, data.motion)) - float(p.regressors.output_mean))
    A = np.column_stack(basis) / float(p.regressors.output_scale)
    target = (np.asarray(data.force) - float(p.regressors.output_mean)) / float(p.regressors.output_scale)
    coef = np.linalg.lstsq(A, target, rcond=None)[0]
    np.testing.assert_allclose(result.model.d, coef[: p.d.size], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(result.model.theta, coef[p.d.size + 1 :], rtol=1e-6, atol=1e-8)
