"""`fit`: gradient-based identification of any fricjax model through its simulator.

Solvers: any optax `GradientTransformation` (Adam, L-BFGS, schedules) or an optimistix least-squares solver
(Levenberg-Marquardt, Gauss-Newton, on the residual vector) or minimiser (BFGS). Options: freezing fields,
separable least squares (linear parameters solved inside every evaluation), vmap-ed multi-start, smoothing
continuation, validation-based early stopping, a divergence guard, progress bar, Gauss-Newton standard
deviations. This replaces the GA + Nelder-Mead of worden2007 §4.4 / parlitz2004 §III-C / amthor §II-B.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx

from .._constraints import AbstractUnwrappable, Fixed, trainable_filter, unwrap
from .._data._record import FrictionData
from .._models._base import AbstractModel
from .._simulate import run, simulate
from .._smoothing import Smooth, exact, is_concrete, with_smoothing
from ._linear import lstsq, parameter_std
from ._losses import AbstractLoss, SimulationLoss
from ._result import FitResult
from ._sharding import shard_batch
from ._strategies import Continuation, MultiStart, ParameterScaling, submodels, where_from_path

# ----------------------------------------------------------------------------------------------------------------
# parameter selection
# ----------------------------------------------------------------------------------------------------------------


Selector = str | Callable[[Any], Any] | Sequence[str]


def _where(selector: Any, model: Any, argument: str) -> list[tuple[str, Callable[[Any], Any]]]:
    """`(label, where)` pairs for a selector: a dotted path, a `where` callable, or a sequence of paths /
    callables. Each is checked against `model`: it must address nodes holding arrays."""
    if selector is None:
        return []
    items = [selector] if isinstance(selector, str) or callable(selector) else list(selector)
    out = []
    for item in items:
        if callable(item):
            label, where = getattr(item, "__name__", "where"), item
        elif isinstance(item, str):
            label, where = item, where_from_path(item)
        else:
            raise TypeError(
                f"fit: `{argument}` takes dotted field paths ('stribeck.Fc', 'mlp.layers.0') or callables "
                f"(lambda m: m.sigma2), got {type(item).__name__}."
            )
        try:
            nodes = where(model)
        except (AttributeError, IndexError, KeyError, TypeError) as err:
            fields = [f.name for f in dataclasses.fields(model)] if dataclasses.is_dataclass(model) else []
            raise ValueError(
                f"fit: {label!r} in `{argument}` is not a field path of {type(model).__name__} ({err}); fields: "
                + ", ".join(fields)
                + ". Use dotted names such as 'sigma1', 'stribeck.Fc' or 'layers.0.weight', or a callable."
            ) from None
        if not jax.tree_util.tree_leaves(nodes):
            raise ValueError(f"fit: {label!r} in `{argument}` of {type(model).__name__} holds no array to select.")
        out.append((label, where))
    return out


def _set_spec(spec: Any, model: Any, selector: Any, value: bool, argument: str) -> Any:
    for _, where in _where(selector, model, argument):
        spec = eqx.tree_at(where, spec, replace_fn=lambda sub: jax.tree_util.tree_map(lambda _: value, sub))
    return spec


def _physical_spec(model: Any, spec: Any) -> Any:
    """The trainable spec mapped onto `unwrap(model)` (a wrapper becomes one leaf: trained if any raw leaf is)."""

    def is_wrapper(node: Any) -> bool:
        return isinstance(node, AbstractUnwrappable)

    def convert(spec_node: Any) -> Any:
        if isinstance(spec_node, Fixed):
            return False
        if is_wrapper(spec_node):
            return any(bool(leaf) for leaf in jax.tree_util.tree_leaves(spec_node))
        return spec_node

    return jax.tree_util.tree_map(convert, spec, is_leaf=is_wrapper)


# ----------------------------------------------------------------------------------------------------------------
# separable least squares
# ----------------------------------------------------------------------------------------------------------------


def _simulate_force(model: Any, data: FrictionData) -> jax.Array:
    model = unwrap(model)
    _, force = run(model, model.samples(data.motion), model.init_state())
    return force


def solve_linear(
    model: Any, linear_spec: Any, data: FrictionData, burn_in: int = 0, *, nonnegative: Sequence[bool] | None = None
) -> Any:
    """Set the parameters selected by `linear_spec` (which enter the simulated force linearly) to their least-
    squares values for `data`, by a differentiable column-scaled solve (`fj.lstsq`, tiny ridge).

    The force is `f(theta) = f(0) + J theta` exactly, with `J` from one forward-mode pass (`jacfwd`).
    `nonnegative`: one flag per selected scalar (in tree order) that must stay >= 0 (damping coefficients);
    `fit` derives it from the models' `nonnegative_fields`.
    """
    linear, rest = eqx.partition(model, linear_spec)
    flat, unravel = jax.flatten_util.ravel_pytree(linear)

    def predict(theta: jax.Array) -> jax.Array:
        return _simulate_force(eqx.combine(unravel(theta), rest), data)[burn_in:]

    zero = jnp.zeros_like(flat)
    f0 = predict(zero)
    J = jax.jacfwd(predict)(zero)
    target = data.force[burn_in:] - f0
    bound = None if nonnegative is None or not any(nonnegative) else np.asarray(nonnegative, dtype=bool)
    theta = lstsq(J, target, ridge=1e-12, nonnegative=bound).x  # the one least-squares kernel, differentiable
    return eqx.combine(unravel(theta), rest)


def _check_linear(model: Any, linear_spec: Any, data: FrictionData, paths: Sequence[str]) -> None:
    linear, rest = eqx.partition(model, linear_spec)
    flat, unravel = jax.flatten_util.ravel_pytree(linear)
    probe = data.slice(0, min(data.length, 400))
    rng = np.random.default_rng(1)
    theta = jnp.asarray(rng.normal(size=flat.shape) * (np.abs(np.asarray(flat)) + 1.0), flat.dtype)

    def f(t: jax.Array) -> np.ndarray:
        return np.asarray(simulate(eqx.combine(unravel(t), rest), probe.motion))

    f0, f1, f2 = f(jnp.zeros_like(flat)), f(theta), f(2 * theta)
    curvature = np.max(np.abs(f2 - 2 * f1 + f0))
    if not curvature <= 1e-6 * (np.max(np.abs(f2)) + np.max(np.abs(f0)) + 1e-300):
        raise ValueError(
            f"fit: the `separable` fields {list(paths)} do not enter the simulated force linearly for "
            f"{type(model).__name__}; list only offsets, FIR coefficients or output weights."
        )


def _parameter_specs(model: Any, train: Any, freeze: Any, separable: Sequence[str], loss: Any, data: Any) -> Any:
    """Which leaves the optimiser moves (`spec`) and which are solved by least squares (`linear_spec`)."""
    spec = trainable_filter(model)
    if train is not None:
        selected = _set_spec(jax.tree_util.tree_map(lambda _: False, spec), model, train, True, "train")
        spec = jax.tree_util.tree_map(lambda a, b: bool(a) and bool(b), spec, selected)
    spec = _set_spec(spec, model, freeze, False, "freeze")
    linear_spec = None
    if separable:
        if not isinstance(loss, SimulationLoss):
            raise ValueError("fit: `separable` needs a SimulationLoss (the linear solve is on the simulated force).")
        for path, where in _where(separable, model, "separable"):
            node = where(model)
            if isinstance(node, AbstractUnwrappable) or not eqx.is_inexact_array(node):
                raise ValueError(
                    f"fit: separable field {path!r} is reparametrised or not a real array; only real fields "
                    "(offsets, FIR coefficients, sigma1 / sigma2, Fv) can be solved linearly."
                )
        linear_spec = _set_spec(jax.tree_util.tree_map(lambda _: False, spec), model, separable, True, "separable")
        spec = _set_spec(spec, model, separable, False, "separable")
        _check_linear(model, linear_spec, data, separable)
    if not any(jax.tree_util.tree_leaves(spec)) and linear_spec is None:
        raise ValueError("fit: nothing to train: every parameter is frozen.")
    return spec, linear_spec


def _nonnegative_mask(model: Any) -> Any:
    """A tree shaped like `model`: True at the real-stored fields their class declares physically >= 0."""
    mask = jax.tree_util.tree_map(lambda _: False, model)
    for path in _nonnegative_paths(model):
        mask = eqx.tree_at(where_from_path(path), mask, True)
    return mask


def _nonnegative_paths(model: Any) -> list[str]:
    return [
        prefix + field.name
        for prefix, node in submodels(model)
        for field in dataclasses.fields(node)
        if field.name in getattr(type(node), "nonnegative_fields", ())
        and eqx.is_inexact_array(getattr(node, field.name, None))
    ]


def _nonnegative_flags(model: Any, linear_spec: Any, separable: Sequence[str]) -> tuple[bool, ...] | None:
    """One flag per scalar solved by separable least squares (tree order): True for fields their model class
    declares physically >= 0 (`nonnegative_fields`: LuGre `sigma1` / `sigma2`, GMS `sigma2`, static `Fv`)."""
    if linear_spec is None:
        return None
    marker = jax.tree_util.tree_map(lambda a: jnp.zeros_like(a) if eqx.is_inexact_array(a) else a, model)
    for path in separable:
        *parents, name = path.split(".")
        owner = where_from_path(".".join(parents))(model) if parents else model
        if name in getattr(type(owner), "nonnegative_fields", ()):
            marker = eqx.tree_at(where_from_path(path), marker, replace_fn=jnp.ones_like)
    flat, _ = jax.flatten_util.ravel_pytree(eqx.partition(marker, linear_spec)[0])
    return tuple(bool(flag) for flag in np.asarray(flat) > 0.5)


# ----------------------------------------------------------------------------------------------------------------
# the driver
# ----------------------------------------------------------------------------------------------------------------


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
) -> FitResult:
    """Fit the parameters of `model` to `data` by gradients through the simulator.

    **Arguments:**

    - `model`: the initial model (any fricjax model, or any equinox Module the loss can evaluate, such as an
      `EMPSPlant` with `EMPSOpenLoopLoss`); every floating leaf is trained except `Fixed` ones and smoothing
      widths (narrow it with `train` / `freeze`).
    - `data`: training data (`FrictionData` for the friction losses; the loss's `data_type` otherwise).
    - `loss`: `SimulationLoss()` (default), `MultipleShootingLoss(L)`, `OneStepLoss()`.
    - `solver`: an optax transformation (default `optax.adam(1e-2)`; parameters are in log space for positive
      ones, so a learning rate of 1e-2 is a 1 % step), or an optimistix least-squares solver
      (`optx.LevenbergMarquardt(rtol, atol)`, `optx.GaussNewton`) or minimiser (`optx.BFGS`).
    - `steps`: optimiser steps (optax) or maximum solver steps (optimistix), split over continuation stages.
    - `validation`: data for early stopping / choosing among starts (scored by free-run simulation).
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
      solvers then run in chunks of that many steps). Default: none (optax runs its budget; optimistix stops
      by its own `rtol` / `atol`).
    - `progress`: show a tqdm progress bar. `seed`: for the multi-start draws (results are deterministic).
    - `compute_std`: Gauss-Newton standard deviations of the trained physical parameters (a dense Jacobian
      over them: for physical models, not for networks with thousands of weights).

    **Returns:** a `FitResult` (never raises on divergence: see its `result` and `message`). The returned
    model is never worse than the start (scored as the starts are chosen: validation loss, else training loss).

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
    start_time = time.perf_counter()
    loss = SimulationLoss() if loss is None else loss
    if not isinstance(loss, AbstractLoss):
        raise TypeError(f"fit: `loss` must be a fricjax loss (fj.SimulationLoss(), ...), got {type(loss).__name__}.")
    _validate(model, data, validation, steps, loss)
    solver = DEFAULT_SOLVER if solver is None else solver
    kind = _solver_kind(solver)
    if isinstance(multistart, int):
        multistart = MultiStart(multistart)
    count = 1 if multistart is None else multistart.count
    val_loss_fn = loss.validation_loss() if validation_burn_in is None else SimulationLoss(burn_in=validation_burn_in)
    if validation is not None and getattr(val_loss_fn, "burn_in", 0) >= validation.length:
        raise ValueError(
            f"fit: the validation burn-in ({getattr(val_loss_fn, 'burn_in', 0)} samples) leaves nothing to score "
            f"in a validation record of {validation.length} samples; lower `validation_burn_in` or pass more data."
        )

    if continuation is not None:  # smooth from the start, so every stage shares one tree structure
        model = with_smoothing(model, Smooth(jnp.asarray(continuation.eps_start, dtype=float)))
    spec, linear_spec = _parameter_specs(model, train, freeze, separable, loss, data)

    eps_schedule = [None] if continuation is None else list(continuation.schedule())
    params0, static0 = eqx.partition(model, spec)

    scales = None if scaling is None else scaling.scales(params0, model)

    problem = _Problem(
        loss=loss,
        linear_spec=linear_spec,
        linear_nonnegative=_nonnegative_flags(model, linear_spec, separable),
        nonnegative=eqx.partition(_nonnegative_mask(model), spec)[0],
        scales=scales,
        data=data,
        validation=validation,
        val_loss=val_loss_fn,
    )
    extra0 = loss.init_extra(model, data)
    starts = (MultiStart(1, 0.0) if multistart is None else multistart).draw(params0, seed)
    if scales is not None:
        starts = jax.tree_util.tree_map(lambda p, c: p / c, starts, scales)
    extras = jax.tree_util.tree_map(lambda e: jnp.broadcast_to(e, (count,) + e.shape), extra0)
    states = shard_batch((starts, extras))  # the starts spread over the local devices (identity on one)

    search = _Search(states, validation is not None, start_time, _progress_bar(progress, steps, kind))
    result_code, message = "max_steps", f"ran the full budget of {steps} steps"
    stop = False
    stage_steps = _split(steps, len(eps_schedule))
    static = static0
    solver_codes: list[str] = []

    linear_only = not any(eqx.is_array(leaf) for leaf in jax.tree_util.tree_leaves(params0))
    if linear_only:  # only separable (linear) parameters: one least-squares solve is the whole fit
        stop, result_code, message = True, "successful", "only linear parameters: solved by least squares"
        search.best_scores = np.zeros(count)
    converged = ""  # the tolerance rule's message, where it ended the last stage
    for eps, budget in zip(eps_schedule, stage_steps, strict=True):
        if stop or budget == 0:
            continue
        converged = ""
        if eps is not None:
            static = eqx.partition(with_smoothing(model, Smooth(jnp.asarray(eps, dtype=float))), spec)[1]
            # losses at different widths are not comparable: each stage starts its own best-so-far
            search.restart(*_batched_losses(problem, search.states, static))
        if kind == "optax":
            chunk = eval_every or max(1, steps // 50)
            opt_states = _optax_init(solver, search.states)
            done = 0
            while done < budget and not stop:
                n = min(chunk, budget - done)
                # the chunk length is a traced argument: chunks of any length (a stage's last, shorter one, the
                # next stage's) share one compilation of the gradient program
                states, opt_states, bad = _run_chunk(solver, problem, search.states, opt_states, static, jnp.asarray(n))
                done += n
                search.observe(states, n, np.asarray(bad), *_batched_losses(problem, states, static), eps)
                if search.diverged.all():
                    stop, result_code, message = True, "diverged", _DIVERGENCE_MESSAGE
                elif tolerance is not None and search.converged(tolerance):
                    converged = _converged_message(tolerance, chunk, search.step_count)
                    break  # this stage has converged (the next continuation stage, if any, still runs)
                elif patience is not None and validation is not None and search.stall >= patience:
                    stop, result_code = True, "early_stopped"
                    message = f"validation loss did not improve for {patience} evaluations (step {search.step_count})"
        else:
            chunk = budget if tolerance is None else (eval_every or max(1, budget // 8))
            done = 0
            while done < budget and not stop:
                n = min(chunk, budget - done)
                states, solver_codes, nsteps = _run_optimistix(solver, kind, problem, search.states, static, n)
                states = (problem.project(states[0]), states[1])  # the solver cannot bound: damping back to >= 0
                train_now, val_now = map(np.asarray, _batched_losses(problem, states, static))
                search.observe(states, int(np.max(nsteps)), ~np.isfinite(train_now), train_now, val_now, eps)
                done += n
                if search.diverged.all():
                    stop, result_code, message = True, "diverged", "the loss became non-finite for every start"
                elif all(code == "successful" for code in solver_codes):
                    break  # the solver's own tolerance
                elif tolerance is not None and search.converged(tolerance):
                    converged = _converged_message(tolerance, chunk, search.step_count)
                    break
    search.close()
    if converged and not stop:  # the tolerance rule ended the last stage
        result_code, message = "successful", converged
    best_states, best_scores, diverged, history = (
        search.best_states,
        search.best_scores,
        search.diverged,
        search.history,
    )

    # choose the best start; keep its best snapshot
    if np.isfinite(best_scores).any():
        best = int(np.argmin(best_scores))
    else:  # every start diverged before the first check: fall back to the initial parameters
        best = 0
        best_states = (starts, extras)
    chosen = jax.tree_util.tree_map(lambda a: a[best], best_states)
    if kind != "optax" and result_code != "diverged" and not converged:
        code = solver_codes[best] if solver_codes else "successful"
        result_code = code.split(":")[0]
        message = {
            "successful": "the optimistix solver converged",
            "max_steps": f"the optimistix solver reached max_steps = {steps} before converging",
        }.get(code, f"the optimistix solver failed ({code.split(':')[-1]}); the best model seen was kept")
    elif kind == "optax" and result_code == "max_steps" and diverged[best]:
        result_code, message = "diverged", "the chosen start diverged; its last good parameters were kept"
    if result_code == "max_steps" and kind == "optax":
        message = _budget_message(steps, [row[best] for row in history["train_loss"]])
    if result_code not in ("diverged",) and diverged.any() and not diverged.all():
        message += f" ({int(diverged.sum())} of {count} starts diverged and were discarded)"
    # never worse than the start: the initial model, scored as the starts are chosen, in the final setting
    start = jax.tree_util.tree_map(lambda a: a[:1], (starts, extras))
    if linear_only:  # the least-squares solve is the fit: nothing to compare
        start = None
    if start is not None:
        pair = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), chosen, start)
        pair_train, pair_val = map(np.asarray, _batched_losses(problem, pair, static))
        pair_scores = pair_val if validation is not None else pair_train
        if np.isfinite(pair_scores[1]) and not pair_scores[0] <= pair_scores[1]:
            chosen = jax.tree_util.tree_map(lambda a: a[0], start)
            message += "; no step improved on the start, so the start is returned"
            if scales is None and kind == "optax":
                message += (
                    " (real parameters are stepped as stored: for physical models pass scaling="
                    "fj.ParameterScaling(), which scales each by its magnitude or physical range)"
                )

    fitted = problem.materialise(chosen[0], static)
    train_loss = float(_evaluate(loss, fitted, chosen[1], data))
    val_loss = float(_evaluate(val_loss_fn, fitted, None, validation)) if validation is not None else float("nan")
    exact_val = (
        float(_evaluate(val_loss_fn, exact(fitted), None, validation)) if validation is not None else float("nan")
    )
    if validation is not None and not np.isfinite(val_loss) and result_code != "diverged":
        result_code = "diverged"
        message = (
            f"the validation loss of the returned model is not finite ({val_loss}); check the validation data "
            "(NaN, scale) or the model's behaviour on it; " + message
        )
    std = None
    if compute_std and np.isfinite(train_loss):
        std = _gauss_newton_std(fitted, spec, linear_spec, loss, chosen[1], data)
    history_arrays = {
        "step": np.asarray(history["step"]),
        "train_loss": np.asarray([row[best] for row in history["train_loss"]]),
        "val_loss": np.asarray([row[best] for row in history["val_loss"]]),
        "eps": np.asarray(history["eps"], dtype=float),
        "time": np.asarray(history["time"], dtype=float),
    }
    return FitResult(
        model=fitted,
        result=result_code,
        message=message,
        history=history_arrays,
        train_loss=train_loss,
        val_loss=val_loss,
        exact_val_loss=exact_val,
        evaluations=search.evaluations,
        wall_time=time.perf_counter() - start_time,
        num_starts=count,
        best_start=best,
        std=std,
        extra=chosen[1],
    )


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------


def _validate(model: Any, data: Any, validation: Any, steps: Any, loss: Any) -> None:
    if not isinstance(model, eqx.Module):
        raise TypeError(f"fit: `model` must be a fricjax model (an equinox Module), got {type(model).__name__}.")
    if isinstance(model, AbstractModel):  # the signals the model needs are in the records (dt, x / v, ...)
        for record in (data, validation):
            if isinstance(record, FrictionData):
                model.check_inputs(record.motion)
    for name, record in (("data", data), ("validation", validation)):
        if isinstance(record, FrictionData) and getattr(loss, "normalise", False) and is_concrete(record.force):
            if not float(np.std(np.asarray(record.force))) > 0:
                raise ValueError(
                    f"fit: the measured force of `{name}` is constant (std = 0), so the normalised loss (error / "
                    "std) is undefined; check the record, or use a loss with normalise=False."
                )
    data_type = getattr(loss, "data_type", FrictionData)
    for name, value in (("data", data), ("validation", validation)):
        if value is not None and not isinstance(value, data_type):
            raise TypeError(
                f"fit: `{name}` must be a {data_type.__name__} for {type(loss).__name__}, got {type(value).__name__}"
                + (" (wrap motion and force as fj.FrictionData(motion, force))." if data_type is FrictionData else ".")
            )
    if not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"fit: `steps` must be a positive integer, got {steps!r}.")


