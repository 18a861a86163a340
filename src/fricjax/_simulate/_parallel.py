"""The time-parallel free run: a model's per-sample state maps (`AbstractModel.parallel_maps`) composed by
`jax.lax.associative_scan`, then the model's own `step` evaluated at every sample at once.

A sequential scan takes T dependent steps; on a GPU each is a kernel launch of a few microseconds, so one long
record runs hundreds of times slower than a compiled CPU loop. The associative scan takes O(log T) dependent
steps of O(T) parallel work (Blelloch 1990), which is what an accelerator does well; on a CPU the sequential loop
is faster (more arithmetic, no parallelism to gain), so `scan="auto"` uses this form on accelerators only
(benchmarks/README.md, "Time-parallel simulation"). Values equal the sequential scan's to round-off and derivatives
are JAX's own of these operations (tests/test_parallel_scan.py).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from .._models._base import AbstractModel
from .._models._state_maps import apply, compose
from ._scan import split_time_signals

SCANS = ("auto", "sequential", "parallel")
# `scan="auto"` takes the parallel form from this many samples on (on an accelerator): a sequential step costs about
# 10 us there, so the log-depth scan wins from a few dozen samples (H100: 1 000 samples 0.29 ms against 11 ms;
# benchmarks/README.md, "Accelerators")
PARALLEL_MIN_LENGTH = 256
# how the prefix compositions are computed: "doubling" (Hillis & Steele 1986: log2 T rounds, each composing every
# map with the one 2^r samples earlier: one fused kernel per round, O(T log T) work), "blelloch"
# (`jax.lax.associative_scan`: O(T) work in about 2 log2 T rounds of strided slices and interleaves), or "auto":
# doubling for maps of at most DOUBLING_MAX_WIDTH numbers per sample, blelloch for wider ones. On an H100 (10^6
# samples, benchmarks/README.md): LuGre (2 numbers) 0.80 ms doubling against 1.2 ms blelloch, compiled in 0.4 s
# against 3.6 s; Maxwell-slip NLR(7) (21) 6.6 ms against 4.2 ms
PREFIX = "auto"
DOUBLING_MAX_WIDTH = 8


def on_accelerator() -> bool:
    """Whether computations run on an accelerator by default (the default device, or JAX's first device, is not
    a CPU): decided when a program is traced."""
    device = getattr(jax.config, "jax_default_device", None)
    if device is None:
        return jax.default_backend() != "cpu"
    platform = device if isinstance(device, str) else getattr(device, "platform", "cpu")
    return platform != "cpu"


def has_parallel_form(model: AbstractModel, samples: Any) -> bool:
    """Whether `model` declares a time-parallel form for these samples (decided from structure, not values)."""
    return jax.eval_shape(model.parallel_maps, samples) is not None


def uses_parallel(model: AbstractModel, samples: Any, scan: str, length: int) -> bool:
    """The choice of `run` for `scan=` (validated by `check_options`): "parallel" (an error when the model has no
    parallel form), "sequential", or "auto": the parallel form on an accelerator for records of at least
    `PARALLEL_MIN_LENGTH` samples when the model has one."""
    if scan == "sequential" or length == 0:
        return False
    if scan == "parallel":
        if not has_parallel_form(model, samples):
            raise ValueError(
                f"simulate: scan='parallel' needs a model with a time-parallel form (LuGre, exact Maxwell-slip LR / "
                f"NLR, exact play operators, static friction laws); {type(model).__name__} has none here (a smooth "
                "clip, an FIR force map, or a state that is not a composition of affine or clamp maps): use "
                "scan='auto' or 'sequential'."
            )
        return True
    return length >= PARALLEL_MIN_LENGTH and on_accelerator() and has_parallel_form(model, samples)


def parallel_run(model: AbstractModel, samples: Any, state: Any, return_states: bool = False) -> tuple[Any, Any]:
    """The free run of `run` in its time-parallel form: `(final_state, outputs)`, or `(final_state, (outputs,
    states))` with `return_states` (the state after every sample)."""
    maps = model.parallel_maps(samples)
    state = jax.tree_util.tree_map(jnp.asarray, state)
    if jax.tree_util.tree_leaves(maps):
        method = PREFIX
        if method == "auto":
            width = sum(leaf.size // leaf.shape[0] for leaf in jax.tree_util.tree_leaves(maps))
            method = "doubling" if width <= DOUBLING_MAX_WIDTH else "blelloch"
        after = apply(prefix_compositions(maps, method), state)  # the state after each sample
        entering = jax.tree_util.tree_map(
            lambda s0, s: jnp.concatenate([s0[None].astype(s.dtype), s[:-1]]), state, after
        )
    else:  # no state (a static law): every sample is evaluated at once
        entering = state
    steps, rebuild = split_time_signals(samples)
    leaving, outputs = jax.vmap(lambda s, signals: model.step(s, rebuild(signals)))(entering, steps)
    final = jax.tree_util.tree_map(lambda s: s[-1], leaving)
    return final, ((outputs, leaving) if return_states else outputs)


def prefix_compositions(maps: Any, method: str = "doubling") -> Any:
    """Map k composed with every map before it (`maps[k] o ... o maps[0]`), for every k: the state maps from the
    initial state to the state after each sample. `method` as `PREFIX`."""
    if method == "blelloch":
        return jax.lax.associative_scan(compose, maps)
    length = jax.tree_util.tree_leaves(maps)[0].shape[0]
    index = jnp.arange(length)
    shift = 1
    while shift < length:  # after the round with shift s, map k holds the composition of samples k - 2s + 1 ... k
        earlier = jax.tree_util.tree_map(lambda leaf, s=shift: jnp.roll(leaf, s, axis=0), maps)
        composed = compose(earlier, maps)  # the first `shift` entries compose with wrapped-around maps: not kept

        def keep(new: jax.Array, old: jax.Array, s: int = shift) -> jax.Array:
            reached = (index >= s).reshape((length,) + (1,) * (new.ndim - 1))
            return jnp.where(reached, new, old)

        maps = jax.tree_util.tree_map(keep, composed, maps)
        shift *= 2
    return maps
