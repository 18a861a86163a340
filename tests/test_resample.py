"""Records at different sample rates (issue 55, item 5): `fj.resample` and `fricjax compare --resample HZ`."""

from __future__ import annotations

import json

import numpy as np
import pytest

import fricjax as fj


def _sine_record(n: int, dt: float) -> fj.FrictionData:
    t = np.arange(n) * dt
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 3.0 * t), dt=dt)
    return fj.FrictionData(motion, np.tanh(np.cos(2 * np.pi * 3.0 * t) / 0.2))


def test_resampling_keeps_a_band_limited_record_and_its_time_axis():
    record = _sine_record(4000, 1e-3)  # 4 s at 1 kHz
    for rate, step in ((500.0, 2), (250.0, 4)):
        down = fj.resample(record, rate)
        assert float(down.motion.dt) == pytest.approx(1.0 / rate) and down.length == 4000 // step
        inner = slice(50, -50)  # the edges are extended linearly
        x = np.asarray(record.motion.x)[::step]
        assert np.max(np.abs(np.asarray(down.motion.x) - x)[inner]) < 1e-3 * 1e-3  # 0.1 % of the amplitude
    up = fj.resample(record, 1024.0)  # a rational ratio: 128 / 125
    assert float(up.motion.dt) == pytest.approx(1 / 1024) and up.length == 4096
    assert fj.resample(record, 1000.0) is record
    with pytest.raises(ValueError, match="positive sample rate"):
        fj.resample(record, -5.0)


@pytest.mark.slow  # two short compare runs (~15 s)
def test_compare_fits_records_of_different_rates_with_resample(tmp_path, capsys):
    paths = []
    for name, seed, step in (("a.csv", 0, 1), ("b.csv", 1, 2), ("c.csv", 2, 1)):
        data = fj.make_tribometer("mixed", seed=seed, duration=1.0).full
        t = np.arange(data.length) * float(data.motion.dt)
        table = np.c_[t, np.asarray(data.motion.samples().x), np.asarray(data.force)][::step]
        np.savetxt(tmp_path / name, table, delimiter=",", header="t,x,force", comments="")
        paths.append(str(tmp_path / name))
    argv = ["compare", "--data", *paths[:2], "--test", paths[2], "--models", "stribeck", "--steps", "3"]
    argv += ["--no-progress", "--out", str(tmp_path / "out")]
    assert fj.main(argv) == 2
    assert "--resample HZ resamples every record to one rate" in capsys.readouterr().err
    assert fj.main([*argv, "--resample", "1000"]) == 0
    printed = capsys.readouterr().out  # each test record's offset beside the table, in the records' unit
    assert "offsets on the test records [N] (on each one's initialisation window" in printed
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    (row,) = [m for m in report["models"] if m["name"] == "stribeck"]
    assert [r["record"] for r in row["training_records"]] == paths[:2] and list(row["test_scores"]) == paths[2:]
    cards = report["data_card"]  # one per training record
    assert cards[0].get("resampled_to_hz") == pytest.approx(1000.0, rel=1e-6), cards
