"""`fricjax compare`: success on a user file and on the EMPS data, and one-line failures that leave no report."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import fricjax as fj
from fricjax import main
from fricjax.compare import (
    DataScales,
    FitSettings,
    Split,
    TestRecord,
    add_ensembles,
    fit_and_score,
    format_table,
    load_record_spec,
    load_split,
    paired_validation_gain,
    reference_scores,
    score,
    score_prediction,
    statistics_warnings,
)


@pytest.fixture(scope="module")
def record_csv(tmp_path_factory):
    """A small GMS record written as CSV with columns t, x, force."""
    data = fj.make_tribometer("mixed", seed=1)
    n = 1500
    t = np.arange(n) * float(data.full.motion.dt)
    table = np.column_stack([t, np.asarray(data.full.motion.x)[:n], np.asarray(data.full.force)[:n]])
    path = tmp_path_factory.mktemp("data") / "record.csv"
    np.savetxt(path, table, delimiter=",", header="t,x,force", comments="")
    return path


@pytest.mark.slow
def test_compare_on_a_user_file_writes_a_complete_report(record_csv, tmp_path, capsys):
    out = tmp_path / "report"
    # files of the user's in --out: none may be deleted or changed by the run
    mine = {out / "models" / "sub" / "thesis.csv": "a,b\n1,2\n", out / ".write-test": "keep", out / "notes.txt": "x"}
    for path, text in mine.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    code = main(
        ["compare", "--data", str(record_csv), "--models", "stribeck", "nlr", "--out", str(out), "--no-progress"]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert all(path.read_text() == text for path, text in mine.items())

    def refuse(constant):
        raise AssertionError(f"report.json is not strict JSON: {constant}")

    report = json.loads((out / "report.json").read_text(), parse_constant=refuse)
    names = [m["name"] for m in report["models"]]
    assert {"stribeck", "nlr", "ensemble_average", "ensemble_weighted"} <= set(names)
    nmses = [m["nmse_percent"] for m in report["models"]]
    assert nmses == sorted(nmses)  # the table is sorted by test NMSE
    assert all(np.isfinite(nmses))
    assert (out / "test_errors.png").stat().st_size > 10_000
    assert (out / "hysteresis_loops.png").stat().st_size > 10_000
    reloaded = fj.load_model(out / "models" / "nlr.eqx")
    assert isinstance(reloaded, fj.SensorDrift) and isinstance(reloaded.model, fj.MaxwellSlip)  # with its drift
    assert "NMSE %" in printed and "Maxwell-slip NLR(5)" in printed
    assert not list(out.glob(".partial-*"))


@pytest.mark.slow
def test_best_single_and_ensemble_reach_the_noise_floor():
    """Issue 9's acceptance on the default regime (mixed, seed 0, every default model, as `fricjax compare`):
    scored after the initialisation window, the best single model is within 3x and the best ensemble within 2x
    of the noise floor (the true model with its sensor drift and offset, scored the same way)."""
    data = fj.make_tribometer("mixed", seed=0)
    split, _, _ = load_split("tribometer:mixed", seed=0)
    test = split.test_record(reference=data.sensor_force)
    rows = fit_and_score(list(fj.compare.PHYSICS_MODELS), split, tests=[test], progress=False, log=lambda _: None)
    ensembles = add_ensembles(rows, split, [test])
    floor = reference_scores([test])["test part"].nmse
    best_single = min(r.nmse for r in rows)
    best_ensemble = min(r.nmse for r in ensembles if r.name != "ensemble_average")
    assert best_single <= 3 * floor, (best_single, floor)
    assert best_ensemble <= 2 * floor, (best_ensemble, floor)
    # GMS, the true model class, from its data-driven start and 256 screened starts: near the floor (measured 1.09x
    # since its LM judges convergence over 10 steps; 1.33x when a run of rejected steps stopped it), its Stribeck
    # curve near the true one
    gms = next(r for r in rows if r.name == "gms")
    assert gms.nmse <= 1.3 * floor, (gms.nmse, floor)
    stribeck = fj.unwrap(gms.model).model.stribeck
    assert abs(float(stribeck.Fc) - 1.0) < 0.2 and abs(float(stribeck.Fs) - 1.4) < 0.2, stribeck
    # without the initialisation window (the old scoring), the drift alone costs the true model 15x its floor
    assert score(data.true_model, split)[0] > 10 * floor


@pytest.mark.slow
def test_fit_on_one_record_and_run_free_on_another(tmp_path, capsys):
    """`--test`: fit on one built-in record, run free on one with another excitation (seed) and another force-cell
    offset; the offset is recovered from the initialisation window and the score is near that record's floor."""
    out = tmp_path / "out"
    train, other = "tribometer:mixed:duration=2,offset=0.2", "tribometer:mixed:seed=1,duration=2,offset=-0.5"
    code = main(["compare", "--data", train, "--test", other, "--models", "gms", "nlr", "--out", str(out),
                 "--no-progress", "--steps", "40"])  # fmt: skip
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    (record,) = report["test_records"]
    assert record["name"] == other and record["card"]["sensor"]["force_offset_N"] == -0.5
    gms = next(m for m in report["models"] if m["name"] == "gms")
    score_ = gms["test_scores"][other]
    fitted_offset = gms["parameters"]["model.offset"]  # the friction model's offset (inside its sensor drift)
    assert gms["parameter_units"]["model.offset"] == "N" and gms["parameter_units"]["model.k"] == "N/m"
    assert set(gms["parameter_units"]) == set(gms["parameters"])
    # the estimated offset: the difference of the two cells' offsets (-0.7 N) up to drift and the fit's own offset
    assert abs(score_["offset"] + fitted_offset - (-0.5)) < 0.1, (score_["offset"], fitted_offset)
    # 2-s records and the default 40-step budget: within 10x of the floor (measured 1.12x when GMS's LM had 40
    # steps, it has 80 now; with 20 it stopped at its budget far from it, 42x: the `max_steps` advice is the cure)
    assert score_["nmse"] <= 10 * record["noise_floor_nmse_percent"], (score_, record)
    assert report["split"]["test_part"] is None and report["split"]["validation"][1] == 4000
    printed = capsys.readouterr().out
    assert "noise floor" in printed and "result:" in printed


