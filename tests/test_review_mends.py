"""Mends from a new user's and an API prober's reading (2026-11-27): each a defect they hit, checked through the
public API and the command line."""

from __future__ import annotations

import json
import warnings
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
import pytest

import fricjax as fj

from helpers import coulomb_viscous_record

DT = 1e-3


def _record(samples: int = 600) -> fj.FrictionData:
    return coulomb_viscous_record(samples, frequency=1.5)


def test_the_documented_noise_floor_snippet_gives_the_floor():
    """docs/exercises/compare.md: `reference_scores([split.test_record()])` on built-in data is the noise floor
    (the split carries the sensor's noise-free reading); it printed `{}`."""
    split, _, _ = fj.compare.load_split("tribometer:mixed")
    floor = fj.compare.reference_scores([split.test_record()])
    assert floor["test part"].nmse == pytest.approx(0.0958, abs=5e-4)


def test_emps_table_refuses_the_options_it_would_ignore(tmp_path, capsys):
    code = fj.main(["compare", "--data", "emps", "--models", "lugre", "--steps", "3", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "--models" in err and "--steps" in err and len(err.strip().splitlines()) == 1


def test_validation_records_without_test_records_say_so(tmp_path, capsys):
    argv = ["compare", "--data", "tribometer:mixed", "--validation", "tribometer:mixed:seed=1"]
    assert fj.main([*argv, "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--validation records: name the records to test on with --test" in err and "several" not in err


def test_parameter_units_follow_the_module_that_owns_the_field():
    """A network's bias `w0` has no unit (it was printed in metres, the unit of LuGre with backlash's `w0`)."""
    regressors = fj.NARXRegressors(("x", "v"), 0, 2)
    network = fj.GSNN.init(regressors, units=2, key=jax.random.PRNGKey(0))
    assert [line for line in str(network).splitlines() if line.strip().startswith("w0")][0].endswith("]")
    assert "w0 = 0 [m]" in str(fj.LuGreBacklash(fj.ExponentialStribeck(1.0, 1.4, 1e-3), 1e5, 300.0, 10.0, gap=1e-4))
    element = fj.MaxwellSlip.nlr(k=[2e4], thresholds=[1e-4])
    text = str(fj.HystereticOscillator(m=2.0, c=10.0, k=5e4, element=element))
    assert "m = 2 [kg]" in text and "c = 10 [N s/m]" in text and "element.thresholds = [0.0001] [m]" in text


def test_a_zero_sample_time_is_named_before_it_divides():
    for build in (fj.Motion.from_position, fj.Motion.from_velocity):
        with pytest.raises(ValueError, match="`dt` must be a positive, finite sample time"):
            build(np.linspace(0.0, 1e-3, 20), dt=0.0)


def test_a_force_column_or_a_batch_of_forces_is_refused_at_construction():
    motion = fj.Motion.from_position(np.linspace(0.0, 1e-3, 30), dt=DT)
    with pytest.raises(ValueError, match=r"shape \(30, 1\).*flatten the column"):
        fj.FrictionData(motion, np.zeros((30, 1)))
    with pytest.raises(ValueError, match=r"shape \(2, 30\).*one force sample per motion sample"):
        fj.FrictionData(motion, np.zeros((2, 30)))


def test_a_wrong_initial_state_is_named():
    model = fj.LuGre(fj.ExponentialStribeck(1.0, 1.4, 1e-3), 1e5, 300.0, 10.0)
    motion = fj.Motion.from_position(np.linspace(0.0, 1e-4, 10), dt=DT)
    with pytest.raises(ValueError, match="`state0` must be shaped as LuGre's `init_state\\(\\)`"):
        fj.simulate(model, motion, np.zeros(3))
    assert fj.simulate(model, motion, model.init_state()).shape == (10,)


@pytest.mark.parametrize("family", [fj.GMS, fj.MaxwellSlip])
def test_initial_guess_of_element_models_on_a_record_shorter_than_its_grid(family):
    """50 samples give fewer rows than the regression's candidate thresholds (an IndexError before)."""
    motion = fj.Motion.from_position(1e-5 * np.sin(np.arange(50) * 0.2), dt=DT)
    truth = fj.MaxwellSlip.nlr(k=[1e5, 5e4], thresholds=[2e-6, 5e-6])
    start = fj.initial_guess(family, fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion))))
    assert np.all(np.isfinite(np.asarray(fj.simulate(start, motion))))


def test_sweep_returns_each_configuration_at_its_best_never_worse_than_its_start():
    """A learning rate too high ends worse than it began: the sweep returned that last iterate."""
    data = _record()
    start = fj.CoulombViscous(0.95, 29.0, smoothing=fj.Smooth(1e-4))
    start_loss = float(fj.SimulationLoss()(start, None, data))
    result = fj.sweep([start, start], data, steps=40, learning_rate=[0.5, 2.0], checks=10)
    history = np.asarray(result.history["train_loss"])
    assert np.all(result.train_loss <= start_loss * (1 + 1e-12))
    np.testing.assert_allclose(result.train_loss, np.minimum(history.min(axis=0), start_loss), rtol=1e-9)
    with pytest.raises(ValueError, match=r"one number or one per model \(2\)"):
        fj.sweep([start, start], data, steps=2, learning_rate=[0.1, 0.2, 0.3], optimiser=optax.sgd)


def test_a_non_finite_force_is_named_by_its_sample():
    motion = fj.Motion.from_position(np.linspace(0.0, 1e-3, 10), dt=DT)
    force = np.zeros(10)
    force[7] = np.nan
    with pytest.raises(ValueError, match=r"`force` contains NaN or inf \(first at flat index 7\)"):
        fj.FrictionData(motion, force)


def test_a_model_class_passed_for_an_instance_is_named_with_the_fix():
    motion = fj.Motion.from_position(np.linspace(0.0, 1e-3, 10), dt=DT)
    with pytest.raises(TypeError, match=r"got the class LuGre; pass an instance .*fj.initial_guess\(fj.LuGre, data\)"):
        fj.simulate(fj.LuGre, motion)
    with pytest.raises(TypeError, match="got the class CoulombViscous"):
        fj.fit(fj.CoulombViscous, fj.FrictionData(motion, np.zeros(10)))


def test_carrying_a_drift_that_was_not_fitted_is_refused(tmp_path, capsys):
    several = ["compare", "--data", "tribometer:mixed", "tribometer:sliding", "--test", "tribometer:mixed:seed=1"]
    assert fj.main([*several, "--test-drift", "carry", "--out", str(tmp_path / "a")]) == 2
    assert "with several --data records each keeps its own" in capsys.readouterr().err
    one = ["compare", "--data", "tribometer:mixed", "--drift", "none", "--test-drift", "carry"]
    assert fj.main([*one, "--out", str(tmp_path / "b")]) == 2
    assert "--drift none fits none" in capsys.readouterr().err


def test_keeping_the_files_velocity_needs_one(tmp_path):
    t = np.arange(200) * DT
    path = tmp_path / "r.csv"
    np.savetxt(path, np.c_[t, 1e-3 * np.sin(t), np.cos(t)], delimiter=",", header="t,x,force", comments="")
    with pytest.raises(fj.RecordError, match=r"velocity='file' \(--velocity file\) .* has no velocity column"):
        fj.load_record(path, velocity="file")
    assert fj.load_record(path).length == 200


def test_element_models_refuse_zero_elements():
    with pytest.raises(ValueError, match="at least one element"):
        fj.MaxwellSlip.nlr(k=[], thresholds=[])
    with pytest.raises(ValueError, match="at least one element"):
        fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.4, vs=1e-3), k=[], alpha=[], C=1.0)


