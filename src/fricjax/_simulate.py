"""`simulate`: the one driver that runs any fricjax model over an input record as a `lax.scan`.

Free run (simulation, "NOE"), one-step-ahead prediction (teacher forcing through the model's `feedback`) and
k-step-ahead prediction all go through `run`, the only scan over time for models in the package: losses,
ensembles, systems, data generators and protocols call `simulate` or `run`, never a scan of their own.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from ._constraints import unwrap
from ._models._base import AbstractModel, feeds_back
from ._validation import positive_int

# Loop unrolling of the scan: measured by benchmarks/simulate.py on the 2-core CPU (see benchmarks/README.md).
DEFAULT_UNROLL = 2
# ... and of the batch-minor free run under vmap (`model.batch_minor()`): 1 measured faster than 2 (Maxwell-slip)
BATCH_MINOR_UNROLL = 1

# How the loop runs (not what it computes): the options of `simulate` and `run`, chosen in one place (`run`), in the
# way diffrax's `diffeqsolve(..., adjoint=)` is. Models declare what they support (`AbstractModel.batch_minor`,
# `packed_unroll`; the tangent path applies to free runs with floating-point states and signals, the scan's own
# derivative elsewhere: one-step / k-step prediction, integer states).
DERIVATIVES = ("auto", "scan", "tangent")
BATCHING = ("auto", "vmap", "batch_minor")


def check_options(model: Any, derivatives: Any, batching: Any, where: str = "simulate") -> None:
    """Validate `simulate`'s `derivatives` / `batching` for `model` (a clear error naming the argument)."""
    if derivatives not in DERIVATIVES:
        raise ValueError(f"{where}: `derivatives` must be one of {DERIVATIVES}, got {derivatives!r}.")
    if batching not in BATCHING:
        raise ValueError(f"{where}: `batching` must be one of {BATCHING}, got {batching!r}.")
    if model is None:
        return
    if batching == "batch_minor" and not unwrap(model).batch_minor():
        raise ValueError(
            f"{where}: batching='batch_minor' needs a model that declares it (LuGre, Maxwell-slip LR / NLR); "
            f"{type(model).__name__} does not: use batching='auto' or 'vmap'."
        )


def simulate(
    model: AbstractModel,
    inputs: Any,
    state0: Any = None,
    *,
    measured: Any = None,
    horizon: int | None = None,
    unroll: int | None = None,
    derivatives: str = "auto",
    batching: str = "auto",
) -> Any:
    """Run `model` along `inputs`: one jit-compiled `lax.scan` over time.

    Three modes (the vocabulary of system identification):

    - free run (default): the model runs on its own outputs from `state0`: simulation, output error (NOE);
    - one-step-ahead (`measured=y`): after each step the model's fed-back output is replaced by the measured
      one (`model.feedback(state, y_k)`), so sample k is predicted from measurements up to k-1;
    - k-step-ahead (`measured=y, horizon=k`): each sample t is predicted by a free run of k steps from the
      teacher-forced state at t-k (the first k-1 samples by the free run from `state0`). `horizon=1` is the
      one-step prediction.

    For a model without fed-back outputs (every physics model) the three modes coincide. Works under
    `jax.vmap` / `eqx.filter_vmap` over batches of models and of inputs, and is differentiable with respect to
    every parameter. Structure is checked on every call; values (NaN, `dt`) when the inputs are built.

    **Arguments:**

    - `model`: any fricjax model (`LuGre`, `GMS`, `MaxwellSlip`, an ensemble, a system, your own).
    - `inputs`: a `Motion` for friction models (signals the model needs are derived when missing), an
      `InputRecord` for systems.
    - `state0`: the initial state; `None` means `model.init_state()` (at rest).
    - `measured`: the measured outputs, shaped like the output (for a friction model the force, `(T,)`).
    - `horizon`: prediction horizon k >= 1 (needs `measured`); a horizon of T or more is the free run.
    - `unroll`: scan unrolling (performance only); `None`: `DEFAULT_UNROLL`, or the model's `packed_unroll`
      for a free run that is not differentiated.
    - `derivatives`: how the free run is differentiated (the values are the same; speed only): `"scan"` the scan's
      own JVP / VJP; `"tangent"` the tangent-linear recurrence (per-step state Jacobians in parallel over time,
      then one small linear scan; free runs with floating-point states; teacher-forced runs keep the scan's);
      `"auto"` (default) the scan's, or the tangent path for a model wrapped in the older `fj.TangentGradients`.
    - `batching`: how a free run batched by `jax.vmap` is laid out (speed only): `"batch_minor"` the batch as the
      loop's minor axis, outputs written in `(batch, time)` order (models that declare it: LuGre, Maxwell-slip LR /
      NLR); `"vmap"` vmap's own batching; `"auto"` (default) batch-minor where the model declares it.

    **Returns:** the outputs along time: the friction force `(T,)` for friction models.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> model = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4)
    >>> motion = fj.Motion.from_position(1e-4 * np.sin(np.linspace(0, 6.28, 500)), dt=1e-3)
    >>> fj.simulate(model, motion).shape
    (500,)
    ```
    """
    if not isinstance(model, AbstractModel):
        raise TypeError(
            f"simulate: `model` must be a fricjax model (an fj.AbstractModel: fj.LuGre, fj.GMS, ...), "
            f"got {type(model).__name__}."
        )
    model.check_inputs(inputs)
    if horizon is not None:
        horizon = positive_int(horizon, "horizon", "simulate", hint="(steps ahead)")
        if measured is None:
            raise ValueError("simulate: `horizon` needs the measured outputs: pass `measured=` (teacher forcing).")
    check_options(model, derivatives, batching)
    if measured is not None:  # arrays, never static Python values, under the jit
        measured = jax.tree_util.tree_map(jnp.asarray, measured)
    return _simulate(model, inputs, state0, measured, horizon, unroll, derivatives, batching)


