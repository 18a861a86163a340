#!/usr/bin/env python
"""Where the Maxwell-slip sweep's time goes: the loop, or the layout of its output (issue 12, vmap target).

`benchmarks/simulate.py` measures `eqx.filter_vmap(fj.simulate)` of Maxwell-slip NLR(7) over 1024 parameter sets
(4 000 steps) against a target of 3x a single numba trajectory's throughput. This script splits that figure, on
the same models, record and numba loop, every variant in the same run (round-robin timing):

- `fricjax (B, T)`: `filter_vmap(fj.simulate)`, the forces as vmap returns them, one row per configuration
  (Maxwell-slip's batch-minor free run: the batch as the minor axis, the rows written one column per step);
- `fricjax (T, B)`: the same with `out_axes=1` (time-major: now one transposition of the rows);
- `fricjax (B, T)` / `(T, B), vmap's own batching`: the same model with `batch_minor()` false (the previous
  version's path: batch-major loop, outputs stacked time-major, so the rows layout pays the transposition);
- `fricjax loss`: a mean-squared error per configuration inside the vmap (what a sweep or a fit computes);
  `fricjax loss, time-major`: the same error computed outside the vmap from the time-major forces;
- `hand (T, B)`: a hand-written `lax.scan` of the same equations with the elements and the batch as a
  `(M, B)` carry (batch-minor: the sum over the elements is a vector add), the forces stacked time-major;
- `hand (B, T)` by a final transposition, by writing one column per step into a `(B, T)` buffer (`columns`,
  what fricjax's batch-minor loop does), by stacking blocks of K steps transposed in the loop body
  (`chunked K`), or by writing `(B, K)` blocks into a `(B, T)` buffer with `dynamic_update_slice` (`blocks K`);
- `numba`: `maxwell_nlr_numba` of simulate.py, one trajectory (the target's reference).

Each line: `ns_per_trajectory_step` (wall time / (B T)) and `ratio_vs_numba` (numba ns per step / that: the
target is >= 3). `--host-devices N` shards the batch over N XLA host devices (`fj.shard_batch`) as simulate.py
does. Informational: nothing here is a test.

Run: `python benchmarks/vmap_layout.py [--host-devices 2] [--batch 1024] [--steps 4000]`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

import simulate as bench  # isort: skip  (first: it sets XLA_FLAGS for --host-devices before jax starts)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import fricjax as fj  # noqa: E402


def element_step(th: jax.Array, kk: jax.Array, offset: jax.Array) -> Callable[[jax.Array, jax.Array], Any]:
    """The NLR Maxwell-slip step (exact clip) on a batch-minor carry: `th`, `kk` (M, B), `offset` (B,)."""

    def step(delta: jax.Array, d: jax.Array) -> tuple[jax.Array, jax.Array]:
        delta = jnp.clip((delta + d) / th, -1.0, 1.0) * th
        return delta, jnp.sum(kk * delta, axis=0) + offset

    return step


def hand_time_major(thresholds: jax.Array, k: jax.Array, offset: jax.Array, dx: jax.Array) -> jax.Array:
    """The forces (T, B) of a batch: `thresholds`, `k` (B, M), `offset` (B,), the elements and the batch carried as
    (M, B) (batch-minor: the sum over the elements is a vector add), the outputs stacked time-major."""
    th = thresholds.T
    return jax.lax.scan(element_step(th, k.T, offset), jnp.zeros_like(th), dx)[1]


def hand_columns(thresholds: jax.Array, k: jax.Array, offset: jax.Array, dx: jax.Array) -> jax.Array:
    """As `hand_time_major`, each step's forces written as one column of a (B, T) buffer carried by the loop."""
    th = thresholds.T
    step = element_step(th, k.T, offset)

    def body(t: jax.Array, carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta, out = carry
        delta, forces = step(delta, dx[t])
        return delta, jax.lax.dynamic_update_slice(out, forces[:, None], (0, t))

    start = (jnp.zeros_like(th), jnp.zeros((thresholds.shape[0], dx.shape[0]), thresholds.dtype))
    return jax.lax.fori_loop(0, dx.shape[0], body, start)[1]


class OwnBatchingMaxwellSlip(fj.MaxwellSlip):
    """Maxwell-slip with `batch_minor()` false: `jax.vmap` batches its scan itself (the previous version's path)."""

    def batch_minor(self) -> bool:
        return False


def own_batching(models: fj.MaxwellSlip) -> OwnBatchingMaxwellSlip:
    """The same batch of models (same leaves) as `OwnBatchingMaxwellSlip`s."""
    like = OwnBatchingMaxwellSlip.nlr(k=bench.MS_K, thresholds=bench.MS_THRESHOLDS, offset=0.0)
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(like), jax.tree_util.tree_leaves(models))


