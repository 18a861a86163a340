"""`least_squares`: minimise the squares of any residual function of a pytree by the one optimisation loop.

For problems that are not a model simulated against a record (an error filter's coefficients, a calibration): the
residual function is the whole problem. The same loop, solvers and result codes as `fj.fit`, without its model
machinery (parameter selection, scaling, validation).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ..._validation import positive_int
from ._levenberg_marquardt import levenberg_marquardt
from ._loop import Search, run_stage
from ._solution import FitFailed, Solution
from ._solvers import as_solver, dense_gauss_newton


class ResidualProblem(eqx.Module):
    """A residual function as a problem of the loop: `objective` is half the sum of squares, no bounds, no
    validation."""

    fn: Callable[[Any, Any], jax.Array]

    def residuals(self, y: Any, args: Any) -> jax.Array:
        return self.fn(y, args)

    def objective(self, y: Any, args: Any) -> jax.Array:
        r = self.fn(y, args)
        return 0.5 * jnp.sum(r * r)

    def loss_of_residuals(self, residuals: jax.Array) -> jax.Array:
        return 0.5 * jnp.sum(residuals * residuals)

    def gauss_newton(self, y: Any, args: Any) -> tuple[jax.Array, jax.Array]:
        """`([J r]^T [J r], r)`: the residuals' Gauss-Newton products (J with respect to the flattened `y`)."""
        flat, unravel = jax.flatten_util.ravel_pytree(y)
        return dense_gauss_newton(lambda q: jnp.ravel(self.fn(unravel(q), args)), flat)

    def val_objective(self, y: Any, args: Any) -> jax.Array:
        return jnp.asarray(jnp.nan)

    def project(self, y: Any) -> Any:
        return y


def least_squares(
    residuals: Callable[[Any, Any], jax.Array],
    y0: Any,
    *,
    args: Any = None,
    solver: Any = None,
    steps: int = 256,
    throw: bool = False,
) -> Solution:
    """Minimise `0.5 * sum(residuals(y, args) ** 2)` over the pytree `y`, from `y0`, in the one optimisation loop.

    **Arguments:** `residuals(y, args)` returns a vector; `solver` an optimistix least-squares solver (default
    `fj.levenberg_marquardt()`), minimiser, optax transformation or `fj.AbstractSolver`; `steps` the step budget;
    `throw` raise `fj.FitFailed` when the solve diverged or its solver failed.

    **Returns:** a `fj.Solution` whose `model` is the solution pytree (the best iterate seen, never a non-finite
    one), `train_loss` its objective, `result` / `message` why it stopped.

    ```python
    >>> import jax.numpy as jnp, fricjax as fj
    >>> t = jnp.linspace(0.0, 1.0, 50)
    >>> sol = fj.least_squares(lambda p, _: p[0] * jnp.exp(-p[1] * t) - 2.0 * jnp.exp(-3.0 * t), jnp.array([1.0, 1.0]))
    >>> sol.code, [round(float(v), 6) for v in sol.model]
    ('successful', [2.0, 3.0])
    ```
    """
    start_time = time.perf_counter()
    steps = positive_int(steps, "steps", "least_squares")
    if not callable(residuals):
        raise TypeError(f"least_squares: `residuals` must be a function (y, args) -> vector, got {residuals!r}.")
    solver = as_solver(levenberg_marquardt() if solver is None else solver, "least_squares")
    problem = ResidualProblem(residuals)
    ys0 = jax.tree_util.tree_map(lambda a: jnp.asarray(a)[None], y0)
    search = Search(ys0, False, start_time, None)
    outcome = run_stage(solver, problem, search, args, budget=steps, check_every=steps)
    best = search.best_ys if np.isfinite(search.best_scores).any() else ys0
    y = jax.tree_util.tree_map(lambda a: a[0], best)
    loss = float(np.asarray(search.best_scores)[0]) if np.isfinite(search.best_scores).any() else np.nan
    if outcome.stop is not None:
        code, message = outcome.stop, outcome.message
    else:
        code = outcome.results[0]
        message = {
            "successful": "the solver's convergence test held",
            "max_steps": f"the step budget ({steps} steps) ran out before the solver's convergence test held",
        }.get(code) or f"the solver failed ({solver.failure(jax.tree_util.tree_map(lambda a: a[0], outcome.states))})"
    history = search.history
    solution = Solution(
        model=y,
        result=code,
        message=message,
        history={key: np.asarray([np.ravel(v)[0] for v in history[key]]) for key in ("train_loss", "val_loss")}
        | {"step": np.asarray(history["step"]), "time": np.asarray(history["time"]), "eps": np.asarray(history["eps"])},
        train_loss=loss,
        val_loss=float("nan"),
        exact_val_loss=float("nan"),
        evaluations=search.step_count,
        wall_time=time.perf_counter() - start_time,
        num_starts=1,
        best_start=0,
    )
    if throw and not solution.success:
        raise FitFailed(solution)
    return solution
