"""fricjax's own Levenberg-Marquardt solver: one forward-mode Jacobian per step in one compiled program, the rest
(a P x P damped solve, the gain ratio, the damping rule) in NumPy between calls.

Levenberg (1944), Marquardt (1963); the damping update is Nielsen's (1999, IMM-REP-1999-05; Madsen, Nielsen &
Tingleff, "Methods for non-linear least squares problems", 2004, §3.2), the scaling of the damping term Marquardt's
/ MINPACK's (the running maximum of the Jacobian's column norms, Moré 1978).

Why a solver of our own beside the optimistix adapter (`fj.OptimistixSolver(optx.LevenbergMarquardt(...))`): a
fit's first call is dominated by compiling, and XLA spends 10-50 ms on every small kernel of a program (a P x P
solve, a norm, a select), whatever its size. Here the compiled part of a step is only what needs the simulator:
`evaluate` projects the trial point onto the problem's bounds and returns `[J r]^T [J r] / R` (the Gauss-Newton
matrix, the gradient and twice the cost, from one `jax.jacfwd` pass with the residuals as its auxiliary output), a
(P + 1) x (P + 1) array per start. The loop (`_loop.run_steps_on_host`) calls that one program once per step for
all starts (vmapped) and does the algebra below in NumPy (`propose`, `judge`). An accepted trial needs no second
evaluation: its Gauss-Newton quantities are the next step's. The same algebra in `jax.numpy` makes the traced
`step` of the `AbstractSolver` interface (what `_loop.run_steps` would run inside its compiled loop).
On the 40 000-sample LuGre record of `benchmarks/fit.py --latency` this compiles one program of about 0.3 s where
optimistix's loop took 1.7 s (benchmarks/README.md).
"""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from .._lapack_threads import thin_svd
from .._validation import nonnegative_float
from ._solution import RESULTS
from ._solvers import AbstractSolver, tree_finite

#: a trial is accepted when it achieves this fraction of the decrease the linear model predicted
_ACCEPT_RATIO = 1e-4
#: damping beyond which no step lowers the cost (a minimum to round-off): the start has converged
_MAX_DAMPING = 1e30


class LMState(eqx.Module):
    """The state of one start (or, on the host, a batch of starts along axis 0): the Gauss-Newton quantities at the
    current iterate once `evaluated`, per residual (divided by the residual count R)."""

    gram: Any  # J^T J / R, (P, P)
    gradient: Any  # J^T r / R, (P,)
    cost: Any  # r^T r / (2 R)
    loss: Any  # the problem's loss at the iterate (`problem.loss_of_residuals`: a fit's mean square)
    damping: Any  # lambda, relative to the scaled Gauss-Newton matrix
    growth: Any  # Nielsen's nu: the factor of lambda at the next rejected step
    scale: Any  # (P,) running maximum of the Jacobian's column norms (Marquardt's scaling)
    evaluated: Any  # False until the first step has evaluated the start
    done: Any


def _propose(xp: Any, state: LMState, flat: Any) -> tuple[Any, Any]:
    """The damped Gauss-Newton step from `flat` (batch axis first; `xp` is `numpy` or `jax.numpy`) and the updated
    column scales: `(J^T J + lambda D^2) delta = -J^T r`, solved on the scaled columns through an SVD (a pseudo-
    inverse: a singular Gauss-Newton matrix gives a finite step). Zero before the first evaluation."""
    A, g = state.gram, state.gradient
    size = A.shape[-1]
    scale = xp.maximum(state.scale, xp.sqrt(xp.maximum(xp.diagonal(A, axis1=-2, axis2=-1), 0.0)))
    safe = xp.where(scale > 0, scale, 1.0)
    damped = A / safe[..., :, None] / safe[..., None, :] + state.damping[..., None, None] * xp.eye(size)
    U, s, Vt = np.linalg.svd(damped) if xp is np else jax.vmap(thin_svd)(damped)
    kept = s > s[..., :1] * size * np.finfo(s.dtype).eps
    coefficients = xp.where(kept, xp.einsum("bij,bi->bj", U, g / safe) / xp.where(kept, s, 1.0), 0.0)
    delta = -xp.einsum("bji,bj->bi", Vt, coefficients) / safe
    return xp.where(state.evaluated[..., None], delta, 0.0), scale


