"""Data-driven starts: a starting model of any physics family built from the scales read off its records
(`fj.initial_guess`, `initial_guesses`; the scales: `_record_scales`, the elements of multi-element models:
`_elements`). Elements of multi-element models (GMS, Maxwell-slip) get thresholds spread from a small fraction of
the breakaway displacement up to it, as reversals of every size between them load them.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..._constraints import Positive, sided_paths, unwrap
from ..._data._record import FrictionData
from ..._metrics import scaled_std
from ..._models._base import AbstractFrictionModel
from ..._smoothing import AbstractSmoothing, Exact
from ..._validation import positive_int
from ..loop._strategies import where_from_path
from ..problem._records import RecordBatch
from ._elements import (
    element_count,
    element_count_of,
    maxwell_slip_elements,
    replace_small_elements,
    screen_gms_sliding_law,
)
from ._record_scales import RecordScales, as_records, linkage_gap


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


@dataclasses.dataclass(frozen=True)
class StartReader:
    """What a family's start reads off its records (`AbstractFrictionModel.start_from_scales`): the records' scales
    and the regressions of this layer, bound to the records."""

    scales: RecordScales
    records: Sequence[FrictionData]

    def linkage_gap(self) -> tuple[float, float]:
        """The gap [m] of a linkage with backlash and the stiffness [N/m] once it is closed."""
        return linkage_gap(self.records, self.scales)

    def maxwell_elements(self, elements: int, viscous: bool = False) -> Any:
        """The thresholds, stiffnesses, offset and viscous slope of a Maxwell-slip regression (None without motion)."""
        return maxwell_slip_elements(self.records, self.scales, elements, viscous=viscous)

    def replace_small_elements(self, thresholds: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return replace_small_elements(thresholds, k)

    def screen_gms_sliding_law(self, guess: Any) -> Any:
        return screen_gms_sliding_law(guess, self.records)


def _has_start(cls: type) -> bool:
    return cls.start_from_scales.__func__ is not AbstractFrictionModel.start_from_scales.__func__  # type: ignore[attr-defined]


def _with_starts() -> list[str]:
    """The public friction model classes with a data-driven start, for the message of a class without one."""
    found, pending = set(), list(AbstractFrictionModel.__subclasses__())
    while pending:
        cls = pending.pop()
        pending += cls.__subclasses__()
        if _has_start(cls) and cls.__module__.startswith("fricjax.") and not cls.__name__.startswith("_"):
            found.add(cls.__name__)
    return sorted(found)


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
    last). `fricjax compare` fits GMS from each. Each family builds its own start from the scales read here
    (`AbstractFrictionModel.start_from_scales`)."""
    cls: Any = model if isinstance(model, type) else type(model)
    if not (issubclass(cls, AbstractFrictionModel) and _has_start(cls)):
        names = ", ".join(f"fj.{name}" for name in _with_starts())
        raise TypeError(f"initial_guess: no data-driven start for {cls.__name__}; it has one for {names}.")
    if without_small_elements and not cls.replaces_small_elements:
        raise TypeError(f"initial_guess: `without_small_elements` is for fj.GMS starts, not {cls.__name__}.")
    if smoothing is None:
        smoothing = Exact() if isinstance(model, type) else getattr(model, "smoothing", Exact())
    records = as_records(data, "initial_guess")
    if elements is None:
        elements = 4 if isinstance(model, type) else element_count_of(model)
    elif elements == "auto":
        elements = element_count(records) if cls.has_elements else 4  # others have no elements
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
    if cls.presliding and not any(count for count in moves if count is not None):
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
    starts = cls.start_from_scales(
        StartReader(s, records), elements=elements, smoothing=smoothing, without_small_elements=without_small_elements
    )
    sided = () if isinstance(model, type) else sorted(sided_paths(unwrap(model)))
    return [_with_pairs(start, sided) for start in starts or []]


def _with_pairs(start: Any, paths: Sequence[str]) -> Any:
    """`start` with a (+, -) pair at each of `paths` (an instance's asymmetric coefficients, `sided_paths`), both
    sides at the start's symmetric value: the structure the instance asked for is kept, and the fit separates the
    sides (in sliding a force offset and an asymmetry of the levels are alike, so the record alone does not)."""
    for path in paths:
        where = where_from_path(path)
        try:
            node = where(start)
        except (AttributeError, IndexError, KeyError, TypeError):
            continue
        value = np.asarray(unwrap(node))
        if value.shape == (2,):
            continue
        pair = np.full((2,), float(value), dtype=value.dtype)
        replaced = Positive(pair, transform=node.transform) if isinstance(node, Positive) else jnp.asarray(pair)
        start = eqx.tree_at(where, start, replaced)
    return start
