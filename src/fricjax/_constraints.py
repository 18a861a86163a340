"""Parameter reparametrisations: positive (log / softplus) and fixed parameters, and `unwrap`; the parameter table
(`parameter_arrays`) and the units of the literature symbols (`PARAMETER_UNITS`).

Constructors take physical values and store positive parameters through a wrapper whose leaf is the
unconstrained value, so an unconstrained optimiser can never make a stiffness or threshold negative.
Wrappers are resolved once by `unwrap` at the simulation / loss boundary (as in equinox / paramax).
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Generic, Literal, TypeAlias, TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._smoothing import is_concrete

ParamLike: TypeAlias = ArrayLike | Sequence[float] | Sequence[Sequence[float]]
"""What constructors accept for a parameter: a scalar, a NumPy / JAX array or a (nested) list of floats."""

_T = TypeVar("_T")


class AbstractUnwrappable(eqx.Module):
    """A leaf wrapper that `unwrap` replaces by the array it represents."""

    @abc.abstractmethod
    def unwrap(self) -> Array:
        """The represented (constrained) value."""


class Positive(AbstractUnwrappable):
    """A strictly positive parameter stored as an unconstrained leaf `raw`.

    `value = exp(raw)` (`transform="log"`, default) or `softplus(raw)` (`transform="softplus"`).

    **Arguments:**

    - `value`: the positive physical value (scalar or array); validated when concrete.
    - `name`: the argument's name, used in error messages.
    """

    raw: Array
    transform: Literal["log", "softplus"] = eqx.field(static=True)

    def __init__(
        self,
        value: ParamLike,
        *,
        transform: Literal["log", "softplus"] = "log",
        name: str = "value",
        dtype: Any = None,
    ):
        value = as_float_array(value, dtype)
        if is_concrete(value):
            if not bool(np.all(np.isfinite(np.asarray(value)))):
                raise ValueError(f"`{name}` must be finite, got {np.asarray(value)!r}.")
            if not bool(np.all(np.asarray(value) > 0)):
                raise ValueError(f"`{name}` must be positive, got {np.asarray(value)!r}; pass a value > 0.")
            check_normal(value, name)
        self.transform = transform
        if transform == "log":
            self.raw = jnp.log(value)
        elif transform == "softplus":
            # inverse softplus, stable for large values: x + log(-expm1(-x))
            self.raw = value + jnp.log(-jnp.expm1(-value))
        else:
            raise ValueError(f"`transform` must be 'log' or 'softplus', got {transform!r}.")

    def unwrap(self) -> Array:
        if self.transform == "log":
            return jnp.exp(self.raw)
        return jax.nn.softplus(self.raw)


class Bounded(AbstractUnwrappable):
    """A parameter held inside an interval: stored as an unconstrained leaf `raw`, `value = low + (high - low)
    sigmoid(raw)` (System Identification Toolbox's `Minimum` / `Maximum` of an `idnlgrey` parameter), so every solver
    steps freely and the value never leaves `(low, high)`. The bounds are settings, never trained.

    **Arguments:** `value` the physical value (scalar or array; strictly inside the interval); `low`, `high` the
    bounds (`low < high`, finite); `name` the parameter's name in error messages.
    """

    raw: Array
    low: float = eqx.field(static=True)
    high: float = eqx.field(static=True)

    def __init__(self, value: ParamLike, low: float, high: float, *, name: str = "value", dtype: Any = None):
        low, high = float(low), float(high)
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ValueError(f"`{name}`: bounds must be finite with low < high, got ({low!r}, {high!r}).")
        value = as_float_array(value, dtype)
        if is_concrete(value):
            inside = np.asarray(value)
            if not bool(np.all(np.isfinite(inside) & (inside > low) & (inside < high))):
                raise ValueError(
                    f"`{name}` = {inside.tolist()} is not strictly inside its bounds ({low:g}, {high:g}); start it "
                    "inside them, or widen them."
                )
        self.low, self.high = low, high
        fraction = (value - low) / (high - low)
        self.raw = jnp.log(fraction) - jnp.log1p(-fraction)

    def unwrap(self) -> Array:
        return self.low + (self.high - self.low) * jax.nn.sigmoid(self.raw)

    @staticmethod
    def inside(value: Any, low: float, high: float) -> np.ndarray:
        """`value` clipped to 1 % of the interval inside `(low, high)`: where a start outside its bounds begins."""
        margin = 0.01 * (high - low)
        return np.clip(np.asarray(value), low + margin, high - margin)


def check_normal(value: Any, name: str) -> None:
    """Refuse a positive value below the smallest normal float of its dtype (a subnormal such as 1e-320): a model
    divides by such parameters, and the quotient overflows to inf / NaN forces."""
    array = np.asarray(value)
    if np.issubdtype(array.dtype, np.floating):
        tiny = np.finfo(array.dtype).tiny
        if bool(np.any((array > 0) & (array < tiny))):
            raise ValueError(
                f"`{name}` = {array.tolist()} is too small to compute with (below {tiny:.3g}, the smallest normal "
                f"{array.dtype} number: forces divided by it overflow); check its unit, or pass a value >= {tiny:.3g}."
            )


class Fixed(AbstractUnwrappable, Generic[_T]):
    """A parameter excluded from training: its gradient is stopped at `unwrap`. As a type, `Fixed[Float[Array, " N"]]`
    is a field that holds a fixed array of that shape (the array itself once the model is unwrapped)."""

    value: _T  # what was wrapped: an array (a number or list as a user passed it), or a wrapper (`Fixed(Positive(v))`)

    def unwrap(self) -> Any:
        return jax.lax.stop_gradient(unwrap(self.value))


# Field types of model parameters, for annotations only: nothing checks them at run time. Dimension names as in
# STYLE.md (`N` elements). A constructor stores a parameter as a float array or inside a wrapper (`Positive`, `Fixed`,
# `Simplex`) that `unwrap` resolves at the simulation / loss boundary: in a model as built a field holds what its
# constructor stored, in an unwrapped model the array.
if TYPE_CHECKING:
    # The type checker reads these three as `Any`: whether such a field holds an array or a wrapper depends on the
    # constructor and on the caller's arguments (`fj.Fixed(1.0)`, `fj.Positive(...)`), and code reads them as arrays
    # from unwrapped models (`p = unwrap(model)`, `isinstance(p, GMS)`, `p.k * dx`), which a union would reject
    # at every read without a cast.
    Parameter: TypeAlias = Any
    ParameterVector: TypeAlias = Any
    SidedParameter: TypeAlias = Any
else:
    Parameter: TypeAlias = Float[Array, ""] | AbstractUnwrappable
    """One number: a 0-d float array, or a wrapper of one (`Positive`, `Fixed`)."""

    ParameterVector: TypeAlias = Float[Array, " N"] | AbstractUnwrappable
    """One number per element (stiffnesses, thresholds, fractions): a 1-d float array, or a wrapper of one
    (`Positive`, `Fixed`, `Simplex`)."""

    SidedParameter: TypeAlias = Float[Array, ""] | Float[Array, " 2"] | AbstractUnwrappable
    """A static law's coefficient: one number (symmetric law) or a pair (value for v > 0, value for v < 0), or a
    wrapper of either."""

FixedScalar: TypeAlias = Fixed[Float[Array, ""]]
"""One number held fixed, never trained (a normalisation, a kernel width, a forgetting factor)."""


def _is_wrapper(leaf: object) -> bool:
    return isinstance(leaf, AbstractUnwrappable)


def unwrap(tree: Any) -> Any:
    """Replace every `Positive` / `Fixed` / `Bounded` / `Simplex` wrapper inside `tree` by its constrained value."""
    return jax.tree_util.tree_map(lambda leaf: leaf.unwrap() if _is_wrapper(leaf) else leaf, tree, is_leaf=_is_wrapper)


def positive(value: ParamLike, name: str, dtype: Any = None, *, scalar: bool = False) -> Any:
    """Shorthand used by model constructors: `Positive(value, name=name)`; Python numbers take `dtype`.
    `scalar=True`: the parameter is one number (checked here, with its name, instead of a JAX shape error later).
    `Fixed(value)` gives a fixed positive parameter (not trained)."""
    if isinstance(value, Fixed):
        return Fixed(positive(value.value, name, dtype, scalar=scalar))
    _check_numeric(value, name)
    if scalar:
        _check_scalar(value, name)
    return Positive(value, name=name, dtype=dtype)


def real(value: ParamLike, name: str, dtype: Any = None, *, scalar: bool = False) -> Array:
    """Convert an unconstrained real parameter to a float array, checking it is finite when concrete (and one
    number with `scalar=True`). `Fixed(value)` gives a fixed real parameter (not trained)."""
    if isinstance(value, Fixed):
        return Fixed(real(value.value, name, dtype, scalar=scalar))  # type: ignore[return-value]
    _check_numeric(value, name)
    if scalar:
        _check_scalar(value, name)
    value = as_float_array(value, dtype)
    if is_concrete(value) and not bool(np.all(np.isfinite(np.asarray(value)))):
        raise ValueError(f"`{name}` must be finite, got {np.asarray(value)!r}.")
    return value


def _check_numeric(value: Any, name: str) -> None:
    """Strings (also inside lists) are refused by name: NumPy would read "1.0" as a dtype or a string array."""
    items = value if isinstance(value, (list, tuple)) else [value]
    if any(isinstance(item, (str, bytes)) for item in items):
        raise TypeError(f"`{name}` must be a number or an array of numbers, got {value!r}.")


def _check_scalar(value: Any, name: str) -> None:
    if isinstance(value, AbstractUnwrappable):
        value = jax.tree_util.tree_leaves(value)[0] if jax.tree_util.tree_leaves(value) else 0.0
    shape = np.shape(value)
    if shape != ():
        raise ValueError(f"`{name}` must be one number (a scalar), got shape {shape}; pass a float.")


def _is_weak(value: Any) -> bool:
    """Python numbers and (nested) lists of them carry no dtype of their own."""
    if isinstance(value, (list, tuple)):
        return all(_is_weak(item) for item in value)
    return isinstance(value, (int, float))


def model_dtype(*values: Any) -> Any:
    """The floating dtype a model takes from its arguments: that of its array arguments (NumPy / JAX, floating),
    else the default float. Python numbers (e.g. defaults such as `offset=0.0`) follow it."""
    strong = [jnp.result_type(v) for v in values if v is not None and not _is_weak(v) and hasattr(v, "dtype")]
    strong = [d for d in strong if jnp.issubdtype(d, jnp.floating)]
    return jnp.result_type(*strong) if strong else jnp.result_type(float)


def as_float_array(value: Any, dtype: Any = None) -> Array:
    """`value` (scalar, list, NumPy or JAX array) as a floating JAX array. A floating array keeps its dtype;
    Python numbers and lists take `dtype` (default: the default float)."""
    if _is_weak(value):
        return jnp.asarray(np.asarray(value, dtype=np.float64), dtype=dtype or jnp.result_type(float))
    if isinstance(value, (list, tuple)):
        value = np.asarray(value)
    own = jnp.result_type(value)
    if jnp.issubdtype(own, jnp.complexfloating):  # casting would drop the imaginary part
        raise TypeError(f"expected real numbers, got a complex array ({own}); pass its real part (np.real) if meant.")
    if not jnp.issubdtype(own, jnp.floating):
        own = dtype or jnp.result_type(float)
    return jnp.asarray(value, dtype=own)


class Simplex(AbstractUnwrappable):
    """Positive fractions that sum to one, stored as N - 1 unconstrained logits relative to the last fraction
    (`value = softmax([raw, 0])`): no redundant direction, so Gauss-Newton / Levenberg-Marquardt Jacobians
    stay full rank.

    Used for the GMS element fractions alpha_i (sum alpha_i = 1, so the elements share the Stribeck force).
    """

    raw: Array

    def __init__(self, value: ParamLike, *, name: str = "value", dtype: Any = None):
        value = as_float_array(value, dtype)
        if value.ndim != 1:
            raise ValueError(f"`{name}` must be a 1-D array of fractions, got shape {value.shape}.")
        if is_concrete(value):
            if not bool(np.all(np.isfinite(np.asarray(value)) & (np.asarray(value) > 0))):
                raise ValueError(f"`{name}` must hold positive fractions, got {np.asarray(value)!r}.")
            total = float(np.sum(np.asarray(value)))
            if abs(total - 1.0) > 1e-6:
                raise ValueError(f"`{name}` must sum to 1, got sum {total!r}; divide it by its sum.")
        self.raw = jnp.log(value[:-1]) - jnp.log(value[-1])

    def unwrap(self) -> Array:
        return jax.nn.softmax(jnp.concatenate([self.raw, jnp.zeros((1,), self.raw.dtype)]))


def trainable_filter(model: Any) -> Any:
    """A pytree of bools over `model`: True for the trainable leaves (floating arrays), False for leaves inside
    `Fixed` wrappers and smoothing strategies (`eps` is a setting, not a parameter). Use with `eqx.partition`.
    """
    from ._smoothing import AbstractSmoothing

    def mark(node: Any) -> Any:
        if isinstance(node, (Fixed, AbstractSmoothing)):
            return jax.tree_util.tree_map(lambda _: False, node)
        return eqx.is_inexact_array(node)

    return jax.tree_util.tree_map(mark, model, is_leaf=lambda n: isinstance(n, (Fixed, AbstractSmoothing)))


def parameter_arrays(tree: Any) -> dict[str, np.ndarray]:
    """The floating-point array leaves of `tree` as NumPy arrays keyed by their path (`"stribeck.Fc"`,
    `"members[0].k"`): the one parameter table behind `FitResult.parameters`, `fj.model_parameters` and the
    `compare` report. Pass `unwrap(model)` for physical values."""
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        if eqx.is_array(leaf) and jnp.issubdtype(leaf.dtype, jnp.floating):
            out[jax.tree_util.keystr(path).lstrip(".")] = np.asarray(leaf)
    return out


# Units of the literature symbols (DESIGN.md names), by the last component of a parameter's path.
PARAMETER_UNITS = {
    "Fc": "N",
    "Fs": "N",
    "vs": "m/s",
    "v0": "m/s",
    "delta": "-",
    "Fv": "N s/m",
    "sigma0": "N/m",
    "sigma1": "N s/m",
    "sigma2": "N s/m",
    "offset": "N",
    "z0": "m",
    "k": "N/m",
    "alpha": "-",
    "C": "N/s",
    "thresholds": "m",
    "rate": "N/s",
    "tau": "s",
    "Fc_pos": "N",
    "Fc_neg": "N",
    "Fs_pos": "N",
    "Fs_neg": "N",
    "Fv_pos": "N s/m",
    "Fv_neg": "N s/m",
    "mass": "kg",
    "M": "kg",
    "F0": "N",
    "gap": "m",
    "w0": "m",
    "mu": "-",
    "reference": "N",
}


def parameter_unit(path: str) -> str:
    """The unit of a literature symbol by the last name of its path (`"stribeck.Fc"` -> `"N"`), `""` where fricjax
    does not know it. For a model's parameters use `parameter_units`, which asks the module that owns each field
    (a network's bias `w0` has no unit; LuGre with backlash's `w0` is a length)."""
    return PARAMETER_UNITS.get(path.split(".")[-1], "")


def parameter_units(tree: Any) -> dict[str, str]:
    """The unit of every floating-point array of `tree` (pass `unwrap(exact(model))`, as to `parameter_arrays`),
    keyed by the same paths: the owning module's own table where its class declares one (`units`, a class
    attribute: `{}` for black-box networks, whose weights have no units; `{"m": "kg", ...}` for the oscillators),
    else the literature symbols (`PARAMETER_UNITS`) by the field's name; `""` where unknown."""
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        if not (eqx.is_array(leaf) and jnp.issubdtype(leaf.dtype, jnp.floating)):
            continue
        owner, name = tree, None
        node = tree
        for key in path:
            if isinstance(key, jax.tree_util.GetAttrKey):
                owner, name = node, key.name
                node = getattr(node, key.name)
            elif isinstance(key, (jax.tree_util.SequenceKey, jax.tree_util.DictKey)):
                node = node[key.idx if isinstance(key, jax.tree_util.SequenceKey) else key.key]
            else:  # a flattened index of another container: the field above it names the array
                break
        table = getattr(type(owner), "units", None)
        if table is None:  # the literature symbols, for fields a fricjax class declares (a user's `C` is not GMS's)
            table = PARAMETER_UNITS if name is not None and _declared_by_fricjax(type(owner), name) else {}
        out[jax.tree_util.keystr(path).lstrip(".")] = table.get(name, "") if name is not None else ""
    return out