def _solver_kind(solver: Any) -> str:
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        return "least_squares"
    if isinstance(solver, optx.AbstractMinimiser):
        return "minimise"
    if isinstance(solver, optax.GradientTransformation):
        return "optax"
    raise TypeError(
        f"fit: `solver` must be an optax GradientTransformation (e.g. optax.adam(1e-2)) or an optimistix "
        f"least-squares solver / minimiser (e.g. optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)), got "
        f"{type(solver).__name__}."
    )


def levenberg_marquardt(rtol: float = 1e-10, atol: float = 1e-12) -> optx.LevenbergMarquardt:
    """A Levenberg-Marquardt solver with tolerances suited to friction fits (an optimistix solver)."""
    return optx.LevenbergMarquardt(rtol=rtol, atol=atol)


@eqx.filter_jit
def _optax_init(solver: Any, states: Any) -> Any:
    return jax.vmap(solver.init)(states)


def _tree_finite(tree: Any) -> jax.Array:
    leaves = [jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(tree) if eqx.is_inexact_array(x)]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.asarray(True)


def _where_tree(condition: jax.Array, new: Any, old: Any) -> Any:
    """`where(condition, new, old)` leaf by leaf; a condition of shape (B,) selects along the leading batch axis."""

    def select(a: jax.Array, b: jax.Array) -> jax.Array:
        return jnp.where(condition.reshape(condition.shape + (1,) * (a.ndim - condition.ndim)), a, b)

    return jax.tree_util.tree_map(select, new, old)


