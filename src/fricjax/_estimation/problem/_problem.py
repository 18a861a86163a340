"""The fit problem: which parameters a fit moves, the separable (linear) ones it solves by least squares, and the
`Problem` every solver steps on (objective, residuals, bounds, validation score); Gauss-Newton standard deviations.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ..._constraints import AbstractUnwrappable, Fixed, trainable_filter, unwrap
from ..._data._record import FrictionData
from ..._metrics import scaled_std
from ..._simulate import run, simulate
from ..._smoothing import on_host
from ..linear._covariance import parameter_std
from ..linear._lstsq import lstsq
from ..loop._solvers import dense_gauss_newton
from ..loop._strategies import submodels, where_from_path
from ._losses import AbstractLoss, SimulationLoss
from ._records import RecordsLoss

# ----------------------------------------------------------------------------------------------------------------
# parameter selection
# ----------------------------------------------------------------------------------------------------------------


Selector = str | Callable[[Any], Any] | Sequence[str]


def _where(selector: Any, model: Any, argument: str) -> list[tuple[str, Callable[[Any], Any]]]:
    """`(label, where)` pairs for a selector: a dotted path, a `where` callable, or a sequence of paths /
    callables. Each is checked against `model`: it must address nodes holding arrays."""
    out = []
    for item in selector_items(selector):
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
                + (
                    f". The wrapped model's field: {_wrapped_path(model, label)!r}."
                    if _wrapped_path(model, label)
                    else ". Use dotted names such as 'sigma1', 'stribeck.Fc' or 'layers.0.weight', or a callable."
                )
            ) from None
        if not jax.tree_util.tree_leaves(nodes):
            raise ValueError(f"fit: {label!r} in `{argument}` of {type(model).__name__} holds no array to select.")
        out.append((label, where))
    return out


def _wrapped_path(model: Any, label: str) -> str:
    """`label` inside the model a wrapper holds (`NormalLoad`, `SensorDrift`, `Backlash`: field `model`), where it
    names a field there (`"sigma0"` -> `"model.sigma0"`); "" otherwise."""
    path = label
    while hasattr(model, "model") and isinstance(model.model, eqx.Module):
        model, path = model.model, f"model.{path}"
        try:
            where_from_path(label)(model)
        except (AttributeError, IndexError, KeyError, TypeError):
            continue
        return path
    return ""


def selector_items(selector: Any) -> list[Any]:
    """A selector's items: one path or callable, a sequence of them, or none (`None`)."""
    if selector is None:
        return []
    return [selector] if isinstance(selector, str) or callable(selector) else list(selector)


def selector_paths(selector: Any) -> list[str]:
    """The dotted paths among a selector's items (callables are not compared)."""
    return [item for item in selector_items(selector) if isinstance(item, str)]


def _set_spec(spec: Any, model: Any, selector: Any, value: bool, argument: str) -> Any:
    for _, where in _where(selector, model, argument):
        spec = eqx.tree_at(where, spec, replace_fn=lambda sub: jax.tree_util.tree_map(lambda _: value, sub))
    return spec


def physical_spec(spec: Any) -> Any:
    """The trainable spec of a model mapped onto the leaves of `unwrap(model)`: a wrapper (a bounded or transformed
    parameter) becomes one leaf, trained if any of its raw leaves is; a `Fixed` one is not trained."""

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


