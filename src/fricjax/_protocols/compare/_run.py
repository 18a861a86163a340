"""`fricjax compare` from end to end: fit the named models and score them on the test records (`fit_and_score`),
then, from the command line's options, load and split the records, add ensembles, print the table and write the
models, figures and `report.json` (`run_compare`)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..._constraints import parameter_arrays, unwrap
from ..._data._record import FrictionData
from ..._estimation.loop._interrupts import abandonable, check_interrupt
from ..._estimation.loop._placement import choose_device, forced_device, resolve_device
from ..._estimation.loop._plausibility import half_excursion, implausible, poorly_determined
from ..._version import fricjax_version
from ._checks import trained_on, unused_load_columns
from ._config import CompareConfig, CompareRecords, expanded_specs, load_records
from ._emps_table import emps_table
from ._ensembles import add_ensembles
from ._output import (
    check_writable,
    lock_output,
    output_folder,
    releasing_output_locks,
    remove_stale_staging,
)
from ._plausibility import command_line_advice
from ._recipes import matching_paths
from ._records import (
    Split,
    TestRecord,
    TrainingRecords,
    short_labels,
    statistics_warnings,
)
from ._registry import PHYSICS_MODELS, default_models
from ._report import FIGURES, Report, figure_name
from ._scoring import (
    ModelScore,
    carries_drift,
    count_parameters,
    free_run,
    predict_test_record,
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
                f"`models` {' '.join(others)}: several training records are fitted by the physics models "
                f"({', '.join(PHYSICS_MODELS)}); fit the others on one `data` record"
            )
    if tests is None:
        if not isinstance(split, Split):
            raise CompareError("several training records: name the records to test on (`test`)")
        tests = [split.test_record()]
    tests = list(tests)
    scales = DataScales.from_data(split.train_records)  # several: each read on its own start, the readings pooled
    builders = {name: specs[name].build for name in names}
    starts = {name: None if build is None else build(scales) for name, build in builders.items()}
    _check_constrained_names(settings, starts)
    rows = []
    for name in names:
        check_interrupt()  # SIGINT / SIGTERM under `fricjax compare` stop the run here (a no-op elsewhere)
        spec = specs[name]
        start_time = time.perf_counter()
        start = starts[name]
        target, reason = choose_device(start, split.train, device, batched=False)
        label = spec.label_for(start)
        log(f"fitting {label} ..." if target is None else f"fitting {label} on {target.platform} ({reason}) ...")
        with forced_device(target):
            row = _fit_and_score_one(name, spec, start, split, tests, seed, progress, start_time, settings)
        rows.append(row)
        log(f"  {row.label}: test NMSE {row.nmse:.3f} %, MAX {row.max_error:.3f}, {row.fit_time:.1f} s: {row.message}")
    return rows


def _check_constrained_names(settings: FitSettings, starts: dict[str, Any]) -> None:
    """Each parameter `settings.fix` / `settings.bounds` names is a parameter of a physics model fitted here."""
    physics = [start for name, start in starts.items() if name in PHYSICS_MODELS and start is not None]
    for field, names in (("fix", [n for n, _ in settings.fix]), ("bounds", [n for n, *_ in settings.bounds])):
        unknown = [n for n in names if not any(matching_paths(start, n) for start in physics)]
        if unknown:
            known = sorted({p.split(".")[-1] for start in physics for p in parameter_arrays(unwrap(start))})
            raise CompareError(
                f"`{field}` {unknown[0]}: no physics model fitted here has such a parameter; theirs: {', '.join(known)}"
            )


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
    states: dict[str, Any] = {}  # each test record's initial state, where its window estimated one
    predictions = {
        test.name: full_prediction
        if full_prediction is not None and test.record is split.full
        else predict_test_record(model, test, settings.init, settings.test_drift, training_range, states)
        for test in tests
    }
    notes = implausible(model, _largest_excursion(split))
    if name in PHYSICS_MODELS:  # a network's weights or a regression's coefficients are not read one by one
        notes += poorly_determined(model, result.std)
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
        test_states=states,
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
def run_compare(config: CompareConfig | None = None, /, **fields: Any) -> Report | None:
    """`fricjax compare` as a function: `config` a `CompareConfig` (or its fields as keywords; with both, the keywords
    replace its fields). Load and check the records it names (`load_records`), fit every model on the training
    record(s) (each record's last 20 % or the `validation` records choose among starts; each record gets its own
    offset, initial state and drift), score each by free run on the test records, add ensembles (one training
    record), print the table and write the `Report` (models, figures, `report.json`) to `config.out`. `data="emps"`:
    the EMPS table instead (`emps_table`; returns None). Files are staged in a folder inside `out` and published
    together (`Staging`: all or none of them); staging folders of killed runs are removed first; one run at a time
    writes to `out` (`lock_output`: a second fails at once, naming the first). Under the command line's signal
    handlers (`stop_on_signals`), SIGINT / SIGTERM stop the run at the next check: between models, within fits,
    before the ensembles and before each file is written.

    **Returns:** the `Report` (rows, records, table). **Raises:** `CompareError` for bad input or a failed write
    (one line, naming the configuration's fields); `Interrupted` after SIGINT / SIGTERM (nothing written to `out`).
    """
    config = CompareConfig(**fields) if config is None else dataclasses.replace(config, **fields)
    target = None if config.device == "auto" else resolve_device(config.device)
    if target is not None:  # everything on `target`: data, fits, scores, ensembles
        with forced_device(target):
            return run_compare(config, device="auto")
    out = output_folder(config.out)
    specs = expanded_specs(config)
    emps = specs["data"] == ["emps"]
    expected = [figure_name(stem, k) for k in range(len(specs["test"]) + 1) for stem in FIGURES]
    check_writable(out, ("report.json",) if emps else (*expected, "test_records.png", "report.json"))
    lock_output(out)  # until this run ends: a second run into `out` fails here, at once, naming this one
    remove_stale_staging(out)
    if emps:
        emps_table(out)
        return None
    records = load_records(config, specs)
    _announce(config, records)
    started = time.perf_counter()
    # nothing is written until the files are staged: a signal that a long compiled call keeps the run from acting on
    # within seconds ends the process there (module _interrupts, `abandonable`)
    with abandonable(f"fricjax compare: interrupted; nothing was written to {out}"):
        rows = fit_and_score(
            list(config.models),
            records.split,
            tests=records.tests,
            settings=records.settings,
            seed=config.seed,
            progress=config.progress,
            device=config.device,
        )
        check_interrupt()
        if isinstance(records.split, Split):
            rows += add_ensembles(rows, records.split, records.tests)
        else:
            print("ensembles: not formed with several training records (their weights come from one validation part)")
        report = Report.of(rows, records, seed=config.seed, started=started)
    print()
    print(report.table())
    report.write(out)
    print(
        f"\nreport: {out / 'report.json'}; figures: {report.figures_line(out)}; models: {out / 'models'} "
        f"({time.perf_counter() - started:.0f} s)"
    )
    return report


def _announce(config: CompareConfig, records: CompareRecords) -> None:
    """Print the run's header (the records, their parts, the test records, the models) and its warnings."""
    split, tests = records.split, records.tests
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
        labels = names[-len(tests) :]  # each record by the shortest name that keeps them apart, not its full path
    else:
        described = (
            f"{records.data}, {split.full.length} samples at {_timing(split.full)} (train {split.train_end}, "
            f"validation {split.validation_end - split.train_end})"
        )
        labels = short_labels([t.name for t in tests])
    print(
        f"fricjax {fricjax_version()} compare: {described}; test: "
        + "; ".join(
            f"{label} ({t.record.length - t.scored_start} scored after a {t.init_window}-sample initialisation window)"
            for label, t in zip(labels, tests, strict=True)
        )
        + f"; models: {', '.join(config.models)}"
    )
    training_cards = records.training_cards or [records.training.card]
    unused_loads = unused_load_columns(split, training_cards)
    not_held_out = trained_on(records.specs["data"], records.specs["test"], records.specs["validation"])
    for line in [*not_held_out, *unused_loads, *statistics_warnings(split, tests, records.training.units)]:
        print("warning: " + line)
    for card in [*training_cards, *records.cards.values()]:
        if card.get("units_assumed_si"):
            quantities = " and ".join(
                {"x": "displacement (m)", "force": "force (N)"}[q] for q in card["units_assumed_si"]
            )
            print(
                f"note: {card['source']} gives no unit for its {quantities}: read as SI; if it is not, write the "
                "unit in the header (`x [mm]`, `force [kN]`) or pass `x_unit` / `force_unit` (--x-unit / --force-unit)"
            )
