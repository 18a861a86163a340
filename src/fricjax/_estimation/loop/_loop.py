"""The one optimisation loop: every fit (`fj.fit`, `fj.sweep`, multi-start, the protocols' refinements) steps its
solver here.

Two levels, as in optimistix's `iterative_solve` with diffrax's progress meter:

- `run_steps` (jit-compiled): up to `n` steps of a solver for a batch of starts (`vmap`), each start stopping at its
  solver's convergence test (`terminate`) or at its first non-finite step, whose parameters are discarded (the last
  good ones are kept). `n` is traced, so checks of any length share one compilation.
- `Search` and `run_stage` (host): between chunks of steps the loop scores every start (training and validation
  loss), keeps each start's best parameters so far, records the history, advances the progress bar and applies the
  stopping rules (divergence of every start, the solver's convergence, a relative `tolerance` on the loss,
  `patience` on the validation loss).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ..._smoothing import on_host
from ._interrupts import check_interrupt, interruptible
from ._sharding import shard_batch
from ._solution import RESULTS
from ._solvers import AbstractHostSolver, AbstractSolver, tree_finite

MAPPED = eqx.if_array(0)  # a batch's arrays along axis 0; its other leaves (a model's functions) shared


def _args_axis(batched_args: bool) -> Any:
    """How `args` are mapped: a sweep's (one model a configuration, `batched_args`) by their arrays; else shared."""
    return MAPPED if batched_args else None


def _first(tree: Any) -> Any:
    """The first entry of a batch: each array's row 0, other leaves as they are."""
    return jax.tree_util.tree_map(lambda leaf: leaf[0] if eqx.is_array(leaf) else leaf, tree)


@eqx.filter_jit
def init_states(solver: AbstractSolver, problem: Any, ys: Any, args: Any, batched_args: bool = False) -> Any:
    """The solver state of every start, in a program of its own (so `run_steps` compiles once per fit for solvers
    whose state lives across checks)."""
    return eqx.filter_vmap(lambda y, a: solver.init(problem, y, a), in_axes=(MAPPED, _args_axis(batched_args)))(
        ys, args
    )


@eqx.filter_jit
def run_steps(
    solver: AbstractSolver,
    problem: Any,
    ys: Any,
    states: Any,
    args: Any,
    n: jax.Array,
    batched_args: bool = False,
    stopped: jax.Array | None = None,
) -> tuple[Any, Any, jax.Array, jax.Array, Any, jax.Array]:
    """Up to `n` steps of `solver` for every start (`ys` batched along axis 0, `args` too with `batched_args`), from
    solver states `states` (None: `solver.init` of each start). Returns `(ys, states, steps, done, result, bad)`: the
    solver states (their arrays batched, their other leaves, such as an optimistix solver's jaxprs, as the trace made
    them: passed back, they continue the solver where it stopped), the steps each start took, whether its solver's
    convergence test ended it, the solver's verdict (`fj.RESULTS`), and whether it met a non-finite step (its
    parameters are then the last finite ones). `stopped` (one bool per start): starts that met a non-finite step in
    an earlier call, which take no step here (`run_in_pieces`)."""
    arrays, static_in = (None, None) if states is None else eqx.partition(states, eqx.is_array)
    static_out: list[Any] = []  # the non-array part of the solver state, as traced

    def one(y: Any, state_arrays: Any, a: Any, bad: Any) -> Any:
        state = solver.init(problem, y, a) if state_arrays is None else eqx.combine(state_arrays, static_in)
        # as optimistix's loop: only the arrays of the state are carried (a solver may keep jaxprs in its state)
        dynamic, static = eqx.partition(state, eqx.is_array)
        static_out.append(static)
        done, result = solver.terminate(problem, y, a, state)

        def cond(carry: Any) -> jax.Array:
            i, _, _, done, _, bad = carry
            return (i < n) & jnp.invert(done) & jnp.invert(bad)

        def body(carry: Any) -> Any:
            i, y, dynamic, _, _, _ = carry
            new_y, new_state, ok = solver.step(problem, y, a, eqx.combine(dynamic, static))
            ok = ok & tree_finite(new_y)
            done, result = solver.terminate(problem, y, a, new_state)
            new_dynamic = eqx.filter(new_state, eqx.is_array)
            keep = lambda new, old: _where_tree(ok, new, old)  # noqa: E731 - a non-finite step changes nothing
            return i + 1, keep(new_y, y), keep(new_dynamic, dynamic), done & ok, result, jnp.invert(ok)

        carry = (jnp.asarray(0), y, dynamic, done, result, jnp.asarray(False) if bad is None else bad)
        return jax.lax.while_loop(cond, body, carry)

    in_axes = (MAPPED, None if arrays is None else MAPPED, _args_axis(batched_args), None if stopped is None else 0)
    if _batch_size(ys) == 1:  # one start: the unbatched program (vmap of a batch of one compiles ~2x longer)
        squeeze = lambda tree, axis: tree if axis is None else _first(tree)  # noqa: E731
        out = one(*(squeeze(tree, axis) for tree, axis in zip((ys, arrays, args, stopped), in_axes, strict=True)))
        steps, ys, states, done, result, bad = jax.tree_util.tree_map(lambda leaf: jnp.asarray(leaf)[None], out)
        return ys, eqx.combine(states, static_out[0]), steps, done, result, bad
    steps, ys, states, done, result, bad = eqx.filter_vmap(one, in_axes=in_axes)(ys, arrays, args, stopped)
    states = eqx.combine(states, static_out[0])
    return ys, states, steps, done, result, bad


