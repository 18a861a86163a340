#!/usr/bin/env python
"""Every CPU core for batched work (issue 33 item 6): the same batched jobs with fricjax's default host devices
(one per core, `src/fricjax/_xla_flags.py`) and with one device (`FRICJAX_HOST_DEVICES=1`), each in a fresh process.

Run as `python benchmarks/host_devices.py [--repeats 3]`. Prints one JSON object per job and device count: the
median wall time of the warm calls, the first call, and the results' agreement with one device:

- `vmap_free_run`: `jax.vmap` of `fj.simulate` over 1024 LuGre models (4 000 samples), sharded by `fj.shard_batch`;
- `sweep`: `fj.sweep` of 64 LuGre configurations (learning rates), 100 Adam steps on a tribometer record;
- `multistart`: `fj.fit` of LuGre with `fj.MultiStart(64)` and Levenberg-Marquardt, 20 steps;
- `single_fit`: one start, the same fit (must not change).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

JOB = r"""
import json, statistics, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import equinox as eqx, numpy as np, optax
import fricjax as fj

repeats = int(sys.argv[1])
data = fj.make_tribometer("mixed", seed=0, duration=2.0).train
start = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.4, vs=2e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4,
                 smoothing=fj.Smooth(1e-5))
t = np.arange(4000) * 1e-3
motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * t) * t / t[-1], dt=1e-3)
sigma0 = fj.shard_batch(jax.numpy.linspace(5e4, 2e5, 1024))
free_run = jax.jit(jax.vmap(lambda s: fj.simulate(eqx.tree_at(lambda m: m.sigma0, start, s), motion)))

jobs = {
    "vmap_free_run": lambda: free_run(sigma0),
    "sweep": lambda: fj.sweep([start] * 64, data, learning_rate=list(np.geomspace(1e-3, 1e-1, 64)),
                              steps=100).train_loss,
    "multistart": lambda: fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=20, progress=False,
                                 multistart=fj.MultiStart(64, spread=0.3), seed=1).train_loss,
    "single_fit": lambda: fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=20, progress=False).train_loss,
}
out = {"devices": len(jax.devices()), "shard_devices_64": len(fj.batch_devices(64))}
for name, job in jobs.items():
    t0 = time.perf_counter(); value = np.asarray(jax.block_until_ready(job())); first = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter(); jax.block_until_ready(job()); warm.append(time.perf_counter() - t0)
    out[name] = {"first_s": round(first, 3), "warm_s": round(statistics.median(warm), 3),
                 "value": value.ravel()[:64].tolist()}
print(json.dumps(out))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    cfg = parser.parse_args()
    sys.path.insert(0, os.path.dirname(__file__))
    from _environment import environment

    runs = {}
    for devices in ("1", "default"):
        env = {k: v for k, v in os.environ.items() if k != "FRICJAX_HOST_DEVICES"}
        if devices == "1":
            env["FRICJAX_HOST_DEVICES"] = "1"
        done = subprocess.run([sys.executable, "-c", JOB, str(cfg.repeats)], env=env, capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(done.stderr[-3000:])
        runs[devices] = json.loads(done.stdout.strip().splitlines()[-1])
    one, many = runs["1"], runs["default"]
    for name in ("vmap_free_run", "sweep", "multistart", "single_fit"):
        a, b = (one[name]["value"], many[name]["value"])
        scale = max(max(abs(x) for x in a), 1e-300)
        print(
            json.dumps(
                {
                    "bench": "host_devices",
                    "job": name,
                    "devices": many["devices"],
                    "sharded_over": many["shard_devices_64"] if name != "single_fit" else 1,
                    "one_device": {k: one[name][k] for k in ("first_s", "warm_s")},
                    "default": {k: many[name][k] for k in ("first_s", "warm_s")},
                    "warm_speedup": round(one[name]["warm_s"] / many[name]["warm_s"], 3),
                    "max_rel_difference": max(abs(x - y) for x, y in zip(a, b, strict=True)) / scale,
                    **environment(),
                }
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
