"""The records of `compare`: the training record's split into train / validation / test parts (`Split`), several
training records of one device (`TrainingRecords`), the records the models are scored on (`TestRecord`, with its
initialisation window), and the records named on the command line (`load_record_spec`: built-in synthetic
tribometer records or CSV / NPZ files; `expand_record_specs`: file globs)."""

from __future__ import annotations

import dataclasses
import os
import pathlib
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._data._columns import Units
from ..._data._io import read_record
from ..._data._record import FrictionData
from ..._data._record import resample as resample_record
from ..._metrics import numpy_std
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


def short_labels(names: Sequence[str]) -> list[str]:
    """Labels of records named by file paths, as short as keeps them apart: the file names when they differ, else
    the paths below their common folder (`a/run1.csv`, `b/run1.csv`); a name that is not a path is kept."""
    paths = [pathlib.PurePath(name) for name in names]
    is_path = [len(p.parts) > 1 for p in paths]
    short = [p.name if flag else name for p, flag, name in zip(paths, is_path, names, strict=True)]
    if len(set(short)) == len(short):
        return short
    folders = [str(p.parent) for p, flag in zip(paths, is_path, strict=True) if flag]
    try:
        common = pathlib.PurePath(os.path.commonpath(folders)) if folders else None
    except ValueError:  # absolute and relative paths together: no common folder
        return list(names)
    out = []
    for p, flag, name in zip(paths, is_path, names, strict=True):
        out.append(str(p.relative_to(common)) if flag and common is not None and common.parts else name)
    return out if len(set(out)) == len(out) else list(names)  # a bare name beside a path of the same file name


def default_init_window(samples: int) -> int:
    """The default initialisation window: 10 % of a test part's samples (at least 1)."""
    return max(1, int(round(0.1 * samples)))


@dataclasses.dataclass(frozen=True)
class Split:
    """A record and its train / validation / test boundaries: train = [0, train_end), validation =
    [train_end, validation_end), test = [validation_end, T) (empty when the models are tested on other
    records). Hysteretic models are always simulated from the start of the record, and scored on their part
    only, so they enter each part in the state their history gives them (parlitz2004 and worden2007 simulate the
    whole record in the same way). `reference`: for a synthetic record, the force its sensor reads without white
    noise (`load_split` and `split_record` attach it for built-in records), which `test_record` hands on so that
    `reference_scores` gives the noise floor."""

    full: FrictionData
    train_end: int
    validation_end: int
    reference: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if not 0 < self.train_end < self.validation_end <= self.full.length:
            raise CompareError(
                f"the split edges {self.train_end}, {self.validation_end} of a {self.full.length}-sample record leave "
                "an empty training or validation part; use --split TRAIN_END VALIDATION_END as fractions, e.g. 0.6 0.8"
            )

    @classmethod
    def fractions(
        cls, full: FrictionData, train_end: float, validation_end: float, reference: np.ndarray | None = None
    ) -> Split:
        """Split at fractions of the record (`0 < train_end < validation_end <= 1`)."""
        if not 0 < train_end < validation_end <= 1:
            raise CompareError(
                f"--split {train_end} {validation_end}: need 0 < TRAIN_END < VALIDATION_END <= 1 (fractions of the "
                "training record)"
            )
        n = full.length
        return cls(full, int(round(train_end * n)), int(round(validation_end * n)), reference)

    @property
    def train(self) -> FrictionData:
        return self.full.slice(0, self.train_end)

    @property
    def several(self) -> bool:
        """False: one training record (`TrainingRecords` is the several-record form)."""
        return False

    @property
    def train_records(self) -> list[FrictionData]:
        """The train part as a list of one record (`TrainingRecords.train_records`: one per record)."""
        return [self.train]

    def fit_arguments(self, model: Any, drift: bool = False) -> tuple[Any, dict[str, Any]]:
        """`fj.fit`'s data and validation arguments: the train part, and the record up to the validation part's end
        with the train part as burn-in (hysteretic models enter the validation part in the state their history
        gives them). `model` and `drift` are for `TrainingRecords` (one record: the drift is a model wrapper)."""
        return self.train, {"validation": self.until_validation_end, "validation_burn_in": self.train_end}

    @property
    def until_validation_end(self) -> FrictionData:
        return self.full.slice(0, self.validation_end)

    @property
    def test(self) -> FrictionData:
        return self.full.slice(self.validation_end, self.full.length)

    def test_record(self, init_window: int | None = None, reference: Any = None) -> TestRecord:
        """The test part as a `TestRecord` simulated from the record's start; `init_window` samples of it (default
        `default_init_window`) initialise the model and estimate the offset; `reference` (default the split's own)
        the sensor's noise-free reading, for the noise floor (`reference_scores`)."""
        samples = self.full.length - self.validation_end
        if samples <= 0:
            raise CompareError("the training record has no test part (its split ends at 1); pass --test records")
        window = default_init_window(samples) if init_window is None else int(init_window)
        reference = self.reference if reference is None else reference
        ref = None if reference is None else np.asarray(reference, dtype=float)
        return TestRecord("test part", self.full, self.validation_end, window, ref)


