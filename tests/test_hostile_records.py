"""Hostile record files and requests: `t` and `dt` that disagree, bad sample times named by their column, quoted
numbers, `;` and tab separators, short errors naming the first bad line, memory within a small multiple of the
file's size, requests and files refused before they allocate more memory than there is, and forces of 1e200 N or
1e-200 N scored as the record in newtons (every loss and score scales before it squares: the metrics, the kernel
NARX and local-model scores, the Bouc-Wen loss, the stage's tracking NRMSE)."""

from __future__ import annotations

import builtins
import io
import os
import tracemalloc

import numpy as np
import pytest

import fricjax as fj

N = 150
K = np.arange(N)
X = 1e-3 * np.sin(K / 50)
F = np.sin(K / 50)


def table(header: str, rows: list[str], separator: str = ",") -> str:
    return header.replace(",", separator) + "\n" + "\n".join(rows) + "\n"


def rows(fmt: str = "{t:.6f},{x:.9f},{f:.6f}", dt: float = 1e-3) -> list[str]:
    return [fmt.format(t=k * dt, x=x, f=f, dt=dt) for k, x, f in zip(K, X, F, strict=True)]


def load(tmp_path, text: str, name: str = "record.csv") -> fj.FrictionData:
    path = tmp_path / name
    path.write_text(text)
    return fj.load_record(path)


def test_t_and_dt_columns_that_disagree_name_both(tmp_path):
    text = table("t,dt,x,force", rows("{t:.6f},0.002,{x:.9f},{f:.6f}"))  # t steps 1 ms, dt says 2 ms
    with pytest.raises(fj.RecordError, match=r"columns 't' and 'dt' disagree: 't' advances 0\.001 s .* 0\.002 s"):
        load(tmp_path, text)
    rounded = [f"{round(k * 7e-4, 3)},0.0007,{x},{f}" for k, x, f in zip(K, X, F, strict=True)]
    assert load(tmp_path, table("t,dt,x,force", rounded)).motion.dt == pytest.approx(7e-4)  # a rounded t agrees


@pytest.mark.parametrize("bad", ["0", "nan", "-0.001", "1e-320"])
def test_bad_sample_times_are_named(tmp_path, bad):
    with pytest.raises(fj.RecordError, match=r"column 'dt' holds .* in data row 1; the sample time must be"):
        load(tmp_path, table("dt,x,force", [f"{bad},{x},{f}" for x, f in zip(X, F, strict=True)]))
    constant_t = [f"0.5,{x},{f}" for x, f in zip(X, F, strict=True)]
    with pytest.raises(fj.RecordError, match=r"column 't' must increase"):
        load(tmp_path, table("t,x,force", constant_t))
    with pytest.raises(fj.RecordError, match=r"dt must be a positive finite sample time in seconds, got 5e-324"):
        fj.load_record(tmp_path / "record.csv", dt=5e-324)


def test_quoted_numbers_and_names(tmp_path):
    data = load(tmp_path, table('"t","x [mm]","force"', rows('"{t:.6f}","{x:.9f}", "{f:.6f}"')))
    assert data.length == N and data.motion.dt == pytest.approx(1e-3)
    np.testing.assert_allclose(np.asarray(data.motion.x), 1e-3 * np.round(X, 9), atol=1e-15)
    np.testing.assert_allclose(np.asarray(data.force), np.round(F, 6))


@pytest.mark.parametrize("separator", [";", "\t"])
def test_semicolon_and_tab_files_are_recognised(tmp_path, separator):
    plain = load(tmp_path, table("t,x,force", rows()), "plain.csv")
    fmt = separator.join(["{t:.6f}", "{x:.9f}", "{f:.6f}"])
    other = load(tmp_path, table("t,x,force", rows(fmt), separator))
    np.testing.assert_array_equal(np.asarray(other.force), np.asarray(plain.force))
    decimal_comma = [line.replace(".", ",") for line in rows(fmt)]  # a European spreadsheet's export
    other = load(tmp_path, table("t,x,force", decimal_comma, separator))
    np.testing.assert_array_equal(np.asarray(other.force), np.asarray(plain.force))


