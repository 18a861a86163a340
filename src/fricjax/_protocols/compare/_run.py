"""`fricjax compare` from end to end: fit the named models and score them on the test records (`fit_and_score`),
then, from the command line's options, load and split the records, add ensembles, print the table and write the
models, figures and `report.json` (`run_compare`)."""

from __future__ import annotations

import functools
import inspect
import json
import os
import pathlib
import re
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..._data._model_files import save_model
from ..._data._record import FrictionData
from ..._estimation.loop._interrupts import abandonable, check_interrupt
from ..._estimation.loop._placement import check_device, choose_device, forced_device, resolve_device
from ..._estimation.loop._plausibility import half_excursion, implausible
from ..._validation import nonnegative_int
from ..._version import fricjax_version
from ._checks import check_load_leaks, check_records_together, check_test_record, trained_on, unused_load_columns
from ._emps_table import emps_table
from ._ensembles import add_ensembles
from ._figures import plot_prediction_errors, plot_test_loops, plot_test_records
from ._output import (
    Staging,
    check_writable,
    lock_output,
    output_folder,
    releasing_output_locks,
    remove_stale_staging,
    strict_json,
)
from ._plausibility import command_line_advice
from ._records import (
    Split,
    TestRecord,
    TrainingRecords,
    expand_record_specs,
    is_built_in,
    load_record_spec,
    short_labels,
    split_record,
    statistics_warnings,
)
from ._registry import MODEL_NAMES, PHYSICS_MODELS, default_models
from ._report import compare_report, format_record_nuisances, format_table
from ._scoring import (
    ModelScore,
    carries_drift,
    count_parameters,
    free_run,
    predict_test_record,
    reference_scores,
    residual_summary,
    residuals_on,
    rows_on_test,
    score_row,
)
from ._settings import CompareError, DataScales, FitSettings


def fit_and_score(
    names: list[str],
    split: Split | TrainingRecords,
    *,
    tests: list[TestRecord] | None = None,
    settings: FitSettings | None = None,
    seed: int = 0,
    progress: bool = True,
    log: Callable[[str], None] = print,
    device: Any = "auto",
) -> list[ModelScore]:
    """Fit each named model on the train part (the validation part chooses among starts), then score it by
    free-run simulation in exact mode on every test record (default: the split's test part, with the default
    initialisation window). `device` as `fj.fit`'s, for each model's fit and scoring: `"auto"` the host CPU for
    sequential work when the default device is an accelerator (stated in the log), `"cpu"`, `"gpu"`. With several
    training records (`TrainingRecords`) only the physics models can be fitted."""
    settings = FitSettings() if settings is None else settings
    load = split.train.motion.normal_force
    normal_load = None if load is None else float(np.mean(np.abs(np.asarray(load))))
    if normal_load is not None:
        log(
            f"the records hold the normal load (mean {normal_load:.4g} N): physics models scale with it (fj.NormalLoad)"
        )
    specs = default_models(settings, several=split.several, normal_load=normal_load)
    if split.several:
        others = [name for name in names if name not in PHYSICS_MODELS]
        if others:
            raise CompareError(
                f"--models {' '.join(others)}: several training records are fitted by the physics models "
                f"({', '.join(PHYSICS_MODELS)}); fit the others on one --data record"
            )
    if tests is None:
        if not isinstance(split, Split):
            raise CompareError("several training records: name the records to test on (--test)")
        tests = [split.test_record()]
    tests = list(tests)
    scales = DataScales.from_data(split.train_records)  # several: each read on its own start, the readings pooled
    rows = []
    for name in names:
        check_interrupt()  # SIGINT / SIGTERM under `fricjax compare` stop the run here (a no-op elsewhere)
        spec = specs[name]
        start_time = time.perf_counter()
        start = None if spec.build is None else spec.build(scales)
        target, reason = choose_device(start, split.train, device, batched=False)
        label = spec.label_for(start)
        log(f"fitting {label} ..." if target is None else f"fitting {label} on {target.platform} ({reason}) ...")
        with forced_device(target):
            row = _fit_and_score_one(name, spec, start, split, tests, seed, progress, start_time, settings)
        rows.append(row)
        log(f"  {row.label}: test NMSE {row.nmse:.3f} %, MAX {row.max_error:.3f}, {row.fit_time:.1f} s: {row.message}")
    return rows