class _Problem(eqx.Module):
    """Everything an evaluation needs besides the parameters, as one pytree: jitted drivers take it as an
    argument (arrays traced, the rest static), so a second `fit` of the same shapes reuses the compilation."""

    loss: AbstractLoss
    linear_spec: Any
    linear_nonnegative: tuple[bool, ...] | None = eqx.field(static=True)
    nonnegative: Any  # a tree of Python bools shaped like the trained parameters (static under jit)
    scales: Any
    data: FrictionData
    validation: FrictionData | None
    val_loss: AbstractLoss

    def project(self, params: Any) -> Any:
        """Trained parameters with the physically non-negative ones (damping coefficients) clipped at 0."""
        return jax.tree_util.tree_map(lambda p, m: jnp.maximum(p, 0.0) if m else p, params, self.nonnegative)

    def materialise(self, params: Any, static: Any) -> Any:
        if self.scales is not None:
            params = jax.tree_util.tree_map(lambda u, c: u * c, params, self.scales)
        m = eqx.combine(params, static)
        if self.linear_spec is None:
            return m
        burn_in = getattr(self.loss, "burn_in", 0)
        return solve_linear(m, self.linear_spec, self.data, burn_in, nonnegative=self.linear_nonnegative)

    def objective(self, state: Any, static: Any) -> jax.Array:
        params, extra = state
        return self.loss(self.materialise(params, static), extra, self.data)

    def residuals(self, state: Any, static: Any) -> jax.Array:
        params, extra = state
        return self.loss.residuals(self.materialise(params, static), extra, self.data)

    def val_objective(self, state: Any, static: Any) -> jax.Array:
        if self.validation is None:
            return jnp.asarray(jnp.nan)
        return self.val_loss(self.materialise(state[0], static), None, self.validation)


