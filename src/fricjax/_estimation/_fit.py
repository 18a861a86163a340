"""`fit`: gradient-based identification of any fricjax model through its simulator: the driver.

It builds the `Problem` (which parameters move, which are solved by least squares, bounds, scaling), draws the
starts, and runs the one optimisation loop (`_loop.run_stage`) for each smoothing stage; then it picks the best
start, checks the result against the start, scores it and says why it stopped (`Solution`). Solvers: any optax
`GradientTransformation`, optimistix least-squares solver or minimiser, or `fj.AbstractSolver`. This replaces the
GA + Nelder-Mead of worden2007 §4.4 / parlitz2004 §III-C / amthor §II-B.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._data._record import FrictionData
from .._smoothing import AbstractSmoothing, Smooth, exact, with_smoothing
from .._validation import nonnegative_float, nonnegative_int, optional, positive_int, seed_value
from ._loop import Search, run_stage, start_losses, trees_equal
from ._losses import AbstractLoss, SimulationLoss
from ._placement import choose_device, to_device
from ._problem import (
    Problem,
    Selector,
    evaluate,
    gauss_newton_std,
    held_paths,
    nonnegative_flags,
    nonnegative_mask,
    parameter_specs,
    selector_items,
    selector_paths,
)
from ._records import (
    Nuisances,
    RecordBatch,
    RecordsLoss,
    as_record_batch,
    check_burn_in,
    check_records,
    record_nuisances,
)
from ._sharding import shard_batch
from ._solution import FitFailed, Solution
from ._solvers import as_solver
from ._stop_messages import scaling_hint, stopping_reason
from ._strategies import (
    AbstractStrategy,
    Continuation,
    EarlyStopping,
    FitPlan,
    MultiStart,
    ParameterScaling,
    Separable,
    Tolerance,
)

__all__ = ["DEFAULT_SOLVER", "fit"]

# one object, so that repeated fits with the default solver hit the same compilation
DEFAULT_SOLVER = optax.adam(1e-2)


def fit(
    model: Any,
    data: Any,
    *,
    loss: AbstractLoss | None = None,
    solver: Any = None,
    steps: int = 1000,
    validation: Any = None,
    validation_burn_in: int | None = None,
    train: Selector | None = None,
    freeze: Selector = (),
    separable: Sequence[str] = (),
    scaling: ParameterScaling | None = None,
    multistart: MultiStart | int | None = None,
    continuation: Continuation | None = None,
    eval_every: int | None = None,
    patience: int | None = None,
    tolerance: float | None = None,
    progress: bool = False,
    seed: int = 0,
    compute_std: bool = False,
    throw: bool = False,
    strategies: Sequence[AbstractStrategy] = (),
    device: Any = "auto",
    nuisances: Nuisances | None = None,
) -> Solution:
    """Fit the parameters of `model` to `data` by gradients through the simulator.

    **Arguments:**

    - `model`: the initial model (any fricjax model, or any equinox Module the loss can evaluate, such as an
      `EMPSPlant` with `EMPSOpenLoopLoss`); every floating leaf is trained except `Fixed` ones and smoothing
      widths (narrow it with `train` / `freeze`).
    - `data`: training data (`FrictionData` for the friction losses; the loss's `data_type` otherwise), or a list of
      `FrictionData` records of one device (different lengths, one sample time; a dict `{name: record}` names
      them): the model's parameters are shared, each record gets its own nuisances (`nuisances`), the records are
      simulated side by side in one program (padded, masked), and the loss is the mean over records of each
      record's NMSE (`fj.RecordsLoss`).
    - `loss`: `SimulationLoss()` (default), `MultipleShootingLoss(L)`, `OneStepLoss()`.
    - `solver`: an optax transformation (default `optax.adam(1e-2)`; parameters are in log space for positive
      ones, so a learning rate of 1e-2 is a 1 % step), an optimistix least-squares solver
      (`optx.LevenbergMarquardt(rtol, atol)`, `optx.GaussNewton`) or minimiser (`optx.BFGS`), or any
      `fj.AbstractSolver` (the interface of the one optimisation loop; docs/concepts.md).
    - `steps`: optimiser steps (optax) or maximum solver steps (optimistix), split over continuation stages.
    - `validation`: data for early stopping / choosing among starts (scored by free-run simulation); with a list of
      training records, a list of records (or an `fj.RecordBatch` whose mask scores only the validation part of
      each), each scored with its least-squares offset.
    - `validation_burn_in`: samples of `validation` simulated but not scored. For hysteretic models pass the
      record from its start up to the end of the validation part, with `validation_burn_in` = the length of
      the part before it, so the model enters the validation part in the state its history gives it.
    - `train`: train only these parameters: a dotted field path (`"stribeck.Fc"`, `"mlp.layers.0"`), a `where`
      callable (`lambda m: (m.sigma0, m.stribeck)`), or a sequence of them. Default: every trainable leaf.
    - `freeze`: parameters not to train, in the same forms, e.g. `("sigma2", "stribeck.vs")`.
    - `separable`: dotted paths of real fields that enter the force linearly (offsets, FIR coefficients,
      LuGre `sigma1` / `sigma2`, static `Fv`): solved exactly by least squares inside every evaluation
      (`SimulationLoss` only).
    - `scaling`: a `ParameterScaling()`: the optimiser sees real parameters divided by their initial magnitude
      (for physical models whose real parameters span decades). Default: none, parameters as they are stored
      (positive ones as logs).
    - `multistart`: a `MultiStart(count, spread)` or a count. With several local devices the starts are
      sharded over them (`fj.shard_batch`), with the results of one device.
    - `continuation`: a `Continuation(eps_start, eps_end, stages)`.
    - `eval_every`: optax steps between checks (validation, divergence, progress); default steps / 50.
    - `patience`: evaluations without validation improvement before stopping (default: never).
    - `tolerance`: a stopping rule for any solver: the fit ends as converged (`successful`) when the training
      loss of the best start falls by less than this fraction over one check (`eval_every` steps; optimistix
      solvers and fricjax's LM then run in chunks of that many steps, by default an eighth of the budget and at
      least 5: a trust-region solver rejects runs of trial steps, which leave the loss unchanged). Default: none
      (optax runs its budget; optimistix stops by its own `rtol` / `atol`).
    - `progress`: show a tqdm progress bar. `seed`: for the multi-start draws (results are deterministic).
    - `compute_std`: Gauss-Newton standard deviations of the trained physical parameters (a dense Jacobian
      over them: for physical models, not for networks with thousands of weights).
    - `strategies`: further `fj.AbstractStrategy` wrappers of the problem, applied after the keyword ones above
      (which are the same strategies: `scaling=` is `fj.ParameterScaling`, `multistart=` `fj.MultiStart`,
      `continuation=` `fj.Continuation`, `separable=` `fj.Separable`, `patience=` `fj.EarlyStopping`,
      `tolerance=` `fj.Tolerance`).
    - `device`: where the fit runs: `"auto"` (default) the host CPU for a single start of a model without a
      time-parallel form (or on a short record) when the default device is an accelerator, the accelerator
      otherwise (batched starts, long records of LuGre / Maxwell-slip); `"cpu"`, `"accelerator"`, a `jax.Device`;
      `None`: JAX's default device. The choice is stated in `message`.
    - `nuisances`: with several records, which per-record nuisances are estimated with the shared parameters:
      `fj.Nuisances(offset=True, drift=False, initial_state=True)` (the default); reported in `Solution.records`.
    - `throw`: raise `fj.FitFailed` (holding the `Solution`) when the fit diverged or its solver failed, instead
      of returning the failure.

    **Returns:** a `fj.Solution` (`result`: a `fj.RESULTS` item; `message`: why it stopped and which stage produced
    the model). Without `throw` it never raises on divergence. The returned model is never worse than the start
    (scored as the starts are chosen: validation loss, else training loss).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 12, 600)), dt=1e-3)
    >>> truth = fj.CoulombViscous(Fc=1.0, Fv=30.0, smoothing=fj.Smooth(1e-4))
    >>> data = fj.FrictionData(motion, fj.simulate(truth, motion))
    >>> start = fj.CoulombViscous(Fc=0.5, Fv=10.0, smoothing=fj.Smooth(1e-4))
    >>> result = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=50)
    >>> round(float(fj.unwrap(result.model).Fc), 3)
    1.0
    ```
    """
    arguments = dict(locals())
    if device is not None:
        counts = [getattr(s, "count", 1) for s in (multistart, *strategies) if isinstance(s, MultiStart)]
        batched = (isinstance(multistart, int) and multistart > 1) or any(count > 1 for count in counts)
        target, reason = choose_device(model, data, device, batched)
        if target is not None:  # the same fit, on `target`
            arguments.update(
                device=None, **{k: to_device(arguments[k], target) for k in ("model", "data", "validation")}
            )
            with jax.default_device(target):
                solution = fit(**arguments)
            return dataclasses.replace(solution, message=f"{solution.message} (on {target.platform}: {reason})")
    start_time = time.perf_counter()
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
    strategies = [*_keyword_strategies(scaling, multistart, continuation, separable, patience, tolerance), *strategies]
    val_loss_fn = loss.validation_loss() if validation_burn_in is None else _burn_in_loss(loss, validation_burn_in)
    if validation is not None and getattr(val_loss_fn, "burn_in", 0) >= validation.length:
        raise ValueError(
            f"fit: the validation burn-in ({getattr(val_loss_fn, 'burn_in', 0)} samples) leaves nothing to score "
            f"in a validation record of {validation.length} samples; lower `validation_burn_in` or pass more data."
        )
    check_burn_in(loss, data, "data", "fit")
    if isinstance(validation, RecordBatch):
        check_burn_in(val_loss_fn, validation, "validation", "fit")

    # the plan: each strategy wraps the problem (before and after parameter selection), in the order given
    plan = FitPlan(model=model, seed=seed)
    for strategy in strategies:
        plan = strategy.prepare(plan)
    model, separable, tolerance, patience = plan.model, plan.separable, plan.tolerance, plan.patience
    if patience is not None and validation is None:
        raise ValueError(
            "fit: `patience` (fj.EarlyStopping) stops on the validation loss, and no `validation` record was passed; "
            "pass `validation=` (a record not trained on) or drop `patience` (for a stop on the training loss: "
            "`tolerance=`)."
        )
    own_width = _smoothing_width(model)  # the history's `eps` of a stage that keeps the model's own width
    spec, linear_spec = parameter_specs(model, train, freeze, separable, loss, data)
    params0, static = eqx.partition(model, spec)
    plan = dataclasses.replace(plan, params0=params0, starts=MultiStart(1, 0.0).draw(params0, seed))
    for strategy in strategies:
        plan = strategy.transform(plan)
    problem = Problem(
        loss=loss,
        linear_spec=linear_spec,
        linear_nonnegative=nonnegative_flags(model, linear_spec, separable),
        nonnegative=eqx.partition(nonnegative_mask(model), spec)[0],
        scales=plan.scales,
        data=data,
        validation=validation,
        val_loss=val_loss_fn,
    )
    count = jax.tree_util.tree_leaves(plan.starts)[0].shape[0] if jax.tree_util.tree_leaves(plan.starts) else 1
    if isinstance(loss, RecordsLoss):
        loss, extra0 = loss.bind_and_start(model, data)
        problem = dataclasses.replace(problem, loss=loss, val_loss=loss.validation_loss())
    else:
        extra0 = loss.init_extra(model, data)
    extras = jax.tree_util.tree_map(
        lambda e: jax.device_put(np.broadcast_to(np.asarray(e), (count,) + e.shape)), extra0
    )
    ys0 = shard_batch((plan.starts, extras))  # the starts spread over the local devices (identity on one)

    bar = _progress_bar(progress, steps, solver.kind)
    search = Search(ys0, validation is not None, start_time, bar)
    linear_only = not any(eqx.is_array(leaf) for leaf in jax.tree_util.tree_leaves(params0))
    code, message, outcome, converged, screened = "max_steps", "", None, "", ""
    if linear_only:  # only separable (linear) parameters: one least-squares solve is the whole fit
        code, message = "successful", "only linear parameters: solved by least squares"
        search.best_scores = np.zeros(count)
    else:
        for eps, budget in zip(plan.stages, _split(steps, len(plan.stages)), strict=True):
            if budget == 0:
                continue
            if eps is not None:
                static = eqx.partition(with_smoothing(model, Smooth(jnp.asarray(eps, dtype=float))), spec)[1]
                # losses at different widths are not comparable: each stage starts its own best-so-far
                search.restart(*start_losses(solver, problem, search.ys, static))
            if solver.kind == "optax":
                check_every = eval_every or max(1, steps // 50)
            else:  # solvers with their own convergence test run their budget unless a tolerance asks for checks
                # at least 5 steps a check: LM rejects runs of trial steps, and a window of one rejected step
                # reads as no change (`--steps 10` stopped at step 3 as converged)
                check_every = budget if tolerance is None else (eval_every or min(budget, max(5, budget // 8)))
            screening, plan = plan.screen, dataclasses.replace(plan, screen=None)  # the first stage screens
            if screening is not None and screening[0] == 0:  # forward screening: each start's loss, no step
                search.restart(*start_losses(solver, problem, search.ys, static))
                survivors, screened = _survivors(search.best_scores, screening[1], count, "by their loss at the start")
                search.keep(survivors)
                screening = None
            first = budget if screening is None else max(1, min(budget - 1, round(screening[0] * budget)))
            for part in (first, budget - first):
                if part == 0:
                    continue
                outcome = run_stage(
                    solver,
                    problem,
                    search,
                    static,
                    budget=part,
                    check_every=min(check_every, part),
                    tolerance=tolerance,
                    patience=patience if validation is not None else None,
                    eps=own_width if eps is None else eps,
                )
                if outcome.stop is not None or screening is None:
                    break
                survivors, screened = _survivors(search.best_scores, screening[1], count, "")
                search.keep(survivors)
                screening = None
            assert outcome is not None  # budget >= 1: the first part ran
            converged = outcome.converged
            if outcome.stop is not None:
                code, message = outcome.stop, outcome.message
                break
    search.close()

    # choose the best start; keep its best snapshot
    best_ys, best_scores, diverged = search.best_ys, search.best_scores, search.diverged
    if np.isfinite(best_scores).any():
        best = int(np.argmin(best_scores))
        original = int(search.active[best])  # its index among all the starts (screening keeps some)
    else:  # every start diverged before the first check: fall back to the initial parameters
        best, original, best_ys = 0, 0, ys0
    chosen = _host_take(best_ys, best)
    best_losses = [row[original] for row in search.history["train_loss"]]
    if code == "max_steps":  # no stopping rule ended the fit: the tolerance rule, the solver's verdict, the budget
        code, message = stopping_reason(solver, outcome, converged, best, steps, best_losses, diverged[best])
    message += screened
    if code != "diverged" and diverged.any() and not diverged.all():
        message += f" ({int(diverged.sum())} of {count} starts diverged and were discarded)"
    losses, kept = None, ""
    if not linear_only:  # never worse than the start: the initial model, scored as the starts are chosen
        chosen, kept, losses = _no_worse_than_start(solver, problem, chosen, ys0, static, validation is not None)
        if kept:
            message += "; " + kept
        elif code != "diverged" and trees_equal(chosen[0], _host_take(ys0, 0)[0]):
            kept = "no step improved on the model the fit was given, which is returned unchanged"
            message += "; " + kept
    if plan.scales is None and (code != "successful" or kept) and code != "diverged":
        if kept and solver.kind == "optax":  # a learning rate far from every parameter's size
            message += (
                " (real parameters are stepped as stored: for physical models pass scaling="
                "fj.ParameterScaling(), which scales each by its magnitude or physical range)"
            )
        else:
            message += scaling_hint(params0)
    fitted = problem.materialise(chosen[0], static)
    if losses is not None:  # the returned model's losses, as the problem scores it (no further program)
        train_loss, val_loss = losses
    else:
        train_loss = float(evaluate(loss, fitted, chosen[1], data))
        val_loss = float(evaluate(val_loss_fn, fitted, None, validation)) if validation is not None else float("nan")
    exact_val = float(evaluate(val_loss_fn, exact(fitted), None, validation)) if validation is not None else np.nan
    if validation is not None and not np.isfinite(val_loss) and code != "diverged":
        code = "diverged"
        message = (
            f"the validation loss of the returned model is not finite ({val_loss}); check the validation data "
            "(NaN, scale) or the model's behaviour on it; " + message
        )
    if not np.isfinite(train_loss) and code == "diverged":  # no finite loss was ever seen: not a divergence
        message = (
            f"the training loss is not finite ({train_loss}) at the start already, so no step could improve it: check "
            "the initial parameters against the data (a force that overflows, the square root or logarithm of a "
            "negative value in a custom model) and the data (NaN, scale); the initial model is returned"
        )
    elif not np.isfinite(train_loss) and code != "solver_failed":
        code, message = "diverged", f"the training loss of the returned model is not finite ({train_loss}); " + message
    std = None
    if compute_std and np.isfinite(train_loss):
        std = gauss_newton_std(fitted, spec, linear_spec, loss, chosen[1], data)
    history = search.history
    solution = Solution(
        model=fitted,
        result=code,
        message=message,
        history={
            "step": np.asarray(history["step"]),
            "train_loss": np.asarray(best_losses),
            "val_loss": np.asarray([row[original] for row in history["val_loss"]]),
            "eps": np.asarray(history["eps"], dtype=float),
            "time": np.asarray(history["time"], dtype=float),
        },
        train_loss=train_loss,
        val_loss=val_loss,
        exact_val_loss=float(exact_val),
        evaluations=search.step_count,
        wall_time=time.perf_counter() - start_time,
        num_starts=count,
        best_start=original,
        std=std,
        extra=chosen[1],
        records=record_nuisances(loss, fitted, chosen[1], data) if isinstance(loss, RecordsLoss) else None,
        start_kept=bool(kept),
    )
    if throw and not solution.success:
        raise FitFailed(solution)
    return solution


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------


def _burn_in_loss(loss: AbstractLoss, burn_in: Any) -> SimulationLoss:
    """The free-run validation loss with `burn_in` samples not scored; a `SimulationLoss`'s simulator options carry
    over (they change how the loop runs, and the values by round-off: the fit scores training and validation alike)."""
    burn_in = nonnegative_int(burn_in, "validation_burn_in", "fit")
    if isinstance(loss, SimulationLoss):
        return SimulationLoss(burn_in=burn_in, derivatives=loss.derivatives, batching=loss.batching)
    return SimulationLoss(burn_in=burn_in)


def _smoothing_width(model: Any) -> float:
    """The width of the model's smoothing when every strategy in it is `Smooth` with one scalar width; else NaN
    (exact, no smoothing, or differing widths)."""
    found = jax.tree_util.tree_leaves(model, is_leaf=lambda leaf: isinstance(leaf, AbstractSmoothing))
    widths = {
        float(np.asarray(leaf.eps)) if isinstance(leaf, Smooth) and np.size(leaf.eps) == 1 else np.nan
        for leaf in found
        if isinstance(leaf, AbstractSmoothing)
    }
    return widths.pop() if len(widths) == 1 else float("nan")


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


def _survivors(scores: np.ndarray, keep: int, count: int, how: str) -> tuple[np.ndarray, str]:
    """The `keep` best starts by `scores`, and the initial one (start 0) with them; the message's note."""
    survivors = np.argsort(scores, kind="stable")[:keep]
    note = f" (all {count} starts screened{' ' + how if how else ''}, the best {len(survivors)} went on"
    if 0 not in survivors:  # the initial model (start 0) always goes on too
        survivors = np.append(survivors, 0)
        note += " with the initial start"
    return survivors, note + ")"


def _no_worse_than_start(
    solver: Any, problem: Problem, chosen: Any, ys0: Any, static: Any, by_validation: bool
) -> tuple[Any, str, tuple[float, float]]:
    """`chosen`, or the model the fit was given where that scores better (as the starts are chosen, in the final
    smoothing), with a sentence saying so (empty when `chosen` stands), and the training and validation losses of
    the one returned. Each is scored by the loop's program for one start (no other compilation for a single start)."""
    start = _host_take(ys0, slice(0, 1))
    scores = [
        tuple(float(value[0]) for value in start_losses(solver, problem, candidate, static))
        for candidate in (_host_take(chosen, None), start)
    ]
    (train, val), (start_train, start_val) = scores
    if np.isfinite(start_val if by_validation else start_train) and not (
        (val <= start_val) if by_validation else (train <= start_train)
    ):
        score = "validation" if by_validation else "training"
        sentence = (
            f"no step of this fit improved the {score} loss of the model it was given "
            f"({start_val if by_validation else start_train:.4g}; best step {val if by_validation else train:.4g}), "
            "so the input model is returned unchanged"
        )
        return _host_take(start, 0), sentence, (start_train, start_val)
    return chosen, "", (train, val)


def _host_take(tree: Any, index: Any) -> Any:
    """`leaf[index]` of every array leaf, indexed in NumPy (an eager JAX index compiles a program of its own)."""
    return jax.tree_util.tree_map(lambda a: jax.device_put(np.asarray(a)[index]) if eqx.is_array(a) else a, tree)


def _split(total: int, parts: int) -> list[int]:
    base = [total // parts] * parts
    for i in range(total - sum(base)):
        base[i] += 1
    return base


def _progress_bar(progress: bool, steps: int, kind: str) -> Any:
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=steps, desc=f"fit ({kind})", unit="step", leave=False)
