"""Bad input found by an API prober's reading (2026-11-28): each case raised an obscure error, returned NaN, or
counted a record that scores nothing as a perfect fit; now a named error at the entry point."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import fricjax as fj

from helpers import coulomb_viscous_record

jax.config.update("jax_enable_x64", True)

DT = 1e-3


def _record(samples: int = 600) -> fj.FrictionData:
    return coulomb_viscous_record(samples, frequency=3.0)


def _start() -> fj.CoulombViscous:
    return fj.CoulombViscous(0.5, 10.0, smoothing=fj.Smooth(1e-4))


def test_a_burn_in_that_covers_a_record_is_refused():
    """A record shorter than the loss's burn-in scored nothing: in a fit to several records it counted as NMSE 0
    (half the loss), on one record the fit 'diverged' and pointed at the learning rate, and sweeps returned NaN."""
    data = _record()
    with pytest.raises(ValueError, match=r"burn_in .* all of record 1 of `data` \(300 samples\)"):
        fj.fit(_start(), [data, data.slice(0, 300)], loss=fj.SimulationLoss(burn_in=400), steps=2)
    with pytest.raises(ValueError, match=r"burn_in .* all of `data` \(600 samples\)"):
        fj.fit(_start(), data, loss=fj.SimulationLoss(burn_in=600), steps=2)
    with pytest.raises(ValueError, match=r"sweep: the loss's burn_in"):
        fj.sweep([_start(), _start()], data, loss=fj.SimulationLoss(burn_in=700), steps=2)
    with pytest.raises(ValueError, match=r"sweep: `validation_burn_in` leaves 600 samples unscored"):
        fj.sweep([_start(), _start()], data, validation=data, validation_burn_in=600, steps=2)
    with pytest.raises(ValueError, match=r"sweep: the loss's burn_in .* all of record 0 of `validation`"):
        fj.sweep(
            [_start(), _start()], [data, data], loss=fj.SimulationLoss(burn_in=400), validation=[data.slice(0, 300)]
        )
    fitted = fj.fit(_start(), [data, data.slice(0, 500)], loss=fj.SimulationLoss(burn_in=400), steps=2)
    assert np.all(np.asarray(fitted.records.train_nmse) > 0)  # both records scored


def test_sweep_checks_its_records_and_models_as_fit_does():
    data = _record()
    with pytest.raises(TypeError, match=r"sweep: `data` must be a FrictionData .*wrap motion and force"):
        fj.sweep([_start(), _start()], data.motion, steps=2)
    with pytest.raises(ValueError, match=r"sweep: the measured force of `data` is constant"):
        fj.sweep([_start(), _start()], fj.FrictionData(data.motion, np.ones(data.length)), steps=2)
    with pytest.raises(ValueError, match=r"sweep: `models` must be a list .* pass a list, e.g. \[model\]"):
        fj.sweep(fj.CoulombViscous(Fc=[1.0, 1.2], Fv=[30.0, 31.0]), data, steps=2)


@pytest.mark.parametrize(
    "build",
    [
        lambda: fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 1e-3), 1e5, 300.0, 0.4, smoothing=1e-4),
        lambda: fj.CoulombViscous(1.0, 2.0, smoothing=1e-4),
        lambda: fj.MaxwellSlip.nlr(k=[1e5], thresholds=[1e-6], smoothing=0.01),
        lambda: fj.GMS(fj.ExponentialStribeck(1.0, 1.5, 1e-3), [1e4], [1.0], 20.0, smoothing=fj.Smooth),
        lambda: fj.with_smoothing(fj.CoulombViscous(1.0, 2.0), 1e-4),
    ],
)
def test_a_smoothing_that_is_not_a_strategy_is_refused_at_construction(build):
    """`smoothing=1e-4` for `smoothing=fj.Smooth(1e-4)` failed only in `simulate`, with an AttributeError."""
    with pytest.raises(TypeError, match=r"`smoothing` must be fj.Smooth\(eps\) or fj.Exact\(\)"):
        build()


def test_save_model_warns_of_what_load_model_would_refuse(tmp_path):
    """A parameter made NaN (a diverged update, an edit) was written silently, and the file then failed to load as
    'damaged or edited'; now the save warns, writes the file all the same, and the load names that case too."""
    path = tmp_path / "model.eqx"
    broken = eqx.tree_at(lambda m: m.Fv, fj.CoulombViscous(1.0, 2.0), jnp.asarray(np.nan))
    with pytest.warns(UserWarning, match=r"save_model: .* `Fv` holds a non-finite value .* load_model will refuse"):
        fj.save_model(path, broken)
    with pytest.raises(ValueError, match=r"or was saved from a model that held it"):
        fj.load_model(path)
    fj.save_model(path, fj.CoulombViscous(1.0, 2.0))
    assert float(fj.load_model(path).Fv) == 2.0


def test_a_start_whose_loss_is_not_finite_says_so():
    """A start with a non-finite loss was reported as 'became non-finite; the last good parameters were kept', and
    no good parameters ever existed."""
    fitted = fj.fit(fj.CoulombViscous(1e300, 1e305, smoothing=fj.Smooth(1e-4)), _record(), steps=3)
    assert fitted.code == "diverged"
    assert "not finite (inf) at the start already" in fitted.message
    assert "last good" not in fitted.message


class _IntegerGain(fj.AbstractFrictionModel):
    gain: jax.Array

    def init_state(self) -> tuple[()]:
        return ()

    def step(self, state: tuple[()], sample: fj.MotionSample) -> tuple[tuple[()], jax.Array]:
        return state, self.gain * sample.v


def test_a_model_of_integer_arrays_is_told_why_nothing_trains():
    with pytest.raises(ValueError, match=r"integer arrays are never trained \(model.gain\): build them from floats"):
        fj.fit(_IntegerGain(jnp.asarray(1)), _record(), steps=2)


def test_a_float32_record_beside_a_float64_one_is_not_a_sample_time_mismatch():
    """The 1e-9 tolerance on equal sample times was below float32 rounding: the same dt was refused as two."""
    dt = 1 / 299.5
    x = 1e-3 * np.sin(2 * np.pi * 3.0 * np.arange(600) * dt)
    wide = fj.FrictionData(fj.Motion.from_position(x, dt), np.sin(np.arange(600) * 0.05))
    narrow = fj.FrictionData(fj.Motion.from_position(x.astype(np.float32), np.float32(dt)), wide.force)
    assert fj.fit(_start(), [wide, narrow], steps=1).model is not None
    other = fj.FrictionData(fj.Motion.from_position(x, 1 / 299.0), wide.force)
    with pytest.raises(ValueError, match="need one sample time"):
        fj.fit(_start(), [wide, other], steps=1)


def test_simulate_checks_unroll_and_measured():
    """`unroll=0` compiled the whole record into one program (minutes); `measured` of shape (T, 1) failed with a
    broadcasting error, a list of numbers was read as T scalars, and NaN in it went through."""
    model, data = fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 1e-3), 1e5, 300.0, 0.4), _record()
    for bad in (0, -3, 1.5):
        with pytest.raises(ValueError, match="`unroll` must be a positive integer"):
            fj.simulate(model, data.motion, unroll=bad)
    with pytest.raises(TypeError, match="`unroll` must be a positive number"):
        fj.simulate(model, data.motion, unroll=True)
    force = np.asarray(data.force)
    with pytest.raises(ValueError, match=r"`measured` must be shaped as the model's outputs, \(600,\), got \(600, 1\)"):
        fj.simulate(model, data.motion, measured=force[:, None])
    with pytest.raises(ValueError, match="`measured` contains NaN"):
        fj.simulate(model, data.motion, measured=np.where(np.arange(600) == 5, np.nan, force))
    as_list = fj.simulate(model, data.motion, measured=list(force))
    np.testing.assert_array_equal(np.asarray(as_list), np.asarray(fj.simulate(model, data.motion, measured=force)))


def test_small_conversions_name_the_fix():
    data = _record()
    with pytest.raises(ValueError, match=r"shape \(600, 1\) and time is the last axis"):
        fj.Motion.from_position(np.zeros((600, 1)), DT)
    assert [part.length for part in data.split(np.float32(0.5))] == [300, 300]  # a NumPy float is a fraction
    assert [part.length for part in data.split(np.int64(200))] == [200, 400]
    assert [part.length for part in data.split(jnp.argmax(jnp.arange(201)))] == [200, 400]  # a 0-d JAX array
    with pytest.raises(TypeError, match="split points are fractions"):
        data.split("0.5")
    with pytest.raises(TypeError, match="`data` must be one fj.FrictionData record, got list"):
        fj.identify_polynomial_narx([data, data])


def test_the_table_marks_the_validation_choice_and_shows_validation_errors():
    """compare's table was sorted by test NMSE with no validation column, so its top row was in effect chosen on
    the test part; an ensemble's validation error, its own fit, looked better than every single model's."""
    score = lambda test, val, name, label: fj.compare.ModelScore(  # noqa: E731
        name, label, test, 0.5, 1.0, 3, "successful", None, np.zeros(1), validation_nmse=val
    )
    rows = [
        score(1.0, 2.0, "gms", "GMS"),
        score(0.8, 3.0, "lugre", "LuGre"),  # best on test, not on validation
        score(0.9, 1.0, "ensemble_press", "Ensemble: PRESS (gms+lugre)"),  # its validation error is its fit
    ]
    lines = fj.compare.format_table(rows).splitlines()
    assert "val %" in lines[0]
    assert lines[1].startswith("  LuGre") and " 3.0000 " in lines[1]  # sorted by test NMSE
    assert lines[2].startswith("  Ensemble: PRESS") and "(1.0000)" in lines[2]
    assert lines[3].startswith("* GMS")  # the lowest validation error among the single models
    assert any(line.startswith("* the validation part's choice") for line in lines)
    assert "an ensemble: its weights or members found in closed form" in "\n".join(lines)


def test_separable_with_several_records_names_the_real_cause():
    """It said "`separable` needs a SimulationLoss" to a user who passed no loss at all."""
    data = _record()
    with pytest.raises(ValueError, match="a fit to several records already solves each record's offset"):
        fj.fit(_start(), [data, data], solver=fj.levenberg_marquardt(), separable=("Fv",), steps=2)


def test_command_line_errors_name_the_fix(tmp_path, capsys):
    """A misspelt option printed the top-level usage with no hint; a `.mat` file, an `--out` that is a file and a
    CSV without units said nothing useful (the last read the file as m and N silently)."""
    with pytest.raises(SystemExit) as exited:
        fj.main(["compare", "--modles", "lugre"])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert "usage: fricjax compare" in err and "did you mean --models for --modles?" in err
    mat = tmp_path / "DATA_EMPS.mat"
    mat.write_bytes(b"")
    assert fj.main(["compare", "--data", str(mat), "--out", str(tmp_path / "o")]) == 2
    assert "--data emps" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert fj.main(["compare", "--out", str(blocker)]) == 2
    assert "a file, not a folder" in capsys.readouterr().err


def test_a_record_without_units_is_said_to_be_read_as_si(tmp_path):
    t = np.arange(300) * DT
    path = tmp_path / "plain.csv"
    np.savetxt(path, np.c_[t, 1e-3 * np.sin(2 * np.pi * t), np.cos(t)], delimiter=",", header="t,x,force", comments="")
    assert fj.compare.load_record_spec(str(path)).card["units_assumed_si"] == ["x", "force"]
    np.savetxt(path, np.c_[t, np.sin(t), np.cos(t)], delimiter=",", header="t,x [mm],force", comments="")
    assert fj.compare.load_record_spec(str(path)).card["units_assumed_si"] == ["force"]
    assert fj.compare.load_record_spec(str(path), force_unit="kN").card["units_assumed_si"] == []


def test_the_summary_of_a_fit_names_what_is_implausible_in_the_model():
    """compare's notes (Fs < Fc, a damping at its bound) never reached `fj.fit` users."""
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 2.0 * np.arange(2000) * DT), dt=DT)
    truth = fj.Tustin(Fc=1.0, Fs=0.7, vs=1e-3, Fv=5.0, smoothing=fj.Smooth(1e-4))
    data = fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion)))
    start = fj.Tustin(Fc=0.8, Fs=0.9, vs=2e-3, Fv=3.0, smoothing=fj.Smooth(1e-4))
    summary = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=30).summary()
    assert "implausible: Fs < Fc (a Stribeck curve falling towards standstill)" in summary
    clean = fj.fit(_start(), _record(), solver=fj.levenberg_marquardt(), steps=10).summary()
    assert "implausible" not in clean