@eqx.filter_jit
def _batched_losses(problem: _Problem, states: Any, static: Any) -> tuple[jax.Array, jax.Array]:
    def both(state: Any) -> tuple[jax.Array, jax.Array]:
        return problem.objective(state, static), problem.val_objective(state, static)

    return jax.vmap(both)(states)


@eqx.filter_jit
def _run_chunk(solver: Any, problem: _Problem, states: Any, opt_states: Any, static: Any, n: jax.Array) -> Any:
    """`n` (a traced integer) optimiser steps of every start, each start's steps stopping at its first
    non-finite value or gradient. Returns `(states, opt_states, bad)`."""
    solver = optax.with_extra_args_support(solver)

    def one(state: Any, opt_state: Any) -> Any:
        def body(_: Any, carry: Any) -> Any:
            s, o, bad = carry
            value, grads = jax.value_and_grad(problem.objective)(s, static)
            updates, o_new = solver.update(
                grads, o, s, value=value, grad=grads, value_fn=lambda p: problem.objective(p, static)
            )
            s_new = optax.apply_updates(s, updates)
            s_new = (problem.project(s_new[0]), s_new[1])  # physically signed parameters stay >= 0
            ok = jnp.isfinite(value) & _tree_finite(grads) & _tree_finite(s_new) & ~bad
            s = _where_tree(ok, s_new, s)
            o = _where_tree(ok, o_new, o)
            return s, o, bad | ~ok

        return jax.lax.fori_loop(0, n, body, (state, opt_state, jnp.asarray(False)))

    return jax.vmap(one)(states, opt_states)


