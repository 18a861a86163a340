"""The faster free runs outside derivatives: packed parameters (`packed_unroll`) and the batch-minor layout under
vmap (`batch_minor()`), both behind a custom JVP whose rule is the plain scan's."""

from __future__ import annotations

import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from .._models._base import AbstractModel
from ._scan import BATCH_MINOR_UNROLL, DEFAULT_UNROLL, join_signals, plain_run, split_time_signals


def primal_run(
    model: AbstractModel, samples: Any, state: Any, unroll: int | None, batch_minor: bool
) -> tuple[Any, Any]:
    """The free run of `run` for a model declaring a faster primal (`packed_unroll`, `batch_minor()`): a custom JVP
    whose rule is the JVP of the plain scan, so every derivative, of any order, is that of `plain_run`; only the
    values outside derivatives take the faster forms (benchmarks/README.md):

    - `packed_unroll`: the parameters packed into one vector that the loop body unpacks. XLA:CPU builds a much
      faster loop from a body closing over one parameter vector than over many small parameter arrays (GMS,
      4 elements, unroll 1: ~110 against ~510 ns per step). Differentiated, the packed body is slower (nested
      derivatives 2.4-3x: tangents and cotangents gathered into the vector at every step), hence primal only.
    - `batch_minor` (the model declares `batch_minor()` and `batching` is not "vmap"): under `jax.vmap`,
      `_batch_minor_scan` (a `custom_vmap` rule) instead of vmap's own batching.
    """
    # every array of the model is an argument of the custom rules (a batched integer field must reach the vmap
    # rule as an argument, not as a constant it closes over); only the floating-point arrays are packed
    params, static = eqx.partition(model, eqx.is_array)
    primal_unroll = int(model.packed_unroll or DEFAULT_UNROLL) if unroll is None else unroll
    is_step = [signal is not None for signal in split_time_signals(samples)[0]]  # decided on one configuration

    def plain(theta: Any, samples_: Any, state_: Any) -> tuple[Any, Any]:
        return plain_run(
            eqx.combine(theta, static), samples_, state_, None, DEFAULT_UNROLL if unroll is None else unroll, False
        )

    def primal(theta: Any, samples_: Any, state_: Any) -> tuple[Any, Any]:
        if model.packed_unroll is None:
            return plain(theta, samples_, state_)
        floats, others = eqx.partition(theta, eqx.is_inexact_array)
        flat, unravel = ravel_pytree(floats)
        steps, rebuild = split_time_signals(samples_)

        def body(carry: Any, step_signals: Any) -> tuple[Any, Any]:
            return eqx.combine(unravel(flat), others, static).step(carry, rebuild(step_signals))

        return jax.lax.scan(body, state_, steps, unroll=primal_unroll)

    if batch_minor:
        primal = jax.custom_batching.custom_vmap(primal)

        @primal.def_vmap
        def primal_batched(size: int, in_batched: Any, theta: Any, samples_: Any, state_: Any) -> Any:
            batched_unroll = BATCH_MINOR_UNROLL if unroll is None else unroll
            out = _batch_minor_scan(static, size, in_batched, (theta, samples_, state_), is_step, batched_unroll)
            return out, jax.tree_util.tree_map(lambda _: True, out)

    def batched_alike(args: Any, outputs: Any) -> Any:
        """Under every vmap, the same batch axes for the primal's and the derivative rule's outputs (JAX takes
        a custom JVP's output axes from one and combines them with the other's): when the model is batch-minor,
        every output batched if any argument is, along axis 0 (as the custom_vmap rule batches them)."""
        if not batch_minor:
            return outputs
        flag = _any_nan(args)
        return jax.tree_util.tree_map(lambda leaf: _batched_like_the_rule(flag, leaf), outputs)

    @jax.custom_jvp
    def free_run(theta: Any, samples_: Any, state_: Any) -> tuple[Any, Any]:
        return batched_alike((theta, samples_, state_), primal(theta, samples_, state_))

    @free_run.defjvp
    def free_run_jvp(primals: tuple[Any, ...], tangents: tuple[Any, ...]) -> tuple[Any, Any]:
        out, out_tangent = jax.jvp(plain, primals, tangents)
        return batched_alike(primals, (out, out_tangent))

    return free_run(params, samples, state)


def _any_nan(tree: Any) -> jax.Array:
    """Whether any array of `tree` holds a NaN: a flag that depends on every one of them (batched if any is)."""
    flags = [jnp.any(leaf != leaf) for leaf in jax.tree_util.tree_leaves(tree)]
    return functools.reduce(jnp.logical_or, flags, jnp.asarray(False))


