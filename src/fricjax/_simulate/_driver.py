"""`simulate`: the one driver that runs any fricjax model over an input record as a `lax.scan`.

Free run (simulation, "NOE"), one-step-ahead prediction (teacher forcing through the model's `feedback`) and
k-step-ahead prediction all go through `run`, the only scan over time for models in the package: losses,
ensembles, systems, data generators and protocols call `simulate` or `run`, never a scan of their own.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._constraints import unwrap
from .._models._base import AbstractFrictionModel, AbstractModel, feeds_back
from .._smoothing import is_concrete
from .._validation import got_model, positive_int
from ._parallel import SCANS, parallel_run, uses_parallel
from ._primal import primal_run
from ._scan import DEFAULT_UNROLL, plain_run, split_time_signals
from ._tangent import all_inexact, tangent_run

# How the loop runs (not what it computes): the options of `simulate` and `run`, chosen in one place (`run`), in the
# way diffrax's `diffeqsolve(..., adjoint=)` is. Models declare what they support (`AbstractModel.batch_minor`,
# `packed_unroll`; the tangent path applies to free runs with floating-point states and signals, the scan's own
# derivative elsewhere: one-step / k-step prediction, integer states).
DERIVATIVES = ("auto", "scan", "tangent")
BATCHING = ("auto", "vmap", "batch_minor")


def check_options(model: Any, derivatives: Any, batching: Any, where: str = "simulate", scan: Any = "auto") -> None:
    """Validate `simulate`'s `derivatives` / `batching` / `scan` for `model` (a clear error naming the argument;
    whether a model has the parallel form asked for by `scan="parallel"` is checked when the samples are known)."""
    if scan not in SCANS:
        raise ValueError(f"{where}: `scan` must be one of {SCANS}, got {scan!r}.")
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
    scan: str = "auto",
) -> Any:
    """Run `model` along `inputs`: one jit-compiled `lax.scan` over time, or its time-parallel form.

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
    - `scan`: how time is traversed (the values are the same to round-off; speed only): `"sequential"` one step
      after another (`lax.scan`); `"parallel"` the time-parallel form, a parallel prefix of the model's state
      maps in O(log T) depth (LuGre, exact Maxwell-slip LR / NLR, exact play operators, the classical Dahl model
      with `alpha=fj.Fixed(1.0)`, static laws; an error for other models); `"auto"` (default) the parallel form
      on a GPU / TPU for records of at least 256 samples when the model has one, the sequential scan otherwise
      (on a CPU the sequential loop is faster).
      Differentiated, the parallel form's tangent is one more parallel scan, of affine maps (`derivatives`
      applies to the sequential scan).

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
            f"got {got_model(model)}."
        )
    model.check_inputs(inputs)
    if horizon is not None:
        horizon = positive_int(horizon, "horizon", "simulate", hint="(steps ahead)")
        if measured is None:
            raise ValueError("simulate: `horizon` needs the measured outputs: pass `measured=` (teacher forcing).")
    check_options(model, derivatives, batching, scan=scan)
    if unroll is not None:  # 0 or True would unroll the whole record into one program (minutes of compilation)
        if isinstance(unroll, bool):
            raise TypeError("simulate: `unroll` must be a positive number of steps per loop iteration, got a bool.")
        unroll = positive_int(unroll, "unroll", "simulate", hint="(scan steps per loop iteration)")
    if state0 is not None:
        _check_state(model, state0)
    if measured is not None:  # arrays, never static Python values, under the jit
        if isinstance(measured, (list, tuple)) and all(np.ndim(item) == 0 for item in measured):
            measured = np.asarray(measured)  # a list of numbers is one signal, not a tree of scalars
        measured = jax.tree_util.tree_map(jnp.asarray, measured)
        for leaf in jax.tree_util.tree_leaves(measured):
            if is_concrete(leaf) and not bool(np.all(np.isfinite(np.asarray(leaf)))):
                raise ValueError("simulate: `measured` contains NaN or inf; clean or interpolate the record.")
    return _simulate(model, inputs, state0, measured, horizon, unroll, derivatives, batching, scan)


