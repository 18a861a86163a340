"""Honest words on a fitted physics model: parameters a model of its class should not have (`implausible`),
read by `Solution.summary()` and by `fricjax compare`'s table."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._constraints import unwrap
from ..._models._base import FS_BELOW_FC, NEGLIGIBLE

__all__ = ["FS_BELOW_FC", "NEGLIGIBLE", "half_excursion", "implausible"]


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
