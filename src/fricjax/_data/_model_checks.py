"""Checks of a model loaded from a file (`fj.load_model`): the invariants its class's constructor would enforce.

Loading rebuilds a model without calling any constructor (nothing from the file is executed), so nothing checked
the values in the file: a damaged file could hold a stiffness of shape (2, 2), a NaN, a negative damping or a
positivity transform named "mog". `check_loaded` checks, for every fricjax Module in the loaded tree:

- every field against the class's own annotation: jaxtyping shapes (named dimensions consistent across the fields
  of one Module, as `jaxtyping.jaxtyped` checks them) and dtypes, `Literal` choices (the `Positive` transform),
  Python types, tuples; a parameter wrapper (`Positive`, `Fixed`, `Simplex`) stands for the array it unwraps to;
- finite values in every floating array of a model, a wrapper or a smoothing strategy, positive unwrapped values
  of `Positive` and `Simplex`, non-negative values of the fields a model lists in `nonnegative_fields`;
- the class's `__check_init__`, where fricjax defines one (fricjax's code, run on the loaded values).

The classes a caller passes to `load_model(classes=...)` are not checked (their annotations and `__check_init__`
are the caller's code); the fricjax Modules inside them are.
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import types
import typing
import warnings
from typing import Any

import equinox as eqx
import jax
import jaxtyping
import numpy as np

from .._constraints import AbstractUnwrappable, Fixed, Positive, Simplex, unwrap

# fricjax modules whose floating arrays are parameters (constructors refuse non-finite values there)
_PARAMETER_MODULES = ("fricjax._models", "fricjax._systems", "fricjax._constraints", "fricjax._smoothing")


def check_loaded(tree: Any, path: pathlib.Path) -> None:
    """Raise `ValueError` naming `path` and the offending field when `tree` (a loaded model file) breaks an
    invariant of its classes; see the module docstring."""
    problem = _first_problem(tree, "model")
    if problem:
        name, where, what = problem
        raise ValueError(
            f"load_model: {path} holds an invalid {name} at `{where}`: {what}; the file is damaged or was edited (a "
            "model built by its constructor cannot hold this), or was saved from a model that held it (save_model "
            "warned)."
        )


def warn_unloadable(tree: Any) -> None:
    """Warn, as `save_model` writes it, that `load_model` will refuse `tree` (a parameter made non-finite by a
    diverged update or an edit with `eqx.tree_at`, say): the file is written all the same, nothing is lost."""
    problem = _first_problem(tree, "model")
    if problem:
        name, where, what = problem
        warnings.warn(
            f"save_model: `model` holds an invalid {name} at `{where}`: {what}, so load_model will refuse the file; "
            "save a model with valid parameters (after a fit that diverged: the Solution's model is the best one "
            "seen).",
            UserWarning,
            stacklevel=3,
        )


def _first_problem(node: Any, where: str) -> tuple[str, str, str] | None:
    """The innermost invalid fricjax Module of `node`: its class name, its place and what is wrong, or None."""
    children: list[tuple[Any, str]] = []
    if isinstance(node, (tuple, list)):
        children = [(item, f"{where}[{i}]") for i, item in enumerate(node)]
    elif isinstance(node, dict):
        children = [(value, f"{where}[{key!r}]") for key, value in node.items()]
    elif isinstance(node, eqx.Module):
        children = [(getattr(node, f.name), f"{where}.{f.name}") for f in dataclasses.fields(node)]
    for child, place in children:  # the innermost problem is named first
        problem = _first_problem(child, place)
        if problem:
            return problem
    if isinstance(node, eqx.Module) and type(node).__module__.startswith("fricjax."):
        what = _problem(node)
        if what:
            return type(node).__name__, where, what
    return None


def _problem(module: eqx.Module) -> str | None:
    """What is wrong with one loaded fricjax Module (its children are checked already), or None."""
    cls = type(module)
    hints = _hints(cls)
    # fields with symbolic dimensions ("M+J+2") last, once the names they refer to are bound
    names = sorted((f.name for f in dataclasses.fields(module)), key=lambda n: _symbolic(hints.get(n)))
    with jaxtyping.jaxtyped("context"):  # named dimensions agree across the fields of one Module
        for name in names:
            value = getattr(module, name)
            if name in hints and not _fits(value, hints[name]):
                return f"`{name}` is {_describe(value)}, where {cls.__name__} holds {_hint_name(hints[name])}"
    if cls.__module__.startswith(_PARAMETER_MODULES):
        for f in dataclasses.fields(module):
            value = getattr(module, f.name)
            if _is_float_array(value) and not bool(np.all(np.isfinite(np.asarray(value)))):
                return f"`{f.name}` holds a non-finite value ({_summary(value)})"
    if isinstance(module, (Positive, Simplex)):
        value = np.asarray(module.unwrap())
        if not bool(np.all(np.isfinite(value) & (value > 0))):
            return f"its value must be finite and positive, got {_summary(value)} (`raw` {_summary(module.raw)})"
        if bool(np.any(value < np.finfo(value.dtype).tiny)):
            tiny = np.finfo(value.dtype).tiny
            return f"its value {_summary(value)} is below the smallest normal number, {tiny:.3g} (a subnormal)"
    for name in sorted(getattr(cls, "nonnegative_fields", ())):
        if not hasattr(module, name):  # declared by a base class for fields only some subclasses have
            continue
        value = np.asarray(unwrap(getattr(module, name)))
        if bool(np.any(value < 0)):
            return f"`{name}` must be >= 0, got {_summary(value)}"
    for klass in cls.__mro__:
        check = vars(klass).get("__check_init__")
        if check is not None and klass.__module__.startswith("fricjax."):
            try:
                check(module)
            except (ValueError, TypeError) as err:
                return str(err)
    return None


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except Exception:  # an annotation that cannot be resolved is not checked
        return {}


def _symbolic(hint: Any) -> bool:
    return any(
        any(not str(d).isidentifier() for d in getattr(t, "dim_str", "").split())
        for t in _alternatives(hint)
        if _is_array_hint(t)
    )


def _alternatives(hint: Any) -> tuple[Any, ...]:
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return typing.get_args(hint)
    if typing.get_origin(hint) is Fixed:
        return _alternatives(typing.get_args(hint)[0])
    return (hint,)


def _is_array_hint(hint: Any) -> bool:
    return isinstance(hint, type) and issubclass(hint, jaxtyping.AbstractArray)


def _is_float_array(value: Any) -> bool:
    return eqx.is_array(value) and np.issubdtype(np.asarray(value).dtype, np.inexact)


def _fits(value: Any, hint: Any) -> bool:
    """Whether `value` fits the annotation `hint`; True where the annotation says nothing checkable."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any or isinstance(hint, typing.TypeVar):
        return True
    if origin in (typing.Union, types.UnionType):
        if isinstance(value, AbstractUnwrappable) and any(_is_array_hint(a) for a in args):
            # a wrapper stands for the array it unwraps to
            arrays = [a for a in args if _is_array_hint(a)]
            return any(_fits_array(unwrap(value), a) for a in arrays)
        return any(_fits(value, a) for a in args)
    if origin is typing.Literal:
        return any(type(value) is type(a) and value == a for a in args)
    if origin is Fixed:
        if not isinstance(value, Fixed):
            return False
        inner = unwrap(value.value) if isinstance(value.value, AbstractUnwrappable) else value.value
        return _fits(inner, args[0]) if args else True
    if origin is eqx.AbstractVar:
        return _fits(value, args[0])
    if origin is tuple:
        if not isinstance(value, tuple):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_fits(item, args[0]) for item in value)
        return len(args) == len(value) and all(_fits(v, a) for v, a in zip(value, args, strict=True))
    if origin is not None or not isinstance(hint, type):
        return True  # dict[...], Callable[...], type[...]: not checked
    if _is_array_hint(hint):
        return _fits_array(value, hint)
    if hint in (jax.Array, np.ndarray):
        return eqx.is_array(value)
    if hint is float:
        return type(value) in (int, float)
    if hint in (int, bool, str):
        return type(value) is hint or (hint is int and type(value) is bool)
    return isinstance(value, hint)