@eqx.filter_jit
def evaluate_starts(
    solver: Any, problem: Any, flat: jax.Array, structure: Any, args: Any, batched_args: bool = False
) -> tuple[jax.Array, Any, Any]:
    """`solver.evaluate(problem, y, args)` for every start, the starts given as the rows of `flat` (one vector per
    start, in the order of `structure`'s leaves: `jax.ShapeDtypeStruct`s of one start). One compiled program,
    reused by every step of a fit whose solver steps on the host; the evaluated points come back as rows too."""

    def one(row: jax.Array, a: Any) -> Any:
        y, products, loss = solver.evaluate(problem, _unravel(row, structure), a)
        return jax.flatten_util.ravel_pytree(y)[0].astype(row.dtype), products, loss

    if flat.shape[0] == 1:  # one start: the unbatched program, as `run_steps`
        out = one(flat[0], _first(args) if batched_args else args)
        return jax.tree_util.tree_map(lambda leaf: leaf[None], out)
    return eqx.filter_vmap(one, in_axes=(MAPPED, _args_axis(batched_args)))(flat, args)


def _unravel(flat: Any, structure: Any) -> Any:
    """The pytree shaped like `structure` (`jax.ShapeDtypeStruct` leaves of one start) whose leaves fill the last
    axis of `flat` in order: a row (traced) or a batch of rows (NumPy), the batch axes kept in front."""
    leaves, treedef = jax.tree_util.tree_flatten(structure)
    parts, offset = [], 0
    for leaf in leaves:
        size = int(np.prod(leaf.shape))
        parts.append(flat[..., offset : offset + size].reshape(flat.shape[:-1] + leaf.shape).astype(leaf.dtype))
        offset += size
    return jax.tree_util.tree_unflatten(treedef, parts)


def _rows(ys: Any) -> tuple[np.ndarray, Any]:
    """A batch of starts as NumPy rows (one vector per start) and the structure of one start."""
    leaves = jax.tree_util.tree_leaves(ys)
    count = _batch_size(ys)
    dtype = np.result_type(*[leaf.dtype for leaf in leaves]) if leaves else np.float64
    structure = jax.tree_util.tree_map(lambda leaf: jax.ShapeDtypeStruct(leaf.shape[1:], leaf.dtype), ys)
    flat = np.concatenate([np.asarray(leaf, dtype).reshape(count, -1) for leaf in leaves], 1)
    return flat, structure


PIECE_SECONDS = 1.0  # `run_in_pieces`: about this long a compiled call, so that a signal is acted on within seconds


def piece_seconds() -> float:
    """The length [s] of a piece of compiled steps under the command line: `FRICJAX_PIECE_SECONDS` where set (0: one
    step a piece, as the tests check that pieces change nothing), else `PIECE_SECONDS`."""
    try:
        return max(0.0, float(os.environ.get("FRICJAX_PIECE_SECONDS", PIECE_SECONDS)))
    except ValueError:
        return PIECE_SECONDS


