"""Local (nearest-neighbour) models, parlitz2004 §III-F: `fj.LocalModel` and `fj.identify_local_model`.

1. NumPy oracle: a brute-force loop written from the paper's equations (delay vectors built sample by sample,
   every distance, a stable sort for the neighbours, eq. 22's mean or eqs. 23-25's TPCR fit by NumPy's SVD) for
   the free run and the one-step prediction, locally constant and linear, with and without fed-back forces.
2. Properties: a training point with k = 1 predicts its own force; the full-rank local fit is
   `numpy.linalg.lstsq` of eq. 25; truncation keeps the principal components above `rcond` or up to `rank`;
   ties go to the lower index.
3. JAX: jit == no jit, vmap over models and motions == loop, `step` loop == `simulate`; model files.
4. Identification: the grid's scores (masks: neighbour masks equal smaller `k`) are the free-run errors of the
   separately built models; the drift rate is recovered; errors name the argument.
5. (slow) The acceptance figure on the mixed tribometer regime.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

DT = 1e-3
T = 260
TRAIN = 200


def multisine(t, amplitude, freqs, rng):
    return sum(amplitude * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in freqs)


@pytest.fixture(scope="module")
def record():
    """A hysteretic record: a Maxwell-slip force of a multisine displacement with a little noise."""
    rng = np.random.default_rng(3)
    t = np.arange(T) * DT
    x = multisine(t, 4e-6, [3.0, 7.0, 17.0], rng) + 2e-6
    motion = fj.Motion.from_position(x, dt=DT)
    truth = fj.MaxwellSlip.nlr(k=[2e5, 1e5, 5e4], thresholds=[1e-6, 3e-6, 8e-6])
    force = np.asarray(fj.simulate(truth, motion)) + 0.01 * rng.standard_normal(T)
    return fj.FrictionData(motion, force)


# ----------------------------------------------------------------------------------------------------------------
# 1. NumPy oracle
# ----------------------------------------------------------------------------------------------------------------


def numpy_signals(motion):
    samples = motion.samples(frozenset({"x", "v"}))
    return {name: np.asarray(getattr(samples, name)) for name in ("x", "v", "dx")}


class Oracle:
    """A local model by brute force: delay vectors from their definition, every distance, a stable sort."""

    def __init__(self, train, *, signals, m, tau, plays=(), m_out=0, tau_out=1, k, kind, rank=None, rcond=1e-3):
        self.signals, self.m, self.tau, self.m_out, self.tau_out = signals, m, tau, m_out, tau_out
        self.plays, self.k, self.kind, self.rank, self.rcond = np.asarray(plays, float), k, kind, rank, rcond
        u = numpy_signals(train.motion)
        self.mean = np.array([u["x"].mean() if s == "x" else 0.0 for s in signals])
        self.scale = np.array([u[s].std() for s in signals])
        force = np.asarray(train.force)
        self.force_mean, self.force_scale = force.mean(), force.std()
        self.lag = max((m - 1) * tau, 1 + (m_out - 1) * tau_out if m_out else 0)
        rows = self.vectors(train.motion, force)
        self.points, self.forces = rows[self.lag :], force[self.lag :]

    def vector(self, u, plays, past, k):
        """The delay vector at sample k: signals at lags 0, tau, ...; play states; past forces 1, 1 + tau_out, ..."""
        z = []
        for lag in range(0, self.m * self.tau, self.tau):
            for j, s in enumerate(self.signals):
                value = u[s][k - lag] if k - lag >= 0 else 0.0  # at rest before the record
                z.append((value - self.mean[j]) / self.scale[j])
        z.extend(plays)
        for lag in range(1, 1 + self.m_out * self.tau_out, self.tau_out):
            value = past[k - lag] if k - lag >= 0 else 0.0
            z.append((value - self.force_mean) / self.force_scale)
        return np.array(z)

    def vectors(self, motion, measured):
        u, plays, rows = numpy_signals(motion), np.zeros(self.plays.size), []
        for k in range(motion.length):
            plays = np.clip(plays + u["dx"][k] / self.plays, -1.0, 1.0)
            rows.append(self.vector(u, plays, measured, k))
        return np.array(rows)

    def predict(self, z):
        distance = np.sum((self.points - z) ** 2, axis=1)
        nn = np.argsort(distance, kind="stable")[: self.k]
        y = self.forces[nn]
        if self.kind == "constant":
            return y.mean()  # eq. 22, constant weights
        Z = self.points[nn]
        zbar, ybar = Z.mean(axis=0), y.mean()
        U, S, Vt = np.linalg.svd(Z - zbar, full_matrices=False)
        floor = max(self.rcond, np.finfo(float).eps * max(Z.shape)) * S[0]
        rank = Z.shape[1] if self.rank is None else self.rank
        keep = (S > floor) & (np.arange(S.size) < rank)
        a = Vt[keep].T @ ((U[:, keep].T @ (y - ybar)) / S[keep])
        return ybar + a @ (z - zbar)

    def run(self, motion, measured=None):
        """Free run (measured None) or one-step prediction (fed-back forces are the measured ones)."""
        u, plays, past, out = numpy_signals(motion), np.zeros(self.plays.size), np.zeros(motion.length), []
        for k in range(motion.length):
            plays = np.clip(plays + u["dx"][k] / self.plays, -1.0, 1.0)
            out.append(self.predict(self.vector(u, plays, past, k)))
            past[k] = out[-1] if measured is None else measured[k]
        return np.array(out)


CASES = {
    "constant_plays": dict(signals=("x",), m=3, tau=2, plays=(2e-6, 6e-6), k=4, kind="constant"),
    "linear_feedback": dict(
        signals=("x", "v"), m=2, tau=1, m_out=2, tau_out=2, k=10, kind="linear", rank=4, rcond=1e-2
    ),
}


def build(train, case):
    kwargs = dict(case)
    plays = kwargs.pop("plays", None)
    return fj.LocalModel.from_data(
        train,
        embedding=kwargs.pop("m"),
        delay=kwargs.pop("tau"),
        output_embedding=kwargs.pop("m_out", 0),
        output_delay=kwargs.pop("tau_out", 1),
        plays=plays,
        play_states=None if plays is None else fj.simulate(fj.PlayOperators(plays), train.motion),
        neighbours=kwargs.pop("k"),
        **kwargs,
    )


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n == "linear_feedback" else n for n in sorted(CASES)]
)
def test_free_run_and_one_step_match_numpy(record, name):
    """Free run against the brute-force loop; with fed-back forces also the one-step prediction (teacher forcing
    through `feedback`), which differs from the free run."""
    train = record.slice(0, TRAIN)
    model, oracle = build(train, CASES[name]), Oracle(train, **CASES[name])
    np.testing.assert_allclose(model.points.value, oracle.points, rtol=1e-12, atol=1e-12)
    free = np.asarray(fj.simulate(model, record.motion))
    np.testing.assert_allclose(free, oracle.run(record.motion), rtol=1e-9, atol=1e-9)
    if "m_out" in CASES[name]:
        force = np.asarray(record.force)
        one_step = np.asarray(fj.simulate(model, record.motion, measured=force))
        np.testing.assert_allclose(one_step, oracle.run(record.motion, force), rtol=1e-9, atol=1e-9)
        assert np.max(np.abs(one_step - free)) > 1e-3


# ----------------------------------------------------------------------------------------------------------------
# 2. properties of the local fits
# ----------------------------------------------------------------------------------------------------------------


def test_training_point_with_one_neighbour_is_its_own_force(record):
    model = fj.LocalModel.from_data(record, embedding=3, delay=2, signals=("x", "v"), neighbours=1)
    np.testing.assert_array_equal(model.predict(model.points.value), model.forces.value)
    assert model.describe() == ["x[k]", "v[k]", "x[k-2]", "v[k-2]", "x[k-4]", "v[k-4]"]


def local_linear(points, forces, **kwargs):
    regressors = fj.NARXRegressors(("x",), points.shape[1] - 1, 0)
    return fj.LocalModel(regressors, points, forces, neighbours=points.shape[0], kind="linear", **kwargs)


def test_full_rank_local_fit_is_least_squares():
    """With every point a neighbour and no truncation, the locally linear model is eq. 25: the least-squares
    fit of `F ~ a . z + a0` (numpy.linalg.lstsq of `[Z, 1]`), evaluated at the query."""
    rng = np.random.default_rng(0)
    points, query = rng.standard_normal((40, 4)), rng.standard_normal((3, 4))  # shapes as below: one compile
    forces = rng.standard_normal(40)
    design = np.column_stack([points, np.ones(40)])
    coef = np.linalg.lstsq(design, forces, rcond=None)[0]
    model = local_linear(points, forces, rcond=0.0)
    np.testing.assert_allclose(model.predict(query), np.column_stack([query, np.ones(3)]) @ coef, rtol=1e-10)
    # targets: the same fit of other values attached to the points, several at once
    other = np.column_stack([forces, rng.standard_normal((40, 2))])
    expected = np.column_stack([query, np.ones(3)]) @ np.linalg.lstsq(design, other, rcond=None)[0]
    np.testing.assert_allclose(model.predict(query, other), expected, rtol=1e-10)


@pytest.mark.parametrize("options", [dict(rank=2), dict(rcond=0.15)])
def test_truncation_keeps_the_leading_principal_components(options):
    """TPCR: the slope is the least-squares solution on the leading principal components of the centred
    neighbourhood (NumPy SVD); the discarded directions get no slope."""
    rng = np.random.default_rng(1)
    points = rng.standard_normal((40, 4)) * np.array([3.0, 1.0, 0.2, 0.05])  # principal axes = coordinates
    forces = points @ np.array([1.0, -2.0, 5.0, 20.0]) + 0.1 * rng.standard_normal(40)
    query = rng.standard_normal((3, 4))
    centred = points - points.mean(axis=0)
    U, S, Vt = np.linalg.svd(centred, full_matrices=False)
    keep = np.arange(4) < 2 if "rank" in options else S > options["rcond"] * S[0]
    assert keep.sum() == 2  # both settings keep two components here
    slope = Vt[keep].T @ ((U[:, keep].T @ (forces - forces.mean())) / S[keep])
    expected = forces.mean() + (query - points.mean(axis=0)) @ slope
    np.testing.assert_allclose(local_linear(points, forces, **options).predict(query), expected, rtol=1e-10)
    full = np.linalg.lstsq(np.column_stack([centred, np.ones(40)]), forces, rcond=None)[0]
    assert np.max(np.abs(np.asarray(local_linear(points, forces, rcond=0.0).predict(query)) - expected)) > 0.1
    np.testing.assert_allclose(
        local_linear(points, forces, rcond=0.0).predict(query),
        np.column_stack([query - points.mean(axis=0), np.ones(3)]) @ full,
        rtol=1e-10,
    )


def test_neighbours_are_exact_with_ties_to_the_lower_index():
    """Many exact duplicates (ties): the neighbours are those of a stable sort of the distances, also where the
    search runs in blocks (1000 points)."""
    rng = np.random.default_rng(2)
    points = np.round(rng.uniform(0, 3, (1000, 2)))  # 16 distinct points
    forces = np.arange(1000.0)
    queries = rng.uniform(-0.5, 3.5, (50, 2))
    regressors = fj.NARXRegressors(("x",), 1, 0)
    model = fj.LocalModel(regressors, points, forces, neighbours=7)
    expected = [forces[np.argsort(np.sum((points - q) ** 2, 1), kind="stable")[:7]].mean() for q in queries]
    np.testing.assert_allclose(model.predict(queries), expected, rtol=1e-14)


# ----------------------------------------------------------------------------------------------------------------
# 3. JAX transformations and model files
# ----------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def feedback_model(record):
    return build(record.slice(0, TRAIN), CASES["linear_feedback"])


@pytest.fixture(scope="module")
def periodic():
    """A displacement sine (period 103 samples) and a force that is a function of it plus a 2 N/s drift."""
    t = np.arange(T) * DT
    x = 5e-6 * np.sin(2 * np.pi * 9.7 * t)
    return fj.FrictionData(fj.Motion.from_position(x, dt=DT), np.tanh(x / 3e-6) + 2.0 * t)


@pytest.mark.slow  # about 4 s
def test_step_loop_and_vmap(record, feedback_model):
    """`simulate` (one scan) equals a Python loop over `step` (each step jit-compiled on its own; an eager step
    compiles every primitive separately, seconds for the SVD and the search); vmap over models == loop."""
    model, motion = feedback_model, record.motion
    eager = np.asarray(fj.simulate(model, motion))
    state, samples, out = model.init_state(), model.samples(motion), []
    step = eqx.filter_jit(model.step)
    for k in range(20):
        state, y = step(state, samples.at(k))
        out.append(y)
    np.testing.assert_allclose(out, eager[:20], rtol=1e-12, atol=1e-12)
    # vmap over models (other training forces: the points' forces scaled) == loop
    scales = jnp.asarray([0.5, 1.0, 2.0])

    def scaled(s):
        return eqx.tree_at(lambda m: m.forces, model, fj.Fixed(s * model.forces.value))

    batch = eqx.filter_vmap(lambda s: fj.simulate(scaled(s), motion))(scales)
    for i, s in enumerate([0.5, 1.0, 2.0]):
        np.testing.assert_allclose(batch[i], fj.simulate(scaled(s), motion), rtol=1e-10, atol=1e-12)
    assert fj.compare.count_parameters(model) == 0  # nothing to train: the training set is fixed


@pytest.mark.slow  # fast tier trimmed (2026-11-27): test_serialise.py round-trips every family in the fast tier
def test_model_files_round_trip(tmp_path, record, feedback_model, drift_result, periodic):
    """A local model with fed-back forces, and an identified one wrapped in its sensor drift."""
    for i, (model, motion) in enumerate([(feedback_model, record.motion), (drift_result.model, periodic.motion)]):
        fj.save_model(tmp_path / f"m{i}.eqx", model)
        loaded = fj.load_model(tmp_path / f"m{i}.eqx")
        assert type(loaded) is type(model)
        np.testing.assert_array_equal(fj.simulate(loaded, motion), fj.simulate(model, motion))
    assert loaded.model.kind == "linear" and float(loaded.rate) == float(drift_result.model.rate)
    assert feedback_model.describe() == ["x[k]", "v[k]", "x[k-1]", "v[k-1]", "F[k-1]", "F[k-3]"]
    states = fj.simulate(fj.PlayOperators([2e-6, 6e-6]), record.motion)
    plays = fj.LocalModel.from_data(record, embedding=3, delay=2, plays=[2e-6, 6e-6], play_states=states)
    assert plays.describe() == ["x[k]", "x[k-2]", "x[k-4]", "play[0]", "play[1]"]


# ----------------------------------------------------------------------------------------------------------------
# 4. identification
# ----------------------------------------------------------------------------------------------------------------


def free_run_nmse(model, record, start):
    prediction = np.asarray(fj.simulate(model, record.motion))
    return float(fj.nmse(np.asarray(record.force)[start:], prediction[start:]))


def grid_scores_match(record, feedback, checked):
    train = record.slice(0, TRAIN)
    grid = dict(embedding=(1, 3), delay=(1, 2), neighbours=(2, 5))
    result = fj.identify_local_model(
        train, validation=record, validation_burn_in=TRAIN, output_embedding=feedback, kind="linear", **grid
    )
    assert result.scores.shape == (2, 2, 2) and result.embedding == (1, 3) and result.neighbours == (2, 5)
    best = np.unravel_index(np.argmin(result.scores), (2, 2, 2))
    for i, j, k in [best] if checked is None else checked:
        m, tau, n = grid["embedding"][i], grid["delay"][j], grid["neighbours"][k]
        single = fj.LocalModel.from_data(
            train, embedding=m, delay=tau, neighbours=n, kind="linear", output_embedding=feedback, burn_in=4
        )
        assert result.scores[i, j, k] == pytest.approx(free_run_nmse(single, record, TRAIN), rel=1e-9)
    assert result.best == tuple(v[i] for v, i in zip(grid.values(), best, strict=True))
    assert free_run_nmse(result.model, record, TRAIN) == pytest.approx(np.min(result.scores), rel=1e-9)


@pytest.mark.slow  # about 6 s
def test_grid_scores_are_the_free_runs_of_the_models(record):
    """A score of the grid (one maximal shape, coordinates and neighbours switched off by masks) is the
    validation free-run NMSE of the model built on its own with that configuration (here the best, which is
    returned; every one in the slow tier, with and without fed-back forces)."""
    grid_scores_match(record, 0, None)


@pytest.mark.slow
@pytest.mark.parametrize("feedback", [0, 1])
def test_every_grid_score_is_the_free_run_of_its_model(record, feedback):
    grid_scores_match(record, feedback, [(i, j, k) for i in range(2) for j in range(2) for k in range(2)])


DRIFT_GRID = dict(validation_burn_in=TRAIN, embedding=1, delay=1, neighbours=(2, 3), kind="linear")


@pytest.fixture(scope="module")
def drift_result(periodic):
    return fj.identify_local_model(periodic.slice(0, TRAIN), validation=periodic, drift=True, **DRIFT_GRID)


def test_drift_rate_is_recovered(periodic, drift_result):
    """A force that is a function of the displacement plus a linear sensor drift (2 N/s): the fitted rate is the
    drift's, and the returned `SensorDrift` model predicts the drifting validation part."""
    result, options = drift_result, dict(DRIFT_GRID, validation=periodic)
    assert isinstance(result.model, fj.SensorDrift)
    assert float(result.model.rate) == pytest.approx(2.0, rel=1e-3)
    plain = fj.identify_local_model(periodic.slice(0, TRAIN), **options)
    assert np.min(result.scores) < 1e-3 * np.min(plain.scores)
    prediction = np.asarray(fj.simulate(result.model, periodic.motion))
    np.testing.assert_allclose(prediction[TRAIN:], np.asarray(periodic.force)[TRAIN:], atol=1e-3)


