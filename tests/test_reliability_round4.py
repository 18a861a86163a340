"""Reliability, round 4 (issue 52): values no model can compute with, records named twice or weighted silently,
checks too strict or too loose, plausible records that raised tracebacks. The cache: tests/test_compilation_cache.py."""

import json

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj


@pytest.mark.parametrize(
    "build",
    [
        lambda value: fj.Backlash(fj.Coulomb(Fc=1.0), gap=value),
        lambda value: fj.NormalLoad(fj.Coulomb(Fc=1.0), reference=value),
    ],
    ids=["Backlash.gap", "NormalLoad.reference"],
)
def test_subnormal_divisors_are_refused_by_the_constructors(build):
    with pytest.raises(ValueError, match="too small to compute with"):
        build(1e-320)
    build(1e-6)  # small, normal: fine


@pytest.mark.parametrize("bad", [0.0, -5.0, 1e-320])
def test_load_model_refuses_a_reference_load_the_constructor_refuses(tmp_path, bad):
    model = fj.NormalLoad(fj.Coulomb(Fc=1.0), reference=100.0)
    edited = eqx.tree_at(lambda m: m.reference.value, model, jnp.asarray(bad))
    path = tmp_path / "normal_load.eqx"
    with pytest.warns(UserWarning, match="load_model will refuse"):
        fj.save_model(path, edited)
    with pytest.raises(ValueError, match="NormalLoad.*reference"):
        fj.load_model(path)
    fj.save_model(path, model)
    assert float(fj.load_model(path).reference.value) == 100.0


def test_load_model_refuses_a_subnormal_gap(tmp_path):
    model = fj.Backlash(fj.Coulomb(Fc=1.0), gap=1e-3)
    edited = eqx.tree_at(lambda m: m.gap.raw, model, jnp.asarray(-736.8))  # log(1e-320): a subnormal gap
    path = tmp_path / "backlash.eqx"
    with pytest.warns(UserWarning):
        fj.save_model(path, edited)
    with pytest.raises(ValueError, match="invalid Positive at `model.gap`"):
        fj.load_model(path)


# ---------------------------------------------------------------- the command line's records and output folder


def _record(path, *, samples=1500, amplitude=1e-3, force_scale=1.0, header=("t", "x", "force"), columns=None):
    """A small CSV record: a 2 Hz sine of `amplitude` [m] and a smooth Coulomb + viscous force [N]."""
    dt = 1e-3
    t = np.arange(samples) * dt
    x = amplitude * np.sin(2 * np.pi * 2.0 * t)
    v = np.gradient(x, dt)
    columns = columns or {}
    force = force_scale * (np.tanh(v / 1e-3) + 20.0 * v) + 0.01 * np.random.default_rng(0).standard_normal(samples)
    table = {"t": t, "x": x, "force": force, **columns}
    names = list(header) + [name for name in columns if name not in header]
    values = [table[name if name in table else name.split(" ")[0]] for name in names]
    np.savetxt(path, np.column_stack(values), delimiter=",", header=",".join(names), comments="")
    return path


RUN = ["compare", "--models", "stribeck", "--steps", "3", "--no-cache", "--no-progress"]


def test_an_empty_out_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert fj.main(["compare", "--out", ""]) == 2
    assert "--out: an empty name" in capsys.readouterr().err
    assert fj.main(["demo", "--out", " "]) == 2
    assert list(tmp_path.iterdir()) == []