@eqx.filter_jit
def _simulate(
    model: AbstractModel,
    inputs: Any,
    state0: Any,
    measured: Any,
    horizon: int | None,
    unroll: int | None,
    derivatives: str = "auto",
    batching: str = "auto",
) -> Any:
    model = unwrap(model)
    samples = model.samples(inputs)
    length = _length(samples)
    if measured is not None:
        measured = jax.tree_util.tree_map(jnp.asarray, measured)
        for leaf in jax.tree_util.tree_leaves(measured):
            if leaf.shape[:1] != (length,):
                raise ValueError(
                    f"simulate: `measured` must have one value per sample ({length}), got shape {leaf.shape}."
                )
    state = model.init_state() if state0 is None else state0
    if horizon is None or horizon == 1:
        _, outputs = run(model, samples, state, measured, unroll=unroll, derivatives=derivatives, batching=batching)
        return outputs
    if horizon >= length or not feeds_back(model):  # nothing is fed back within reach: the free run
        return run(model, samples, state, unroll=unroll, derivatives=derivatives, batching=batching)[1]
    return _k_step(model, samples, state, measured, horizon, unroll)


def run(
    model: AbstractModel,
    samples: Any,
    state: Any,
    measured: Any = None,
    *,
    unroll: int | None = None,
    return_states: bool = False,
    derivatives: str = "auto",
    batching: str = "auto",
) -> tuple[Any, Any]:
    """The scan itself (not jitted, no checks): `model` must be unwrapped (`fj.unwrap`), `samples` the model's
    per-step signals (`model.samples(inputs)`: leaves with a leading time axis; scalar leaves, such as `dt`, are
    constants closed over by the loop body). With `measured`, each step is followed by
    `model.feedback(state, measured_k)`.

    `derivatives` and `batching` as for `simulate` (checked there, by `check_options`); this is the one place they
    choose how the loop runs.

    **Returns:** `(final_state, outputs)`, or `(final_state, (outputs, states))` with `return_states=True`
    (the state after every sample, feedback applied).
    """
    free = measured is None and not return_states
    tangent = derivatives == "tangent" or (derivatives == "auto" and model.tangent_gradients())
    if free and tangent and _all_inexact(samples, state):
        return _tangent_run(model, samples, state, DEFAULT_UNROLL if unroll is None else unroll)
    batch_minor = model.batch_minor() and batching != "vmap"
    if free and (model.packed_unroll is not None or batch_minor):
        return _primal_run(model, samples, state, unroll, batch_minor)
    return _plain_run(model, samples, state, measured, DEFAULT_UNROLL if unroll is None else unroll, return_states)


def _plain_run(
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


def _primal_run(
    model: AbstractModel, samples: Any, state: Any, unroll: int | None, batch_minor: bool
) -> tuple[Any, Any]:
    """The free run of `run` for a model declaring a faster primal (`packed_unroll`, `batch_minor()`): a custom JVP
    whose rule is the JVP of the plain scan, so every derivative, of any order, is that of `_plain_run`; only the
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
        return _plain_run(
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
        sample = jax.tree_util.tree_unflatten(treedef, _join(signal, scalar, is_step))
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


def _all_inexact(*trees: Any) -> bool:
    return all(jnp.issubdtype(jnp.result_type(leaf), jnp.inexact) for leaf in jax.tree_util.tree_leaves(trees))


def _tangent_run(model: AbstractModel, samples: Any, state: Any, unroll: int) -> tuple[Any, Any]:
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
        new, y = eqx.combine(theta, static).step(unravel_state(s), rebuild(_join(signals, scalars, is_step)))
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


def _join(signals: list[Any], scalars: list[Any], is_step: list[bool]) -> list[Any]:
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


def _k_step(model: AbstractModel, samples: Any, state0: Any, measured: Any, k: int, unroll: int | None) -> Any:
    """k-step-ahead prediction: free runs of k samples from every teacher-forced state (see `simulate`)."""
    length = _length(samples)
    _, (_, forced) = run(model, samples, state0, measured, unroll=unroll, return_states=True)
    # the state entering sample j: state0 for j = 0, the teacher-forced state after sample j-1 otherwise
    entering = jax.tree_util.tree_map(lambda s0, s: jnp.concatenate([jnp.asarray(s0)[None], s[:-1]]), state0, forced)
    starts = jnp.arange(length - k + 1)
    steps, rebuild = split_time_signals(samples)

    def window(j: jax.Array) -> Any:  # the prediction of sample j + k - 1 from the state entering sample j
        start = jax.tree_util.tree_map(lambda s: s[j], entering)
        part = [None if a is None else jax.lax.dynamic_slice_in_dim(a, j, k) for a in steps]
        return jax.tree_util.tree_map(lambda y: y[-1], run(model, rebuild(part), start, unroll=unroll)[1])

    tail = jax.vmap(window)(starts)  # samples k-1 ... T-1
    head_part = [None if a is None else a[: k - 1] for a in steps]
    head = run(model, rebuild(head_part), state0, unroll=unroll)[1]  # samples 0 ... k-2: the free run from state0
    return jax.tree_util.tree_map(lambda h, t: jnp.concatenate([h, t]), head, tail)


def _length(samples: Any) -> int:
    return int(next(leaf for leaf in jax.tree_util.tree_leaves(samples) if jnp.ndim(leaf) > 0).shape[0])