def _batched_like_the_rule(flag: jax.Array, leaf: Any) -> Any:
    """`leaf` itself, except that under `jax.vmap` it is batched whenever `flag` is, along axis 0: the batch axes
    the custom_vmap rule gives every output of a batched free run.

    JAX batches a jitted custom JVP with the output batch axes of its primal and batches its derivative rule later,
    when the program is differentiated, and combines the two without reconciling them, so both must batch every
    output alike. Two differences are removed here: an output that reads no batched argument (Maxwell-slip's
    forces do not read `dt`) is batched by the rule but not by vmap's batching of the plain scan, nor by an outer
    vmap around the rule's own operations; it is made to depend on `flag` (a select between two equal values,
    which XLA removes). And vmap stacks the plain scan's outputs with the batch along axis 1: a reshape, whose vmap
    rule moves the batch axis to the front, puts it first. Without them a vmap over `dt` alone gave a third of the
    gradient, and `jax.jvp(jax.vmap(fj.simulate))` read a `(T, B)` array as `(B, T)` (tests/test_batch_minor.py;
    JAX issue 16374 reports a mismatch of the same kind)."""
    leaf = jnp.asarray(leaf)
    if leaf.dtype == jax.dtypes.float0:
        return leaf
    leaf = jnp.where(flag, leaf, leaf)
    return jax.lax.squeeze(jax.lax.reshape(leaf, (1, *leaf.shape)), (0,))


def _batch_minor_scan(
    static: Any,
    size: int,
    in_batched: tuple[Any, Any, Any],
    args: tuple[Any, Any, Any],
    is_step: list[bool],
    unroll: int,
) -> tuple[Any, Any]:
    """The free run of a batch of `size` configurations (`args`: parameters, samples, state, each leaf batched
    along axis 0 where `in_batched` says so; `is_step`: which sample leaves are signals along time) with the batch
    as the last, minor axis of every array in the loop, and the outputs written straight into `(batch, time, ...)`
    buffers, one column per step.

    vmap's own batching of the scan puts the batch first: a model's element vector (Maxwell-slip's M
    deflections) is then a short minor axis, and its outputs are stacked time-major, so that returning them in
    vmap's `(batch, time)` layout transposes the whole output (32 MB for 1024 x 4 000 samples) after the loop.
    Batch-minor, each element is one contiguous vector over the batch (the sum over elements a vector add), and
    a column written per step lands in the rows' cache lines, which stay in cache for the next steps
    (Maxwell-slip NLR(7), 1024 x 4 000 steps, two devices: 4.8 -> 3.1 ns per trajectory-step;
    benchmarks/README.md). Unbatched parameters and state are broadcast; unbatched scalar signals stay scalars.
    **Returns:** `(final_state, outputs)`, every leaf batched along axis 0.
    """
    theta, samples, state = args
    theta_batched, samples_batched, state_batched = in_batched

    def minor(leaf: Any, batched: bool) -> Any:  # (B, ...) -> (..., B); an unbatched leaf broadcast to it
        leaf = jnp.asarray(leaf)
        return jnp.moveaxis(leaf, 0, -1) if batched else jnp.broadcast_to(leaf[..., None], (*leaf.shape, size))

    theta_m = jax.tree_util.tree_map(minor, theta, theta_batched)
    state_m = jax.tree_util.tree_map(minor, state, state_batched)
    leaves, treedef = jax.tree_util.tree_flatten(samples)
    flags = jax.tree_util.tree_leaves(samples_batched)
    signals, signal_axes, scalars, scalar_axes = [], [], [], []
    for leaf, batched, along_time in zip(leaves, flags, is_step, strict=True):
        leaf = jnp.asarray(leaf)
        if not along_time:  # a constant of the record (`dt`): a scalar, or (B,) batched
            scalars.append(leaf)
            scalar_axes.append(-1 if batched else None)
            continue
        if batched:
            leaf = jnp.moveaxis(leaf, 0, -1)  # (T, ..., B)
        elif leaf.ndim > 1:  # a per-step vector shared by the batch: broadcast, so the step sees one layout
            leaf = jnp.broadcast_to(leaf[..., None], (*leaf.shape, size))
        signals.append(leaf)
        signal_axes.append(-1 if leaf.ndim > 1 else None)

    def one(th: Any, carry: Any, signal: list[Any], scalar: list[Any]) -> tuple[Any, Any]:
        sample = jax.tree_util.tree_unflatten(treedef, join_signals(signal, scalar, is_step))
        return eqx.combine(th, static).step(carry, sample)

    step = jax.vmap(one, in_axes=(-1, -1, signal_axes, scalar_axes), out_axes=-1)
    length = signals[0].shape[0]
    one_step = [jax.ShapeDtypeStruct(leaf.shape[1:], leaf.dtype) for leaf in signals]
    _, per_step = jax.eval_shape(step, theta_m, state_m, one_step, scalars)  # output leaves (..., B)

    def buffer(leaf: jax.ShapeDtypeStruct) -> jax.Array:  # (B, T, ...)
        return jnp.zeros((size, length, *leaf.shape[:-1]), leaf.dtype)

    def body(carry: Any, signal: list[Any]) -> tuple[Any, None]:
        t, state_, out = carry
        state_, y = step(theta_m, state_, signal, scalars)

        def write(rows: jax.Array, column: jax.Array) -> jax.Array:
            return jax.lax.dynamic_update_index_in_dim(  # t counts from 0: no wrapping of negative indices
                rows, jnp.moveaxis(column, -1, 0), t, 1, allow_negative_indices=False
            )

        return (t + 1, state_, jax.tree_util.tree_map(write, out, y)), None

    start = (jnp.zeros((), jnp.int32), state_m, jax.tree_util.tree_map(buffer, per_step))
    (_, final, outputs), _ = jax.lax.scan(body, start, signals, unroll=unroll)
    return jax.tree_util.tree_map(lambda leaf: jnp.moveaxis(leaf, -1, 0), final), outputs