def test_screening_that_keeps_every_start_is_refused():
    """`keep >= count` screened nothing and said nothing; `keep=None` fits every start."""
    with pytest.raises(ValueError, match="`keep` \\(4\\) must be below `count` \\(4\\)"):
        fj.MultiStart(4, keep=4)
    assert fj.MultiStart(4).keep is None


def test_the_table_flags_a_row_with_notes_and_lists_them_below():
    scores = {"a.csv": fj.compare.Score(1.0, 0.5, 0.1), "b.csv": fj.compare.Score(2.0, 0.7, -0.2)}
    flagged = fj.compare.ModelScore(
        "lugre", "LuGre", 1.0, 0.5, 3.0, 7, "successful", None, np.zeros(1), tests=scores, notes=("Fs < Fc", "x")
    )
    clean = fj.compare.ModelScore("gms", "GMS", 0.5, 0.4, 3.0, 14, "successful", None, np.zeros(1), tests=scores)
    lines = fj.compare.format_table([flagged, clean]).splitlines()
    assert "MAX/std 1" in lines[0]  # the first test record's, as the NMSE the rows are sorted by
    assert lines[1].startswith("  GMS") and lines[1].endswith("successful")
    assert lines[2].startswith("  LuGre") and lines[2].endswith("successful (note 1)")
    assert lines[-1] == "note 1, LuGre: Fs < Fc; x"


