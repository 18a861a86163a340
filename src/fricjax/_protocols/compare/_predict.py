"""`fricjax predict`: fitted models (model files, as compare writes them) run on records they were not fitted on,
as compare scores its test records (MATLAB's `compare(data, model)` / `sim`): each record's initialisation window
estimates its force offset and the model's initial state (`fj.initialise`), the model runs free over the rest, and
the scored part is compared with the measured force. Writes the predictions (CSV), the figures and a report."""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import time
from collections.abc import Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from ..._constraints import unwrap
from ..._data._model_files import load_model
from ..._estimation.loop._interrupts import abandonable, check_interrupt
from ..._models.combine._ensemble import AbstractEnsemble
from ..._plot import plot_residual_analysis
from ..._residuals import ResidualAnalysis
from ..._validation import nonnegative_int
from ..._version import fricjax_version
from ._checks import check_load_leaks, check_test_record
from ._figures import plot_prediction_errors, plot_test_loops
from ._output import (
    Staging,
    check_writable,
    lock_output,
    output_folder,
    releasing_output_locks,
    remove_stale_staging,
    strict_json,
    versions,
)
from ._records import TestRecord, expand_record_specs, load_record_spec, short_labels
from ._scoring import predict_test_record, residual_summary, residuals_on, score_prediction
from ._settings import CompareError

__all__ = ["Prediction", "run_predict"]


@dataclasses.dataclass(frozen=True)
class Prediction:
    """One model on one record: `nmse` [%] and `max_error` (MAX / std) on the scored part, the `offset` [N] of the
    initialisation window, and `prediction`, the offset-corrected force [N] on the scored part (as compare's
    figures take it); `residuals` the `fj.ResidualAnalysis` of the scored part against the velocity (or why there is
    none: a prediction that is not finite); `name` and `label` the model's (its file's stem)."""

    name: str
    label: str
    record: str
    nmse: float
    max_error: float
    offset: float
    prediction: np.ndarray
    residuals: ResidualAnalysis | str


