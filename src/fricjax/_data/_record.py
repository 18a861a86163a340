"""`FrictionData`: a motion record with the measured friction force, and its splits."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._constraints import as_float_array
from .._inputs import Motion
from .._smoothing import is_concrete


class FrictionData(eqx.Module):
    """A motion record and the measured friction force [N] along it, shape `(T,)`.

    **Arguments:** `motion` a `Motion`; `force` the measured force [N], same length, finite.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> data = fj.FrictionData(fj.Motion.from_position(np.linspace(0, 1e-3, 100), dt=1e-3), np.zeros(100))
    >>> train, test = data.split(0.8)
    >>> train.length, test.length
    (80, 20)
    ```
    """

    motion: Motion
    force: Float[Array, "T"]

    def __init__(self, motion: Motion, force: ArrayLike):
        if not isinstance(motion, Motion):
            raise TypeError(f"FrictionData: `motion` must be a fricjax.Motion, got {type(motion).__name__}.")
        force = as_float_array(force)
        shape = (motion.x if motion.x is not None else motion.v).shape  # type: ignore[union-attr]
        if force.shape != shape:
            if force.size == motion.length and force.ndim == 2 and 1 in force.shape:
                fix = "flatten the column (`np.ravel(force)`)"
            elif len(shape) == 2 and shape[0] == force.size:  # columns of a table passed as one signal
                fix = (
                    "the motion's signal looks like a table's columns (samples along the first axis): pass one "
                    "signal a column, e.g. fj.Motion.from_position(table[:, 0], dt)"
                )
            else:
                fix = "give one force sample per motion sample"
            samples = (
                f"{motion.length} samples"
                if len(shape) < 2
                else f"read as {shape[0]} motions of {motion.length} samples: time is the last axis"
            )
            raise ValueError(
                f"FrictionData: `force` has shape {force.shape} but the motion's signals have {shape} ({samples}); "
                f"{fix}."
            )
        if is_concrete(force) and not bool(np.all(np.isfinite(np.asarray(force)))):
            bad = int(np.flatnonzero(~np.isfinite(np.asarray(force)))[0])
            raise ValueError(
                f"FrictionData: `force` contains NaN or inf (first at flat index {bad}); clean or interpolate the "
                "record."
            )
        self.motion = motion
        self.force = force

    @property
    def length(self) -> int:
        """Number of samples T."""
        return self.motion.length

    def slice(self, start: int, stop: int) -> FrictionData:
        """Samples `start:stop` (Python slice semantics), as a new record."""
        if not 0 <= start < stop <= self.length:
            raise ValueError(
                f"FrictionData.slice: need 0 <= start < stop <= {self.length}, got start={start}, stop={stop}; "
                "an empty split cannot be fitted or scored."
            )
        m = self.motion

        def cut(signal: Array | None) -> Array | None:
            return None if signal is None else signal[..., start:stop]

        motion = Motion(x=cut(m.x), v=cut(m.v), dt=m.dt, a=cut(m.a), normal_force=cut(m.normal_force))
        return FrictionData(motion, self.force[..., start:stop])

    def split(self, *points: float | int) -> tuple[FrictionData, ...]:
        """Split in consecutive parts at `points`: fractions in (0, 1) or sample indices.

        `data.split(0.6, 0.8)` gives train / validation / test = 60 / 20 / 20 %. Each part must be non-empty.
        """
        if not points:
            raise ValueError("FrictionData.split: give at least one split point (a fraction or an index).")
        indices: list[int] = []
        for p in points:
            kind = np.asarray(p).dtype.kind if np.ndim(p) == 0 else ""  # a number or a 0-d NumPy / JAX array
            if isinstance(p, (str, bytes)) or kind not in "iuf" or not kind:
                raise TypeError(
                    f"FrictionData.split: split points are fractions in (0, 1) or sample indices, got {p!r}."
                )
            indices.append(int(p) if kind in "iu" else int(round(float(p) * self.length)))
        edges = [0, *indices, self.length]
        if any(b <= a for a, b in zip(edges[:-1], edges[1:], strict=True)):
            raise ValueError(
                f"FrictionData.split: split points {list(points)} give an empty or reversed part of a record of "
                f"{self.length} samples (edges {edges}); use increasing points inside the record."
            )
        return tuple(self.slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True))


def concatenate(parts: Sequence[FrictionData]) -> FrictionData:
    """Join records end to end (same `dt`); each signal of the records' motions (`x`, `v`, `a`, `normal_force`) is
    joined where every record has it, and dropped where none has; a signal that only some records have is an error
    (joined, the others' samples would be missing; dropped, theirs would be lost without a word)."""
    first = parts[0].motion

    def join(name: str) -> np.ndarray | None:
        present = [getattr(p.motion, name) is not None for p in parts]
        if not any(present):
            return None
        if not all(present):
            raise ValueError(
                f"concatenate: record {present.index(not present[0])} {'lacks' if present[0] else 'has'} the "
                f"signal `{name}` that record 0 {'has' if present[0] else 'lacks'}; give it to every record or to none."
            )
        return np.concatenate([np.asarray(getattr(p.motion, name)) for p in parts])

    motion = Motion(x=join("x"), v=join("v"), dt=first.dt, a=join("a"), normal_force=join("normal_force"))
    return FrictionData(motion, np.concatenate([np.asarray(p.force) for p in parts]))


def resample(data: FrictionData, rate: float, *, max_denominator: int = 1000) -> FrictionData:
    """`data` at another sample rate `rate` [Hz]: each signal (`x`, `v`, `a`, `normal_force`, the force) resampled by a
    polyphase filter (`scipy.signal.resample_poly`, its Kaiser-windowed anti-alias low-pass, the edges extended
    linearly), the ratio of the rates as a fraction `up / down` with `down <= max_denominator` (the rate reached is
    `rate` within that approximation: the new `dt` is the old one times `down / up`). Records sampled at different
    rates can then be fitted together (`fricjax compare --resample HZ`).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(np.sin(np.linspace(0, 6, 1000)), dt=1e-3)
    >>> fj.resample(fj.FrictionData(motion, np.cos(np.linspace(0, 6, 1000))), 500.0).length
    500
    ```
    """
    from fractions import Fraction

    import scipy.signal as ss

    rate = float(rate)
    if not (np.isfinite(rate) and rate > 0):
        raise ValueError(f"resample: `rate` must be a positive sample rate in Hz, got {rate!r}.")
    dt = float(np.asarray(data.motion.dt).reshape(-1)[0])
    ratio = Fraction(rate * dt).limit_denominator(int(max_denominator))
    if ratio <= 0:
        raise ValueError(f"resample: {rate:g} Hz is too far below the record's {1 / dt:g} Hz; choose a higher rate.")
    if ratio == 1:
        return data

    def poly(signal: Any) -> np.ndarray:
        return ss.resample_poly(np.asarray(signal, dtype=float), ratio.numerator, ratio.denominator, padtype="line")

    motion = data.motion
    resampled = Motion(
        x=None if motion.x is None else poly(motion.x),
        v=None if motion.v is None else poly(motion.v),
        dt=dt * ratio.denominator / ratio.numerator,
        a=None if motion.a is None else poly(motion.a),
        normal_force=None if motion.normal_force is None else poly(motion.normal_force),
    )
    return FrictionData(resampled, poly(data.force))


# a normal load whose |correlation| with the friction force, or with its magnitude, reaches this follows the force
# itself: the damper's actuator forces (its drive, 0.98-0.998 with |F|) fed as the load made every model 7x better. A
# genuine load swept while sliding also follows |F| = mu N (0.94-0.95 in a slow sweep with a noisy force), which is
# why the line is above that; a load at or above it is refused with an override (`--accept-correlated-load`)
LOAD_FOLLOWS_FORCE = 0.97


def load_force_correlation(force: ArrayLike, normal_force: ArrayLike) -> float:
    """How closely a normal load follows the friction force: the larger |Pearson correlation| of the load with the
    force and with |force| (NaN where either is constant). A load at or above `LOAD_FOLLOWS_FORCE` is, as an input,
    a copy of the output a model should predict (a drive or reaction force, not the load pressing the surfaces)."""
    force = np.asarray(force, np.float64).reshape(-1)
    load = np.asarray(normal_force, np.float64).reshape(-1)
    values = []
    for target in (force, np.abs(force)):
        a, b = load - load.mean(), target - target.mean()
        scale = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
        if scale > 0 and np.isfinite(scale):
            values.append(abs(float(np.sum(a * b)) / scale))
    return max(values) if values else float("nan")