@eqx.filter_jit
def _optimistix_solve(solver: Any, kind: str, problem: _Problem, states: Any, static: Any, max_steps: int) -> Any:
    def one(state: Any) -> Any:
        sol: Any
        if kind == "least_squares":
            sol = optx.least_squares(
                lambda y, args: problem.residuals(y, args), solver, state, args=static, max_steps=max_steps, throw=False
            )
        else:
            sol = optx.minimise(
                lambda y, args: problem.objective(y, args), solver, state, args=static, max_steps=max_steps, throw=False
            )
        return sol.value, sol.result._value, sol.stats["num_steps"]  # noqa: SLF001

    return jax.vmap(one)(states)


def _run_optimistix(
    solver: Any, kind: str, problem: _Problem, states: Any, static: Any, max_steps: int
) -> tuple[Any, list[str], np.ndarray]:
    values, codes, nsteps = _optimistix_solve(solver, kind, problem, states, static, max_steps)
    names = [_optx_code(int(c)) for c in np.asarray(codes)]
    return values, names, np.asarray(nsteps)


def _optx_code(value: int) -> str:
    """Map an optimistix RESULTS index to a fricjax result code."""
    names = list(optx.RESULTS._name_to_item)  # noqa: SLF001 - index order is the enumeration's
    name = names[value] if 0 <= value < len(names) else "unknown"
    if name == "successful":
        return "successful"
    if "max_steps" in name:
        return "max_steps"
    return f"solver_failed:{name}"


