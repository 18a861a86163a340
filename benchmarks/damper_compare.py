#!/usr/bin/env python
"""The friction damper's characterisation tests through `fricjax compare` as a user runs it (the real device of
`shared/data/damper`, dataset-3: sinusoidal tests at 0.25-2 Hz and 0.5-1.5 in, band tension 30 lb).

Two protocols, each `fricjax compare` with its defaults in a subprocess:

- `several`: trained on the six 0.25 and 0.5 Hz tests together (one model, each record its own offset and initial
  state), run free on the 1 Hz tests (0.5, 1, 1.5 in) and the 2 Hz 0.5 in test;
- `single`: trained on the 1 Hz 1 in test alone, run free on the 0.25 Hz 1 in, 0.5 Hz 1.5 in and 2 Hz 0.5 in tests.

Prints one JSON line per protocol: every model's test NMSE [%] per test record (the first 10 % of each test record
initialises the model and is not scored), the mean over the records, the best model per record, compare's wall
time, machine and versions. The device's force drops to about zero for ~3 mm after each reversal (its linkage's
play): `lugre-backlash` (`fj.LuGreBacklash`) is the model of that; `--models` restricts the fit.

Run: `python benchmarks/damper_compare.py [--protocol several single] [--models ...] [--reversed]` (about 5 + 2
minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

import fricjax as fj
from _environment import environment

RECORD = "{}Hz30lbtension{}amplitude.npz"
PROTOCOLS = {
    "several": (
        [(f, a) for f in ("0.25", "0.5") for a in ("0.5", "1", "1.5")],
        [("1", "0.5"), ("1", "1"), ("1", "1.5"), ("2", "0.5")],
    ),
    "single": ([("1", "1")], [("0.25", "1"), ("0.5", "1.5"), ("2", "0.5")]),
}


def run(protocol: str, models: list[str] | None, reverse: bool = False) -> dict:
    folder = fj.data_folder("damper") / "dataset-3" / "characterization_tests"
    train, test = PROTOCOLS[protocol]
    # in file-name order, as a shell glob (`'char/0.25Hz*.npz'`) passes them, or reversed (`--reversed`): the starts
    # are read off each record on its own and pooled, so the order moves the fits by round-off only
    paths = sorted((str(folder / RECORD.format(*pair)) for pair in train), reverse=reverse)
    tests = sorted(str(folder / RECORD.format(*pair)) for pair in test)
    with tempfile.TemporaryDirectory() as scratch:
        out = pathlib.Path(scratch) / "compare"
        command = [sys.executable, "-m", "fricjax", "compare", "--data", *paths, "--test", *tests]
        command += ["--models", *models] if models else []
        start = time.perf_counter()
        subprocess.run([*command, "--out", str(out), "--no-progress"], check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - start
        report = json.loads((out / "report.json").read_text())
    names = [pathlib.Path(t).name for t in tests]
    scores = {
        m["name"]: [round(m["test_scores"][t]["nmse"], 4) for t in tests]
        for m in report["models"]
        if set(tests) <= set(m["test_scores"])
    }
    return {
        "benchmark": "damper_compare",
        "protocol": protocol,
        "training_order": "reversed file names" if reverse else "file names",
        "train": [pathlib.Path(p).name for p in paths],
        "test": names,
        "test_nmse_percent": scores,
        "mean_nmse_percent": {name: round(float(np.mean(values)), 4) for name, values in scores.items()},
        "best_per_record": [min(scores, key=lambda name: scores[name][i]) for i in range(len(tests))],
        "compare_wall_s": round(wall, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", nargs="+", choices=sorted(PROTOCOLS), default=["several", "single"])
    parser.add_argument("--models", nargs="+", default=None, help="compare's --models (default: its defaults)")
    parser.add_argument("--reversed", action="store_true", help="the training records in reversed file-name order")
    args = parser.parse_args()
    for protocol in args.protocol:
        print(json.dumps({**run(protocol, args.models, args.reversed), **environment()}), flush=True)


if __name__ == "__main__":
    main()
