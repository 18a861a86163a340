"""Data-driven starts: scales read off a record before any fit (`RecordScales`) and a starting model of any physics
family built from them (`fj.initial_guess`).

The readings follow the phenomena the papers describe (worden2007 §2, parlitz2004 §II): in gross sliding the force
is `offset + Fc sign(v) + Fv v` (plus the Stribeck rise at low speed), fitted by least squares on the fastest
samples; the static level `Fs` is the top of |F - offset|; right after a reversal the force changes with the
displacement at the pre-sliding stiffness (the slope |dF/dx| over a few samples), and the breakaway displacement is
`Fs / stiffness`; elements of multi-element models (GMS, Maxwell-slip) get thresholds spread from a small fraction of
the breakaway displacement up to it, as reversals of every size between them load them.
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import numpy as np

from .._constraints import unwrap
from .._data._record import FrictionData
from .._metrics import scaled_std
from .._models.physics._dahl import Dahl
from .._models.physics._gms import GMS
from .._models.physics._lugre import LuGre
from .._models.physics._lugre_backlash import LuGreBacklash
from .._models.physics._maxwell_slip import MaxwellSlip, SpringForces
from .._models.physics._static import BoPavelescu, Coulomb, CoulombViscous, Tustin
from .._models.physics._stribeck import ExponentialStribeck
from .._simulate import simulate
from .._smoothing import AbstractSmoothing, Exact
from .._validation import nonnegative_float, positive_int
from ._records import RecordBatch, padded_record
from ._sweep import stack_models

_SIMULATE_EACH = eqx.filter_jit(eqx.filter_vmap(simulate, in_axes=(0, None)))  # a batch of models, one record


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
        signals = [_host_signals(r) for r in records]
        x_of, v_of, force_of = ([item[i] for item in signals] for i in range(3))
        v, force = np.concatenate(v_of), np.concatenate(force_of)
        centred = np.concatenate([f - np.median(f) for f in force_of])
        scale = 0.5 * float(np.percentile(centred, 99) - np.percentile(centred, 1))
        fast = np.abs(v) > np.percentile(np.abs(v), 70)
        sliding = _sliding_samples(x_of, force_of, centred)
        group = _record_of_each_sample([len(f) for f in force_of])
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
        offset = _mean_offset(offsets, [len(f) for f in force_of])
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


def _linkage_gap(records: Sequence[FrictionData], s: RecordScales) -> tuple[float, float]:
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
    for x, _, force in map(_host_signals, records):
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
    """For each reversal of one record (`_linkage_gap`): the force swing `W` [N] after it, the travel [m] to 20 % of
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
    columns = np.concatenate([_indicator(group, len(offsets))[:, present], np.sign(v)[:, None]], axis=1)
    coef = _with_viscous_slope(columns, v, force)
    offsets = np.array(offsets, dtype=float)
    offsets[present] = coef[: len(present)]
    Fc, Fv = float(coef[len(present)]), float(coef[-1])
    for i in sorted(set(range(len(offsets))) - set(present.tolist())):
        own = np.abs(v_of[i]) > np.percentile(np.abs(v_of[i]), 70)
        if own.any():
            offsets[i] = float(np.mean(force_of[i][own] - Fc * np.sign(v_of[i][own]) - Fv * v_of[i][own]))
    return Fc, Fv, offsets


