"""Figures: friction-displacement hysteresis loops and friction-velocity curves."""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np


def plot_loops(
    motion: Any,
    forces: Mapping[str, Any],
    *,
    presliding_window: tuple[int, int] | None = None,
    velocity_only: Collection[str] = (),
    title: str = "",
) -> Any:
    """Three panels: F(x) in pre-sliding (first samples), F(x) over the whole record, and F(v).

    **Arguments:** `motion` a `Motion` with `x` and `v`; `forces` {label: force array (T,)};
    `presliding_window` sample range of the pre-sliding panel (default: the first quarter);
    `velocity_only` labels drawn only in the F(v) panel (static curves, whose F(x) is a square wave).
    **Returns:** the matplotlib `Figure`.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    x = np.asarray(motion.x) * 1e6
    v = np.asarray(motion.v) * 1e3
    start, stop = presliding_window or (0, len(x) // 4)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    for label, force in forces.items():
        force = np.asarray(force)
        style = {"lw": 0.8, "label": label}
        if label in velocity_only:
            axes[2].plot(v, force, ls="--", color="k", **style)
            continue
        axes[0].plot(x[start:stop], force[start:stop], **style)
        axes[1].plot(x, force, **style)
        axes[2].plot(v, force, **style)
    axes[0].set(xlabel="displacement x [µm]", ylabel="friction force F [N]", title="pre-sliding: hysteresis loops")
    axes[1].set(xlabel="displacement x [µm]", ylabel="F [N]", title="pre-sliding into gross sliding")
    axes[2].set(xlabel="velocity v [mm/s]", ylabel="F [N]", title="friction-velocity")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[2].legend(fontsize=8, loc="lower right")
    if title:
        fig.suptitle(title)
    return fig


def plot_prediction_errors(rows: Sequence[Any], split: Any, path: Any) -> None:
    """Test-set prediction errors per model, one panel each (parlitz2004 Fig. 6 layout). `rows`: scored models
    with `label`, `nmse`, `max_error`, `prediction`; `split`: the record and its split (`fj.compare.Split`)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    ordered = sorted(rows, key=lambda r: (not np.isfinite(r.nmse), np.nan_to_num(r.nmse)))
    measured = np.asarray(split.full.force)[split.validation_end :]
    t = np.arange(measured.size) * float(np.asarray(split.full.motion.dt))
    fig, axes = plt.subplots(len(ordered) + 1, 1, figsize=(10, 1.4 * (len(ordered) + 1)), sharex=True)
    axes[0].plot(t, measured, "k", lw=0.7)
    axes[0].set_ylabel("F [N]")
    axes[0].set_title("test set: measured force (top) and prediction errors e = F_hat - F per model")
    limit = max(float(np.max(np.abs(r.prediction - measured))) for r in ordered)
    for ax, r in zip(axes[1:], ordered, strict=True):
        ax.plot(t, r.prediction - measured, lw=0.6)
        ax.set_ylim(-limit, limit)
        ax.text(0.01, 0.8, f"{r.label}: NMSE {r.nmse:.3g} %, MAX {r.max_error:.3g}", transform=ax.transAxes, fontsize=8)
        ax.set_ylabel("e [N]")
    axes[-1].set_xlabel("time in the test set [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_test_loops(rows: Sequence[Any], split: Any, path: Any) -> None:
    """Measured vs predicted friction-displacement loops on the test set, best four models."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    ordered = sorted(rows, key=lambda r: (not np.isfinite(r.nmse), np.nan_to_num(r.nmse)))[:4]
    x = np.asarray(split.full.motion.x)[split.validation_end :] * 1e6
    measured = np.asarray(split.full.force)[split.validation_end :]
    fig, axes = plt.subplots(1, len(ordered), figsize=(4 * len(ordered), 3.8), squeeze=False)
    for ax, r in zip(axes[0], ordered, strict=True):
        ax.plot(x, measured, color="0.6", lw=0.8, label="measured")
        ax.plot(x, r.prediction, "r", lw=0.6, label="predicted")
        ax.set(title=f"{r.label}\nNMSE {r.nmse:.3g} %", xlabel="x [µm]", ylabel="F [N]")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
