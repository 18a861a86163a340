"""Hostile input: malformed records give one clear line (exit 2 on the command line) and change nothing in --out."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import fricjax as fj

GOOD_ROWS = "\n".join(f"{k * 1e-3:.6f},{1e-3 * np.sin(k / 50):.9f},{np.sin(k / 50):.6f}" for k in range(150))


def _write(path, text, encoding="utf-8"):
    path.write_text(text, encoding=encoding)
    return path


@pytest.mark.parametrize(
    "name, text, match",
    [
        ("empty.csv", "", "empty"),
        ("header_only.csv", "t,x,force\n", "no data rows"),
        ("varying_dt.csv", "dt,x,force\n" + "\n".join(f"{1e-3 * (1 + k % 2)},{k},{k}" for k in range(150)), "'dt'"),
        ("rounded_t.csv", "t,x,force\n" + "\n".join(f"{round(k * 0.0007, 3)},{k},{k}" for k in range(150)), "'dt'"),
        ("no_force.csv", "t,x,F_measured\n" + GOOD_ROWS, "missing column 'force'"),
    ],
)
def test_malformed_records_one_line_and_nothing_changed(tmp_path, capsys, name, text, match):
    path = _write(tmp_path / name, text)
    with pytest.raises(fj.RecordError, match=match):
        fj.load_record(path)
    out = tmp_path / "out"
    (out / "models").mkdir(parents=True)
    mine = {out / "report.json": "{}", out / "models" / "mine.eqx": "keep"}
    for file, content in mine.items():
        file.write_text(content)
    assert fj.main(["compare", "--data", str(path), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match.strip("'") in err, err
    assert all(file.read_text() == content for file, content in mine.items())
    assert sorted(p.name for p in out.rglob("*")) == ["mine.eqx", "models", "report.json"]


def test_byte_order_mark_header_is_read(tmp_path):
    path = _write(tmp_path / "excel.csv", "t,x,force\n" + GOOD_ROWS, encoding="utf-8-sig")
    record = fj.load_record(path)
    assert record.length == 150 and float(record.motion.dt) == pytest.approx(1e-3)


def test_constant_force_is_named_not_called_divergence():
    motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6, 200)), dt=1e-3)
    data = fj.FrictionData(motion, np.full(200, 2.0))
    with pytest.raises(ValueError, match="constant"):
        fj.fit(fj.Coulomb(Fc=1.0), data, steps=1)


def test_float64_data_with_x64_off_warns_once():
    code = (
        "import warnings, numpy as np, fricjax as fj\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    fj.Motion(x=np.zeros(10)); fj.Motion(x=np.zeros(10))\n"
        "print(sum('x64' in str(w.message) for w in caught))\n"
    )
    printed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert printed.strip() == "1"
