"""`fit`'s arguments checked and brought to one form before anything is built (`checked_arguments`: the loss, the
records, several records as a batch with per-record nuisances, the keyword strategies), and the state the driver's
phases fill (`FitState`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import optax

from .._data._record import FrictionData
from .._validation import nonnegative_float, nonnegative_int, optional, positive_int, seed_value
from .loop._solvers import as_solver
from .loop._strategies import (
    AbstractStrategy,
    Continuation,
    EarlyStopping,
    MultiStart,
    ParameterScaling,
    Separable,
    Tolerance,
)
from .problem._losses import AbstractLoss, SimulationLoss
from .problem._problem import (
    held_paths,
    selector_items,
    selector_paths,
)
from .problem._records import (
    Nuisances,
    RecordBatch,
    RecordsLoss,
    as_record_batch,
    check_burn_in,
    check_records,
)

# one object, so that repeated fits with the default solver hit the same compilation
DEFAULT_SOLVER = optax.adam(1e-2)


@dataclasses.dataclass
class FitState:
    """One fit's state as the driver's phases fill it: the checked arguments (`checked_arguments`), the problem and
    its starts (`_fit._build_problem`), how the stages ended (`_fit._run_stages`)."""

    model: Any
    data: Any
    validation: Any
    loss: Any
    val_loss_fn: Any
    solver: Any
    steps: int
    eval_every: int | None
    seed: int
    freeze: Any
    strategies: list[AbstractStrategy]
    plan: Any = None
    problem: Any = None
    spec: Any = None
    linear_spec: Any = None
    params0: Any = None
    static: Any = None
    own_width: float = 0.0
    count: int = 1
    ys0: Any = None
    tolerance: float | None = None
    patience: int | None = None
    linear_only: bool = False
    code: str = "max_steps"
    message: str = ""
    outcome: Any = None
    converged: str = ""
    screened: str = ""


def checked_arguments(
    model: Any,
    data: Any,
    *,
    loss: Any,
    solver: Any,
    steps: Any,
    validation: Any,
    validation_burn_in: Any,
    train: Any,
    freeze: Any,
    nuisances: Any,
    eval_every: Any,
    seed: Any,
    strategies: Any,
    keyword_strategies: tuple[Any, ...],
) -> FitState:
    """`fit`'s arguments checked and brought to one form (several records: a batch with per-record nuisances);
    `keyword_strategies` are the values of `fit`'s `scaling`, `multistart`, `continuation`, `separable`, `patience`,
    `tolerance`, in that order."""
    loss = SimulationLoss() if loss is None else loss
    if not isinstance(loss, AbstractLoss):
        raise TypeError(f"fit: `loss` must be a fricjax loss (fj.SimulationLoss(), ...), got {type(loss).__name__}.")
    both = sorted(set(selector_paths(train)) & set(selector_paths(freeze))) if train is not None else []
    if both:  # the user's own freeze: the nuisances a fit to several records holds per record are not theirs
        raise ValueError(
            f"fit: {', '.join(map(repr, both))} is in both `train` and `freeze`; name a parameter in one of them "
            "(`freeze` narrows `train`: train='stribeck', freeze='stribeck.vs')."
        )
    if isinstance(data, (list, tuple, dict, RecordBatch)):  # several records: shared parameters, per-record nuisances
        data, validation, loss, freeze = _several_records(
            model, data, validation, validation_burn_in, loss, nuisances, freeze
        )
        validation_burn_in = None
    elif nuisances is not None:
        raise ValueError(
            "fit: `nuisances` are per-record parameters of a fit to several records; pass a list of records as `data`."
        )
    elif isinstance(validation, (list, tuple, dict, RecordBatch)):
        raise ValueError("fit: a list of validation records needs a list of training records as `data`.")
    check_records(model, data, validation, loss)
    steps = positive_int(steps, "steps", "fit")
    eval_every = optional(positive_int, eval_every, "eval_every", "fit")
    seed = seed_value(seed, "seed", "fit")
    solver = as_solver(DEFAULT_SOLVER if solver is None else solver)
    for strategy in strategies:
        if not isinstance(strategy, AbstractStrategy):
            raise TypeError(
                "fit: `strategies` takes fj.AbstractStrategy objects (fj.MultiStart, fj.Continuation, "
                f"fj.ParameterScaling, fj.Separable, fj.EarlyStopping, fj.Tolerance), got {type(strategy).__name__}."
            )
    strategies = [*_keyword_strategies(*keyword_strategies), *strategies]
    val_loss_fn = loss.validation_loss() if validation_burn_in is None else _burn_in_loss(loss, validation_burn_in)
    if validation is not None and getattr(val_loss_fn, "burn_in", 0) >= validation.length:
        raise ValueError(
            f"fit: the validation burn-in ({getattr(val_loss_fn, 'burn_in', 0)} samples) leaves nothing to score "
            f"in a validation record of {validation.length} samples; lower `validation_burn_in` or pass more data."
        )
    check_burn_in(loss, data, "data", "fit")
    if isinstance(validation, RecordBatch):
        check_burn_in(val_loss_fn, validation, "validation", "fit")
    return FitState(model, data, validation, loss, val_loss_fn, solver, steps, eval_every, seed, freeze, strategies)


def _several_records(
    model: Any, data: Any, validation: Any, validation_burn_in: Any, loss: Any, nuisances: Any, freeze: Any
) -> tuple[RecordBatch, Any, RecordsLoss, Any]:
    """A fit to several records: the padded batches, the loss summed over records, and the model's own offsets
    frozen where each record has one (and the fields that set its state at rest, where each record's initial state
    is estimated)."""
    nuisances = Nuisances() if nuisances is None else nuisances
    if not isinstance(nuisances, Nuisances):
        raise TypeError(f"fit: `nuisances` must be fj.Nuisances(offset=, drift=, initial_state=), got {nuisances!r}.")
    if isinstance(loss, RecordsLoss):
        loss = loss.loss
    batch = as_record_batch(data, model, "data")
    if isinstance(validation, FrictionData):
        validation = [validation]
    if isinstance(validation, (list, tuple, dict)):
        burn_in = (
            None if validation_burn_in is None else nonnegative_int(validation_burn_in, "validation_burn_in", "fit")
        )
        starts = None if burn_in is None else [burn_in] * len(validation)
        validation = as_record_batch(validation, model, "validation", starts)
    elif validation is not None and not isinstance(validation, RecordBatch):
        raise TypeError(f"fit: `validation` must be records like `data`, got {type(validation).__name__}.")
    held = held_paths(model, nuisances)  # one offset and one initial state per record replace the model's own
    if held:
        freeze = (*selector_items(freeze), *held)
    return batch, validation, RecordsLoss(loss, nuisances), freeze


def _keyword_strategies(
    scaling: Any, multistart: Any, continuation: Any, separable: Any, patience: Any, tolerance: Any
) -> list[AbstractStrategy]:
    """The strategies `fit`'s keywords stand for (thin compatibility: each keyword is one strategy)."""
    out: list[AbstractStrategy] = []
    if continuation is not None:
        if not isinstance(continuation, Continuation):
            raise TypeError(
                f"fit: `continuation` must be fj.Continuation(eps_start, eps_end, stages), got {continuation!r}."
            )
        out.append(continuation)
    if separable:
        out.append(Separable(separable))
    if scaling is not None:
        if not isinstance(scaling, ParameterScaling):
            raise TypeError(f"fit: `scaling` must be fj.ParameterScaling(...), got {scaling!r}.")
        out.append(scaling)
    if multistart is not None:
        if isinstance(multistart, bool) or not isinstance(multistart, (int, np.integer, MultiStart)):
            raise TypeError(f"fit: `multistart` must be a count or fj.MultiStart(count, spread), got {multistart!r}.")
        out.append(
            multistart
            if isinstance(multistart, MultiStart)
            else MultiStart(positive_int(multistart, "multistart", "fit"))
        )
    if patience is not None:
        out.append(EarlyStopping(positive_int(patience, "patience", "fit")))
    if tolerance is not None:
        out.append(Tolerance(nonnegative_float(tolerance, "tolerance", "fit")))
    return out


def _burn_in_loss(loss: AbstractLoss, burn_in: Any) -> SimulationLoss:
    """The free-run validation loss with `burn_in` samples not scored; a `SimulationLoss`'s simulator options carry
    over (they change how the loop runs, and the values by round-off: the fit scores training and validation alike)."""
    burn_in = nonnegative_int(burn_in, "validation_burn_in", "fit")
    if isinstance(loss, SimulationLoss):
        return SimulationLoss(burn_in=burn_in, derivatives=loss.derivatives, batching=loss.batching)
    return SimulationLoss(burn_in=burn_in)