def test_a_file_name_the_system_cannot_take_is_one_line(tmp_path, capsys):
    name = str(tmp_path / ("a" * 300 + ".csv"))
    assert fj.main([*RUN, "--data", name, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "not a usable file name" in err and "characters" in err and "Traceback" not in err


def _stops_at_a_missing_test(tmp_path, capsys, *args):
    """Run compare up to where it loads its test records (a missing one: exit 2 before any fit); its output."""
    code = fj.main([*RUN, *args, "--test", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "o")])
    captured = capsys.readouterr()
    assert code == 2 and "missing.csv: no such file" in captured.err, captured.err
    return captured.out


def test_a_record_named_twice_is_read_once(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _record(tmp_path / "A.csv")
    _record(tmp_path / "B.csv", amplitude=1.5e-3)
    printed = _stops_at_a_missing_test(tmp_path, capsys, "--data", "A.csv", "./A.csv", str(tmp_path / "A.csv"), "*.csv")
    assert printed.count("is A.csv again; each record is read once") == 3, printed


def test_an_existing_file_with_glob_characters_is_that_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _record(tmp_path / "run[1].csv")
    _stops_at_a_missing_test(tmp_path, capsys, "--data", "run[1].csv")
    assert fj.main([*RUN, "--data", "r[2].csv", "--out", str(tmp_path / "o")]) == 2  # no such file: a pattern
    assert "the pattern matches no file" in capsys.readouterr().err


def test_a_float32_sample_time_column_of_one_millisecond_is_one_sample_time(tmp_path, capsys):
    a = _record(tmp_path / "A.csv")  # t in float64
    dt32 = float(np.float32(1e-3))  # a dt column written from float32: 1e-3 + 4.7e-11
    b = _record(tmp_path / "B.csv", header=("dt", "x", "force"), columns={"dt": np.full(1500, dt32)})
    _stops_at_a_missing_test(tmp_path, capsys, "--data", str(a), str(b))


def test_records_with_declared_units_are_not_refused_as_a_unit_mistake(tmp_path, capsys):
    header = ("t [s]", "x [m]", "force [N]")
    light = _record(tmp_path / "light.csv", header=header)
    heavy = _record(tmp_path / "heavy.csv", header=header, force_scale=12.0)
    printed = _stops_at_a_missing_test(tmp_path, capsys, "--data", str(light), str(heavy))
    assert "every record declares its unit" in printed
    bare = [str(_record(tmp_path / f"{n}.csv", force_scale=f)) for n, f in (("a", 1.0), ("b", 12.0))]
    assert fj.main([*RUN, "--data", *bare, "--test", bare[0], "--out", str(tmp_path / "o")]) == 2
    assert "check the units" in capsys.readouterr().err


@pytest.mark.slow  # two compare runs
def test_a_users_own_files_in_out_are_kept_and_validation_records_trained_on_are_named(tmp_path, capsys):
    out = tmp_path / "o"
    (out / "models").mkdir(parents=True)
    (out / "report.json").write_text('{"mine": true}')
    (out / "models" / "stribeck.eqx").write_text("my model")
    a, b, c = (_record(tmp_path / f"{n}.csv", amplitude=k * 1e-3) for n, k in (("A", 1.0), ("B", 1.2), ("C", 0.8)))
    argv = [*RUN, "--data", str(a), str(b), "--validation", str(b), "--test", str(c), "--out", str(out)]
    assert fj.main(argv) == 0
    printed = capsys.readouterr().out
    assert "B.csv: a training record too; its validation score is not held out" in printed
    assert (out / "report.json.bak").read_text() == '{"mine": true}'
    assert (out / "models" / "stribeck.eqx.bak").read_text() == "my model"
    assert "your report.json is kept as report.json.bak" in printed
    assert fj.main(argv) == 0  # its own files: replaced, no new copy
    assert not (out / "report.json.bak2").exists() and not (out / "models" / "stribeck.eqx.bak2").exists()


# ---------------------------------------------------------------- stopping within seconds


@pytest.mark.slow  # two compare runs of a neural model
def test_compiled_steps_in_pieces_give_the_fit_of_whole_chunks(tmp_path, monkeypatch, capsys):
    """Under the command line a chunk of compiled steps (optax: the neural models) runs as pieces of about a second
    with a check for a signal between them; one step a piece must give the fit that chunks in one call give."""
    record = _record(tmp_path / "A.csv")
    reports = []
    for seconds in ("0", "1e9"):  # one step a piece; the whole chunk in one piece (after the first step)
        monkeypatch.setenv("FRICJAX_PIECE_SECONDS", seconds)
        out = tmp_path / f"o{seconds}"
        argv = ["compare", "--models", "mlp", "--neural-steps", "40", "--no-cache", "--no-progress", "--data"]
        assert fj.main([*argv, str(record), "--out", str(out)]) == 0, capsys.readouterr().err
        reports.append(json.loads((out / "report.json").read_text())["models"])
    (pieces,), (whole,) = reports
    assert pieces["parameters"] == whole["parameters"] and pieces["nmse_percent"] == whole["nmse_percent"]


@pytest.mark.slow  # three compare runs on a 40 000-sample record, signalled in compilation and in the fit
def test_a_signal_stops_a_long_fit_within_seconds(tmp_path):
    """Issue 52: SIGTERM during a Maxwell-slip DNLRX fit of a 74 000-sample record was acted on when that fit ended,
    minutes later. Now the loop checks between steps (and pieces of compiled steps), and a signal that one long
    compiled call keeps the run from acting on ends the process after `GRACE_S` (module _interrupts)."""
    import signal
    import subprocess
    import sys
    import time

    rng = np.random.default_rng(0)
    t = np.arange(40_000) / 3000.0
    x = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in np.arange(1, 21) * 0.2)
    x = 3e-3 * x / np.max(np.abs(x))
    v = np.gradient(x, t)
    force = 2.0 * np.tanh(v / 1e-3) + 30.0 * v + 0.02 * rng.standard_normal(t.size)
    record = tmp_path / "long.csv"
    np.savetxt(record, np.c_[t, x, force], delimiter=",", header="t,x,force", comments="")
    wrong = []
    for delay in (0.3, 4.0, 15.0):  # compiling the step; in the steps; later (a second start, or the scores)
        out = tmp_path / f"out{delay}"
        process = subprocess.Popen(
            [sys.executable, "-m", "fricjax", "compare", "--data", str(record), "--models", "dnlrx", "--steps", "400"]
            + ["--no-cache", "--no-progress", "--out", str(out)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert process.stdout is not None
        for line in process.stdout:
            if line.startswith("fitting"):
                break
        time.sleep(delay)
        sent = time.perf_counter()
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=600)
        waited = time.perf_counter() - sent
        if process.returncode != 130 or waited > 8.0 or out.exists() or "Traceback" in err:
            wrong.append(f"at {delay} s: exit {process.returncode} after {waited:.1f} s, out {out.exists()}: {err}")
    assert not wrong, "\n".join(wrong)


# ---------------------------------------------------------------- plausible records: one line, before any fit


def test_a_constant_force_record_is_one_line_before_any_fit(tmp_path, capsys):
    constant = tmp_path / "const.csv"
    t = np.arange(1500) * 1e-3
    np.savetxt(
        constant,
        np.c_[t, 1e-3 * np.sin(2 * np.pi * t), np.full(t.size, 0.5)],
        delimiter=",",
        header="t,x,force",
        comments="",
    )
    good = _record(tmp_path / "A.csv")
    for args in (["--data", str(constant)], ["--data", str(good), "--test", str(constant)]):
        assert fj.main([*RUN, *args, "--out", str(tmp_path / "o")]) == 2
        captured = capsys.readouterr()
        assert "const.csv: column 'force' holds one value (0.5 N) in every row" in captured.err
        assert "fitting" not in captured.out and "Traceback" not in captured.err


def test_a_test_record_at_rest_in_its_initialisation_window_names_the_options(tmp_path, capsys):
    path = _record(tmp_path / "rest.csv")
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    table[:300, 1:] = 0.0  # the sensor reads exactly 0 before the motion starts
    np.savetxt(path, table, delimiter=",", header="t,x,force", comments="")
    good = _record(tmp_path / "A.csv")
    args = [*RUN, "--data", str(good), "--test", str(path), "--init-window", "200", "--out", str(tmp_path / "o")]
    assert fj.main(args) == 2
    captured = capsys.readouterr()
    assert "rest.csv: the force is 0 N throughout its 200-sample initialisation window" in captured.err
    assert "--init-window" in captured.err and "--init offset" in captured.err and "fitting" not in captured.out


def test_normal_loads_of_zero_or_in_some_records_only_are_one_line(tmp_path, capsys):
    loaded = _record(tmp_path / "N.csv", columns={"normal_force": np.full(1500, 100.0)})
    zero = _record(tmp_path / "Z.csv", columns={"normal_force": np.zeros(1500)})
    bare = _record(tmp_path / "bare.csv")
    test = _record(tmp_path / "T.csv", columns={"normal_force": np.full(1500, 80.0)})
    cases = {
        ("--data", str(zero)): "Z.csv: its normal load is 0 N in every row",
        ("--data", str(loaded), str(bare), "--test", str(test)): "N.csv holds a normal load and",
        ("--data", str(bare), str(loaded), "--test", str(test)): "N.csv holds a normal load and",
        ("--data", str(loaded), "--test", str(zero)): "Z.csv: its normal load is 0 N",
    }
    for args, expected in cases.items():
        assert fj.main([*RUN, *args, "--out", str(tmp_path / "o")]) == 2, args
        captured = capsys.readouterr()
        assert expected in captured.err and "Traceback" not in captured.err, (args, captured.err)
        assert "fitting" not in captured.out


def test_fit_refuses_a_record_with_no_normal_load_for_a_load_scaled_model():
    t = np.arange(500) * 1e-3
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 2 * t), dt=1e-3)
    zero = fj.FrictionData(fj.Motion(x=motion.x, v=motion.v, dt=1e-3, normal_force=np.zeros(t.size)), np.sin(t))
    model = fj.NormalLoad(fj.Coulomb(Fc=0.5, smoothing=fj.Smooth(1e-3)), reference=100.0)
    with pytest.raises(ValueError, match="normal load of `data` is 0 N in every sample"):
        fj.fit(model, zero, steps=3)
    loaded = fj.FrictionData(fj.Motion(x=motion.x, v=motion.v, dt=1e-3, normal_force=np.full(t.size, 50.0)), np.sin(t))
    with pytest.raises(ValueError, match="normal load of record 1 of `data` is 0 N"):
        fj.fit(model, [loaded, zero], steps=3)
    with pytest.raises(ValueError, match="lacks the signal `normal_force`"):
        fj.concatenate([loaded, fj.FrictionData(motion, np.sin(t))])