def test_record_files_and_motions_refuse_what_they_misread(tmp_path):
    """An NPZ's scalar `t` and swapped time stamps were both 'not uniformly sampled'; a complex displacement lost
    its imaginary part with a JAX warning; `dt=True` was one second."""
    n = 300
    t, x, force = np.arange(n) * DT, 1e-3 * np.sin(np.arange(n) * 0.02), np.cos(np.arange(n) * 0.02)
    np.savez(tmp_path / "scalar.npz", t=np.float64(DT), x=x, force=force)
    with pytest.raises(fj.RecordError, match="holds one time stamp, not a time per sample; .* name it 'dt'"):
        fj.load_record(tmp_path / "scalar.npz")
    swapped = t.copy()
    swapped[[10, 11]] = swapped[[11, 10]]
    np.savez(tmp_path / "swapped.npz", t=swapped, x=x, force=force)
    with pytest.raises(fj.RecordError, match=r"goes back at data row 12"):
        fj.load_record(tmp_path / "swapped.npz")
    with pytest.raises(TypeError, match="Motion: `x`: expected real numbers, got a complex array"):
        fj.Motion(x=x * (1 + 1j), dt=DT)
    with pytest.raises(TypeError, match="`dt` must be a sample time in seconds, got True"):
        fj.Motion.from_position(x, True)