def _judge(
    xp: Any, state: LMState, scale: Any, flat: Any, trial: Any, products: Any, loss: Any, rtol: float, atol: float
) -> tuple[LMState, Any, Any]:
    """The state after evaluating the trial point `trial` (`products`: `[J r]^T [J r] / R` there, `loss` the
    problem's loss), whether the trial is accepted, and whether the start is still sound (False: its own residuals
    were not finite)."""
    A, g, cost, evaluated = state.gram, state.gradient, state.cost, state.evaluated
    step = trial - flat  # the step the bounds let through
    A_new, g_new, cost_new = products[..., :-1, :-1], products[..., :-1, -1], 0.5 * products[..., -1, -1]
    predicted = -(xp.sum(g * step, axis=-1) + 0.5 * xp.einsum("bi,bij,bj->b", step, A, step))
    ratio = (cost - cost_new) / xp.maximum(predicted, np.finfo(flat.dtype).tiny)
    finite = xp.all(xp.isfinite(products), axis=(-2, -1))
    accept = finite & (~evaluated | (ratio > _ACCEPT_RATIO))
    improving = accept & evaluated
    # Nielsen: an accepted step shrinks lambda by up to 3x as the model predicted well; a rejected one grows it
    shrink = xp.maximum(1.0 / 3.0, 1.0 - (2.0 * xp.clip(ratio, 0.0, 1.0) - 1.0) ** 3)
    damping = xp.where(improving, state.damping * shrink, xp.where(accept, state.damping, state.damping * state.growth))
    safe = xp.where(scale > 0, scale, 1.0)
    size = xp.sqrt(xp.sum((step * safe) ** 2, axis=-1))
    reference = xp.sqrt(xp.sum((flat * safe) ** 2, axis=-1))
    done = (
        (improving & (cost - cost_new <= rtol * cost))
        | (evaluated & (size <= rtol * reference + atol))
        | (accept & (cost_new == 0))
        | (damping > _MAX_DAMPING)
    )
    first_scale = xp.sqrt(xp.maximum(xp.diagonal(A_new, axis1=-2, axis2=-1), 0.0))
    new_state = LMState(
        gram=xp.where(accept[..., None, None], A_new, A),
        gradient=xp.where(accept[..., None], g_new, g),
        cost=xp.where(accept, cost_new, cost),
        loss=xp.where(accept, loss, state.loss),
        damping=damping,
        growth=xp.where(accept, 2.0, 2.0 * state.growth),
        scale=xp.where(evaluated[..., None], scale, first_scale),
        evaluated=evaluated | accept,
        done=done,
    )
    return new_state, accept, evaluated | finite