@dataclasses.dataclass(frozen=True)
class TrainingRecords:
    """Several training records of one device (`--data A B ...`): one model, fitted on all of them with per-record
    nuisances (force offset, initial state, and a drift with `--drift`: `fj.fit(model, [records], nuisances=...)`).
    Record i is trained on its samples `[0, train_ends[i])`; the rest of it is its validation part (simulated from
    the record's start, scored after the train part), unless `validation` holds whole validation records
    (`--validation FILE ...`; the training records are then trained on whole).

    `train` and `full`, the attributes the single-record code reads of a `Split`, are the training parts joined end
    to end (for the data scales starting models are built from, and the statistics warnings)."""

    records: tuple[FrictionData, ...]
    train_ends: tuple[int, ...]
    names: tuple[str, ...]
    validation: tuple[FrictionData, ...] = ()
    validation_names: tuple[str, ...] = ()

    @classmethod
    def build(
        cls, trainings: Sequence[LoadedRecord], validations: Sequence[LoadedRecord], train_fraction: float | None
    ) -> TrainingRecords:
        """The records with their train parts: whole records with `validations`, else the first `train_fraction`
        (default 0.8) of each."""
        if validations and train_fraction is not None:
            raise CompareError("--split and --validation: with validation records the training records are whole")
        fraction = 1.0 if validations else (0.8 if train_fraction is None else float(train_fraction))
        if not 0 < fraction <= 1:
            raise CompareError(f"--split {fraction}: the train fraction of each record must be in (0, 1]")
        ends = tuple(max(1, min(t.data.length, int(round(fraction * t.data.length)))) for t in trainings)
        if not validations and any(end >= t.data.length for end, t in zip(ends, trainings, strict=True)):
            raise CompareError("--split leaves no validation part in a training record; lower TRAIN_END")
        return cls(
            tuple(t.data for t in trainings),
            ends,
            tuple(short_name(t.name) for t in trainings),
            tuple(v.data for v in validations),
            tuple(short_name(v.name) for v in validations),
        )

    @property
    def several(self) -> bool:
        return True

    @property
    def train_records(self) -> list[FrictionData]:
        return [r.slice(0, end) for r, end in zip(self.records, self.train_ends, strict=True)]

    @property
    def train(self) -> FrictionData:
        from ..._data._record import concatenate

        parts = self.train_records
        return concatenate(parts) if len(parts) > 1 else parts[0]

    @property
    def full(self) -> FrictionData:
        return self.train

    def validation_batch(self, model: Any) -> Any:
        """The validation records as one `fj.RecordBatch`: each training record simulated from its start with only
        its validation part scored, or the `--validation` records whole."""
        from ..._estimation.problem._records import RecordBatch

        requires = _signals(model)
        if self.validation:
            return RecordBatch.from_records(
                list(self.validation), names=self.validation_names, requires=requires, argument="--validation"
            )
        return RecordBatch.from_records(
            list(self.records), score_from=self.train_ends, names=self.names, requires=requires, argument="--data"
        )

    def fit_arguments(self, model: Any, drift: bool = False) -> tuple[Any, dict[str, Any]]:
        """`fj.fit`'s data and validation arguments: the train parts as a list, the validation batch, and the
        per-record nuisances (offset and initial state always; a linear drift per record with `drift`)."""
        from ..._estimation.problem._records import Nuisances, RecordBatch

        requires = _signals(model)
        train = RecordBatch.from_records(self.train_records, names=self.names, requires=requires, argument="--data")
        return train, {
            "validation": self.validation_batch(model),
            "nuisances": Nuisances(offset=True, drift=drift, initial_state=True),
        }


def _signals(model: Any) -> frozenset[str]:
    """The signals of `model` that a batch of records keeps beside x and v (`"a"`, `"normal_force"`)."""
    return frozenset(getattr(model, "requires", frozenset())) & {"a", "normal_force"}


