"""The records of `compare`: the training record's split into train / validation / test parts (`Split`), the
records the models are scored on (`TestRecord`, with its initialisation window), and the records named on the
command line (`load_record_spec`: built-in synthetic tribometer records or CSV / NPZ files)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._data._io import Units, read_record
from ..._data._record import FrictionData
from ._settings import CompareError


@dataclasses.dataclass(frozen=True)
class TestRecord:
    """A record a fitted model is scored on by free-run simulation in exact mode from the record's first sample.

    Samples `[start, start + init_window)` are the initialisation window: the model runs through them (its
    state settles from the record's history) and the record's force-cell offset is estimated there, as the mean
    of measured minus predicted force, and added to the prediction. Samples `[start + init_window, T)` are
    scored; the window never is. `start` > 0 when the test part follows training data in the same record
    (`Split.test_record`).

    `reference`: where the record is synthetic, the force its sensor reads without white noise (the true model
    plus drift and offset): scored the same way, it is the noise floor.
    """

    __test__ = False  # not a pytest test class

    name: str
    record: FrictionData
    start: int = 0
    init_window: int = 0
    reference: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not (self.start >= 0 and self.init_window >= 0 and self.start + self.init_window < self.record.length):
            raise CompareError(
                f"{self.name}: an initialisation window of {self.init_window} samples leaves nothing to score in a "
                f"test part of {self.record.length - self.start} samples; lower --init-window"
            )

    @classmethod
    def whole(cls, loaded: LoadedRecord, init_window: int | None = None, name: str | None = None) -> TestRecord:
        """A whole record loaded on the command line as a test record (default window: `default_init_window`)."""
        window = default_init_window(loaded.data.length) if init_window is None else int(init_window)
        return cls(loaded.name if name is None else name, loaded.data, 0, window, loaded.reference)

    @property
    def scored_start(self) -> int:
        return self.start + self.init_window


def default_init_window(samples: int) -> int:
    """The default initialisation window: 10 % of a test part's samples (at least 1)."""
    return max(1, int(round(0.1 * samples)))


@dataclasses.dataclass(frozen=True)
class Split:
    """A record and its train / validation / test boundaries: train = [0, train_end), validation =
    [train_end, validation_end), test = [validation_end, T) (empty when the models are tested on other
    records). Hysteretic models are always simulated from the start of the record, and scored on their part
    only, so they enter each part in the state their history gives them (parlitz2004 and worden2007 simulate the
    whole record in the same way)."""

    full: FrictionData
    train_end: int
    validation_end: int

    def __post_init__(self) -> None:
        if not 0 < self.train_end < self.validation_end <= self.full.length:
            raise CompareError(
                f"the split edges {self.train_end}, {self.validation_end} of a {self.full.length}-sample record leave "
                "an empty training or validation part; use --split TRAIN_END VALIDATION_END as fractions, e.g. 0.6 0.8"
            )

    @classmethod
    def fractions(cls, full: FrictionData, train_end: float, validation_end: float) -> Split:
        """Split at fractions of the record (`0 < train_end < validation_end <= 1`)."""
        if not 0 < train_end < validation_end <= 1:
            raise CompareError(
                f"--split {train_end} {validation_end}: need 0 < TRAIN_END < VALIDATION_END <= 1 (fractions of the "
                "training record)"
            )
        n = full.length
        return cls(full, int(round(train_end * n)), int(round(validation_end * n)))

    @property
    def train(self) -> FrictionData:
        return self.full.slice(0, self.train_end)

    @property
    def until_validation_end(self) -> FrictionData:
        return self.full.slice(0, self.validation_end)

    @property
    def test(self) -> FrictionData:
        return self.full.slice(self.validation_end, self.full.length)

    def test_record(self, init_window: int | None = None, reference: Any = None) -> TestRecord:
        """The test part as a `TestRecord` simulated from the record's start; `init_window` samples of it (default
        `default_init_window`) initialise the model and estimate the offset."""
        samples = self.full.length - self.validation_end
        if samples <= 0:
            raise CompareError("the training record has no test part (its split ends at 1); pass --test records")
        window = default_init_window(samples) if init_window is None else int(init_window)
        ref = None if reference is None else np.asarray(reference, dtype=float)
        return TestRecord("test part", self.full, self.validation_end, window, ref)


@dataclasses.dataclass(frozen=True)
class LoadedRecord:
    """A record named on the command line: the data (SI), its data card, its units, and for built-in synthetic
    records the true model and the noise-free sensor reading (`reference`)."""

    name: str
    data: FrictionData
    card: dict[str, Any]
    units: Units
    truth: Any = None
    reference: np.ndarray | None = None


_TRIBOMETER_KEYS = {"seed": int, "offset": float, "duration": float, "drift": float}


def load_record_spec(
    spec: str, *, seed: int = 0, dt: float | None = None, x_unit: str | None = None, force_unit: str | None = None
) -> LoadedRecord:
    """Resolve a record named on the command line: `tribometer:REGIME[:key=value,...]` (keys `seed`, `offset`
    [N] force-cell offset, `drift` [N], `duration` [s]; e.g. `tribometer:mixed:seed=1,offset=0.3`), or a `.npz`
    / `.csv` file (`fj.load_record`: column aliases, units, `dt`)."""
    import pathlib

    from ..._data._tribometer import make_tribometer

    if spec.startswith("tribometer"):
        parts = spec.split(":")
        regime = parts[1] if len(parts) > 1 and parts[1] else "mixed"
        options: dict[str, Any] = {"seed": seed}
        for item in ",".join(parts[2:]).split(",") if len(parts) > 2 else []:
            key, _, value = item.partition("=")
            if key not in _TRIBOMETER_KEYS or not value:
                raise CompareError(
                    f"{spec}: options are key=value pairs of {', '.join(_TRIBOMETER_KEYS)} (e.g. "
                    f"tribometer:mixed:seed=1,offset=0.3), got {item!r}"
                )
            try:
                options[key] = _TRIBOMETER_KEYS[key](value)
            except ValueError:
                raise CompareError(f"{spec}: {key}={value!r} is not a number") from None
        seed_value = options.pop("seed")
        kwargs = {
            "force_offset": options.get("offset", 0.0),
            **({"drift": options["drift"]} if "drift" in options else {}),
            **({"duration": options["duration"]} if "duration" in options else {}),
        }
        try:
            data = make_tribometer(regime, seed=seed_value, **kwargs)
        except (ValueError, TypeError) as err:
            raise CompareError(f"{spec}: {err}") from err
        return LoadedRecord(
            spec, data.full, dict(data.card), Units(), data.true_model, np.asarray(data.sensor_force, dtype=float)
        )
    path = pathlib.Path(spec)
    if not path.is_file():
        raise CompareError(f"{spec}: no such file (use tribometer:presliding|mixed|sliding, emps, or a .csv / .npz)")
    try:
        full, info = read_record(path, dt=dt, x_unit=x_unit, force_unit=force_unit)
    except ValueError as err:
        raise CompareError(str(err)) from err
    card = {
        "source": str(path),
        "samples": full.length,
        "columns": dict(info.columns),
        "ignored": list(info.ignored),
        "units": {"x": info.units.x, "force": info.units.force},
        "dt_s": float(np.asarray(full.motion.dt)),
    }
    return LoadedRecord(spec, full, card, info.units)


def split_record(
    loaded: LoadedRecord, fractions: Sequence[float] | None = None, *, tested_elsewhere: bool = False
) -> Split:
    """The training record's split: `fractions` (TRAIN_END, VALIDATION_END) where given; else 0.8 / 1.0 when the
    models are tested on other records (`tested_elsewhere`), the tribometer's own edges for built-in records, and
    60 / 20 / 20 otherwise."""
    edges = loaded.card.get("split_edges")
    if fractions is not None:
        return Split.fractions(loaded.data, *fractions)
    if tested_elsewhere:
        return Split.fractions(loaded.data, 0.8, 1.0)
    if edges is not None:
        return Split(loaded.data, int(edges[1]), int(edges[2]))
    return Split.fractions(loaded.data, 0.6, 0.8)


def load_split(spec: str, *, seed: int = 0) -> tuple[Split, dict[str, Any], Any]:
    """Resolve `--data` and split it 60 / 20 / 20 (the tribometer's own edges for built-in records).
    **Returns:** `(split, data card, true model or None)`."""
    loaded = load_record_spec(spec, seed=seed)
    return split_record(loaded), loaded.card, loaded.truth


def statistics_warnings(split: Split, tests: list[TestRecord], units: Units) -> list[str]:
    """Warnings when a test record's scored part differs sharply from the training part: force spread 3x
    (its NMSE is then normalised by a very different variance) or displacement range 10x (the model is
    extrapolated)."""
    out = []
    train_force = float(np.std(np.asarray(split.train.force)))
    train_x = float(np.ptp(np.asarray(split.train.motion.samples().x)))
    for test in tests:
        force = np.asarray(test.record.force)[test.scored_start :]
        x = np.asarray(test.record.motion.samples().x)[test.scored_start :]
        for what, ours, theirs, unit, factor, limit in (
            ("force std", float(np.std(force)), train_force, units.force, units.force_factor, 3.0),
            ("displacement range", float(np.ptp(x)), train_x, units.x, units.x_factor, 10.0),
        ):
            if theirs > 0 and ours > 0 and not 1 / limit <= ours / theirs <= limit:
                out.append(
                    f"{test.name}: {what} {ours / factor:.3g} {unit} against {theirs / factor:.3g} {unit} in training "
                    f"({ours / theirs:.2g}x): its scores are not comparable with the training fit's"
                )
    return out
