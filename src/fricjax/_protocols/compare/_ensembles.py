"""Ensembles of the fitted models (`add_ensembles`): the average, least-squares weights fitted on the validation
part, and the PRESS forward selection, scored on every test record like the single models."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np

from ._records import Split, TestRecord
from ._scoring import ModelScore, free_run, score_row


def add_ensembles(rows: list[ModelScore], split: Split, tests: list[TestRecord] | None = None) -> list[ModelScore]:
    """Average and least-squares-weighted ensembles (weights with intercept fitted on the validation part,
    parlitz2004 §IV-H, emps-ensemble §3.3), and the PRESS forward selection of worden2007 §7, scored on every
    test record like the single models (default: the split's test part)."""
    from ..._estimation.families._ensemble_fit import fit_weighted_ensemble, select_forward
    from ..._models.combine._ensemble import AverageEnsemble

    if len(rows) < 2:
        return []
    tests = [split.test_record()] if tests is None else list(tests)
    members = [row.model for row in rows]
    full_predictions = np.stack(
        [row.full_prediction if row.full_prediction is not None else free_run(row.model, split.full) for row in rows]
    )

    def member_predictions(test: TestRecord) -> np.ndarray:
        if all(test.name in row.test_predictions for row in rows):
            return np.stack([row.test_predictions[test.name] for row in rows])
        return np.stack([free_run(row.model, test.record) for row in rows])

    per_test = {test.name: member_predictions(test) for test in tests}
    val = slice(split.train_end, split.validation_end)
    val_data = split.full.slice(split.train_end, split.validation_end)

    def row(
        name: str, label: str, ensemble: Any, combine: Callable[[np.ndarray], np.ndarray], count: int, start: float
    ) -> Any:
        """The ensemble's row; `start`: when its fit (weights, selection) began, for the fit time."""
        full = combine(full_predictions)
        predictions = {key: combine(value) for key, value in per_test.items()}
        return score_row(
            name,
            label,
            ensemble,
            full,
            predictions,
            split,
            tests,
            fit_time=time.perf_counter() - start,
            num_parameters=count,
            result="successful",
        )

    start = time.perf_counter()
    out = [row("ensemble_average", "Ensemble: average", AverageEnsemble(members), lambda p: p.mean(axis=0), 0, start)]
    start = time.perf_counter()
    weighted = fit_weighted_ensemble(members, val_data, predictions=full_predictions[:, val])
    out.append(
        row(
            "ensemble_weighted",
            "Ensemble: LS weights",
            weighted,
            lambda p: np.asarray(weighted.combine(jnp.asarray(p.T))),
            len(members) + 1,
            start,
        )
    )
    start = time.perf_counter()
    selection = select_forward(members, val_data, predictions=full_predictions[:, val])
    chosen = list(selection.indices)
    names = "+".join(rows[i].name for i in chosen)
    out.append(
        row(
            "ensemble_press",
            f"Ensemble: PRESS ({names})",
            selection.ensemble,
            lambda p: np.asarray(selection.ensemble.combine(jnp.asarray(p[chosen].T))),
            len(chosen) + 1,
            start,
        )
    )
    return out
