"""User-argument checks, in one place: each names the function and the argument and says what to pass instead.

The checks run on Python values at the entry points (`fj.fit`, `fj.sweep`, the command line, constructors), once,
never inside a traced computation. Every function returns the value it accepted, converted (an `np.int64` becomes an
`int`), so a caller writes `steps = positive_int(steps, "steps", "fit")`.

Messages read `"{where}: `{name}` must be {requirement} {hint}, got {value!r}."`: `where` is the function (or class)
as the user calls it, `hint` optional words after the requirement, such as `"(samples)"`. The command line passes
`where=""` and the option as `name` (`"--steps"`): its own prefix names the command.
"""

from __future__ import annotations

import hashlib
import math
import numbers
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = [
    "finite_float",
    "fraction",
    "integer",
    "integers",
    "is_integer",
    "is_real",
    "nonnegative_float",
    "nonnegative_int",
    "optional",
    "positive_float",
    "positive_int",
    "same_sample_time",
    "seed_value",
]

SAMPLE_TIME_RTOL = 1e-6  # records fitted together share one sample time to this relative tolerance: a sample time
# stored in float32 anywhere on its way (a float32 time column of 1 ms) is 1e-7 off

_T = TypeVar("_T")


def got_model(value: Any) -> str:
    """What was passed where a model instance belongs, for an error message: a class is named with the fix (its
    type is equinox's metaclass, which says nothing)."""
    if isinstance(value, type):
        name = value.__name__
        return (
            f"the class {name}; pass an instance (fj.{name}(...)) or a start read off a record "
            f"(fj.initial_guess(fj.{name}, data))"
        )
    return type(value).__name__


def is_integer(value: Any) -> bool:
    """Whether `value` is an integer (`int`, `np.int64`, ...) and not a bool: for arguments that take an integer or
    something else (a sequence of them, a name)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_real(value: Any) -> bool:
    """Whether `value` is a real number (`int`, `float`, `np.float32`, ...) and not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _fail(value: Any, name: str, where: str, requirement: str, hint: str) -> ValueError:
    prefix = f"{where}: " if where else ""
    words = f"{requirement} {hint}" if hint else requirement
    return ValueError(f"{prefix}`{name}` must be {words}, got {value!r}.")


def _integer_requirement(minimum: int | None, maximum: int | None, hint: str) -> str:
    if minimum is not None and maximum is not None:
        return f"an integer in {minimum}..{maximum}"
    if minimum == 1:  # with a hint, the hint is the example
        return "a positive integer" if hint else "a positive integer (1, 2, ...)"
    if minimum is not None:
        return f"an integer >= {minimum}"
    if maximum is not None:
        return f"an integer <= {maximum}"
    return "an integer"


def integer(
    value: Any, name: str, where: str, *, minimum: int | None = None, maximum: int | None = None, hint: str = ""
) -> int:
    """`value` as an `int` in `minimum..maximum` (both included; either may be left out); bools, floats and strings
    are refused."""
    if not is_integer(value) or (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        raise _fail(value, name, where, _integer_requirement(minimum, maximum, hint), hint)
    return int(value)


def positive_int(value: Any, name: str, where: str, *, hint: str = "") -> int:
    """`value` as an `int` >= 1; bools, floats and strings are refused."""
    return integer(value, name, where, minimum=1, hint=hint)


def nonnegative_int(value: Any, name: str, where: str, *, hint: str = "") -> int:
    """`value` as an `int` >= 0; bools, floats and strings are refused."""
    return integer(value, name, where, minimum=0, hint=hint)


def integers(value: Any, name: str, where: str, *, minimum: int = 1, hint: str = "") -> tuple[int, ...]:
    """An integer >= `minimum` or a non-empty sequence of them (a grid of sizes), as a tuple of `int`s."""
    values = (value,) if is_integer(value) else value
    try:
        out = tuple(values)
    except TypeError:
        out = ()
    if not out or not all(is_integer(v) and v >= minimum for v in out):
        one = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        raise _fail(value, name, where, f"{one} or a non-empty sequence of them", hint)
    return tuple(int(v) for v in out)


def finite_float(value: Any, name: str, where: str, *, hint: str = "") -> float:
    """`value` as a finite `float`; bools, NaN and infinities are refused."""
    if not is_real(value) or not math.isfinite(float(value)):
        raise _fail(value, name, where, "a finite number", hint)
    return float(value)


def nonnegative_float(value: Any, name: str, where: str, *, hint: str = "") -> float:
    """`value` as a finite `float` >= 0 (a tolerance, a spread)."""
    value = finite_float(value, name, where, hint=hint)
    if value < 0:
        raise _fail(value, name, where, ">= 0", hint)
    return value


def positive_float(value: Any, name: str, where: str, *, hint: str = "") -> float:
    """`value` as a finite `float` > 0 (a learning rate, a width)."""
    value = finite_float(value, name, where, hint=hint)
    if not value > 0:
        raise _fail(value, name, where, "> 0", hint)
    return value


def fraction(value: Any, name: str, where: str, *, hint: str = "") -> float:
    """`value` as a `float` in [0, 1) (a probability, a discrete-time pole)."""
    if not is_real(value) or not 0 <= float(value) < 1:
        raise _fail(value, name, where, "a number in [0, 1)", hint)
    return float(value)


def optional(
    check: Callable[..., _T], value: Any, name: str, where: str, *, hint: str = "", **options: Any
) -> _T | None:
    """`None`, or `check(value, name, where, **options)`, whose message then says "or None" (before `hint`):
    `optional(positive_int, max_terms, "max_terms", "select_terms", hint="(no limit)")`."""
    return None if value is None else check(value, name, where, hint=f"or None {hint}".rstrip(), **options)


def seed_value(value: Any, name: str, where: str) -> int:
    """An integer seed of any size as a valid `jax.random.PRNGKey` seed in [0, 2**32).

    Seeds already in that range are used as they are (so results of earlier versions are reproduced); others
    (negative, or 2**32 and above) are reduced by a hash of their decimal digits, so that different seeds stay
    different with overwhelming probability.
    """
    if not is_integer(value):
        raise _fail(value, name, where, "an integer (any size)", "")
    value = int(value)
    if 0 <= value < 2**32:
        return value
    digest = hashlib.sha256(str(value).encode()).digest()
    return int.from_bytes(digest[:4], "little")


def same_sample_time(dt: float, reference: float) -> bool:
    """Whether two records' sample times [s] are one (`SAMPLE_TIME_RTOL`): the test of `fj.fit` and the command line."""
    return abs(dt - reference) <= SAMPLE_TIME_RTOL * abs(reference)