def short_name(spec: str) -> str:
    """A record's name for tables: a file's name without its folder (built-in records as they are)."""
    import os

    return os.path.basename(spec) if os.sep in spec else spec


def is_built_in(spec: str) -> bool:
    """Whether a record named on the command line is built in (`emps`, `tribometer[:REGIME[:options]]`), not a
    file (`tribometer_run.csv` is a file)."""
    return spec in ("emps", "tribometer") or spec.startswith("tribometer:")


def expand_record_specs(specs: Sequence[str], option: str) -> list[str]:
    """The records named by an option: built-in names as they are; a name that is an existing file as it is (a file
    called `run[1].csv` is that file, not a pattern); other names with `*`, `?` or `[` expanded as globs (sorted; a
    glob that matches no file is an error naming it). A record named twice (the same file by two paths, overlapping
    globs) is kept once, with a note: fitted twice, its share of the loss would be doubled."""
    import glob

    out: list[str] = []
    seen: dict[str, str] = {}  # the real path of each file (a built-in record: its name) -> the name first given
    for spec in specs:
        if is_built_in(spec) or _exists(spec) or not any(c in spec for c in "*?["):
            matches = [spec]
        else:
            matches = sorted(glob.glob(spec))
            if not matches:
                raise CompareError(
                    f"{option} {spec}: the pattern matches no file (quote it so the shell does not expand it)"
                )
        for name in matches:
            key = name if is_built_in(name) else os.path.realpath(name)
            if key in seen:
                print(f"note: {option} {name} is {seen[key]} again; each record is read once")
                continue
            seen[key] = name
            out.append(name)
    return out


def _exists(spec: str) -> bool:
    """Whether `spec` names an existing file or folder (False for a name the system cannot take: the loader says so)."""
    return os.path.isfile(spec) or os.path.isdir(spec)


def _short(spec: str, limit: int = 80) -> str:
    """A file name as an error message shows it: at most `limit` characters."""
    return spec if len(spec) <= limit else f"{spec[: limit // 2]}...{spec[-limit // 2 :]} ({len(spec)} characters)"


def _reason_of(err: Exception) -> str:
    return getattr(err, "strerror", None) or str(err)


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
    spec: str,
    *,
    seed: int = 0,
    dt: float | None = None,
    x_unit: str | None = None,
    force_unit: str | None = None,
    velocity: str = "auto",
    normal_force_column: Sequence[str] | None = None,
    t_unit: str | None = None,
    columns: dict[str, str] | None = None,
    resample: float | None = None,
) -> LoadedRecord:
    """Resolve a record named on the command line: `tribometer:REGIME[:key=value,...]` (keys `seed`, `offset`
    [N] force-cell offset, `drift` [N], `duration` [s]; e.g. `tribometer:mixed:seed=1,offset=0.3`), or a `.npz`
    / `.csv` file (`fj.load_record`: column aliases, units, `dt`), resampled to `resample` [Hz] where given
    (`fj.resample`; its data card keeps the file's `dt_s` and says `resampled_to_hz`)."""
    import pathlib

    from ..._data._tribometer import make_tribometer

    if is_built_in(spec) and spec != "emps":
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
    try:
        is_dir, is_file = path.is_dir(), path.is_file()
    except (OSError, ValueError) as err:  # a name longer than the system takes; a NUL character
        raise CompareError(
            f"{_short(spec)}: not a usable file name ({_reason_of(err)}); name the file by a shorter path"
        ) from None
    if is_dir:
        raise CompareError(f"{spec}: a folder; name its records, e.g. with a quoted glob '{path / '*.npz'}'")
    if not is_file:
        raise CompareError(f"{spec}: no such file (use tribometer:presliding|mixed|sliding, emps, or a .csv / .npz)")
    try:
        with warnings.catch_warnings():  # compare refuses such a load itself, saying how to go on (check_load_leaks)
            warnings.filterwarnings("ignore", message=".*follows the friction force itself")
            full, info = read_record(
                path,
                dt=dt,
                x_unit=x_unit,
                force_unit=force_unit,
                velocity=velocity,
                normal_force_column=None if not normal_force_column else tuple(normal_force_column),
                t_unit=t_unit,
                columns=columns or None,
            )
    except ValueError as err:
        raise CompareError(str(err)) from err
    if not np.ptp(np.asarray(full.force)) > 0:
        raise CompareError(
            f"{spec}: column {info.columns.get('force', 'force')!r} holds one value ({float(full.force[0]):.6g} N) in "
            "every row: no friction to identify or score; check the column"
        )
    card = {
        "source": str(path),
        "samples": full.length,
        "columns": dict(info.columns),
        "ignored": list(info.ignored),
        "units": {"x": info.units.x, "force": info.units.force},
        "units_assumed_si": list(info.assumed_si),
        "dt_s": float(np.asarray(full.motion.dt)),
        "read_with": {"columns": dict(columns) if columns else None, "velocity": velocity, "t_unit": t_unit},
    }
    if resample is not None:
        try:
            full = resample_record(full, resample)
        except ValueError as err:
            raise CompareError(f"{spec}: {err} (`resample`)") from None
        card.update(resampled_to_hz=1.0 / float(np.asarray(full.motion.dt)), samples=full.length)
    return LoadedRecord(spec, full, card, info.units)


