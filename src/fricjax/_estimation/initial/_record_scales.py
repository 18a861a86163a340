"""Scales of a friction record read before any fit (`RecordScales`): the sliding line (offset, Coulomb level,
viscous slope), the static level, the pre-sliding stiffness and breakaway displacement, the slip distance, and the
linkage gap of a record with backlash.

The readings follow the phenomena the papers describe (worden2007 §2, parlitz2004 §II): in gross sliding the force
is `offset + Fc sign(v) + Fv v` (plus the Stribeck rise at low speed), fitted by least squares on the fastest
samples; the static level `Fs` is the top of |F - offset|; right after a reversal the force changes with the
displacement at the pre-sliding stiffness (the slope |dF/dx| over a few samples), and the breakaway displacement is
`Fs / stiffness`.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._data._record import FrictionData
from ..problem._records import RecordBatch


@dataclasses.dataclass(frozen=True)
class RecordScales:
    """Scales of a friction record, read before any fit.

    `force` [N]: half the 1-99 % range of the force about its median; `Fc` [N], `Fv` [N·s/m], `offset` [N]: the
    least-squares fit of `offset + Fc sign(v) + Fv v` to the fastest 30 % of the samples (`Fv >= 0`), or to the
    faster half of the sliding samples (`SLIDING_TRAVEL` breakaway displacements past a reversal; at least
    `MIN_SLIDING_SAMPLES`) where the fastest ones give below half their `Fc` (a record that passes pre-sliding
    quickly: on the mixed tribometer records of a GMS with `Fc` 1 N, `Fv` 10 N s/m, the fastest read `Fc`
    0.15-0.44 N and `Fv` 450-925 N s/m, the sliding ones 1.14-1.19 N, the Stribeck level at their speed, and 0);
    where fewer slide, the level |F - offset| held at the reversals (90 % level; the force never reaches `Fc`
    there) where the line's `Fc` is below half of it; `Fs` [N]: the
    99.5 % level of |F - offset| (at least 1.05 Fc); `vs` [m/s]: the 30 % level of |v|; `stiffness` [N/m]: the 90 %
    level of |dF/dx| over 3-sample windows that move (pre-sliding after reversals); `breakaway` [m] = Fs /
    stiffness; `dx` [m]: the median step; `duration` [s]; `v_fast` [m/s]: the 90 % level of |v|; `slip` [m]: half
    the median distance from a reversal to 90 % of the sliding swing `2 Fc` (where the last elements of a
    multi-element model slip; the breakaway displacement when no reversal gets there).
    """

    force: float
    Fc: float
    Fs: float
    vs: float
    stiffness: float
    breakaway: float
    dx: float
    duration: float = 1.0
    v_fast: float = 1e-3
    Fv: float = 0.0
    offset: float = 0.0
    slip: float = 0.0

    @classmethod
    def from_data(cls, data: FrictionData | Sequence[FrictionData]) -> RecordScales:
        """The scales of `data` (a `fj.FrictionData`, or several records of one device as a list: the readings pooled
        over the records, each read on its own, so that neither their order nor the seams between them count; each
        record its own force offset in the sliding line (a record with none of the pooled samples the line is
        fitted through: the mean residual of its own fastest 30 % from the pooled line), `offset` their mean weighted
        by length)."""
        records = as_records(data, "RecordScales.from_data")
        signals = [host_signals(r) for r in records]
        x_of, v_of, force_of = ([item[i] for item in signals] for i in range(3))
        v, force = np.concatenate(v_of), np.concatenate(force_of)
        centred = np.concatenate([f - np.median(f) for f in force_of])
        scale = 0.5 * float(np.percentile(centred, 99) - np.percentile(centred, 1))
        fast = np.abs(v) > np.percentile(np.abs(v), 70)
        sliding = _sliding_samples(x_of, force_of, centred)
        group = record_of_each_sample([len(f) for f in force_of])
        offsets = np.array([float(np.median(f)) for f in force_of]) if len(records) > 1 else np.zeros(1)
        if fast.sum() >= 3:
            Fc, Fv, offsets = _sliding_line(force[fast], v[fast], group[fast], offsets, v_of, force_of)
            count = 0 if sliding is None else int(sliding.sum())
            if sliding is not None and count >= MIN_SLIDING_SAMPLES:  # the fastest samples may not slide
                sliding &= np.abs(v) >= np.median(np.abs(v[sliding]))  # their faster half
                line = _sliding_line(force[sliding], v[sliding], group[sliding], offsets, v_of, force_of)
                if Fc < 0.5 * line[0]:
                    Fc, Fv, offsets = line
            else:  # (almost) no sample slides: the level the reversals hold, where the line's Fc is below half
                held = _held_at_reversals(x_of, force_of, offsets)  # of it, as above
                if Fc < 0.5 * held:
                    Fc, Fv = held, 0.0
        else:
            Fc, Fv = scale, 0.0
        if not Fc > 0:
            Fc = float(np.median(np.abs(centred[fast]))) if fast.any() else scale
        offset = mean_offset(offsets, [len(f) for f in force_of])
        Fs = max(float(np.percentile(np.abs(force - offsets[group]), 99.5)), 1.05 * Fc)
        vs = float(np.percentile(np.abs(v), 30)) or 1e-3
        stiffness = _presliding_stiffness(x_of, force_of, Fs)
        if stiffness is None:  # no reversal spans the pre-sliding range: the steepest 3-sample slopes
            dxw = np.concatenate([x[3:] - x[:-3] for x in x_of])
            dfw = np.concatenate([f[3:] - f[:-3] for f in force_of])
            moving = np.abs(dxw) > np.percentile(np.abs(dxw), 20) + 1e-15 if dxw.size else dxw > 0
            slopes = np.abs(dfw[moving] / dxw[moving])
            stiffness = float(np.percentile(slopes, 90)) if slopes.size else scale / 1e-5
        if not stiffness > 0:  # a record without force or motion: a unit stiffness keeps the scales finite
            stiffness = 1.0
        steps = np.abs(np.concatenate([np.diff(x) for x in x_of]))
        dx = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1e-9
        duration = sum(r.length * float(np.asarray(r.motion.dt)) for r in records)
        v_fast = float(np.percentile(np.abs(v), 90)) or 1e-3
        slip = _slip_distance(x_of, force_of, Fc) or Fs / stiffness
        return cls(scale, Fc, Fs, vs, stiffness, Fs / stiffness, dx, duration, v_fast, Fv, offset, slip)

    def thresholds(self, elements: int) -> np.ndarray:
        """`elements` element thresholds [m], geometrically spread from 5 % of the slip distance to it."""
        return max(self.slip, self.breakaway) * np.geomspace(0.05, 1.0, elements)


SLIDING_TRAVEL = 3.0  # breakaway displacements from a reversal beyond which a sample counts as sliding
MIN_SLIDING_SAMPLES = 50  # sliding samples (all records together) the sliding line is fitted through


def _sliding_samples(
    x_of: Sequence[np.ndarray], force_of: Sequence[np.ndarray], centred: np.ndarray
) -> np.ndarray | None:
    """The samples (all records' one after another) more than `SLIDING_TRAVEL` breakaway displacements from the last
    displacement reversal, where the force is the sliding friction (a breakaway displacement read as the 99.5 %
    level of the force about its median, `centred`, over the median reversal secant slope); None where no reversal
    gives the slope (every one too small to span the pre-sliding range, or none at all)."""
    level = float(np.percentile(np.abs(centred), 99.5))
    stiffness = _presliding_stiffness(x_of, force_of, level) if level > 0 else None
    if stiffness is None or not stiffness > 0:
        return None
    breakaway = level / stiffness
    travel = np.concatenate([_travel_since_reversal(x, 0.2 * breakaway) for x in x_of])
    return travel > SLIDING_TRAVEL * breakaway


def _held_at_reversals(x_of: Sequence[np.ndarray], force_of: Sequence[np.ndarray], offsets: np.ndarray) -> float:
    """The 90 % level of |F - the record's offset| [N] at the displacement's turning points (beyond 1 % of its
    range), over the records: the friction a record that never slides holds (0 without turning points)."""
    held = [
        np.abs(force[turns] - offsets[i if offsets.size > 1 else 0])
        for i, (x, force) in enumerate(zip(x_of, force_of, strict=True))
        if (turns := _turning_points(x, 0.01 * float(np.ptp(x)) if x.size else 0.0))
    ]
    return float(np.percentile(np.concatenate(held), 90)) if held else 0.0


def _travel_since_reversal(x: np.ndarray, threshold: float) -> np.ndarray:
    """|x - x at the last turning point| [m] at each sample (`_turning_points` with `threshold`; from the first
    sample before the first one)."""
    starts = np.zeros(len(x), dtype=int)
    turns = _turning_points(x, threshold)
    if turns:
        starts[np.asarray(turns)] = np.asarray(turns)
    return np.abs(x - x[np.maximum.accumulate(starts)])


def _presliding_stiffness(
    x_of: Sequence[np.ndarray], force_of: Sequence[np.ndarray], Fs: float, share: float = 0.3
) -> float | None:
    """The median secant slope |dF / dx| [N/m] from each displacement reversal until the force has changed by `share`
    of the full swing `2 Fs` (for an exponential pre-sliding curve `0.84 x` its initial slope at 0.3), over the
    reversals of every record (displacements `x_of`, forces `force_of`) that reach it before the next one; None when
    none does."""
    reached = [row for x, f in zip(x_of, force_of, strict=True) for row in _reversal_secants(x, f, share * 2.0 * Fs)]
    return float(np.median([change / travelled for travelled, change in reached])) if reached else None


def _slip_distance(
    x_of: Sequence[np.ndarray], force_of: Sequence[np.ndarray], Fc: float, share: float = 0.9
) -> float | None:
    """Half the median displacement [m] from a reversal until the force has changed by `share` of the sliding swing
    `2 Fc`, over the reversals of every record: where the last elements of a multi-element model start slipping (a
    reversal curve is the loading curve doubled, Masing's rule); None when no reversal gets there."""
    reached = [row for x, f in zip(x_of, force_of, strict=True) for row in _reversal_secants(x, f, share * 2.0 * Fc)]
    return 0.5 * float(np.median([travelled for travelled, _ in reached])) if reached else None


def _reversal_secants(x: np.ndarray, force: np.ndarray, target: float) -> list[tuple[float, float]]:
    """For each displacement reversal whose force changes by `target` [N] before the next reversal: the distance
    travelled [m] and the force change [N] at the first sample where it does."""
    step = np.diff(x)
    direction = np.sign(step)
    moving = np.flatnonzero(direction != 0)
    if moving.size < 2:
        return []
    turns = moving[1:][direction[moving[1:]] != direction[moving[:-1]]]  # first step of each new direction
    if not turns.size:  # a record that never reverses
        return []
    found = []
    bounds = [*turns[1:], len(step)]
    for start, end in zip(turns, bounds, strict=True):
        travelled = np.abs(x[start + 1 : end + 1] - x[start])
        change = np.abs(force[start + 1 : end + 1] - force[start])
        reached = np.flatnonzero(change >= target)
        if reached.size and travelled[reached[0]] > 0:
            found.append((float(travelled[reached[0]]), float(change[reached[0]])))
    return found


def linkage_gap(records: Sequence[FrictionData], s: RecordScales) -> tuple[float, float]:
    """A linkage's gap [m] and the bristle stiffness behind it [N/m] (`fj.LuGreBacklash`'s start), read off the
    reversals from sliding to sliding (those whose force swing is at least 80 % of the largest) by LuGre's bristle law
    (relaxation length `L = W / (2 sigma0)`, `W` the reversal's swing `2 Fc`): the first 20 % of the swing (unloading
    from `-L` to `-0.6 L`, a travel of `ln(1.25) L = 0.223 L`) gives `sigma0`; the travel from 20 % to 80 % of it is
    the gap plus `ln(4) L = 1.39 L` (unloading to 0, then loading to `0.6 L`). Force differences only, so the record's
    offset and an asymmetry of the two sliding levels hardly enter (a viscous term does: it adds `2 sigma2 |v|` to the
    swing). Reversals are the turning points of the displacement beyond 1 % of its range (sensor noise makes no
    reversal), the crossings interpolated between samples. Medians over the reversals; without such reversals the
    record's stiffness and 5 % of its breakaway displacement, which is also the least gap returned. Several records:
    the reversals of each, pooled."""
    found = []  # (swing W [N], travel to 20 % of it, travel from 20 % to 80 % [m]) per reversal
    for x, _, force in map(host_signals, records):
        found.extend(_linkage_reversals(x, force))
    largest = max((w for w, _, _ in found), default=0.0)
    found = [row for row in found if row[0] >= 0.8 * largest]
    if not found:
        return 0.05 * s.breakaway, s.stiffness
    swing, unloading, crossing = (np.median([row[i] for row in found]) for i in range(3))
    length = float(unloading) / np.log(1.25)
    sigma0 = 0.5 * float(swing) / length
    return max(float(crossing) - np.log(4.0) * length, 0.05 * s.breakaway), sigma0


def _linkage_reversals(x: np.ndarray, force: np.ndarray) -> list[tuple[float, float, float]]:
    """For each reversal of one record (`linkage_gap`): the force swing `W` [N] after it, the travel [m] to 20 % of
    the swing, and the travel [m] from 20 % to 80 % of it."""
    turns = _turning_points(x, 0.01 * float(np.ptp(x)) if x.size else 0.0)
    found = []
    for start, end in itertools.pairwise([*turns, len(x) - 1]):  # none for a record that never reverses
        direction = np.sign(x[end] - x[start])
        swing = direction * (force[start : end + 1] - force[start])  # rises from 0 after the reversal
        travelled = np.abs(x[start : end + 1] - x[start])
        full = float(swing.max())
        if not full > 0:
            continue
        early, late = (_crossing(travelled, swing, share * full) for share in (0.2, 0.8))
        if early > 0:
            found.append((full, early, late - early))
    return found


def _turning_points(x: np.ndarray, threshold: float) -> list[int]:
    """The indices of the displacement's turning points: an extreme counts once `x` has moved back from it by more
    than `threshold` [m] (so that noise on `x` makes no reversal); the last one starts the last segment."""
    turns, extreme, direction = [], 0, 0
    for k in range(1, len(x)):
        if direction == 0:
            if abs(x[k] - x[0]) > threshold:
                direction = int(np.sign(x[k] - x[0]))
                extreme = k
            continue
        if direction * (x[k] - x[extreme]) > 0:
            extreme = k
        elif direction * (x[extreme] - x[k]) > threshold:
            turns.append(extreme)
            direction, extreme = -direction, k
    return turns


def _crossing(travelled: np.ndarray, rising: np.ndarray, level: float) -> float:
    """The travel [m] where `rising` first reaches `level`, interpolated linearly between the two samples."""
    k = int(np.argmax(rising >= level))
    if k == 0:
        return float(travelled[0])
    share = (level - rising[k - 1]) / (rising[k] - rising[k - 1])
    return float(travelled[k - 1] + share * (travelled[k] - travelled[k - 1]))


def _sliding_line(
    force: np.ndarray,
    v: np.ndarray,
    group: np.ndarray,
    offsets: np.ndarray,
    v_of: Sequence[np.ndarray],
    force_of: Sequence[np.ndarray],
) -> tuple[float, float, np.ndarray]:
    """Least squares of `force ~ offset[group] + Fc sign(v) + Fv v` with `Fv >= 0` on the chosen samples (`group`:
    each one's record): `(Fc, Fv, offsets)`, each record's offset [N]; a record with none of the chosen samples: the
    mean residual of its own fastest 30 % (`v_of`, `force_of`: every record's velocity and force) from the line,
    or its entry of `offsets` when none of its samples is faster than its own 70 % level (it does not move, or moves
    at one speed)."""
    present = np.unique(group)
    columns = np.concatenate([record_indicator(group, len(offsets))[:, present], np.sign(v)[:, None]], axis=1)
    coef = with_viscous_slope(columns, v, force)
    offsets = np.array(offsets, dtype=float)
    offsets[present] = coef[: len(present)]
    Fc, Fv = float(coef[len(present)]), float(coef[-1])
    for i in sorted(set(range(len(offsets))) - set(present.tolist())):
        own = np.abs(v_of[i]) > np.percentile(np.abs(v_of[i]), 70)
        if own.any():
            offsets[i] = float(np.mean(force_of[i][own] - Fc * np.sign(v_of[i][own]) - Fv * v_of[i][own]))
    return Fc, Fv, offsets


def host_signals(record: FrictionData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A record's displacement [m], velocity [m/s] and force [N] as float64 NumPy arrays (`Motion.host_signals`)."""
    x, v, _, _ = record.motion.host_signals()
    return np.asarray(x, float), np.asarray(v, float), np.asarray(record.force, float)


def record_of_each_sample(lengths: Sequence[int]) -> np.ndarray:
    """The index of the record each sample belongs to, the records' samples one after another."""
    return np.repeat(np.arange(len(lengths)), lengths)


def record_indicator(group: np.ndarray, records: int) -> np.ndarray:
    """One column per record, 1 on its samples (`group`: each sample's record): the per-record offset columns."""
    return (group[:, None] == np.arange(records)[None, :]).astype(np.float64)


def mean_offset(offsets: Any, lengths: Sequence[int]) -> float:
    """The records' force offsets [N] as one: their mean weighted by the records' lengths (one record's as it is)."""
    offsets = np.asarray(offsets, np.float64)
    return float(offsets[0]) if offsets.size == 1 else float(np.average(offsets, weights=lengths))


def as_records(data: Any, owner: str) -> list[FrictionData]:
    """`data` as a list of records: an `fj.FrictionData`, a non-empty list / tuple of them, a dict `{name: record}`
    (as `fj.fit` takes) or an `fj.RecordBatch` (its records unpadded); a clear error naming `owner` otherwise."""
    if isinstance(data, FrictionData):
        return [data]
    if isinstance(data, RecordBatch):
        return [data.record(i) for i in range(data.count)]
    if isinstance(data, dict):
        data = list(data.values())
    if isinstance(data, (list, tuple)) and data and all(isinstance(r, FrictionData) for r in data):
        return list(data)
    raise TypeError(
        f"{owner}: `data` must be an fj.FrictionData or a non-empty list of them (several records of one device; a "
        f"dict of them or an fj.RecordBatch also does), got {type(data).__name__}."
    )


def with_viscous_slope(columns: np.ndarray, v: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of `y ~ columns @ c + Fv v` with `Fv >= 0` (last): a negative viscous slope is not
    physical, and the fit is then redone without it."""
    coef = np.linalg.lstsq(np.concatenate([columns, v[:, None]], axis=1), y, rcond=None)[0]
    if coef[-1] < 0:
        coef = np.append(np.linalg.lstsq(columns, y, rcond=None)[0], 0.0)
    return coef
