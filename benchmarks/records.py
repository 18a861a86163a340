"""Several records in one fit: `fj.fit(model, [records])` against the two ways of doing without it.

Ten synthetic records of one LuGre device (`--samples` = 20 000 samples each at 1 kHz; sine displacements of
amplitudes from 20 um (pre-sliding) to 2 mm (gross sliding) and frequencies from 0.5 to 3 Hz; each record with its
own force-cell offset, up to +-0.3 N on forces of about 1.5 N, and white force noise of 0.5 % of its spread) are
fitted from the same start (every parameter 50 % off) by Levenberg-Marquardt (`--steps` at most) three ways:

- `records`: `fj.fit(start, records, nuisances=fj.Nuisances(offset=True, initial_state=True))`: shared
  parameters, each record's offset and initial state, the ten records simulated side by side in one program;
- `loop`: a Python loop of ten single-record fits `fj.fit(start, record)` (each fits its own parameters and the
  model's own `offset` and `z0`): ten models, not one;
- `concatenated`: one fit to `fj.concatenate(records)` (200 000 samples): one model, one offset for all records
  (the model's), the state carried across the joins.

Each way runs in a fresh process (so that no way finds another's compiled programs), three calls there: the first
(tracing and XLA compilation included), a second of the same shapes and values (warm), and a third from another
start (every parameter 40 % off instead of 50 %: the same shapes, new values). Printed, one JSON line per way:

- the three wall times, `compile_s` = first - warm; the XLA compilations during each call and their seconds
  (`jax.monitoring` backend-compile events: a warm call of the same shapes should compile nothing); solver steps
  per call and `ms_per_step_warm`;
- the final training loss (mean NMSE over the records, a fraction); `clean_nmse_percent`, the exact-mode NMSE of
  the fitted model(s) against the noise-free forces (the model's own offset set to 0; for `loop` each model on its
  own record, and the median and worst over its models of each one's mean NMSE on all ten records); the largest
  relative error of the physical parameters (for `loop` also the median over its fits);
  for `records` the largest error of the per-record offsets [N] and each record's training NMSE.

A last line (`summary`) gives the ratios. Every line carries the machine, the versions and `loadavg_1min`.

Run: `python benchmarks/records.py [--records 10] [--samples 20000] [--steps 40]`; about a minute on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.monitoring  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402

DT = 1e-3
SMOOTHING = fj.Smooth(1e-6)  # m/s: the smooth model trained (the data come from the exact one)


def truth() -> fj.LuGre:
    return fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=2e-3, delta=2.0), sigma0=1e5, sigma1=300.0, sigma2=40.0)


def start(off: float) -> fj.LuGre:
    """Every parameter `off` (a fraction) away from the truth, alternately above and below."""
    up, down = 1 + off, 1 - off
    stribeck = fj.ExponentialStribeck(Fc=1.0 * up, Fs=1.5 * down, vs=2e-3 * down, delta=2.0 * up)
    return fj.LuGre(stribeck, sigma0=1e5 * down, sigma1=300.0 * up, sigma2=40.0 * down, smoothing=SMOOTHING)


def make_records(count: int, samples: int, seed: int = 0) -> tuple[list[fj.FrictionData], list[np.ndarray], np.ndarray]:
    """`count` records (measured: offset and noise added), their noise-free forces and their offsets [N]."""
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * DT
    amplitudes = np.geomspace(2e-5, 2e-3, count)
    frequencies = rng.permutation(np.linspace(0.5, 3.0, count))
    offsets = rng.uniform(-0.3, 0.3, count)
    records, clean = [], []
    for amplitude, frequency, offset in zip(amplitudes, frequencies, offsets, strict=True):
        motion = fj.Motion.from_position(amplitude * np.sin(2 * np.pi * frequency * t), dt=DT)
        force = np.asarray(fj.simulate(truth(), motion))
        noise = 0.005 * np.std(force) * rng.standard_normal(samples)
        records.append(fj.FrictionData(motion, force + offset + noise))
        clean.append(force)
    return records, clean, offsets


class CompileCounter:
    """Counts XLA backend compilations (and their seconds) reported by `jax.monitoring`."""

    def __init__(self) -> None:
        self.count, self.seconds = 0, 0.0
        jax.monitoring.register_event_duration_secs_listener(self._event)

    def _event(self, name: str, duration: float, **_: Any) -> None:
        if name == "/jax/core/compile/backend_compile_duration":
            self.count += 1
            self.seconds += duration

    def measure(self, call: Any, *args: Any) -> tuple[Any, float, int, float]:
        """`call(*args)`, its wall time [s], and the XLA compilations (count, seconds) during it."""
        count, seconds = self.count, self.seconds
        began = time.perf_counter()
        out = call(*args)
        return out, time.perf_counter() - began, self.count - count, self.seconds - seconds


def parameter_error(model: Any) -> float:
    """Largest relative error of the physical parameters (offset and z0 excluded)."""
    f, g = fj.unwrap(fj.exact(model)), fj.unwrap(truth())
    pairs = [
        (f.stribeck.Fc, g.stribeck.Fc),
        (f.stribeck.Fs, g.stribeck.Fs),
        (f.stribeck.vs, g.stribeck.vs),
        (f.stribeck.delta, g.stribeck.delta),
        (f.sigma0, g.sigma0),
        (f.sigma1, g.sigma1),
        (f.sigma2, g.sigma2),
    ]
    return max(float(np.max(np.abs(np.asarray(a) - b) / abs(float(b)))) for a, b in pairs)


def clean_nmse(model: Any, records: list[fj.FrictionData], clean: list[np.ndarray]) -> float:
    """Mean exact-mode NMSE [%] of `model` (its own offset set to 0) against the noise-free forces."""
    exact = fj.unwrap(fj.exact(model))
    exact = eqx.tree_at(lambda m: m.offset, exact, jnp.zeros_like(exact.offset))
    return float(
        np.mean([float(fj.nmse(c, fj.simulate(exact, r.motion))) for r, c in zip(records, clean, strict=True)])
    )


WAYS = ("records", "loop", "concatenated")


def run_way(way: str, args: argparse.Namespace, env: dict[str, Any]) -> dict[str, Any]:
    """Three calls of one way (first, warm, new start) in this process, and the line describing them."""
    counter = CompileCounter()
    records, clean, offsets = make_records(args.records, args.samples)
    common = dict(solver=fj.levenberg_marquardt(), steps=args.steps, scaling=fj.ParameterScaling())
    concatenated = fj.concatenate(records)

    def call(model: Any) -> list[Any]:
        if way == "records":
            nuisances = fj.Nuisances(offset=True, drift=False, initial_state=True)
            # z0 held: each record's initial state is a nuisance (the model's own z0 would duplicate it)
            return [fj.fit(model, records, nuisances=nuisances, freeze=("z0",), **common)]
        if way == "loop":
            return [fj.fit(model, record, **common) for record in records]
        return [fj.fit(model, concatenated, **common)]

    results, first_s, first_compiles, first_compile_s = counter.measure(call, start(0.5))
    warm, warm_s, warm_compiles, warm_compile_s = counter.measure(call, start(0.5))  # same shapes, same values
    third, third_s, third_compiles, third_compile_s = counter.measure(call, start(0.4))  # same shapes, new values
    steps = [sum(int(r.evaluations) for r in out) for out in (results, warm, third)]
    line: dict[str, Any] = {
        "bench": "records",
        "way": way,
        "first_call_s": round(first_s, 2),
        "warm_s": round(warm_s, 2),
        "new_start_s": round(third_s, 2),
        "compile_s": round(first_s - warm_s, 2),
        "xla_compiles": [first_compiles, warm_compiles, third_compiles],
        "xla_compile_s": [round(first_compile_s, 2), round(warm_compile_s, 2), round(third_compile_s, 2)],
        "steps": steps,
        "ms_per_step_warm": round(1e3 * warm_s / steps[1], 1),
        "result": sorted({r.code for r in results}),
        "train_loss": round(float(np.mean([r.train_loss for r in results])), 6),
    }
    if way == "loop":
        errors = [parameter_error(r.model) for r in results]
        line["steps_per_fit"] = [int(r.evaluations) for r in results]
        line["param_rel_error_median"] = round(statistics.median(errors), 4)
        line["param_rel_error_max"] = round(max(errors), 4)
        nmse = [clean_nmse(r.model, [rec], [c]) for r, rec, c in zip(results, records, clean, strict=True)]
        line["clean_nmse_percent"] = round(float(np.mean(nmse)), 5)
        cross = [clean_nmse(r.model, records, clean) for r in results]  # each model on all ten records
        line["clean_nmse_percent_all_records_median"] = round(statistics.median(cross), 5)
        line["clean_nmse_percent_all_records_max"] = round(max(cross), 5)
    else:
        line["param_rel_error_max"] = round(parameter_error(results[0].model), 4)
        line["clean_nmse_percent"] = round(clean_nmse(results[0].model, records, clean), 5)
    if way == "records":
        found = results[0].records
        line["offset_error_max_N"] = round(float(np.max(np.abs(found.offset - offsets))), 5)
        line["train_nmse_percent_per_record"] = [round(float(v), 4) for v in found.train_nmse]
    line["loadavg_1min"] = round(os.getloadavg()[0], 2)
    return {**line, **env}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=10)
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--way", choices=WAYS, help="run one way in this process (default: each in a fresh one)")
    args = parser.parse_args()
    env = {**environment(fricjax=getattr(fj, "__version__", "")), "records": args.records, "samples": args.samples}
    if args.way:
        print(json.dumps(run_way(args.way, args, env)), flush=True)
        return
    lines = {}
    for way in WAYS:  # a fresh process each, so that no way finds another's compiled programs
        command = [sys.executable, __file__, "--way", way]
        command += ["--records", str(args.records), "--samples", str(args.samples), "--steps", str(args.steps)]
        out = subprocess.run(command, capture_output=True, text=True, check=True).stdout
        lines[way] = json.loads(out.strip().splitlines()[-1])
        print(json.dumps(lines[way]), flush=True)
    summary = {
        "bench": "records",
        "way": "summary",
        "warm_loop_over_records": round(lines["loop"]["warm_s"] / lines["records"]["warm_s"], 2),
        "first_call_loop_over_records": round(lines["loop"]["first_call_s"] / lines["records"]["first_call_s"], 2),
        "warm_concatenated_over_records": round(lines["concatenated"]["warm_s"] / lines["records"]["warm_s"], 2),
        "records_warm_compiles": lines["records"]["xla_compiles"][1:],
        "loadavg_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps({**summary, **env}), flush=True)


if __name__ == "__main__":
    main()