def _declared_by_fricjax(cls: type, name: str) -> bool:
    """Whether the class that declares field `name` (the first in the MRO that annotates it) is fricjax's own."""
    for klass in cls.__mro__:
        if name in vars(klass).get("__annotations__", {}):
            return klass.__module__.split(".")[0] == "fricjax"
    return cls.__module__.split(".")[0] == "fricjax"


def sided_paths(tree: Any) -> set[str]:
    """The paths (as `parameter_arrays` keys them) of `tree`'s (+, -) pairs: fields declared `SidedParameter` that
    hold two values, the first for v > 0 and the second for v < 0 (decided by the declaration and the shape, never by
    the values). Pass `unwrap(model)`."""
    out: set[str] = set()

    def walk(node: Any, prefix: str) -> None:
        if isinstance(node, eqx.Module):
            for field in dataclasses.fields(node):
                value: Any = getattr(node, field.name, None)
                path = f"{prefix}{field.name}"
                if "SidedParameter" in str(field.type) and eqx.is_array(value) and np.shape(value) == (2,):
                    out.add(path)
                else:
                    walk(value, path + ".")
        elif isinstance(node, (list, tuple)):
            for i, item in enumerate(node):
                walk(item, f"{prefix.removesuffix('.')}[{i}].")

    walk(tree, "")
    return out


