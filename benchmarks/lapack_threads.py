"""LAPACK inside XLA:CPU programs: SciPy's OpenBLAS on one thread (fricjax's setting) vs its default (one per core).

A jitted scan of `--steps` steps, each a QR, an eigh and a thin SVD of `--size` x `--size` matrices (independent
operations XLA may run at once on its pool), timed `--repeats` times in a fresh interpreter per setting, on a quiet
machine, beside one busy process (a Python busy loop) and beside another JAX program using both cores. Prints
one JSON line per setting and load (median and worst seconds per call). See src/fricjax/_lapack_threads.py.

    python benchmarks/lapack_threads.py            # 1-5 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

import scipy

from _environment import environment

CHILD = """
import json, sys, time
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
import fricjax
n, steps, repeats = map(int, sys.argv[1:4])
@jax.jit
def run(a, b):
    def body(c, k):
        x = a + 1e-3 * jnp.sin(k + c) * jnp.eye(n)
        y = b + 1e-3 * jnp.cos(k - c) * jnp.eye(n)
        r = jnp.linalg.qr(x)[1]
        w = jnp.linalg.eigh(y @ y.T)[0]
        s = jnp.linalg.svd(x[:, : n // 4], full_matrices=False)[1]
        return c + 1e-9 * (r[0, 0] + w[-1] + s[0]), w[0]
    return jax.lax.scan(body, 0.0, jnp.arange(float(steps)))
a = jax.random.normal(jax.random.PRNGKey(0), (n, n))
b = jax.random.normal(jax.random.PRNGKey(1), (n, n))
run(a, b)[0].block_until_ready()  # compile
times = []
for i in range(repeats):
    tic = time.perf_counter()
    run(a + i, b - i)[0].block_until_ready()
    times.append(time.perf_counter() - tic)
print(json.dumps({"times": times, "blas_threads": fricjax._lapack_threads.blas_threads()}))
"""

LOADS = {
    "quiet": None,
    "one busy process": "while True: pass",
    # another JAX program using both cores (XLA's pool: a large matrix product), as a second notebook would
    "a JAX process": (
        "import jax, jax.numpy as jnp\nx = jnp.ones((1500, 1500))\nwhile True: (x @ x).block_until_ready()"
    ),
}


def measure(size: int, steps: int, repeats: int, keep_threads: bool, load: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "FRICJAX_KEEP_BLAS_THREADS")}
    if keep_threads:
        env["FRICJAX_KEEP_BLAS_THREADS"] = "1"
    competitor = subprocess.Popen([sys.executable, "-c", LOADS[load]]) if LOADS[load] else None
    try:
        out = subprocess.run(
            [sys.executable, "-c", CHILD, str(size), str(steps), str(repeats)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
            timeout=1800,
        )
    finally:
        if competitor is not None:
            competitor.kill()
            competitor.wait()
    child = json.loads(out.stdout.strip().splitlines()[-1])
    times = child["times"]
    return {
        "setting": "openblas default threads" if keep_threads else "fricjax: openblas 1 thread",
        "load": load,
        "size": size,
        "steps": steps,
        "repeats": repeats,
        "median_s": round(statistics.median(times), 3),
        "worst_s": round(max(times), 3),
        "blas_threads": child["blas_threads"],
        **environment(scipy=scipy.__version__),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=200)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=8)
    args = parser.parse_args()
    for load in LOADS:
        for keep in (False, True):
            print(json.dumps(measure(args.size, args.steps, args.repeats, keep, load)), flush=True)


if __name__ == "__main__":
    main()