def run_in_pieces(
    solver: AbstractSolver, problem: Any, ys: Any, states: Any, args: Any, n: int, batched_args: bool = False
) -> tuple[Any, Any, Any, Any, Any, Any]:
    """`run_steps`'s `n` steps as several calls of about `PIECE_SECONDS` each, with `check_interrupt` between them
    (under `fricjax compare`, where a chunk of steps on a long record is minutes): the same returns, and the same
    iterates, as one call (the solver state is passed on; starts that met a non-finite step stay stopped)."""
    count = _batch_size(ys)
    stopped = jnp.zeros(count, bool)
    total = np.zeros(count, int)
    finished = result = None
    piece, left = 1, n  # the first piece measures a step (and compiles)
    while left > 0:
        check_interrupt()
        k = min(piece, left)
        begin = time.perf_counter()
        ys, states, steps, new_finished, new_result, bad = run_steps(
            solver, problem, ys, states, args, jnp.asarray(k), batched_args, stopped
        )
        if finished is not None:  # a start stopped before this piece keeps its verdict
            new_finished = jnp.where(stopped, finished, new_finished)
            keep = functools.partial(jnp.where, stopped)
            new_result = jax.tree_util.tree_map(lambda new, old, keep=keep: keep(old, new), new_result, result)
        finished, result, stopped = new_finished, new_result, bad
        total += np.asarray(steps)
        left -= k
        if bool(np.all(np.asarray(finished) | np.asarray(bad))):
            break
        per_step = (time.perf_counter() - begin) / k
        piece = max(1, int(piece_seconds() / max(per_step, 1e-9)))
    return ys, states, jnp.asarray(total), finished, result, stopped


def run_steps_on_host(
    solver: Any, problem: Any, ys: Any, states: Any, args: Any, n: int, batched_args: bool = False
) -> tuple[Any, Any, Any, Any, Any, Any]:
    """`run_steps` for a solver whose steps are driven from the host (an `AbstractHostSolver`, fricjax's Levenberg-
    Marquardt): up to `n` steps, each one call of `evaluate_starts` for every start's trial point and the
    solver's `propose` / `judge` in NumPy; the same returns as `run_steps` (states: the solver's batched NumPy
    state). Starts that converged or met a non-finite start stay where they are."""
    flat, structure = _rows(ys)
    count = flat.shape[0]
    state = solver.start_state(np, flat) if states is None else states
    steps, bad = np.zeros(count, int), np.zeros(count, bool)
    for _ in range(n):
        check_interrupt()  # each step is one compiled call: under `fricjax compare`, stop between steps
        active = ~(np.asarray(state.done) | bad)
        if not active.any():
            break
        with np.errstate(all="ignore"):  # non-finite trials are expected: the solver rejects them
            delta = solver.propose(np, state, flat)
            # the starts' own dtype (a float32 model with float64 data: float64 steps), spread over the devices
            rows = shard_batch(jax.device_put((flat + delta).astype(flat.dtype)))
            trial, products, loss = map(
                np.asarray, evaluate_starts(solver, problem, rows, structure, args, batched_args)
            )
            new_state, accept, sound = solver.judge(np, state, flat, trial, products, loss)
        state = jax.tree_util.tree_map(functools.partial(_where_rows, active), new_state, state)
        flat = np.where((active & accept)[:, None], trial, flat).astype(flat.dtype)
        bad |= active & ~sound
        steps += active
    done = np.asarray(state.done) & ~bad
    result = jax.tree_util.tree_map(lambda value: np.full(count, value), RESULTS.successful)  # never fails
    return shard_batch(jax.device_put(_unravel(flat, structure))), state, steps, done, result, bad  # NumPy split


def _where_rows(rows: np.ndarray, new: Any, old: Any) -> np.ndarray:
    """`new` in the rows (leading axis) where `rows` is True, `old` elsewhere (NumPy)."""
    return np.where(rows.reshape(rows.shape + (1,) * (np.ndim(new) - 1)), new, old)


def _batch_size(ys: Any) -> int:
    leaves = jax.tree_util.tree_leaves(ys)
    return int(leaves[0].shape[0]) if leaves else 1


@eqx.filter_jit
def batched_losses(problem: Any, ys: Any, args: Any, batched_args: bool) -> tuple[jax.Array, jax.Array]:
    """Training and validation loss of every start (validation NaN when the problem has none)."""

    def both(y: Any, a: Any) -> tuple[jax.Array, jax.Array]:
        return problem.objective(y, a), problem.val_objective(y, a)

    if _batch_size(ys) == 1:  # one start: the unbatched program, as `run_steps`
        losses = both(_first(ys), _first(args) if batched_args else args)
        return jax.tree_util.tree_map(lambda leaf: leaf[None], losses)
    return eqx.filter_vmap(both, in_axes=(MAPPED, _args_axis(batched_args)))(ys, args)