@pytest.mark.slow  # a whole compare run (~18 s)
def test_a_fit_worse_than_a_constant_force_is_noted_in_the_table(tmp_path, capsys):
    """A static law on a pre-sliding record (NMSE above 100 %) was printed without a word beside its result."""
    argv = ["compare", "--data", "tribometer:presliding:duration=1", "--models", "stribeck", "--steps", "3"]
    assert fj.main([*argv, "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "(note 1)" in out and "note 1, Stribeck (static): NMSE above 100 % (" in out
    assert "worse than a constant force" in out


def test_per_record_offsets_print_in_the_records_force_unit():
    """compare printed each training record's offset in N for records read in kip."""
    nuisances = fj.RecordNuisances(("a.csv",), np.array([2 * 4448.2216]), np.array([4448.2216]), None, np.ones(1))
    (line,) = nuisances.lines("kip", 4448.2216)
    assert line == "a.csv: train NMSE 1 %, offset 2 kip, drift 1 kip/s"
    assert nuisances.lines()[0].endswith("offset 8896 N, drift 4448 N/s")


def _csv(path, header: str, *columns) -> str:
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="")
    return str(path)


def _damper_like(path, scale: float = 1.0, samples: int = 800, units: bool = True) -> str:
    """A record in the damper's column names: inches, kip, and an actuator force in pounds (a normal-load candidate);
    `units=False`: the same without units in its names (read as SI, and checked for a unit mistake)."""
    t = np.arange(samples) * DT
    x = 0.02 * np.sin(2 * np.pi * 2.0 * t)
    force = scale * (0.5 * np.tanh(np.gradient(x, DT) / 0.01) + 0.01 * np.random.default_rng(0).normal(size=samples))
    header = "time_s,displacement_in,friction_force_kip,actuator_force1_lb,actuator_pos1_in"
    if not units:
        header = "t,x,force,actuator_force1,actuator_pos1"
    return _csv(path, header, t, x, force, np.full(samples, 3000.0), x)


def test_a_length_column_named_as_the_normal_load_is_refused(tmp_path):
    """`actuator_pos1_in` was read as a force in the friction force's unit (0.655 in became 2914 N)."""
    path = _damper_like(tmp_path / "r.csv")
    with pytest.raises(fj.RecordError, match="'actuator_pos1_in' is named in a displacement unit \\('in'\\)"):
        fj.load_record(path, normal_force_column="actuator_pos1_in")
    data = fj.load_record(path, normal_force_column="actuator_force1_lb")
    np.testing.assert_allclose(data.motion.normal_force, 3000.0 * 4.4482216152605)


def test_a_sample_time_argument_that_contradicts_the_time_column_is_warned_of(tmp_path):
    path = _damper_like(tmp_path / "r.csv")
    with pytest.warns(UserWarning, match="dt = 1 s \\(the argument, used\\) disagrees with 'time_s'"):
        data = fj.load_record(path, dt=1.0)
    assert float(data.motion.dt) == 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        fj.load_record(path, dt=DT * (1 + 1e-6))  # within rounding: no warning


def test_two_training_records_in_units_10x_apart_are_refused_naming_both(tmp_path, capsys):
    """Against a median that includes the record itself, two records 10x apart read 0.18x / 1.8x and passed."""
    good, bad = _damper_like(tmp_path / "good.csv", units=False), _damper_like(tmp_path / "bad.csv", 10.0, units=False)
    argv = ["compare", "--data", good, bad, "--test", good, "--models", "stribeck", "--no-progress"]
    assert fj.main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "force spread is" in err and "good.csv" in err and "bad.csv" in err and "check the units of both" in err


def test_of_three_records_the_one_in_other_units_is_named(tmp_path, capsys):
    """Of spreads 1 : 1 : 100, the first record's others' median (50.5) named the first, a sound record."""
    paths = [_damper_like(tmp_path / f"r{i}.csv", scale, units=False) for i, scale in enumerate((1.0, 1.0, 100.0))]
    argv = ["compare", "--data", *paths, "--test", paths[0], "--models", "stribeck", "--no-progress"]
    assert fj.main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "r2.csv: its force spread is 100x the other records' median" in err, err


def test_several_records_train_a_path_the_fit_holds_per_record():
    """`train=['Fc', 'offset']` with several records was refused as 'in both train and freeze' (the offsets a fit
    to several records estimates per record are frozen in the shared model, not by the user)."""
    records = [_record(300), _record(400)]
    start = fj.CoulombViscous(0.5, 10.0, smoothing=fj.Smooth(1e-4))
    solution = fj.fit(start, records, train=["Fc", "offset"], steps=5)
    assert float(fj.unwrap(solution.model).Fc) != pytest.approx(0.5)


def test_a_folder_given_as_a_record_is_named_with_the_glob(tmp_path, capsys):
    assert fj.main(["compare", "--data", str(tmp_path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    assert "a folder; name its records, e.g. with a quoted glob" in capsys.readouterr().err


@pytest.mark.slow  # a whole compare run (~18 s)
def test_compare_dedupes_models_and_warns_of_unused_loads_and_of_testing_on_training_data(tmp_path, capsys):
    """`--models lugre lugre` fitted twice and then failed to write its files; a test record that is a training
    record, and unused columns that hold the damper's normal load, passed without a word."""
    path = _damper_like(tmp_path / "r.csv")
    argv = ["compare", "--data", path, "--test", path, "--models", "stribeck", "STRIBECK", "--steps", "3"]
    assert fj.main([*argv, "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    table = out[out.index("\nmodel ") : out.index("\nresult:")]  # the table's rows: one per model fitted
    assert "models: stribeck\n" in out and table.count("Stribeck (static)  ") == 1
    assert "a training record too; its test score is not held out" in out
    assert "columns 'actuator_force1_lb' are not used; if they hold the normal load, name them" in out


def test_load_split_takes_the_record_options_its_errors_name(tmp_path):
    t = np.arange(800) * DT
    x = 1e-3 * np.sin(2 * np.pi * 2.0 * t)
    path = _csv(tmp_path / "r.csv", "t,x,v,force", t, x, 0.01 * np.gradient(x, DT), np.tanh(np.gradient(x, DT) / 1e-3))
    with pytest.raises(fj.compare.CompareError, match="velocity='derive'"):
        fj.compare.load_split(path)
    split, card, truth = fj.compare.load_split(path, velocity="derive")
    assert split.full.length == 800 and truth is None


def test_wrapped_models_name_the_field_and_the_record_they_miss():
    motion = fj.Motion.from_position(1e-3 * np.sin(np.arange(500) * DT), dt=DT)
    loaded = fj.Motion(x=motion.x, v=motion.v, dt=DT, normal_force=np.full(500, 100.0))
    model = fj.NormalLoad(fj.CoulombViscous(1.0, 30.0, smoothing=fj.Smooth(1e-4)), reference=100.0)
    with pytest.raises(TypeError, match="got the class CoulombViscous; pass an instance"):
        fj.NormalLoad(fj.CoulombViscous, reference=100.0)
    data = fj.FrictionData(loaded, np.asarray(fj.simulate(model, loaded)))
    with pytest.raises(ValueError, match="The wrapped model's field: 'model.Fc'"):
        fj.fit(model, data, freeze="Fc", steps=1)
    with pytest.raises(ValueError, match="record 1 of `data`: NormalLoad needs the normal load"):
        fj.fit(model, [data, fj.FrictionData(motion, data.force)], steps=1)


class _ScalarForce(fj.AbstractFrictionModel):
    """A researcher's model (tests below): `Fc tanh(v / 1e-4) + C v`, its force reshaped as `shape`."""

    Fc: jax.Array
    C: jax.Array
    shape: tuple = eqx.field(static=True, default=())
    reads_a: bool = eqx.field(static=True, default=False)
    requires: ClassVar[frozenset[str]] = frozenset({"v"})

    def init_state(self):
        return jnp.zeros(())

    def step(self, state, sample):
        force = self.Fc * jnp.tanh(sample.v / 1e-4) + self.C * sample.v
        if self.reads_a:
            force = force + 0.1 * sample.a
        return state, jnp.reshape(force, self.shape)


def test_a_custom_step_returning_a_force_of_shape_1_is_refused_with_the_fix():
    """It broadcast against the (T,) force: Adam drove Fc to 1e-5 silently; LM failed in a concatenate."""
    data = _record()
    bad = _ScalarForce(jnp.asarray(0.5), jnp.asarray(0.0), shape=(1,))
    assert fj.simulate(bad, data.motion).shape == (data.length, 1)  # simulate runs any output (diagnostics)
    for call in (
        lambda: fj.fit(bad, data, steps=2, solver=optax.adam(1e-1)),
        lambda: fj.fit(bad, [data, data], steps=2),
        lambda: fj.fit(bad, data, steps=2, solver=fj.levenberg_marquardt()),
    ):
        with pytest.raises(ValueError, match="_ScalarForce.step returned a force of shape \\(1,\\)"):
            call()


def test_a_signal_read_but_not_required_is_named():
    model = _ScalarForce(jnp.asarray(1.0), jnp.asarray(0.0), reads_a=True)
    with pytest.raises(TypeError, match="step failed on a sample without a, .*add it there"):
        fj.simulate(model, _record().motion)


def test_custom_fields_print_their_declared_units_not_fricjax_symbols():
    """A user's `C` (a damping) printed GMS's unit; undeclared fields now print bare, `units` is the hook."""
    model = _ScalarForce(jnp.asarray(1.0), jnp.asarray(30.0))
    assert str(model).splitlines()[1:] == ["  Fc = 1", "  C = 30"]

    class Declared(_ScalarForce):
        units: ClassVar[dict[str, str]] = {"Fc": "N", "C": "N s/m"}

    assert "C = 30 [N s/m]" in str(Declared(jnp.asarray(1.0), jnp.asarray(30.0)))
    assert "C = 20 [N/s]" in str(fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.4, vs=1e-3), k=[1e4], alpha=[1.0], C=20.0))


def test_continuation_refuses_a_rising_width_and_a_model_without_smoothing():
    with pytest.raises(ValueError, match="`eps_start` \\(1e-06\\) must be at least `eps_end` \\(0.001\\)"):
        fj.Continuation(1e-6, 1e-3, 3)
    model = _ScalarForce(jnp.asarray(0.5), jnp.asarray(0.0))
    with pytest.raises(ValueError, match="_ScalarForce has no smoothing field"):
        fj.fit(model, _record(), steps=2, continuation=fj.Continuation(1e-3, 1e-5, 2))


def test_sweep_names_the_field_that_differs_and_asks_for_an_optimiser_factory():
    data = _record()
    exact, smooth = fj.CoulombViscous(1.0, 30.0), fj.CoulombViscous(1.0, 30.0, smoothing=fj.Smooth(1e-4))
    with pytest.raises(ValueError, match="at model.smoothing \\(Exact against Smooth\\)"):
        fj.sweep([exact, smooth], data, steps=2)
    with pytest.raises(TypeError, match="an optimiser already built"):
        fj.sweep([smooth, smooth], data, steps=2, optimiser=optax.adam(1e-2))


class _Lagged(fj.AbstractFrictionModel):
    """A model with a static integer (as the NARX regressors' lags): `Fc tanh(v / 1e-4)`, `lags` unused."""

    Fc: jax.Array
    lags: int = eqx.field(static=True, default=1)
    requires: ClassVar[frozenset[str]] = frozenset({"v"})

    def init_state(self):
        return jnp.zeros(())

    def step(self, state, sample):
        return state, self.Fc * jnp.tanh(sample.v / 1e-4)


def test_sweep_names_a_static_number_that_differs():
    """Static Python numbers were taken for array values that may differ: models differing only in their lags got
    the structure message with no place named."""
    with pytest.raises(ValueError, match="at model.lags \\(1 against 2\\)"):
        fj.sweep([_Lagged(jnp.asarray(1.0)), _Lagged(jnp.asarray(1.0), lags=2)], _record(), steps=2)


def test_a_model_file_whose_class_moved_module_says_so(tmp_path):
    model = _ScalarForce(jnp.asarray(1.0), jnp.asarray(0.0))
    path = tmp_path / "m.eqx"
    fj.save_model(path, model)
    moved = type("_ScalarForce", (_ScalarForce,), {"__module__": "mymodels", "__qualname__": "_ScalarForce"})
    with pytest.raises(ValueError, match="`classes` has mymodels._ScalarForce, from another module"):
        fj.load_model(path, classes=(moved,))
    assert fj.load_model(path, classes=(_ScalarForce,)) == model


def test_an_unknown_required_signal_is_refused():
    class Misspelt(_ScalarForce):
        requires: ClassVar[frozenset[str]] = frozenset({"velocity"})

    with pytest.raises(ValueError, match="requires names 'velocity', not a signal"):
        fj.simulate(Misspelt(jnp.asarray(1.0), jnp.asarray(0.0)), _record().motion)


def test_selections_that_would_be_silently_ignored_are_refused():
    """`patience` without validation data, a path in both `train` and `freeze`, and a smoothing width in `train`
    used to pass (patience never fired; the last said only "nothing to train")."""
    data = _record(300)
    start = fj.CoulombViscous(0.5, 10.0, smoothing=fj.Smooth(1e-4))
    with pytest.raises(ValueError, match="`patience`.*no `validation`"):
        fj.fit(start, data, steps=5, patience=3)
    with pytest.raises(ValueError, match="'Fc' is in both `train` and `freeze`"):
        fj.fit(start, data, steps=5, train="Fc", freeze="Fc")
    with pytest.raises(ValueError, match="'smoothing.eps' in `train`.*Continuation"):
        fj.fit(start, data, steps=5, train=["Fc", "smoothing.eps"])
    narrowed = fj.fit(start, data, steps=5, train=lambda m: (m.Fc, m.Fv), freeze="Fv")  # freeze narrows train
    fitted = fj.unwrap(narrowed.model)
    assert float(fitted.Fv) == pytest.approx(10.0) and float(fitted.Fc) != pytest.approx(0.5)


def test_the_history_records_the_models_own_width_without_continuation():
    data = _record(300)
    start = fj.CoulombViscous(0.5, 10.0, smoothing=fj.Smooth(2e-4))
    history = fj.fit(start, data, steps=10, eval_every=5).history
    np.testing.assert_allclose(history["eps"], 2e-4)
    exact_history = fj.fit(fj.exact(start), data, steps=10, eval_every=5).history
    assert np.isnan(exact_history["eps"]).all()


@pytest.mark.slow  # two whole compare runs (~40 s): the fast tier stays under 5 minutes
def test_every_test_record_gets_its_figures_and_a_short_label(tmp_path, capsys):
    """With several --test records compare drew only the first one, and labelled the records by their full
    paths; now each record has its error and loop figures, `test_records.png` shows each model on each record,
    and the table's legend names the records by the shortest label that keeps them apart."""
    for folder, seed in (("a", 1), ("b", 2)):
        data = fj.make_tribometer("mixed", seed=seed, duration=1.0)
        (tmp_path / folder).mkdir()
        t = np.arange(data.full.length) * float(data.full.motion.dt)
        np.savez(
            tmp_path / folder / "run.npz", t=t, x=np.asarray(data.full.motion.x), force=np.asarray(data.full.force)
        )
    out = tmp_path / "o"
    argv = ["compare", "--data", "tribometer:mixed:duration=1", "--models", "stribeck", "--steps", "1", "--test"]
    argv += [str(tmp_path / "a" / "run.npz"), str(tmp_path / "b" / "run.npz"), "--out", str(out), "--no-progress"]
    assert fj.main(argv) == 0
    printed = capsys.readouterr().out
    assert "test records: 1 = a/run.npz; 2 = b/run.npz" in printed, printed
    for name in ("test_errors", "hysteresis_loops"):
        for suffix in ("", "_2"):
            assert (out / f"{name}{suffix}.png").stat().st_size > 10_000, name + suffix
    assert (out / "test_records.png").stat().st_size > 10_000
    assert "test_records.png" in printed
    report = json.loads((out / "report.json").read_text())
    assert report["figures"] == [
        "test_errors.png", "hysteresis_loops.png", "test_errors_2.png", "hysteresis_loops_2.png", "test_records.png"
    ]  # fmt: skip
    # a later run with one test record into the same folder removes the figures it no longer draws (those the
    # earlier report listed), and leaves a file of the user's with a figure-like name alone
    (out / "test_errors_9.png").write_bytes(b"mine")
    argv = argv[: argv.index("--test") + 1] + [str(tmp_path / "a" / "run.npz"), "--out", str(out), "--no-progress"]
    assert fj.main(argv) == 0
    for name in ("test_errors_2.png", "hysteresis_loops_2.png", "test_records.png"):
        assert not (out / name).exists(), name
    assert (out / "test_errors.png").exists() and (out / "test_errors_9.png").read_bytes() == b"mine"
    assert json.loads((out / "report.json").read_text())["figures"] == ["test_errors.png", "hysteresis_loops.png"]
    assert fj.compare.short_labels(["run.csv", "old/run.csv"]) == ["run.csv", "old/run.csv"]  # never two alike


def test_a_table_passed_as_one_motion_signal_is_named_with_the_fix():
    motion = fj.Motion.from_position(np.zeros((100, 2)), dt=DT)
    with pytest.raises(ValueError, match="looks like a table's columns.*table\\[:, 0\\]"):
        fj.FrictionData(motion, np.zeros(100))


class _WithActivation(fj.AbstractFrictionModel):
    """A model holding a function (as an MLP holds its activation): `Fc * activation(v / 1e-4)`."""

    Fc: jax.Array
    activation: Any = jax.nn.tanh
    requires: ClassVar[frozenset[str]] = frozenset({"v"})

    def init_state(self):
        return jnp.zeros(())

    def step(self, state, sample):
        return state, self.Fc * self.activation(sample.v / 1e-4)


@pytest.mark.slow  # 5-6 s: the fast tier stays within 5 minutes
def test_models_holding_functions_pass_the_shape_checks():
    """The force-shape and state checks traced the model with `jax.eval_shape`, which takes no function leaves:
    every fit of an MLP-NARX failed before its first step (the CI of 2026-11-28 caught it in the slow tier); so
    did optimistix solvers' start and sweeps (their configurations' functions were stacked as arrays)."""
    data = _record(300)
    model = _WithActivation(jnp.asarray(0.5))
    solution = fj.fit(model, data, steps=3)
    assert np.isfinite(solution.train_loss)
    force = fj.simulate(model, data.motion, state0=model.init_state())
    assert force.shape == (300,)
    with pytest.raises(ValueError, match="`state0` must be shaped as _WithActivation"):
        fj.simulate(model, data.motion, state0=(jnp.zeros(()), jnp.zeros(())))
    optimistix = fj.fit(model, data, solver=optx.LevenbergMarquardt(1e-8, 1e-8), steps=5)  # its init traced `args`
    assert np.isfinite(optimistix.train_loss)
    swept = fj.sweep([model, _WithActivation(jnp.asarray(0.7))], data, steps=5)  # functions shared, not stacked
    assert swept.train_loss.shape == (2,) and np.isfinite(swept.train_loss).all()
    with pytest.raises(ValueError, match="holds another .* at .activation than model 0"):
        fj.stack_models([model, _WithActivation(jnp.asarray(0.7), activation=jax.nn.relu)])
