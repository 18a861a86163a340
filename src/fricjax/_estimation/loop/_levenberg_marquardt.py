"""fricjax's own Levenberg-Marquardt solver: optimistix's algorithm, with one forward-mode Jacobian per step in one
compiled program and the rest (a P x P damped solve, the trust-region test) in NumPy between calls.

The algorithm is optimistix's `LevenbergMarquardt` (Levenberg 1944, Marquardt 1963; Kidger et al., optimistix): the
damped Gauss-Newton step `(J^T J + lambda I) delta = -J^T r` with `lambda = 1 / step_size`, and a classical trust
region on the ratio of the actual to the predicted decrease of `0.5 |r|^2`: a trial is accepted when it achieves 1 %
of the predicted decrease, the step size grows 3.5x when it achieves 99 %, shrinks 4x when the trial is rejected
(a non-finite trial is rejected). It converges on an accepted step that moves every parameter by less than
`atol + rtol |y|` and changes the cost by less than `atol + rtol * cost` (optimistix compares each residual's
change instead: a stricter test), and also where the full Gauss-Newton step from the new iterate would move every
parameter by less than that, or change the residuals by less than `rtol` of their norm. Same steps as
`optx.LevenbergMarquardt` on well-conditioned problems, so the fits and benchmarks tuned on it keep their minima
(the test checks the iterates against it); the step comes from the normal equations (scaled to a unit diagonal,
SVD) where optimistix solves `[J; sqrt(lambda) I]` by QR, so on a Jacobian of condition ~1e6 and beyond its last
digits are less accurate (more steps to the same tolerance), and in float32 sooner.

Bounds (damping coefficients >= 0, `Problem.project`), which optimistix does not have: `evaluate` projects each
trial onto them; with `hold_bounds=True` a parameter the projection stopped at its bound is held there (its row and
column out of the damped system: an active set, as projected Newton methods do) while the gradient points out of the
bounds. The iterates equal optimistix's until a bound binds. Clipping the trials alone (the default) pinned a LuGre
fit whose unconstrained path crosses `sigma2 < 0` to `sigma2 = 0` with steps the quadratic model did not predict:
half the trials rejected and the loss 1e-6 after 200 steps, where holding it converges in 25 (issue 56).

Why a solver of our own beside the optimistix adapter (`fj.OptimistixSolver(optx.LevenbergMarquardt(...))`): a
fit's first call is dominated by compiling, and XLA spends 10-50 ms on every small kernel of a program (a P x P
solve, a norm, a select), whatever its size. Here the compiled part of a step is only what needs the simulator:
`evaluate` projects the trial point onto the problem's bounds and returns `[J r]^T [J r]` (the Gauss-Newton
matrix, the gradient and twice the cost, from one `jax.jacfwd` pass with the residuals as its auxiliary output), a
(P + 1) x (P + 1) array per start. The loop (`_loop.run_steps_on_host`) calls that one program once per step for
all starts (vmapped) and does the algebra below in NumPy (`propose`, `judge`). An accepted trial needs no second
evaluation: its Gauss-Newton quantities are the next step's. The same algebra in `jax.numpy` makes the traced
`step` of the `AbstractSolver` interface (what `_loop.run_steps` would run inside its compiled loop).
On the 40 000-sample LuGre record of `benchmarks/fit.py --latency` a fit compiles one program of about 0.3 s where
optimistix's loop took 1.7 s (benchmarks/README.md).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ..._lapack_threads import thin_svd
from ..._validation import nonnegative_float
from ._solution import RESULTS
from ._solvers import AbstractHostSolver, tree_finite

# optimistix's `ClassicalTrustRegion`: accept at 1 % of the predicted decrease, grow the step size 3.5x at 99 %,
# shrink it 4x on a rejected trial
_LOW_CUTOFF, _HIGH_CUTOFF, _HIGH_CONSTANT, _LOW_CONSTANT = 0.01, 0.99, 3.5, 0.25


class LMState(eqx.Module):
    """The state of one start (or, on the host, a batch of starts along axis 0): the Gauss-Newton quantities at the
    current iterate once `evaluated`."""

    gram: Any  # J^T J, (P, P)
    gradient: Any  # J^T r, (P,)
    cost: Any  # r^T r / 2
    loss: Any  # the problem's loss at the iterate (`problem.loss_of_residuals`: a fit's mean square)
    step_size: Any  # the trust region: lambda = 1 / step_size
    evaluated: Any  # False until the first step has evaluated the start
    done: Any
    # per parameter: +1 (-1) where the problem's projection stopped the iterate at a lower (upper) bound, else 0
    bound: Any


def _solve(xp: Any, A: Any, g: Any, damping: Any) -> Any:
    """`(A + damping I)^-1 g` for a batch (batch axis first; `xp` is `numpy` or `jax.numpy`) through an SVD of the
    damped matrix scaled to a unit diagonal (a pseudo-inverse: a singular Gauss-Newton matrix gives a finite step;
    the damping inside the scale, so that a parameter the residuals barely see, whose diagonal the damping
    dominates, does not make the cut-off drop the well-determined directions)."""
    size = A.shape[-1]
    # a rejected non-finite trial's matrix (NumPy's SVD raises on it, and its scaling warns): the identity instead,
    # its result unused
    finite = xp.all(xp.isfinite(A), axis=(-2, -1)) & xp.all(xp.isfinite(g), axis=-1) & xp.isfinite(damping)
    A, g = xp.where(finite[..., None, None], A, xp.eye(size)), xp.where(finite[..., None], g, 0.0)
    damping = xp.where(finite, damping, 0.0)
    diagonal = xp.maximum(xp.diagonal(A, axis1=-2, axis2=-1), 0.0) + damping[..., None]
    d = xp.where(diagonal > 0, xp.sqrt(xp.where(diagonal > 0, diagonal, 1.0)), 1.0)
    damped = (A + damping[..., None, None] * xp.eye(size)) / d[..., :, None] / d[..., None, :]
    U, s, Vt = np.linalg.svd(damped) if xp is np else jax.vmap(thin_svd)(damped)
    kept = s > s[..., :1] * size * np.finfo(A.dtype).eps
    coefficients = xp.where(kept, xp.einsum("bij,bi->bj", U, g / d) / xp.where(kept, s, 1.0), 0.0)
    return xp.einsum("bji,bj->bi", Vt, coefficients) / d


def _held(bound: Any, gradient: Any) -> Any:
    """The parameters at a bound whose descent direction `-gradient` points out of the bounds: they are held there."""
    return (bound != 0) & (gradient * bound > 0)


def _without(xp: Any, A: Any, g: Any, held: Any) -> tuple[Any, Any]:
    """`J^T J` and `J^T r` with the held parameters' rows and columns removed (zeroed: their step is 0)."""
    return xp.where(held[..., :, None] | held[..., None, :], 0.0, A), xp.where(held, 0.0, g)