def compact_value(value: Any) -> str:
    """An array in a line of text: a number (`1.2e-07`), up to 6 entries (`[0.1 0.2]`), else its shape and range."""
    array = np.asarray(value, dtype=float)
    if array.size == 1:
        return f"{float(array.reshape(-1)[0]):.4g}"
    if array.size <= 6:
        return "[" + " ".join(f"{v:.3g}" for v in array.reshape(-1)) + "]"
    return f"shape {array.shape}, range [{array.min():.3g}, {array.max():.3g}]"


def parameter_line(path: str, value: Any, std: Any = None, unit: str = "", *, sided: bool = False) -> str:
    """One parameter array as a line of text: `"sigma0 = 100000 ± 312 [N/m]"` (the `±` part only where every
    entry of `std` is finite); an array of more than 8 entries by its shape and range; a (+, -) pair (`sided`,
    `sided_paths`) as `"Fc = 1.2 (v > 0), 1 (v < 0) [N]"`. `Solution.summary` and `str(model)` write their
    parameters so."""
    value = np.asarray(value)
    suffix = f" [{unit}]" if unit else ""
    if value.size > 8:
        return f"{path}: shape {value.shape}, range [{value.min():.4g}, {value.max():.4g}]" + suffix
    known = std is not None and bool(np.all(np.isfinite(std)))
    if sided and value.shape == (2,):
        plus_minus = [f" ± {float(s):.3g}" for s in np.asarray(std)] if known else ["", ""]
        return f"{path} = {value[0]:.6g}{plus_minus[0]} (v > 0), {value[1]:.6g}{plus_minus[1]} (v < 0){suffix}"
    text = np.array2string(value, formatter={"float_kind": lambda x: f"{x:.6g}"})
    if known:
        text += " ± " + np.array2string(np.asarray(std), formatter={"float_kind": lambda x: f"{x:.3g}"})
    return f"{path} = {text}{suffix}"
