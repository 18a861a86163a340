"""`fricjax compare` from end to end: fit the named models and score them on the test records (`fit_and_score`),
then, from the command line's options, load and split the records, add ensembles, print the table and write the
models, figures and `report.json` (`run_compare`)."""

from __future__ import annotations

import functools
import os
import pathlib
import time
from collections.abc import Callable, Sequence
from typing import Any

from ..._estimation._interrupts import check_interrupt
from ..._estimation._placement import check_device, choose_device, forced_device, resolve_device
from ..._estimation._serialise import save_model
from ..._validation import nonnegative_int
from ..._version import fricjax_version
from ._emps_table import emps_table
from ._ensembles import add_ensembles
from ._figures import plot_prediction_errors, plot_test_loops
from ._output import Staging, check_writable, remove_stale_staging, strict_json
from ._plausibility import command_line_advice, half_excursion, implausible
from ._records import Split, TestRecord, load_record_spec, split_record, statistics_warnings
from ._registry import MODEL_NAMES, PHYSICS_MODELS, default_models
from ._report import compare_report, format_table
from ._scoring import ModelScore, count_parameters, free_run, reference_scores, score_row
from ._settings import CompareError, DataScales, FitSettings


def fit_and_score(
    names: list[str],
    split: Split,
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
    sequential work when the default device is an accelerator (stated in the log), `"cpu"`, `"gpu"`."""
    specs = default_models(settings)
    tests = [split.test_record()] if tests is None else list(tests)
    scales = DataScales.from_data(split.train)
    rows = []
    for name in names:
        check_interrupt()  # SIGINT / SIGTERM under `fricjax compare` stop the run here (a no-op elsewhere)
        spec = specs[name]
        start_time = time.perf_counter()
        start = None if spec.build is None else spec.build(scales)
        target, reason = choose_device(start, split.train, device, batched=False)
        log(
            f"fitting {spec.label} ..."
            if target is None
            else f"fitting {spec.label} on {target.platform} ({reason}) ..."
        )
        with forced_device(target):
            row = _fit_and_score_one(name, spec, start, split, tests, seed, progress, start_time)
        rows.append(row)
        log(f"  {spec.label}: test NMSE {row.nmse:.3f} %, MAX {row.max_error:.3f}, {row.fit_time:.1f} s: {row.message}")
    return rows


def _fit_and_score_one(
    name: str, spec: Any, start: Any, split: Split, tests: list[TestRecord], seed: int, progress: bool, t0: float
) -> ModelScore:
    """`fit_and_score` for one model: fit `start` (None: identified from the split), then score it."""
    result = spec.fit(start, split, seed, progress)
    elapsed = time.perf_counter() - t0
    model = result.model
    full_prediction = free_run(model, split.full)
    predictions = {
        test.name: full_prediction if test.record is split.full else free_run(model, test.record) for test in tests
    }
    return score_row(
        name,
        spec.label,
        model,
        full_prediction,
        predictions,
        split,
        tests,
        fit_time=elapsed,
        num_parameters=count_parameters(model),
        result=result.code,  # the name of the fj.RESULTS item
        message="; ".join(
            [command_line_advice(result.message), *implausible(model, half_excursion(split.train.motion))]
        ),
        std=result.std,
    )


def run_compare(
    *,
    data: str = "tribometer:mixed",
    test: Sequence[str] | None = None,
    split_at: Sequence[float] | None = None,
    init_window: int | None = None,
    models: Sequence[str] = PHYSICS_MODELS,
    steps: int = 40,
    gms_elements: int = 4,
    maxwell_elements: int = 5,
    starts: int = 2,
    drift: str = "linear",
    neural_steps: int = 600,
    dt: float | None = None,
    x_unit: str | None = None,
    force_unit: str | None = None,
    out: str | os.PathLike[str] = "fricjax-compare",
    seed: int = 0,
    progress: bool = True,
    device: str = "auto",
) -> None:
    """`fricjax compare` with the command line's options as arguments (`fricjax compare --help` says what each
    does): fit every model on the training record `data`, score each by free run on the test records (`test`, or
    the record's own test part), add ensembles, print the table, and write the models, the figures and
    `report.json` to `out`. `data="emps"`: the EMPS table instead (`emps_table`). Files are staged in a folder
    inside `out` and published together (`Staging`: all or none of them); staging folders of killed runs are
    removed first. Under the command line's signal handlers (`stop_on_signals`), SIGINT / SIGTERM stop the run at
    the next check: between models, within fits, before the ensembles and before each file is written.

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
    out = pathlib.Path(out)
    models = [m.lower() for m in models]  # model names are case-insensitive
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
    settings = FitSettings(
        steps=steps,
        gms_elements=gms_elements,
        maxwell_elements=maxwell_elements,
        starts=starts,
        drift=drift,
        neural_steps=neural_steps,
    )
    check_writable(
        out, ("report.json",) if data == "emps" else ("test_errors.png", "hysteresis_loops.png", "report.json")
    )
    remove_stale_staging(out)
    if data == "emps":
        emps_table(out)
        return
    units_kw: dict[str, Any] = {"dt": dt, "x_unit": x_unit, "force_unit": force_unit}
    training = load_record_spec(data, seed=seed, **units_kw)
    test_specs = list(test or [])
    split = split_record(training, split_at, tested_elsewhere=bool(test_specs))
    tests: list[TestRecord] = []
    cards: dict[str, Any] = {}  # the data cards of the other test records, by test name
    if split.validation_end < training.data.length:
        tests.append(split.test_record(init_window, training.reference))
    for spec in test_specs:
        loaded = load_record_spec(spec, seed=seed, **units_kw)
        name = loaded.name if loaded.name not in {t.name for t in tests} else f"{loaded.name} #{len(tests) + 1}"
        tests.append(TestRecord.whole(loaded, init_window, name))
        cards[name] = loaded.card
    if not tests:
        raise CompareError("nothing to test on: the split leaves no test part; pass --test records")
    units = training.units
    print(
        f"fricjax {fricjax_version()} compare: {data}, {split.full.length} samples (train {split.train_end}, "
        f"validation {split.validation_end - split.train_end}); test: "
        + "; ".join(
            f"{t.name} ({t.record.length - t.scored_start} scored after a {t.init_window}-sample initialisation window)"
            for t in tests
        )
        + f"; models: {', '.join(models)}"
    )
    for line in statistics_warnings(split, tests, units):
        print("warning: " + line)
    started = time.perf_counter()
    rows = fit_and_score(
        list(models), split, tests=tests, settings=settings, seed=seed, progress=progress, device=device
    )
    check_interrupt()
    rows += add_ensembles(rows, split, tests)
    floor = reference_scores(tests)
    print()
    print(format_table(rows, floor))
    try:
        staging = Staging(out)  # the files are written there, then moved into `out` together (or not at all)
    except OSError as err:
        raise CompareError(f"--out {out}: could not create a staging folder ({err.strerror})") from None
    with staging:
        for row in rows:
            staging.write(f"models/{row.name}.eqx", functools.partial(save_model, model=row.model))
        staging.write("test_errors.png", lambda path: plot_prediction_errors(rows, tests[0], path, units=units))
        staging.write("hysteresis_loops.png", lambda path: plot_test_loops(rows, tests[0], path, units=units))
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
        )
        staging.write("report.json", lambda path: path.write_text(strict_json(report)))  # the report last
        staging.publish()
    print(
        f"\nreport: {out / 'report.json'}; figures: {out / 'test_errors.png'}, {out / 'hysteresis_loops.png'}; "
        f"models: {out / 'models'} ({time.perf_counter() - started:.0f} s)"
    )