def _check_state(model: AbstractModel, state0: Any) -> None:
    """`state0` of the structure and shapes of `model.init_state()`: one line naming both where not (inside the
    model's step a wrong state fails with an error about tracers)."""
    expected = eqx.filter_eval_shape(lambda m: unwrap(m).init_state(), model)
    structure, given = jax.tree_util.tree_structure(expected), jax.tree_util.tree_structure(state0)
    shapes = [jnp.shape(leaf) for leaf in jax.tree_util.tree_leaves(expected)]
    got = [jnp.shape(leaf) for leaf in jax.tree_util.tree_leaves(state0)]
    if given != structure or got != shapes:  # type: ignore[operator]
        raise ValueError(
            f"simulate: `state0` must be shaped as {type(model).__name__}'s `init_state()` "
            f"({type(expected).__name__}, leaf shapes {shapes}), got {type(state0).__name__} with leaf shapes "
            f"{got}; start from `model.init_state()` "
            "or a state `fj.initialise` returns."
        )


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
    scan: str = "auto",
) -> Any:
    model = unwrap(model)
    check_force_shape(model, inputs, scalar=False)  # at trace time only
    samples = model.samples(inputs)
    length = _length(samples)
    if measured is not None:
        measured = jax.tree_util.tree_map(jnp.asarray, measured)
        expected = None
        if isinstance(model, AbstractFrictionModel):  # shaped as the model's outputs: one force per sample
            output = eqx.filter_eval_shape(lambda m, x: m.step(m.init_state(), x)[1], model, first_sample(samples))
            expected = (length, *output.shape)
        for leaf in jax.tree_util.tree_leaves(measured):
            if leaf.shape[:1] != (length,):
                raise ValueError(
                    f"simulate: `measured` must have one value per sample ({length}), got shape {leaf.shape}."
                )
            if expected is not None and leaf.shape != expected:
                raise ValueError(
                    f"simulate: `measured` must be shaped as the model's outputs, {expected}, got {leaf.shape}"
                    + ("; pass a 1-D array (np.ravel)." if expected == (length,) else ".")
                )
    state = model.init_state() if state0 is None else state0
    if horizon is None or horizon == 1:
        options: dict[str, Any] = {"derivatives": derivatives, "batching": batching, "scan": scan}
        return run(model, samples, state, measured, unroll=unroll, **options)[1]
    if horizon >= length or not feeds_back(model):  # nothing is fed back within reach: the free run
        return run(model, samples, state, unroll=unroll, derivatives=derivatives, batching=batching, scan=scan)[1]
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
    scan: str = "auto",
) -> tuple[Any, Any]:
    """The scan itself (not jitted, no checks): `model` must be unwrapped (`fj.unwrap`), `samples` the model's
    per-step signals (`model.samples(inputs)`: leaves with a leading time axis; scalar leaves, such as `dt`, are
    constants closed over by the loop body). With `measured`, each step is followed by
    `model.feedback(state, measured_k)`.

    `derivatives`, `batching` and `scan` as for `simulate` (checked there, by `check_options`); this is the one
    place they choose how the loop runs. A model that does not feed back outputs ignores `measured`.

    **Returns:** `(final_state, outputs)`, or `(final_state, (outputs, states))` with `return_states=True`
    (the state after every sample, feedback applied).
    """
    if measured is not None and not feeds_back(model):  # teacher forcing changes nothing: the free run
        measured = None
    if measured is None and uses_parallel(model, samples, scan, _length(samples)):
        return parallel_run(model, samples, state, return_states)
    free = measured is None and not return_states
    tangent = derivatives == "tangent" or (derivatives == "auto" and model.tangent_gradients())
    if free and tangent and all_inexact(samples, state):
        return tangent_run(model, samples, state, DEFAULT_UNROLL if unroll is None else unroll)
    batch_minor = model.batch_minor() and batching != "vmap"
    if free and (model.packed_unroll is not None or batch_minor):
        return primal_run(model, samples, state, unroll, batch_minor)
    return plain_run(model, samples, state, measured, DEFAULT_UNROLL if unroll is None else unroll, return_states)


def first_sample(samples: Any) -> Any:
    """The signals of a record's first sample (a `model.samples(...)` with its time axis taken at 0): what one
    `step` reads, for tracing its output's shape."""
    steps, rebuild = split_time_signals(samples)
    return rebuild([None if signal is None else signal[0] for signal in steps])


def check_force_shape(model: Any, motion: Any, *, scalar: bool = True) -> None:
    """A friction model fitted to a measured force must return one scalar force per sample; a force of shape (1,)
    broadcast against the measured (T,) force in the losses and fitted nothing (a custom model's mistake). By shape
    only (`eqx.filter_eval_shape` of one step: a model may hold functions, such as an MLP's activation); `fit`
    checks it (and `sweep` on several records, through their batch), `simulate` does not (a model may return more
    than the force, for diagnostics). A signal that `step` reads but `requires` does not name is named here too
    (`scalar=False`: only that, as `simulate` does when it traces)."""
    if not isinstance(model, AbstractFrictionModel):
        return

    def one_step(model: Any, motion: Any) -> Any:
        plain = unwrap(model)
        return plain.step(plain.init_state(), first_sample(plain.samples(motion)))[1]

    try:  # traced, never compiled: no program runs here
        force = eqx.filter_eval_shape(one_step, model, motion)
    except TypeError as err:  # a signal read that `requires` does not name arrives as None
        first = eqx.filter_eval_shape(lambda m, mo: first_sample(unwrap(m).samples(mo)), model, motion)
        missing = (
            [name for name, value in first._asdict().items() if value is None] if hasattr(first, "_asdict") else []
        )
        if "NoneType" not in str(err) or not missing:
            raise
        raise TypeError(
            f"{type(model).__name__}.step failed on a sample without {', '.join(missing)} ({err}): a signal that "
            f"`requires` ({', '.join(sorted(model.requires))}) does not name is None in the sample; add it there."
        ) from None
    if scalar and jnp.shape(force) != ():
        raise ValueError(
            f"{type(model).__name__}.step returned a force of shape {jnp.shape(force)}; fitted to a measured force, "
            "a friction model's step returns one scalar force [N] per sample (e.g. `jnp.reshape(force, ())`)."
        )


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