def split_record(
    loaded: LoadedRecord, fractions: Sequence[float] | None = None, *, tested_elsewhere: bool = False
) -> Split:
    """The training record's split: `fractions` (TRAIN_END, VALIDATION_END) where given; else 0.8 / 1.0 when the
    models are tested on other records (`tested_elsewhere`), the tribometer's own edges for built-in records, and
    60 / 20 / 20 otherwise."""
    edges, reference = loaded.card.get("split_edges"), loaded.reference
    if fractions is not None:
        train_end, validation_end = fractions
        return Split.fractions(loaded.data, train_end, validation_end, reference)
    if tested_elsewhere:
        return Split.fractions(loaded.data, 0.8, 1.0, reference=reference)
    if edges is not None:
        return Split(loaded.data, int(edges[1]), int(edges[2]), reference)
    return Split.fractions(loaded.data, 0.6, 0.8, reference=reference)


def load_split(spec: str, *, seed: int = 0, **record_options: Any) -> tuple[Split, dict[str, Any], Any]:
    """Resolve `--data` and split it 60 / 20 / 20 (the tribometer's own edges for built-in records);
    `record_options` are `load_record_spec`'s (`dt`, `x_unit`, `force_unit`, `velocity`, `normal_force_column`).
    **Returns:** `(split, data card, true model or None)`."""
    loaded = load_record_spec(spec, seed=seed, **record_options)
    return split_record(loaded), loaded.card, loaded.truth


SPEED_LIMIT = 3.0  # test speeds above this multiple of the training part's are warned of (`statistics_warnings`)


def statistics_warnings(split: Split | TrainingRecords, tests: list[TestRecord], units: Units) -> list[str]:
    """Warnings when a test record's scored part differs sharply from the training part: force spread 3x
    (its NMSE is then normalised by a very different variance), displacement range 10x (the model is
    extrapolated), or speeds (99th percentile of |v|) above `SPEED_LIMIT` times the training part's: the sliding law
    (Stribeck curve, viscous slope) is then extrapolated, and the training record does not determine it there
    (benchmarks/held_out_compare.py: a record at 7x the training speeds, GMS 1.74x the true model's error, 1.00x
    when trained with a record that reaches them)."""
    out = []
    train_force = float(numpy_std(split.train.force))
    train_samples = split.train.motion.samples()
    train_x = float(np.ptp(np.asarray(train_samples.x)))
    train_speed = float(np.percentile(np.abs(np.asarray(train_samples.v)), 99))
    for test in tests:
        force = np.asarray(test.record.force)[test.scored_start :]
        samples = test.record.motion.samples()
        x = np.asarray(samples.x)[test.scored_start :]
        for what, ours, theirs, unit, factor, limit in (
            ("force std", float(numpy_std(force)), train_force, units.force, units.force_factor, 3.0),
            ("displacement range", float(np.ptp(x)), train_x, units.x, units.x_factor, 10.0),
        ):
            if theirs > 0 and ours > 0 and not 1 / limit <= ours / theirs <= limit:
                out.append(
                    f"{test.name}: {what} {ours / factor:.3g} {unit} against {theirs / factor:.3g} {unit} in training "
                    f"({ours / theirs:.2g}x): its scores are not comparable with the training fit's"
                )
        speed = float(np.percentile(np.abs(np.asarray(samples.v)[test.scored_start :]), 99))
        if train_speed > 0 and speed > SPEED_LIMIT * train_speed:
            out.append(
                f"{test.name}: speeds up to {speed / units.x_factor:.3g} {units.v} against "
                f"{train_speed / units.x_factor:.3g} {units.v} in training ({speed / train_speed:.2g}x): the sliding "
                "law (Stribeck curve, viscous slope) is extrapolated there; to predict such speeds, train on a record "
                "that reaches them too (several --data records are fitted together)"
            )
    return out
