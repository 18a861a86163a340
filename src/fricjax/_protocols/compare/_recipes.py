"""Fit recipes shared by the model families of `compare`: what a recipe is (`ModelSpec`: a start built from the
training record and a fit), Levenberg-Marquardt with the linear parameters by least squares (`lm_recipe`), the
output layer by least squares then output error (`least_squares_then_noe`), a structure chosen on the validation
part (`structure_by_validation`), and the result of a model identified without iterations (`identified_result`)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optax

from ..._constraints import Bounded, Fixed, Positive, parameter_arrays, unwrap
from ..._estimation._fit import fit
from ..._estimation.loop._levenberg_marquardt import levenberg_marquardt
from ..._estimation.loop._solution import FitResult
from ..._estimation.loop._strategies import MultiStart, ParameterScaling, where_from_path
from ..._metrics import nmse
from ..._models.combine._wrapper import inner_friction, wrapper_path
from ._records import Split, TrainingRecords
from ._scoring import SIGNIFICANT_T, VALIDATION_BLOCKS, free_run, paired_validation_gain
from ._settings import CompareError, DataScales, FitSettings


@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """How to start and fit one model family in `compare`: `build(scales)` and
    `fit(start, split, seed, progress)`. `build` is None for models identified from the split as a whole (their
    `fit` gets `start=None`: structure and parameters chosen on the training and validation parts together).
    `label` may hold `{elements}`, filled in with the element count of the model it labels (`label_for`)."""

    label: str
    build: Callable[[DataScales], Any] | None
    fit: Callable[[Any, Split, int, bool], FitResult]

    def label_for(self, model: Any) -> str:
        """The label of `model` (a start or a fitted model of this family): `{elements}` filled in."""
        if "{elements}" not in self.label:
            return self.label
        friction = unwrap(inner_friction(model)) if model is not None else None
        k = getattr(friction, "k", None)
        return self.label.replace("{elements}", "?" if k is None else str(np.shape(k)[-1]))


def separable_paths(start: Any, paths: tuple[str, ...]) -> tuple[str, ...]:
    """The linear parameters of a (possibly wrapped) model: the friction model's, and the drift rate; none that is
    fixed or bounded (`constrained`: not solved by unconstrained least squares)."""
    prefixed = tuple(wrapper_path(start) + path for path in paths)
    linear = (*prefixed, "rate") if getattr(start, "drifts", False) else prefixed
    return tuple(path for path in linear if not isinstance(where_from_path(path)(start), (Fixed, Bounded)))


def matching_paths(model: Any, name: str) -> list[str]:
    """The parameter paths of `model` (as `fj.unwrap(model)`'s `parameter_arrays`) that `name` names: the path
    itself or its end after a dot (`sigma2` names `model.sigma2`; `stribeck.Fc` names `model.stribeck.Fc`)."""
    return [path for path in parameter_arrays(unwrap(model)) if path == name or path.endswith("." + name)]


def constrained(model: Any, settings: FitSettings) -> Any:
    """`model` with the parameters `settings.fix` names held at their values (`fj.Fixed`, a positive one as
    `Fixed(Positive(value))`) and those `settings.bounds` names kept in their intervals (`fj.Bounded`, a start outside
    moved 1 % inside); idempotent (a parameter already fixed or bounded is left as it is)."""
    for name, value in settings.fix:
        for path in matching_paths(model, name):
            where = where_from_path(path)
            node = where(model)
            if isinstance(node, (Fixed, Bounded)):
                continue
            current = np.asarray(unwrap(node))
            held = np.broadcast_to(np.asarray(value, current.dtype), current.shape)
            if isinstance(node, Positive):
                if value <= 0:
                    raise CompareError(f"`fix` {name}={value:g}: {path} is a positive parameter; give a value > 0")
                model = eqx.tree_at(where, model, Fixed(Positive(held, transform=node.transform, name=path)))
            else:
                model = eqx.tree_at(where, model, Fixed(jnp.asarray(held)))
    for name, low, high in settings.bounds:
        for path in matching_paths(model, name):
            where = where_from_path(path)
            node = where(model)
            if isinstance(node, (Fixed, Bounded)):
                continue
            current = np.asarray(unwrap(node))
            inside = Bounded.inside(current.astype(float), low, high)
            model = eqx.tree_at(where, model, Bounded(inside, low, high, name=path, dtype=current.dtype))
    return model


def lm_recipe(separable: tuple[str, ...], starts: int, settings: FitSettings) -> Callable[..., FitResult]:
    """Levenberg-Marquardt with parameter scaling from `starts` starts (the validation part choosing), the
    parameters `separable` (and the drift rate) solved by least squares inside each step."""

    def run(start: Any, split: Split | TrainingRecords, seed: int, progress: bool) -> FitResult:
        start = constrained(start, settings)
        data, records = split.fit_arguments(start, drift=settings.drift != "none")
        return fit(
            start,
            data,
            scaling=ParameterScaling(),
            solver=levenberg_marquardt(),
            steps=settings.steps,
            tolerance=settings.tolerance,
            # several records: every parameter by LM (the per-record nuisances are decision variables of the loss)
            separable=() if split.several else separable_paths(start, separable),
            multistart=_multistart(starts),
            seed=seed,
            progress=progress,
            compute_std=True,
            **records,
        )

    return run


def _multistart(starts: int) -> MultiStart | None:
    """The starts of an LM recipe: none beyond the given one, 2 drawn normally (spread 0.5), or more drawn
    log-uniformly over a factor e either way and screened down to the best 2 (`FitSettings.starts`)."""
    if starts <= 1:
        return None
    if starts <= 2:
        return MultiStart(starts, spread=0.5)
    return MultiStart(starts, spread=1.0, distribution="log-uniform", keep=2)


def identified_result(model: Any, message: str, wall_time: float, validation_nmse: float) -> FitResult:
    """A `FitResult` for a model identified in closed form or by a grid (no optimiser steps)."""
    empty = np.zeros(0)
    history = {"step": empty, "train_loss": empty, "val_loss": empty, "eps": empty, "time": empty}
    nan = float("nan")
    return FitResult(model, "successful", message, history, nan, validation_nmse, validation_nmse, 0, wall_time, 1, 0)


def structure_by_validation(
    structures: dict[str, Callable[[DataScales], Any]], refine: Callable[..., FitResult]
) -> Callable[..., FitResult]:
    """Identify each structure on the training part, keep the one whose free run (exact) has the least NMSE on the
    validation part, then `refine` it; the fit's message names the structure and every validation score."""

    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        began = time.perf_counter()
        scales = DataScales.from_data(split.train)
        measured = np.asarray(split.until_validation_end.force)[split.train_end :]
        scores = {}
        candidates = {}
        for name, build in structures.items():
            model = build(scales)
            prediction = free_run(model, split.until_validation_end)[split.train_end :]
            value = float(nmse(measured, prediction))
            candidates[name], scores[name] = model, value if np.isfinite(value) else np.inf
        chosen = min(scores, key=lambda name: scores[name])
        refined = refine(candidates[chosen], split, seed, progress)
        listed = ", ".join(f"{name} {value:.3g} %" for name, value in scores.items())
        message = f"structure: {chosen} (validation NMSE before refinement: {listed}); {refined.message}"
        return dataclasses.replace(refined, message=message, wall_time=time.perf_counter() - began)

    return run


def least_squares_then_noe(linear: tuple[str, ...], settings: FitSettings) -> Callable[..., FitResult]:
    """The output layer `linear` (and the drift rate) by least squares, then every weight by output error; the
    output-error model is kept only when it predicts the validation part significantly better
    (`paired_validation_gain`)."""

    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        validation: dict[str, Any] = {"validation": split.until_validation_end, "validation_burn_in": split.train_end}
        paths = separable_paths(start, linear)
        if not paths:  # nothing enters the free run linearly (a NARX with fed-back forces and no drift)
            first = identified_result(start, "", 0.0, float("nan"))
        else:
            first = fit(start, split.train, train=paths, separable=paths, steps=1, **validation)
        rate = 3e-3
        warmup = min(30, settings.neural_steps // 5)  # 30 steps, less for short budgets (decay needs > warm-up)
        schedule = optax.warmup_cosine_decay_schedule(rate / 10, rate, warmup, settings.neural_steps, rate / 30)
        noe = fit(
            first.model,
            split.train,
            solver=optax.chain(optax.clip_by_global_norm(1.0), optax.adam(schedule)),
            steps=settings.neural_steps,
            separable=separable_paths(start, ()),
            seed=seed,
            progress=progress,
            **validation,
        )
        # the output-error stage's budget is the command line's --neural-steps, not fit's `steps` or --steps
        noe = dataclasses.replace(noe, message=noe.message.replace("raise `steps`", "raise --neural-steps"))
        wall_time = first.wall_time + noe.wall_time
        if not noe.val_loss < first.val_loss:  # the NOE stage returned its start
            return dataclasses.replace(noe, wall_time=wall_time)
        improvement, t = paired_validation_gain(first.model, noe.model, split)
        gain = f"; output error improved the validation error by {100 * improvement:.2g} % (paired t = {t:.2f}"
        if t >= SIGNIFICANT_T:
            return dataclasses.replace(noe, message=f"{noe.message}{gain}): kept", wall_time=wall_time)
        noise = f" over {VALIDATION_BLOCKS} blocks, < {SIGNIFICANT_T:g}: within the noise)"
        within = noise + ", so the least-squares start is kept"
        return dataclasses.replace(
            noe,
            model=first.model,
            message=noe.message + gain + within,
            train_loss=first.train_loss,
            val_loss=first.val_loss,
            exact_val_loss=first.exact_val_loss,
            std=first.std,
            wall_time=wall_time,
        )

    return run