def _propose(xp: Any, state: LMState, flat: Any, hold: bool = False) -> Any:
    """The damped Gauss-Newton steps `-(J^T J + lambda I)^-1 J^T r` of a batch of starts, over the parameters not
    held at a bound. Zero before the first evaluation and once the step size has shrunk to round-off (optimistix:
    lambda = the largest float)."""
    usable = state.evaluated & (state.step_size > np.finfo(flat.dtype).eps)
    if not hold:
        delta = -_solve(xp, state.gram, state.gradient, 1.0 / xp.where(usable, state.step_size, 1.0))
        return xp.where(usable[..., None], delta, 0.0)
    held = _held(state.bound, state.gradient)
    A, g = _without(xp, state.gram, state.gradient, held)
    delta = -_solve(xp, A, g, 1.0 / xp.where(usable, state.step_size, 1.0))
    return xp.where(usable[..., None] & ~held, delta, 0.0)


def _judge(
    xp: Any,
    state: LMState,
    flat: Any,
    trial: Any,
    products: Any,
    loss: Any,
    rtol: float,
    atol: float,
    hold: bool = False,
) -> tuple[LMState, Any, Any]:
    """The state after evaluating the trial points `trial` (`products`: `[J r]^T [J r]` there, `loss` the
    problem's loss), which trials are accepted, and which starts are sound (False: their own residuals were not
    finite)."""
    A, g, cost, evaluated = state.gram, state.gradient, state.cost, state.evaluated
    step = trial - flat  # the step the bounds let through
    # where the problem's projection moved the proposed point (beyond a float32 rounding), the trial sits at a
    # bound; a parameter held at one stays there (a zero step) and keeps it, one that left it is free
    if hold:
        proposed = flat + _propose(xp, state, flat, hold)
        moved = xp.abs(trial - proposed) > 1e-6 * xp.maximum(xp.abs(trial), xp.abs(proposed))
        bound = xp.where(moved, xp.sign(trial - proposed), xp.where(step == 0, state.bound, 0.0))
    else:
        bound = state.bound  # all 0: no parameter is held
    A_new, g_new, cost_new = products[..., :-1, :-1], products[..., :-1, -1], 0.5 * products[..., -1, -1]
    predicted = xp.sum(g * step, axis=-1) + 0.5 * xp.einsum("bi,bij,bj->b", step, A, step)  # <= 0
    change = cost_new - cost
    finite = xp.all(xp.isfinite(products), axis=(-2, -1))
    accept = ~evaluated | (finite & (change <= _LOW_CUTOFF * predicted))
    good = evaluated & finite & (change < _HIGH_CUTOFF * predicted) & (predicted < 0)
    factor = xp.where(accept, xp.where(good, _HIGH_CONSTANT, 1.0), _LOW_CONSTANT)
    small_step = xp.all(xp.abs(step) < atol + rtol * xp.abs(trial), axis=-1)
    small_change = xp.abs(change) < atol + rtol * xp.abs(cost_new)
    # beyond optimistix: converged where the full Gauss-Newton step from the new iterate is within the same
    # tolerance (the model's minimum is there; optimistix takes further trust-region steps to see it)
    # (over the parameters not held at a bound: a minimum on the bounds)
    if hold:
        newton_step = _solve(xp, *_without(xp, A_new, g_new, _held(bound, g_new)), xp.zeros_like(cost_new))
    else:
        newton_step = _solve(xp, A_new, g_new, xp.zeros_like(cost_new))
    at_minimum = xp.all(xp.abs(newton_step) < atol + rtol * xp.abs(trial), axis=-1)
    # or where that full step would change the residuals by less than `rtol` of their norm (`|J d|^2 = g.d`): the
    # model's predictions have converged. On long simulations the step itself stays near 1e-8 relative there
    # (round-off; parameters near 0, such as a record's state), and the step length test alone shrinks the trust
    # region for ten more rejected steps before it holds
    flat = finite & (xp.sum(xp.where(finite[..., None], g_new, 0.0) * newton_step, axis=-1) < rtol**2 * 2 * cost_new)
    done = accept & evaluated & ((small_step & small_change) | at_minimum | flat | (cost_new == 0))
    pick = lambda new, old: xp.where(accept.reshape(accept.shape + (1,) * (new.ndim - accept.ndim)), new, old)  # noqa: E731
    new_state = LMState(
        gram=pick(A_new, A),
        gradient=pick(g_new, g),
        cost=pick(cost_new, cost),
        loss=pick(loss, state.loss),
        step_size=factor * state.step_size,
        evaluated=evaluated | accept,
        done=done,
        bound=pick(bound, state.bound),
    )
    return new_state, accept, evaluated | finite


