"""Local (nearest-neighbour) models on the built-in tribometer regimes: accuracy and the cost of the search.

parlitz2004 §III-F's local models on delay vectors of the displacement, and the extension recommended for
`fricjax compare` (play operators of the displacement and the velocity as coordinates, the sensor drift fitted),
each identified by `fj.identify_local_model` on the training part of `fj.compare.load_split("tribometer:REGIME")`
with the embedding dimension, delay and number of neighbours chosen on the validation part (free-run NMSE), then
scored on the test part with `fj.compare.score` (exact free run from the record's start, no offset window). This
script prints one JSON line per (regime, recipe):

- `best`: the chosen (embedding, delay, neighbours); `val_nmse_percent`, `test_nmse_percent`, `max_error`;
  `floor_percent`: the noise floor (the true model plus the sensor's drift, scored the same way) and `ratio` the
  test NMSE over it; `rate`: the fitted drift [N/s] (0 without drift);
- `identify_s`: the grid search (compilation included); `free_run_compile_s`: the first `fj.compare.score`
  call (compilation and one free run of the 8000-sample record); `free_run_s` and `us_per_step`: a second call
  (the free run alone: a neighbour search over the 4800 - burn-in training points per step);
- `loadavg_1min`: the machine's load when the line was written (timings on a shared machine vary with it).

Run: `python benchmarks/local.py [--regimes mixed presliding sliding] [--recipes paper_constant ...]`.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402

PAPER_GRID = dict(embedding=(2, 4, 8, 12, 16), delay=(1, 5, 10, 20))
EXTENSION_GRID = dict(signals=("x", "v"), embedding=(1, 2, 4), delay=(1, 10))
RECIPES: dict[str, dict[str, Any]] = {
    # parlitz2004's structure: delay vectors of the displacement alone
    "paper_constant": dict(PAPER_GRID, neighbours=(5, 10, 20, 50), kind="constant"),
    "paper_linear": dict(PAPER_GRID, neighbours=(20, 50, 100), kind="linear", rcond=1e-1),
    # the extension: displacement and velocity delay vectors plus 20 play states
    "plays_linear_drift": dict(EXTENSION_GRID, neighbours=(30, 100, 300), kind="linear", rcond=1e-2, drift=True),
    "plays_linear": dict(EXTENSION_GRID, neighbours=(30, 100, 300), kind="linear", rcond=1e-2),
    "plays_constant_drift": dict(EXTENSION_GRID, neighbours=(3, 10, 30), kind="constant", drift=True),
}


def play_thresholds(train: fj.FrictionData, count: int = 20) -> np.ndarray:
    """Play thresholds [m] log-spaced over 0.01-1 x the training record's largest excursion from its median."""
    x = np.asarray(train.motion.samples().x)
    return float(np.max(np.abs(x - np.median(x)))) * np.geomspace(0.01, 1.0, count)


def run(regime: str, recipe: str, env: dict[str, Any]) -> dict[str, Any]:
    split, _, _ = fj.compare.load_split(f"tribometer:{regime}")
    reference = fj.compare.load_record_spec(f"tribometer:{regime}").reference
    floor = fj.compare.reference_scores([split.test_record(init_window=0, reference=reference)])["test part"].nmse
    options = dict(RECIPES[recipe])
    if "signals" in options:  # the extension: play states as coordinates
        options["plays"] = play_thresholds(split.train)
    start = time.perf_counter()
    result = fj.identify_local_model(
        split.train, validation=split.until_validation_end, validation_burn_in=split.train_end, **options
    )
    identified = time.perf_counter()
    nmse, max_error, _ = fj.compare.score(result.model, split)
    compiled = time.perf_counter()
    fj.compare.score(result.model, split)
    done = time.perf_counter()
    best = np.unravel_index(int(np.argmin(result.scores)), result.scores.shape)
    return {
        "kind": "local_model",
        "regime": regime,
        "recipe": recipe,
        "best": list(result.best),
        "val_nmse_percent": round(float(np.min(result.scores)), 4),
        "test_nmse_percent": round(nmse, 4),
        "max_error": round(max_error, 4),
        "floor_percent": round(floor, 4),
        "ratio": round(nmse / floor, 2),
        "rate": round(float(result.rates[best]), 5),
        "identify_s": round(identified - start, 2),
        "free_run_compile_s": round(compiled - identified, 2),
        "free_run_s": round(done - compiled, 2),
        "us_per_step": round(1e6 * (done - compiled) / split.full.length, 1),
        "loadavg_1min": round(os.getloadavg()[0], 2),
        **env,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--regimes", nargs="*", default=["mixed", "presliding", "sliding"])
    parser.add_argument("--recipes", nargs="*", default=list(RECIPES), choices=list(RECIPES))
    args = parser.parse_args()
    env = environment(fricjax=fj.__version__)
    for regime in args.regimes:
        for recipe in args.recipes:
            print(json.dumps(run(regime, recipe, env)), flush=True)


if __name__ == "__main__":
    main()
