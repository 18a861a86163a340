"""The tangent-linear free run: a custom JVP whose tangent recurrence is one small linear scan."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from .._models._base import AbstractModel
from ._scan import join_signals, split_time_signals


def all_inexact(*trees: Any) -> bool:
    return all(jnp.issubdtype(jnp.result_type(leaf), jnp.inexact) for leaf in jax.tree_util.tree_leaves(trees))


def tangent_run(model: AbstractModel, samples: Any, state: Any, unroll: int) -> tuple[Any, Any]:
    """The free run of `run`, with a custom JVP (`AbstractModel.tangent_gradients`): for the step
    `s_k = f(s_k-1, u_k, theta)`, `y_k = g(s_k-1, u_k, theta)`, the tangent obeys the linear recurrence
    `ds_k = A_k ds_k-1 + b_k`, `dy_k = C_k ds_k-1 + e_k`, with `A_k = df/ds` and `C_k = dg/ds` taken at the stored
    states by one `vmap` of `jacfwd` over time and the forcings `b_k, e_k` by one `vmap` of `jvp` (the states
    held); only that small linear scan runs step by step. Reverse mode transposes it (the adjoint recurrence)."""
    params, static = eqx.partition(model, eqx.is_inexact_array)
    flat_state, unravel_state = ravel_pytree(state)
    steps, rebuild = split_time_signals(samples)
    is_step = [signal is not None for signal in steps]

    def step(theta: Any, s: jax.Array, signals: list[Any], scalars: list[Any]) -> tuple[jax.Array, Any]:
        new, y = eqx.combine(theta, static).step(unravel_state(s), rebuild(join_signals(signals, scalars, is_step)))
        return ravel_pytree(new)[0].astype(s.dtype), y

    def primal_scan(theta: Any, s0: jax.Array, signals: list[Any], body: Any) -> tuple[jax.Array, Any]:
        flat, unravel_theta = ravel_pytree(theta)  # one packed vector in the loop body (see below)
        return jax.lax.scan(lambda s, u: body(unravel_theta(flat), s, u), s0, signals, unroll=unroll)

    @jax.custom_jvp
    def scan(theta: Any, s0: jax.Array, signals: list[Any], scalars: list[Any]) -> tuple[jax.Array, Any]:
        return primal_scan(theta, s0, signals, lambda th, s, u: step(th, s, u, scalars))

    @scan.defjvp
    def scan_jvp(primals: tuple[Any, ...], tangents: tuple[Any, ...]) -> tuple[Any, Any]:
        theta, s0, signals, scalars = primals
        dtheta, ds0, dsignals, dscalars = tangents

        def body(th: Any, s: jax.Array, u: list[Any]) -> tuple[jax.Array, Any]:
            new, y = step(th, s, u, scalars)
            return new, (y, s)

        s_final, (ys, entering) = primal_scan(theta, s0, signals, body)
        a, c = jax.vmap(jax.jacfwd(lambda s, u: step(theta, s, u, scalars)))(entering, signals)

        def forcing(s: jax.Array, u: list[Any], du: list[Any]) -> tuple[jax.Array, Any]:
            def held(th: Any, u_: list[Any], k_: list[Any]) -> tuple[jax.Array, Any]:  # the entering state held
                return step(th, s, u_, k_)

            return jax.jvp(held, (theta, u, scalars), (dtheta, du, dscalars))[1]

        b, e = jax.vmap(forcing)(entering, signals, dsignals)

        def tangent(ds: jax.Array, xs: tuple[Any, ...]) -> tuple[jax.Array, Any]:
            a_k, c_k, b_k, e_k = xs
            # elementwise products and sums, not dot products: XLA:CPU fuses them into the loop body
            dy = jax.tree_util.tree_map(lambda c_, e_: jnp.sum(c_ * ds, axis=-1) + e_, c_k, e_k)
            return jnp.sum(a_k * ds, axis=1) + b_k, dy

        ds_final, dys = jax.lax.scan(tangent, ds0, (a, c, b, e), unroll=unroll)
        return (s_final, ys), (ds_final, dys)

    leaves = jax.tree_util.tree_leaves(samples)
    signals = [signal for signal in steps if signal is not None]
    scalars = [leaf for signal, leaf in zip(steps, leaves, strict=True) if signal is None]
    s_final, ys = scan(params, flat_state, signals, scalars)
    return unravel_state(s_final), ys