def parameter_specs(model: Any, train: Any, freeze: Any, separable: Sequence[str], loss: Any, data: Any) -> Any:
    """Which leaves the optimiser moves (`spec`) and which are solved by least squares (`linear_spec`)."""
    spec = trainable_filter(model)
    if train is not None:
        both = lambda a, b: bool(a) and bool(b)  # noqa: E731
        selected = jax.tree_util.tree_map(lambda _: False, spec)
        for label, where in _where(train, model, "train"):
            item = _set_spec(jax.tree_util.tree_map(lambda _: False, spec), model, where, True, "train")
            if not any(jax.tree_util.tree_leaves(jax.tree_util.tree_map(both, spec, item))):
                raise ValueError(
                    f"fit: {label!r} in `train` selects only fields that are never trained: smoothing widths (a "
                    "setting: vary it with `continuation=fj.Continuation(eps_start, eps_end)`), `fj.Fixed` fields "
                    "or integer arrays."
                )
            selected = jax.tree_util.tree_map(lambda a, b: bool(a) or bool(b), selected, item)
        spec = jax.tree_util.tree_map(both, spec, selected)
    spec = _set_spec(spec, model, freeze, False, "freeze")
    linear_spec = None
    if separable:
        if not isinstance(loss, SimulationLoss):
            if isinstance(loss, RecordsLoss):  # a list of records: one offset per record is solved already
                raise ValueError(
                    "fit: `separable` solves parameters of one record's simulated force; a fit to several records "
                    "already solves each record's offset (fj.Nuisances(offset=True)) and cannot solve shared ones "
                    "linearly: drop `separable` (the parameters are then trained with the others)."
                )
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
        integers = [
            "model" + jax.tree_util.keystr(path)
            for path, leaf in jax.tree_util.tree_leaves_with_path(model)
            if eqx.is_array(leaf) and jnp.issubdtype(leaf.dtype, jnp.integer)
        ]
        raise ValueError(
            "fit: nothing to train: every parameter is frozen"
            + (
                f"; integer arrays are never trained ({', '.join(integers[:3])}): build them from floats (1.0, not 1)."
                if integers
                else " (`freeze`, `train`, fj.Fixed fields and smoothing widths are not trained)."
            )
        )
    return spec, linear_spec


def nonnegative_mask(model: Any) -> Any:
    """A tree shaped like `model`: True at the real-stored fields their class declares physically >= 0."""
    mask = jax.tree_util.tree_map(lambda _: False, model)
    for path in _nonnegative_paths(model):
        mask = eqx.tree_at(where_from_path(path), mask, True)
    return mask


def offset_paths(model: Any) -> list[str]:
    """Dotted paths of the models' own force-offset fields (`offset`, trainable arrays) in `model`."""
    out = []
    for prefix, node in submodels(model):
        value = getattr(node, "offset", None)
        if isinstance(value, Fixed) or "offset" not in {field.name for field in dataclasses.fields(node)}:
            continue
        if jax.tree_util.tree_leaves(eqx.filter(value, eqx.is_inexact_array)):
            out.append(prefix + "offset")
    return out


def initial_state_paths(model: Any) -> list[str]:
    """Dotted paths of the fields that only set a model's state at rest (`initial_state_fields`: LuGre `z0`)."""
    out = []
    for prefix, node in submodels(model):
        for name in sorted(getattr(type(node), "initial_state_fields", ())):
            value = getattr(node, name, None)
            if not isinstance(value, Fixed) and jax.tree_util.tree_leaves(eqx.filter(value, eqx.is_inexact_array)):
                out.append(prefix + name)
    return out


def held_paths(model: Any, nuisances: Any) -> list[str]:
    """The model's own fields that a fit to several records holds at their start, because each record gets its own
    (`nuisances`, an `fj.Nuisances`): the force offsets and the fields of the state at rest."""
    return [
        *(offset_paths(model) if nuisances.offset else []),
        *(initial_state_paths(model) if nuisances.initial_state else []),
    ]


def _nonnegative_paths(model: Any) -> list[str]:
    return [
        prefix + field.name
        for prefix, node in submodels(model)
        for field in dataclasses.fields(node)
        if field.name in getattr(type(node), "nonnegative_fields", ())
        and eqx.is_inexact_array(getattr(node, field.name, None))
    ]


def nonnegative_flags(model: Any, linear_spec: Any, separable: Sequence[str]) -> tuple[bool, ...] | None:
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


