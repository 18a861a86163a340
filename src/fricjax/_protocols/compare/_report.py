"""What `compare` reports: the comparison table (`format_table`, sorted by test NMSE with `by_score`) and the
contents of `report.json` (`compare_report`: data, split, test records, settings, noise floor, and every model's
scores, parameters with their SI units and standard deviations)."""

from __future__ import annotations

import dataclasses
import functools
import json
import pathlib
import re
import time
from typing import Any

import numpy as np

from ..._constraints import compact_value, parameter_arrays, parameter_units, unwrap
from ..._data._columns import Units
from ..._data._model_files import save_model
from ..._smoothing import exact
from ..._version import fricjax_version
from ._config import CompareRecords
from ._figures import plot_prediction_errors, plot_test_loops, plot_test_records
from ._names import NEURAL_MODELS
from ._output import Staging, strict_json, versions
from ._records import LoadedRecord, Split, TestRecord, TrainingRecords, short_labels
from ._scoring import (
    ModelScore,
    Score,
    is_ensemble,
    reference_scores,
    residual_summary,
    residuals_on,
    rows_on_test,
)
from ._settings import RESULT_CODES, CompareError, FitSettings


def by_score(row: ModelScore) -> tuple[bool, float]:
    """Sort key of the table: by test NMSE (the first test record), non-finite scores last."""
    return (not np.isfinite(row.nmse), float(row.nmse) if np.isfinite(row.nmse) else 0.0)


def validation_choice(rows: list[ModelScore]) -> ModelScore | None:
    """The single model (not an ensemble) with the lowest finite validation NMSE: what a user chooses without the
    test part; None where no row has one."""
    scored = [r for r in rows if not is_ensemble(r) and np.isfinite(r.validation_nmse)]
    return min(scored, key=lambda r: float(r.validation_nmse)) if scored else None


def label_width(rows: list[ModelScore]) -> int:
    """The width of the table's first column: the longest label (at least 44 characters)."""
    return max([44, *(len(r.label) for r in rows)])


def fit_percent_of(nmse: float) -> float:
    """The system-identification FIT [%] (`fj.fit_percent`, MATLAB's `compare`) of an NMSE [%]: `100 (1 - ||e|| /
    ||F - mean F||)` = `100 (1 - sqrt(NMSE / 100))`; 100 a perfect prediction, 0 the mean force's, below 0 worse."""
    return 100.0 * (1.0 - float(np.sqrt(nmse / 100.0))) if np.isfinite(nmse) and nmse >= 0 else float("nan")


def format_table(rows: list[ModelScore], reference: dict[str, Score] | None = None) -> str:
    """The comparison table, sorted by test NMSE (kernel paper Table 1 / worden2007 Fig. 11 layout): one NMSE
    column per test record (where there are several), `fit %` (MATLAB's FIT, `fit_percent_of`, the first test
    record's), MAX as the largest absolute error divided by the standard
    deviation of the measured force (the first test record's), the noise-floor reference row where there is one,
    what the result codes mean, and each flagged row's notes (`ModelScore.notes`)."""
    w = label_width(rows) + 2  # "* " marks the validation part's choice
    names = list(rows[0].tests) if rows and rows[0].tests else ["test"]
    several = len(names) > 1
    heads = [f"NMSE % {i + 1}" for i in range(len(names))] if several else ["NMSE %"]
    max_head = "MAX/std 1" if several else "MAX/std"  # the first test record's, as the sort
    fit_head = "fit % 1" if several else "fit %"
    lines = [
        f"{'model':{w}s} {'params':>6s} {'val %':>11s} "
        + " ".join(f"{h:>10s}" for h in heads)
        + f" {fit_head:>7s} {max_head:>9s} {'fit s':>7s}  result"
    ]

    def values(tests: dict[str, Score], fallback: float) -> list[float]:
        return [tests[n].nmse if n in tests else fallback for n in names] if tests else [fallback]

    chosen = validation_choice(rows)
    flagged: list[ModelScore] = []
    for r in sorted(rows, key=by_score):
        cells = " ".join(f"{v:10.4f}" for v in values(r.tests, r.nmse))
        flag = f" (note {len(flagged) + 1})" if r.notes else ""
        if r.notes:
            flagged.append(r)
        val = r.validation_nmse
        val_cell = "-" if not np.isfinite(val) else (f"({val:.4f})" if is_ensemble(r) else f"{val:.4f}")
        label = ("* " if r is chosen else "  ") + r.label
        lines.append(
            f"{label:{w}s} {r.num_parameters:6d} {val_cell:>11s} {cells} {fit_percent_of(r.nmse):7.2f} "
            f"{r.max_error:9.3f} {r.fit_time:7.1f}  {r.result}{flag}"
        )
    if reference:
        floor = [reference[n].nmse if n in reference else float("nan") for n in names]
        cells = " ".join(f"{v:10.4f}" for v in floor)
        first = reference.get(names[0])
        lines.append(
            f"{'  noise floor (true model + sensor model)':{w}s} {'':6s} {'':11s} {cells} "
            f"{fit_percent_of(first.nmse if first else float('nan')):7.2f} "
            f"{(first.max_error if first else float('nan')):9.3f}"
        )
    if chosen is not None:
        lines += [
            "* the validation part's choice: the single model with the lowest validation NMSE (`val %`); the rows are",
            "  sorted by test NMSE, which no choice may use. An ensemble's `val %` (in brackets) is its own fit.",
        ]
    if several:
        lines.append("test records: " + "; ".join(f"{i + 1} = {n}" for i, n in enumerate(short_labels(names))))
    codes = sorted({r.result for r in rows if r.result in RESULT_CODES})
    legend = dict(RESULT_CODES)
    if any(r.result == "max_steps" and r.name in NEURAL_MODELS for r in rows):  # their budget is --neural-steps
        legend["max_steps"] = legend["max_steps"].replace("--steps", "--steps; neural models: --neural-steps")
    if any(is_ensemble(r) and r.result == "successful" for r in rows):  # no iterative solver
        legend["successful"] += "; an ensemble: its weights or members found in closed form on the validation part"
    lines.append("result: " + "; ".join(f"{c} = {legend[c]}" for c in codes))
    lines += [f"note {i + 1}, {r.label}: " + "; ".join(r.notes) for i, r in enumerate(flagged)]
    return "\n".join(lines)