@pytest.mark.parametrize("fmt", ["%.18e", "%.9g"])
@pytest.mark.parametrize("kind", ["summed", "rounded"])
def test_float32_time_stamps_are_a_uniform_sample_time(tmp_path, fmt, kind):
    steps = np.full(3000, 1e-3, np.float32)
    t = np.cumsum(steps) if kind == "summed" else (np.arange(3000) * 1e-3).astype(np.float32)
    x = 1e-3 * np.sin(2 * np.pi * 2 * np.arange(3000) * 1e-3)
    path = tmp_path / "f32.csv"
    np.savetxt(
        path,
        np.c_[t.astype(float), x, np.tanh(np.gradient(x) / 1e-6)],
        delimiter=",",
        header="t,x,force",
        comments="",
        fmt=fmt,
    )
    assert float(fj.load_record(path).motion.dt) == pytest.approx(1e-3, rel=2e-5)
    jittered = tmp_path / "jitter.csv"  # float64 stamps that are not uniform: still refused
    t64 = np.arange(3000) * 1e-3 + 2e-7 * np.random.default_rng(1).random(3000)
    np.savetxt(jittered, np.c_[t64, x, np.tanh(np.gradient(x) / 1e-6)], delimiter=",", header="t,x,force", comments="")
    with pytest.raises(ValueError, match="must be uniformly sampled"):
        fj.load_record(jittered)
