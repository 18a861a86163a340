"""`fricjax compare` with several training records: globs, per-record nuisances in the table and report.json, test
records started from the state and offset fitted on their initialisation window, and one-line errors for records
that cannot be fitted together."""

from __future__ import annotations

import json

import numpy as np
import pytest

import fricjax as fj
from fricjax import main

from helpers import lugre

DT = 1e-3
OFFSETS = (0.3, -0.2, 0.1, 0.5)


def _truth() -> fj.LuGre:
    return lugre()


def _write(path, amplitude, frequency, n, offset, seed, dt=DT, scale=1.0):
    t = np.arange(n) * dt
    x = amplitude * np.sin(2 * np.pi * frequency * t) * np.minimum(1.0, t / 0.3)
    motion = fj.Motion.from_position(x, dt=dt)
    force = np.asarray(fj.simulate(_truth(), motion)) + offset + 0.01 * np.random.default_rng(seed).normal(size=n)
    np.savetxt(path, np.c_[t, x, scale * force], delimiter=",", header="t,x,force", comments="")
    return path


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("records")
    shapes = ((1e-3, 1.0, 1200), (2e-3, 1.5, 1000), (5e-4, 2.0, 900))
    for i, (amplitude, frequency, n) in enumerate(shapes):
        _write(folder / f"char_{i}.csv", amplitude, frequency, n, OFFSETS[i], i)
    test = _write(folder / "other.csv", 1.5e-3, 1.2, 1100, OFFSETS[3], 9)
    return folder, test


@pytest.mark.slow
def test_several_records_from_a_glob_per_record_offsets_in_table_and_report(records, tmp_path, capsys):
    folder, test = records
    out = tmp_path / "out"
    code = main(["compare", "--data", str(folder / "char_*.csv"), "--test", str(test), "--models", "lugre",
                 "--steps", "40", "--drift", "none", "--out", str(out), "--no-progress"])  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "3 training records: char_0.csv" in printed and "per training record" in printed
    report = json.loads((out / "report.json").read_text())
    parts = report["split"]["training_records"]
    assert [p["name"] for p in parts] == ["char_0.csv", "char_1.csv", "char_2.csv"]
    assert parts[0]["train"] == [0, 960] and parts[0]["validation"] == [960, 1200]  # the last 20 % of each
    assert isinstance(report["data_card"], list) and len(report["data_card"]) == 3
    (lugre,) = report["models"]
    offsets = [row["offset_N"] for row in lugre["training_records"]]
    np.testing.assert_allclose(offsets, OFFSETS[:3], atol=0.05)
    assert lugre["parameters"]["offset"] == 0.0  # one offset per record instead of the model's own
    score = lugre["test_scores"][str(test)]
    assert abs(score["offset"] - OFFSETS[3]) < 0.05 and score["nmse"] < 1.0, score
    assert "initial state" in report["settings"]["scoring"]


@pytest.mark.slow  # three physics fits, twice (~60 s)
def test_the_order_of_the_training_records_does_not_move_the_fits(records, tmp_path, capsys):
    """The starts are read off each training record on its own (`fj.initial_guess` of the list, pooled), not off the
    records joined in the order given: the same records in another order give the same fits, to round-off (before,
    on the friction damper's records, GMS start stiffnesses 3.7x apart and NLR 6.00 against 4.83 % on a test)."""
    folder, test = records
    names = sorted(str(path) for path in folder.glob("char_*.csv"))
    scores = []
    for order in (names, [names[2], names[0], names[1]]):
        out = tmp_path / f"out{len(scores)}"
        code = main(["compare", "--data", *order, "--test", str(test), "--models", "nlr", "gms", "lugre-backlash",
                     "--steps", "6", "--drift", "none", "--out", str(out), "--no-progress"])  # fmt: skip
        assert code == 0, capsys.readouterr()
        report = json.loads((out / "report.json").read_text())
        scores.append({m["name"]: m["test_scores"][str(test)]["nmse"] for m in report["models"]})
    assert sorted(scores[0]) == sorted(scores[1]) and len(scores[0]) >= 3, scores
    for name, value in scores[0].items():
        assert abs(scores[1][name] - value) <= 1e-6 * value, (name, value, scores[1][name])


@pytest.mark.slow  # fast tier trimmed (2026-11-27): error messages of the many-records CLI
def test_records_that_do_not_go_together_are_refused_in_one_line(records, tmp_path, capsys):
    folder, test = records
    other_dt = _write(tmp_path / "slow.csv", 1e-3, 1.0, 600, 0.0, 3, dt=2e-3)
    in_kilonewton = _write(tmp_path / "kn.csv", 1e-3, 1.0, 600, 0.0, 4, scale=1e-3)  # forces in kN, header says N
    cases = [
        (["--data", str(folder / "char_0.csv"), str(other_dt)], "slow.csv: sampled at dt = 0.002 s"),
        (["--data", str(folder / "char_0.csv"), str(in_kilonewton)], "kn.csv (in SI units): check the units of both"),
        (["--data", str(tmp_path / "none_*.csv")], "the pattern matches no file"),
        (["--data", str(folder / "char_0.csv"), str(folder / "char_1.csv")], "name the records to test on"),
        (["--data", str(folder / "char_*.csv"), "--test", str(test), "--models", "mlp"], "fitted by the physics"),
        (
            [
                "--data",
                str(folder / "char_0.csv"),
                "--validation",
                str(test),
                "--split",
                "0.5",
                "0.6",
                "--test",
                str(test),
            ],
            "with validation records the training records are whole",
        ),  # fmt: skip
    ]
    for arguments, message in cases:
        code = main(["compare", *arguments, "--out", str(tmp_path / "never"), "--no-progress"])
        err = capsys.readouterr().err
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, (arguments, err)
    assert not (tmp_path / "never" / "report.json").exists()


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 345 s)
def test_a_test_record_starts_from_the_state_fitted_on_its_window():
    """`predict_test_record`: a record cut mid-loop, scored after its window: starting from the fitted state beats
    the run from rest with the window's mean error as offset (the former default, `--init offset`)."""
    from fricjax.compare import TestRecord, predict_test_record, score_prediction

    t = np.arange(2400) * DT
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 1.0 * t), dt=DT)
    record = fj.FrictionData(motion, np.asarray(fj.simulate(_truth(), motion)) + 0.4).slice(1100, 2400)
    test = TestRecord("cut", record, 0, 100)
    state, _ = score_prediction(predict_test_record(_truth(), test, "state"), test)
    rest, _ = score_prediction(predict_test_record(_truth(), test, "offset"), test)
    assert abs(state.offset - 0.4) < 1e-4 and state.nmse < 1e-2 * rest.nmse  # NMSE in %