def start_losses(solver: Any, problem: Any, ys: Any, args: Any) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation loss of every start (NumPy), as `batched_losses`; for a single start of a solver
    that steps on the host, on a problem without validation data, from the solver's own compiled evaluation (a
    fit then compiles one program for its steps and its scores)."""
    if isinstance(solver, AbstractHostSolver) and _batch_size(ys) == 1 and getattr(problem, "validation", None) is None:
        flat, structure = _rows(ys)
        loss = np.asarray(evaluate_starts(solver, problem, jax.device_put(flat), structure, args, False)[2])
        return loss, np.full(loss.shape, np.nan)
    train, val = batched_losses(problem, ys, args, False)
    return np.asarray(train), np.asarray(val)


def trees_equal(a: Any, b: Any) -> bool:
    """Whether two pytrees of arrays hold the same values (host side)."""
    return all(
        bool(np.array_equal(np.asarray(x), np.asarray(y)))
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True)
    )


def _is_successful(result: Any) -> np.ndarray:
    """Per start, whether a (batched) `fj.RESULTS` item is `successful` (compared in NumPy)."""
    values = [np.asarray(leaf) for leaf in jax.tree_util.tree_leaves(result)]
    expected = [np.asarray(leaf) for leaf in jax.tree_util.tree_leaves(RESULTS.successful)]
    return np.all([v == e for v, e in zip(values, expected, strict=True)], axis=0).reshape(-1)


def _where_tree(condition: Any, new: Any, old: Any) -> Any:
    """`where(condition, new, old)` leaf by leaf; a condition of shape (B,) selects along the leading batch axis."""

    def select(a: Any, b: Any) -> Any:
        if not eqx.is_array(a):
            return a
        mask = condition.reshape(condition.shape + (1,) * (jnp.ndim(a) - condition.ndim))
        return on_host(lambda xp, m, x, y: xp.where(m, x, y), mask, a, b)

    return jax.tree_util.tree_map(select, new, old)


class Search:
    """The bookkeeping of a fit over a batch of starts: current and best parameters, scores (validation loss, else
    training loss), which starts diverged, stalls for early stopping, the history and the progress bar."""

    def __init__(self, ys: Any, by_validation: bool, start_time: float, bar: Any):
        leaves = jax.tree_util.tree_leaves(ys)
        count = leaves[0].shape[0] if leaves else 1
        self.ys = self.best_ys = ys
        self.best_scores = np.full(count, np.inf)
        self.diverged = np.zeros(count, dtype=bool)
        self.by_validation, self.start_time, self.bar = by_validation, start_time, bar
        self.step_count = self.stall = 0
        self.history: dict[str, list[Any]] = {"step": [], "train_loss": [], "val_loss": [], "eps": [], "time": []}
        self.active = np.arange(count)  # the original index of each start still searched (`keep`)
        self.count = count

    def keep(self, indices: np.ndarray) -> None:
        """Go on with the starts at `indices` only (screening): their current and best parameters, scores and
        flags; the history keeps one column per original start (NaN for the dropped ones)."""
        indices = np.asarray(indices)

        def take(tree: Any) -> Any:
            return jax.tree_util.tree_map(lambda a: a[indices] if eqx.is_array(a) and jnp.ndim(a) else a, tree)

        self.ys, self.best_ys = shard_batch(take(self.ys)), shard_batch(take(self.best_ys))
        self.best_scores, self.diverged = self.best_scores[indices], self.diverged[indices]
        self.active = self.active[indices]

    def _full(self, values: Any) -> np.ndarray:
        """Per-start values of the active starts as a row over every original start (NaN where dropped)."""
        row = np.full(self.count, np.nan)
        row[self.active] = np.asarray(values, dtype=float).reshape(-1)
        return row

    def _scores(self, train: Any, val: Any) -> np.ndarray:
        scores = np.asarray(val if self.by_validation else train)
        return np.where(np.isfinite(scores) & ~self.diverged, scores, np.inf)

    def restart(self, train: Any, val: Any) -> None:
        """A new continuation stage: its best-so-far (and its patience) start from the current parameters."""
        self.best_ys, self.best_scores = self.ys, self._scores(train, val)
        self.stall = 0

    def observe(self, ys: Any, steps: int, bad: np.ndarray, train: Any, val: Any, eps: Any) -> None:
        """After `steps` more solver steps: keep the best parameters of each start, record, update the bar."""
        train, val = np.asarray(train), np.asarray(val)
        self.ys = ys
        self.step_count += steps
        self.diverged |= bad
        scores = self._scores(train, val)
        improved = scores < self.best_scores
        self.best_ys = _where_tree(improved, ys, self.best_ys)
        self.best_scores = np.where(improved, scores, self.best_scores)
        self.stall = 0 if improved.any() else self.stall + 1
        history = self.history
        history["time"].append(time.perf_counter() - self.start_time)
        history["step"].append(self.step_count)
        history["train_loss"].append(self._full(train))
        history["val_loss"].append(self._full(val))
        history["eps"].append(np.nan if eps is None else float(eps))
        if self.bar is not None:
            self.bar.update(steps)
            self.bar.set_postfix(loss=f"{np.nanmin(train):.3g}", val=f"{np.nanmin(val):.3g}")

    def converged(self, tolerance: float) -> bool:
        """Whether the best start's training loss fell by less than `tolerance` (relative) over the last check, with
        at least one step taken in it."""
        losses, steps = self.history["train_loss"], self.history["step"]
        if len(losses) < 2 or steps[-1] == steps[-2]:
            return False
        previous, last = np.nanmin(losses[-2]), np.nanmin(losses[-1])
        return bool(np.isfinite(last) and previous - last <= tolerance * abs(previous))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


@dataclasses.dataclass
class StageOutcome:
    """How a stage of steps ended: `stop` is a `RESULTS` name that ends the whole fit (`diverged`,
    `early_stopped`) or None; `converged` is the tolerance rule's sentence where it ended the stage; `results`
    (per start, `fj.RESULTS` names) and `states` are the solver's verdicts and states after the last chunk."""

    stop: str | None = None
    message: str = ""
    converged: str = ""
    results: list[str] = dataclasses.field(default_factory=list)
    states: Any = None


