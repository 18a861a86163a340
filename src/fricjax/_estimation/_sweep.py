"""Hyperparameter sweeps as one vmap-ed program: `stack_models` and `sweep`.

Models of different orders, widths or network sizes are compared in one compiled program by giving them one
maximal shape and masking what a configuration does not use (`fj.NARXRegressors(input_mask=, output_mask=)`,
`unit_mask=` of the networks): the masks are array leaves, so a batch of configurations is a batch of arrays,
and `jax.vmap` trains them side by side. Seeds are a batch of initial weights; learning rates a batch of
numbers (`optax.inject_hyperparams`). This is the design card's "vmap-ed hyperparameter sweeps".
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._constraints import trainable_filter
from .._data._record import FrictionData
from .._validation import got_model, nonnegative_int, positive_int
from .loop._loop import Search, batched_losses, run_stage
from .loop._sharding import shard_batch
from .loop._solution import RESULTS, Solution
from .loop._solvers import OptaxSolver
from .problem._losses import AbstractLoss, SimulationLoss
from .problem._problem import Problem, held_paths, parameter_specs
from .problem._records import Nuisances, RecordBatch, RecordsLoss, as_record_batch, check_burn_in, check_records


def stack_models(models: Sequence[Any]) -> Any:
    """Stack models of one structure (same classes, static fields and array shapes) along a new leading axis,
    for `jax.vmap` / `fj.sweep`. Configurations that differ in order or width must share one maximal shape and
    differ by their masks; the error names the first field that differs."""
    models = list(models)
    if not models:
        raise ValueError("stack_models: give at least one model.")
    first = jax.tree_util.tree_structure(models[0])
    for i, model in enumerate(models[1:], start=1):
        if jax.tree_util.tree_structure(model) != first:  # type: ignore[operator]
            where = _first_difference(models[0], model)
            raise ValueError(
                f"stack_models: model {i} differs in structure from model 0"
                + (f" at {where}" if where else "")
                + " (class, static fields such as the number of lags or the smoothing, or None fields); a physics "
                "model needs one class, element count and kind of smoothing (fj.Smooth or fj.Exact) in every "
                "configuration; NARX models: build every configuration at one maximal shape and switch lags and "
                "units off with masks (NARXRegressors(input_mask=, output_mask=), unit_mask=)."
            )
        for (path, a), b in zip(
            jax.tree_util.tree_leaves_with_path(models[0]), jax.tree_util.tree_leaves(model), strict=True
        ):
            if not (_stackable(a) and _stackable(b)):  # a function (an MLP's activation): shared, not stacked
                if a is not b:
                    raise ValueError(
                        f"stack_models: model {i} holds another {type(b).__name__} at {jax.tree_util.keystr(path)} "
                        "than model 0; configurations share their functions (only arrays and numbers are stacked)."
                    )
                continue
            if np.shape(a) != np.shape(b):
                raise ValueError(
                    f"stack_models: model {i} has shape {np.shape(b)} at {jax.tree_util.keystr(path)}, model 0 has "
                    f"{np.shape(a)}; a physics model needs one element count in every configuration (sweep each "
                    "count on its own), NARX models one maximal shape and masks."
                )
    return jax.tree_util.tree_map(
        lambda *leaves: jnp.stack([jnp.asarray(x) for x in leaves]) if _stackable(leaves[0]) else leaves[0], *models
    )


def _stackable(leaf: Any) -> bool:
    """Arrays and numbers are stacked along the configurations; other leaves (functions) are shared."""
    return isinstance(leaf, (jax.Array, np.ndarray, np.number, np.bool_, int, float, complex))


def _first_difference(a: Any, b: Any, path: str = "model") -> str:
    """Where two models first differ in structure (a class, a static value, a container's length or keys), as
    `"model.smoothing (Exact against Smooth)"`; "" where only array values differ."""
    if type(a) is not type(b):
        return f"{path} ({type(a).__name__} against {type(b).__name__})"
    if isinstance(a, eqx.Module):
        for field in dataclasses.fields(a):
            x, y = getattr(a, field.name, None), getattr(b, field.name, None)
            if field.metadata.get("static", False):  # a static field (lags, degree): part of the structure
                if not _same(x, y):
                    return f"{path}.{field.name} ({x!r} against {y!r})"
                continue
            found = _first_difference(x, y, f"{path}.{field.name}")
            if found:
                return found
        return ""
    if isinstance(a, (list, tuple)):
        if len(a) != len(b):
            return f"{path} (length {len(a)} against {len(b)})"
        return next(
            (d for i, (x, y) in enumerate(zip(a, b, strict=True)) if (d := _first_difference(x, y, f"{path}[{i}]"))), ""
        )
    if isinstance(a, dict):
        if set(a) != set(b):
            return f"{path} (keys {sorted(map(str, a))} against {sorted(map(str, b))})"
        return next((d for k in a if (d := _first_difference(a[k], b[k], f"{path}[{k!r}]"))), "")
    if a is None or eqx.is_array(a) or isinstance(a, (int, float, complex, np.generic)) and not isinstance(a, bool):
        return ""  # array values (and Python numbers, which are leaves) may differ
    return "" if _same(a, b) else f"{path} ({a!r} against {b!r})"


def _same(a: Any, b: Any) -> bool:
    """`a == b` as one bool; True for values that do not compare to one (left to the structure check's message)."""
    try:
        return bool(a == b)
    except Exception:
        return True


def sweep(
    models: Any,
    data: Any,
    *,
    loss: AbstractLoss | None = None,
    learning_rate: float | Sequence[float] | np.ndarray = 1e-2,
    optimiser: Any = optax.adam,
    steps: int = 500,
    validation: Any = None,
    validation_burn_in: int = 0,
    checks: int = 10,
    progress: bool = False,
    nuisances: Nuisances | None = None,
) -> Solution:
    """Train a batch of configurations side by side in one vmap-ed, jit-compiled program.

    **Arguments:**

    - `models`: a list of models of one structure (`fj.stack_models` is applied) or an already stacked batch.
    - `data`: the training `fj.FrictionData`, shared by every configuration, or a list of records of one device (as
      `fj.fit`: per-record nuisances `nuisances`, default `fj.Nuisances()`, the loss the mean of the records' NMSEs).
    - `loss`: any fricjax loss (default `fj.SimulationLoss()`, output error; `fj.OneStepLoss()` teacher forcing).
    - `learning_rate`: one number, or one per configuration (a sweep over learning rates).
    - `optimiser`: an optax optimiser factory taking `learning_rate` (default `optax.adam`).
    - `steps`: optimiser steps; `checks`: how often the training loss is recorded (and the bar advanced).
    - `validation`, `validation_burn_in`: a record scored by free run after the burn-in samples (a list of records
      with a list as `data`, each scored with its least-squares offset).

    With several local devices the configurations are sharded over them (`fj.shard_batch`: as many devices as
    divide the batch); the results are those of one device.

    **Returns:** one batched `fj.Solution`: `model` the stacked configurations (`solution[i]` is configuration
    `i`'s own `Solution`, its model unbatched), each where its training loss was lowest (its start and each check:
    never worse than its start); `train_loss`, `val_loss` `(B,)` of the returned models; `history` (`step`, and
    `train_loss` of shape `(checks, B)`: the loss after each check); `result` per configuration, `max_steps` (a sweep
    runs its `steps`; no convergence test) or `diverged` (its loss became non-finite: it keeps its best finite
    parameters), named by `codes`; `best_configuration`; `wall_time` [s] (compilation included).

    ```python
    >>> import jax, numpy as np, fricjax as fj
    >>> data = fj.make_tribometer("sliding", seed=0, duration=0.5).train
    >>> reg = lambda mask: fj.NARXRegressors(("v",), 0, 2, output_mask=mask)
    >>> models = [fj.MLPNARX.init(reg(m), 4, key=jax.random.PRNGKey(0)) for m in ([1, 0], [1, 1])]
    >>> result = fj.sweep(models, data, loss=fj.OneStepLoss(), steps=20)
    >>> result.train_loss.shape
    (2,)
    ```
    """
    start_time = time.perf_counter()
    loss = SimulationLoss() if loss is None else loss
    if not isinstance(loss, AbstractLoss):
        raise TypeError(f"sweep: `loss` must be a fricjax loss (fj.SimulationLoss(), ...), got {type(loss).__name__}.")
    steps = positive_int(steps, "steps", "sweep")
    checks = positive_int(checks, "checks", "sweep")
    validation_burn_in = nonnegative_int(validation_burn_in, "validation_burn_in", "sweep")
    batch = stack_models(models) if isinstance(models, (list, tuple)) else models
    arrays = [leaf for leaf in jax.tree_util.tree_leaves(batch) if eqx.is_array(leaf)]
    sizes = {int(np.shape(leaf)[0]) if np.ndim(leaf) else -1 for leaf in arrays}
    if len(sizes) != 1 or -1 in sizes:
        raise ValueError(
            "sweep: `models` must be a list of models or a stack of them (every array with one leading batch axis); "
            f"got {got_model(models)}"
            + (
                ", one model or a stack with arrays of different leading sizes: pass a list, e.g. [model]."
                if not isinstance(models, (list, tuple))
                else "."
            )
        )
    (count,) = sizes
    if not callable(optimiser):
        raise TypeError(
            f"sweep: `optimiser` must be an optax optimiser factory taking `learning_rate` (e.g. optax.adam), got "
            f"{type(optimiser).__name__}, an optimiser already built; the rates come from `learning_rate`."
        )
    rates = np.asarray(learning_rate, dtype=float)
    if rates.ndim == 0 or rates.shape == (1,):
        rates = np.broadcast_to(rates.reshape(()), (count,))
    if rates.shape != (count,) or not bool(np.all(np.isfinite(rates) & (rates > 0))):
        raise ValueError(f"sweep: `learning_rate` must be positive and finite, one number or one per model ({count}).")

    one = jax.tree_util.tree_map(lambda leaf: leaf[0] if eqx.is_array(leaf) else leaf, batch)
    val_loss_fn: AbstractLoss = SimulationLoss(burn_in=validation_burn_in)
    if isinstance(data, (list, tuple, dict, RecordBatch)):  # several records: per-record nuisances, as fj.fit
        nuisances = Nuisances() if nuisances is None else nuisances
        data = as_record_batch(data, one, "data")
        loss, extra0 = RecordsLoss(loss, nuisances).bind_and_start(one, data)
        val_loss_fn = loss.validation_loss()
        if isinstance(validation, FrictionData):  # one validation record, as fj.fit takes it
            validation = [validation]
        if isinstance(validation, (list, tuple, dict)):
            starts = [validation_burn_in] * len(validation)
            validation = as_record_batch(validation, one, "validation", starts)
    elif nuisances is not None:
        raise ValueError("sweep: `nuisances` are per-record parameters of a sweep over several records; pass a list.")
    else:
        check_records(one, data, validation, loss, "sweep")
    check_burn_in(loss, data, "data", "sweep")
    if isinstance(validation, FrictionData):
        check_burn_in(val_loss_fn, validation, "validation", "sweep", "validation_burn_in")
    elif isinstance(validation, RecordBatch):  # the training loss's burn-in applies to them too
        check_burn_in(val_loss_fn, validation, "validation", "sweep")
    spec = trainable_filter(one)
    if isinstance(loss, RecordsLoss):  # each record's offset and initial state replace the model's own, as fj.fit
        spec = parameter_specs(one, None, held_paths(one, loss.nuisances), (), loss, data)[0]
    params, static = eqx.partition(batch, spec)
    if not isinstance(loss, RecordsLoss):
        extra0 = loss.init_extra(one, data)
    extras = jax.tree_util.tree_map(lambda e: jnp.broadcast_to(e, (count,) + jnp.shape(e)), extra0)
    problem = Problem(loss, None, None, None, None, data, None, loss)
    ys = (params, extras)
    try:
        states = _init_states(ys, jnp.asarray(rates), optimiser)
    except (TypeError, jax.errors.ConcretizationTypeError) as err:  # a rate it cannot take traced, per configuration
        raise TypeError(
            f"sweep: `optimiser` {getattr(optimiser, '__name__', optimiser)!r} cannot take one learning rate per "
            f"configuration (optax.inject_hyperparams: {type(err).__name__}); sweep runs first-order optax optimisers "
            "(optax.adam, optax.sgd, ...): fit line-search ones (optax.lbfgs) with fj.fit."
        ) from None
    # the configurations spread over every local device (as many as divide the batch; identity on one device)
    ys, static, states = shard_batch((ys, static, states))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=steps, desc=f"sweep x{count}", leave=False)
    # the one optimisation loop: each configuration's own rate sits in its optimiser state (inject_hyperparams)
    solver = _injected_solver(optimiser)
    search = Search(ys, False, start_time, bar)
    search.restart(*batched_losses(problem, ys, static, True))  # the start is each configuration's first best
    run_stage(
        solver, problem, search, static, budget=steps, check_every=max(1, steps // checks), states=states,
        batched_args=True,
    )  # fmt: skip
    search.close()
    # each configuration at its lowest training loss, its start and the checks (the last iterate of a learning rate
    # too high can be worse than its start)
    trained = eqx.combine(search.best_ys[0], static)
    train_loss = np.asarray(_batch_loss(trained, loss, search.best_ys[1], data))
    val_loss = np.full(count, np.nan)
    if validation is not None:
        val_loss = np.asarray(_batch_loss(trained, val_loss_fn, None, validation))
    diverged = np.asarray(search.diverged, dtype=bool)
    bad = int(diverged.sum())
    outcome = f"{bad} of {count} diverged (each kept its best finite parameters); " if bad else ""
    return Solution(
        model=trained,
        result=jax.vmap(lambda bad: RESULTS.where(bad, RESULTS.diverged, RESULTS.max_steps))(jnp.asarray(diverged)),
        message=f"{outcome}each configuration ran {steps} optimiser steps (a sweep has no convergence test) and is "
        "returned at its lowest training loss",
        history={"step": np.asarray(search.history["step"]), "train_loss": np.asarray(search.history["train_loss"])},
        train_loss=train_loss,
        val_loss=val_loss,
        exact_val_loss=np.full(count, np.nan),
        evaluations=steps,
        wall_time=time.perf_counter() - start_time,
        num_starts=count,
    )


# Module-level jitted pieces (the loss, data and optimiser factory are arguments, not closures), so that a second
# sweep of the same shapes reuses the compilation.


@functools.lru_cache(maxsize=16)
def _injected_solver(optimiser: Any) -> OptaxSolver:
    """The solver of a sweep with `optimiser`, one object per factory: a second sweep reuses the compiled loop. Its
    rate 1.0 is a placeholder: each configuration's rate is a hyperparameter in its state (`_init_states`)."""
    return OptaxSolver(optax.inject_hyperparams(optimiser)(learning_rate=1.0))


@eqx.filter_jit
def _init_states(ys: Any, rates: Any, optimiser: Any) -> Any:
    make = optax.inject_hyperparams(optimiser)
    return jax.vmap(lambda y, lr: make(learning_rate=lr).init(y))(ys, rates)


@eqx.filter_jit
def _batch_loss(models: Any, loss: AbstractLoss, extras: Any, data: Any) -> Any:
    """The loss of every configuration with its own extra decision variables (`extras` batched; None: none)."""
    if extras is None:
        return eqx.filter_vmap(lambda m: loss(m, None, data))(models)
    return eqx.filter_vmap(lambda m, e: loss(m, e, data))(models, extras)
