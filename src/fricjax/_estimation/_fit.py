"""`fit`: gradient-based identification of any fricjax model through its simulator: the driver.

`fit` is a short driver of four phases: the arguments checked (`_fit_arguments.checked_arguments`), the `Problem`
built (which parameters move, which are solved by least squares, bounds, scaling) with its starts
(`_build_problem`), the one optimisation loop (`_loop.run_stage`) run for each smoothing stage (`_run_stages`), and
the best start picked, checked against the start, scored and said why it stopped (`_solution`: a `Solution`).
Solvers: any optax `GradientTransformation`, optimistix least-squares solver or minimiser, or `fj.AbstractSolver`.
This replaces the GA + Nelder-Mead of worden2007 §4.4 / parlitz2004 §III-C / amthor §II-B.
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

from .._smoothing import AbstractSmoothing, Smooth, exact, with_smoothing
from ._fit_arguments import DEFAULT_SOLVER, FitState, checked_arguments
from .loop._loop import Search, run_stage, start_losses, trees_equal
from .loop._placement import choose_device, to_device
from .loop._sharding import shard_batch
from .loop._solution import FitFailed, Solution
from .loop._stop_messages import scaling_hint, stopping_reason
from .loop._strategies import (
    AbstractStrategy,
    Continuation,
    FitPlan,
    MultiStart,
    ParameterScaling,
)
from .problem._losses import AbstractLoss
from .problem._problem import (
    Problem,
    Selector,
    evaluate,
    gauss_newton_std,
    nonnegative_flags,
    nonnegative_mask,
    parameter_specs,
)
from .problem._records import (
    Nuisances,
    RecordsLoss,
    record_nuisances,
)

__all__ = ["DEFAULT_SOLVER", "fit"]


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
    if device is not None:
        moved = _on_chosen_device(dict(locals()))  # the same fit, on the device `device` names
        if moved is not None:
            return moved
    start_time = time.perf_counter()
    fitting = checked_arguments(
        model, data, loss=loss, solver=solver, steps=steps, validation=validation,
        validation_burn_in=validation_burn_in, train=train, freeze=freeze, nuisances=nuisances,
        eval_every=eval_every, seed=seed, strategies=strategies,
        keyword_strategies=(scaling, multistart, continuation, separable, patience, tolerance),
    )  # fmt: skip
    _build_problem(fitting, train)
    bar = _progress_bar(progress, fitting.steps, fitting.solver.kind)
    search = Search(fitting.ys0, fitting.validation is not None, start_time, bar)
    _run_stages(fitting, search)
    solution = _solution(fitting, search, start_time, compute_std)
    if throw and not solution.success:
        raise FitFailed(solution)
    return solution


def _on_chosen_device(arguments: dict[str, Any]) -> Solution | None:
    """The same fit on the device `choose_device` picks (`device="auto"` etc.), or None to run it here."""
    multistart, strategies = arguments["multistart"], arguments["strategies"]
    counts = [getattr(s, "count", 1) for s in (multistart, *strategies) if isinstance(s, MultiStart)]
    batched = (isinstance(multistart, int) and multistart > 1) or any(count > 1 for count in counts)
    target, reason = choose_device(arguments["model"], arguments["data"], arguments["device"], batched)
    if target is None:
        return None
    moved = {k: to_device(arguments[k], target) for k in ("model", "data", "validation")}
    with jax.default_device(target):
        solution = fit(**{**arguments, **moved, "device": None})
    return dataclasses.replace(solution, message=f"{solution.message} (on {target.platform}: {reason})")


def _build_problem(f: FitState, train: Selector | None) -> None:
    """The plan (each strategy wraps the problem, before and after parameter selection, in the order given), the
    `Problem` and the batch of starts."""
    plan = FitPlan(model=f.model, seed=f.seed)
    for strategy in f.strategies:
        plan = strategy.prepare(plan)
    model, separable, f.tolerance, f.patience = plan.model, plan.separable, plan.tolerance, plan.patience
    if f.patience is not None and f.validation is None:
        raise ValueError(
            "fit: `patience` (fj.EarlyStopping) stops on the validation loss, and no `validation` record was passed; "
            "pass `validation=` (a record not trained on) or drop `patience` (for a stop on the training loss: "
            "`tolerance=`)."
        )
    f.model = model
    f.own_width = _smoothing_width(model)  # the history's `eps` of a stage that keeps the model's own width
    f.spec, f.linear_spec = parameter_specs(model, train, f.freeze, separable, f.loss, f.data)
    f.params0, f.static = eqx.partition(model, f.spec)
    plan = dataclasses.replace(plan, params0=f.params0, starts=MultiStart(1, 0.0).draw(f.params0, f.seed))
    for strategy in f.strategies:
        plan = strategy.transform(plan)
    f.plan = plan
    f.problem = Problem(
        loss=f.loss,
        linear_spec=f.linear_spec,
        linear_nonnegative=nonnegative_flags(model, f.linear_spec, separable),
        nonnegative=eqx.partition(nonnegative_mask(model), f.spec)[0],
        scales=plan.scales,
        data=f.data,
        validation=f.validation,
        val_loss=f.val_loss_fn,
        penalty=plan.penalty,
    )
    f.count = jax.tree_util.tree_leaves(plan.starts)[0].shape[0] if jax.tree_util.tree_leaves(plan.starts) else 1
    if isinstance(f.loss, RecordsLoss):
        f.loss, extra0 = f.loss.bind_and_start(model, f.data)
        f.problem = dataclasses.replace(f.problem, loss=f.loss, val_loss=f.loss.validation_loss())
    else:
        extra0 = f.loss.init_extra(model, f.data)
    extras = jax.tree_util.tree_map(
        lambda e: jax.device_put(np.broadcast_to(np.asarray(e), (f.count,) + e.shape)), extra0
    )
    f.ys0 = shard_batch((plan.starts, extras))  # the starts spread over the local devices (identity on one)
    f.linear_only = not any(eqx.is_array(leaf) for leaf in jax.tree_util.tree_leaves(f.params0))


def _run_stages(f: FitState, search: Search) -> None:
    """The smoothing stages of the fit (one unless a continuation asks for more), each run by the loop
    (`run_stage`), the first one screening the starts where a multi-start asks for it."""
    if f.linear_only:  # only separable (linear) parameters: one least-squares solve is the whole fit
        f.code, f.message = "successful", "only linear parameters: solved by least squares"
        search.best_scores = np.zeros(f.count)
    else:
        for eps, budget in zip(f.plan.stages, _split(f.steps, len(f.plan.stages)), strict=True):
            if budget == 0:
                continue
            if eps is not None:
                f.static = eqx.partition(with_smoothing(f.model, Smooth(jnp.asarray(eps, dtype=float))), f.spec)[1]
                # losses at different widths are not comparable: each stage starts its own best-so-far
                search.restart(*start_losses(f.solver, f.problem, search.ys, f.static))
            if f.solver.kind == "optax":
                check_every = f.eval_every or max(1, f.steps // 50)
            else:  # solvers with their own convergence test run their budget unless a tolerance asks for checks
                # at least 5 steps a check: LM rejects runs of trial steps, and a window of one rejected step
                # reads as no change (`--steps 10` stopped at step 3 as converged)
                check_every = budget if f.tolerance is None else (f.eval_every or min(budget, max(5, budget // 8)))
            screening, f.plan = f.plan.screen, dataclasses.replace(f.plan, screen=None)  # the first stage screens
            if screening is not None and screening[0] == 0:  # forward screening: each start's loss, no step
                search.restart(*start_losses(f.solver, f.problem, search.ys, f.static))
                survivors, f.screened = _survivors(
                    search.best_scores, screening[1], f.count, "by their loss at the start"
                )
                search.keep(survivors)
                screening = None
            first = budget if screening is None else max(1, min(budget - 1, round(screening[0] * budget)))
            for part in (first, budget - first):
                if part == 0:
                    continue
                f.outcome = run_stage(
                    f.solver,
                    f.problem,
                    search,
                    f.static,
                    budget=part,
                    check_every=min(check_every, part),
                    tolerance=f.tolerance,
                    patience=f.patience if f.validation is not None else None,
                    eps=f.own_width if eps is None else eps,
                )
                if f.outcome.stop is not None or screening is None:
                    break
                survivors, f.screened = _survivors(search.best_scores, screening[1], f.count, "")
                search.keep(survivors)
                screening = None
            assert f.outcome is not None  # budget >= 1: the first part ran
            f.converged = f.outcome.converged
            if f.outcome.stop is not None:
                f.code, f.message = f.outcome.stop, f.outcome.message
                break
    search.close()


def _solution(f: FitState, search: Search, start_time: float, compute_std: bool) -> Solution:
    """The best start's best snapshot, never worse than the start, scored and said why it stopped."""
    # choose the best start; keep its best snapshot
    best_ys, best_scores, diverged = search.best_ys, search.best_scores, search.diverged
    if np.isfinite(best_scores).any():
        best = int(np.argmin(best_scores))
        original = int(search.active[best])  # its index among all the starts (screening keeps some)
    else:  # every start diverged before the first check: fall back to the initial parameters
        best, original, best_ys = 0, 0, f.ys0
    chosen = _host_take(best_ys, best)
    best_losses = [row[original] for row in search.history["train_loss"]]
    if f.code == "max_steps":  # no stopping rule ended the fit: the tolerance rule, the solver's verdict, the budget
        f.code, f.message = stopping_reason(
            f.solver, f.outcome, f.converged, best, f.steps, best_losses, diverged[best]
        )
    f.message += f.screened
    if f.code != "diverged" and diverged.any() and not diverged.all():
        f.message += f" ({int(diverged.sum())} of {f.count} starts diverged and were discarded)"
    losses, kept = None, ""
    if not f.linear_only:  # never worse than the start: the initial model, scored as the starts are chosen
        chosen, kept, losses = _no_worse_than_start(
            f.solver, f.problem, chosen, f.ys0, f.static, f.validation is not None
        )
        if kept:
            f.message += "; " + kept
        elif f.code != "diverged" and trees_equal(chosen[0], _host_take(f.ys0, 0)[0]):
            kept = "no step improved on the model the fit was given, which is returned unchanged"
            f.message += "; " + kept
    if f.plan.scales is None and (f.code != "successful" or kept) and f.code != "diverged":
        if kept and f.solver.kind == "optax":  # a learning rate far from every parameter's size
            f.message += (
                " (real parameters are stepped as stored: for physical models pass scaling="
                "fj.ParameterScaling(), which scales each by its magnitude or physical range)"
            )
        else:
            f.message += scaling_hint(f.params0)
    fitted = f.problem.materialise(chosen[0], f.static)
    if losses is not None:  # the returned model's losses, as the problem scores it (no further program)
        train_loss, val_loss = losses
        if f.problem.penalty is not None:  # the data's loss, without the regularisation's penalty
            train_loss = float(evaluate(f.loss, fitted, chosen[1], f.data))
    else:
        train_loss = float(evaluate(f.loss, fitted, chosen[1], f.data))
        val_loss = (
            float(evaluate(f.val_loss_fn, fitted, None, f.validation)) if f.validation is not None else float("nan")
        )
    exact_val = (
        float(evaluate(f.val_loss_fn, exact(fitted), None, f.validation)) if f.validation is not None else np.nan
    )
    if f.validation is not None and not np.isfinite(val_loss) and f.code != "diverged":
        f.code = "diverged"
        f.message = (
            f"the validation loss of the returned model is not finite ({val_loss}); check the validation data "
            "(NaN, scale) or the model's behaviour on it; " + f.message
        )
    if not np.isfinite(train_loss) and f.code == "diverged":  # no finite loss was ever seen: not a divergence
        f.message = (
            f"the training loss is not finite ({train_loss}) at the start already, so no step could improve it: check "
            "the initial parameters against the data (a force that overflows, the square root or logarithm of a "
            "negative value in a custom model) and the data (NaN, scale); the initial model is returned"
        )
    elif not np.isfinite(train_loss) and f.code != "solver_failed":
        returned = f"the training loss of the returned model is not finite ({train_loss}); "
        f.code, f.message = "diverged", returned + f.message
    std = None
    if compute_std and np.isfinite(train_loss):
        std = gauss_newton_std(fitted, f.spec, f.linear_spec, f.loss, chosen[1], f.data)
    history = search.history
    solution = Solution(
        model=fitted,
        result=f.code,
        message=f.message,
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
        num_starts=f.count,
        best_start=original,
        std=std,
        extra=chosen[1],
        records=record_nuisances(f.loss, fitted, chosen[1], f.data) if isinstance(f.loss, RecordsLoss) else None,
        start_kept=bool(kept),
    )
    return solution


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------


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
