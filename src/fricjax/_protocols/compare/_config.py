"""What a `compare` run is given (`CompareConfig`, validated when it is made) and the records it names, loaded,
checked and split (`CompareRecords`). Errors name the configuration's fields in backticks (`` `init_window` ``); the
command line shows them as its flags (`as_flags`: `--init-window`)."""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._estimation.loop._placement import check_device
from ..._validation import nonnegative_int
from ._checks import check_load_leaks, check_records_together, check_test_record
from ._records import (
    LoadedRecord,
    Split,
    TestRecord,
    TrainingRecords,
    expand_record_specs,
    is_built_in,
    load_record_spec,
    split_record,
)
from ._registry import MODEL_NAMES, PHYSICS_MODELS
from ._settings import CompareError, FitSettings

# each field of `CompareConfig` as the command line spells it
FLAGS = {
    "data": "--data",
    "test": "--test",
    "validation": "--validation",
    "split_at": "--split",
    "init_window": "--init-window",
    "models": "--models",
    "steps": "--steps",
    "gms_elements": "--gms-elements",
    "maxwell_elements": "--maxwell-elements",
    "starts": "--starts",
    "drift": "--drift",
    "neural_steps": "--neural-steps",
    "dt": "--dt",
    "x_unit": "--x-unit",
    "force_unit": "--force-unit",
    "t_unit": "--t-unit",
    "columns": "--t-column / --x-column / --v-column / --force-column",
    "resample": "--resample",
    "velocity": "--velocity",
    "normal_force_column": "--normal-force-column",
    "accept_correlated_load": "--accept-correlated-load",
    "init": "--init",
    "test_drift": "--test-drift",
    "fix": "--fix",
    "bounds": "--bounds",
    "out": "--out",
    "seed": "--seed",
    "progress": "--no-progress",
    "device": "--device",
}

_FIELD = re.compile(r"`([a-z_]+)`")


def as_flags(message: str) -> str:
    """A library message with each field of `CompareConfig` (`` `init_window` ``) named by its flag (--init-window)."""
    return _FIELD.sub(lambda match: FLAGS.get(match.group(1), match.group(0)), message)


# the fields `data="emps"` (the EMPS table: its own records, split and laws) takes none of
_NOT_FOR_EMPS = (
    "test", "validation", "split_at", "init_window", "models", "steps", "gms_elements", "maxwell_elements", "starts",
    "drift", "neural_steps", "dt", "x_unit", "force_unit", "t_unit", "columns", "velocity", "normal_force_column",
    "accept_correlated_load", "init", "test_drift", "seed", "fix", "bounds", "resample",
)  # fmt: skip
# the fields that describe record files (given with built-in records only, they would be ignored)
_FILE_FIELDS = ("dt", "x_unit", "force_unit", "t_unit", "velocity", "columns", "normal_force_column", "resample")


def _strings(value: Any, field: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, (str, os.PathLike)):
        return (os.fspath(value),)
    try:
        return tuple(os.fspath(item) for item in value)
    except TypeError:
        raise CompareError(f"`{field}`: a record name or a list of them, got {type(value).__name__}") from None