def test_errors_name_the_argument(record):
    train = record.slice(0, TRAIN)
    regressors = fj.NARXRegressors(("x",), 1, 0)
    points, forces = np.zeros((5, 2)), np.zeros(5)
    with pytest.raises(ValueError, match="`kind`"):
        fj.LocalModel(regressors, points, forces, neighbours=2, kind="quadratic")
    with pytest.raises(ValueError, match="`neighbours` must be an integer in 1..5"):
        fj.LocalModel(regressors, points, forces, neighbours=6)
    with pytest.raises(ValueError, match=r"`points` must have shape \(N, 2\)"):
        fj.LocalModel(regressors, np.zeros((5, 3)), forces, neighbours=2)
    with pytest.raises(ValueError, match="`forces` must have shape"):
        fj.LocalModel(regressors, points, np.zeros(4), neighbours=2)
    with pytest.raises(ValueError, match="`columns` must index"):
        fj.LocalModel(regressors, points, forces, columns=[0, 2], neighbours=2)
    with pytest.raises(ValueError, match="`metric` must be >= 0"):
        fj.LocalModel(regressors, points, forces, neighbours=2, metric=[1.0, -1.0])
    with pytest.raises(ValueError, match="`rcond`"):
        fj.LocalModel(regressors, points, forces, neighbours=2, rcond=1.5)
    with pytest.raises(ValueError, match="`rank`"):
        fj.LocalModel(regressors, points, forces, neighbours=2, rank=-1)
    with pytest.raises(TypeError, match="`regressors`"):
        fj.LocalModel("x", points, forces)
    with pytest.raises(ValueError, match="`embedding` must be a positive integer"):
        fj.LocalModel.from_data(train, embedding=0)
    with pytest.raises(ValueError, match="`burn_in`"):
        fj.LocalModel.from_data(train, burn_in=TRAIN)
    with pytest.raises(ValueError, match=r"with `plays`, pass .* play_states=fj.simulate\(fj.PlayOperators\(plays\)"):
        fj.LocalModel.from_data(train, plays=[1e-6])
    model = fj.LocalModel(regressors, points + np.arange(5.0)[:, None], forces, neighbours=2)
    with pytest.raises(ValueError, match=r"`query` must have shape \(..., 2\)"):
        model.predict(np.zeros(3))
    with pytest.raises(ValueError, match="`targets` must have shape"):
        model.predict(np.zeros(2), np.zeros(4))
    with pytest.raises(ValueError, match="`neighbours` must be a positive integer or a non-empty sequence"):
        fj.identify_local_model(train, validation=record, neighbours=())
    with pytest.raises(ValueError, match="`delay`"):
        fj.identify_local_model(train, validation=record, delay=(1, 0))
    with pytest.raises(ValueError, match="`validation_burn_in`"):
        fj.identify_local_model(train, validation=record, validation_burn_in=T)
    with pytest.raises(ValueError, match="drift=True"):
        fj.identify_local_model(train, validation=record, output_embedding=1, drift=True)
    with pytest.raises(TypeError, match="`validation`"):
        fj.identify_local_model(train, validation=np.zeros(3))


# ----------------------------------------------------------------------------------------------------------------
# 5. acceptance (slow)
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_mixed_regime_within_twenty_times_the_noise_floor():
    """The recommended recipe (locally linear on the displacement, velocity and 20 play states, drift fitted)
    trained on the mixed regime's training part, chosen on its validation part: test NMSE <= 1.9 % (20 x the
    noise floor of 0.096 %)."""
    split, _, _ = fj.compare.load_split("tribometer:mixed")
    x = np.asarray(split.train.motion.samples().x)
    result = fj.identify_local_model(
        split.train, validation=split.until_validation_end, validation_burn_in=split.train_end,
        signals=("x", "v"), plays=np.max(np.abs(x - np.median(x))) * np.geomspace(0.01, 1.0, 20),
        embedding=(1, 2), delay=1, neighbours=(100, 300), kind="linear", rcond=1e-2, drift=True,
    )  # fmt: skip
    nmse, _, _ = fj.compare.score(result.model, split)
    assert nmse <= 1.9
