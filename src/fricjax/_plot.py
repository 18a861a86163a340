"""Figures: friction-displacement hysteresis loops and friction-velocity curves (the figures of `compare` are in
`fricjax._protocols.compare._figures`)."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

import numpy as np


def subplots(*args: Any, pyplot: bool = True, **kwargs: Any) -> tuple[Any, Any]:
    """A figure and its axes (`plt.subplots`' arguments). `pyplot=True`: through pyplot, with the user's backend, so
    a notebook shows it; `pyplot=False`: a `matplotlib.figure.Figure` no backend holds, for a file the command line
    writes (fricjax never switches the backend: `matplotlib.use('Agg')` in a notebook silenced every later figure)."""
    if pyplot:
        import matplotlib.pyplot as plt

        return plt.subplots(*args, **kwargs)
    from matplotlib.figure import Figure

    layout = {key: kwargs.pop(key) for key in ("figsize", "constrained_layout", "layout") if key in kwargs}
    figure = Figure(**layout)
    return figure, figure.subplots(*args, **kwargs)


def plot_loops(
    motion: Any,
    forces: Mapping[str, Any],
    *,
    presliding_window: tuple[int, int] | None = None,
    velocity_only: Collection[str] = (),
    title: str = "",
    pyplot: bool = True,
) -> Any:
    """Three panels: F(x) in pre-sliding (first samples), F(x) over the whole record, and F(v).

    **Arguments:** `motion` a `Motion` with `x` and `v`; `forces` {label: force array (T,)};
    `presliding_window` sample range of the pre-sliding panel (default: the first quarter);
    `velocity_only` labels drawn only in the F(v) panel (static curves, whose F(x) is a square wave); `pyplot`
    False for a figure outside pyplot (to save to a file; see `subplots`).
    **Returns:** the matplotlib `Figure`.
    """
    x = np.asarray(motion.x) * 1e6
    v = np.asarray(motion.v) * 1e3
    start, stop = presliding_window or (0, len(x) // 4)
    fig, axes = subplots(1, 3, figsize=(15, 4.6), constrained_layout=True, pyplot=pyplot)
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


def plot_residual_analysis(analyses: Mapping[str, Any], *, title: str = "", pyplot: bool = True) -> Any:
    """Residual analysis figure (MATLAB's `resid` layout): for each `fj.ResidualAnalysis` in `analyses` {label:
    analysis}, the residual's autocorrelation (left) and its cross-correlation with the input (right), with the
    confidence band shaded; `pyplot` False for a figure outside pyplot (to save to a file). **Returns:** the
    matplotlib `Figure`."""
    rows = max(len(analyses), 1)
    fig, axes = subplots(rows, 2, figsize=(10, 1.9 * rows + 0.6), squeeze=False, pyplot=pyplot)
    for (label, analysis), (auto_ax, cross_ax) in zip(analyses.items(), axes, strict=False):
        for ax, lags, values, name, band in (
            (auto_ax, analysis.lags[1:], analysis.autocorrelation[1:], "autocorrelation of e", analysis.band),
            (
                cross_ax,
                analysis.cross_lags,
                analysis.cross_correlation,
                f"cross-correlation of {analysis.input_name}, e",
                analysis.cross_band,
            ),
        ):
            ax.axhspan(-band, band, color="0.85", lw=0)
            outside = np.abs(values) > band
            ax.vlines(lags, 0, values, colors=np.where(outside, "C3", "C0"), lw=1.5)
            ax.axhline(0, color="k", lw=0.5)
            ax.set_title(f"{label}: {name}", fontsize=8, loc="left")
        cross_ax.set_xlabel("lag [samples]") if label == list(analyses)[-1] else None
        auto_ax.set_xlabel("lag [samples]") if label == list(analyses)[-1] else None
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
