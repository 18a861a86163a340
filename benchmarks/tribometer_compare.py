#!/usr/bin/env python
"""The README's results tables: `fricjax compare --data tribometer:REGIME` as a user runs it, for the three regimes
of the built-in synthetic tribometer (pre-sliding, mixed, sliding; seed 0, 8000 samples each).

Each regime is one `fricjax compare` in a subprocess (its defaults, or `--models ...`), with the compilation cache
as the user has it. Prints one JSON line per regime: the noise floor of the test part (the true model's own test
NMSE against the noisy force), every model's and ensemble's test NMSE [%] and validation NMSE, the best single
model chosen by **validation** (compare's table is sorted by test NMSE; this is the choice a user makes without the
test part), the PRESS ensemble (worden2007 §7: its members chosen on the validation part; the ensembles' own
validation NMSE is their fit, so it cannot choose among them), compare's wall time, machine and versions.

Run: `python benchmarks/tribometer_compare.py [--regimes presliding mixed sliding] [--models all]` (35-55 s
per regime with the default physics models on 2 cores, 2-3 minutes with `--models all`).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

from _environment import environment

REGIMES = ("presliding", "mixed", "sliding")


def run(regime: str, models: list[str] | None) -> dict:
    with tempfile.TemporaryDirectory() as scratch:
        out = pathlib.Path(scratch) / "compare"
        command = [sys.executable, "-m", "fricjax", "compare", "--data", f"tribometer:{regime}"]
        command += ["--models", *models] if models else []
        start = time.perf_counter()
        subprocess.run([*command, "--out", str(out), "--no-progress"], check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - start
        report = json.loads((out / "report.json").read_text())
    (test,) = report["test_records"]
    rows = {
        m["name"]: {
            "test_nmse_percent": round(m["test_scores"][test["name"]]["nmse"], 4),
            "validation_nmse_percent": None
            if m["validation_nmse_percent"] is None
            else round(m["validation_nmse_percent"], 4),
            "result": m["result"],
        }
        for m in report["models"]
    }
    singles = [n for n in rows if not n.startswith("ensemble") and rows[n]["validation_nmse_percent"] is not None]
    best = min(singles, key=lambda n: rows[n]["validation_nmse_percent"]) if singles else None
    press = rows.get("ensemble_press", {}).get("test_nmse_percent")
    floor = test["noise_floor_nmse_percent"]
    return {
        "benchmark": "tribometer_compare",
        "regime": regime,
        "models_option": models or "default",
        "test_samples": test["scored"][1] - test["scored"][0],
        "noise_floor_nmse_percent": round(floor, 4),
        "models": rows,
        "best_single_by_validation": best,
        "best_single_over_floor": None if best is None else round(rows[best]["test_nmse_percent"] / floor, 3),
        "press_ensemble_over_floor": None if press is None else round(press / floor, 3),
        "compare_wall_s": round(wall, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--regimes", nargs="+", choices=REGIMES, default=list(REGIMES))
    parser.add_argument("--models", nargs="+", default=None, help="compare's --models (default: its defaults)")
    args = parser.parse_args()
    for regime in args.regimes:
        print(json.dumps({**run(regime, args.models), **environment()}), flush=True)


if __name__ == "__main__":
    main()