def run_stage(
    solver: AbstractSolver,
    problem: Any,
    search: Search,
    args: Any,
    *,
    budget: int,
    check_every: int,
    tolerance: float | None = None,
    patience: int | None = None,
    eps: Any = None,
    states: Any = None,
    batched_args: bool = False,
) -> StageOutcome:
    """`budget` solver steps from `search.ys`, in chunks of `check_every` with the host-side checks between them.
    `states` are initial solver states (default: `solver.init` of every start, inside the loop's program)."""
    outcome = StageOutcome()
    host = isinstance(solver, AbstractHostSolver)
    if states is None and not solver.restarts_at_checks and not host:
        states = init_states(solver, problem, search.ys, args, batched_args)
    done, restart = 0, True
    while done < budget:
        check_interrupt()  # SIGINT / SIGTERM under `fricjax compare`: stop between chunks (a no-op elsewhere)
        n = min(check_every, budget - done)
        if solver.restarts_at_checks and restart:
            states = None  # initialised inside `run_steps`, from the (projected) iterate
        if host:  # its trial points are projected when evaluated
            ys, states, steps, finished, result, bad = run_steps_on_host(
                solver, problem, search.ys, states, args, n, batched_args
            )
        elif interruptible():  # under `fricjax compare`: pieces of about a second, a check between them
            ys, states, steps, finished, result, bad = run_in_pieces(
                solver, problem, search.ys, states, args, n, batched_args
            )
        else:
            ys, states, steps, finished, result, bad = run_steps(
                solver, problem, search.ys, states, args, jnp.asarray(n), batched_args
            )
            projected = problem.project(ys)  # bounds (elementwise); a no-op for solvers that project at every step
            # a solver that keeps copies of the iterate goes on from its state unless the bounds moved the iterate
            restart = not trees_equal(projected, ys)
            ys = projected
        if host and getattr(problem, "validation", None) is None:  # the solver's own evaluations scored them
            train, val = np.asarray(states.loss), np.full(len(states.loss), np.nan)
        else:
            train, val = map(np.asarray, batched_losses(problem, ys, args, batched_args))
        done += n
        search.observe(ys, int(np.max(np.asarray(steps))), np.asarray(bad) | ~np.isfinite(train), train, val, eps)
        ended = np.asarray(finished)
        outcome.states = eqx.filter(states, eqx.is_array)
        outcome.results = [
            "successful" if f and ok else ("max_steps" if ok else "solver_failed")
            for f, ok in zip(ended, _is_successful(result), strict=True)
        ]
        if search.diverged.all():
            outcome.stop = "diverged"
            outcome.message = (
                "the loss or the parameters became non-finite for every start; the last good parameters were kept "
                "(lower the learning rate, check the data scale, or start closer)"
            )
            break
        if ended.all():
            break  # every start's solver met its own convergence test (or failed)
        if tolerance is not None and search.converged(tolerance):
            outcome.converged = (
                f"converged: the loss fell by less than {tolerance:g} (relative) over the last {n} "
                f"step{'s' if n != 1 else ''} "
                f"(step {search.step_count})"
            )
            break  # this stage has converged (a next continuation stage, if any, still runs)
        if patience is not None and search.by_validation and search.stall >= patience:
            outcome.stop = "early_stopped"
            outcome.message = f"validation loss did not improve for {patience} evaluations (step {search.step_count})"
            break
    return outcome