@pytest.mark.slow
def test_compare_emps_table(data_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FRICJAX_DATA", str(data_dir))
    assert main(["compare", "--data", "emps", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert len(report["idm"]) == 8
    symmetric = report["idm"][0]
    assert abs(symmetric["train_relative_error_percent"] - 4.08) < 0.1
    assert abs(symmetric["test_relative_error_percent"] - 5.98) < 0.1
    for row in report["idm"]:  # every parameter with its SI unit
        assert set(row["parameter_units"]) == set(row["parameters"]) and all(row["parameter_units"].values()), row
    assert re.search(r"M=95\.1\d* kg, offset=-3\.1\d* N", capsys.readouterr().out)  # printed with its units


@pytest.mark.parametrize(
    "content, match",
    [
        ("t,x\n0,0\n0.001,1e-6\n", "missing column 'force'"),
        ("this is not, a table\n\x00\x01", "cannot read|missing column"),
        ("t,force\n" + "".join(f"{i * 1e-3},{i}\n" for i in range(200)), "'x'"),
        ("x,force\n" + "".join(f"{i * 1e-6},{i}\n" for i in range(200)), "'t'"),
    ],
)
def test_bad_files_give_one_line_errors_and_no_report(tmp_path, capsys, content, match):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    out = tmp_path / "out"
    code = main(["compare", "--data", str(path), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("fricjax compare:")
    import re

    assert re.search(match, err), err
    assert not (out / "report.json").exists()


def test_unknown_model_missing_file_and_unwritable_output(tmp_path, capsys):
    assert main(["compare", "--models", "lugre", "nonsense", "--out", str(tmp_path)]) == 2
    assert "unknown model 'nonsense'" in capsys.readouterr().err
    assert main(["compare", "--data", str(tmp_path / "missing.npz"), "--out", str(tmp_path)]) == 2
    assert "no such file" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["compare", "--out", str(blocker / "sub")]) == 2
    assert "not writable" in capsys.readouterr().err
    assert main(["compare", "--data", "tribometer:wet", "--out", str(tmp_path)]) == 2
    assert "wet" in capsys.readouterr().err


def test_data_scales_read_the_record():
    data = fj.make_tribometer("mixed", seed=0)
    scales = DataScales.from_data(data.train)
    assert 0.5 < scales.Fc < 1.5 and scales.Fs >= scales.Fc
    assert 1e4 < scales.stiffness < 1e7
    split = Split(data.full, 4800, 6400)
    assert split.train.length == 4800 and split.test.length == 1600


# ----------------------------------------------------------------------------------------------------------------
# test records, initialisation windows, the noise floor (issue 9)
# ----------------------------------------------------------------------------------------------------------------


def test_initialisation_window_recovers_an_offset_and_is_not_scored():
    data = fj.make_tribometer("mixed", seed=0, duration=1.0, force_offset=0.7)
    clean = np.asarray(data.clean_force)
    test = TestRecord("record", data.full, start=500, init_window=200)
    result, scored = score_prediction(clean, test)
    drift_there = float(np.mean((np.asarray(data.sensor_force) - clean)[500:700]))
    assert abs(result.offset - drift_there) < 0.01 and abs(drift_there - 0.7) < 0.05
    assert scored.size == data.full.length - 700
    # a prediction that is wrong only inside the window scores the same
    spoiled = clean.copy()
    spoiled[550:650] += 100.0
    assert score_prediction(spoiled, test)[0].nmse != result.nmse  # the offset estimate sees the window...
    unscored = clean.copy()
    unscored[:500] += 100.0  # ...but samples before it are never used
    assert score_prediction(unscored, test)[0] == result
    with pytest.raises(fj.compare.CompareError, match="init-window"):
        TestRecord("record", data.full, start=500, init_window=data.full.length)


def test_noise_floor_is_the_sensor_reading_and_beats_the_drift_free_truth():
    data = fj.make_tribometer("presliding", seed=0)
    split = Split(data.full, *data.card["split_edges"][1:3])
    test = split.test_record(reference=data.sensor_force)
    floor = reference_scores([test])["test part"]
    noise = data.card["sensor"]["force_noise_std_N"] ** 2
    measured = np.asarray(data.full.force)[test.scored_start :]
    assert floor.nmse == pytest.approx(100 * noise / np.var(measured), rel=0.15)  # white noise only
    assert score(data.true_model, split)[0] > 10 * floor.nmse


def test_builtin_record_specs_and_their_errors():
    loaded = load_record_spec("tribometer:sliding:seed=3,offset=-0.25,duration=1")
    assert loaded.data.length == 2000 and loaded.card["seed"] == 3
    assert loaded.card["sensor"]["force_offset_N"] == -0.25 and loaded.reference is not None
    for bad in ("tribometer:mixed:colour=red", "tribometer:mixed:seed=x", "tribometer:mixed:offset"):
        with pytest.raises(fj.compare.CompareError, match="tribometer"):
            load_record_spec(bad)


def test_cli_budget_split_and_window_errors_are_one_line(tmp_path, capsys):
    for argv, match in [
        (["--steps", "0"], "--steps"),
        (["--gms-elements", "-1"], "--gms-elements"),
        (["--split", "0.8", "0.6"], "--split"),
        (["--init-window", "-3"], "--init-window"),
        (["--init-window", "100000"], "init-window"),
        (["--test", "tribometer:mixed:seed=x"], "seed"),
    ]:
        code = main(["compare", *argv, "--out", str(tmp_path / "out"), "--no-progress", "--models", "stribeck"])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and match in err, (argv, err)
    assert not (tmp_path / "out" / "report.json").exists()
    with pytest.raises(fj.compare.CompareError):
        FitSettings(steps=0)


def test_table_lists_every_test_record_the_floor_and_the_result_codes():
    scores = {"a.csv": fj.compare.Score(1.0, 0.5, 0.1), "b.csv": fj.compare.Score(2.0, 0.7, -0.2)}
    row = fj.compare.ModelScore("gms", "GMS (N=4)", 1.0, 0.5, 3.0, 14, "max_steps", None, np.zeros(1), tests=scores)
    text = format_table([row], {"a.csv": fj.compare.Score(0.1, 0.2, 0.0)})
    assert "NMSE % 1" in text and "NMSE % 2" in text and "1 = a.csv; 2 = b.csv" in text
    assert "noise floor" in text and "max_steps = the step budget ran out" in text


def test_a_quiet_test_tail_is_warned_about():
    data = fj.make_tribometer("mixed", seed=0)
    split = Split(data.full, 4800, 6400)
    quiet = fj.FrictionData(data.full.motion, np.asarray(data.full.force) * np.r_[np.ones(6400), np.full(1600, 0.05)])
    test = TestRecord("quiet", quiet, 6400, 10)
    (warning,) = statistics_warnings(split, [test], fj.compare.load_record_spec("tribometer:mixed").units)
    assert "force std" in warning and "quiet" in warning
    assert statistics_warnings(split, [split.test_record()], load_record_spec("tribometer:mixed").units) == []


def test_test_speeds_beyond_the_training_records_are_warned_about():
    """A gross-sliding test record (peak speed ~10x the mixed training part's): the warning names the speeds, the
    ratio and the cure (train on a record that reaches them); a mixed record of another seed gets none."""
    split = Split(fj.make_tribometer("mixed", seed=0).full, 4800, 6400)
    units = load_record_spec("tribometer:mixed").units
    fast = fj.make_tribometer("sliding", seed=1).full
    (warning,) = statistics_warnings(split, [TestRecord("fast", fast, 0, 800)], units)
    assert "fast: speeds up to" in warning and "m/s" in warning and "extrapolated" in warning, warning
    other = fj.make_tribometer("mixed", seed=1).full
    assert statistics_warnings(split, [TestRecord("other", other, 0, 800)], units) == []


@pytest.mark.slow
def test_units_of_a_file_reach_the_report_and_the_fit_works_in_si(tmp_path):
    """A record in um / kN with a rounded time column (fixed by --dt) and an extra column: fitted in SI, the
    report names the record's units and the ignored column."""
    data = fj.make_tribometer("sliding", seed=2, duration=1.5)
    x_um = np.asarray(data.full.motion.x) * 1e6
    force_kn = np.asarray(data.full.force) / 1e3
    t = np.round(np.arange(x_um.size) * 5e-4, 3)
    path = tmp_path / "record.csv"
    header = "time [s],position [um],F [kN],temperature"
    np.savetxt(path, np.c_[t, x_um, force_kn, np.zeros_like(t)], delimiter=",", header=header, comments="")
    out = tmp_path / "out"
    argv = ["compare", "--data", str(path), "--models", "nlr", "--out", str(out), "--no-progress"]
    assert main(argv) == 2  # the rounded time column is refused ...
    assert main([*argv, "--dt", "5e-4"]) == 0  # ... and --dt fixes it
    report = json.loads((out / "report.json").read_text())
    assert report["units"]["x"] == "um" and report["units"]["force"] == "kN"
    assert report["data_card"]["ignored"] == ["temperature"]
    (nlr,) = [m for m in report["models"] if m["name"] == "nlr"]
    assert nlr["nmse_percent"] < 5.0  # a sensible fit: the SI conversion is right (thresholds in metres)
    assert max(nlr["parameters"]["model.thresholds"]) < 1e-3


@pytest.mark.slow
def test_compare_fits_the_neural_models(record_csv, tmp_path, capsys):
    """`--models mlp gsnn rnn avd` (small budgets): each is fitted, scored, saved, reloadable and in the ensembles."""
    out = tmp_path / "neural"
    code = main(
        ["compare", "--data", str(record_csv), "--models", "MLP", "gsnn", "rnn", "avd", "stribeck"]
        + ["--neural-steps", "20", "--out", str(out), "--no-progress"]
    )
    assert code == 0
    printed = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    rows = {m["name"]: m for m in report["models"]}
    assert {"mlp", "gsnn", "rnn", "avd", "ensemble_average", "ensemble_weighted"} <= set(rows)
    assert all(np.isfinite(rows[name]["nmse_percent"]) for name in ("mlp", "gsnn", "rnn", "avd"))
    for name, kind in (("mlp", fj.MLPNARX), ("gsnn", fj.GSNN), ("rnn", fj.RecurrentNetwork), ("avd", fj.MLPNARX)):
        reloaded = fj.load_model(out / "models" / f"{name}.eqx")
        assert isinstance(reloaded, fj.SensorDrift) and isinstance(reloaded.model, kind)
    assert "GSNN (5) on 20 plays" in printed and "recurrent network (20 play + 8)" in printed
    # a neural model out of its output-error budget is told to raise --neural-steps, not --steps
    stopped = [m for name, m in rows.items() if name in ("mlp", "gsnn", "rnn", "avd") and m["result"] == "max_steps"]
    assert all("raise `steps`" not in m["result_message"] for m in stopped)
    if stopped:
        assert "--neural-steps" in printed and "raise --neural-steps" in stopped[0]["result_message"], printed


@pytest.mark.slow
def test_neural_models_reach_the_noise_floor():
    """Issue 10's acceptance on the default regime (mixed, seed 0, the default sizes of `fricjax compare`): the
    recurrent network and the GSNN within 3x, the MLP within 5x of the noise floor (measured 2.54x, 2.72x, 2.67x:
    the least-squares models, their NOE stage not significantly better)."""
    data = fj.make_tribometer("mixed", seed=0)
    split, _, _ = load_split("tribometer:mixed", seed=0)
    test = split.test_record(reference=data.sensor_force)
    rows = {r.name: r for r in fit_and_score(["rnn", "gsnn", "mlp"], split, tests=[test], progress=False, log=print)}
    floor = reference_scores([test])["test part"].nmse
    print({name: round(row.nmse / floor, 3) for name, row in rows.items()})
    assert rows["rnn"].nmse <= 3 * floor, (rows["rnn"].nmse, floor)
    assert rows["gsnn"].nmse <= 3 * floor, (rows["gsnn"].nmse, floor)
    assert rows["mlp"].nmse <= 5 * floor, (rows["mlp"].nmse, floor)


@pytest.mark.slow
def test_linear_in_parameters_models_reach_the_noise_floor():
    """Issue 11's acceptance on the default regime (mixed, seed 0): the polynomial NARX within 10x of the noise
    floor (measured 2.75x: the validation part chooses the degree-1 structure on the velocity and the play
    operators), its structure and every candidate's validation score named in the fit's message; the kernel
    NARX and the local models (kNN) within 20x (measured 5.1x and 13.7x)."""
    data = fj.make_tribometer("mixed", seed=0)
    split, _, _ = load_split("tribometer:mixed", seed=0)
    test = split.test_record(reference=data.sensor_force)
    rows = {r.name: r for r in fit_and_score(["narx", "kernel", "knn"], split, tests=[test], progress=False, log=print)}
    floor = reference_scores([test])["test part"].nmse
    print({name: round(row.nmse / floor, 3) for name, row in rows.items()})
    assert rows["narx"].nmse <= 10 * floor, (rows["narx"].nmse, floor)
    assert "structure: v and 20 plays" in rows["narx"].message and "lags of dx, v and F" in rows["narx"].message
    assert rows["knn"].nmse <= 20 * floor, (rows["knn"].nmse, floor)
    assert rows["kernel"].nmse <= 20 * floor, (rows["kernel"].nmse, floor)
    assert "width" in rows["kernel"].message and "best of 24" in rows["kernel"].message
    assert "locally linear" in rows["knn"].message


def test_paired_validation_gain_tells_a_real_improvement_from_none():
    """The rule that keeps a neural model's NOE stage: the relative drop of the validation error and its paired t
    over blocks; the same model gains nothing (t = 0), the true model against one with its Coulomb level 40 % off
    gains much (t above 3; NOE is kept from 2), and the reverse comparison is negative."""
    import equinox as eqx

    data = fj.make_tribometer("mixed", seed=0)
    split, _, _ = load_split("tribometer:mixed", seed=0)
    truth = data.true_model
    off = eqx.tree_at(lambda m: m.stribeck, truth, fj.ExponentialStribeck(Fc=0.6, Fs=1.4, vs=1e-3, delta=1.0))
    assert paired_validation_gain(truth, truth, split) == (0.0, 0.0)
    gain, t = paired_validation_gain(off, truth, split)
    assert 0.5 < gain < 1 and t > 3, (gain, t)
    loss, t_reverse = paired_validation_gain(truth, off, split)
    assert loss < 0 and t_reverse < -3, (loss, t_reverse)


def test_loop_figure_shows_distinct_models_one_ensemble_at_most():
    """The hysteresis figure's panels: the best models by test NMSE with at most one ensemble (the ensembles are
    near-identical mixtures of the best single model)."""
    from types import SimpleNamespace

    from fricjax.compare import distinct_models

    rows = [
        SimpleNamespace(name=name, nmse=value)
        for name, value in (
            ("gms", 0.10),
            ("ensemble_weighted", 0.101),
            ("ensemble_press", 0.102),
            ("dnlrx", 2.8),
            ("nlr", 3.2),
            ("lugre", 6.0),
            ("ensemble_average", float("nan")),
        )  # fmt: skip
    ]
    assert [r.name for r in distinct_models(rows, 4)] == ["gms", "ensemble_weighted", "dnlrx", "nlr"]
