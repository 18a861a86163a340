"""User-argument checks, in one place: each names the function and the argument and says what to pass instead.

The checks run on Python values at the entry points (`fj.fit`, `fj.sweep`, the command line, constructors), once,
never inside a traced computation. Every function returns the value it accepted, converted (an `np.int64` becomes an
`int`), so a caller writes `steps = positive_int(steps, "steps", "fit")`.
"""

from __future__ import annotations

import hashlib
import math
import numbers
from typing import Any

__all__ = [
    "finite_float",
    "nonnegative_float",
    "nonnegative_int",
    "optional",
    "positive_float",
    "positive_int",
    "seed_value",
]


def _is_integer(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def positive_int(value: Any, name: str, where: str) -> int:
    """`value` as an `int` >= 1; bools, floats and strings are refused."""
    if not _is_integer(value) or value < 1:
        raise ValueError(f"{where}: `{name}` must be a positive integer (1, 2, ...), got {value!r}.")
    return int(value)


def nonnegative_int(value: Any, name: str, where: str) -> int:
    """`value` as an `int` >= 0; bools, floats and strings are refused."""
    if not _is_integer(value) or value < 0:
        raise ValueError(f"{where}: `{name}` must be an integer >= 0, got {value!r}.")
    return int(value)


def finite_float(value: Any, name: str, where: str) -> float:
    """`value` as a finite `float`; bools, NaN and infinities are refused."""
    if not _is_real(value) or not math.isfinite(float(value)):
        raise ValueError(f"{where}: `{name}` must be a finite number, got {value!r}.")
    return float(value)


def nonnegative_float(value: Any, name: str, where: str) -> float:
    """`value` as a finite `float` >= 0 (a tolerance, a spread)."""
    value = finite_float(value, name, where)
    if value < 0:
        raise ValueError(f"{where}: `{name}` must be >= 0, got {value!r}.")
    return value


def positive_float(value: Any, name: str, where: str) -> float:
    """`value` as a finite `float` > 0 (a learning rate, a width)."""
    value = finite_float(value, name, where)
    if not value > 0:
        raise ValueError(f"{where}: `{name}` must be > 0, got {value!r}.")
    return value


def optional(check: Any, value: Any, name: str, where: str) -> Any:
    """`None`, or `check(value, name, where)`."""
    return None if value is None else check(value, name, where)


def seed_value(value: Any, name: str, where: str) -> int:
    """An integer seed of any size as a valid `jax.random.PRNGKey` seed in [0, 2**32).

    Seeds already in that range are used as they are (so results of earlier versions are reproduced); others
    (negative, or 2**32 and above) are reduced by a hash of their decimal digits, so that different seeds stay
    different with overwhelming probability.
    """
    if not _is_integer(value):
        raise ValueError(f"{where}: `{name}` must be an integer (any size), got {value!r}.")
    value = int(value)
    if 0 <= value < 2**32:
        return value
    digest = hashlib.sha256(str(value).encode()).digest()
    return int.from_bytes(digest[:4], "little")
