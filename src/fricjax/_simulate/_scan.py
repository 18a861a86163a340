"""The sequential scan over time: the loop every model's free run and teacher-forced run goes through, and the
helpers that split a record's per-step signals from its constants."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from .._models._base import AbstractModel

# Loop unrolling of the scan: measured by benchmarks/simulate.py on the 2-core CPU (see benchmarks/README.md).
DEFAULT_UNROLL = 2
# ... and of the batch-minor free run under vmap (`model.batch_minor()`): 1 measured faster than 2 (Maxwell-slip)
BATCH_MINOR_UNROLL = 1


def plain_run(
    model: AbstractModel, samples: Any, state: Any, measured: Any, unroll: int, return_states: bool
) -> tuple[Any, Any]:
    steps, rebuild = split_time_signals(samples)

    def body(carry: Any, xs: tuple[Any, Any]) -> tuple[Any, Any]:
        step_signals, y_measured = xs
        carry, y = model.step(carry, rebuild(step_signals))
        if y_measured is not None:  # teacher forcing; the state keeps its dtype (float32 models, float64 data)
            forced = model.feedback(carry, y_measured)
            carry = jax.tree_util.tree_map(lambda new, old: jnp.asarray(new, jnp.result_type(old)), forced, carry)
        return carry, ((y, carry) if return_states else y)

    return jax.lax.scan(body, state, (steps, measured), unroll=unroll)


def join_signals(signals: list[Any], scalars: list[Any], is_step: list[bool]) -> list[Any]:
    """The leaf list of `split_time_signals` from the per-step signals and the scalar constants."""
    per_step, constant = iter(signals), iter(scalars)
    return [next(per_step) if flag else next(constant) for flag in is_step]


def split_time_signals(samples: Any) -> tuple[list[Any], Callable[[list[Any]], Any]]:
    """Split per-step samples into the signals along time (a list of leaves, `None` for the scalar constants)
    and a function rebuilding the samples from such a list (or from slices / segments of it)."""
    leaves, treedef = jax.tree_util.tree_flatten(samples)
    steps = [leaf if jnp.ndim(leaf) > 0 else None for leaf in leaves]

    def rebuild(step_leaves: list[Any]) -> Any:
        signals = [leaf if signal is None else signal for signal, leaf in zip(step_leaves, leaves, strict=True)]
        return jax.tree_util.tree_unflatten(treedef, signals)

    return steps, rebuild