def test_a_carried_drift_is_scaled_by_the_force_range_the_model_predicts():
    """`--test-drift carry` with the training record's force range: the drift goes over in proportion to the force
    ranges the friction model predicts on the two records' displacements (the tribometer's cell drifts by a fixed
    fraction of each record's range); a record of a smaller range gets that much less drift, and the test record's
    measured force does not enter (scrambling it changes nothing)."""
    from fricjax.compare import TestRecord, predict_test_record

    friction = fj.exact(_truth())  # compare scores in exact mode
    drifting = fj.SensorDrift(friction, rate=-0.05)
    t = np.arange(2000) * DT
    big = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * t), dt=DT)
    small = fj.Motion.from_position(2e-6 * np.sin(2 * np.pi * t), dt=DT)  # pre-sliding: a smaller force range
    training_range = float(np.ptp(np.asarray(fj.simulate(friction, big))))
    force = np.asarray(fj.simulate(friction, small))
    ratio = np.ptp(force) / training_range
    assert 0.05 < ratio < 0.9
    test = TestRecord("small", fj.FrictionData(small, force), 0, 100)
    carried = predict_test_record(drifting, test, test_drift="carry", training_range=training_range)
    np.testing.assert_allclose(carried - force, ratio * (-0.05) * t, atol=1e-9)
    unscaled = predict_test_record(drifting, test, test_drift="carry")
    np.testing.assert_allclose(unscaled - force, -0.05 * t, atol=1e-9)
    scrambled = TestRecord("small", fj.FrictionData(small, force[::-1] * 3.0), 0, 100)
    np.testing.assert_array_equal(
        predict_test_record(drifting, scrambled, test_drift="carry", training_range=training_range), carried
    )


@pytest.mark.slow  # one static-curve fit (~10 s)
def test_compare_carries_a_tribometer_drift_scaled_by_its_training_record():
    """`fit_and_score` hands the training record's predicted force range to the carried drift: a built-in
    tribometer test record (auto: carry) gets the fitted drift scaled by the two records' force ranges."""
    from fricjax.compare import TestRecord, fit_and_score, free_run, load_record_spec, load_split, predict_test_record

    split, _, _ = load_split("tribometer:mixed")
    loaded = load_record_spec("tribometer:presliding:seed=1")
    test = TestRecord.whole(loaded)
    (row,) = fit_and_score(["stribeck"], split, tests=[test], progress=False, log=lambda _: None)
    assert isinstance(row.model, fj.SensorDrift)
    training_range = float(np.ptp(free_run(row.model.model, split.full)))
    expected = predict_test_record(row.model, test, training_range=training_range)
    np.testing.assert_allclose(row.test_predictions[test.name], expected, rtol=1e-12)
    assert not np.allclose(expected, predict_test_record(row.model, test), rtol=1e-6)  # the scaling matters


@pytest.mark.slow
def test_records_with_a_normal_load_scale_the_physics_models(tmp_path, capsys):
    """A normal-load column named on the command line: the physics models are wrapped in `fj.NormalLoad`, so a
    record at another load is predicted from the load alone (the training loads 100 and 200 N, the test at 150 N)."""
    truth = fj.NormalLoad(_truth(), reference=100.0)
    paths = []
    for i, (load, n) in enumerate(((100.0, 1200), (200.0, 1000), (150.0, 1100))):
        t = np.arange(n) * DT
        x = 1e-3 * np.sin(2 * np.pi * 1.2 * t) * np.minimum(1.0, t / 0.3)
        normal = load * (1 + 0.2 * np.sin(2 * np.pi * 0.4 * t))
        motion = fj.Motion(x=x, v=fj.Motion.from_position(x, dt=DT).v, dt=DT, normal_force=normal)
        force = np.asarray(fj.simulate(truth, motion)) + 0.01 * np.random.default_rng(i).normal(size=n)
        path = tmp_path / f"load_{i}.csv"
        np.savetxt(path, np.c_[t, x, force, normal / 2, normal / 2], delimiter=",", comments="",
                   header="t,x,force,press_a [N],press_b [N]")  # fmt: skip
        paths.append(str(path))
    out = tmp_path / "out"
    options = ["--normal-force-column", "press_a", "press_b", "--models", "lugre", "--steps", "40", "--drift", "none"]
    code = main(["compare", "--data", *paths[:2], "--test", paths[2], *options, "--out", str(out), "--no-progress"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "scale with it" in printed and "LuGre x N" in printed
    report = json.loads((out / "report.json").read_text())
    (lugre,) = report["models"]
    assert lugre["test_scores"][paths[2]]["nmse"] < 1.0, lugre["test_scores"]
    assert report["data_card"][0]["columns"]["normal_force"] == "press_a [N] + press_b [N]"
