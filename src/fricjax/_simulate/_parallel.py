"""The time-parallel free run: a model's per-sample state maps (`AbstractModel.parallel_maps`) composed in
O(log T) dependent rounds of O(T) parallel work, then the model's own `step` evaluated at every sample at once.

A sequential scan takes T dependent steps; on a GPU each is a kernel launch of a few microseconds, so one long
record runs hundreds of times slower than a compiled CPU loop. A parallel prefix (Hillis & Steele 1986; Blelloch
1990) takes log2 T rounds, which is what an accelerator does well; on a CPU the sequential loop is faster for most
models (more arithmetic, no parallelism to gain), so `scan="auto"` uses this form on accelerators only
(benchmarks/README.md, "Accelerators"). Values equal the sequential scan's to round-off; derivatives come from
`_states_after_jvp`, one more parallel scan, of affine maps (tests/test_parallel_scan.py).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from .._models._base import AbstractModel
from .._models._state_maps import AffineMaps, apply, compose, delayed, full_fields, is_state_maps
from ._scan import split_time_signals

SCANS = ("auto", "sequential", "parallel")
# `scan="auto"` takes the parallel form from this many samples on (on an accelerator): a sequential step costs about
# 10 us there, so the log-depth scan wins from a few dozen samples (H100: 1 000 samples 0.29 ms against 11 ms;
# benchmarks/README.md, "Accelerators")
PARALLEL_MIN_LENGTH = 256
# How the states after every sample are computed (`states_after`):
# - "blocked": the record cut into blocks of BLOCK samples; inside every block the prefix compositions by a loop
#   along the block (WITHIN = "sequential", BLOCK - 1 compositions of whole columns) or by doubling ("doubling");
#   the blocks' totals by doubling (ACROSS = "doubling") or blocked again ("blocked"); then each block's maps applied
#   to the state entering it;
# - "doubling": log2 T rounds over the whole record, each composing every map with the one 2^r samples earlier;
# - "blelloch": `jax.lax.associative_scan` (O(T) work in about 2 log2 T rounds of strided slices).
# H100, 10^6 samples, forward (benchmarks/README.md, "Accelerators", session of 2026-11-27): LuGre 0.66-0.73 ms
# blocked 8 / sequential / doubling, 0.68-0.78 ms other blocked forms, 0.90 ms doubling, 1.2 ms blelloch; Maxwell-slip
# NLR(7) 1.16-1.30 ms blocked 8 / sequential / doubling, 1.6-3.8 ms other blocked forms, 4.2 ms blelloch, 6.6-6.8 ms
# doubling.
PREFIX = "blocked"
BLOCK = 8
WITHIN = "sequential"
ACROSS = "doubling"
# How the doubling rounds run: "auto" in a `fori_loop` on CPU devices (XLA:CPU ran 17 unrolled rounds of clamp maps
# 27x slower than the same rounds in a loop) and unrolled on accelerators (as measured on the H100); "loop" or
# "unrolled" everywhere (benchmarks/parallel_scan.py --rounds)
ROUNDS = "auto"
# How reverse mode runs the tangent scan backwards: "jax" (default) JAX's own transpose of the affine prefix; "adjoint"
# the adjoint recurrence as one more affine prefix, backwards in time (`jax.custom_derivatives.linear_call`), which
# on a 2-core CPU takes Maxwell-slip NLR(7)'s gradient at 10^5 samples from 3.05-3.20x to 2.65-2.86x its forward pass
# (LuGre 2.47-2.50x -> 2.26-2.30x), equal to JAX's transpose to 2e-16, but cannot run under `jax.vmap`, `jacfwd` or
# `jacrev` (jax 0.10 has no batching rule for `linear_call`, nor a transpose rule for `custom_vmap`, which would
# supply one): a measured option of benchmarks/parallel_scan.py --transpose for the GPU (issue 33), not a default
TRANSPOSE = "jax"


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
                f"NLR, exact play operators, Dahl with alpha=fj.Fixed(1.0), static friction laws); "
                f"{type(model).__name__} has none here (a smooth clip, an FIR force map, a trained Dahl exponent, or "
                "a state that is not a composition of affine or clamp maps): use scan='auto' or 'sequential'."
            )
        return True
    return length >= PARALLEL_MIN_LENGTH and on_accelerator() and has_parallel_form(model, samples)


def parallel_run(model: AbstractModel, samples: Any, state: Any, return_states: bool = False) -> tuple[Any, Any]:
    """The free run of `run` in its time-parallel form: `(final_state, outputs)`, or `(final_state, (outputs,
    states))` with `return_states` (the state after every sample)."""
    maps = model.parallel_maps(samples)
    state = jax.tree_util.tree_map(jnp.asarray, state)
    if jax.tree_util.tree_leaves(maps):
        after = states_after(maps, state)
        entering = _entering(state, after)
    else:  # no state (a static law): every sample is evaluated at once
        entering = state
    steps, rebuild = split_time_signals(samples)
    leaving, outputs = jax.vmap(lambda s, signals: model.step(s, rebuild(signals)))(entering, steps)
    final = jax.tree_util.tree_map(lambda s: s[-1], leaving)
    return final, ((outputs, leaving) if return_states else outputs)


def _entering(state: Any, after: Any) -> Any:
    """The state entering every sample (or block): the initial `state`, then `after` shifted by one."""
    return jax.tree_util.tree_map(lambda s0, s: jnp.concatenate([jnp.asarray(s0, s.dtype)[None], s[:-1]]), state, after)


def states_after(maps: Any, state: Any, method: str | None = None) -> Any:
    """The state after every sample: the prefix compositions of `maps` applied to the initial `state`, by
    `method` (default `PREFIX`). Differentiated by `_states_after_jvp`."""
    return _states_after(PREFIX if method is None else method, full_fields(maps, state), state)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _states_after(method: str, maps: Any, state: Any) -> Any:
    if method == "blocked":
        return _blocked_states(maps, state, BLOCK)
    return apply(prefix_compositions(maps, method), state)


@_states_after.defjvp
def _states_after_jvp(method: str, primals: tuple[Any, Any], tangents: tuple[Any, Any]) -> tuple[Any, Any]:
    """The tangent of the states is itself a parallel scan, of affine maps: the maps act elementwise, so
    `dot s_k = J_k dot s_k-1 + dmap_k`, with `J_k` the derivative of map k with respect to the state entering it
    and `dmap_k` its derivative along the maps' own tangent, both at that state. One affine scan (two numbers per
    state component, linear in the tangents, so JAX transposes it for reverse mode) in place of differentiating
    every composition of the prefix (a clamp map's three fields through every round)."""
    maps, state = primals
    maps_dot, state_dot = tangents
    after = _states_after(method, maps, state)
    entering = _entering(state, after)
    linear = jax.tree_util.tree_map(
        lambda m, s, dm: m.linearised(s, dm), maps, entering, maps_dot, is_leaf=is_state_maps
    )
    # the tangents in the dtype of the states (a weakly typed Python-float initial state takes the maps' dtype)
    state_dot = jax.tree_util.tree_map(lambda d, s: jnp.asarray(d, s.dtype), state_dot, after)
    if TRANSPOSE == "adjoint":
        tangent = functools.partial(_affine_tangent, method)
        return after, jax.tree_util.tree_map(tangent, linear, state_dot, is_leaf=is_state_maps)
    return after, _states_after(method, linear, state_dot)


def _affine_tangent(method: str, linear: AffineMaps, state_dot: jax.Array) -> jax.Array:
    """`TRANSPOSE = "adjoint"`: the tangents of one state array after every sample, `ds_k = scale_k ds_k-1 + shift_k`
    from `state_dot`, as a linear function of the shifts with its own transpose (`_affine_transpose`). The initial
    tangent enters as part of the first sample's shift (`scale_0 state_dot`, what the first map does to it), so that
    the function has one linear argument, differentiated or constant as a whole (`linear_call` transposes only the
    first kind)."""
    first = linear.scale[:1] * state_dot[None] + linear.shift[:1]
    shift = jnp.concatenate([first, linear.shift[1:]]).astype(state_dot.dtype)
    return jax.custom_derivatives.linear_call(
        functools.partial(_affine_states, method), functools.partial(_affine_transpose, method), linear.scale, shift
    )


def _affine_states(method: str, scale: jax.Array, shift: jax.Array) -> jax.Array:
    """The states after every sample of `s_k = scale_k s_k-1 + shift_k` from `s = 0`."""
    return _states_after(method, AffineMaps(scale, shift), jnp.zeros_like(shift[0]))


def _affine_transpose(method: str, scale: jax.Array, cotangent: jax.Array) -> jax.Array:
    """The transpose of `_affine_states`: the adjoint recurrence `l_k = g_k + scale_k+1 l_k+1` (`l_k` the cotangent
    of `shift_k`, `g_k` that of the state after sample k), run backwards in time as one more prefix of affine maps
    (the scales reversed and shifted by one sample)."""
    reversed_scale = jnp.concatenate([jnp.ones_like(scale[:1]), jnp.flip(scale, axis=0)[:-1]])
    maps = AffineMaps(reversed_scale, jnp.flip(cotangent, axis=0).astype(scale.dtype))
    return jnp.flip(_states_after(method, maps, jnp.zeros_like(scale[0])), axis=0)


def _blocked_states(maps: Any, state: Any, block: int) -> Any:
    """`states_after` in blocks of `block` samples: the prefix compositions inside every block at once (`WITHIN`),
    the blocks' totals one level up (`ACROSS`), and each block's maps applied to the state entering it: a few
    passes over the whole record where doubling takes log2 T, the remaining rounds on T / `block` totals."""
    length = jax.tree_util.tree_leaves(maps)[0].shape[0]
    if length <= 2 * block:
        return apply(prefix_compositions(maps, "doubling"), state)
    blocks = -(-length // block)

    def split(leaf: jax.Array) -> jax.Array:  # the maps padded with zeros after the record (never read back)
        leaf = jnp.pad(leaf, [(0, blocks * block - length)] + [(0, 0)] * (leaf.ndim - 1))
        return leaf.reshape((blocks, block, *leaf.shape[1:]))

    within = _within_blocks(jax.tree_util.tree_map(split, maps))
    totals = jax.tree_util.tree_map(lambda leaf: leaf[:, -1], within)
    if ACROSS == "doubling":
        after = apply(prefix_compositions(totals, "doubling"), state)
    else:
        after = _blocked_states(totals, state, block)  # the state leaving every block
    entering = jax.tree_util.tree_map(lambda s: s[:, None], _entering(state, after))
    states = apply(within, entering)
    return jax.tree_util.tree_map(lambda s: s.reshape((blocks * block, *s.shape[2:]))[:length], states)


def _within_blocks(maps: Any) -> Any:
    """Prefix compositions along axis 1 (inside each block), by `WITHIN`."""
    if WITHIN == "doubling":
        return prefix_compositions(maps, "doubling", axis=1)
    block = jax.tree_util.tree_leaves(maps)[0].shape[1]
    column = [jax.tree_util.tree_map(lambda leaf, k=k: leaf[:, k], maps) for k in range(block)]
    prefix = [column[0]]
    for k in range(1, block):
        prefix.append(compose(prefix[-1], column[k]))
    return jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves, axis=1), *prefix)


def prefix_compositions(maps: Any, method: str = "doubling", axis: int = 0) -> Any:
    """Map k composed with every map before it (`maps[k] o ... o maps[0]`), for every k along `axis`: the state
    maps from the initial state to the state after each sample. `method`: "doubling" or "blelloch". On a CPU
    device the doubling rounds run in a `fori_loop` (benchmarks/README.md, "XLA:CPU and unrolled doubling
    rounds"); on an accelerator they are unrolled (as measured there)."""
    if method == "blelloch":
        return jax.lax.associative_scan(compose, maps, axis=axis)
    length = jax.tree_util.tree_leaves(maps)[0].shape[axis]
    if ROUNDS == "loop" or (ROUNDS == "auto" and not on_accelerator()):  # see ROUNDS
        rounds = (length - 1).bit_length()
        return jax.lax.fori_loop(0, rounds, lambda r, m: compose(delayed(m, jnp.left_shift(1, r), axis), m), maps)
    shift = 1
    while shift < length:  # after the round with shift s, map k holds the composition of samples k - 2s + 1 ... k
        maps = compose(delayed(maps, shift, axis), maps)  # identity maps before the first sample
        shift *= 2
    return maps
