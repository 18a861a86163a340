"""Compare as data in and a report out (issue 53, item 5): a `CompareConfig` validated when made, whose errors name its
fields (the command line shows them as its flags), and `run_compare` returning the `Report` it printed and wrote."""

from __future__ import annotations

import json

import numpy as np
import pytest

import fricjax as fj

CompareConfig, CompareError = fj.compare.CompareConfig, fj.compare.CompareError


@pytest.mark.parametrize(
    "fields, field",
    [
        ({"init_window": -3}, "`init_window`"),
        ({"models": ["lugre", "friction9000"]}, "`models`"),
        ({"velocity": "fast"}, "`velocity`"),
        ({"steps": 0}, "`steps`"),
        ({"drift": "quadratic"}, "`drift`"),
        ({"test_drift": "carry", "drift": "none"}, "`test_drift`"),
        ({"dt": 1e-3}, "`dt`"),  # a file option with built-in records only
        ({"data": "emps", "models": ["lugre"]}, "`models`"),
        ({"data": ["emps", "tribometer"]}, "`data`"),
        ({"data": []}, "`data`"),
        ({"out": " "}, "`out`"),
        ({"device": "tpu9"}, "`device`"),
    ],
)
def test_a_bad_configuration_is_refused_naming_its_field(fields, field):
    with pytest.raises(CompareError) as caught:
        CompareConfig(**fields)
    assert field in str(caught.value) and "--" not in str(caught.value), str(caught.value)


def test_the_configuration_is_normalised_once():
    config = CompareConfig(data="run.csv", models=["LuGre", "lugre", "GMS"], normal_force_column=[], columns={})
    assert config.data == ("run.csv",) and config.models == ("lugre", "gms")
    assert config.normal_force_column is None and config.columns is None and config.test == ()
    assert CompareConfig(models=["all"]).models == tuple(fj.compare.MODEL_NAMES)
    assert config.settings(several=True).drift == "none" and config.settings(several=False).drift == "linear"


def test_the_command_line_names_the_fields_by_its_flags(tmp_path, capsys):
    for argv, flag in [
        (["--models", "friction9000"], "--models: unknown model 'friction9000'"),
        (["--dt", "0.001"], "--dt describes record files"),
        (["--test-drift", "carry", "--drift", "none"], "--test-drift carry carries"),
    ]:
        code = fj.main(["compare", *argv, "--out", str(tmp_path / "out"), "--no-progress"])
        err = capsys.readouterr().err
        assert code == 2 and flag in err and "`" not in err.split(":", 1)[1][:20], err


@pytest.mark.slow
def test_run_compare_returns_the_report_it_printed_and_wrote(tmp_path, capsys):
    data = fj.make_tribometer("mixed", seed=1).full
    n = 1500
    t = np.arange(n) * float(data.motion.dt)
    path = tmp_path / "record.csv"
    table = np.c_[t, np.asarray(data.motion.x)[:n], np.asarray(data.force)[:n]]
    np.savetxt(path, table, delimiter=",", header="t,x,force", comments="")
    config = CompareConfig(data=str(path), models=["stribeck"], steps=3, out=tmp_path / "out", progress=False)
    report = fj.compare.run_compare(config)
    printed = capsys.readouterr().out
    assert isinstance(report, fj.compare.Report) and report.table() in printed
    written = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [m["name"] for m in written["models"]] == [m["name"] for m in report.contents([])["models"]]
    assert written["figures"] == ["test_errors.png", "hysteresis_loops.png"]
    assert {row.name for row in report.rows} >= {"stribeck"} and report.records.data == str(path)


def test_fix_and_bounds_are_checked_and_name_a_parameter_of_the_models(tmp_path, capsys):
    with pytest.raises(CompareError, match="`bounds` sigma0=2:1"):
        CompareConfig(bounds={"sigma0": (2.0, 1.0)})
    with pytest.raises(CompareError, match="`fix` sigma2"):
        CompareConfig(fix={"sigma2": float("nan")})
    assert CompareConfig(fix={"sigma2": 0}, bounds={"vs": (1e-4, 1e-2)}).settings(False).bounds == (("vs", 1e-4, 1e-2),)
    out = str(tmp_path / "out")
    code = fj.main(["compare", "--models", "stribeck", "--fix", "sigma0=1e5", "--out", out, "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "--fix sigma0: no physics model fitted here has such a parameter; theirs:" in err, err
    with pytest.raises(SystemExit) as exited:  # argparse's usage error
        fj.main(["compare", "--bounds", "vs=1e-3"])
    assert exited.value.code == 2 and "give NAME=LO:HI" in capsys.readouterr().err


@pytest.mark.slow  # one LuGre fit (~20 s)
def test_fixed_and_bounded_parameters_hold_in_the_fitted_models(tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["compare", "--data", "tribometer:mixed:duration=1", "--models", "lugre", "--steps", "8", "--no-progress"]
    argv += ["--test", "tribometer:mixed:seed=3,duration=1", "--test-drift", "window"]  # its own window, not carried
    code = fj.main([*argv, "--fix", "sigma2=0.5", "--bounds", "stribeck.vs=1e-4:1e-2", "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out  # the test record's offset and the initial state its window found
    assert "offsets on the test records [N]" in printed and "LuGre on tribometer:mixed:seed=3,duration=1: z " in printed
    model = fj.load_model(out / "models" / "lugre.eqx")
    physical = fj.unwrap(model)
    assert float(physical.model.sigma2) == 0.5 and 1e-4 < float(physical.model.stribeck.vs) < 1e-2
    assert "sigma2 = 0.5 [N s/m] (fixed)" in str(model) and "(bounded 0.0001 .. 0.01)" in str(model)
    report = json.loads((out / "report.json").read_text())
    assert report["settings"]["fix"] == [["sigma2", 0.5]]