class LevenbergMarquardt(AbstractSolver):
    """Levenberg-Marquardt for least-squares problems (`problem.residuals`), fricjax's own: what
    `fj.levenberg_marquardt()` returns. Its steps are driven from the host (`steps_on_host`): each step is one call
    of a compiled program that evaluates the residuals and their Jacobian at every start's trial point.

    **Arguments:** `rtol`, `atol`: a start has converged when an accepted step lowers the cost (half the mean
    square residual) by at most `rtol * cost`, or when its scaled step is at most `rtol` times the scaled iterate
    `+ atol`, or at a cost of 0. `damping`: the initial damping, relative to the scaled Gauss-Newton matrix.

    A trial is accepted when its gain ratio (actual over predicted decrease) exceeds 1e-4; the damping follows
    Nielsen's rule; a trial with non-finite residuals is rejected (larger damping). The first step evaluates the
    start; a start whose own residuals are not finite stops there (the fit reports it as diverged).

    ```python
    >>> import jax.numpy as jnp, fricjax as fj
    >>> t = jnp.linspace(0.0, 1.0, 50)
    >>> residuals = lambda p, _: p[0] * jnp.exp(-p[1] * t) - 2.0 * jnp.exp(-3.0 * t)
    >>> sol = fj.least_squares(residuals, jnp.array([1.0, 1.0]), solver=fj.LevenbergMarquardt())
    >>> sol.code, [round(float(v), 8) for v in sol.model]
    ('successful', [2.0, 3.0])
    ```
    """

    rtol: float = eqx.field(static=True, default=1e-10)
    atol: float = eqx.field(static=True, default=1e-12)
    damping: float = eqx.field(static=True, default=1e-3)

    #: the loop calls `evaluate` (compiled) and `propose` / `judge` (NumPy) instead of compiling `step` into its loop
    steps_on_host: ClassVar[bool] = True

    def __check_init__(self) -> None:
        for name in ("rtol", "atol", "damping"):
            nonnegative_float(getattr(self, name), name, "LevenbergMarquardt")

    @property
    def kind(self) -> str:
        return "least_squares"

    @property
    def name(self) -> str:
        return "Levenberg-Marquardt solver"

    def evaluate(self, problem: Any, y: Any, args: Any) -> tuple[Any, jax.Array, jax.Array]:
        """The trial point projected onto the bounds, `[J r]^T [J r] / R` there and the problem's loss (one start;
        traced)."""
        y = problem.project(y)
        flat, unravel = jax.flatten_util.ravel_pytree(y)

        def with_residuals(q: jax.Array) -> tuple[jax.Array, jax.Array]:
            residuals = problem.residuals(unravel(q), args)
            return residuals, residuals

        J, r = jax.jacfwd(with_residuals, has_aux=True)(flat)
        Jr = jnp.concatenate([J, r[:, None]], axis=1)
        products = jnp.matmul(Jr.T, Jr, precision=jax.lax.Precision.HIGHEST) / r.size
        return y, products, problem.loss_of_residuals(r)

    def propose(self, xp: Any, state: LMState, flat: Any) -> tuple[Any, Any]:
        """The damped steps of a batch of starts and their column scales (`xp`: `numpy` on the host)."""
        return _propose(xp, state, flat)

    def judge(
        self, xp: Any, state: LMState, scale: Any, flat: Any, trial: Any, products: Any, loss: Any
    ) -> tuple[Any, Any, Any]:
        """The states after the trial points were evaluated, which trials were accepted, which starts are sound."""
        return _judge(xp, state, scale, flat, trial, products, loss, self.rtol, self.atol)

    def start_state(self, xp: Any, flat: Any) -> LMState:
        """The state of a batch of starts `flat` (B, P) before their first evaluation."""
        count, size = flat.shape
        zeros = xp.zeros((count, size), flat.dtype)
        return LMState(
            gram=xp.zeros((count, size, size), flat.dtype),
            gradient=zeros,
            cost=xp.zeros(count, flat.dtype),
            loss=xp.full(count, np.nan, flat.dtype),
            damping=xp.full(count, self.damping, flat.dtype),
            growth=xp.full(count, 2.0, flat.dtype),
            scale=zeros,
            evaluated=xp.zeros(count, bool),
            done=xp.zeros(count, bool),
        )

    def init(self, problem: Any, y: Any, args: Any) -> LMState:
        flat, _ = jax.flatten_util.ravel_pytree(y)
        return jax.tree_util.tree_map(lambda a: a[0], self.start_state(jnp, flat[None]))

    def step(self, problem: Any, y: Any, args: Any, state: LMState) -> tuple[Any, LMState, jax.Array]:
        """One step, traced (the host-driven loop's `propose` / `evaluate` / `judge` in `jax.numpy`)."""
        flat, unravel = jax.flatten_util.ravel_pytree(y)
        batched = jax.tree_util.tree_map(lambda a: a[None], state)
        delta, scale = self.propose(jnp, batched, flat[None])
        trial, products, loss = self.evaluate(problem, unravel(flat + delta[0]), args)
        trial_flat, _ = jax.flatten_util.ravel_pytree(trial)
        new_state, accept, sound = self.judge(
            jnp, batched, scale, flat[None], trial_flat[None], products[None], loss[None]
        )
        new_y = jax.tree_util.tree_map(lambda a, b: jnp.where(accept[0], a, b), trial, y)
        return new_y, jax.tree_util.tree_map(lambda a: a[0], new_state), sound[0] & tree_finite(new_y)

    def terminate(self, problem: Any, y: Any, args: Any, state: LMState) -> tuple[jax.Array, Any]:
        return state.done, RESULTS.successful


def levenberg_marquardt(rtol: float = 1e-10, atol: float = 1e-12) -> LevenbergMarquardt:
    """fricjax's Levenberg-Marquardt solver (`fj.LevenbergMarquardt`) with tolerances suited to friction fits. The
    optimistix one stays available: `solver=optx.LevenbergMarquardt(rtol, atol)`."""
    return LevenbergMarquardt(rtol=rtol, atol=atol)