class Problem(eqx.Module):
    """What a solver steps on: everything an evaluation needs besides the iterate, as one pytree (jitted drivers
    take it as an argument, arrays traced and the rest static, so a second fit of the same shapes reuses the
    compilation).

    The iterate is `y = (params, extra)`: the trained parameters (divided by `scales` where given) and the loss's
    extra decision variables (multiple-shooting states); `args` is the rest of the model (`eqx.partition`'s static
    half: frozen arrays, smoothing widths, structure). `nonnegative` (a tree of Python bools, or None) marks the
    parameters `project` keeps >= 0. `penalty` (an `fj.Regularisation`'s `Penalty`, or None) is added to the
    objective; the residuals then end with its rows, scaled so that `loss_of_residuals` is the penalised loss.
    """

    loss: AbstractLoss
    linear_spec: Any
    linear_nonnegative: tuple[bool, ...] | None = eqx.field(static=True)
    nonnegative: Any  # a tree of Python bools shaped like the trained parameters (static under jit)
    scales: Any
    data: FrictionData
    validation: FrictionData | None
    val_loss: AbstractLoss
    penalty: Any = None  # a `Penalty` (fj.Regularisation): added to the objective, rows appended to the residuals

    def project(self, y: Any) -> Any:
        """The iterate with the physically non-negative parameters (damping coefficients) clipped at 0 (elementwise:
        batched iterates too)."""
        if self.nonnegative is None:
            return y
        params, extra = y
        clipped = jax.tree_util.tree_map(lambda p, m: jnp.maximum(p, 0.0) if m else p, params, self.nonnegative)
        return clipped, extra

    def materialise(self, params: Any, static: Any) -> Any:
        if self.scales is not None:
            params = jax.tree_util.tree_map(_times, params, self.scales)
        m = eqx.combine(params, static)
        if self.linear_spec is None:
            return m
        burn_in = getattr(self.loss, "burn_in", 0)
        return solve_linear(m, self.linear_spec, self.data, burn_in, nonnegative=self.linear_nonnegative)

    def objective(self, state: Any, static: Any) -> jax.Array:
        params, extra = state
        loss = self.loss(self.materialise(params, static), extra, self.data)
        return loss if self.penalty is None else loss + self.penalty.value(params)

    def residuals(self, state: Any, static: Any) -> jax.Array:
        params, extra = state
        r = self.loss.residuals(self.materialise(params, static), extra, self.data)
        if self.penalty is None:
            return r
        # mean(r^2) is the loss: the penalty's rows times sqrt(len(r)) add its value to sum(.^2) / len(r)
        return jnp.concatenate([r, jnp.sqrt(jnp.asarray(r.size, r.dtype)) * self.penalty.rows(params)])

    def gauss_newton(self, state: Any, static: Any) -> tuple[jax.Array, jax.Array]:
        """`([J r]^T [J r], r)`: the residuals at `state` and their Gauss-Newton products (J their Jacobian with
        respect to the flattened `state`, by forward mode). Where the loss declares which residuals each element of
        its `extra` moves (`AbstractLoss.jacobian_groups`: several records, each record's residuals moved by the
        shared parameters and its own nuisances; multiple shooting, a segment's start moving that segment and the two
        gaps beside it) the columns whose residuals do not overlap share one tangent (structurally orthogonal columns
        compressed: Curtis, Powell & Reid, "On the estimation of sparse Jacobian matrices", J. Inst. Math. Appl. 13,
        1974), so a fit to R records with k nuisances each propagates P + k tangents through the simulation instead
        of P + R k; the products are then summed group by group from the compressed columns (no N x P Jacobian)."""
        flat, unravel = jax.flatten_util.ravel_pytree(state)

        def residuals(q: jax.Array) -> jax.Array:
            return self.residuals(unravel(q), static)

        coupled = self.linear_spec is not None or self.penalty is not None  # every row moved by every variable
        groups = None if coupled else self.loss.jacobian_groups(state[1], self.data)
        if groups is None:  # a separable fit's linear solve couples every row with every variable
            return dense_gauss_newton(residuals, flat)
        shared = jax.tree_util.tree_map(lambda leaf: np.full(np.shape(leaf), -1), state[0])
        columns = np.concatenate(
            [np.ravel(g) for g in jax.tree_util.tree_leaves((shared, groups.columns))] or [np.zeros(0, int)]
        )
        if not groups.reach:
            raise ValueError(f"{type(self.loss).__name__}.jacobian_groups: `reach` is empty; give at least (0,).")
        colors = _colours(columns, max(groups.reach) - min(groups.reach))
        seeds = np.zeros((colors.max(initial=-1) + 1, columns.size), flat.dtype)
        seeds[colors, np.arange(columns.size)] = 1.0
        r, compressed = jax.vmap(lambda seed: jax.jvp(residuals, (flat,), (seed,)), out_axes=(None, -1))(seeds)
        return _grouped_products(compressed, r, columns, colors, groups, type(self.loss).__name__), r

    def loss_of_residuals(self, residuals: jax.Array) -> jax.Array:
        """`objective` from the residual vector: every fricjax loss is the mean square of its residuals (with a
        penalty: their sum of squares over the loss's own count, the penalty's rows after them)."""
        if self.penalty is None:
            return jnp.mean(residuals**2)
        count = residuals.size - self.penalty.row_count
        return jnp.sum(residuals**2) / count

    def val_objective(self, state: Any, static: Any) -> jax.Array:
        if self.validation is None:
            return jnp.asarray(jnp.nan)
        return self.val_loss(self.materialise(state[0], static), None, self.validation)