class LevenbergMarquardt(AbstractHostSolver):
    """Levenberg-Marquardt for least-squares problems (`problem.residuals`), fricjax's own: what
    `fj.levenberg_marquardt()` returns. optimistix's algorithm (the damped Gauss-Newton step with `lambda = 1 /
    step_size` and a classical trust region), with its steps driven from the host (an `AbstractHostSolver`): each
    step is one call of a compiled program that evaluates the residuals and their Jacobian at every start's trial
    point.

    **Arguments:** `hold_bounds`: a parameter the bounds stopped (damping >= 0) is held there, out of the damped
    system, while the gradient points out of the bounds (an active set; see the module's docstring); off by default
    until it is measured on the real records (on the default `fricjax compare` run it moves GMS from 0.1025 to
    0.1029 % test NMSE, validation 0.0559 to 0.0564 %). `rtol`, `atol`: a start has converged on an accepted step
    that moves every parameter by less
    than `atol + rtol * |parameter|` and changes the cost (half the sum of squared residuals) by less than
    `atol + rtol * cost`, or after which even the full Gauss-Newton step would move every
    parameter by less than `atol + rtol * |parameter|` or change the residuals by less than `rtol` of their norm,
    or at a cost of 0. For simulation fits of long records the
    Gauss-Newton steps meet round-off near 1e-9 relative: `rtol=1e-8` (scipy's default tolerances) ends such fits
    where further steps cannot be resolved; the default 1e-10 then lets the trust region shrink the steps first.

    The first step evaluates the start; a start whose own residuals are not finite stops there (the fit reports it
    as diverged). A trial with non-finite residuals is rejected (a smaller step follows).

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
    hold_bounds: bool = eqx.field(static=True, default=False)

    def __check_init__(self) -> None:
        for name in ("rtol", "atol"):
            nonnegative_float(getattr(self, name), name, "LevenbergMarquardt")

    @property
    def kind(self) -> str:
        return "least_squares"

    @property
    def name(self) -> str:
        return "Levenberg-Marquardt solver"

    def evaluate(self, problem: Any, y: Any, args: Any) -> tuple[Any, jax.Array, jax.Array]:
        """The trial point projected onto the bounds, `[J r]^T [J r]` there and the problem's loss (one start;
        traced)."""
        y = problem.project(y)
        products, r = problem.gauss_newton(y, args)
        return y, products, problem.loss_of_residuals(r)

    def propose(self, xp: Any, state: LMState, flat: Any) -> Any:
        """The damped steps of a batch of starts (`xp`: `numpy` on the host)."""
        return _propose(xp, state, flat, self.hold_bounds)

    def judge(self, xp: Any, state: LMState, flat: Any, trial: Any, products: Any, loss: Any) -> tuple[Any, Any, Any]:
        """The states after the trial points were evaluated, which trials were accepted, which starts are sound."""
        return _judge(xp, state, flat, trial, products, loss, self.rtol, self.atol, self.hold_bounds)

    def start_state(self, xp: Any, flat: Any) -> LMState:
        """The state of a batch of starts `flat` (B, P) before their first evaluation."""
        count, size = flat.shape
        return LMState(
            gram=xp.zeros((count, size, size), flat.dtype),
            gradient=xp.zeros((count, size), flat.dtype),
            cost=xp.zeros(count, flat.dtype),
            loss=xp.full(count, np.nan, flat.dtype),
            step_size=xp.ones(count, flat.dtype),
            evaluated=xp.zeros(count, bool),
            done=xp.zeros(count, bool),
            bound=xp.zeros((count, size), flat.dtype),
        )

    def init(self, problem: Any, y: Any, args: Any) -> LMState:
        flat, _ = jax.flatten_util.ravel_pytree(y)
        return jax.tree_util.tree_map(lambda a: a[0], self.start_state(jnp, flat[None]))

    def step(self, problem: Any, y: Any, args: Any, state: LMState) -> tuple[Any, LMState, jax.Array]:
        """One step, traced (the host-driven loop's `propose` / `evaluate` / `judge` in `jax.numpy`)."""
        flat, unravel = jax.flatten_util.ravel_pytree(y)
        batched = jax.tree_util.tree_map(lambda a: a[None], state)
        delta = self.propose(jnp, batched, flat[None])
        trial, products, loss = self.evaluate(problem, unravel(flat + delta[0]), args)
        trial_flat, _ = jax.flatten_util.ravel_pytree(trial)
        new_state, accept, sound = self.judge(jnp, batched, flat[None], trial_flat[None], products[None], loss[None])
        new_y = jax.tree_util.tree_map(lambda a, b: jnp.where(accept[0], a, b), trial, y)
        return new_y, jax.tree_util.tree_map(lambda a: a[0], new_state), sound[0] & tree_finite(new_y)

    def terminate(self, problem: Any, y: Any, args: Any, state: LMState) -> tuple[jax.Array, Any]:
        return state.done, RESULTS.successful


def levenberg_marquardt(rtol: float = 1e-10, atol: float = 1e-12, *, hold_bounds: bool = False) -> LevenbergMarquardt:
    """fricjax's Levenberg-Marquardt solver (`fj.LevenbergMarquardt`) with tolerances suited to friction fits
    (`hold_bounds`: the active set at the damping bounds). The optimistix one stays available:
    `solver=optx.LevenbergMarquardt(rtol, atol)`."""
    return LevenbergMarquardt(rtol=rtol, atol=atol, hold_bounds=hold_bounds)
