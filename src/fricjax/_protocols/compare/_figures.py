"""The figures of `compare`: prediction errors on a test record per model (`plot_prediction_errors`), measured
vs predicted friction-displacement loops of the best models (`plot_test_loops`), and with several test records
each model's NMSE on each (`plot_test_records`)."""

from __future__ import annotations

import pathlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._plot import subplots
from ._scoring import is_ensemble


def _display(units: Any) -> tuple[float, str, str]:
    """(factor from SI to the displayed displacement unit, that unit, the force unit): a record given in SI is
    shown in µm (pre-sliding scales), one given in other units in those units."""
    if units is None or (units.x == "m" and units.force == "N"):
        return 1e6, "µm", "N"
    return 1.0 / units.x_factor, units.x, units.force


def _stride(n: int, limit: int = 20_000) -> int:
    """A stride that keeps at most `limit` points of a long record in a figure."""
    return max(1, -(-n // limit))


def plot_prediction_errors(
    rows: Sequence[Any], test: Any, path: Any, *, units: Any = None, label: str | None = None
) -> None:
    """Prediction errors on a test record per model, one panel each with its own error scale (parlitz2004 Fig. 6
    layout). `rows`: scored models with `label`, `nmse`, `max_error`, `prediction` (offset-corrected, on the
    scored part); `test`: the `fj.compare.TestRecord` (or a `Split`: its test part); `units`: the record's units
    (forces are shown in them); `label`: the record's name in the title (default: its file name)."""
    test = _as_test(test)
    _, _, f_unit = _display(units)
    f_scale = 1.0 if units is None else 1.0 / units.force_factor
    ordered = sorted(rows, key=lambda r: (not np.isfinite(r.nmse), np.nan_to_num(r.nmse)))
    measured = np.asarray(test.record.force)[test.scored_start :]
    t = np.arange(measured.size) * float(np.asarray(test.record.motion.dt))
    step = _stride(measured.size)
    fig, axes = subplots(len(ordered) + 1, 1, figsize=(10, 1.6 * (len(ordered) + 1)), sharex=True, pyplot=False)
    axes[0].plot(t[::step], f_scale * measured[::step], "k", lw=0.7)
    axes[0].set_ylabel(f"F [{f_unit}]")
    axes[0].set_title(
        f"{_record_name(test, label)}: measured force (top), prediction errors e = F_hat - F (below, each its own "
        "scale)",
        fontsize=9,
    )
    for ax, r in zip(axes[1:], ordered, strict=True):
        error = f_scale * (np.asarray(r.prediction) - measured)
        ax.plot(t[::step], error[::step], lw=0.6)
        limit = float(np.nanmax(np.abs(error))) if np.isfinite(error).any() else 1.0
        ax.set_ylim(-1.05 * limit, 1.05 * limit)
        # above the panel, not over its trace
        ax.set_title(f"{r.label}: NMSE {r.nmse:.3g} %, MAX/std {r.max_error:.3g}", fontsize=8, loc="left", pad=2)
        ax.set_ylabel(f"e [{f_unit}]")
    axes[-1].set_xlabel("time in the scored part [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def plot_test_loops(rows: Sequence[Any], test: Any, path: Any, *, units: Any = None, label: str | None = None) -> None:
    """Measured vs predicted friction-displacement loops on a test record's scored part: the four best distinct
    models (`distinct_models`: the ensembles, whose predictions are near-identical mixtures of the best single
    model, count as one); `label`: the record's name in the title (default: its file name)."""
    test = _as_test(test)
    x_scale, x_unit, f_unit = _display(units)
    f_scale = 1.0 if units is None else 1.0 / units.force_factor
    ordered = distinct_models(rows, 4)
    x = np.asarray(test.record.motion.samples().x)[test.scored_start :] * x_scale
    measured = np.asarray(test.record.force)[test.scored_start :] * f_scale
    step = _stride(x.size)
    fig, axes = subplots(1, len(ordered), figsize=(4 * len(ordered), 3.8), squeeze=False, pyplot=False)
    for ax, r in zip(axes[0], ordered, strict=True):
        ax.plot(x[::step], measured[::step], color="0.6", lw=0.8, label="measured")
        ax.plot(x[::step], f_scale * np.asarray(r.prediction)[::step], "r", lw=0.6, label="predicted")
        ax.set(title=f"{r.label}\nNMSE {r.nmse:.3g} %", xlabel=f"x [{x_unit}]", ylabel=f"F [{f_unit}]")
    axes[0][0].legend(fontsize=8, loc="lower right", framealpha=0.9)
    fig.suptitle(f"{_record_name(test, label)}: friction-displacement loops", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def plot_test_records(rows: Sequence[Any], labels: Sequence[str], path: Any) -> None:
    """Each model's free-run NMSE on every test record (log scale), one line per model in the table's order: how
    each model carries over to records it was not fitted on. `rows`: scored models with `label` and `tests` (the
    `Score` on each test record, in order); `labels`: the test records' names."""
    ordered = sorted(rows, key=lambda r: (not np.isfinite(r.nmse), np.nan_to_num(r.nmse)))
    positions = np.arange(len(labels))
    fig, ax = subplots(figsize=(max(6.0, 1.2 * len(labels) + 3.0), 4.2), pyplot=False)
    for r in ordered:
        values = np.array([score.nmse for score in r.tests.values()], dtype=float)
        values = np.where(np.isfinite(values) & (values > 0), values, np.nan)
        ax.plot(positions, values, "o-", lw=1.0, ms=4, label=r.label)
    ax.set_yscale("log")
    ax.set_xticks(positions, [str(label) for label in labels], rotation=30, ha="right", fontsize=8)
    ax.set(ylabel="free-run NMSE [%]", title="test NMSE of each model on each test record")
    ax.grid(True, which="both", alpha=0.3)
    # below the axes, in columns: a legend beside them took most of the width from the plot
    below = 0.1 + 0.008 * max((len(str(label)) for label in labels), default=0)  # under the rotated names
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -below), ncol=3, frameon=False)
    fig.savefig(path, dpi=100, bbox_inches="tight")  # the canvas grows to hold the rotated names and the legend


def distinct_models(rows: Sequence[Any], count: int) -> list[Any]:
    """The `count` best rows by test NMSE with at most one ensemble (rows named `ensemble_*`): the best of each
    model, not three near-identical mixtures of one."""
    ordered = sorted(rows, key=lambda r: (not np.isfinite(r.nmse), np.nan_to_num(r.nmse)))
    out, ensemble = [], False
    for row in ordered:
        if is_ensemble(row) and ensemble:
            continue
        ensemble |= is_ensemble(row)
        out.append(row)
        if len(out) == count:
            break
    return out


def _record_name(test: Any, label: str | None) -> str:
    """A test record's name in a title: `label`, else its file name (a path overflows), else its name."""
    return label or pathlib.PurePath(test.name).name or test.name


def _as_test(test: Any) -> Any:
    return test.test_record(init_window=0) if hasattr(test, "test_record") else test