def _record(
    history: dict[str, list[Any]], step: int, train: np.ndarray, val: np.ndarray, eps: Any, elapsed: float
) -> None:
    history["time"].append(elapsed)
    history["step"].append(step)
    history["train_loss"].append(train)
    history["val_loss"].append(val)
    history["eps"].append(np.nan if eps is None else float(eps))


def _split(total: int, parts: int) -> list[int]:
    base = [total // parts] * parts
    for i in range(total - sum(base)):
        base[i] += 1
    return base


class _Search:
    """The bookkeeping of a fit over a batch of starts: current and best states, scores (validation loss, else
    training loss), which starts diverged, stalls for early stopping, the history and the progress bar."""

    def __init__(self, states: Any, by_validation: bool, start_time: float, bar: Any):
        count = jax.tree_util.tree_leaves(states)[0].shape[0] if jax.tree_util.tree_leaves(states) else 1
        self.states = self.best_states = states
        self.best_scores = np.full(count, np.inf)
        self.diverged = np.zeros(count, dtype=bool)
        self.by_validation, self.start_time, self.bar = by_validation, start_time, bar
        self.step_count = self.evaluations = self.stall = 0
        self.history: dict[str, list[Any]] = {"step": [], "train_loss": [], "val_loss": [], "eps": [], "time": []}

    def _scores(self, train: Any, val: Any) -> np.ndarray:
        scores = np.asarray(val if self.by_validation else train)
        return np.where(np.isfinite(scores) & ~self.diverged, scores, np.inf)

    def restart(self, train: Any, val: Any) -> None:
        """A new continuation stage: its best-so-far (and its patience) start from the current states."""
        self.best_states, self.best_scores = self.states, self._scores(train, val)
        self.stall = 0

    def observe(self, states: Any, steps: int, bad: np.ndarray, train: Any, val: Any, eps: Any) -> None:
        """After `steps` more solver steps: keep the best state of each start, record, update the bar."""
        train, val = np.asarray(train), np.asarray(val)
        self.states = states
        self.step_count += steps
        self.evaluations += steps
        self.diverged |= bad
        scores = self._scores(train, val)
        improved = scores < self.best_scores
        self.best_states = _where_tree(jnp.asarray(improved), states, self.best_states)
        self.best_scores = np.where(improved, scores, self.best_scores)
        self.stall = 0 if improved.any() else self.stall + 1
        _record(self.history, self.step_count, train, val, eps, time.perf_counter() - self.start_time)
        if self.bar is not None:
            self.bar.update(steps)
            self.bar.set_postfix(loss=f"{np.nanmin(train):.3g}", val=f"{np.nanmin(val):.3g}")

    def converged(self, tolerance: float) -> bool:
        """Whether the best start's training loss fell by less than `tolerance` (relative) over the last check."""
        losses = self.history["train_loss"]
        if len(losses) < 2:
            return False
        previous, last = np.nanmin(losses[-2]), np.nanmin(losses[-1])
        return bool(np.isfinite(last) and previous - last <= tolerance * abs(previous))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _budget_message(steps: int, losses: list[Any]) -> str:
    """Why an optax fit stopped at its budget, in a sentence: still improving, or levelled off."""
    finite = [float(x) for x in losses if np.isfinite(x)]
    if len(finite) < 2:
        return f"ran the full budget of {steps} steps (no convergence test for optax solvers)"
    previous, last = finite[-2], finite[-1]
    change = (previous - last) / max(abs(previous), 1e-300)
    if change > 1e-3:
        return (
            f"stopped at the step budget ({steps} steps) while the loss was still falling ({100 * change:.2g} % over "
            "the last check): not converged; raise `steps` to go on"
        )
    if change < -1e-3:
        return (
            f"stopped at the step budget ({steps} steps) with the loss rising or oscillating at the end "
            f"({100 * -change:.2g} % up over the last check); the best model seen is returned: lower the learning rate"
        )
    return f"ran the full budget of {steps} steps; the loss had levelled off (change {100 * change:.2g} % at the end)"


def _converged_message(tolerance: float, chunk: int, step: int) -> str:
    return f"converged: the loss fell by less than {tolerance:g} (relative) over the last {chunk} steps (step {step})"


_DIVERGENCE_MESSAGE = (
    "the loss or the parameters became non-finite for every start; the last good parameters were kept "
    "(lower the learning rate, check the data scale, or start closer)"
)


def _progress_bar(progress: bool, steps: int, kind: str) -> Any:
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=steps, desc=f"fit ({kind})", unit="step", leave=False)


