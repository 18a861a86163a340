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
