"""Kernel (RKHS) Volterra and NARX models: solver scaling, the kernel-method paper's Table 1, and compare's recipe.

Three parts (`--part`), each a few minutes on 2 cores, one JSON line per run (append them to
`benchmarks/results/kernel.jsonl`):

- `scaling`: `fj.identify_kernel_narx` on training records of 2 500 / 5 000 / 10 000 / 20 000 / 40 000 samples of
  the mixed tribometer regime (2 kHz, seed 0, the record lengthened so that its first 60 % holds that many
  samples; the test part is its last 20 %), with the direct solver (where the N x N matrix and its Cholesky
  factor fit jaxlib's CPU LAPACK: up to 10 000 here; 15 500 is its limit, above which the Cholesky segfaults),
  matrix-free conjugate gradients (Nyström preconditioner, 1 000 landmarks) and
  Nyström (1 000 landmarks as centres). Fixed hyperparameters (no grid): the recipe's structure, an exponential
  kernel (width 30, ridge 1e-3) on the velocity and 20 play operators, no fed-back force, so the free run equals
  the one-step prediction and the test part is predicted by one blocked kernel matvec. Fields: `fit_s` (the
  identification, compilation included), `peak_rss_mb` (the peak resident memory of the process that ran the
  case alone: `resource.getrusage(RUSAGE_SELF).ru_maxrss`, so XLA's buffers are counted, and the JAX runtime's
  baseline too, `baseline_rss_mb`), `cg_steps`, `train_nmse_percent` (one-step), `test_nmse_percent` (compare's
  scoring: the test part, offset from its first 10 %).
- `table1`: the paper's Table 1 pattern on the three built-in regimes (`fj.compare.load_split`, 4 800 training
  samples): finite VS (polynomial kernel, memory M = 24), infinite VS (exponential kernel), finite NARX
  (polynomial, M = 11 and 1-3 past forces), infinite NARX (exponential), each with hyperparameters (degree or
  width, ridge, N_AR) chosen on the validation part by free-run NMSE; Nyström with 1 000 landmarks (the paper
  instead downsampled its records by 5 to keep N x N small). Test NMSE by compare's scoring, beside the paper's.
- `recipe`: the extension recommended for `compare`: the velocity and 20 play operators of the displacement
  (thresholds 0.03-3 x the breakaway displacement, as compare's networks), exponential kernel, Nyström with 1 000
  landmarks of the 4 800 training rows (`--solver direct` for all of them), width {10, 30, 100} x ridge {1e-4,
  1e-3, 1e-2, 1e-1} x N_AR {0, 1} chosen by validation free-run NMSE; all three regimes, with the noise floor.

Run: `python benchmarks/kernel.py --part scaling|table1|recipe [--sizes ...]`; `--smoke` runs a tiny size of
each part in well under a minute (for CI).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import lineax  # noqa: E402
import numpy as np  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402

REGIMES = ("presliding", "mixed", "sliding")
# the kernel-method paper's Table 1 (NMSE %, low / medium / high excitation = pre-sliding / mixed / sliding)
PAPER_TABLE1 = {
    "finite_vs": (14.09, 18.71, 18.25),
    "infinite_vs": (14.13, 20.67, 18.40),
    "finite_narx": (0.68, 1.49, 1.76),
    "infinite_narx": (9.41, 1.70, 2.95),
}
RIDGES = (1e-6, 1e-4, 1e-2, 1.0)
RECIPE_RIDGES = (1e-4, 1e-3, 1e-2, 1e-1)


def env() -> dict[str, Any]:
    return environment(lineax=lineax.__version__, fricjax=fj.__version__)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def plays_for(train: fj.FrictionData, count: int = 20) -> np.ndarray:
    """compare's play thresholds [m]: the breakaway displacement x geomspace(0.03, 3, count)."""
    return fj.compare.DataScales.from_data(train).breakaway * np.geomspace(0.03, 3.0, count)


def compare_nmse(prediction: np.ndarray, test: Any) -> float:
    return float(fj.compare.score_prediction(prediction, test)[0].nmse)


# ----------------------------------------------------------------------------------------------------------------
# scaling
# ----------------------------------------------------------------------------------------------------------------


