#!/usr/bin/env python
"""One long record: `fj.simulate`'s time-parallel form (`scan="parallel"`) against its sequential scan and a numba
loop on the host CPU, forward and gradient, and a Levenberg-Marquardt fit of LuGre on a long record.

Run as `python benchmarks/parallel_scan.py [--lengths 10000 100000 1000000] [--fit-length 1000000]`. Works on any
JAX backend (CPU, GPU, TPU: the default device); the numba loop always runs on the host CPU. Prints one JSON object
per line:

- `long_record`: per model (LuGre; Maxwell-slip NLR(7), exact) and record length, the time of one free run by
  `jax.jit(fj.simulate)` with `scan="sequential"` and `scan="parallel"`, of `value_and_grad` of a mean-squared
  error through each, and of the numba loop of the same equations (benchmarks/simulate.py), with the agreement of
  the parallel and sequential forces (max |difference| / max |force|) and the speed-ups; the sequential scan is
  skipped above `--sequential-max` samples on an accelerator (one launch per step: minutes per gradient);
- `fit`: `fj.fit` of LuGre with `fj.levenberg_marquardt()` on a `--fit-length`-sample record from 50 % off:
  first call (compilation included) and a second call, final loss, steps, which scan `auto` took.

Timings are informational (nothing here is a test); device and versions are in every line.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import fricjax as fj  # noqa: E402
from simulate import NOMINAL, environment, growing_sine, numba_runner, steady  # noqa: E402

ENV: dict[str, Any] = {}


def emit(record: dict[str, Any]) -> None:
    print(json.dumps({**record, **ENV}), flush=True)


def timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    return time.perf_counter() - t0, out


def long_record(name: str, length: int, cfg: argparse.Namespace) -> dict[str, Any]:
    make, nominal = NOMINAL[name]
    model = make(nominal)
    # the growing sine of benchmarks/simulate.py, 20 cycles per 4 000 samples (the same local shape at every length)
    motion = fj.Motion.from_position(growing_sine(length, cycles=length / 200), dt=1e-3)
    params, static = eqx.partition(model, eqx.is_inexact_array)
    target = jnp.asarray(fj.simulate(model, motion)) * 1.01

    def forward(scan: str) -> Callable[[Any, Any], Any]:
        return jax.jit(lambda p, m: fj.simulate(eqx.combine(p, static), m, scan=scan))

    def gradient(scan: str) -> Callable[[Any, Any], Any]:
        def loss(p: Any, m: Any) -> Any:
            return jnp.mean((fj.simulate(eqx.combine(p, static), m, scan=scan) - target) ** 2)

        return jax.jit(jax.value_and_grad(loss))

    scans = ["parallel"]
    if jax.default_backend() == "cpu" or length <= cfg.sequential_max:
        scans.append("sequential")
    fns: dict[str, Callable[[], Any]] = {}
    compile_s: dict[str, float] = {}
    outputs: dict[str, Any] = {}
    for scan in scans:
        f, g = forward(scan), gradient(scan)
        fns[scan] = lambda f=f: f(params, motion)
        compile_s[scan], outputs[scan] = timed(fns[scan])
        if not cfg.forward_only:
            fns[f"{scan}_grad"] = lambda g=g: g(params, motion)
            compile_s[f"{scan}_grad"], _ = timed(fns[f"{scan}_grad"])
    run_numba = numba_runner(name, model, motion)
    run_numba()  # compile
    fns["numba"] = run_numba
    timing = steady(fns, cfg.repeats, cfg.budget)
    force = np.asarray(outputs["parallel"])
    scale = float(np.max(np.abs(force)))
    record: dict[str, Any] = {
        "bench": "long_record",
        "model": name,
        "length": length,
        "seconds": {key: round(value["median"], 6) for key, value in timing.items()},
        "first_call_s": {key: round(value, 3) for key, value in compile_s.items()},
        "parallel_vs_numba_rel": float(np.max(np.abs(force - np.asarray(run_numba()))) / scale),
        "numba_over_parallel": round(timing["numba"]["median"] / timing["parallel"]["median"], 3),
    }
    if not cfg.forward_only:
        record["parallel_grad_over_forward"] = round(
            timing["parallel_grad"]["median"] / timing["parallel"]["median"], 3
        )
    if not cfg.forward_only and cfg.transpose != "jax":  # the gradient against JAX's own transpose, same run
        from jax.flatten_util import ravel_pytree

        from fricjax._simulate import _parallel

        ours = np.asarray(ravel_pytree(fns["parallel_grad"]()[1])[0])
        _parallel.TRANSPOSE = "jax"
        jax.clear_caches()
        theirs = np.asarray(ravel_pytree(gradient("parallel")(params, motion)[1])[0])
        _parallel.TRANSPOSE = cfg.transpose
        jax.clear_caches()
        record["grad_vs_jax_transpose_rel"] = float(np.max(np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1e-300)))
    if "sequential" in outputs:
        record["parallel_vs_sequential_rel"] = float(np.max(np.abs(force - np.asarray(outputs["sequential"]))) / scale)
        record["sequential_over_parallel"] = round(timing["sequential"]["median"] / timing["parallel"]["median"], 3)
        record["numba_over_sequential"] = round(timing["numba"]["median"] / timing["sequential"]["median"], 3)
    return record


def fit(length: int) -> dict[str, Any]:
    t = np.arange(length) * 1e-3
    amplitude = 2e-6 * (1e-3 / 2e-6) ** (0.5 * (1 - np.cos(2 * np.pi * t / t[-1])))
    motion = fj.Motion.from_position(amplitude * np.sin(2 * np.pi * t), dt=1e-3)
    truth = fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 2e-3, 2.0), sigma0=1e5, sigma1=300.0, sigma2=40.0)
    start = fj.LuGre(fj.ExponentialStribeck(1.5, 0.75, 1e-3, 3.0), sigma0=5e4, sigma1=450.0, sigma2=20.0)
    start = fj.with_smoothing(start, fj.Smooth(1e-6))
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    kwargs = {"solver": fj.levenberg_marquardt(), "steps": 60, "compute_std": False, "progress": False}
    first, result = timed(lambda: fj.fit(start, data, **kwargs))
    warm, result = timed(lambda: fj.fit(start, data, **kwargs))
    samples = fj.unwrap(start).samples(motion)
    return {
        "bench": "fit",
        "model": "lugre",
        "solver": "levenberg_marquardt",
        "length": length,
        "first_call_s": round(first, 3),
        "warm_s": round(warm, 3),
        "train_loss": float(result.train_loss),
        "evaluations": int(result.evaluations),
        "result": result.code,
        "auto_scan_parallel": bool(fj_uses_parallel(start, samples, length)),
    }


def fj_uses_parallel(model: Any, samples: Any, length: int) -> bool:
    from fricjax._simulate._parallel import uses_parallel

    return uses_parallel(fj.unwrap(model), samples, "auto", length)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lengths", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--models", nargs="+", default=["lugre", "maxwell_nlr7"], choices=["lugre", "maxwell_nlr7"])
    parser.add_argument("--sequential-max", type=int, default=100_000, help="on an accelerator (launch-bound)")
    parser.add_argument("--fit-length", type=int, default=0, help="0: no fit")
    parser.add_argument(
        "--prefix",
        nargs="+",
        default=[None],
        help="prefix forms to time (fricjax._simulate._parallel.PREFIX), each 'doubling', 'blelloch' or "
        "'blocked:BLOCK:WITHIN[:ACROSS]' (WITHIN 'doubling' or 'sequential', ACROSS 'doubling' or 'blocked'), e.g. "
        "blocked:8:sequential:doubling; default: fricjax's",
    )
    parser.add_argument(
        "--rounds",
        choices=["auto", "loop", "unrolled"],
        default="auto",
        help="the doubling rounds (fricjax._simulate._parallel.ROUNDS): in a fori_loop, unrolled, or auto (a loop "
        "on CPU devices, unrolled on accelerators)",
    )
    parser.add_argument(
        "--transpose",
        choices=["jax", "adjoint"],
        default="jax",
        help="reverse mode of the tangent scan (fricjax._simulate._parallel.TRANSPOSE): JAX's own transpose, or the "
        "adjoint recurrence as a backward affine prefix (not under vmap); with 'adjoint' the gradient is also "
        "compared with JAX's transpose (grad_vs_jax_transpose_rel)",
    )
    parser.add_argument("--forward-only", action="store_true", help="time the free run only (no gradient)")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--budget", type=float, default=5.0, help="seconds of timing per configuration")
    cfg = parser.parse_args(argv)
    from fricjax._simulate import _parallel

    ENV.update(environment())
    _parallel.ROUNDS = ENV["rounds"] = cfg.rounds
    _parallel.TRANSPOSE = ENV["transpose"] = cfg.transpose
    for prefix in cfg.prefix:
        if prefix:
            jax.clear_caches()  # fj.simulate's traces read the prefix form: trace again
            method, *options = prefix.split(":")
            _parallel.PREFIX = method
            if method == "blocked":
                _parallel.BLOCK, _parallel.WITHIN = int(options[0]), options[1]
                _parallel.ACROSS = options[2] if len(options) > 2 else "blocked"
        ENV["prefix"] = prefix or _parallel.PREFIX
        for length in cfg.lengths:
            for name in cfg.models:
                emit(long_record(name, length, cfg))
    if cfg.fit_length:
        emit(fit(cfg.fit_length))


if __name__ == "__main__":
    main()
