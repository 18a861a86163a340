"""Scoring in exact mode: a model's free run from a record's first sample (`free_run`), its NMSE and MAX error on
a test record's scored part after the initialisation window's offset (`score_prediction`, `score`), the noise
floor (`reference_scores`), the rows of the comparison table (`ModelScore`), and whether one model predicts the
validation part significantly better than another (`paired_validation_gain`)."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np

from ..._data._record import FrictionData
from ..._metrics import max_error, nmse
from ..._residuals import ResidualAnalysis, residual_analysis
from ..._simulate import simulate
from ..._smoothing import exact
from ._records import Split, TestRecord


@dataclasses.dataclass(frozen=True)
class Score:
    """A model's score on one test record: NMSE [%] and MAX / std of the measured force on the scored part, and
    the force offset [N] estimated in the initialisation window."""

    nmse: float
    max_error: float
    offset: float


def score_prediction(prediction: Any, test: TestRecord) -> tuple[Score, np.ndarray]:
    """Score a prediction over the whole test record: the offset is the mean error in the initialisation window
    (0 without one). **Returns:** `(Score, the offset-corrected prediction on the scored part)`."""
    prediction = np.asarray(prediction, dtype=float)
    measured = np.asarray(test.record.force, dtype=float)
    window = slice(test.start, test.scored_start)
    offset = float(np.mean(measured[window] - prediction[window])) if test.init_window > 0 else 0.0
    scored = prediction[test.scored_start :] + offset
    truth = measured[test.scored_start :]
    return Score(float(nmse(truth, scored)), float(max_error(truth, scored)), offset), scored


def free_run(model: Any, record: FrictionData) -> np.ndarray:
    """`model`'s exact-mode free-run force over the whole `record` (from its first sample), as NumPy."""
    return np.asarray(simulate(exact(model), record.motion))  # type: ignore[arg-type]


def carries_drift(test: TestRecord, test_drift: str) -> bool:
    """Whether a training record's drift goes over to `test` (`predict_test_record`): `"carry"`, or `"auto"` on a
    record of the built-in tribometer (one with a `reference`: its simulated force cell drifts by one law in every
    record, a fixed fraction of the record's force range); a file record's drift belongs to it."""
    return test_drift == "carry" or (test_drift == "auto" and test.reference is not None)


def predict_test_record(
    model: Any,
    test: TestRecord,
    init: str = "state",
    test_drift: str = "auto",
    training_range: float | None = None,
    states: dict[str, Any] | None = None,
) -> np.ndarray:
    """`model`'s exact-mode prediction over the whole of a record it was not fitted on (`--test`). A training
    record's drift (`fj.SensorDrift`) belongs to that record: it is left out (`test_drift="none"`), estimated on
    the initialisation window (`"window"`), or carried over restarting at 0 (`"carry"`; `"auto"`: `carries_drift`).
    A carried drift is scaled by the ratio of the force ranges (peak to peak) that the friction model predicts on the
    test record and on the training record (`training_range` [N], the latter; None: unscaled), so a drift that is a
    fixed fraction of the force range (a piezo cell's charge leakage grows with the charge, i.e. the load; the
    built-in tribometer's cell drifts by 3 % of each record's range) goes over in proportion; only the model and the
    motions enter, never the test record's measured force. Its time course goes over as it is: records of equal
    length are assumed (the tribometer's drift reaches its level at each record's end). With `init="state"` and a
    window, the record's offset and the model's initial state are fitted on the window (`fj.initialise`; the state is
    put in `states[test.name]` where a dict is given); otherwise the model runs from rest (and `score_prediction`
    takes the window's mean error as the offset: `fj.AtRest`'s)."""
    from ..._estimation.initial._initialise import WindowLeastSquares, initialise

    drifting = getattr(model, "drifts", False)
    friction = model.without_drift() if drifting else model
    if carries_drift(test, test_drift):
        force = free_run(friction, test.record)
        if not drifting:
            return force
        dt = np.broadcast_to(np.asarray(test.record.motion.samples().dt, np.float64), force.shape)
        drift = np.asarray(model.drift(np.concatenate([[0.0], np.cumsum(dt)[:-1]])), np.float64)  # t of each sample
        test_range = float(np.ptp(force))
        ratio = test_range / training_range if training_range else 1.0
        return force + (ratio if np.isfinite(ratio) else 1.0) * drift
    if init == "offset" or test.init_window == 0:
        return free_run(friction, test.record)
    window = test.record.slice(test.start, test.scored_start)
    with warnings.catch_warnings(record=True) as caught:  # said again with the record's name
        warnings.simplefilter("always")
        found = initialise(exact(friction), window, initialiser=WindowLeastSquares(drift=test_drift == "window"))
    for warning in caught:
        warnings.warn(f"{test.name}: {warning.message}", warning.category, stacklevel=2)
    if states is not None:
        states[test.name] = found.state0
    # without the offset: `score_prediction` takes the window's mean error, which is the offset fitted with the state
    return found.predict(exact(friction), test.record.motion) - found.offset


