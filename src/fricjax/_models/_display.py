"""How a model prints: `str(model)` / `repr(model)` list its physical parameter values with their units.

```
LuGre (smooth, eps 0.001)
  stribeck.Fc = 1 [N]
  ...
  sigma0 = 100000 [N/m]
```

The values are those of `fj.unwrap(fj.exact(model))` (constraint wrappers resolved; the smoothing is named on the
first line, not listed as a parameter); parameters held by `fj.Fixed` say so. A model whose leaves are not concrete
(inside `jax.jit`, `jax.vmap` or `jax.grad`, or shape-only leaves from `eqx.filter_eval_shape`) prints as equinox
prints it. `eqx.tree_pformat(model)` / `eqx.tree_pprint(model)` keep equinox's structural view: they format
dataclasses field by field and never call `__repr__`.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import numpy as np

from .._constraints import Bounded, Fixed, parameter_arrays, parameter_line, parameter_units, sided_paths, unwrap
from .._smoothing import AbstractSmoothing, Exact, Smooth, exact
from .._smoothing import is_concrete as _no_tracers

MAX_LINES = 20  # parameter arrays listed before "... and N more"


def model_text(model: Any, max_lines: int = MAX_LINES) -> str:
    """The parameter listing of `model`, or equinox's own formatting where the values are not concrete."""
    text = _listing(model, max_lines)
    return eqx.tree_pformat(model) if text is None else text


def _concrete(model: Any) -> bool:
    leaves = jax.tree_util.tree_leaves(model)
    return _no_tracers(model) and not any(isinstance(leaf, jax.ShapeDtypeStruct) for leaf in leaves)


def _listing(model: Any, max_lines: int) -> str | None:
    if not _concrete(model):
        return None
    try:
        # eagerly even when printed while a jit is being traced (an error message): unwrap's exp / softplus on
        # concrete values must give values, not tracers of the enclosing trace
        with jax.ensure_compile_time_eval():
            values = parameter_arrays(unwrap(exact(model)))
            units = parameter_units(unwrap(exact(model)))
            sided = sided_paths(unwrap(exact(model)))
            smoothing = _smoothing_text(model)
    except Exception:  # a repr never raises: a half-built model (an error in its __init__) prints as equinox's
        return None
    fixed, bounded = _fixed_paths(model), bounded_paths(model)
    lines = [type(model).__name__ + (f" ({smoothing})" if smoothing else "")]
    rows = list(values.items())
    for path, value in rows[:max_lines]:
        line = "  " + parameter_line(path, value, None, units[path], sided=path in sided)
        if any(path == f or path.startswith(f + ".") or path.startswith(f + "[") for f in fixed):
            line += " (fixed)"
        elif path in bounded:
            line += f" (bounded {bounded[path][0]:g} .. {bounded[path][1]:g})"
        lines.append(line)
    if len(rows) > max_lines:
        lines.append(f"  ... and {len(rows) - max_lines} more parameter arrays (fj.unwrap(model) holds them all)")
    if not rows:
        lines.append("  (no floating-point parameters)")
    return "\n".join(lines)


def _smoothing_text(model: Any) -> str:
    """`"exact"`, `"smooth, eps 0.001"` (every strategy smooth), `"smooth, eps 0.001; exact in part"`, or `""` for
    a model without a smoothing strategy."""
    strategies = [
        leaf
        for leaf in jax.tree_util.tree_leaves(model, is_leaf=lambda x: isinstance(x, AbstractSmoothing))
        if isinstance(leaf, AbstractSmoothing)
    ]
    if not strategies:
        return ""
    smooth = [s for s in strategies if isinstance(s, Smooth)]
    if not smooth:
        return "exact" if all(isinstance(s, Exact) for s in strategies) else ""
    widths = np.unique(np.concatenate([np.asarray(s.eps, dtype=float).reshape(-1) for s in smooth]))
    shown = ", ".join(f"{w:.3g}" for w in widths[:3]) + (", ..." if widths.size > 3 else "")
    text = f"smooth, eps {shown}"
    return text + ("; exact in part" if len(smooth) < len(strategies) else "")


def bounded_paths(model: Any) -> dict[str, tuple[float, float]]:
    """`{path: (low, high)}` of the `fj.Bounded` wrappers in `model` (paths as `parameter_arrays` writes them)."""
    found = jax.tree_util.tree_leaves_with_path(model, is_leaf=lambda x: isinstance(x, Bounded))
    return {
        jax.tree_util.keystr(path).lstrip("."): (leaf.low, leaf.high)
        for path, leaf in found
        if isinstance(leaf, Bounded)
    }


def _fixed_paths(model: Any) -> list[str]:
    """The paths (as `parameter_arrays` writes them) of the `fj.Fixed` wrappers in `model`."""
    found = jax.tree_util.tree_leaves_with_path(model, is_leaf=lambda x: isinstance(x, Fixed))
    return [jax.tree_util.keystr(path).lstrip(".") for path, leaf in found if isinstance(leaf, Fixed)]