def _host_signals(record: FrictionData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A record's displacement [m], velocity [m/s] and force [N] as float64 NumPy arrays (`Motion.host_signals`)."""
    x, v, _, _ = record.motion.host_signals()
    return np.asarray(x, float), np.asarray(v, float), np.asarray(record.force, float)


def _record_of_each_sample(lengths: Sequence[int]) -> np.ndarray:
    """The index of the record each sample belongs to, the records' samples one after another."""
    return np.repeat(np.arange(len(lengths)), lengths)


def _indicator(group: np.ndarray, records: int) -> np.ndarray:
    """One column per record, 1 on its samples (`group`: each sample's record): the per-record offset columns."""
    return (group[:, None] == np.arange(records)[None, :]).astype(np.float64)


def _mean_offset(offsets: Any, lengths: Sequence[int]) -> float:
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


def _with_viscous_slope(columns: np.ndarray, v: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of `y ~ columns @ c + Fv v` with `Fv >= 0` (last): a negative viscous slope is not
    physical, and the fit is then redone without it."""
    coef = np.linalg.lstsq(np.concatenate([columns, v[:, None]], axis=1), y, rcond=None)[0]
    if coef[-1] < 0:
        coef = np.append(np.linalg.lstsq(columns, y, rcond=None)[0], 0.0)
    return coef


GUESSABLE = (Coulomb, CoulombViscous, Tustin, BoPavelescu, LuGre, LuGreBacklash, GMS, MaxwellSlip, Dahl)


def initial_guess(
    model: Any,
    data: FrictionData | Sequence[FrictionData] | dict[str, FrictionData] | RecordBatch,
    *,
    elements: int | str | None = None,
    smoothing: AbstractSmoothing | None = None,
    without_small_elements: bool = False,
) -> Any:
    """A starting model of `model`'s family, its parameters read off `data` (`RecordScales`).

    **Arguments:**

    - `model`: a class (`fj.LuGre`, `fj.LuGreBacklash` (its gap and stiffness from the reversals), `fj.GMS`,
      `fj.MaxwellSlip` (an NLR model), `fj.Dahl`, `fj.Coulomb`, `fj.CoulombViscous`, `fj.Tustin`, `fj.BoPavelescu`)
      or an instance, whose structure (element count, smoothing) is kept.
    - `data`: the training record (`fj.FrictionData`), or several records of one device (a list, a dict of them, or
      an `fj.RecordBatch`): every reading pooled over them, each record read on its own (no reversal or element
      state carried from one into the next, each its own force offset; the start's `offset` is their mean weighted
      by length), so that the order of the records does not matter.
    - `elements`: element count of GMS / Maxwell-slip (default: the instance's, else 4); `"auto"`: read off the
      record (`fj.element_count`).
    - `smoothing`: the start's smoothing (default: the instance's, else `fj.Exact()`).
    - `without_small_elements`: GMS only: each element of less than 2 % of the force replaced by a split of the
      largest one. The regression leaves such elements where the record has a faint kink near its reversals: on
      some records a true element seen faintly, on others none, where a fit keeps them dead; fit from both starts
      and keep the better (what `fricjax compare` does where they differ).

    What is not readable from a record starts at a neutral value: LuGre's `sigma1` at 0 (it enters the force
    linearly: `fj.fit(..., separable=("sigma1",))` solves it), GMS's attraction rate `C` at 10 Fs per second,
    equal GMS fractions `alpha`, Dahl's exponent at 1.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 20, 4000)), dt=1e-3)
    >>> data = fj.FrictionData(motion, fj.simulate(fj.CoulombViscous(Fc=2.0, Fv=30.0), motion))
    >>> guess = fj.initial_guess(fj.CoulombViscous, data)
    >>> round(float(fj.unwrap(guess).Fc), 1)
    2.0
    ```
    """
    return initial_guesses(
        model, data, elements=elements, smoothing=smoothing, without_small_elements=without_small_elements
    )[-1]


def _reversals(record: FrictionData) -> int | None:
    """How often a record's motion reverses (sign changes of its displacement steps, else of its velocity); None
    when it does not move at all."""
    motion = record.motion
    steps = np.diff(np.asarray(motion.x, dtype=float)) if motion.x is not None else np.asarray(motion.v, dtype=float)
    signs = np.sign(steps[steps != 0])
    if signs.size == 0:
        return None
    return int(np.sum(signs[1:] != signs[:-1]))


def initial_guesses(
    model: Any,
    data: FrictionData | Sequence[FrictionData] | dict[str, FrictionData] | RecordBatch,
    *,
    elements: int | str | None = None,
    smoothing: AbstractSmoothing | None = None,
    without_small_elements: bool = False,
) -> list[Any]:
    """`initial_guess`'s starts from one reading of `data`: one start, or for GMS with `without_small_elements` the
    default start and, where replacing its small elements changes it, that one too (`initial_guess` returns the
    last). `fricjax compare` fits GMS from each."""
    cls = model if isinstance(model, type) else type(model)
    if not issubclass(cls, GUESSABLE):
        names = ", ".join(f"fj.{c.__name__}" for c in GUESSABLE)
        raise TypeError(f"initial_guess: no data-driven start for {cls.__name__}; it has one for {names}.")
    if without_small_elements and not issubclass(cls, GMS):
        raise TypeError(f"initial_guess: `without_small_elements` is for fj.GMS starts, not {cls.__name__}.")
    if smoothing is None:
        smoothing = Exact() if isinstance(model, type) else getattr(model, "smoothing", Exact())
    records = as_records(data, "initial_guess")
    if elements is None:
        elements = 4 if isinstance(model, type) else _element_count(model)
    elif elements == "auto":
        elements = element_count(records) if issubclass(cls, (GMS, MaxwellSlip)) else 4  # others have no elements
    else:
        elements = positive_int(elements, "elements", "initial_guess", hint="(or 'auto')")
    if not any(float(scaled_std(np.asarray(r.force))) > 0 for r in records):
        raise ValueError(
            "initial_guess: the record's force does not vary (no friction level to read a start from); check the "
            "force column, or build the start by hand."
        )
    moves = [_reversals(r) for r in records]
    if all(count is None for count in moves):
        raise ValueError("initial_guess: the record does not move (no displacement or velocity); check the record.")
    hysteretic = (LuGre, LuGreBacklash, GMS, MaxwellSlip, Dahl)
    if issubclass(cls, hysteretic) and not any(count for count in moves if count is not None):
        warnings.warn(
            f"initial_guess: the record never reverses its motion, so {cls.__name__}'s pre-sliding stiffness (and "
            "its elements' breakaways) cannot be read from it; the start's values for them are rough guesses: "
            "identify on a record with reversals.",
            UserWarning,
            stacklevel=2,
        )
    s = RecordScales.from_data(records)
    if not s.Fc > 0:
        raise ValueError(
            "initial_guess: the record's force does not vary (no friction level to read a start from); check the "
            "force column, or build the start by hand."
        )
    if cls is Coulomb:
        return [Coulomb(Fc=s.Fc, offset=s.offset, smoothing=smoothing)]
    if cls is CoulombViscous:
        return [CoulombViscous(Fc=s.Fc, Fv=s.Fv, offset=s.offset, smoothing=smoothing)]
    if cls is Tustin:
        return [Tustin(Fc=s.Fc, Fs=s.Fs, vs=s.vs, Fv=s.Fv, offset=s.offset, smoothing=smoothing)]
    if cls is BoPavelescu:
        return [BoPavelescu(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0, Fv=s.Fv, offset=s.offset, smoothing=smoothing)]
    stribeck = ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)
    if cls is LuGre:
        return [LuGre(stribeck, sigma0=s.stiffness, sigma1=0.0, sigma2=s.Fv, offset=s.offset, smoothing=smoothing)]
    if cls is LuGreBacklash:
        gap, sigma0 = _linkage_gap(records, s)
        return [
            LuGreBacklash(
                stribeck, sigma0=sigma0, sigma1=0.0, sigma2=s.Fv, gap=gap, offset=s.offset, smoothing=smoothing
            )
        ]
    if cls is GMS:
        found = maxwell_slip_elements(records, s, elements, viscous=True)
        if found is not None:  # the elements of a Maxwell-slip model of the record: stiffness and force shares
            thresholds, k, offset, Fv = found
            sets = [(thresholds, k)]
            if without_small_elements:  # a second start where replacing the small elements changes the first
                replaced = _without_small_elements(thresholds, k)
                sets += [] if np.array_equal(replaced[1], k) else [replaced]
            return [
                _screen_gms_sliding_law(
                    GMS(
                        stribeck,
                        k=k_i,
                        alpha=t_i * k_i / np.sum(t_i * k_i),
                        C=10.0 * s.Fs,
                        sigma2=Fv,
                        offset=offset,
                        smoothing=smoothing,
                    ),
                    records,
                )  # fmt: skip
                for t_i, k_i in sets
            ]
        shares = np.arange(elements, 0, -1, dtype=float)  # stiffer elements first
        return [
            GMS(
                stribeck,
                k=s.stiffness * shares / shares.sum(),
                alpha=np.full(elements, 1.0 / elements),
                C=10.0 * s.Fs,
                sigma2=s.Fv,
                offset=s.offset,
                smoothing=smoothing,
            )
        ]
    if cls is Dahl:
        return [Dahl(sigma0=s.stiffness, Fc=s.Fc, offset=s.offset, smoothing=smoothing)]
    found = maxwell_slip_elements(records, s, elements)
    if found is None:  # no motion to regress on: the elements share the static level
        thresholds = s.thresholds(elements)
        return [
            MaxwellSlip.nlr(k=s.Fs / elements / thresholds, thresholds=thresholds, offset=s.offset, smoothing=smoothing)
        ]
    thresholds, k, offset, _ = found
    return [MaxwellSlip.nlr(k=k, thresholds=thresholds, offset=offset, smoothing=smoothing)]


GRID_ELEMENTS = 48  # the dense LR model of `maxwell_slip_elements`


def maxwell_slip_elements(
    data: FrictionData | Sequence[FrictionData], scales: RecordScales, elements: int, *, viscous: bool = False
) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The `elements` Maxwell-slip elements that best reproduce the record: thresholds [m], stiffnesses [N/m], the
    force offset [N] and, with `viscous`, a viscous slope [N s/m] (>= 0) fitted with them (else 0); None for a
    record without motion. GMS starts take their element stiffnesses and force shares from them. Several records
    (a list): one regression of all, each record's elements starting from rest and each record its own offset (the
    offset returned is their mean weighted by length).

    Two steps, both without a descent through the non-smooth threshold clip (parlitz2004 §III-C fits NLR models by a
    genetic algorithm and Nelder-Mead for that reason): (1) an LR model (parlitz2004 §III-A) of `GRID_ELEMENTS`
    elements, thresholds spread geometrically from the small steps near reversals to 20x the slip distance, its
    element forces `k_i Delta_i >= 0` and offset by non-negative least squares on the exact element deflections
    (`_dense_elements`); (2) adjacent elements of that model merged, the pair whose merge changes the initial
    loading curve `sum_i k_i min(delta, Delta_i)` least first (a merged element keeps the pair's force capacity, at
    the stiffness-weighted threshold or at either member's), until `elements` are left (the curve fixes the model's
    response to any displacement history: Masing's rule). On the NLR records of benchmarks/global_search.py the start
    alone is within 1.008x of the true model's held-out error."""
    dense = _dense_elements(as_records(data, "maxwell_slip_elements"), scales, viscous=viscous, elements=elements)
    if dense is None:
        return None
    grid, stiffness, offset, Fv = dense
    thresholds, k = _merge_elements(grid, stiffness, elements)
    return thresholds, k, offset, Fv


def _elements_by_nnls(
    deflections: np.ndarray, velocity: np.ndarray | None, force: Any, group: np.ndarray | None = None
) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Non-negative least squares of `force ~ deflections @ c + Fv v + offset[group]` (the normalised element
    deflections, shape (N, M); no viscous column when `velocity` is None; `group` each sample's record, default one
    record; the offsets of either sign): the element forces `c` [N], `Fv` [N s/m], the offset of each record [N] and
    the mean squared residual [N^2]. The design is first reduced to its triangular factor (small; the same
    minimiser, and the residual of the part it cannot reach added back)."""
    import scipy.optimize

    force = np.asarray(force, np.float64)
    group = np.zeros(len(force), int) if group is None else np.asarray(group)
    records = int(group.max()) + 1
    indicator = _indicator(group, records)
    v = np.zeros((len(force), 0)) if velocity is None else np.asarray(velocity, np.float64)[:, None]
    design = np.concatenate([deflections, v, indicator, -indicator], axis=1)
    triangle = np.asarray(np.linalg.qr(np.concatenate([design, force[:, None]], axis=1), mode="r"))
    n = design.shape[1]
    # fewer samples than columns (a short record, a fine grid): the factor has fewer rows; its missing rows are zeros
    triangle = np.pad(triangle, ((0, max(0, n + 1 - triangle.shape[0])), (0, 0)))
    solution, reduced = scipy.optimize.nnls(triangle[:n, :n], triangle[:n, n], maxiter=50 * n)
    m = deflections.shape[1]
    Fv = float(solution[m]) if velocity is not None else 0.0
    residual = (float(reduced) ** 2 + float(triangle[n, n]) ** 2) / len(force)
    offsets = solution[n - 2 * records : n - records] - solution[n - records :]
    return solution[:m], Fv, offsets, residual


def _dense_elements(
    records: Sequence[FrictionData], scales: RecordScales, *, viscous: bool, elements: int = 2
) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The dense LR model of `maxwell_slip_elements` (step 1): the thresholds [m] and stiffnesses [N/m] of its
    elements with a non-zero force, its offset [N] (several records: their offsets' mean weighted by length) and
    viscous slope [N s/m]; None for records without motion (or shorter than `3 * elements` samples)."""
    signals = [_host_signals(r) for r in records]
    steps = np.abs(np.concatenate([np.diff(x) for x, _, _ in signals]))
    steps = steps[steps > 0]
    lengths = [r.length for r in records]
    if steps.size < 2 or sum(lengths) < 3 * elements:
        return None
    top = 20.0 * max(scales.slip, scales.breakaway)
    low = min(max(float(np.percentile(steps, 2)), 5e-5 * top), 1e-2 * top)  # the small steps near reversals
    grid = np.geomspace(low, top, GRID_ELEMENTS)
    velocity = np.concatenate([v for _, v, _ in signals]) if viscous else None
    force = np.concatenate([f for _, _, f in signals])
    group = _record_of_each_sample(lengths)
    capacity, Fv, offsets, _ = _elements_by_nnls(_deflections(records, grid), velocity, force, group)
    keep = capacity > 1e-9 * max(float(capacity.max()), 1e-300)
    if not keep.any():
        return None
    offset = _mean_offset(offsets, lengths)
    return grid[keep], capacity[keep] / grid[keep], offset, Fv


MOST_ELEMENTS = 8  # the largest element count `element_count` considers
ELEMENT_TOLERANCE = 0.02  # the relative excess of the mean squared residual that `element_count` accepts


def element_count(
    data: FrictionData | Sequence[FrictionData],
    *,
    most: int = MOST_ELEMENTS,
    tolerance: float = ELEMENT_TOLERANCE,
    fewest: int = 2,
) -> int:
    """How many elements a multi-element model (GMS, Maxwell-slip) of the record needs, read off it before any
    fit: the fewest (`fewest` ... `most`) whose Maxwell-slip model (the thresholds of the dense regression of
    `maxwell_slip_elements` merged down to that count; the element forces, viscous slope and offset refitted by
    non-negative least squares) leaves a mean squared residual within `1 + tolerance` of the best count's. The
    merged models' deflections come from one vmap-ed simulation. Several records (a list): the most that any one
    of them needs (a record with little pre-sliding cannot tell small elements apart, and one regression of records
    of different regimes fits neither well). Returns 4 (the former default, within `fewest`-`most`) for a record
    without motion.

    The residuals of neighbouring counts can differ by several per cent from the merging alone, so a count above
    the true one is read off some records: on the synthetic tribometer (3 seeds, 60 % and 80 % training parts) 4
    off 4 of 6 mixed records of the default 4-element GMS (5 off the others) and 6 off the mixed records of a
    6-element GMS that benchmarks/held_out_compare.py uses (there GMS(4) scores 2.8-16x the true model's error on
    held-out records, GMS(5) 1.5-10x, GMS(6) 1.0-1.7x). `fricjax compare` therefore keeps more than 4 GMS elements only
    where the validation part prefers them significantly. Counts below the truth are read too, where the record does
    not load every element apart (a user's trial, 2026-11-28: a GMS(4) truth on a pre-sliding record read 3; GMS(2)
    and GMS(3) truths read 3-6): the count is a start for a model choice, not an estimate of the truth.
    """
    fewest, most = positive_int(fewest, "fewest", "element_count"), positive_int(most, "most", "element_count")
    tolerance = nonnegative_float(tolerance, "tolerance", "element_count")
    if fewest > most:
        raise ValueError(f"element_count: `fewest` ({fewest}) must be at most `most` ({most}).")
    if not isinstance(data, FrictionData):
        try:
            records = list(data)
        except TypeError:
            records = []
        if not records or not all(isinstance(r, FrictionData) for r in records):
            raise TypeError("element_count: `data` must be an fj.FrictionData or a non-empty list of them.")
        return max(element_count(r, most=most, tolerance=tolerance, fewest=fewest) for r in records)
    dense = _dense_elements([data], RecordScales.from_data(data), viscous=True, elements=most)
    if dense is None:  # nothing to read: the former default, within the asked range
        return min(max(4, fewest), most)
    grid, stiffness, _, _ = dense
    counts = list(range(fewest, most + 1))
    merged = [_merge_elements(grid, stiffness, m)[0] for m in counts]
    deflections = _deflections([data], np.concatenate(merged))  # normalised, (N, all counts' elements)
    v = np.asarray(data.motion.samples().v, np.float64)
    edges = np.cumsum([0, *(len(t) for t in merged)])
    residuals = [
        _elements_by_nnls(deflections[:, a:b], v, data.force)[3] for a, b in zip(edges[:-1], edges[1:], strict=True)
    ]
    best = min(residuals)
    return next((m for m, r in zip(counts, residuals, strict=True) if r <= (1.0 + tolerance) * best), most)


STATIC_RATIOS = (1.1, 1.5, 2.2, 3.2, 4.5)  # Fs / Fc screened by `_screen_gms_sliding_law`
STRIBECK_VELOCITY_FACTORS = (0.3, 1.0, 3.0)  # times the record's slow velocity
ATTRACTION_FACTORS = (1.0, 4.0)  # times 10 Fs per second


def _screen_gms_sliding_law(guess: GMS, records: Sequence[FrictionData]) -> GMS:
    """`guess` with the Stribeck curve and attraction rate of the best of a small grid (`STATIC_RATIOS` x
    `STRIBECK_VELOCITY_FACTORS` x `ATTRACTION_FACTORS`, and `guess`'s own), each run free on the record in one
    vmap-ed program, with the viscous slope (>= 0) and offset of each solved by least squares: the peak of |F| on a
    record underestimates `Fs` when the elements reach their bound only once the velocity has passed `vs`, and a
    gradient fit from too low an `Fs` stays in a flat Stribeck curve (benchmarks/global_search.py: 8-17x the true
    model's error on 4 of 10 seeds). Several records: each run from rest, each its own offset, the cost pooled."""
    p = unwrap(guess)
    Fc, vs, C = float(p.stribeck.Fc), float(p.stribeck.vs), float(p.C) / float(p.stribeck.Fs)
    candidates = [guess]
    for ratio in STATIC_RATIOS:
        for factor in STRIBECK_VELOCITY_FACTORS:
            for rate in ATTRACTION_FACTORS:
                stribeck = ExponentialStribeck(Fc=Fc, Fs=ratio * Fc, vs=factor * vs, delta=float(p.stribeck.delta))
                candidates.append(
                    GMS(stribeck, k=p.k, alpha=p.alpha, C=rate * C * ratio * Fc, sigma2=p.sigma2, offset=p.offset,
                        smoothing=guess.smoothing)
                )  # fmt: skip
    forces = _simulate_each(candidates, records)
    signals = [_host_signals(r) for r in records]
    v = np.concatenate([v for _, v, _ in signals])
    elastic = forces - np.asarray(p.sigma2) * v - np.asarray(p.offset)  # each candidate without its linear terms
    residual = np.concatenate([f for _, _, f in signals])[None, :] - elastic
    best, best_cost, best_linear = 0, np.inf, (float(p.sigma2), float(p.offset))
    lengths = [r.length for r in records]
    group = _record_of_each_sample(lengths)
    indicator = _indicator(group, len(records))
    for i, r in enumerate(residual):
        *offsets, Fv = _with_viscous_slope(indicator, v, r)
        cost = float(np.mean((r - Fv * v - np.asarray(offsets)[group]) ** 2))
        if np.isfinite(cost) and cost < best_cost:
            best, best_cost = i, cost
            best_linear = (float(Fv), _mean_offset(offsets, lengths))
    chosen = unwrap(candidates[best])
    law = chosen.stribeck
    stribeck = ExponentialStribeck(Fc=float(law.Fc), Fs=float(law.Fs), vs=float(law.vs), delta=float(law.delta))
    return GMS(
        stribeck, k=chosen.k, alpha=chosen.alpha, C=chosen.C, sigma2=best_linear[0], offset=best_linear[1],
        smoothing=guess.smoothing,
    )  # fmt: skip


def _deflections(records: Sequence[FrictionData], thresholds: np.ndarray) -> np.ndarray:
    """The exact Maxwell-slip element deflections over thresholds, normalised (`delta_i / Delta_i`), shape (N, M)
    (N the records' samples one after another), each record from rest (parlitz2004 eq. 3): one single-element model
    per threshold (`k = 1 / Delta`: its force is the normalised deflection), run side by side in one vmap-ed
    program."""
    return _simulate_each([MaxwellSlip.nlr(k=[1.0 / t], thresholds=[t]) for t in thresholds], records).T


def _simulate_each(models: list[Any], records: Sequence[FrictionData]) -> np.ndarray:
    """The free-run forces of models of one structure on each record's motion from rest, shape (models, N), the
    records one after another: one vmap-ed program (compiled once per structure and record shape; several records
    are padded at rest to the longest, so one program serves them all, and the padding is cut off)."""
    stacked = stack_models(models)
    if len(records) == 1:
        return np.asarray(_SIMULATE_EACH(stacked, records[0].motion), np.float64)
    total = max(r.length for r in records)
    return np.concatenate(
        [
            np.asarray(_SIMULATE_EACH(stacked, padded_record(r, total, frozenset(), False).motion), np.float64)[
                :, : r.length
            ]
            for r in records
        ],
        axis=1,
    )


def _merge_elements(grid: np.ndarray, stiffness: np.ndarray, elements: int) -> tuple[np.ndarray, np.ndarray]:
    """`elements` elements whose initial loading curve `sum k_i min(delta, Delta_i)` is closest to that of the given
    ones: adjacent pairs merged greedily (force capacity kept, at the stiffness-weighted threshold or at either
    member's); where there are fewer, the one of
    the largest capacity split in two around its threshold."""
    thresholds, k = [float(t) for t in grid], [float(s) for s in stiffness]
    delta = np.geomspace(thresholds[0] / 3.0, thresholds[-1] * 3.0, 256)

    def curve(t: list[float], s: list[float]) -> np.ndarray:
        return np.sum(np.asarray(s)[:, None] * np.minimum(delta[None, :], np.asarray(t)[:, None]), axis=0)

    target = curve(thresholds, k)
    while len(thresholds) > elements:
        best: tuple[float, list[float], list[float]] | None = None
        for i in range(len(thresholds) - 1):
            capacity = k[i] * thresholds[i] + k[i + 1] * thresholds[i + 1]
            # the merged threshold: the stiffness-weighted mean (the stiffness added) or either member's own (the
            # other's capacity moved there): an element of a small force share is absorbed by its neighbour
            # instead of dragging the merged threshold towards it
            for merged in (capacity / (k[i] + k[i + 1]), thresholds[i], thresholds[i + 1]):
                t = [*thresholds[:i], merged, *thresholds[i + 2 :]]
                s = [*k[:i], capacity / merged, *k[i + 2 :]]
                cost = float(np.sum((curve(t, s) - target) ** 2))
                if best is None or cost < best[0]:
                    best = (cost, t, s)
        assert best is not None
        _, thresholds, k = best
    return _split_largest(thresholds, k, elements)


MIN_ELEMENT_SHARE = 0.02  # the force share below which `_without_small_elements` replaces an element


def _without_small_elements(thresholds: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The elements with each one of less than `MIN_ELEMENT_SHARE` of the force capacity dropped and the largest
    split instead (as many elements). The non-negative least squares of the dense model leave such elements at the
    small steps near reversals, where a GMS start kept them dead through the fit; on other records they are a true
    element seen faintly (a 5 % element at 0.25 um read as 0.7 %), so both starts are fitted where they differ
    (`initial_guess(..., without_small_elements=True)`; benchmarks/README.md, "Global search, round 6")."""
    t, s = [float(v) for v in thresholds], [float(v) for v in k]
    for _ in range(len(t)):
        capacity = np.asarray(s) * np.asarray(t)
        if len(t) < 2 or capacity.min() >= MIN_ELEMENT_SHARE * capacity.sum():
            break
        i = int(np.argmin(capacity))
        dropped_t, dropped_s = [*t[:i], *t[i + 1 :]], [*s[:i], *s[i + 1 :]]
        split = _split_largest(dropped_t, dropped_s, len(t))
        t, s = [float(v) for v in split[0]], [float(v) for v in split[1]]
    return np.asarray(t), np.asarray(s)


def _split_largest(thresholds: list[float], k: list[float], elements: int) -> tuple[np.ndarray, np.ndarray]:
    """The element of the largest force capacity split in two around its threshold until there are `elements`."""
    while len(thresholds) < elements:
        i = int(np.argmax(np.asarray(k) * np.asarray(thresholds)))
        thresholds = [*thresholds[:i], thresholds[i] / 1.5, thresholds[i] * 1.2, *thresholds[i + 1 :]]
        k = [*k[:i], k[i] / 2.0, k[i] / 2.0, *k[i + 1 :]]
    return np.asarray(thresholds), np.asarray(k)


def _element_count(model: Any) -> int:
    if isinstance(model, GMS):
        return int(np.shape(unwrap(model).k)[-1])
    if isinstance(model, MaxwellSlip):
        if not isinstance(model.force_map, SpringForces):
            raise TypeError("initial_guess: Maxwell-slip starts are NLR models (SpringForces), not DLR / DNLRX.")
        return model.num_elements
    return 4