@dataclasses.dataclass(frozen=True)
class CompareConfig:
    """A `compare` run: the records, the models, their budgets, how test records are started, where the output goes
    (each field is the command line's option of that name: `fricjax compare --help`). Validated when made: a bad
    value raises `CompareError` naming the field.

    - `data`: training record(s): a built-in name (`tribometer:mixed`, `emps`), files or globs; `validation`: whole
      records that choose among starts (several records); `test`: records scored by free run; `split_at`: the
      training record's (TRAIN_END, VALIDATION_END) fractions.
    - `models`: model names (`all`: every one); `steps`, `gms_elements`, `maxwell_elements`, `starts`, `drift`,
      `neural_steps`: budgets and sizes (`FitSettings`); `init`, `test_drift`, `init_window`: how a model starts on
      a test record.
    - `fix` ({name: value}, SI units) and `bounds` ({name: (low, high)}): parameters of the physics models held at a
      value or kept in an interval (`name`: a field or the end of a dotted path, `sigma2`, `stribeck.vs`; every
      physics model that has it).
    - `dt`, `x_unit`, `force_unit`, `t_unit`, `columns` ({role: column name}), `velocity`, `normal_force_column`:
      how record files are read; `resample` [Hz]: every file record resampled to that rate (`fj.resample`);
      `accept_correlated_load`: keep a load column that follows the force.
    - `out`: the output folder; `seed`; `progress`: progress bars; `device`: `auto`, `cpu` or `gpu`.
    """

    data: Sequence[str] | str = ("tribometer:mixed",)
    test: Sequence[str] | None = ()
    validation: Sequence[str] | None = ()
    split_at: Sequence[float] | None = None
    init_window: int | None = None
    models: Sequence[str] = PHYSICS_MODELS
    steps: int = 40
    gms_elements: int | str = "auto"
    maxwell_elements: int = 5
    starts: int = 2
    drift: str = "auto"
    neural_steps: int = 600
    dt: float | None = None
    x_unit: str | None = None
    force_unit: str | None = None
    t_unit: str | None = None
    columns: dict[str, str] | None = None
    resample: float | None = None
    velocity: str = "auto"
    normal_force_column: Sequence[str] | None = None
    accept_correlated_load: bool = False
    init: str = "state"
    test_drift: str = "auto"
    fix: dict[str, float] | None = None
    bounds: dict[str, tuple[float, float]] | None = None
    out: str | os.PathLike[str] = "fricjax-compare"
    seed: int = 0
    progress: bool = True
    device: Any = "auto"

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        for name in ("data", "test", "validation"):
            put(name, _strings(getattr(self, name), name))
        if self.split_at is not None:
            put("split_at", tuple(self.split_at))
        if self.normal_force_column is not None:
            put("normal_force_column", tuple(self.normal_force_column) or None)
        put("columns", dict(self.columns) if self.columns else None)
        put("fix", dict(self.fix) if self.fix else None)
        put("bounds", dict(self.bounds) if self.bounds else None)
        for name, interval in (self.bounds or {}).items():
            if np.shape(interval) != (2,):
                raise CompareError(f"`bounds` {name}: give (low, high), got {interval!r}")
        models = tuple(dict.fromkeys(str(m).lower() for m in self.models))  # case-insensitive, each once
        put("models", tuple(MODEL_NAMES) if models == ("all",) else models)
        unknown = [m for m in self.models if m not in MODEL_NAMES]
        if unknown:
            raise CompareError(f"`models`: unknown model {unknown[0]!r}; choose from {', '.join(MODEL_NAMES)}")
        try:
            check_device(self.device, "`device`")
            if self.init_window is not None:  # None: the default window
                put("init_window", nonnegative_int(self.init_window, "init_window", "", hint="(samples)"))
        except ValueError as error:
            raise CompareError(str(error)) from None
        if self.velocity not in ("auto", "file", "derive"):
            raise CompareError(f"`velocity` must be auto, file or derive, got {self.velocity!r}")
        if not str(os.fspath(self.out)).strip():
            raise CompareError("`out`: an empty name; give a folder (created if missing), or `out` . for this one")
        if not self.data:
            raise CompareError("`data`: name at least one training record")
        if "emps" in self.data:
            self._check_emps()
        elif all(is_built_in(spec) for spec in (*self.data, *self.validation, *self.test)):  # type: ignore[misc]
            named = [f"`{name}`" for name in _FILE_FIELDS if getattr(self, name) not in (None, "auto")]
            if named:
                it = "it" if len(named) == 1 else "them"
                raise CompareError(
                    f"{', '.join(named)} {'describes' if len(named) == 1 else 'describe'} record files, and every "
                    f"record here is built in: drop {it}, or name a file (`data` FILE.csv)"
                )
        self.settings(several=len(self.data) > 1 or bool(self.validation))  # the budgets and sizes, checked

    def _check_emps(self) -> None:
        """`data="emps"` alone, and without a field it would ignore (a run that silently ignored `models` or `test`
        would print a table the user did not ask for)."""
        if len(self.data) > 1:
            raise CompareError("`data` emps runs the EMPS table on its own; give it alone")
        defaults = {field.name: field.default for field in dataclasses.fields(CompareConfig)}
        defaults.update(data=(), test=(), validation=(), models=PHYSICS_MODELS)
        given = [f"`{name}`" for name in _NOT_FOR_EMPS if getattr(self, name) not in (defaults[name], None)]
        if given:
            raise CompareError(
                f"`data` emps runs the EMPS table (the benchmark's own records, split and friction laws) and takes "
                f"none of {', '.join(given)}: drop them, or run compare on a record file (`data` FILE)"
            )

    def settings(self, several: bool) -> FitSettings:
        """The fits' budgets and sizes; `several`: several training records (`drift="auto"`: none then, a linear
        drift with one record: fitted per record on the damper's characterization tests, the drifts made DNLRX's
        held-out NMSE 10x worse and changed nothing for the others)."""
        settings = FitSettings(
            steps=self.steps,
            gms_elements=self.gms_elements,
            maxwell_elements=self.maxwell_elements,
            starts=self.starts,
            drift=self.drift if self.drift != "auto" else ("none" if several else "linear"),
            neural_steps=self.neural_steps,
            init=self.init,
            test_drift=self.test_drift,
            fix=tuple((self.fix or {}).items()),
            bounds=tuple((name, *interval) for name, interval in (self.bounds or {}).items()),
        )
        if self.test_drift == "carry" and (several or settings.drift == "none"):
            raise CompareError(
                "`test_drift` carry carries the drift fitted with one training record; "
                + ("with several `data` records each keeps its own" if several else "`drift` none fits none")
                + ": use `test_drift` window or none"
            )
        return settings

    @property
    def record_options(self) -> dict[str, Any]:
        """How record files are read (`load_record_spec`'s keywords)."""
        return {name: getattr(self, name) for name in _FILE_FIELDS}


