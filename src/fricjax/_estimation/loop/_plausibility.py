"""Honest words on a fitted physics model: parameters a model of its class should not have (`implausible`) and
parameters its records do not determine (`poorly_determined`), read by `Solution.summary()` and by `fricjax compare`'s
table."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._constraints import PARAMETER_UNITS, parameter_arrays, parameter_units, unwrap
from ..._models._base import FS_BELOW_FC, NEGLIGIBLE
from ..._smoothing import exact

__all__ = ["FS_BELOW_FC", "NEGLIGIBLE", "UNCERTAIN", "half_excursion", "implausible", "poorly_determined"]

UNCERTAIN = 0.2  # a Gauss-Newton standard deviation above this fraction of the value: not determined by the records
# what belongs to a record, not to the friction: offsets, initial states, drifts (`poorly_determined` leaves them out)
_NUISANCES = ("offset", "z0", "w0", "rate", "tau", "reference")


def implausible(model: Any, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
    """What is implausible in a fitted physics model (empty when nothing is), as its family says
    (`AbstractFrictionModel.implausible`, through sensor and load wrappers): a Stribeck curve whose static level is
    below its Coulomb level (`Fs < Fc`), a damping coefficient held at its bound 0, GMS elements carrying almost none
    of the force, Maxwell-slip elements that never slip on a record whose reversals span `record_excursion` [m]
    (half the largest displacement swing), or all of them. `bounds=False` leaves out the damping "held at its
    bound" notes (true of a fitted coefficient, not of one that was frozen or left at its default 0). A model that
    is not a friction model (a network, a system) has nothing to say: empty."""
    check = getattr(unwrap(model), "implausible", None)
    return [] if check is None else list(check(record_excursion, bounds=bounds))


def half_excursion(motion: Any) -> float | None:
    """Half the largest displacement swing between two reversals of a motion [m] (how far an element can be
    loaded); None without a displacement."""
    try:
        x = np.asarray(motion.samples(frozenset({"x"})).x, dtype=float)
    except (TypeError, ValueError, AttributeError):
        return None
    step = np.diff(x)
    moving = np.flatnonzero(step != 0)
    if moving.size < 2:
        return float(np.ptp(x)) / 2
    turns = moving[1:][np.sign(step[moving[1:]]) != np.sign(step[moving[:-1]])]
    ends = np.concatenate([[0], turns, [x.size - 1]])
    return float(np.max(np.abs(np.diff(x[ends])))) / 2


def poorly_determined(model: Any, std: Any, limit: float = UNCERTAIN) -> list[str]:
    """A note naming the physical parameters of `model` (the literature's symbols: `PARAMETER_UNITS`) whose
    Gauss-Newton standard deviation `std` (a pytree shaped like `fj.unwrap(model)`, as `Solution.std`) is above `limit`
    of their value: the records do not determine them, and other starts or records may give other values. Offsets,
    initial states and drifts (which belong to a record) are left out; an array by its worst entry. Empty when none
    is, or without `std`."""
    if std is None:
        return []
    physical = unwrap(exact(model))
    values, units = parameter_arrays(physical), parameter_units(physical)
    spreads = parameter_arrays(std)
    parts = []
    for path, value in values.items():
        name = path.split(".")[-1]
        if path not in spreads or not units.get(path) or name not in PARAMETER_UNITS or name in _NUISANCES:
            continue  # a regression's coefficients (no literature symbol) are not read one by one
        spread, value = np.abs(spreads[path]), np.abs(value)
        known = np.isfinite(spread) & (value > 0)  # a value at 0 is held at its bound (`implausible` says so)
        relative = spread[known] / value[known]
        if relative.size and float(np.max(relative)) > limit:
            parts.append(f"{path.removeprefix('model.')} ±{100 * float(np.max(relative)):.0f} %")
    if not parts:
        return []
    return [
        f"standard deviation above {100 * limit:.0f} % of the value ({', '.join(parts)}): not determined by the data"
    ]