def _fit_and_score_one(
    name: str,
    spec: Any,
    start: Any,
    split: Split | TrainingRecords,
    tests: list[TestRecord],
    seed: int,
    progress: bool,
    t0: float,
    settings: FitSettings,
) -> ModelScore:
    """`fit_and_score` for one model: fit `start` (None: identified from the split), then score it: on the
    training record's own test part by the free run from its start (its history and drift), on other records as
    `settings.init` and `settings.test_drift` say (`predict_test_record`)."""
    result = spec.fit(start, split, seed, progress)
    elapsed = time.perf_counter() - t0
    model = result.model
    label = spec.label_for(model)
    full_prediction = None if split.several else free_run(model, split.full)
    carried = not split.several and getattr(model, "drifts", False)
    carried = carried and any(carries_drift(t, settings.test_drift) for t in tests if t.record is not split.full)
    # the training record's force range without the drift, once per model: a carried drift is scaled by it
    training_range = float(np.ptp(free_run(model.without_drift(), split.full))) if carried else None
    predictions = {
        test.name: full_prediction
        if full_prediction is not None and test.record is split.full
        else predict_test_record(model, test, settings.init, settings.test_drift, training_range)
        for test in tests
    }
    notes = implausible(model, _largest_excursion(split))
    # "successful" is the solver's verdict on steps that were not kept; a network's NOE stage that does not improve on
    # its least-squares start is the recipe working (its message says so), a physics fit's is worth a note
    if name in PHYSICS_MODELS and getattr(result, "start_kept", False):
        notes.append("no fit step improved on its start's validation loss: the start is reported")
    return score_row(
        name,
        label,
        model,
        full_prediction,
        predictions,
        split,
        tests,
        fit_time=elapsed,
        num_parameters=count_parameters(model),
        result=result.code,  # the name of the fj.RESULTS item
        message="; ".join([command_line_advice(result.message), *notes]),
        notes=tuple(notes),
        std=result.std,
        validation_nmse=100 * result.val_loss if split.several else None,
        records=result.records,
    )


# run_compare's arguments that `--data emps` does not take (its inverse dynamic model has its own records, split and
# laws); each is the command line's `--NAME` with dashes, `split_at` its `--split`
_NOT_FOR_EMPS = (
    "test", "validation", "split_at", "init_window", "models", "steps", "gms_elements", "maxwell_elements", "starts",
    "drift", "neural_steps", "dt", "x_unit", "force_unit", "t_unit", "columns", "velocity", "normal_force_column",
    "accept_correlated_load", "init",
    "test_drift",
    "seed",
)  # fmt: skip


def _check_emps_options(arguments: dict[str, Any]) -> None:
    """`--data emps` with an option it would ignore: one line naming the options (a run that silently ignored
    `--models` or `--test` would print a table the user did not ask for)."""
    defaults = inspect.signature(run_compare).parameters
    given = []
    for name in _NOT_FOR_EMPS:
        value, default = arguments[name], defaults[name].default
        if name == "models":
            value, default = [m.lower() for m in value], list(default)
        elif isinstance(value, (list, tuple, dict)) and not value:
            value = None
        if value != default:
            flag = {"split_at": "--split", "columns": "--t-column / --x-column / --v-column / --force-column"}.get(name)
            given.append(flag or "--" + name.replace("_", "-"))
    if given:
        raise CompareError(
            f"--data emps runs the EMPS table (the benchmark's own records, split and friction laws) and takes none "
            f"of {', '.join(given)}: drop them, or run compare on a record file (--data FILE)"
        )