def scaling_case(size: int, solver: str, landmarks: int) -> dict[str, Any]:
    """One scaling case, run in a fresh process (its peak memory is its own)."""
    baseline = peak_rss_mb()
    full = fj.make_tribometer("mixed", seed=0, duration=size / (0.6 * 2000.0)).full
    split = fj.compare.Split.fractions(full, 0.6, 0.8)
    train = split.train
    plays = plays_for(train)
    tic = time.perf_counter()
    result = fj.identify_kernel_narx(
        train,
        signals=("v",),
        plays=plays,
        input_lags=0,
        output_lags=0,
        kernel="exponential",
        width=30.0,
        ridge=1e-3,
        solver=solver,
        landmarks=None if solver == "direct" else landmarks,
    )
    jax.block_until_ready(result.model.alpha)
    fit_s = time.perf_counter() - tic
    # no fed-back force: the free run is the one-step prediction, b + K(rows, centres) alpha, here in blocks
    model = fj.unwrap(result.model)
    regressors = model.regressors
    test = split.test_record()
    states = fj.simulate(regressors.play_operators, full.motion)  # the play states: a recursion, run by simulate
    rows = regressors.teacher_forced(full.motion.samples(regressors.requires), full.force, states)[test.start :]
    block = max(1, 2**22 // model.num_centres)
    pieces = [model.kernel.gram(rows[i : i + block], model.centres) @ model.alpha for i in range(0, len(rows), block)]
    prediction = np.zeros(full.length)
    prediction[test.start :] = np.asarray(regressors.denormalise(model.b + jnp.concatenate(pieces)))
    return {
        "kind": "scaling",
        "solver": solver,
        "samples": train.length,
        "landmarks": None if solver == "direct" else landmarks,
        "centres": result.model.num_centres,
        "fit_s": round(fit_s, 2),
        "peak_rss_mb": round(peak_rss_mb(), 1),
        "baseline_rss_mb": round(baseline, 1),
        "cg_steps": result.solver_steps,
        "train_nmse_percent": round(result.train_nmse, 4),
        "test_nmse_percent": round(compare_nmse(prediction, test), 4),
        **env(),
    }


def run_scaling(sizes: list[int], direct_max: int, landmarks: int) -> None:
    for size in sizes:
        for solver in ("direct", "cg", "nystrom"):
            if solver == "direct" and size > direct_max:
                continue
            command = [sys.executable, __file__, "--case", str(size), solver, "--landmarks", str(landmarks)]
            done = subprocess.run(command, capture_output=True, text=True)
            if done.returncode != 0:
                error = done.stderr.strip()[-400:] or f"exit status {done.returncode}"
                line = {"kind": "scaling", "solver": solver, "samples": size, "error": error}
                print(json.dumps(line), flush=True)
            else:
                print(done.stdout.strip().splitlines()[-1], flush=True)


# ----------------------------------------------------------------------------------------------------------------
# Table 1 and the recipe
# ----------------------------------------------------------------------------------------------------------------


def table1_grid(name: str, smoke: bool) -> dict[str, Any]:
    ridges = RIDGES[1:3] if smoke else RIDGES
    if name == "finite_vs":
        return dict(input_lags=23, output_lags=0, kernel="polynomial", degree=[2, 3], ridge=ridges)
    if name == "infinite_vs":
        return dict(input_lags=23, output_lags=0, kernel="exponential", width=[3.0, 10.0, 30.0], ridge=ridges)
    lags = [1] if smoke else [1, 2, 3]
    if name == "finite_narx":
        return dict(input_lags=10, output_lags=lags, kernel="polynomial", degree=[2, 3], ridge=ridges)
    return dict(input_lags=10, output_lags=lags, kernel="exponential", width=[1.5, 3.0, 10.0], ridge=ridges)


def load(regime: str, smoke: bool) -> tuple[Any, Any, float]:
    loaded = fj.compare.load_record_spec(f"tribometer:{regime}")
    split = fj.compare.split_record(loaded)
    if smoke:  # a short record: the first second, split 60 / 20 / 20
        split = fj.compare.Split.fractions(split.full.slice(0, 2000), 0.6, 0.8)
        loaded_ref = np.asarray(loaded.reference)[:2000]
    else:
        loaded_ref = np.asarray(loaded.reference)
    test = split.test_record(reference=loaded_ref)
    floor = fj.compare.reference_scores([test])[test.name].nmse
    return split, test, floor


def identify_and_score(kind: str, regime: str, split: Any, test: Any, floor: float, **options: Any) -> dict[str, Any]:
    tic = time.perf_counter()
    result = fj.identify_kernel_narx(
        split.train, validation=split.until_validation_end, validation_burn_in=split.train_end, **options
    )
    fit_s = time.perf_counter() - tic
    chosen = next(c for c in result.candidates if c.free_run_nmse == result.validation_nmse)
    nmse = compare_nmse(fj.compare.free_run(result.model, split.full), test)
    return {
        "kind": kind,
        "regime": regime,
        "solver": options.get("solver", "direct"),
        "candidates": len(result.candidates),
        "M": chosen.input_lags + 1,
        "N_AR": chosen.output_lags,
        "degree": chosen.degree,
        "width": chosen.width,
        "ridge": chosen.ridge,
        "fit_s": round(fit_s, 2),
        "validation_nmse_percent": round(result.validation_nmse, 4),
        "test_nmse_percent": round(nmse, 4),
        "floor_nmse_percent": round(floor, 4),
        "times_floor": round(nmse / floor, 2),
    }


def run_table1(regimes: list[str], smoke: bool, landmarks: int) -> None:
    for regime in regimes:
        split, test, floor = load(regime, smoke)
        for name in ("infinite_vs", "finite_narx") if smoke else PAPER_TABLE1:
            options = dict(signals=("x",), solver="nystrom", landmarks=landmarks, **table1_grid(name, smoke))
            line = identify_and_score("table1", regime, split, test, floor, **options)
            line["model"] = name
            line["paper_nmse_percent"] = PAPER_TABLE1[name][REGIMES.index(regime)]
            print(json.dumps({**line, **env()}), flush=True)


def run_recipe(regimes: list[str], smoke: bool, solver: str, landmarks: int) -> None:
    for regime in regimes:
        split, test, floor = load(regime, smoke)
        options = dict(
            signals=("v",),
            plays=plays_for(split.train),
            input_lags=0,
            output_lags=[0] if smoke else [0, 1],
            kernel="exponential",
            width=[30.0] if smoke else [10.0, 30.0, 100.0],
            ridge=RECIPE_RIDGES[1:3] if smoke else RECIPE_RIDGES,
            solver=solver,
            landmarks=None if solver == "direct" else min(landmarks, split.train_end),
        )
        line = identify_and_score("recipe", regime, split, test, floor, **options)
        line["landmarks"] = options["landmarks"]
        line["model"] = "exponential kernel on v + 20 plays"
        print(json.dumps({**line, **env()}), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("scaling", "table1", "recipe"), default="recipe")
    parser.add_argument("--sizes", type=int, nargs="*", default=[2500, 5000, 10000, 20000, 40000])
    parser.add_argument("--direct-max", type=int, default=10000, help="largest record for the direct solver")
    parser.add_argument("--landmarks", type=int, default=1000)
    parser.add_argument("--solver", choices=("direct", "cg", "nystrom"), default="nystrom", help="recipe's solver")
    parser.add_argument("--regimes", nargs="*", default=list(REGIMES))
    parser.add_argument("--smoke", action="store_true", help="a tiny size of every part (under a minute)")
    parser.add_argument("--case", nargs=2, metavar=("SIZE", "SOLVER"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        print(json.dumps(scaling_case(int(args.case[0]), args.case[1], args.landmarks)), flush=True)
        return
    if args.smoke:
        run_scaling([600], 600, 100)
        run_table1(["mixed"], True, 200)
        run_recipe(["mixed"], True, "nystrom", 200)
        return
    if args.part == "scaling":
        run_scaling(args.sizes, args.direct_max, args.landmarks)
    elif args.part == "table1":
        run_table1(args.regimes, False, args.landmarks)
    else:
        run_recipe(args.regimes, False, args.solver, args.landmarks)


if __name__ == "__main__":
    main()