def test_file_options_on_built_in_records_are_refused(capsys):
    """`--dt -1` or `--x-unit foo` with `--data tribometer:mixed` ran and exited 0, ignoring them."""
    assert fj.main(["compare", "--data", "tribometer:mixed", "--dt", "-1", "--x-unit", "foo"]) == 2
    assert "--dt, --x-unit describe record files, and every record here is built in" in capsys.readouterr().err
    assert fj.main(["compare", "--data", "tribometer_run.csv", "--dt", "1e-3"]) == 2  # a file of that name
    assert "tribometer_run.csv: no such file" in capsys.readouterr().err


def test_initial_guess_refuses_records_it_cannot_read():
    """A constant force gave Fc = 9e-16, a still record a plausible-looking LuGre, and a motion without reversals
    a GMS of 1 N/m, all without a word."""
    data = _record(2000)
    with pytest.raises(ValueError, match="the record's force does not vary"):
        fj.initial_guess(fj.CoulombViscous, fj.FrictionData(data.motion, np.full(data.length, 0.3)))
    still = fj.Motion.from_position(np.zeros(data.length), DT)
    with pytest.raises(ValueError, match="the record does not move"):
        fj.initial_guess(fj.LuGre, fj.FrictionData(still, data.force))
    t = np.arange(data.length) * DT
    onwards = fj.FrictionData(fj.Motion.from_position(1e-3 * t, DT), np.tanh(t) + 0.01 * np.sin(50 * t))
    with pytest.warns(UserWarning, match="never reverses its motion, so GMS's pre-sliding stiffness"):
        fj.initial_guess(fj.GMS, onwards)


