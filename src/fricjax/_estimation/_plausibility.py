"""Honest words on a fitted physics model: parameters a model of its class should not have (`implausible`),
read by `Solution.summary()` and by `fricjax compare`'s table."""

from __future__ import annotations

from typing import Any

import numpy as np

from .._constraints import unwrap
from .._models.combine._normal_load import NormalLoad
from .._models.combine._sensor import SensorDrift
from .._models.physics._gms import GMS
from .._models.physics._lugre import LuGre
from .._models.physics._maxwell_slip import MaxwellSlip, SpringForces
from .._models.physics._static import AbstractStaticFriction
from .._models.physics._stribeck import ExponentialStribeck

# a fraction of the force or of the elements below which a part of the model does nothing
NEGLIGIBLE = 1e-3
FS_BELOW_FC = "Fs < Fc (a Stribeck curve falling towards standstill)"


def implausible(model: Any, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
    """What is implausible in a fitted physics model (empty when nothing is): a Stribeck curve whose static level is
    below its Coulomb level (`Fs < Fc`), a damping coefficient held at its bound 0, GMS elements carrying almost none
    of the force, Maxwell-slip elements that never slip on a record whose reversals span `record_excursion` [m]
    (half the largest displacement swing), or all of them. `bounds=False` leaves out the damping "held at its
    bound" notes (true of a fitted coefficient, not of one that was frozen or left at its default 0)."""
    friction = unwrap(model)
    while isinstance(friction, (SensorDrift, NormalLoad)):  # the friction model inside the sensor and the load
        friction = unwrap(friction.model)
    notes = []
    stribeck = getattr(friction, "stribeck", None)
    levels = stribeck if isinstance(stribeck, ExponentialStribeck) else friction
    Fc, Fs = getattr(levels, "Fc", None), getattr(levels, "Fs", None)
    if Fc is not None and Fs is not None and np.any(np.asarray(Fs) < np.asarray(Fc)):
        notes.append(FS_BELOW_FC)
    if isinstance(friction, (LuGre, GMS)):
        for name in ("sigma1", "sigma2") if isinstance(friction, LuGre) else ("sigma2",):
            if bounds and float(np.asarray(getattr(friction, name))) <= 0.0:
                notes.append(f"{name} = 0 (held at its bound)")
    static = isinstance(friction, AbstractStaticFriction)
    if bounds and static and float(np.min(np.asarray(getattr(friction, "Fv", 1.0)))) <= 0:
        notes.append("Fv = 0 (held at its bound)")
    if isinstance(friction, GMS):
        alpha = np.asarray(friction.alpha)
        idle = int(np.sum(alpha < NEGLIGIBLE))
        if idle:
            notes.append(f"{idle} of {alpha.size} GMS elements carry < {NEGLIGIBLE:g} of the force")
    if isinstance(friction, MaxwellSlip) and record_excursion is not None:
        stuck = int(np.sum(np.asarray(friction.thresholds) >= record_excursion))
        if stuck == friction.num_elements:
            notes.append("every Maxwell-slip element stays stuck on this record (a linear spring)")
        elif stuck:
            notes.append(f"{stuck} of {friction.num_elements} Maxwell-slip elements never slip on this record")
    if isinstance(friction, MaxwellSlip) and isinstance(friction.force_map, SpringForces):
        k = np.asarray(friction.force_map.k) * np.asarray(friction.thresholds)
        if k.sum() > 0 and np.sum(k < NEGLIGIBLE * k.sum()):
            notes.append(f"{int(np.sum(k < NEGLIGIBLE * k.sum()))} Maxwell-slip elements carry almost no force")
    return notes


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
