"""Fits to several records (`fj.fit(model, [record, ...])`): shared parameters, per-record nuisances (offset, drift,
initial state), padding that never leaks into the loss, and one-line errors for records that cannot go together."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

from helpers import lugre

DT = 1e-3
OFFSETS = (0.3, -0.2, 0.1)
DRIFTS = (0.2, 0.0, -0.1)
SHAPES = ((1e-3, 1.0, 1200), (2e-3, 2.0, 800), (5e-4, 1.5, 1500))  # amplitude [m], frequency [Hz], samples


def _truth() -> fj.LuGre:
    return lugre()


def _start() -> fj.LuGre:
    return lugre(Fc=0.7, Fs=1.2, vs=2e-3, sigma0=5e4, sigma1=200.0, sigma2=20.0)


def _records(drift: bool = False, noise: float = 0.005) -> list[fj.FrictionData]:
    truth = _truth()
    out = []
    for i, (amplitude, frequency, n) in enumerate(SHAPES):
        t = np.arange(n) * DT
        motion = fj.Motion.from_position(amplitude * np.sin(2 * np.pi * frequency * t + 0.7 * i), dt=DT)
        force = np.asarray(fj.simulate(truth, motion)) + OFFSETS[i] + (DRIFTS[i] * t if drift else 0.0)
        out.append(fj.FrictionData(motion, force + noise * np.random.default_rng(i).normal(size=n)))
    return out


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 345 s)
def test_padding_never_leaks_the_loss_is_the_mean_of_each_records_nmse():
    """Without nuisances the batch loss is exactly the mean of the single-record losses (each normalised by its own
    force spread): padding to the longest record changes nothing."""
    records = _records()
    model = _start()
    loss = fj.RecordsLoss(fj.SimulationLoss(), fj.Nuisances(offset=False, drift=False, initial_state=False))
    batch = fj.RecordBatch.from_records(records, requires=model.requires)
    assert batch.count == 3 and batch.length == max(n for *_, n in SHAPES)
    together = float(loss(model, loss.init_extra(model, batch), batch))
    alone = [float(fj.SimulationLoss()(model, None, record)) for record in records]
    np.testing.assert_allclose(together, np.mean(alone), rtol=1e-10)
    # and with a burn-in the scored samples of each record are the same as alone
    burned = fj.RecordsLoss(fj.SimulationLoss(burn_in=100), loss.nuisances)
    alone = [float(fj.SimulationLoss(burn_in=100)(model, None, record)) for record in records]
    np.testing.assert_allclose(float(burned(model, burned.init_extra(model, batch), batch)), np.mean(alone), rtol=1e-10)


@pytest.mark.slow  # 5-6 s: the fast tier stays within 5 minutes
def test_shared_parameters_and_each_records_offset_and_drift_are_recovered():
    records = _records(drift=True)
    solution = fj.fit(
        _start(),
        records,
        solver=fj.levenberg_marquardt(),
        steps=60,
        scaling=fj.ParameterScaling(),
        nuisances=fj.Nuisances(drift=True),
    )
    assert solution.success, solution.message
    fitted = fj.unwrap(solution.model)
    np.testing.assert_allclose(float(fitted.stribeck.Fc), 1.0, rtol=0.02)
    np.testing.assert_allclose(float(fitted.sigma2), 40.0, rtol=0.02)
    assert float(fitted.offset) == 0.0  # held: each record has its own offset
    nuisances = solution.records
    assert nuisances.names == ("record 0", "record 1", "record 2")
    np.testing.assert_allclose(nuisances.offset, OFFSETS, atol=0.01)
    np.testing.assert_allclose(nuisances.drift, DRIFTS, atol=0.02)
    assert np.all(nuisances.train_nmse < 0.1)  # [%]: the noise floor is ~1e-4 of the force variance
    assert "per record (3)" in solution.summary() and "drift" in solution.summary()
    # the model's own offset was held: the summary says so beside it (it read as fitted)
    assert "offset = 0 [N] (held; each record's offset below is added to it)" in solution.summary()
    assert [row["train_nmse_percent"] for row in nuisances.table()] == list(nuisances.train_nmse)  # both [%]
    # the drifts stay in the nuisances: the fitted model plus record 1's offset (its drift is 0) is that record
    alone = np.asarray(fj.simulate(solution.model, records[1].motion)) + nuisances.offset[1]
    assert fj.nmse(np.asarray(records[1].force), alone) < 0.1  # % (the noise floor is ~0.003 %)


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 345 s)
def test_initial_state_of_each_record_is_estimated():
    """Records cut from the middle of a motion start in a state the model's rest state is not: the per-record
    initial state lets the fit explain the first samples (a Dahl model: its state is the force itself)."""
    truth = fj.Dahl(sigma0=2e4, Fc=1.0, alpha=1.0)
    t = np.arange(3000) * DT
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 1.0 * t), dt=DT)
    full = fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion)))
    records = [full.slice(300, 1300), full.slice(1700, 3000)]  # each starts mid-loop, at a force far from 0
    start = fj.Dahl(sigma0=1e4, Fc=0.8, alpha=1.0)
    kwargs = dict(solver=fj.levenberg_marquardt(), steps=40, scaling=fj.ParameterScaling(), train=("sigma0", "Fc"))
    with_state = fj.fit(start, records, nuisances=fj.Nuisances(offset=False), **kwargs)
    without = fj.fit(start, records, nuisances=fj.Nuisances(offset=False, initial_state=False), **kwargs)
    assert with_state.train_loss < 1e-6 < without.train_loss
    initial = with_state.records.initial_state
    # a record's first sample has no increment (dx_0 = 0), so its first force is its initial state
    expected = [float(full.force[300]), float(full.force[1700])]
    np.testing.assert_allclose(np.asarray(initial.F).reshape(-1), expected, atol=2e-3)
    np.testing.assert_allclose(float(fj.unwrap(with_state.model).Fc), 1.0, rtol=1e-3)


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 319 s)
def test_gradients_of_the_records_loss_agree_with_finite_differences():
    records = _records(drift=True)
    model = fj.unwrap(_start())
    loss = fj.RecordsLoss(fj.SimulationLoss(), fj.Nuisances(drift=True))
    batch = fj.RecordBatch.from_records(records, requires=model.requires)
    loss = loss.bind(model, batch)
    extra = loss.init_extra(model, batch)

    def value(offset, rate, sigma2):
        m = eqx.tree_at(lambda m: m.sigma2, model, sigma2)
        e = eqx.tree_at(lambda e: (e.offset, e.rate), extra, (offset, rate))
        return loss(m, e, batch)

    args = (extra.offset, extra.rate + 0.1, jnp.asarray(25.0))
    grads = jax.grad(value, argnums=(0, 1, 2))(*args)
    for which in range(3):
        for index in range(np.size(args[which])):
            h = 1e-6
            up = [jnp.asarray(a, float) for a in args]
            down = [jnp.asarray(a, float) for a in args]
            up[which] = up[which].reshape(-1).at[index].add(h).reshape(np.shape(args[which]))
            down[which] = down[which].reshape(-1).at[index].add(-h).reshape(np.shape(args[which]))
            numeric = (float(value(*up)) - float(value(*down))) / (2 * h)
            analytic = float(np.asarray(grads[which]).reshape(-1)[index])
            np.testing.assert_allclose(analytic, numeric, rtol=1e-4, atol=1e-9)


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 345 s)
def test_one_step_and_multiple_shooting_losses_take_record_lists():
    records = _records()
    narx = fj.MLPNARX.init(fj.NARXRegressors(("v",), 1, 2), 4, key=jax.random.PRNGKey(0))
    batch = fj.RecordBatch.from_records(records, requires=narx.requires)
    one_step = fj.RecordsLoss(fj.OneStepLoss(), fj.Nuisances(offset=False, initial_state=False))
    together = float(one_step(narx, one_step.init_extra(narx, batch), batch))
    alone = [float(fj.OneStepLoss()(narx, None, record)) for record in records]
    np.testing.assert_allclose(together, np.mean(alone), rtol=1e-8)
    solution = fj.fit(_start(), records, loss=fj.MultipleShootingLoss(200), solver=fj.levenberg_marquardt(), steps=5)
    assert np.isfinite(solution.train_loss) and solution.records.offset.shape == (3,)


@pytest.mark.slow
def test_multistart_sweep_and_validation_records():
    records = _records()
    named = {"slow": records[0], "fast": records[1]}
    solution = fj.fit(_start(), named, validation=records[2:], steps=10, multistart=2, seed=0)
    assert solution.num_starts == 2 and np.isfinite(solution.val_loss)
    assert solution.records.names == ("slow", "fast")
    result = fj.sweep([_start(), _start()], records[:2], validation=records[2:], steps=5, learning_rate=[1e-2, 3e-3])
    assert result.train_loss.shape == (2,) and np.all(np.isfinite(result.val_loss))


def test_host_signals_are_the_samples_signals_in_numpy():
    """`Motion.host_signals` derives the missing signals as `Motion.samples` does (central differences, zero-order
    hold), in NumPy: what a batch of records is padded from."""
    rng = np.random.default_rng(3)
    v = rng.normal(size=57)
    for motion in (
        fj.Motion(x=np.cumsum(v) * 1e-4, dt=1e-3),
        fj.Motion(v=v, dt=1e-3),
        fj.Motion.from_velocity(v, 1e-3),
    ):
        requires = frozenset({"a"})
        host, traced = motion.host_signals(requires), motion.samples(requires)
        for ours, theirs in zip(host[:3], (traced.x, traced.v, traced.a), strict=True):
            assert isinstance(ours, np.ndarray)
            np.testing.assert_allclose(ours, np.asarray(theirs), rtol=1e-13, atol=1e-18)
        assert host[3] is None


@pytest.mark.slow  # fast tier trimmed (2026-11-27): a compile-count property; the fit itself is checked fast
def test_a_fit_to_several_records_compiles_a_few_programs_however_many_records():
    """Padding and stacking run on the host and every per-record step inside compiled programs: the first fit over
    five records of five lengths compiles the start (one run of every record), the solver's evaluation and the
    report, and maybe the model's own parameter ranges (at most 4 programs, not some per record); a second fit of
    the same shapes compiles none."""
    truth = _truth()
    records = []
    for i, n in enumerate((301, 407, 523, 611, 719)):  # lengths no other test uses: nothing compiled before
        motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * (1.0 + 0.3 * i) * np.arange(n) * DT), dt=DT)
        records.append(fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion)) + 0.1 * i))
    compiled = []

    def listen(name, duration, **_):
        if name == "/jax/core/compile/backend_compile_duration":
            compiled.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        kwargs = dict(solver=fj.levenberg_marquardt(), steps=3, progress=False)
        first = fj.fit(_start(), records, **kwargs)
        count = len(compiled)
        again = fj.fit(_start(), records, **kwargs)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert count <= 4, f"the first fit compiled {count} programs"
    assert len(compiled) == count, f"the second fit of the same shapes compiled {len(compiled) - count} programs"
    assert first.records is not None and first.records.offset.shape == (5,)
    np.testing.assert_allclose(first.train_loss, again.train_loss, rtol=1e-12)


@pytest.mark.parametrize(
    "loss",
    [
        pytest.param(fj.SimulationLoss(), id="simulation"),
        pytest.param(fj.MultipleShootingLoss(400), id="multiple-shooting", marks=pytest.mark.slow),  # the same check
    ],
)
def test_the_compressed_jacobian_of_several_records_takes_the_dense_one_s_steps(loss):
    """fricjax's Levenberg-Marquardt shares one tangent among the nuisances of different records (record i's
    residuals depend on its own offset, drift and state only); optimistix's differentiates every column. Both take
    the same iterates (the same algorithm), with the simulation loss and with multiple shooting (whose per-record
    segment states are nuisances too)."""
    import optimistix as optx

    records = _records(drift=True)
    kwargs = dict(nuisances=fj.Nuisances(drift=True), loss=loss, steps=3, scaling=fj.ParameterScaling())
    ours = fj.fit(_start(), records, solver=fj.levenberg_marquardt(), **kwargs)
    theirs = fj.fit(_start(), records, solver=optx.LevenbergMarquardt(1e-10, 1e-12), **kwargs)
    for a, b in zip(jax.tree_util.tree_leaves(ours.model), jax.tree_util.tree_leaves(theirs.model), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(ours.records.offset, theirs.records.offset, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(ours.records.drift, theirs.records.drift, rtol=1e-7, atol=1e-9)


def test_records_that_cannot_go_together_get_one_line_errors():
    records = _records()
    other = fj.FrictionData(fj.Motion.from_position(np.asarray(records[0].motion.x), dt=2e-3), records[0].force)
    with pytest.raises(ValueError, match=r"record 1 of `data` is sampled at dt = 0.002 s.*resample"):
        fj.fit(_start(), [records[0], other], steps=1)
    with pytest.raises(ValueError, match="empty list"):
        fj.fit(_start(), [], steps=1)
    with pytest.raises(TypeError, match="record 1 of `data` is a ndarray"):
        fj.fit(_start(), [records[0], np.zeros(3)], steps=1)
    with pytest.raises(ValueError, match="pass a list of records"):
        fj.fit(_start(), records[0], nuisances=fj.Nuisances(), steps=1)
    with pytest.raises(ValueError, match="needs a list of training records"):
        fj.fit(_start(), records[0], validation=records[1:], steps=1)
    loaded = fj.NormalLoad(fj.Coulomb(Fc=0.5), reference=100.0)
    with pytest.raises(ValueError, match="needs the normal load"):
        fj.fit(loaded, records, steps=1)
    with pytest.raises(TypeError, match="BoucWenLoss scores one record only"):
        fj.RecordsLoss(fj.boucwen.BoucWenLoss())
    constant = fj.FrictionData(records[0].motion, np.ones(records[0].length))
    with pytest.raises(ValueError, match="record 1 in `data` is constant"):
        fj.fit(_start(), [records[1], constant], steps=1)


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 345 s)
def test_initialise_recovers_the_offset_and_state_a_record_starts_in():
    """Test-time initialisation: on a record cut from the middle of a motion (its model state is not rest) with a
    force-cell offset, the window's least-squares fit finds both, and the free run from them matches the record;
    the mean-error offset from rest does not."""
    truth = _truth()
    t = np.arange(2000) * DT
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 1.0 * t), dt=DT)
    full = fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion)) + 0.4)
    record = full.slice(1100, 2000)  # starts while sliding back (z far from 0)
    window = record.slice(0, 90)
    start = fj.initialise(truth, window)
    np.testing.assert_allclose(start.offset, 0.4, atol=1e-3)
    predicted = np.asarray(fj.simulate(truth, record.motion, start.state0)) + start.offset
    np.testing.assert_allclose(predicted, np.asarray(record.force), atol=5e-3)
    rest = fj.initialise(truth, window, initial_state=False)  # today's offset: the mean error of a run from rest
    from_rest = np.asarray(fj.simulate(truth, record.motion)) + rest.offset
    assert np.max(np.abs(from_rest - np.asarray(record.force))) > 10 * np.max(np.abs(predicted - record.force))
    with pytest.raises(ValueError, match="at least 2 samples"):
        fj.initialise(truth, record.slice(0, 1))
    # a window without sliding (a pre-sliding branch) cannot tell the offset from the initial state: it says so
    small = fj.Motion.from_position(2e-6 * np.sin(2 * np.pi * 1.0 * t[:300]), dt=DT)
    presliding = fj.FrictionData(small, np.asarray(fj.simulate(truth, small)) + 0.4)
    with pytest.warns(UserWarning, match=r"\(LuGre, a window of 100 samples\).*poorly determined"):
        fj.initialise(truth, presliding.slice(0, 100))


class _Known(fj.AbstractInitialiser):
    """A user's initialiser (room for a state estimator): a state known from elsewhere, no offset."""

    state: fj.DahlState

    def __call__(self, model, window):
        return fj.Initialisation(0.0, self.state, float("nan"), 0)


