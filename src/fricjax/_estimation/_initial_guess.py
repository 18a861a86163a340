"""Data-driven starts: a starting model of any physics family built from the scales read off its records
(`fj.initial_guess`, `initial_guesses`; the scales: `_record_scales`, the elements of multi-element models:
`_elements`). Elements of multi-element models (GMS, Maxwell-slip) get thresholds spread from a small fraction of
the breakaway displacement up to it, as reversals of every size between them load them.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._data._record import FrictionData
from .._metrics import scaled_std
from .._models.physics._dahl import Dahl
from .._models.physics._gms import GMS
from .._models.physics._lugre import LuGre
from .._models.physics._lugre_backlash import LuGreBacklash
from .._models.physics._maxwell_slip import MaxwellSlip
from .._models.physics._static import BoPavelescu, Coulomb, CoulombViscous, Tustin
from .._models.physics._stribeck import ExponentialStribeck
from .._smoothing import AbstractSmoothing, Exact
from .._validation import positive_int
from ._elements import (
    element_count,
    element_count_of,
    maxwell_slip_elements,
    replace_small_elements,
    screen_gms_sliding_law,
)
from ._record_scales import RecordScales, as_records, linkage_gap
from ._records import RecordBatch

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
        elements = 4 if isinstance(model, type) else element_count_of(model)
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
        gap, sigma0 = linkage_gap(records, s)
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
                replaced = replace_small_elements(thresholds, k)
                sets += [] if np.array_equal(replaced[1], k) else [replaced]
            return [
                screen_gms_sliding_law(
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