def _fits_array(value: Any, hint: Any) -> bool:
    if not eqx.is_array(value):
        return False
    try:
        return isinstance(value, hint)
    except jaxtyping.AnnotationError:  # a symbolic dimension whose names are not bound: not checked
        return True


def _describe(value: Any) -> str:
    if isinstance(value, AbstractUnwrappable):
        value = unwrap(value)
    if eqx.is_array(value):
        return f"an array of shape {tuple(np.shape(value))} and dtype {np.asarray(value).dtype}"
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 60 else text[:57] + '...'}"


def _hint_name(hint: Any) -> str:
    """The annotation in words: "a float array of shape (N) or a wrapper of one", "one of 'log', 'softplus'"."""
    names = []
    for alternative in _alternatives(hint):
        if _is_array_hint(alternative):
            kind = getattr(alternative.dtype, "__name__", "").lower() or "an"
            names.append(f"a {kind} array of shape ({alternative.dim_str})")
        elif alternative is AbstractUnwrappable:
            names.append("a wrapper (Positive, Fixed, Simplex) of one")
        elif typing.get_origin(alternative) is typing.Literal:
            names.append("one of " + ", ".join(repr(a) for a in typing.get_args(alternative)))
        else:
            names.append(getattr(alternative, "__name__", repr(alternative)))
    text = " or ".join(names)
    return text if len(text) <= 120 else text[:117] + "..."


def _summary(value: Any) -> str:
    array = np.asarray(value)
    if array.size <= 4:
        return repr(array.tolist())
    bad = array[~np.isfinite(array)] if np.issubdtype(array.dtype, np.inexact) else array
    return f"shape {array.shape}, e.g. {(bad if bad.size else array).flat[0].item()!r}"
