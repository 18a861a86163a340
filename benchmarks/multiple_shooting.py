"""Multiple shooting by Levenberg-Marquardt: the Jacobian's segment structure against a dense Jacobian.

A LuGre record (`--samples` samples at 1 kHz, a sine growing from pre-sliding into sliding, 0.5 % force noise) is
fitted with `fj.MultipleShootingLoss(L)` from a start 50 % off, by

- `fricjax_lm`: `fj.levenberg_marquardt()`: a segment's start moves only that segment's errors and the two
  continuity gaps beside it, so every other segment's start shares one forward-mode tangent (2 tangents per state
  component, whatever the number of segments; `Problem.gauss_newton`);
- `fricjax_lm_dense`: the same solver with the structure hidden (a `MultipleShootingLoss` whose `jacobian_groups`
  is None: one tangent per segment start), the baseline of the same code;
- `optimistix_lm`: `optx.LevenbergMarquardt` through `fj.fit` (the same algorithm; its Jacobian has one column per
  segment start), the previous default.

Each in a fresh process, called twice (first call with compilation, then warm). Printed, one JSON line per
(segment length, solver): wall times, solver steps, ms per step when warm, the final loss and the largest relative
error of the physical parameters; device and versions on every line.

Run: `python benchmarks/multiple_shooting.py [--samples 20000] [--segments 200 1000] [--steps 30]`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402

DT = 1e-3
SOLVERS = ("fricjax_lm", "fricjax_lm_dense", "optimistix_lm")


class DenseMultipleShootingLoss(fj.MultipleShootingLoss):
    """Multiple shooting with its Jacobian's structure hidden (every segment start its own tangent)."""

    def jacobian_groups(self, extra: Any, data: Any) -> None:
        return None


def truth() -> fj.LuGre:
    return fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=2e-3), sigma0=1e5, sigma1=300.0, sigma2=40.0)


def start() -> fj.LuGre:
    stribeck = fj.ExponentialStribeck(Fc=1.5, Fs=0.75 * 1.5, vs=1e-3)
    return fj.LuGre(stribeck, sigma0=5e4, sigma1=450.0, sigma2=20.0, smoothing=fj.Smooth(1e-6))


def record(samples: int) -> fj.FrictionData:
    t = np.arange(samples) * DT
    x = (2e-3 * (t / t[-1]) ** 2 + 2e-5) * np.sin(2 * np.pi * 1.5 * t)
    motion = fj.Motion.from_position(x, dt=DT)
    force = np.asarray(fj.simulate(truth(), motion))
    return fj.FrictionData(motion, force + 0.005 * np.std(force) * np.random.default_rng(0).standard_normal(samples))


def parameter_error(model: Any) -> float:
    f, g = fj.unwrap(fj.exact(model)), fj.unwrap(truth())
    pairs = [(f.stribeck.Fc, g.stribeck.Fc), (f.stribeck.Fs, g.stribeck.Fs), (f.sigma0, g.sigma0), (f.sigma2, g.sigma2)]
    return max(abs(float(a) - float(b)) / abs(float(b)) for a, b in pairs)


def run_one(solver_name: str, segment: int, args: argparse.Namespace) -> dict[str, Any]:
    data = record(args.samples)
    solver = optx.LevenbergMarquardt(1e-10, 1e-12) if solver_name == "optimistix_lm" else fj.levenberg_marquardt()
    loss = DenseMultipleShootingLoss(segment) if solver_name == "fricjax_lm_dense" else fj.MultipleShootingLoss(segment)
    kwargs = dict(loss=loss, solver=solver, steps=args.steps, progress=False)
    times, solutions = [], []
    for _ in range(2):
        began = time.perf_counter()
        solutions.append(fj.fit(start(), data, scaling=fj.ParameterScaling(), **kwargs))
        times.append(time.perf_counter() - began)
    solution = solutions[-1]
    return {
        "bench": "multiple_shooting",
        "solver": solver_name,
        "samples": args.samples,
        "segment_length": segment,
        "segment_starts": args.samples // segment - 1,
        "first_call_s": round(times[0], 2),
        "warm_s": round(times[1], 2),
        "steps": solution.evaluations,
        "ms_per_step_warm": round(1000 * times[1] / max(solution.evaluations, 1), 1),
        "result": solution.code,
        "train_loss": float(solution.train_loss),
        "param_rel_error_max": round(parameter_error(solution.model), 5),
        **environment(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--segments", type=int, nargs="+", default=[200, 1000], help="segment lengths [samples]")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--one", nargs=2, metavar=("SOLVER", "LENGTH"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one[0], int(args.one[1]), args)))
        return
    for segment in args.segments:
        for name in SOLVERS:
            command = [sys.executable, __file__, "--samples", str(args.samples), "--steps", str(args.steps)]
            out = subprocess.run([*command, "--one", name, str(segment)], check=True, capture_output=True, text=True)
            print(out.stdout.strip().splitlines()[-1], flush=True)


if __name__ == "__main__":
    main()
