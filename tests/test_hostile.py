"""Hostile input: malformed records give one clear line (exit 2 on the command line) and change nothing in --out."""

from __future__ import annotations

import subprocess
import sys

import jax
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


@pytest.mark.slow  # the fast tier stays under 5 minutes
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


def test_wrong_parameter_shape_and_fixed_parameters():
    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3)
    with pytest.raises(ValueError, match="`sigma0` must be one number"):
        fj.LuGre(stribeck, sigma0=[1e5, 2e5], sigma1=300.0, sigma2=0.4)
    motion = fj.Motion.from_position(1e-4 * np.sin(np.linspace(0, 6, 100)), dt=1e-3)
    free = fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=0.4, offset=0.1)
    fixed = fj.LuGre(stribeck, sigma0=fj.Fixed(1e5), sigma1=fj.Fixed(300.0), sigma2=0.4, offset=fj.Fixed(0.1))
    np.testing.assert_array_equal(fj.simulate(fixed, motion), fj.simulate(free, motion))

    def trained(model):
        return sum(bool(leaf) for leaf in jax.tree_util.tree_leaves(fj.trainable_filter(model)))

    assert trained(free) - trained(fixed) == 3
    static = fj.CoulombViscous(Fc=fj.Fixed(1.0), Fv=fj.Fixed(20.0))
    assert trained(static) == 1  # the offset


def test_emps_command_on_wrong_files_is_one_line(tmp_path, monkeypatch, capsys):
    (tmp_path / "emps").mkdir()
    for name in ("DATA_EMPS.mat", "DATA_EMPS_PULSES.mat"):
        (tmp_path / "emps" / name).write_text("not a MATLAB file")
    monkeypatch.setenv("FRICJAX_DATA", str(tmp_path))
    assert fj.main(["compare", "--data", "emps", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "MATLAB" in err, err


@pytest.mark.slow  # about 6 s (a compare subprocess)
def test_sigterm_stops_compare_quietly(tmp_path):
    out = tmp_path / "out"
    code = f"import fricjax as fj, sys; sys.exit(fj.main(['compare', '--out', {str(out)!r}, '--no-progress']))"
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in process.stdout:  # wait until the fits have started
            if line.startswith("fitting"):
                break
        process.terminate()
        _, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 130, err
    assert err.strip().splitlines() == [f"fricjax compare: interrupted; nothing was written to {out}"]
    assert not out.exists()  # the run created the folder and, ending with nothing in it, removed it again


def test_model_names_are_case_insensitive_and_long_labels_keep_the_table_aligned(tmp_path, capsys):
    assert fj.main(["compare", "--models", "GMS", "LuGre", "--data", str(tmp_path / "missing.csv")]) == 2
    assert "no such file" in capsys.readouterr().err  # the names were accepted; the data is what is missing
    rows = [
        fj.compare.ModelScore("a", "x" * 60, 1.0, 0.5, 1.0, 3, "max_steps", None, np.zeros(1)),
        fj.compare.ModelScore("b", "short", 0.5, 0.2, 1.0, 4, "successful", None, np.zeros(1)),
    ]
    lines = fj.compare.format_table(rows).splitlines()[:3]  # the header and the rows (a legend follows)
    # two columns mark the validation part's choice ("* "), then the longest label whole
    assert all(line[62] == " " for line in lines)
    assert [line[63:69].strip() for line in lines] == ["params", "4", "3"]  # and the next one stays aligned
    assert lines[1][:62].rstrip() == "  short" and lines[2][:62] == "  " + "x" * 60  # sorted by NMSE, labels whole
    assert "MAX/std" in lines[0]


def test_string_parameters_are_refused_by_name():
    with pytest.raises(TypeError, match="`Fc` must be a number"):
        fj.ExponentialStribeck(Fc="1.0", Fs=1.5, vs=1e-3)
    with pytest.raises(TypeError, match="`offset` must be a number"):
        fj.Coulomb(Fc=1.0, offset="0.1")


def test_tribometer_option_errors_name_the_option(capsys, tmp_path):
    assert fj.main(["compare", "--data", "tribometer:mixed:speed=3", "--out", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "'speed=3'" in err and "{item" not in err and len(err.splitlines()) == 1, err


@pytest.mark.slow  # the EMPS table's fits: about 13 s
def test_emps_report_has_the_mode_of_the_other_outputs(data_dir, tmp_path, monkeypatch):
    """`--data emps` wrote report.json with mode 0600 (tempfile.mkstemp's) where every other output is 0666 less the
    umask (0644)."""
    import os
    import stat

    monkeypatch.setenv("FRICJAX_DATA", str(data_dir))
    umask = os.umask(0o022)
    os.umask(umask)
    assert fj.main(["compare", "--data", "emps", "--out", str(tmp_path)]) == 0
    assert stat.S_IMODE((tmp_path / "report.json").stat().st_mode) == 0o666 & ~umask