def hand_chunked(thresholds: jax.Array, k: jax.Array, offset: jax.Array, dx: jax.Array, block: int) -> jax.Array:
    """As `hand_time_major`, K steps per outer iteration, each block transposed to (B, K) in the loop: (B, T)."""
    th = thresholds.T
    step = element_step(th, k.T, offset)

    def outer(delta: jax.Array, d: jax.Array) -> tuple[jax.Array, jax.Array]:
        delta, forces = jax.lax.scan(step, delta, d)
        return delta, forces.T

    steps = dx.shape[0]
    _, out = jax.lax.scan(outer, jnp.zeros_like(th), dx.reshape(steps // block, block))  # (T/K, B, K)
    return jnp.moveaxis(out, 0, 1).reshape(thresholds.shape[0], steps)


def hand_blocks(thresholds: jax.Array, k: jax.Array, offset: jax.Array, dx: jax.Array, block: int) -> jax.Array:
    """As `hand_chunked`, each (B, K) block written into a (B, T) buffer by `dynamic_update_slice`."""
    th = thresholds.T
    step = element_step(th, k.T, offset)
    steps = dx.shape[0]
    blocks = dx.reshape(steps // block, block)

    def outer(i: jax.Array, carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta, out = carry
        delta, forces = jax.lax.scan(step, delta, blocks[i])
        return delta, jax.lax.dynamic_update_slice(out, forces.T, (0, i * block))

    start = (jnp.zeros_like(th), jnp.zeros((thresholds.shape[0], steps), thresholds.dtype))
    return jax.lax.fori_loop(0, steps // block, outer, start)[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=4000, help="record length of the batch (a multiple of 200)")
    parser.add_argument("--numba-steps", type=int, default=40_000, help="record length of the numba trajectory")
    parser.add_argument("--host-devices", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=41)
    parser.add_argument("--budget", type=float, default=6.0, help="seconds of timed rounds")
    cfg = parser.parse_args()
    if cfg.steps % 200:
        sys.exit("--steps must be a multiple of 200 (the block sizes)")
    bench.ENV.update(bench.environment())

    motion = bench.make_motion(cfg.steps)
    models = eqx.filter_vmap(bench.make_maxwell)(jnp.asarray(bench.batch_parameters("maxwell_nlr7", cfg.batch)))
    own = own_batching(models)
    p = fj.unwrap(models)
    x = jnp.asarray(motion.x)
    dx = jnp.diff(x, prepend=x[:1])  # the per-step signal fj.simulate derives (dx_0 = 0)
    arrays = (p.thresholds, p.force_map.k, p.force_map.offset)
    if cfg.host_devices > 1:
        models, own, arrays = fj.shard_batch(models), fj.shard_batch(own), fj.shard_batch(arrays)
    target = jnp.asarray(np.random.default_rng(1).normal(0.0, 0.1, cfg.steps))  # a measured force [N], say

    @eqx.filter_jit
    def fricjax_loss(ms: fj.MaxwellSlip, mo: fj.Motion, y: jax.Array) -> jax.Array:
        return eqx.filter_vmap(lambda m: jnp.mean((fj.simulate(m, mo) - y) ** 2))(ms)

    @eqx.filter_jit
    def fricjax_loss_time_major(ms: fj.MaxwellSlip, mo: fj.Motion, y: jax.Array) -> jax.Array:
        forces = bench.vmap_simulate(ms, mo, time_major=True)
        return jnp.mean((forces - y[:, None]) ** 2, axis=0)

    hand_tb = jax.jit(hand_time_major)
    hand_bt = jax.jit(lambda *a: hand_time_major(*a).T)
    hand_cols = jax.jit(hand_columns)
    variants = {
        "fricjax (B, T)": lambda: bench.vmap_simulate(models, motion),
        "fricjax (T, B)": lambda: bench.vmap_simulate(models, motion, time_major=True),
        "fricjax (B, T), vmap's own batching": lambda: bench.vmap_simulate(own, motion),
        "fricjax (T, B), vmap's own batching": lambda: bench.vmap_simulate(own, motion, time_major=True),
        "fricjax loss": lambda: fricjax_loss(models, motion, target),
        "fricjax loss, time-major": lambda: fricjax_loss_time_major(models, motion, target),
        "hand (T, B)": lambda: hand_tb(*arrays, dx),
        "hand (B, T), transposed": lambda: hand_bt(*arrays, dx),
        "hand (B, T), columns": lambda: hand_cols(*arrays, dx),
    }
    for block in (8, 50):
        chunked = jax.jit(lambda *a, _k=block: hand_chunked(*a, _k))
        variants[f"hand (B, T), chunked {block}"] = lambda _f=chunked: _f(*arrays, dx)
    for block in (50, 200):
        blocks = jax.jit(lambda *a, _k=block: hand_blocks(*a, _k))
        variants[f"hand (B, T), blocks {block}"] = lambda _f=blocks: _f(*arrays, dx)

    reference = np.asarray(bench.vmap_simulate(models, motion))
    for name, fn in variants.items():  # compile, and check every variant computes the same forces
        out = np.asarray(fn())
        if name.startswith("fricjax loss"):
            expected = np.mean((reference - np.asarray(target)) ** 2, axis=1)
        else:
            expected = reference.T if "(T, B)" in name else reference
        if not np.allclose(out, expected, rtol=1e-9, atol=1e-12 * np.abs(reference).max()):
            sys.exit(f"{name}: differs from fj.simulate")

    run_numba = bench.numba_runner(
        "maxwell_nlr7", bench.make_maxwell(bench.NOMINAL["maxwell_nlr7"][1]), bench.make_motion(cfg.numba_steps)
    )
    run_numba()  # compile
    timing = bench.steady({**variants, "numba": run_numba}, cfg.repeats, cfg.budget)
    numba_ns = timing["numba"]["median"] / cfg.numba_steps * 1e9
    for name in variants:
        ns = timing[name]["median"] / (cfg.batch * cfg.steps) * 1e9
        bench.emit(
            {
                "benchmark": "vmap_layout",
                "model": "maxwell_nlr7",
                "variant": name,
                "ns_per_trajectory_step": round(ns, 3),
                "ratio_vs_numba": round(numba_ns / ns, 3),
                "numba_ns_per_step": round(numba_ns, 3),
                "batch": cfg.batch,
                "steps": cfg.steps,
                "host_devices": cfg.host_devices,
                "repeats": timing[name]["n"],
                "loadavg_1min": bench.load_average(),
            }
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
