"""How a fit says why it stopped: the result code and sentence of a fit that no stopping rule ended
(`stopping_reason`), the budget's sentence for solvers without a convergence test (`budget_message`), and the advice
for large real parameters stepped as stored (`scaling_hint`)."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import numpy as np

from ..._constraints import AbstractUnwrappable


def scaling_hint(params: Any) -> str:
    """Advice for a fit that stopped short without `scaling`: the trained real (not log-stored) parameters above
    1e3, which a solver steps as stored (a damping of 7e4 N s/m barely moves), and the fix; "" if none. (Small
    ones are not named: a network's weights start near 0, and scaling would slow them down.)"""
    large = []
    leaves = jax.tree_util.tree_leaves_with_path(params, is_leaf=lambda n: isinstance(n, AbstractUnwrappable))
    for path, leaf in leaves:
        if isinstance(leaf, AbstractUnwrappable) or not eqx.is_inexact_array(leaf):
            continue
        magnitude = float(np.max(np.abs(np.asarray(leaf)))) if np.size(leaf) else 0.0
        if magnitude > 1e3:
            large.append(f"{jax.tree_util.keystr(path).lstrip('.')} = {magnitude:.3g}")
    if not large:
        return ""
    return (
        f" (large real parameters, {', '.join(large[:3])}, are stepped as stored: pass "
        "scaling=fj.ParameterScaling(), which scales each by its magnitude)"
    )


def stopping_reason(
    solver: Any, outcome: Any, converged: str, best: int, steps: int, losses: list[Any], best_diverged: bool
) -> tuple[str, str]:
    """The result code and sentence of a fit that no stopping rule (divergence, early stopping) ended."""
    if converged:  # the tolerance rule ended the last stage
        return "successful", converged
    if solver.kind != "optax" and outcome is not None and outcome.results:
        code = outcome.results[best]
        if code == "successful":
            return code, f"the {solver.name} converged"
        if code == "max_steps":
            return code, f"the {solver.name} reached max_steps = {steps} before converging"
        state = jax.tree_util.tree_map(lambda a: a[best], outcome.states)
        return code, f"the {solver.name} failed ({solver.failure(state)}); the best model seen was kept"
    if best_diverged:
        return "diverged", "the chosen start diverged; its last good parameters were kept"
    return "max_steps", budget_message(steps, losses)


def budget_message(steps: int, losses: list[Any]) -> str:
    """Why a fit without a convergence test stopped at its budget, in a sentence: still improving, or levelled off."""
    finite = [float(x) for x in losses if np.isfinite(x)]
    if len(finite) < 2:
        return f"ran the full budget of {steps} steps (no convergence test for optax solvers)"
    previous, last = finite[-2], finite[-1]
    change = (previous - last) / max(abs(previous), 1e-300)
    best = min(finite)
    if last > 2 * best and best > 0:  # falling again, but far above where it was: the steps overshoot
        return (
            f"stopped at the step budget ({steps} steps) with the loss at {last / best:.3g}x the best seen "
            f"({best:.4g}): the steps overshoot; the best model seen is returned: lower the learning rate"
        )
    if change > 1e-3:
        return (
            f"stopped at the step budget ({steps} steps) while the loss was still falling ({100 * change:.2g} % over "
            "the last check): not converged; raise `steps` to go on"
        )
    if change < -1e-3:
        return (
            f"stopped at the step budget ({steps} steps) with the loss rising or oscillating at the end "
            f"({100 * -change:.2g} % up over the last check); the best model seen is returned: lower the learning rate"
        )
    return f"ran the full budget of {steps} steps; the loss had levelled off (change {100 * change:.2g} % at the end)"