def format_record_nuisances(rows: list[ModelScore], units: Units | None = None) -> str:
    """Each model's per-record nuisances after a fit to several records: the force offset, drift and training
    NMSE of every training record (`fj.RecordNuisances`), in the records' force unit (`units`; default N)."""
    unit, factor = (units.force, units.force_factor) if units is not None else ("N", 1.0)
    drifts = any(r.records is not None and r.records.drift is not None for r in rows)
    lines = [f"per training record (training NMSE, offset [{unit}]" + (f", drift [{unit}/s]):" if drifts else "):")]
    for r in sorted(rows, key=by_score):
        if r.records is None:
            continue
        lines += [f"  {r.label}:", *("    " + line for line in r.records.lines(unit, factor))]
    return "\n".join(lines)


def format_test_offsets(rows: list[ModelScore], names: list[str], units: Units | None = None) -> str:
    """Each model's force offset on each test record (estimated on the record's initialisation window, with the
    model's initial state), in the records' force unit (`units`; default N): one column per test record (`names`,
    their short labels), the rows in the table's order."""
    unit, factor = (units.force, units.force_factor) if units is not None else ("N", 1.0)
    width = label_width(rows)
    heads = [name[-12:] for name in names]
    lines = [f"offsets on the test records [{unit}] (on each one's initialisation window, with the initial state):"]
    lines.append(f"  {'':{width}s} " + " ".join(f"{h:>12s}" for h in heads))
    states = []
    for r in sorted(rows, key=by_score):
        cells = [r.tests[n].offset / factor if n in r.tests else float("nan") for n in r.tests]
        lines.append(f"  {r.label:{width}s} " + " ".join(f"{c:12.4g}" for c in cells))
        for name, state in r.test_states.items():
            text = state_text(state)
            if text:
                states.append(f"    {r.label} on {short_labels([name])[0]}: {text}")
    if states:
        lines += ["  initial states found on the windows (SI units):", *states]
    return "\n".join(lines)


def state_text(state: Any) -> str:
    """A model's state in a line: each floating field (`z 1.2e-07`), a long array by its shape and range."""
    import jax

    parts = []
    for path, leaf in jax.tree_util.tree_leaves_with_path(state):
        array = np.asarray(leaf)
        if not np.issubdtype(array.dtype, np.floating):
            continue
        parts.append(f"{jax.tree_util.keystr(path).lstrip('.')} {compact_value(array)}")
    return ", ".join(parts)


