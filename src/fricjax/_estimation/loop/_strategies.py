"""Fit strategies: explicit, opt-in wrappers of the problem a fit solves, applied only when asked.

A strategy changes the `FitPlan` the driver builds, through two hooks called for every strategy in the order given:
`prepare(plan)` before the parameters are selected (the model's smoothing, the separable paths, the smoothing
stages, the stopping rules) and `transform(plan)` after (the starts, the scales). `fj.fit(..., strategies=[...])`
takes them in any combination; its keywords `scaling=`, `multistart=`, `continuation=`, `separable=`,
`patience=` and `tolerance=` are the same strategies.

`MultiStart` (vmap-ed global search), `Continuation` (smoothing annealed towards the exact model),
`ParameterScaling` (the optimiser sees real parameters divided by a scale), `Separable` (linear parameters solved by
least squares inside every evaluation), `EarlyStopping` (patience on the validation loss), `Tolerance` (converged
when the loss stops falling). Best-so-far is not a strategy: the loop always keeps each start's best parameters.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ..._constraints import AbstractUnwrappable, Bounded, Fixed, Positive, unwrap
from ..._smoothing import AbstractSmoothing, Smooth, is_concrete, on_host, with_smoothing
from ..._validation import nonnegative_float, positive_float, positive_int


@dataclasses.dataclass(frozen=True)
class FitPlan:
    """What the fit driver runs, as the strategies leave it.

    - `model`: the start model (smoothing as the first stage needs it); `separable`: dotted paths solved by least
      squares; `stages`: the smoothing width of each stage (`None`: the model's own); `tolerance`, `patience`: the
      loop's stopping rules; `seed`: for random starts; `screen`: `(fraction, keep)`: after that fraction of the
      first stage's steps only the `keep` best starts go on.
    - After parameter selection: `params0` (the trained leaves of the start), `scales` (None, or a tree shaped
      like `params0`: the optimiser sees parameters divided by it) and `starts` (a batch of `params0`-shaped trees
      along a new leading axis, in the optimiser's coordinates: divided by `scales`); `penalty` (None, or a
      `Penalty`: regularisation terms added to the loss).
    """

    model: Any
    separable: tuple[str, ...] = ()
    stages: tuple[float | None, ...] = (None,)
    tolerance: float | None = None
    patience: int | None = None
    seed: int = 0
    screen: tuple[float, int] | None = None
    params0: Any = None
    scales: Any = None
    starts: Any = None
    penalty: Any = None


class AbstractStrategy:
    """A wrapper of the fit problem: override `prepare` and / or `transform` (each returns the plan, changed with
    `dataclasses.replace`)."""

    def prepare(self, plan: FitPlan) -> FitPlan:
        """Before parameter selection: the model, the separable paths, the stages, the stopping rules."""
        return plan

    def transform(self, plan: FitPlan) -> FitPlan:
        """After parameter selection: the starts and scales (`plan.params0` is set)."""
        return plan


def _add_start_axis(leaf: Any) -> Any:
    """`leaf[None]` (in NumPy for concrete values: an eager JAX reshape compiles a program of its own)."""
    if not eqx.is_array(leaf):
        return leaf
    return jax.device_put(np.asarray(leaf)[None]) if is_concrete(leaf) else leaf[None]


def _divide(starts: Any, scales: Any) -> Any:
    if scales is None:
        return starts

    return jax.tree_util.tree_map(lambda p, c: on_host(lambda xp, a, b: a / b, p, c), starts, scales)


@dataclasses.dataclass(frozen=True)
class MultiStart(AbstractStrategy):
    """`count` starts drawn around the initial model, fitted together in one vmap-ed program.

    `distribution="normal"` (default): positive (log-stored) parameters are multiplied by `exp(spread * N(0, 1))`,
    real ones get `spread * (|value| + 1e-12) * N(0, 1)` added; `"log-uniform"`: positive parameters multiplied by
    `exp(U(-spread, spread))` (spread over `[p e^-spread, p e^spread]`, even in the logarithm), real ones
    `spread * (|value| + 1e-12) * U(-1, 1)` added. The first start is the initial model itself. The best start is
    chosen by validation loss (training loss without validation data).

    Screening: with `keep` (< `count`), every start runs the first `screen` fraction of the (first stage's) steps,
    then only the `keep` best go on, and the initial model with them (one more compilation, for the smaller batch;
    an optax solver's moments restart), so that many starts cost a short run each. `screen=0`: forward screening,
    each start's loss evaluated once (one vmap-ed free run of every start, the separable parameters solved) and
    the `keep` best fitted: hundreds of starts for the price of a few steps.
    """

    count: int
    spread: float = 0.5
    distribution: str = "normal"
    keep: int | None = None
    screen: float = 0.25

    def __post_init__(self) -> None:
        object.__setattr__(self, "count", positive_int(self.count, "count", "MultiStart"))
        object.__setattr__(self, "spread", nonnegative_float(self.spread, "spread", "MultiStart"))
        if self.distribution not in ("normal", "log-uniform"):
            raise ValueError(
                f"MultiStart: `distribution` must be 'normal' or 'log-uniform', got {self.distribution!r}."
            )
        if self.keep is not None:
            object.__setattr__(self, "keep", positive_int(self.keep, "keep", "MultiStart"))
            if self.keep >= self.count:
                raise ValueError(
                    f"MultiStart: `keep` ({self.keep}) must be below `count` ({self.count}): screening keeps the best "
                    f"`keep` of the `count` starts. Leave `keep=None` to fit every start."
                )
        screen = nonnegative_float(self.screen, "screen", "MultiStart")
        if not 0 <= screen < 1:
            raise ValueError(
                f"MultiStart: `screen` must be a fraction of the steps in [0, 1) (0: by the loss at the start), "
                f"got {self.screen!r}."
            )
        object.__setattr__(self, "screen", screen)

    def prepare(self, plan: FitPlan) -> FitPlan:
        if self.keep is None:
            return plan
        return dataclasses.replace(plan, screen=(self.screen, self.keep))

    def transform(self, plan: FitPlan) -> FitPlan:
        return dataclasses.replace(plan, starts=_divide(self.draw(plan.params0, plan.seed), plan.scales))

    def draw(self, params: Any, seed: int = 0) -> Any:
        """`count` starts around `params` (trainable leaves; a leading axis of size `count` is added to each);
        start 0 is `params` itself. Deterministic for a `seed`."""
        leaves, treedef = jax.tree_util.tree_flatten(params, is_leaf=lambda n: isinstance(n, Positive))
        count, spread = self.count, self.spread
        if count == 1:  # `params` itself: no random draw (nor its compilation)
            return jax.tree_util.tree_map(_add_start_axis, params)
        key = jax.random.PRNGKey(seed)
        out = []
        for leaf in leaves:
            key, sub = jax.random.split(key)
            if isinstance(leaf, Positive) and leaf.raw is not None:
                raw = leaf.raw
                noise = spread * self._unit(sub, (count,) + raw.shape, raw.dtype)
                out.append(eqx.tree_at(lambda p: p.raw, leaf, raw[None] + noise.at[0].set(0.0)))
            elif eqx.is_inexact_array(leaf):
                noise = spread * self._unit(sub, (count,) + leaf.shape, leaf.dtype) * (jnp.abs(leaf) + 1e-12)
                out.append(leaf[None] + noise.at[0].set(0.0))
            else:  # frozen (partitioned out) or not an array
                out.append(leaf)
        return jax.tree_util.tree_unflatten(treedef, out)

    def _unit(self, key: Any, shape: tuple[int, ...], dtype: Any) -> jax.Array:
        """Unit draws of the chosen distribution: N(0, 1), or U(-1, 1) for "log-uniform"."""
        if self.distribution == "log-uniform":
            return jax.random.uniform(key, shape, dtype, -1.0, 1.0)
        return jax.random.normal(key, shape, dtype)


@dataclasses.dataclass(frozen=True)
class Continuation(AbstractStrategy):
    """Smoothing continuation: the model is fitted in smooth mode with `eps` annealed geometrically from
    `eps_start` to `eps_end` in `stages` stages (steps split evenly); the result is also scored in exact mode.
    `eps` is in the units each model documents (m/s for LuGre / Dahl / static curves, m for GMS, a fraction of
    the thresholds for Maxwell-slip)."""

    eps_start: float
    eps_end: float
    stages: int = 5

    def __post_init__(self) -> None:
        object.__setattr__(self, "eps_start", positive_float(self.eps_start, "eps_start", "Continuation"))
        object.__setattr__(self, "eps_end", positive_float(self.eps_end, "eps_end", "Continuation"))
        object.__setattr__(self, "stages", positive_int(self.stages, "stages", "Continuation"))
        if self.eps_start < self.eps_end:
            raise ValueError(
                f"Continuation: the width is annealed from the smoothest model to the sharpest, so `eps_start` "
                f"({self.eps_start:g}) must be at least `eps_end` ({self.eps_end:g}); swap them."
            )

    def prepare(self, plan: FitPlan) -> FitPlan:
        has_smoothing = any(
            isinstance(leaf, AbstractSmoothing)
            for leaf in jax.tree_util.tree_leaves(plan.model, is_leaf=lambda n: isinstance(n, AbstractSmoothing))
        )
        if not has_smoothing:
            raise ValueError(
                f"Continuation: {type(plan.model).__name__} has no smoothing field (fj.Exact() / fj.Smooth(eps)) to "
                "anneal; drop `continuation`, or give the model a `smoothing` field."
            )
        # smooth from the start, so that every stage shares one tree structure
        model = with_smoothing(plan.model, Smooth(jnp.asarray(self.eps_start, dtype=float)))
        return dataclasses.replace(plan, model=model, stages=tuple(float(eps) for eps in self.schedule()))

    def schedule(self) -> np.ndarray:
        return np.geomspace(self.eps_start, self.eps_end, self.stages)


@dataclasses.dataclass(frozen=True)
class ParameterScaling(AbstractStrategy):
    """The optimiser sees every real (not log/softplus-stored) parameter divided by a scale: its initial
    magnitude `|value|`; where that is 0, the physical range the model declares (`parameter_ranges()`: LuGre
    `z0` ~ Fc / sigma0 [m], offsets ~ Fc [N]), else 1; or `scale` where given per dotted field path.

    One learning rate then suits stiffnesses of 1e8 N/m and offsets of 1e-2 N alike (physical models with
    parameters over many decades), and a zero-initialised bristle deflection moves by a fraction of the
    pre-sliding range per step, not by 1e-2 m. Positive parameters are stored as logs and need no scaling.
    Leave it off for black-box models whose weights are initialised near 0 (it would slow their small weights
    down).

    **Arguments:** `scale`: optional `{path: value}` overrides (e.g. `{"z0": 1e-6}` for a state in metres
    initialised at 0).
    """

    scale: dict[str, float] = dataclasses.field(default_factory=dict)

    def transform(self, plan: FitPlan) -> FitPlan:
        scales = self.scales(plan.params0, plan.model)
        return dataclasses.replace(plan, scales=scales, starts=_divide(plan.starts, scales))

    def scales(self, params: Any, model: Any = None) -> Any:
        """The scale of every trained leaf of `params` (a tree shaped like it; 1 for log/softplus leaves).
        `model`: the whole model `params` was partitioned from, for the physical ranges of zero leaves."""

        def leaf_scale(node: Any) -> Any:
            if isinstance(node, AbstractUnwrappable):
                return jax.tree_util.tree_map(lambda a: jnp.ones_like(a) if eqx.is_inexact_array(a) else a, node)
            if eqx.is_inexact_array(node):
                xp = np if is_concrete(node) else jnp  # concrete values in NumPy: no compilation
                magnitude = xp.abs(xp.asarray(node))
                return jnp.asarray(xp.where(magnitude > 0, magnitude, xp.ones_like(magnitude)), node.dtype)
            return node

        scales = jax.tree_util.tree_map(leaf_scale, params, is_leaf=lambda n: isinstance(n, AbstractUnwrappable))
        for path, value in physical_ranges(model).items():
            where = where_from_path(path)
            try:
                leaf = where(params)
            except (AttributeError, IndexError, KeyError, TypeError):
                continue
            if eqx.is_inexact_array(leaf) and np.isfinite(value) and value > 0:
                scales = eqx.tree_at(where, scales, replace_fn=_where_zero(leaf, value))
        for path, value in self.scale.items():
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"ParameterScaling: the scale of {path!r} must be a positive number, got {value!r}.")
            if not eqx.is_inexact_array(where_from_path(path)(params)):
                continue  # held (fj.Fixed) or stored through a wrapper (fj.Bounded): nothing to scale
            scales = eqx.tree_at(where_from_path(path), scales, replace_fn=_constant(value))
        return scales


@dataclasses.dataclass(frozen=True)
class Separable(AbstractStrategy):
    """The fields at these dotted `paths` enter the simulated force linearly (offsets, FIR coefficients, LuGre
    `sigma1` / `sigma2`, static `Fv`): they are solved exactly by least squares inside every evaluation
    (`SimulationLoss` only; physically non-negative ones by non-negative least squares)."""

    paths: tuple[str, ...]

    def __post_init__(self) -> None:
        paths = (self.paths,) if isinstance(self.paths, str) else tuple(self.paths)
        if not all(isinstance(path, str) for path in paths):
            raise TypeError(f"Separable: `paths` must be dotted field paths ('offset', 'model.sigma2'), got {paths!r}.")
        object.__setattr__(self, "paths", paths)

    def prepare(self, plan: FitPlan) -> FitPlan:
        return dataclasses.replace(plan, separable=(*plan.separable, *self.paths))


@dataclasses.dataclass(frozen=True)
class EarlyStopping(AbstractStrategy):
    """Stop when the validation loss has not improved for `patience` checks (needs validation data); the best
    model seen is returned (`early_stopped`)."""

    patience: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "patience", positive_int(self.patience, "patience", "EarlyStopping"))

    def prepare(self, plan: FitPlan) -> FitPlan:
        return dataclasses.replace(plan, patience=self.patience)


@dataclasses.dataclass(frozen=True)
class Tolerance(AbstractStrategy):
    """End a stage as converged (`successful`) when the best start's training loss falls by less than `rtol`
    (relative) over one check; solvers with their own convergence test then run in checks too."""

    rtol: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "rtol", nonnegative_float(self.rtol, "tolerance", "Tolerance"))

    def prepare(self, plan: FitPlan) -> FitPlan:
        return dataclasses.replace(plan, tolerance=self.rtol)


@dataclasses.dataclass(frozen=True)
class Bounds(AbstractStrategy):
    """Keep parameters inside intervals (System Identification Toolbox's `Minimum` / `Maximum`): `{path: (low, high)}`
    with dotted field paths (`"sigma0"`, `"stribeck.Fc"`). Each is stored as an `fj.Bounded` leaf (`low + (high - low)
    sigmoid(raw)`) for the fit, so every solver steps freely and the value never leaves the interval; the fitted model
    keeps the wrappers (`print(model)` says `(bounded low .. high)`, `fj.unwrap` gives the values). A start outside
    its interval is moved inside it (to 1 % of the interval from the bound it crossed), with a warning. A bounded
    parameter cannot be separable (solved by unconstrained least squares) nor fixed.
    """

    bounds: dict[str, tuple[float, float]]

    def __post_init__(self) -> None:
        if not isinstance(self.bounds, dict) or not self.bounds:
            raise TypeError(f"Bounds: give {{path: (low, high)}}, e.g. {{'sigma0': (1e4, 1e7)}}; got {self.bounds!r}.")
        checked = {}
        for path, interval in self.bounds.items():
            try:
                low, high = (float(x) for x in interval)
            except (TypeError, ValueError):
                raise ValueError(f"Bounds: {path!r} needs (low, high), got {interval!r}.") from None
            if not (np.isfinite(low) and np.isfinite(high) and low < high):
                raise ValueError(f"Bounds: {path!r} needs finite low < high, got ({low!r}, {high!r}).")
            checked[str(path)] = (low, high)
        object.__setattr__(self, "bounds", checked)

    def prepare(self, plan: FitPlan) -> FitPlan:
        import warnings

        model = plan.model
        for path, (low, high) in self.bounds.items():
            if path in plan.separable:
                raise ValueError(
                    f"Bounds: {path!r} is also separable (solved by unconstrained least squares); drop it from one."
                )
            where = where_from_path(path)
            try:
                node = where(model)
            except (AttributeError, IndexError, KeyError, TypeError):
                raise ValueError(f"Bounds: {path!r} is not a field path of {type(model).__name__}.") from None
            if isinstance(node, Fixed):
                raise ValueError(
                    f"Bounds: {path!r} is fixed (fj.Fixed); a fixed parameter is not fitted, so not bounded."
                )
            value = np.asarray(unwrap(node), dtype=float)
            inside = Bounded.inside(value, low, high)
            if not np.array_equal(inside, value) and np.any((value <= low) | (value >= high)):
                warnings.warn(
                    f"Bounds: the start's {path} = {value.tolist()} is not inside ({low:g}, {high:g}); it starts at "
                    f"{inside.tolist()}.",
                    stacklevel=4,
                )
            else:
                inside = value
            model = eqx.tree_at(where, model, Bounded(inside, low, high, name=path, dtype=value.dtype))
        return dataclasses.replace(plan, model=model)


class Penalty(eqx.Module):
    """Regularisation of a fit's iterate `y` towards `nominal` (the start, in the optimiser's coordinates):
    `l2 sum d^2 + l1 sum |d|_s` added to the loss, `d = y - nominal` and `|d|_s = d^2 / sqrt(d^2 + 1e-12)` (|d|,
    smooth at 0); `rows(y)` are residual rows whose squares sum to it, for least-squares solvers (finite Jacobians
    at d = 0, where every fit starts)."""

    nominal: Any
    l2: float = eqx.field(static=True)
    l1: float = eqx.field(static=True)

    def _deviation(self, params: Any) -> jax.Array:
        flat, _ = jax.flatten_util.ravel_pytree(params)
        nominal, _ = jax.flatten_util.ravel_pytree(self.nominal)
        return flat - nominal

    def rows(self, params: Any) -> jax.Array:
        d = self._deviation(params)
        parts = []
        if self.l2 > 0:
            parts.append(jnp.sqrt(self.l2) * d)
        if self.l1 > 0:
            parts.append(jnp.sqrt(self.l1) * d * (d**2 + _L1_WIDTH**2) ** -0.25)
        return jnp.concatenate(parts) if parts else jnp.zeros((0,), d.dtype)

    @property
    def row_count(self) -> int:
        """How many rows `rows` appends: one per parameter for each active penalty."""
        size = sum(int(np.size(leaf)) for leaf in jax.tree_util.tree_leaves(self.nominal))
        return size * ((self.l2 > 0) + (self.l1 > 0))

    def value(self, params: Any) -> jax.Array:
        d = self._deviation(params)
        return self.l2 * jnp.sum(d**2) + self.l1 * jnp.sum(d**2 / jnp.sqrt(d**2 + _L1_WIDTH**2))


_L1_WIDTH = 1e-6  # where the L1 penalty's |d| is rounded (the optimiser's coordinates: a 1e-6 relative change)


@dataclasses.dataclass(frozen=True)
class Regularisation(AbstractStrategy):
    """L2 (ridge) and L1 penalties on the parameters' change from the start (`idnlgrey`'s `Regularization` with the
    nominal model): `l2 sum d^2 + l1 sum |d|` added to the loss, `d` the trained parameters minus the start's in the
    optimiser's coordinates (positive parameters are stored as logs, so there `d` is a relative change; real ones as
    they are: with `fj.ParameterScaling` first, relative too). For parameters the data hardly determine (a large
    Gauss-Newton standard deviation): the penalty holds them near the start instead of letting them wander.
    """

    l2: float = 0.0
    l1: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "l2", nonnegative_float(self.l2, "l2", "Regularisation"))
        object.__setattr__(self, "l1", nonnegative_float(self.l1, "l1", "Regularisation"))
        if self.l2 == 0 and self.l1 == 0:
            raise ValueError("Regularisation: give l2 > 0 and / or l1 > 0 (both are 0: no penalty).")

    def transform(self, plan: FitPlan) -> FitPlan:
        nominal = _divide(plan.params0, plan.scales)
        return dataclasses.replace(plan, penalty=Penalty(nominal, self.l2, self.l1))


def submodels(model: Any, prefix: str = "") -> list[tuple[str, eqx.Module]]:
    """Every equinox Module inside `model` (itself included) with the dotted prefix of its fields
    (`""`, `"model."`, `"members.0."`): the one walk behind the per-class parameter declarations
    (`parameter_ranges`, `nonnegative_fields`)."""
    out: list[tuple[str, eqx.Module]] = []
    if isinstance(model, eqx.Module):
        out.append((prefix, model))
        for field in dataclasses.fields(model):
            out += submodels(getattr(model, field.name, None), f"{prefix}{field.name}.")
    elif isinstance(model, (tuple, list)):
        for index, child in enumerate(model):
            out += submodels(child, f"{prefix}{index}.")
    return out


def physical_ranges(model: Any) -> dict[str, float]:
    """`{dotted path: magnitude}` over every model in `model` (ensemble members included) that declares
    `parameter_ranges()`; models whose parameters are traced (inside jit / vmap) give none."""
    out: dict[str, float] = {}
    for prefix, node in submodels(model):
        ranges = getattr(node, "parameter_ranges", None)
        if callable(ranges):
            try:
                out.update({prefix + name: float(value) for name, value in ranges().items()})
            except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError, TypeError):
                pass
    return out


def _where_zero(leaf: Any, value: float) -> Any:
    def replace(scale: Any) -> Any:
        return on_host(lambda xp, a, b: xp.where(a == 0, value, b), leaf, scale)

    return replace


def _constant(value: float) -> Any:
    def replace(array: Any) -> Any:
        return jnp.full_like(array, value)

    return replace


def where_from_path(path: str) -> Any:
    """A `where` callable for a dotted field path: names are attributes, integers index tuples and lists
    (`"mlp.layers.0.weight"`, or `"members[0].Fc"` as parameter tables print it), other keys index dicts."""

    # the keys of parameter tables ("members[0].k", "layers['w']") name the same nodes
    dotted = re.sub(r"\[(\d+)\]", r".\1", re.sub(r"\['([^']*)'\]", r".\1", path)).lstrip(".")

    def where(tree: Any) -> Any:
        for part in dotted.split("."):
            if isinstance(tree, (tuple, list)) and part.lstrip("-").isdigit():
                tree = tree[int(part)]
            elif isinstance(tree, dict):
                tree = tree[part]
            else:
                tree = getattr(tree, part)
        return tree

    return where