def test_a_fit_that_stops_short_names_the_parameters_it_steps_as_stored():
    """A damping of 7e4 N s/m stayed at its start in a Levenberg-Marquardt fit of the damper's records, and
    nothing said that `scaling=fj.ParameterScaling()` was the fix."""
    motion = _record().motion
    data = fj.FrictionData(motion, np.asarray(fj.simulate(fj.CoulombViscous(1.0, 4e3), motion)))
    start = fj.CoulombViscous(0.5, 2e3, smoothing=fj.Smooth(1e-4))
    short = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=1)
    assert short.code == "max_steps"
    assert "large real parameters, Fv = 2e+03, are stepped as stored" in short.message
    scaled = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=1, scaling=fj.ParameterScaling())
    assert "stepped as stored" not in scaled.message


def test_a_fit_whose_steps_never_improve_returns_its_start_and_says_so():
    truth = fj.CoulombViscous(1.0, 30.0, smoothing=fj.Smooth(1e-4))
    data = _record()
    kept = fj.fit(truth, data, solver=optax.sgd(1e3), steps=3)  # every step overshoots
    assert kept.start_kept and "returned unchanged" in kept.message
    assert float(kept.model.Fv) == 30.0
    assert not fj.fit(_start(), data, solver=fj.levenberg_marquardt(), steps=10).start_kept