def compare_report(
    *,
    data: str,
    seed: int,
    training: LoadedRecord,
    split: Split | TrainingRecords,
    tests: list[TestRecord],
    cards: dict[str, Any],
    floor: dict[str, Score],
    settings: FitSettings,
    rows: list[ModelScore],
    started: float,
    training_cards: list[dict[str, Any]] | None = None,
    training_specs: list[str] | None = None,
) -> dict[str, Any]:
    """The contents of `report.json`: `data` and `seed` as given, the training record's data card and units, the
    split, each test record (its windows, noise floor and, for other records, its data card from `cards`), the
    settings, the result codes, the noise floor, and every model's row (sorted by test NMSE; its `test_scores` keyed
    by each test record as it was named, its `training_records` rows by their short `name` and, as named, `record`:
    `training_specs`, the expanded `data` names); `total_time_s` counts
    from `started` (a `time.perf_counter()` reading)."""
    units = training.units
    return {
        "fricjax": fricjax_version(),
        "versions": versions(),
        "data": data,
        "seed": seed,
        "data_card": training.card if training_cards is None else training_cards,
        "units": {
            "x": units.x,
            "v": units.v,
            "force": units.force,
            "internal": "SI (m, m/s, N)",
            "parameters": "SI, whatever the record's units: each model's parameter_units",
        },
        "split": _split_report(split),
        "test_records": [
            {
                "name": t.name,
                "samples": t.record.length,
                "init_window": [t.start, t.scored_start],
                "scored": [t.scored_start, t.record.length],
                "noise_floor_nmse_percent": floor[t.name].nmse if t.name in floor else None,
                "card": cards.get(t.name),
            }
            for t in tests
        ],
        "settings": {
            **dataclasses.asdict(settings),
            "solvers": "Levenberg-Marquardt (fj.levenberg_marquardt) with separable least squares for linear "
            "parameters; GMS: Levenberg-Marquardt from fj.initial_guess's start, 256 log-uniform draws around it "
            "screened by their loss at the start, the best 4 fitted",
            "scoring": "free run in exact mode from each record's first sample; on records the model was not fitted "
            + (
                "on, the force offset and the model's initial state are fitted on the initialisation window "
                "(fj.initialise), which is not scored"
                if settings.init == "state"
                else "on, from rest, the force offset the mean error over the initialisation window, which is not "
                "scored"
            )
            + f"; a training record's drift on other records: {settings.test_drift}",
        },
        "result_codes": RESULT_CODES,
        "reference": {
            "model": "true model + sensor drift and offset (noise-free sensor reading)",
            "scores": {name: dataclasses.asdict(value) for name, value in floor.items()},
        }
        if floor
        else None,
        "models": [
            {
                "name": r.name,
                "label": r.label,
                "nmse_percent": r.nmse,
                "fit_percent": fit_percent_of(r.nmse),
                "max_error_over_std": r.max_error,
                "validation_nmse_percent": r.validation_nmse,
                "test_scores": {name: dataclasses.asdict(value) for name, value in r.tests.items()},
                "fit_time_s": r.fit_time,
                "num_parameters": r.num_parameters,
                "result": r.result,
                "result_message": r.message,
                "notes": list(r.notes),
                "parameters": _parameters(r.model),
                "parameter_units": _units(r.model),
                "parameter_std": _estimated_std(r.std) if r.std is not None else None,
                # each row by its short name and, as `test_scores` keys its records, by the name it was given
                "training_records": [
                    {**row, "record": record}
                    for row, record in zip(r.records.table(), training_specs or split.names, strict=False)
                ]
                if r.records is not None and isinstance(split, TrainingRecords)
                else None,
            }
            for r in sorted(rows, key=by_score)
        ],
        "total_time_s": time.perf_counter() - started,
    }


def _split_report(split: Split | TrainingRecords) -> dict[str, Any]:
    """The split of the training data: one record's parts, or each training record's train and validation parts."""
    if isinstance(split, TrainingRecords):
        return {
            "training_records": [
                {"name": name, "samples": record.length, "train": [0, end], "validation": [end, record.length]}
                for name, record, end in zip(split.names, split.records, split.train_ends, strict=True)
            ],
            "validation_records": list(split.validation_names) or None,
        }
    return {
        "train": [0, split.train_end],
        "validation": [split.train_end, split.validation_end],
        "test_part": [split.validation_end, split.full.length] if split.validation_end < split.full.length else None,
    }


def _parameters(model: Any) -> dict[str, Any]:
    return {path: value.tolist() for path, value in parameter_arrays(unwrap(exact(model))).items()}


def _units(model: Any) -> dict[str, str | None]:
    """The SI unit of each parameter (`fj.Solution.parameter_table`'s), whatever the record's units; `None` where
    fricjax does not know one (network weights, polynomial coefficients)."""
    return {path: unit or None for path, unit in parameter_units(unwrap(exact(model))).items()}


def _estimated_std(std: Any) -> dict[str, Any]:
    """The Gauss-Newton standard deviations that were estimated: fixed and untrained leaves (NaN) are left out."""
    return {path: value.tolist() for path, value in parameter_arrays(std).items() if not np.all(np.isnan(value))}


