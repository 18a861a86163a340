"""The friction of an EMPS record read off its constant-velocity plateaus, with no model: on a plateau the
acceleration is zero, so the mean drive force is the friction characteristic (plus the offset) at that velocity.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from .._data._emps import EMPSRecord
from .._data._preprocessing import _positive_int, _positive_scalar, butter_filtfilt, central_difference

# ---------------------------------------------------------------------------------------------------------------
# Friction read off the constant-velocity plateaus (no model)

EMPS_PLATEAU_VELOCITIES = (0.0825, 0.1247, -0.0825, -0.1247)
"""The constant velocities [m/s] of the EMPS reference trajectory (both benchmark files)."""


class EMPSPlateau(NamedTuple):
    """The drive force on one constant-velocity plateau of an EMPS record.

    `velocity` [m/s]; `force` the mean drive force `gtau * vir` [N] over the plateau's samples (with zero
    acceleration it balances the friction plus the offset at that velocity); `samples` how many; `force_per_part`
    the mean in each of `parts` equal stretches of the record (NaN where a stretch has none of its samples).
    """

    velocity: float
    force: float
    samples: int
    force_per_part: tuple[float, ...]


def emps_plateau_forces(
    record: EMPSRecord,
    velocities: Sequence[float] = EMPS_PLATEAU_VELOCITIES,
    *,
    tolerance: float = 3e-3,
    max_accel: float = 0.05,
    cutoff_hz: float = 20.0,
    parts: int = 4,
    where: ArrayLike | None = None,
) -> list[EMPSPlateau]:
    """The friction force at the trajectory's constant velocities, measured without a model.

    On a plateau of constant velocity the acceleration is zero, so the drive force balances the friction (and the
    offset): the mean of `record.force` over the plateau is the friction characteristic at that velocity, as a
    Stribeck-curve experiment measures it. The velocity and acceleration are central differences of the position
    low-passed at `cutoff_hz` (4th-order Butterworth, zero phase, `butter_filtfilt`); a sample belongs to the
    plateau of velocity `v` when its velocity is within `tolerance` [m/s] of `v` and its acceleration below
    `max_accel` [m/s^2] in magnitude (and `where` allows it). Comparing two records' plateaus tells whether they
    hold the same friction (on EMPS they do not: benchmarks/README.md, "EMPS: the two records' friction").

    **Arguments:** `record` an `EMPSRecord`; `velocities` [m/s] (default: the EMPS trajectory's four);
    `tolerance` [m/s] and `max_accel` [m/s^2] (> 0); `cutoff_hz` [Hz] (> 0, below the Nyquist frequency);
    `parts` (integer >= 1) stretches of the record for the drift over time; `where` an optional boolean mask of
    shape `(T,)`, the samples that may count (e.g. away from the PULSES file's pulses).

    **Returns:** one `EMPSPlateau` per velocity, in the given order.

    **Raises:** `TypeError` for a record that is not an `EMPSRecord`, a non-numeric setting or velocity, or a
    non-boolean `where`; `ValueError` for a
    non-positive setting, non-finite signals or velocities, a mask of the wrong shape, or a velocity with no
    sample on the record (name, and the fix: another velocity, a wider `tolerance` or a larger `max_accel`).

    ```python
    >>> import fricjax as fj
    >>> train = fj.load_emps(fj.data_folder("emps") / "DATA_EMPS.mat")  # doctest: +SKIP
    >>> [round(p.force, 2) for p in fj.emps.emps_plateau_forces(train)]  # doctest: +SKIP
    [34.31, 40.7, -40.26, -50.57]
    ```
    """
    if not isinstance(record, EMPSRecord):
        raise TypeError(f"`record` must be an EMPSRecord (from load_emps), got {type(record).__name__}.")
    parts = _positive_int(parts, "parts")
    tolerance = _positive_scalar(tolerance, "tolerance", "m/s")
    max_accel = _positive_scalar(max_accel, "max_accel", "m/s^2")
    cutoff_hz = _positive_scalar(cutoff_hz, "cutoff_hz", "Hz")
    try:
        levels = np.atleast_1d(np.asarray(velocities, dtype=np.float64))
    except (TypeError, ValueError):
        raise TypeError(f"`velocities` must be plateau velocities in m/s (numbers), got {velocities!r}.") from None
    if levels.ndim != 1 or levels.size == 0 or not np.all(np.isfinite(levels)):
        raise ValueError(f"`velocities` must be finite plateau velocities in m/s, got {velocities!r}.")
    for name in ("qm", "force"):
        if not np.all(np.isfinite(np.asarray(getattr(record, name)))):
            raise ValueError(f"emps_plateau_forces: `record.{name}` of {record.name} contains NaN or inf.")
    allowed = np.ones(record.length, dtype=bool)
    if where is not None:
        allowed = np.asarray(where)
        if allowed.dtype != bool:
            raise TypeError(f"`where` must be a boolean mask (e.g. `pulses == 0`), got dtype {allowed.dtype}.")
        if allowed.shape != (record.length,):
            raise ValueError(
                f"`where` must be a boolean mask of shape ({record.length},), one entry per sample of {record.name}; "
                f"got shape {allowed.shape}."
            )
    q = butter_filtfilt(record.qm, record.dt, cutoff_hz, 4)
    qd = central_difference(q, record.dt)
    qdd = central_difference(qd, record.dt)
    force = np.asarray(record.force, dtype=np.float64)
    in_part = [np.arange(record.length) * parts // record.length == k for k in range(parts)]
    out = []
    for level in (float(v) for v in levels):
        on = allowed & (np.abs(qd - level) < tolerance) & (np.abs(qdd) < max_accel)
        if not on.any():
            raise ValueError(
                f"emps_plateau_forces: no sample of {record.name} moves at {level} m/s (within {tolerance} m/s, "
                f"|acceleration| < {max_accel} m/s^2); give the record's plateau velocities, a wider `tolerance` "
                "or a larger `max_accel`."
            )
        per_part = tuple(float(force[sel].mean()) if sel.any() else np.nan for sel in (on & p for p in in_part))
        out.append(
            EMPSPlateau(velocity=level, force=float(force[on].mean()), samples=int(on.sum()), force_per_part=per_part)
        )
    return out