@dataclasses.dataclass(frozen=True)
class CompareRecords:
    """The records of a run, loaded and checked: `split` the training record(s) with their validation parts, `tests`
    the test records, `training` the first training record (its units label the output), `fitted_on` every record
    the fits see, `training_cards` the data cards of several training records (None with one), `cards` those of
    the named test records by test name, `data` the training records as the report names them, `specs` the
    expanded names (`data`, `validation`, `test`)."""

    split: Split | TrainingRecords
    tests: list[TestRecord]
    training: LoadedRecord
    fitted_on: list[LoadedRecord]
    training_cards: list[Any] | None
    cards: dict[str, Any]
    data: str
    specs: dict[str, list[str]]
    settings: FitSettings

    @property
    def several(self) -> bool:
        return isinstance(self.split, TrainingRecords)


def expanded_specs(config: CompareConfig) -> dict[str, list[str]]:
    """The record names of `data`, `validation` and `test`, globs expanded (each record once)."""
    return {
        name: expand_record_specs(list(getattr(config, name)), f"`{name}`") for name in ("data", "validation", "test")
    }


def load_records(config: CompareConfig, specs: dict[str, list[str]]) -> CompareRecords:
    """Load, check and split the records `specs` names (`expanded_specs`); one `CompareError` line for a record that
    cannot be used, naming it and the fix, before any fit."""
    data_specs, validation_specs, test_specs = specs["data"], specs["validation"], specs["test"]
    several = len(data_specs) > 1 or bool(validation_specs)
    settings = config.settings(several)
    options = config.record_options
    split: Split | TrainingRecords
    if several:
        trainings = [load_record_spec(spec, seed=config.seed, **options) for spec in data_specs]
        validations = [load_record_spec(spec, seed=config.seed, **options) for spec in validation_specs]
        fitted_on = [*trainings, *validations]
        check_records_together(fitted_on)
        training, training_cards = trainings[0], [t.card for t in trainings]
        split = TrainingRecords.build(trainings, validations, None if config.split_at is None else config.split_at[0])
        if not test_specs:
            given = "several `data` records" if len(data_specs) > 1 else "`validation` records"
            raise CompareError(f"{given}: name the records to test on with `test`")
        data = " ".join(data_specs)
    else:
        (data,) = data_specs
        training, training_cards = load_record_spec(data, seed=config.seed, **options), None
        fitted_on = [training]
        split = split_record(training, config.split_at, tested_elsewhere=bool(test_specs))
    tests: list[TestRecord] = []
    cards: dict[str, Any] = {}  # the data cards of the other test records, by test name
    if isinstance(split, Split) and split.validation_end < training.data.length:
        tests.append(split.test_record(config.init_window))  # the split carries the record's noise-free reading
    for spec in test_specs:
        loaded = load_record_spec(spec, seed=config.seed, **options)
        name = loaded.name if loaded.name not in {t.name for t in tests} else f"{loaded.name} #{len(tests) + 1}"
        tests.append(TestRecord.whole(loaded, config.init_window, name))
        cards[name] = loaded.card
    if not tests:
        raise CompareError("nothing to test on: the split leaves no test part; pass `test` records")
    for t in tests:
        check_test_record(t, settings.init)
    for label, motion in [(r.name, r.data.motion) for r in fitted_on] + [(t.name, t.record.motion) for t in tests]:
        if motion.normal_force is not None and not np.any(np.asarray(motion.normal_force)):
            raise CompareError(
                f"{label}: its normal load is 0 N in every row, so a load-scaled model predicts no force; check "
                "the load column and its unit, or name another (`normal_force_column`)"
            )
    if not config.accept_correlated_load:
        check_load_leaks([(r.name, r.data) for r in fitted_on] + [(t.name, t.record) for t in tests])
    if split.train.motion.normal_force is not None:
        for t in tests:
            if t.record.motion.normal_force is None:
                raise CompareError(
                    f"{t.name}: no normal load, but the training records hold one and the models scale with it; "
                    "give it a normal_force column or name it (`normal_force_column`)"
                )
    return CompareRecords(split, tests, training, fitted_on, training_cards, cards, data, specs, settings)
