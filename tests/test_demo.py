"""`fricjax demo`: every physics model from pre-sliding into sliding, a summary, a figure and a JSON report."""

import json

import pytest

from fricjax import main


@pytest.mark.slow
def test_demo_writes_summary_and_figure(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    report = json.loads((tmp_path / "demo.json").read_text())
    names = [row["model"] for row in report["models"]]
    assert any("LuGre" in n for n in names) and any("GMS" in n for n in names)
    for row in report["models"]:
        if "static" not in row["model"]:
            # pre-sliding stiffness of every dynamic demo model is of the order of its total stiffness (1e5 N/m)
            assert 5e4 < row["presliding_stiffness_N_per_m"] < 2e5, row
        else:  # a static law has no pre-sliding spring (its slope in x was printed as one)
            assert row["presliding_stiffness_N_per_m"] is None, row
    assert (tmp_path / "demo_hysteresis.png").stat().st_size > 20_000
    assert "LuGre" in printed


def test_demo_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["demo", "--out", str(blocker / "sub")]) == 2
    assert "not writable" in capsys.readouterr().err