def test_errors_are_short_and_name_the_first_bad_line(tmp_path):
    ragged = rows()
    ragged[40] += ",1.0,2.0"
    ragged[90] += "," + ",".join(["9.9"] * 5000)  # a 40 000-character line later on
    with pytest.raises(fj.RecordError) as caught:
        load(tmp_path, table("t,x,force", ragged))
    message = str(caught.value)
    assert len(message) < 300 and "line 42 has 5 fields where the header names 3 columns" in message, message
    text = rows()
    text[7] = text[7].replace(text[7].split(",")[2], "n/a")
    with pytest.raises(fj.RecordError, match=r"line 9: column 'force' holds 'n/a', not a number"):
        load(tmp_path, table("t,x,force", text))
    # a column that is not used may hold text (a date, a comment)
    dated = [f"2024-01-01 10:00,{line}" for line in rows()]
    assert load(tmp_path, table("date,t,x,force", dated)).length == N


def test_memory_is_a_small_multiple_of_the_file_size(tmp_path):
    """A 100 000-row CSV: the peak of the Python / NumPy allocations while loading is below 3x the file's size
    (17x before, with genfromtxt over a list of strings; a 1M-row file: 1.3x, peak resident memory 1.7x)."""
    n = 100_000
    k = np.arange(n)
    columns = zip(k * 1e-3, 1e-3 * np.sin(k / 50), np.sin(k / 50), strict=True)
    lines = "\n".join(f"{a:.6f},{b:.9e},{c:.6f}" for a, b, c in columns)
    path = tmp_path / "long.csv"
    path.write_text("t,x,force\n" + lines + "\n")
    tracemalloc.start()
    try:
        data = fj.load_record(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert data.length == n
    assert peak < 3 * path.stat().st_size, (peak, path.stat().st_size)


def test_requests_beyond_the_memory_are_refused_before_allocating():
    for duration in (1e9, 1e6):  # 2e12 and 2e9 samples: 800 TB and 800 GB
        with pytest.raises(ValueError, match=r"`duration` .* samples, which need about .* of memory, more than"):
            fj.make_tribometer("mixed", duration=duration)


@pytest.mark.parametrize("source", ["MemAvailable", "sysconf"])
def test_a_table_too_big_for_the_memory_is_refused_before_reading(tmp_path, monkeypatch, capsys, source):
    """The memory available (Linux's MemAvailable, else the free pages) made small: a 1000-row file's table does
    not fit, and it is refused by size before any row is parsed (its bad row 500 is not reached), in one line from
    the command too. The same file with the memory there is read as far as that row."""
    lines = rows()[:-1] * 7  # 1043 rows
    lines[500] = "0.5,abc,1.0"
    path = tmp_path / "big.csv"
    path.write_text(table("t,x,force", lines))
    with pytest.raises(fj.RecordError, match=r"line 502"):
        fj.load_record(path)
    opened = builtins.open

    def small_meminfo(file, *args, **kwargs):
        if str(file) == "/proc/meminfo":  # 10 kB, or none said (then the free pages decide: 2 x 4 kB)
            return io.BytesIO(b"MemTotal: 1000 kB\n" + (b"MemAvailable: 10 kB\n" if source == "MemAvailable" else b""))
        return opened(file, *args, **kwargs)

    sysconf = os.sysconf
    pages = {"SC_AVPHYS_PAGES": 2, "SC_PAGE_SIZE": 4096}
    monkeypatch.setattr(builtins, "open", small_meminfo)
    monkeypatch.setattr(os, "sysconf", lambda name: pages[name] if name in pages else sysconf(name))
    available = "10.2 kB" if source == "MemAvailable" else "8.19 kB"
    message = rf"big.csv: its 1045 lines need about 50.2 kB of memory, more than the {available} available; split"
    with pytest.raises(fj.RecordError, match=message):
        fj.load_record(path)
    assert fj.main(["compare", "--data", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "more than the" in err and "Traceback" not in err, err


def extreme_record(scale: float) -> tuple[fj.Motion, np.ndarray]:
    motion = fj.Motion.from_position(X, 1e-3)
    clean = np.asarray(fj.simulate(fj.Coulomb(Fc=1.0, smoothing=fj.Smooth(1e-4)), motion))
    return motion, scale * (clean + 0.01 * np.sin(K))


@pytest.mark.parametrize("scale", [1e200, 1e-200])
def test_huge_and_tiny_forces_score_as_the_record_in_newtons(scale):
    """Forces of 1e200 N overflowed the variance (a loss of 0.0, "perfect"); 1e-200 N underflowed it."""
    motion, force = extreme_record(1.0)
    start = fj.Coulomb(Fc=0.5, smoothing=fj.Smooth(1e-4))
    scaled_start = fj.Coulomb(Fc=0.5 * scale, offset=0.0, smoothing=fj.Smooth(1e-4))
    loss = fj.SimulationLoss()  # every loss normalises by the same scaled standard deviation
    reference = float(loss(start, None, fj.FrictionData(motion, force)))
    value = float(loss(scaled_start, None, fj.FrictionData(motion, scale * force)))
    assert reference > 0.01 and value == pytest.approx(reference, rel=1e-9)
    prediction = np.asarray(fj.simulate(start, motion))
    for metric in (fj.nmse, fj.nrmse, fj.max_error, fj.relative_error, fj.fit_percent):
        expected = float(metric(force, prediction))
        assert float(metric(scale * force, scale * prediction)) == pytest.approx(expected, rel=1e-9), metric.__name__
    assert float(fj.rmse(scale * force, scale * prediction)) == pytest.approx(scale * float(fj.rmse(force, prediction)))


@pytest.mark.slow  # a fit's compilation: 2-3 s
def test_fits_of_huge_and_tiny_forces_report_the_same_loss():
    motion, force = extreme_record(1.0)
    losses = []
    for scale in (1.0, 1e200, 1e-200):  # Fc in log space, the offset fixed: the same steps at any scale
        start = fj.Coulomb(Fc=0.5 * scale, offset=fj.Fixed(0.0), smoothing=fj.Smooth(1e-4))
        losses.append(fj.fit(start, fj.FrictionData(motion, scale * force), steps=5).train_loss)
    assert losses[0] > 0.01 and losses[1:] == pytest.approx([losses[0]] * 2, rel=1e-9), losses


@pytest.mark.parametrize("scale", [1e150, 1e-150, 1e200, 1e-200])
def test_kernel_narx_scores_huge_and_tiny_forces_as_in_newtons(scale):
    """Its regressors' force scale (`np.std`) was inf at 1e200 N ("`output_scale` must be finite") and its scores
    NaN at 1e-200 N (squares below the smallest float)."""
    motion, force = extreme_record(1.0)
    options = {"input_lags": 2, "output_lags": 1, "degree": [1, 2], "ridge": 0.1, "validation_burn_in": 75}
    results = []
    for factor in (1.0, scale):
        data = fj.FrictionData(motion, factor * force)
        results.append(fj.identify_kernel_narx(data, validation=data, **options))
    unit, scaled = results
    assert 0 < unit.train_nmse < 100 and np.isfinite(unit.validation_nmse)
    assert scaled.train_nmse == pytest.approx(unit.train_nmse, rel=1e-5)  # the ridge solve amplifies round-off
    assert scaled.validation_nmse == pytest.approx(unit.validation_nmse, rel=1e-5)
    for score in ("one_step_nmse", "free_run_nmse"):  # every candidate's
        values = [[getattr(candidate, score) for candidate in r.candidates] for r in results]
        assert np.all(np.isfinite(values[0])) and values[1] == pytest.approx(values[0], rel=1e-5), (score, values)


@pytest.mark.parametrize("scale", [1e150, 1e-150, 1e200, 1e-200])
def test_local_models_score_huge_and_tiny_forces_as_in_newtons(scale):
    motion, force = extreme_record(1.0)
    grid = {"embedding": (2,), "delay": (1, 2), "neighbours": (3, 5), "validation_burn_in": 75}
    scores = []
    for factor in (1.0, scale):
        data = fj.FrictionData(motion, factor * force)
        scores.append(np.asarray(fj.identify_local_model(data, validation=data, **grid).scores))
    assert np.all(np.isfinite(scores[0]) & (scores[0] > 0)) and scores[0].min() < 100, scores[0]
    np.testing.assert_allclose(scores[1], scores[0], rtol=1e-9)


@pytest.mark.parametrize("scale", [1e150, 1e200, 1e-150, 1e-200])
def test_tracking_nrmse_of_huge_and_tiny_signals(scale):
    reference = np.sin(K / 20)
    error = 0.01 * np.cos(K / 7)
    expected = fj.tracking_nrmse(error, reference)
    assert 0.5 < expected < 1.5 and fj.tracking_nrmse(scale * error, scale * reference) == pytest.approx(expected)


@pytest.mark.parametrize("scale", [1e150, 1e-150])
def test_boucwen_loss_and_rmse_of_huge_and_tiny_records(scale):
    """Force and displacement scaled by `scale` (the system too: `beta / scale`, so that its output scales with its
    input; at 1e200 its state's squares would overflow in the system itself): the same loss, `scale` times the
    RMSE. At 1e-150 the displacements' squares fell below the smallest normal float and the loss was inf."""
    true = fj.unwrap(fj.BoucWen.benchmark())
    parameters = {name: float(getattr(true, name)) for name in ("m", "c", "k", "alpha", "beta", "gamma", "delta")}
    u = 50.0 * np.sin(2 * np.pi * 13 * K * fj.BOUCWEN_DT) + 20.0 * np.sin(2 * np.pi * 41 * K * fj.BOUCWEN_DT)
    y = np.asarray(fj.simulate(fj.BoucWen(**parameters, substeps=2), fj.boucwen_inputs(u, fj.BOUCWEN_DT)))
    values = []
    for factor in (1.0, scale):
        changed = {"k": 0.8 * parameters["k"], "beta": parameters["beta"] / factor}  # a start off the true system
        system = fj.BoucWen(**{**parameters, **changed}, substeps=2)
        record = fj.BoucWenRecord(factor * u, factor * y, fj.BOUCWEN_DT, "test", "synthetic")
        loss = float(fj.boucwen.BoucWenLoss(burn_in=10)(system, None, record))
        values.append((loss, fj.boucwen.boucwen_rmse(system, record)[0] / factor))
    assert values[0][0] > 1e-4 and values[1] == pytest.approx(values[0], rel=1e-6), values


@pytest.mark.parametrize("scale", [1e200, 1e-200])
def test_velocity_check_of_huge_and_tiny_records(tmp_path, scale):
    """The load's velocity check squared raw displacements: at 1e200 m a matching velocity column was refused as
    disagreeing (an RMS of inf / inf), at 1e-200 m one 10x too large passed (an RMS of 0)."""
    dt = 1e-3
    v = 1e-3 / 50 / dt * np.cos(K / 50)

    def csv(factor: float) -> str:
        body = [
            f"{k * dt:.6f},{scale * x:.17g},{factor * scale * w:.17g},{f:.17g}"
            for k, x, w, f in zip(K, X, v, F, strict=True)
        ]
        return table("t,x,v,F", body)

    record = load(tmp_path, csv(1.0), "matching.csv")
    assert np.allclose(np.asarray(record.motion.v), scale * v)
    with pytest.raises(fj.RecordError, match="disagrees"):
        load(tmp_path, csv(10.0), "ten-times.csv")


@pytest.mark.parametrize("scale", [1e200, 1e-200])
def test_normalise_huge_and_tiny_signals(scale):
    """`fj.normalise` divided by `np.std`: inf at 1e200 (every value normalised to 0), 0 at 1e-200 (refused as
    constant)."""
    z, normaliser = fj.normalise(scale * F)
    assert np.std(z) == pytest.approx(1.0, rel=1e-12)
    assert np.allclose(normaliser.inverse(z), scale * F, rtol=1e-12, atol=0.0)