@pytest.mark.slow  # 5-6 s: the fast tier stays within 5 minutes
def test_initialisers_are_objects_a_user_can_add_to():
    """`fj.initialise` takes an `fj.AbstractInitialiser`: `fj.WindowLeastSquares` (its default: the same numbers as
    its keyword arguments), `fj.AtRest` (rest, the window's mean error as the offset: exact for a record that starts
    at rest) or a user's own subclass."""
    model = fj.Dahl(sigma0=2e4, Fc=1.0, alpha=1.0)
    motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6, 600)), dt=1e-3)
    from_rest = fj.FrictionData(motion, np.asarray(fj.simulate(model, motion)) + 0.25)
    window = from_rest.slice(0, 60)
    default = fj.initialise(model, window, drift=True, max_steps=20)
    explicit = fj.initialise(model, window, initialiser=fj.WindowLeastSquares(drift=True, max_steps=20))
    assert (default.offset, default.drift, default.steps) == (explicit.offset, explicit.drift, explicit.steps)
    at_rest = fj.initialise(model, window, initialiser=fj.AtRest())
    np.testing.assert_allclose(at_rest.offset, 0.25, rtol=1e-12)
    assert float(at_rest.state0.F) == 0.0 and at_rest.window_nmse < 1e-20 and at_rest.steps == 0
    np.testing.assert_allclose(at_rest.predict(model, motion), np.asarray(from_rest.force), atol=1e-12)
    known = fj.initialise(model, window, initialiser=_Known(fj.DahlState(F=np.asarray(0.6))))
    assert float(known.state0.F) == 0.6 and known.offset == 0.0
    with pytest.raises(TypeError, match=r"fj.AbstractInitialiser \(fj.WindowLeastSquares\(\), fj.AtRest\(\)\)"):
        fj.initialise(model, window, initialiser="rest")
    with pytest.raises(TypeError, match="set them on it"):  # not silently dropped
        fj.initialise(model, window, drift=True, initialiser=fj.AtRest())