@releasing_output_locks
def run_predict(
    *,
    models: Sequence[str],
    data: Sequence[str],
    init_window: int | None = None,
    init: str = "state",
    test_drift: str = "none",
    dt: float | None = None,
    x_unit: str | None = None,
    force_unit: str | None = None,
    t_unit: str | None = None,
    columns: dict[str, str] | None = None,
    velocity: str = "auto",
    normal_force_column: Sequence[str] | None = None,
    accept_correlated_load: bool = False,
    resample: float | None = None,
    out: str | pathlib.Path = "fricjax-predict",
) -> list[Prediction]:
    """Run each model file of `models` on each record of `data` (files, quoted globs, or built-in records) as
    compare scores a test record: the first `init_window` samples (default 10 %) estimate the record's force offset
    and, with `init="state"`, the model's initial state; the rest is scored by NMSE and MAX / std. A model fitted
    with a sensor drift leaves it behind (`test_drift="none"`) or estimates a new one on the window (`"window"`).
    Prints a table, and writes `predictions[_K].csv` per record (time, measured force, each model's prediction over
    the whole record), `test_errors[_K].png`, `hysteresis_loops[_K].png` and `report.json` to `out` (staged and
    published together). **Raises:** `CompareError` (one line) for bad input.
    """
    out = output_folder(out)
    if init_window is not None:
        try:
            init_window = nonnegative_int(init_window, "--init-window", "", hint="(samples)")
        except ValueError as error:
            raise CompareError(str(error)) from None
    if init not in ("state", "offset"):
        raise CompareError(f"--init must be state or offset, got {init!r}")
    if test_drift not in ("none", "window"):
        raise CompareError(f"--test-drift must be none or window for a saved model, got {test_drift!r}")
    files = expand_record_specs(list(models), "--model")
    if not files:
        raise CompareError("--model: name at least one model file (compare writes them to OUT/models/*.eqx)")
    stems = [pathlib.Path(file).stem for file in files]
    names = stems if len(set(stems)) == len(stems) else short_labels([str(pathlib.Path(f)) for f in files])
    loaded_models = {}
    for file, name in zip(files, names, strict=True):
        path = pathlib.Path(file)
        if not path.is_file():
            raise CompareError(f"--model {file}: no such file (compare writes its models to OUT/models/NAME.eqx)")
        try:
            loaded_models[name] = load_model(path)
        except (ValueError, OSError) as err:
            raise CompareError(f"--model {file}: {' '.join(str(err).split())}") from None
    specs = expand_record_specs(list(data), "--data")
    if not specs or "emps" in specs:
        raise CompareError("--data: name the records to predict (files, or tribometer:REGIME); emps has its own table")
    units_kw: dict[str, Any] = {
        "dt": dt,
        "x_unit": x_unit,
        "force_unit": force_unit,
        "t_unit": t_unit,
        "columns": columns,
        "velocity": velocity,
        "normal_force_column": normal_force_column,
        "resample": resample,
    }
    tests, units = [], []
    for spec in specs:
        loaded = load_record_spec(spec, **units_kw)
        tests.append(TestRecord.whole(loaded, init_window))
        units.append(loaded.units)
    for test in tests:
        check_test_record(test, init)
    takes_load = any("normal_force" in getattr(unwrap(m), "requires", ()) for m in loaded_models.values())
    if takes_load and not accept_correlated_load:  # a load that no model takes cannot leak into a prediction
        check_load_leaks([(t.name, t.record) for t in tests])
    check_writable(out)
    lock_output(out)
    remove_stale_staging(out)
    print(
        f"fricjax {fricjax_version()} predict: {len(loaded_models)} model{'s' * (len(loaded_models) != 1)} "
        f"({', '.join(loaded_models)}) on "
        + "; ".join(
            f"{t.name} ({t.record.length - t.scored_start} scored after a {t.init_window}-sample window)" for t in tests
        )
    )
    started = time.perf_counter()
    results: list[Prediction] = []
    whole: dict[tuple[str, str], np.ndarray] = {}
    with abandonable(f"fricjax predict: interrupted; nothing was written to {out}"):
        for test in tests:
            for name, model in loaded_models.items():
                check_interrupt()
                try:
                    full = _predict(model, test, init, test_drift)
                except (ValueError, TypeError) as err:  # a model that needs a signal the record lacks, say
                    raise CompareError(f"{name} on {test.name}: {' '.join(str(err).split())}") from None
                score, scored = score_prediction(full, test)
                residuals = residuals_on(test, scored)
                results.append(
                    Prediction(name, name, test.name, score.nmse, score.max_error, score.offset, scored, residuals)
                )
                whole[test.name, name] = np.asarray(full, dtype=float) + score.offset
    print()
    print(format_predictions(results))
    print()
    short = dict(zip([t.name for t in tests], short_labels([t.name for t in tests]), strict=True))
    for r in results:
        print(f"{r.name} on {short[r.record]}: {residual_summary(r.residuals)['verdict']}")
    labels = short_labels([t.name for t in tests])
    figures, tables = [], []
    try:
        staging = Staging(out)
    except OSError as err:
        raise CompareError(f"--out {out}: could not create a staging folder ({err.strerror})") from None
    with staging:
        for k, (test, label, unit) in enumerate(zip(tests, labels, units, strict=True)):
            suffix = "" if k == 0 else f"_{k + 1}"
            rows = [r for r in results if r.record == test.name]
            for stem, plot in (("test_errors", plot_prediction_errors), ("hysteresis_loops", plot_test_loops)):
                name = f"{stem}{suffix}.png"
                staging.write(name, functools.partial(plot, rows, test, units=unit, label=label))
                figures.append(name)
            name = f"residuals{suffix}.png"
            staging.write(name, functools.partial(_save_residuals, rows=rows, label=label))
            figures.append(name)
            table = f"predictions{suffix}.csv"
            staging.write(
                table, functools.partial(_write_predictions, test=test, whole=whole, models=list(loaded_models))
            )
            tables.append(table)
        report = {
            "fricjax": fricjax_version(),
            "versions": versions(),
            "models": {name: str(pathlib.Path(file)) for name, file in zip(loaded_models, files, strict=True)},
            "settings": {"init": init, "test_drift": test_drift, "init_window": init_window, **_plain(units_kw)},
            "records": [
                {"name": t.name, "label": label, "samples": t.record.length, "init_window": t.init_window}
                for t, label in zip(tests, labels, strict=True)
            ],
            "scores": [
                {
                    "model": r.name,
                    "record": r.record,
                    "nmse": r.nmse,
                    "max_error": r.max_error,
                    "offset_N": r.offset,
                    "residuals": residual_summary(r.residuals),
                }
                for r in results
            ],
            "figures": figures,
            "predictions": tables,
        }
        staging.write("report.json", lambda path: path.write_text(strict_json(report)))
        staging.publish()
    print(f"\nreport: {out / 'report.json'}; predictions: {', '.join(str(out / t) for t in tables)} "
          f"({time.perf_counter() - started:.0f} s)")  # fmt: skip
    return results