@pytest.mark.slow  # a sweep over several records (~13 s): the fast tier stays under 5 minutes
def test_a_sweep_over_several_records_holds_what_fit_holds():
    """fj.sweep on several records trained the model's own offset and initial state, which fj.fit holds (each
    record has its own): the same configuration reached 0.0375 in the sweep and 3.3e-6 in the fit. A single
    validation record crashed after the training; a line-search optimiser failed inside JAX."""
    t = np.arange(1500) * DT

    def record(amplitude: float, offset: float) -> fj.FrictionData:
        motion = fj.Motion.from_position(amplitude * np.sin(2 * np.pi * 2.0 * t), DT)
        truth = fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 1e-3), 1e5, 300.0, 0.4, smoothing=fj.Smooth(1e-4))
        return fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion)) + offset)

    records = [record(1e-3, 0.1), record(5e-4, -0.2), record(8e-4, 0.0)]
    start = fj.LuGre(fj.ExponentialStribeck(0.8, 1.2, 2e-3), 5e4, 100.0, 0.2, smoothing=fj.Smooth(1e-4))
    swept = fj.sweep([start], records[:2], steps=40, learning_rate=1e-2, validation=records[2])
    alone = fj.fit(start, records[:2], solver=optax.adam(1e-2), steps=40)
    np.testing.assert_allclose(swept.train_loss[0], alone.train_loss, rtol=1e-6)
    assert float(np.asarray(fj.unwrap(swept.model).z0)[0]) == 0.0 and np.isfinite(swept.val_loss[0])
    with pytest.raises(TypeError, match=r"cannot take one learning rate per configuration .*optax.lbfgs"):
        fj.sweep([_start(), _start()], _record(), optimiser=optax.lbfgs, steps=2)


def test_a_fit_whose_steps_overshoot_is_told_to_lower_the_rate():
    """The budget message read 'still falling: raise `steps`' at a loss 4e7 times its best."""
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 0.5 * np.arange(2000) * DT), DT)
    stribeck = fj.ExponentialStribeck(10.0, 15.0, 1e-3, 2.0)
    data = fj.FrictionData(motion, np.asarray(fj.simulate(fj.LuGre(stribeck, 1e6, 300.0, 50.0), motion)))
    start = fj.LuGre(fj.ExponentialStribeck(9.0, 13.5, 9e-4), 4.5e5, 200.0, 27.0, smoothing=fj.Smooth(1e-5))
    fitted = fj.fit(start, data, solver=optax.adam(5.0), steps=300)
    assert "raise `steps`" not in fitted.message
    assert "the steps overshoot" in fitted.message, fitted.message


def test_standard_deviations_in_float32_come_with_a_warning():
    f32 = np.float32
    motion = fj.Motion.from_position((1e-3 * np.sin(2 * np.pi * 3.0 * np.arange(600) * DT)).astype(f32), f32(DT))
    truth = fj.CoulombViscous(f32(1.0), f32(30.0), smoothing=fj.Smooth(f32(1e-4)))
    data = fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion)))
    start = fj.CoulombViscous(f32(0.5), f32(10.0), smoothing=fj.Smooth(f32(1e-4)))
    with pytest.warns(UserWarning, match="compute_std in float32"):
        fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=5, compute_std=True)