@dataclasses.dataclass(frozen=True)
class Report:
    """What a `compare` run found, to print and to write: `rows` (a `ModelScore` per model and ensemble), the
    `records` it ran on (`CompareRecords`), the noise-floor scores of the test records (`floor`), each row's
    residual analysis on the first test record (`residuals`: `fj.ResidualAnalysis` or why there is none), the `seed`
    and when the fits `started` (a `time.perf_counter()` reading)."""

    rows: list[ModelScore]
    records: CompareRecords
    floor: dict[str, Score]
    residuals: dict[str, Any]
    seed: int
    started: float

    @classmethod
    def of(cls, rows: list[ModelScore], records: CompareRecords, *, seed: int, started: float) -> Report:
        residuals = {row.name: residuals_on(records.tests[0], row.prediction) for row in rows}
        return cls(rows, records, reference_scores(records.tests), residuals, seed, started)

    @property
    def labels(self) -> list[str]:
        """The test records' short names (figures and their titles)."""
        return short_labels([t.name for t in self.records.tests])

    def table(self) -> str:
        """The table as printed: models by test NMSE, the records' nuisances (several records), residual verdicts."""
        lines = [format_table(self.rows, self.floor)]
        if self.records.several:
            lines.append(format_record_nuisances(self.rows, self.records.training.units))
        if self.records.cards:  # records named with `test` (the training record's own test part needs none)
            lines.append(format_test_offsets(self.rows, self.labels, self.records.training.units))
        lines.append(f"\nresiduals on {self.labels[0]} (its scored part; the 99 % band; v the input):")
        lines += [f"  {row.label}: {residual_summary(self.residuals[row.name])['verdict']}" for row in self.rows]
        return "\n".join(lines)

    def contents(self, figures: list[str]) -> dict[str, Any]:
        """`report.json`'s contents (`compare_report`), with the figures written and the residual summaries."""
        records = self.records
        report = compare_report(
            data=records.data,
            seed=self.seed,
            training=records.training,
            split=records.split,
            tests=records.tests,
            cards=records.cards,
            floor=self.floor,
            settings=records.settings,
            rows=self.rows,
            started=self.started,
            training_cards=records.training_cards,
            training_specs=records.specs["data"],
        )
        report["figures"] = figures
        report["residuals"] = {name: residual_summary(r) for name, r in self.residuals.items()}
        return report

    def write(self, out: pathlib.Path) -> None:
        """Write the models (`models/NAME.eqx`), each test record's figures and `report.json` (last) into `out`,
        staged and published together; figures an earlier run in `out` drew and this one did not are removed."""
        try:
            staging = Staging(out)  # the files are written there, then moved into `out` together (or not at all)
        except OSError as err:
            raise CompareError(f"`out` {out}: could not create a staging folder ({err.strerror})") from None
        tests, units = self.records.tests, self.records.training.units
        with staging:
            for row in self.rows:
                staging.write(f"models/{row.name}.eqx", functools.partial(save_model, model=row.model))
            figures = []
            for k, (record, label) in enumerate(zip(tests, self.labels, strict=True)):
                scored = self.rows if k == 0 else rows_on_test(self.rows, record)
                for stem, plot in zip(FIGURES, (plot_prediction_errors, plot_test_loops), strict=True):
                    name = figure_name(stem, k)
                    staging.write(name, functools.partial(plot, scored, record, units=units, label=label))
                    figures.append(name)
            if len(tests) > 1:
                staging.write("test_records.png", functools.partial(plot_test_records, self.rows, self.labels))
                figures.append("test_records.png")
            report = self.contents(figures)
            staging.write("report.json", lambda path: path.write_text(strict_json(report)))  # the report last
            earlier = _earlier_figures(out)
            staging.publish()
        _remove_stale_figures(out, earlier, figures)

    def figures_line(self, out: pathlib.Path) -> str:
        """Where the figures are, as the run's last line names them."""
        if len(self.records.tests) == 1:
            return f"{out / 'test_errors.png'}, {out / 'hysteresis_loops.png'}"
        return (
            f"{out}/test_errors[_K].png and hysteresis_loops[_K].png for test records 1-{len(self.records.tests)} "
            f"(no _K: record 1, {self.labels[0]}), {out / 'test_records.png'} (each model's NMSE on each)"
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


def figure_name(stem: str, k: int) -> str:
    """The file of figure `stem` for test record `k` (from 0): the first record's keep their names."""
    return f"{stem}.png" if k == 0 else f"{stem}_{k + 1}.png"