def _timing(record: FrictionData) -> str:
    """A record's sample rate and duration, as the run's header says them: `1024 Hz, 40 s`."""
    dt = float(np.asarray(record.motion.dt).reshape(-1)[0])
    return f"{1 / dt:.4g} Hz, {record.length * dt:.4g} s"


def _largest_excursion(split: Split | TrainingRecords) -> float | None:
    """Half the largest displacement swing between two reversals [m] over the training records, each on its own."""
    swings = [h for h in (half_excursion(r.motion) for r in split.train_records) if h is not None]
    return max(swings) if swings else None


@releasing_output_locks
def run_compare(
    *,
    data: str | Sequence[str] = "tribometer:mixed",
    test: Sequence[str] | None = None,
    validation: Sequence[str] | None = None,
    split_at: Sequence[float] | None = None,
    init_window: int | None = None,
    models: Sequence[str] = PHYSICS_MODELS,
    steps: int = 40,
    gms_elements: int | str = "auto",
    maxwell_elements: int = 5,
    starts: int = 2,
    drift: str = "auto",
    neural_steps: int = 600,
    dt: float | None = None,
    x_unit: str | None = None,
    force_unit: str | None = None,
    t_unit: str | None = None,
    columns: dict[str, str] | None = None,
    velocity: str = "auto",
    normal_force_column: Sequence[str] | None = None,
    accept_correlated_load: bool = False,
    init: str = "state",
    test_drift: str = "auto",
    out: str | os.PathLike[str] = "fricjax-compare",
    seed: int = 0,
    progress: bool = True,
    device: str = "auto",
) -> None:
    """`fricjax compare` with the command line's options as arguments (`fricjax compare --help` says what each
    does): fit every model on the training record `data` (or several records: a list, file globs allowed; each
    record's last 20 % or the `validation` records choose among starts, and each record gets its own offset,
    initial state and drift), score each by free run on the test records (`test`, or the record's own test part),
    add ensembles (one training record), print the table, and write the models, the figures and `report.json` to
    `out`. `data="emps"`: the EMPS table instead (`emps_table`). Files are staged in a folder
    inside `out` and published together (`Staging`: all or none of them); staging folders of killed runs are
    removed first; one run at a time writes to `out` (`lock_output`: a second fails at once, naming the first).
    Under the command line's signal handlers (`stop_on_signals`), SIGINT / SIGTERM stop the run at the next check:
    between models, within fits, before the ensembles and before each file is written.

    **Raises:** `CompareError` for bad input or a failed write (one line); `Interrupted` after SIGINT / SIGTERM
    (nothing written to `out`).
    """
    arguments = dict(locals())
    try:
        check_device(device, "--device")
        target = None if device == "auto" else resolve_device(device)
    except ValueError as error:
        raise CompareError(str(error)) from None
    if target is not None:  # everything on `target`: data, fits, scores, ensembles
        with forced_device(target):
            return run_compare(**{**arguments, "device": "auto"})
    out = output_folder(out)
    models = list(dict.fromkeys(m.lower() for m in models))  # case-insensitive, each once
    if models == ["all"]:
        models = list(MODEL_NAMES)
    unknown = [m for m in models if m not in MODEL_NAMES]
    if unknown:
        raise CompareError(f"--models: unknown model {unknown[0]!r}; choose from {', '.join(MODEL_NAMES)}")
    if init_window is not None:  # None: the option not given
        try:
            init_window = nonnegative_int(init_window, "--init-window", "", hint="(samples)")
        except ValueError as error:
            raise CompareError(str(error)) from None
    if velocity not in ("auto", "file", "derive"):
        raise CompareError(f"--velocity must be auto, file or derive, got {velocity!r}")
    data_specs = expand_record_specs([data] if isinstance(data, str) else list(data), "--data")
    validation_specs = expand_record_specs(list(validation or []), "--validation")
    if not data_specs:
        raise CompareError("--data: name at least one training record")
    several = len(data_specs) > 1 or bool(validation_specs)
    if "emps" in data_specs and len(data_specs) > 1:
        raise CompareError("--data emps runs the EMPS table on its own; give it alone")
    if data_specs == ["emps"]:
        _check_emps_options(arguments)
    elif all(is_built_in(spec) for spec in [*data_specs, *validation_specs, *list(test or [])]):
        file_options: dict[str, Any] = {"--dt": dt, "--x-unit": x_unit, "--force-unit": force_unit, "--t-unit": t_unit}
        file_options["--velocity"] = None if velocity == "auto" else velocity
        file_options["--t-column / --x-column / --v-column / --force-column"] = columns or None
        file_options["--normal-force-column"] = normal_force_column or None
        named = [name for name, value in file_options.items() if value is not None]
        if named:
            raise CompareError(
                f"{', '.join(named)} {'describes' if len(named) == 1 else 'describe'} record files, and every record "
                "here is built in: drop "
                f"{'it' if len(named) == 1 else 'them'}, or name a file (--data FILE.csv)"
            )
    settings = FitSettings(
        steps=steps,
        gms_elements=gms_elements,
        maxwell_elements=maxwell_elements,
        starts=starts,
        drift=drift if drift != "auto" else ("none" if several else "linear"),
        neural_steps=neural_steps,
        init=init,
        test_drift=test_drift,
    )
    # --drift auto: a linear drift with one training record, none with several (fitted per record on the damper's
    # characterization tests, the drifts made DNLRX's held-out NMSE 10x worse and changed nothing for the others)
    if test_drift == "carry" and (several or settings.drift == "none"):
        raise CompareError(
            "--test-drift carry carries the drift fitted with one training record; "
            + ("with several --data records each keeps its own" if several else "--drift none fits none")
            + ": use --test-drift window or none"
        )
    data = data_specs[0] if not several else " ".join(data_specs)
    expected = [_figure(stem, k) for k in range(len(test or ()) + 1) for stem in FIGURES]
    check_writable(out, ("report.json",) if data == "emps" else (*expected, "test_records.png", "report.json"))
    lock_output(out)  # until this run ends: a second run into `out` fails here, at once, naming this one
    remove_stale_staging(out)
    if data == "emps":
        emps_table(out)
        return
    units_kw: dict[str, Any] = {
        "dt": dt,
        "x_unit": x_unit,
        "force_unit": force_unit,
        "t_unit": t_unit,
        "columns": columns,
        "velocity": velocity,
        "normal_force_column": normal_force_column,
    }
    test_specs = expand_record_specs(list(test or []), "--test")
    if several:
        trainings = [load_record_spec(spec, seed=seed, **units_kw) for spec in data_specs]
        validations = [load_record_spec(spec, seed=seed, **units_kw) for spec in validation_specs]
        fitted_on = [*trainings, *validations]
        check_records_together(fitted_on)
        training, training_cards = trainings[0], [t.card for t in trainings]
        split: Split | TrainingRecords = TrainingRecords.build(
            trainings, validations, None if split_at is None else split_at[0]
        )
        if not test_specs:
            given = "several --data records" if len(data_specs) > 1 else "--validation records"
            raise CompareError(f"{given}: name the records to test on with --test")
    else:
        training, training_cards = load_record_spec(data, seed=seed, **units_kw), None
        fitted_on = [training]
        split = split_record(training, split_at, tested_elsewhere=bool(test_specs))
    tests: list[TestRecord] = []
    cards: dict[str, Any] = {}  # the data cards of the other test records, by test name
    if isinstance(split, Split) and split.validation_end < training.data.length:
        tests.append(split.test_record(init_window))  # the split carries the record's noise-free reading
    for spec in test_specs:
        loaded = load_record_spec(spec, seed=seed, **units_kw)
        name = loaded.name if loaded.name not in {t.name for t in tests} else f"{loaded.name} #{len(tests) + 1}"
        tests.append(TestRecord.whole(loaded, init_window, name))
        cards[name] = loaded.card
    if not tests:
        raise CompareError("nothing to test on: the split leaves no test part; pass --test records")
    for t in tests:
        check_test_record(t, settings.init)
    for label, motion in [(r.name, r.data.motion) for r in fitted_on] + [(t.name, t.record.motion) for t in tests]:
        if motion.normal_force is not None and not np.any(np.asarray(motion.normal_force)):
            raise CompareError(
                f"{label}: its normal load is 0 N in every row, so a load-scaled model predicts no force; check "
                "the load column and its unit, or name another with --normal-force-column"
            )
    if not accept_correlated_load:
        check_load_leaks([(r.name, r.data) for r in fitted_on] + [(t.name, t.record) for t in tests])
    if split.train.motion.normal_force is not None:
        for t in tests:
            if t.record.motion.normal_force is None:
                raise CompareError(
                    f"{t.name}: no normal load, but the training records hold one and the models scale with it; "
                    "give it a normal_force column or name it with --normal-force-column"
                )
    units = training.units
    if isinstance(split, TrainingRecords):
        names = short_labels([*split.names, *split.validation_names, *(t.name for t in tests)])
        parts = [
            f"{name} ({_timing(record)}: {end} train, {record.length - end} validation)"
            for name, end, record in zip(names[: len(split.names)], split.train_ends, split.records, strict=True)
        ]
        if split.validation:
            parts.append("validation: " + ", ".join(names[len(split.names) : len(split.names) + len(split.validation)]))
        count = len(split.records)
        described = f"{count} training record{'s' if count != 1 else ''}: " + "; ".join(parts)
    else:
        described = (
            f"{data}, {split.full.length} samples at {_timing(split.full)} (train {split.train_end}, "
            f"validation {split.validation_end - split.train_end})"
        )
    if isinstance(split, TrainingRecords):  # each record by the shortest name that keeps them apart, not its full path
        labels = short_labels([*split.names, *split.validation_names, *(t.name for t in tests)])[-len(tests) :]
    else:
        labels = short_labels([t.name for t in tests])
    print(
        f"fricjax {fricjax_version()} compare: {described}; test: "
        + "; ".join(
            f"{label} ({t.record.length - t.scored_start} scored after a {t.init_window}-sample initialisation window)"
            for label, t in zip(labels, tests, strict=True)
        )
        + f"; models: {', '.join(models)}"
    )
    unused_loads = unused_load_columns(split, training_cards or [training.card])
    not_held_out = trained_on(data_specs, test_specs, validation_specs)
    for line in [*not_held_out, *unused_loads, *statistics_warnings(split, tests, units)]:
        print("warning: " + line)
    for card in [*(training_cards or [training.card]), *cards.values()]:
        if card.get("units_assumed_si"):
            quantities = " and ".join(
                {"x": "displacement (m)", "force": "force (N)"}[q] for q in card["units_assumed_si"]
            )
            print(
                f"note: {card['source']} gives no unit for its {quantities}: read as SI; if it is not, write the "
                "unit in the header (`x [mm]`, `force [kN]`) or pass --x-unit / --force-unit"
            )
    started = time.perf_counter()
    # nothing is written until the files are staged: a signal that a long compiled call keeps the run from acting on
    # within seconds ends the process there (module _interrupts, `abandonable`)
    with abandonable(f"fricjax compare: interrupted; nothing was written to {out}"):
        rows = fit_and_score(
            list(models), split, tests=tests, settings=settings, seed=seed, progress=progress, device=device
        )
        check_interrupt()
        if isinstance(split, Split):
            rows += add_ensembles(rows, split, tests)
        else:
            print("ensembles: not formed with several training records (their weights come from one validation part)")
        floor = reference_scores(tests)
    print()
    print(format_table(rows, floor))
    if isinstance(split, TrainingRecords):
        print(format_record_nuisances(rows, units))
    residuals = {row.name: residuals_on(tests[0], row.prediction) for row in rows}
    print(f"\nresiduals on {short_labels([t.name for t in tests])[0]} (its scored part; the 99 % band; v the input):")
    for row in rows:
        print(f"  {row.label}: {residual_summary(residuals[row.name])['verdict']}")
    try:
        staging = Staging(out)  # the files are written there, then moved into `out` together (or not at all)
    except OSError as err:
        raise CompareError(f"--out {out}: could not create a staging folder ({err.strerror})") from None
    with staging:
        for row in rows:
            staging.write(f"models/{row.name}.eqx", functools.partial(save_model, model=row.model))
        labels = short_labels([t.name for t in tests])
        figures = []
        for k, (record, label) in enumerate(zip(tests, labels, strict=True)):
            scored = rows if k == 0 else rows_on_test(rows, record)
            for stem, plot in zip(FIGURES, (plot_prediction_errors, plot_test_loops), strict=True):
                name = _figure(stem, k)
                staging.write(name, functools.partial(plot, scored, record, units=units, label=label))
                figures.append(name)
        if len(tests) > 1:
            staging.write("test_records.png", functools.partial(plot_test_records, rows, labels))
            figures.append("test_records.png")
        report = compare_report(
            data=data,
            seed=seed,
            training=training,
            split=split,
            tests=tests,
            cards=cards,
            floor=floor,
            settings=settings,
            rows=rows,
            started=started,
            training_cards=training_cards,
        )
        report["figures"] = figures
        report["residuals"] = {name: residual_summary(r) for name, r in residuals.items()}
        staging.write("report.json", lambda path: path.write_text(strict_json(report)))  # the report last
        earlier = _earlier_figures(out)
        staging.publish()
    _remove_stale_figures(out, earlier, figures)
    shown = (
        f"{out / 'test_errors.png'}, {out / 'hysteresis_loops.png'}"
        if len(tests) == 1
        else f"{out}/test_errors[_K].png and hysteresis_loops[_K].png for test records 1-{len(tests)} (no _K: record "
        f"1, {labels[0]}), {out / 'test_records.png'} (each model's NMSE on each)"
    )
    print(
        f"\nreport: {out / 'report.json'}; figures: {shown}; models: {out / 'models'} "
        f"({time.perf_counter() - started:.0f} s)"
    )


