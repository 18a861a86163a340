"""The solver interface of the one optimisation loop, and its adapters for optax and optimistix.

A solver is a small state machine over a problem (optimistix's `AbstractIterativeSolver`, reduced to what a fit
needs):

- `init(problem, y, args) -> state`
- `step(problem, y, args, state) -> (y, state, ok)`: one step; `ok` is False when the step met a non-finite value
  (the loop then keeps the last good `y` and stops that start);
- `terminate(problem, y, args, state) -> (done, result)`: the solver's own convergence test and its verdict (a
  `fj.RESULTS` item);
- `restarts_at_checks`: True for solvers that restart (`init`) at a check of the loop where the projection onto the
  bounds (`Problem.project`) moved the iterate (they keep copies of it); most solvers keep their state;
- `failure(state) -> str`: a few words on a failure the solver reported (for the fit's message).

`problem` is the fit's `Problem`: `problem.objective(y, args)` (a scalar loss), `problem.residuals(y, args)` (the
residual vector of a least-squares loss) and `problem.project(y)`. `y` is any pytree of arrays. The loop
(`_loop.run_steps`) owns `jit`, `vmap` over starts, the step count and the finite guard; solvers only step.

`as_solver` turns what users pass to `fj.fit(solver=...)` into one: an optax `GradientTransformation` becomes an
`OptaxSolver`, an optimistix least-squares solver or minimiser an `OptimistixSolver`.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import optax
import optimistix as optx

from ._solution import RESULTS


def tree_finite(tree: Any) -> jax.Array:
    """True when every floating leaf of `tree` is finite."""
    leaves = [jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(tree) if eqx.is_inexact_array(x)]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.asarray(True)


def dense_gauss_newton(residuals: Any, flat: jax.Array) -> tuple[jax.Array, jax.Array]:
    """`([J r]^T [J r], r)`: the Gauss-Newton products of the vector `residuals(flat)` (its dense Jacobian J by
    forward mode, one pass with the residuals) and the residuals."""

    def twice(q: jax.Array) -> tuple[jax.Array, jax.Array]:
        r = residuals(q)
        return r, r

    J, r = jax.jacfwd(twice, has_aux=True)(flat)
    Jr = jnp.concatenate([J, r[:, None]], axis=1)
    return jnp.matmul(Jr.T, Jr, precision=jax.lax.Precision.HIGHEST), r


class AbstractSolver(eqx.Module):
    """A solver of the fit loop: `init` / `step` / `terminate` over a state (see the module docstring)."""

    @property
    def kind(self) -> str:
        """A short name for progress bars and messages ("optax", "least_squares", "minimise")."""
        return type(self).__name__

    @property
    def name(self) -> str:
        """The solver in a message ("the optimistix solver converged")."""
        return f"{type(self).__name__} solver"

    @abc.abstractmethod
    def init(self, problem: Any, y: Any, args: Any) -> Any: ...

    @abc.abstractmethod
    def step(self, problem: Any, y: Any, args: Any, state: Any) -> tuple[Any, Any, jax.Array]: ...

    def terminate(self, problem: Any, y: Any, args: Any, state: Any) -> tuple[jax.Array, Any]:
        """Never converged by itself (a fixed budget, or the loop's own stopping rules)."""
        return jnp.asarray(False), RESULTS.successful

    #: whether the loop re-initialises the solver at each check (see `OptimistixSolver`)
    restarts_at_checks: ClassVar[bool] = False

    def failure(self, state: Any) -> str:
        return "unknown failure"


class AbstractHostSolver(AbstractSolver):
    """A solver whose steps the loop drives from the host (`_loop.run_steps_on_host`): each step evaluates every
    start's trial point in one compiled program (`evaluate`), and the solver proposes the trial (`propose`) and judges
    it (`judge`) in NumPy, from a state of its own (`start_state`). The loop asks the class, never an attribute:
    fricjax's Levenberg-Marquardt is one."""

    @abc.abstractmethod
    def evaluate(self, problem: Any, y: Any, args: Any) -> tuple[Any, jax.Array, jax.Array]:
        """At a point: the point as evaluated (projected), the products the solver needs, the loss."""

    @abc.abstractmethod
    def start_state(self, xp: Any, flat: Any) -> Any:
        """The solver's state for the starts `flat` (one row each), in the array module `xp`."""

    @abc.abstractmethod
    def propose(self, xp: Any, state: Any, flat: Any) -> Any:
        """The step to each start's next trial point."""

    @abc.abstractmethod
    def judge(self, xp: Any, state: Any, flat: Any, trial: Any, products: Any, loss: Any) -> tuple[Any, Any, Any]:
        """The new state, which trials are accepted, and which evaluations were sound (finite)."""


class OptaxSolver(AbstractSolver):
    """An optax `GradientTransformation` as a solver: value and gradient of `problem.objective`, the transformation's
    update (extra arguments `value`, `grad`, `value_fn` for L-BFGS' line search), then the projection onto the
    problem's bounds. `ok` is False when the value, the gradient or the new parameters are not finite.

    ```python
    >>> import optax, fricjax as fj
    >>> fj.OptaxSolver(optax.adam(1e-2)).kind
    'optax'
    ```
    """

    transformation: optax.GradientTransformation

    @property
    def kind(self) -> str:
        return "optax"

    def init(self, problem: Any, y: Any, args: Any) -> Any:
        return self.transformation.init(y)

    def step(self, problem: Any, y: Any, args: Any, state: Any) -> tuple[Any, Any, jax.Array]:
        transformation = optax.with_extra_args_support(self.transformation)
        value, grads = jax.value_and_grad(problem.objective)(y, args)
        updates, new_state = transformation.update(
            grads, state, y, value=value, grad=grads, value_fn=lambda p: problem.objective(p, args)
        )
        new_y = problem.project(optax.apply_updates(y, updates))
        ok = jnp.isfinite(value) & tree_finite(grads) & tree_finite(new_y)
        return new_y, new_state, ok


class _OptimistixState(eqx.Module):
    inner: Any
    done: jax.Array
    result: optx.RESULTS


class OptimistixSolver(AbstractSolver):
    """An optimistix least-squares solver (Levenberg-Marquardt, Gauss-Newton, Dogleg; on `problem.residuals`) or
    minimiser (BFGS, ...; on `problem.objective`), stepped by fricjax's loop exactly as `optx.least_squares` /
    `optx.minimise` step it: the same `init`, `step` and `terminate` calls, a start stopping at its solver's
    convergence test or a non-finite iterate.

    optimistix solvers keep copies of the iterate in their state; at a check where the loop's projection onto the
    problem's bounds (damping coefficients back to >= 0) moved the iterate, the solver restarts from it
    (`restarts_at_checks`); otherwise it goes on from its state (its trust region and pending step intact).
    """

    solver: optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser
    restarts_at_checks: ClassVar[bool] = True

    @property
    def kind(self) -> str:
        return "least_squares" if isinstance(self.solver, optx.AbstractLeastSquaresSolver) else "minimise"

    @property
    def name(self) -> str:
        return "optimistix solver"

    def _fn(self, problem: Any) -> Any:
        if isinstance(self.solver, optx.AbstractLeastSquaresSolver):
            return lambda y, args: (problem.residuals(y, args), None)
        return lambda y, args: (problem.objective(y, args), None)

    def init(self, problem: Any, y: Any, args: Any) -> Any:
        fn = self._fn(problem)
        f_struct, aux_struct = eqx.filter_eval_shape(fn, y, args)  # `args` may hold functions (an activation)
        inner = self.solver.init(fn, y, args, {}, f_struct, aux_struct, frozenset())
        done, result = self.solver.terminate(fn, y, args, {}, inner, frozenset())
        result = optx.RESULTS.where(tree_finite(y), result, optx.RESULTS.nonfinite)
        return _OptimistixState(inner, done, result)

    def step(self, problem: Any, y: Any, args: Any, state: Any) -> tuple[Any, Any, jax.Array]:
        fn = self._fn(problem)
        new_y, inner, _ = self.solver.step(fn, y, args, {}, state.inner, frozenset())
        done, result = self.solver.terminate(fn, y, args, {}, inner, frozenset())  # as optimistix: the previous y
        result = optx.RESULTS.where(tree_finite(y), result, optx.RESULTS.nonfinite)
        return new_y, _OptimistixState(inner, done, result), jnp.asarray(True)

    def terminate(self, problem: Any, y: Any, args: Any, state: Any) -> tuple[jax.Array, Any]:
        ok = state.result == optx.RESULTS.successful
        failed = jnp.invert(ok)
        verdict = RESULTS.where(ok, RESULTS.successful, RESULTS.solver_failed)  # type: ignore[arg-type]
        return state.done | failed, verdict

    def failure(self, state: Any) -> str:
        return optx.RESULTS[state.result] or "unknown failure"  # type: ignore[misc] # the item's sentence


def as_solver(solver: Any, where: str = "fit") -> AbstractSolver:
    """A fricjax solver from an optax transformation, an optimistix solver, or a fricjax solver (returned as it is)."""
    if isinstance(solver, AbstractSolver):
        return solver
    if isinstance(solver, (optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser)):
        return OptimistixSolver(solver)
    if isinstance(solver, optax.GradientTransformation):
        return OptaxSolver(solver)
    raise TypeError(
        f"{where}: `solver` must be an optax GradientTransformation (e.g. optax.adam(1e-2)), an optimistix "
        f"least-squares solver / minimiser (e.g. fj.levenberg_marquardt()) or a fricjax solver (fj.OptaxSolver, "
        f"fj.OptimistixSolver), got {type(solver).__name__}."
    )