def score(model: Any, test: TestRecord | Split) -> tuple[float, float, np.ndarray]:
    """Exact-mode NMSE [%] and normalised MAX error of `model` on a test record (a `Split` stands for its test
    part without an initialisation window), and its free-run prediction over the whole record."""
    if isinstance(test, Split):
        test = test.test_record(init_window=0)
    full_prediction = free_run(model, test.record)
    result, _ = score_prediction(full_prediction, test)
    return result.nmse, result.max_error, full_prediction


def reference_scores(tests: list[TestRecord]) -> dict[str, Score]:
    """The noise floor: each synthetic test record's `reference` force (true model + sensor drift and offset),
    scored like the models (same initialisation window)."""
    return {t.name: score_prediction(t.reference, t)[0] for t in tests if t.reference is not None}


VALIDATION_BLOCKS = 16
SIGNIFICANT_T = 2.0


def paired_validation_gain(reference: Any, candidate: Any, split: Split) -> tuple[float, float]:
    """How much better `candidate` predicts the validation part than `reference` (exact-mode free runs from the
    record's start): the relative drop of the mean squared error, and the paired t statistic of the drops over
    `VALIDATION_BLOCKS` consecutive blocks (blocks, not samples: the errors of a free run are correlated over
    many samples). The neural models keep their output-error (NOE) stage only when t >= `SIGNIFICANT_T`:
    measured on the mixed regime, NOE improved their validation error by 1-2 % at t = 0.2-0.7, and such
    iterates scored from 0.75x to 4x the least-squares start's test error as the records changed by round-off
    or the learning rate and the trained weights were varied (benchmarks/README.md)."""
    record = split.until_validation_end
    measured = np.asarray(record.force, np.float64)[split.train_end :]
    size = max(len(measured) // VALIDATION_BLOCKS, 1)
    count = len(measured) // size
    magnitude = float(np.max(np.abs(measured), initial=0.0)) or 1.0  # scale before squaring (forces of 1e200 N)

    def block_errors(model: Any) -> np.ndarray:
        error = (np.asarray(free_run(model, record), np.float64)[split.train_end :] - measured) / magnitude
        return np.mean(error[: count * size].reshape(count, size) ** 2, axis=1)

    before, after = block_errors(reference), block_errors(candidate)
    drops = before - after
    spread = np.std(drops, ddof=1) / np.sqrt(count) if count > 1 else 0.0
    t = float(np.mean(drops) / spread) if spread > 0 else (np.inf if np.mean(drops) > 0 else 0.0)
    return float(np.mean(drops) / np.mean(before)), t


@dataclasses.dataclass
class ModelScore:
    """One row of the comparison table: `nmse`, `max_error` and `prediction` (offset-corrected, on the scored
    part) are those of the first test record; `tests` holds the `Score` on every test record by name,
    `test_predictions` the raw free-run prediction over each whole test record, `full_prediction` the one over
    the training record (for ensemble weights), `validation_nmse` the NMSE [%] on the validation part."""

    name: str
    label: str
    nmse: float
    max_error: float
    fit_time: float
    num_parameters: int
    result: str
    model: Any
    prediction: np.ndarray
    full_prediction: np.ndarray | None = None
    message: str = ""
    tests: dict[str, Score] = dataclasses.field(default_factory=dict)
    test_predictions: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    test_states: dict[str, Any] = dataclasses.field(default_factory=dict)  # the initial state found on each window
    validation_nmse: float = float("nan")
    std: Any = None
    records: Any = None  # several training records: the fit's `fj.RecordNuisances`
    notes: tuple[str, ...] = ()  # what the table flags: an implausible fitted model, worse than a constant force


def is_ensemble(row: Any) -> bool:
    """Whether a row is one of compare's ensembles (`ensemble_*`: fitted on the validation part)."""
    return str(row.name).startswith("ensemble")


def count_parameters(model: Any) -> int:
    """The number of trainable scalars of `model` (`fj.trainable_filter`: `Fixed` leaves and smoothing widths
    excluded), the parameter count of the comparison table."""
    import equinox as eqx
    import jax

    from ..._constraints import trainable_filter

    params = eqx.filter(model, trainable_filter(model))
    return int(sum(np.size(leaf) for leaf in jax.tree_util.tree_leaves(params)))


def score_row(
    name: str,
    label: str,
    model: Any,
    full_prediction: np.ndarray | None,
    test_predictions: dict[str, np.ndarray],
    split: Any,
    tests: list[TestRecord],
    validation_nmse: float | None = None,
    **extra: Any,
) -> ModelScore:
    """A row of the table from a model's free-run predictions (`full_prediction` over the training record,
    `test_predictions` over each whole test record): each test record scored (`score_prediction`) and the
    validation part's NMSE (given as `validation_nmse` for several training records); `extra` fills the other
    fields of `ModelScore`."""
    scores, corrected = {}, {}
    for test in tests:
        scores[test.name], corrected[test.name] = score_prediction(test_predictions[test.name], test)
    if validation_nmse is None:
        assert full_prediction is not None
        measured = np.asarray(split.full.force)
        val = slice(split.train_end, split.validation_end)
        validation_nmse = float(nmse(measured[val], full_prediction[val]))
    first = scores[tests[0].name]
    notes = (*_poor_predictions(validation_nmse, scores), *extra.pop("notes", ()))  # the prediction first
    return ModelScore(
        name,
        label,
        first.nmse,
        first.max_error,
        model=model,
        prediction=corrected[tests[0].name],
        full_prediction=full_prediction,
        tests=scores,
        test_predictions=test_predictions,
        validation_nmse=validation_nmse,
        notes=notes,
        **extra,
    )


def _poor_predictions(validation_nmse: float, scores: dict[str, Score]) -> list[str]:
    """Where a model's NMSE is above 100 % (it predicts the force worse than its mean would; a fit that stopped
    `successful` can still be there), and where a test record's is above 50 % (most of its force missed)."""
    parts = [f"validation {validation_nmse:.0f} %"] if validation_nmse > 100 else []
    several = len(scores) > 1
    for i, score in enumerate(scores.values()):
        if score.nmse > 100:
            parts.append(f"test{f' {i + 1}' if several else ''} {score.nmse:.0f} %")
    notes = [f"NMSE above 100 % ({', '.join(parts)}): worse than a constant force"] if parts else []
    misses = [
        f"test{f' {i + 1}' if several else ''} {score.nmse:.0f} %"
        for i, score in enumerate(scores.values())
        if 50 < score.nmse <= 100
    ]
    if misses:
        notes.append(f"NMSE above 50 % ({', '.join(misses)}): most of that record's force is not predicted")
    return notes


def rows_on_test(rows: list[ModelScore], test: TestRecord) -> list[ModelScore]:
    """The rows as scored on `test` (one of their test records): `nmse`, `max_error` and the offset-corrected
    `prediction` on its scored part, for the figures of a test record other than the first."""
    return [
        dataclasses.replace(
            r,
            nmse=r.tests[test.name].nmse,
            max_error=r.tests[test.name].max_error,
            prediction=score_prediction(r.test_predictions[test.name], test)[1],
        )
        for r in rows
    ]


def residuals_on(test: TestRecord, prediction: Any) -> ResidualAnalysis | str:
    """The `fj.ResidualAnalysis` of an offset-corrected prediction on the scored part of `test`, against the velocity
    (the input), or why there is none (a prediction that is not finite): compare's and predict's verdicts."""
    measured = np.asarray(test.record.force, dtype=float)[test.scored_start :]
    velocity = np.asarray(test.record.motion.samples().v, dtype=float)[test.scored_start :]
    try:
        lags = min(25, measured.size // 2 - 1)
        return residual_analysis(measured, np.asarray(prediction, float), velocity, max_lag=lags, input_name="v")
    except ValueError as err:
        return "no residual analysis: " + str(err).removeprefix("residual_analysis: ")


def residual_summary(analysis: ResidualAnalysis | str) -> dict[str, Any]:
    """`residuals_on`'s answer for a report: whiteness, independence of v and the verdict line."""
    if isinstance(analysis, str):
        return {"verdict": analysis}
    return {"white": analysis.white, "independent_of_velocity": analysis.independent, "verdict": analysis.verdict()}