FIGURES = ("test_errors", "hysteresis_loops")  # each test record's figures: NAME.png for the first, NAME_K.png
_FIGURE_NAME = re.compile(r"(test_errors|hysteresis_loops)(_([2-9]|[1-9][0-9]+))?\.png|test_records\.png")


def _earlier_figures(out: pathlib.Path) -> list[str]:
    """The figures an earlier run's `report.json` in `out` lists (none where there is no readable report)."""
    try:
        listed = json.loads((out / "report.json").read_text()).get("figures", [])
    except (OSError, ValueError, AttributeError, RecursionError):
        return []
    if not isinstance(listed, list):
        return []
    return [name for name in listed if isinstance(name, str) and _FIGURE_NAME.fullmatch(name)]


def _remove_stale_figures(out: pathlib.Path, earlier: list[str], figures: list[str]) -> None:
    """Remove the figures of an earlier run that this one did not draw (a run with fewer test records): only files
    the earlier run's own report listed, by compare's figure names, so that no file of the user's is touched. After
    publishing: a run stopped in between leaves them, as before."""
    for name in sorted(set(earlier) - set(figures)):
        try:
            (out / name).unlink(missing_ok=True)
        except OSError:
            pass  # a figure that cannot be removed is left, as it was


def _figure(stem: str, k: int) -> str:
    """The file of figure `stem` for test record `k` (from 0): the first record's keep their names."""
    return f"{stem}.png" if k == 0 else f"{stem}_{k + 1}.png"