@eqx.filter_jit
def _evaluate(loss: AbstractLoss, model: Any, extra: Any, data: FrictionData) -> jax.Array:
    return loss(model, extra, data)


def _gauss_newton_std(
    model: Any, spec: Any, linear_spec: Any, loss: AbstractLoss, extra: Any, data: FrictionData
) -> Any:
    """Standard deviations of the trained physical parameters: sqrt(diag(s^2 (J^T J)^+)), s^2 = |r|^2 / (N - p),
    with r the unnormalised residuals and J their Jacobian w.r.t. the physical (unwrapped) parameters."""
    if linear_spec is not None:
        spec = jax.tree_util.tree_map(lambda a, b: bool(a) or bool(b), spec, linear_spec)
    physical = unwrap(model)
    phys_spec = _physical_spec(model, spec)
    params, rest = eqx.partition(physical, phys_spec)
    if not jax.tree_util.tree_leaves(params):
        return None
    return _std_from_jacobian(params, rest, loss, extra, data)


@eqx.filter_jit
def _std_from_jacobian(params: Any, rest: Any, loss: AbstractLoss, extra: Any, data: FrictionData) -> Any:
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    scale = jnp.std(data.force) if getattr(loss, "normalise", False) else 1.0

    def residuals(theta: jax.Array) -> jax.Array:
        return loss.residuals(eqx.combine(unravel(theta), rest), extra, data) * scale

    r = residuals(flat)
    J = jax.jacfwd(residuals)(flat) if flat.size <= 64 else jax.jacrev(residuals)(flat)
    # the cut-off of the former pinv of the Gram matrix (the figures in the docs were computed with it)
    std_flat = parameter_std(
        J, r, max(int(r.size) - int(flat.size), 1), rcond=float(np.sqrt(10 * flat.size * np.finfo(J.dtype).eps))
    )
    nan_rest = jax.tree_util.tree_map(lambda a: jnp.full_like(a, jnp.nan) if eqx.is_inexact_array(a) else a, rest)
    return eqx.combine(unravel(std_flat), nan_rest)