def _predict(model: Any, test: TestRecord, init: str, test_drift: str) -> np.ndarray:
    """A model's prediction over the whole record, as compare makes it (`predict_test_record`); an ensemble's as
    compare scores its ensembles: each member started on the window on its own, their predictions combined."""
    if isinstance(model, AbstractEnsemble):
        members = np.stack([predict_test_record(member, test, init, test_drift) for member in model.members])
        return np.asarray(model.combine(jnp.asarray(members.T)))
    return predict_test_record(model, test, init, test_drift)


def _save_residuals(path: pathlib.Path, *, rows: Sequence[Prediction], label: str) -> None:
    analyses = {r.name: r.residuals for r in rows if not isinstance(r.residuals, str)}
    figure = plot_residual_analysis(analyses, title=f"{label}: residual analysis", pyplot=False)
    figure.savefig(path, dpi=100)


def format_predictions(results: Sequence[Prediction]) -> str:
    """The table: one row per model and record, NMSE [%], MAX / std and the window's offset [N]."""
    width = max([len("model"), *(len(r.name) for r in results)])
    records = list(dict.fromkeys(r.record for r in results))
    labels = dict(zip(records, short_labels(records), strict=True))
    record_width = max([len("record"), *(len(v) for v in labels.values())])
    lines = [f"{'record':<{record_width}}  {'model':<{width}}  {'NMSE %':>10}  {'MAX/std':>8}  {'offset N':>10}"]
    for r in results:
        lines.append(
            f"{labels[r.record]:<{record_width}}  {r.name:<{width}}  {r.nmse:>10.4f}  {r.max_error:>8.3f}  "
            f"{r.offset:>10.4g}"
        )
    return "\n".join(lines)


def _write_predictions(path: pathlib.Path, *, test: TestRecord, whole: dict, models: list[str]) -> None:
    """A CSV of the record: `t` [s], `x` [m], the measured `force` [N], `scored` (0 in the initialisation window),
    and each model's offset-corrected prediction [N] over the whole record."""
    record = test.record
    t = np.arange(record.length) * float(np.asarray(record.motion.dt).reshape(-1)[0])
    x = np.asarray(record.motion.samples().x, dtype=float)
    scored = (np.arange(record.length) >= test.scored_start).astype(float)
    columns = [t, x, np.asarray(record.force, dtype=float), scored] + [whole[test.name, m] for m in models]
    header = ",".join(["t [s]", "x [m]", "force [N]", "scored"] + [f"{m} [N]" for m in models])
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="", fmt="%.10g")


def _plain(options: dict[str, Any]) -> dict[str, Any]:
    """The record options as JSON values (a tuple of column names as a list)."""
    return {key: list(value) if isinstance(value, tuple) else value for key, value in options.items()}