def _grouped_products(
    compressed: jax.Array, r: jax.Array, columns: np.ndarray, colors: np.ndarray, groups: Any, owner: str
) -> jax.Array:
    """`[J r]^T [J r]` from the compressed Jacobian (`compressed[:, colors[p]]` is column p of J on the rows it
    moves): the products of the compressed columns summed over every block of rows of one group (`groups.rows(n)`:
    runs of equal blocks), then each entry (p, q) of the result the sum over the row groups both p and q move (all
    rows for the parameters and the residual)."""
    n = r.shape[0]
    runs = [tuple(int(v) for v in run) for run in groups.rows(n)]
    covers = bool(runs) and [run[0] for run in runs] == [0] + [run[1] for run in runs[:-1]] and runs[-1][1] == n
    if not covers or any(stop > start and (block < 1 or (stop - start) % block) for start, stop, block, _ in runs):
        raise ValueError(
            f"{owner}.jacobian_groups: `rows({n})` must give runs (start, stop, block, first) covering the {n} "
            f"residuals in order, each a whole number of blocks; got {runs}."
        )
    a = jnp.concatenate([compressed, r[:, None]], axis=1)  # (n, C + 1): the last column is the residual
    blocks, labels = [], []
    for start, stop, block, first in runs:
        if stop > start:
            part = a[start:stop].reshape((stop - start) // block, block, a.shape[1])
            blocks.append(jnp.einsum("gbi,gbj->gij", part, part, precision=jax.lax.Precision.HIGHEST))
            labels.append(first + np.arange((stop - start) // block))
    per_block = jnp.concatenate(blocks)
    block_group = np.concatenate(labels)
    ids = np.unique(block_group[block_group >= 0])  # the row groups some column of `extra` moves
    owned = block_group >= 0
    per_group = jax.ops.segment_sum(per_block[owned], np.searchsorted(ids, block_group[owned]), len(ids))
    zero = jnp.zeros((1,) + per_block.shape[1:], per_block.dtype)
    table = jnp.concatenate([jnp.sum(per_block, axis=0)[None], per_group, zero])  # all rows, each group, nothing
    # which table rows make entry (p, q): all rows when both move every row, else the groups both move (those of a
    # grouped one, `g + reach`, that the other moves too)
    group = np.append(columns, -1)
    colour = np.append(colors, a.shape[1] - 1)
    reach = np.asarray(groups.reach)
    gp, gq = group[:, None, None], group[None, :, None]
    candidate = np.where(gp >= 0, gp, gq) + reach  # (P + 1, P + 1, k)
    other = np.where(gp >= 0, gq, -1)
    moved_by_other = (other < 0) | np.isin(candidate - other, reach)
    index = np.searchsorted(ids, candidate)
    present = (index < len(ids)) & (ids[np.minimum(index, max(len(ids) - 1, 0))] == candidate) if len(ids) else False
    where = np.where(moved_by_other & present, 1 + index, len(ids) + 1)
    everywhere = (gp < 0)[..., 0] & (gq < 0)[..., 0]  # both move every row: the sum over all rows, once
    where[everywhere] = len(ids) + 1
    where[everywhere, 0] = 0
    return jnp.sum(table[where, colour[:, None, None], colour[None, :, None]], axis=-1)


def _colours(columns: np.ndarray, span: int = 0) -> np.ndarray:
    """One tangent (colour) per column of a grouped Jacobian (`columns`: each column's group, -1 for the columns
    every row depends on): those get a colour each; the k-th column of group g shares its colour with the k-th
    column of the groups g + j (span + 1), j = +-1, +-2, ..., whose rows do not overlap (a column of group g
    reaches the rows of groups g + r, r in an interval of width `span`)."""
    colors = np.empty(columns.size, int)
    shared = columns < 0
    base = int(shared.sum())
    colors[shared] = np.arange(base)
    grouped = np.unique(columns[~shared])
    largest = max((int(np.sum(columns == g)) for g in grouped), default=0)
    for group in grouped:
        where = np.flatnonzero(columns == group)
        colors[where] = base + (int(group) % (span + 1)) * largest + np.arange(where.size)
    return np.unique(colors, return_inverse=True)[1].reshape(colors.shape)  # no colour left without a column


def _times(u: Any, c: Any) -> Any:
    """`u * c` (in NumPy for concrete values: `on_host`)."""
    return on_host(lambda xp, a, b: a * b, u, c)


@eqx.filter_jit
def evaluate(loss: AbstractLoss, model: Any, extra: Any, data: FrictionData) -> jax.Array:
    return loss(model, extra, data)


def gauss_newton_std(
    model: Any, spec: Any, linear_spec: Any, loss: AbstractLoss, extra: Any, data: FrictionData
) -> Any:
    """Standard deviations of the trained physical parameters: sqrt(diag(s^2 (J^T J)^+)), s^2 = |r|^2 / (N - p),
    with r the unnormalised residuals and J their Jacobian w.r.t. the physical (unwrapped) parameters."""
    if linear_spec is not None:
        spec = jax.tree_util.tree_map(lambda a, b: bool(a) or bool(b), spec, linear_spec)
    physical = unwrap(model)
    phys_spec = physical_spec(spec)
    params, rest = eqx.partition(physical, phys_spec)
    if not jax.tree_util.tree_leaves(params):
        return None
    if any(leaf.dtype == jnp.float32 for leaf in jax.tree_util.tree_leaves(params) if eqx.is_inexact_array(leaf)):
        size = sum(int(np.size(leaf)) for leaf in jax.tree_util.tree_leaves(params))
        warnings.warn(
            "fit: compute_std in float32: the Jacobian's directions weaker than "
            f"{_std_rcond(size, np.float32):.1g} of its strongest are dropped (a pseudo-inverse), so "
            "poorly determined parameters get standard deviations that are too small (measured: up to 14x on a GMS "
            "of 3 elements); enable float64 first (jax.config.update('jax_enable_x64', True)) for reliable ones.",
            UserWarning,
            stacklevel=3,
        )
    return _std_from_jacobian(params, rest, loss, extra, data)


def _std_rcond(size: int, dtype: Any) -> float:
    """The relative singular-value cut-off of the standard deviations of `size` parameters: that of the former
    pinv of the Gram matrix (the figures in the docs were computed with it)."""
    return float(np.sqrt(10 * size * np.finfo(dtype).eps))


@eqx.filter_jit
def _std_from_jacobian(params: Any, rest: Any, loss: AbstractLoss, extra: Any, data: FrictionData) -> Any:
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    scale = scaled_std(data.force) if getattr(loss, "normalise", False) else 1.0

    def residuals(theta: jax.Array) -> jax.Array:
        return loss.residuals(eqx.combine(unravel(theta), rest), extra, data) * scale

    r = residuals(flat)
    J = jax.jacfwd(residuals)(flat) if flat.size <= 64 else jax.jacrev(residuals)(flat)
    std_flat = parameter_std(J, r, max(int(r.size) - int(flat.size), 1), rcond=_std_rcond(flat.size, J.dtype))
    nan_rest = jax.tree_util.tree_map(lambda a: jnp.full_like(a, jnp.nan) if eqx.is_inexact_array(a) else a, rest)
    return eqx.combine(unravel(std_flat), nan_rest)
