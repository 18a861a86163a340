"""A record's nuisances estimated from its first samples, before a model runs free on it (`fj.initialise`): the
force-cell offset, the model's initial state and optionally a drift (`Initialisation`), by an initialiser
(`AbstractInitialiser`): `WindowLeastSquares` fits them on a window of the record with the model's parameters held,
`AtRest` starts the model at rest and reads the offset off the window; a state estimator (a Kalman / RTS smoother)
is one more subclass. compare scores a model on a record it was not fitted on this way (`--init state|offset`).
"""

from __future__ import annotations

import abc
import dataclasses
import warnings
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._constraints import unwrap
from ..._data._record import FrictionData
from ..._inputs import Motion
from ..._models._base import AbstractModel
from ..problem._losses import SimulationLoss
from ..problem._records import Nuisances, RecordBatch, RecordExtra, RecordsLoss, record_nmse

__all__ = ["AbstractInitialiser", "AtRest", "Initialisation", "WindowLeastSquares", "initialise"]


@dataclasses.dataclass(frozen=True)
class Initialisation:
    """A record's nuisances estimated from its first samples by `fj.initialise`: `offset` [N] (0 when not
    estimated), `state0` (the model's state entering the record's first sample, for `fj.simulate(model, motion,
    state0)`), `window_nmse` the NMSE [%] left on the window (as `fj.nmse`), `steps` the solver steps taken, and `drift`
    [N/s] (0 unless asked for: the record's force is then `simulate(...) + offset + drift * t`, t = k dt)."""

    offset: float
    state0: Any
    window_nmse: float
    steps: int
    drift: float = 0.0

    def predict(self, model: Any, motion: Motion) -> np.ndarray:
        """The record's force as `model` predicts it from these nuisances: the free run from `state0` plus the
        offset and drift [N] (NumPy, over the whole `motion`)."""
        from ..._simulate import simulate

        force = np.asarray(simulate(model, motion, self.state0), dtype=float)
        t = np.arange(force.shape[-1]) * float(np.asarray(motion.dt)) if self.drift else 0.0
        return force + self.offset + self.drift * t


class AbstractInitialiser(eqx.Module):
    """How a fitted model starts on a record it was not fitted on: the record's nuisances (`Initialisation`: force
    offset, the model's initial state, a drift) estimated from the record's first samples, the model's parameters
    held. Subclasses implement `__call__(model, window) -> Initialisation`; `fj.initialise(model, window,
    initialiser=...)` checks the arguments and calls it."""

    @abc.abstractmethod
    def __call__(self, model: Any, window: FrictionData) -> Initialisation:
        """The nuisances of the record whose first samples are `window`, for `model` (unwrapped, inputs checked)."""


class WindowLeastSquares(AbstractInitialiser):
    """The force offset, the model's initial state and optionally a linear drift [N/s] fitted together on the window
    by a short least-squares fit through the model's free run (Levenberg-Marquardt, `max_steps`): the default of
    `fj.initialise` and of compare's `--init state`. The initial state is `init_state() + delta * scale` per state
    leaf (`scale`: the RMS of the leaf along the window), so that a small window that barely moves the state leaves
    it near rest; a window on which the offset and the state change the force alike is warned about."""

    offset: bool = True
    initial_state: bool = True
    drift: bool = False
    max_steps: int = 50

    def __call__(self, model: Any, window: FrictionData) -> Initialisation:
        import optimistix as optx

        offset, initial_state, drift, physical = self.offset, self.initial_state, self.drift, model
        batch = RecordBatch.from_records(
            [window], requires=frozenset(getattr(physical, "requires", ())), argument="window"
        )
        loss, extra0 = RecordsLoss(SimulationLoss(), Nuisances(offset, drift, initial_state)).bind_and_start(
            physical, batch
        )
        if not (offset or initial_state or drift):
            nmse = 100 * float(record_nmse(loss, physical, extra0, batch)[0])
            return Initialisation(0.0, physical.init_state(), nmse, 0)
        solver: Any = optx.LevenbergMarquardt(1e-6, 1e-9)
        solved, steps = _solve_nuisances(loss, physical, extra0, batch, self.max_steps, solver)
        found = loss._recorded(physical, solved, batch, jnp.asarray(0))
        nmse = 100 * float(record_nmse(loss, physical, solved, batch)[0])
        state0 = jax.tree_util.tree_map(np.asarray, found.state0)
        if offset and initial_state and _offset_share(loss, physical, solved, batch) < 0.02:
            warnings.warn(
                f"fj.initialise ({type(physical).__name__}, a window of {window.length} samples): on this window the "
                "force offset and the model's initial state change the force almost alike (the motion in the window "
                "does not make the model forget its initial state: a pre-sliding branch, or elements that never "
                "slide, hold it as an offset plus a stiffness), so their split is poorly determined; lengthen the "
                "window (compare: --init-window) or pass initial_state=False (compare: --init offset).",
                stacklevel=3,
            )
        return Initialisation(float(found.offset), state0, nmse, int(steps), float(found.rate))


class AtRest(AbstractInitialiser):
    """The model starts at rest (`init_state()`); the force offset is the mean error of that free run over the
    window (compare's `--init offset`: for a record that starts at rest, or a model whose state the window cannot
    settle)."""

    def __call__(self, model: Any, window: FrictionData) -> Initialisation:
        from ..._simulate import simulate

        force = np.asarray(window.force, np.float64)
        error = force - np.asarray(simulate(model, window.motion), np.float64)
        offset = float(np.mean(error))
        spread = float(np.var(force))
        nmse = 100 * float(np.mean((error - offset) ** 2)) / spread if spread > 0 else float("nan")
        return Initialisation(offset, model.init_state(), nmse, 0)


def initialise(
    model: Any,
    window: FrictionData,
    *,
    offset: bool = True,
    initial_state: bool = True,
    drift: bool = False,
    max_steps: int = 50,
    initialiser: AbstractInitialiser | None = None,
) -> Initialisation:
    """Estimate a record's force offset and the model's initial state from its initialisation window (the record's
    first samples) by a short least-squares fit of both through the model's free run on the window
    (`fj.simulate(model, motion, state0=...)`, Levenberg-Marquardt), the model's parameters fixed. This is how a
    fitted model starts on a record it was not fitted on: an unknown offset and an unknown memory (a hysteretic
    model's state) at the first sample; nuisances of other records (a training record's drift) are never used.

    **Arguments:** `model` a fitted friction model; `window` the record's first samples (`fj.FrictionData`, at least
    2); `offset`, `initial_state`, `drift` (a linear sensor drift [N/s], extrapolated beyond the window: off by
    default) which to estimate; `max_steps` the solver's budget (these: `fj.WindowLeastSquares`, the default
    initialiser); `initialiser` another way (`fj.AtRest()`, or a subclass of `fj.AbstractInitialiser`).
    `Initialisation.predict(model, motion)` gives the record's force from them.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> model = fj.Dahl(sigma0=2e4, Fc=1.0, alpha=1.0)
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6, 600)), dt=1e-3)
    >>> state = fj.DahlState(F=np.asarray(0.6))
    >>> force = np.asarray(fj.simulate(model, motion, state)) + 0.25  # from a state that is not rest, offset 0.25 N
    >>> start = fj.initialise(model, fj.FrictionData(motion, force).slice(0, 60))
    >>> round(start.offset, 3), round(float(start.state0.F), 3)
    (0.25, 0.6)
    ```
    """
    if not isinstance(window, FrictionData):
        raise TypeError(f"initialise: `window` must be an fj.FrictionData, got {type(window).__name__}.")
    if window.length < 2:
        raise ValueError("initialise: the window needs at least 2 samples; pass more of the record.")
    if initialiser is None:
        initialiser = WindowLeastSquares(offset, initial_state, drift, max_steps)
    elif (offset, initial_state, drift, max_steps) != (True, True, False, 50):
        raise TypeError(
            "initialise: offset, initial_state, drift and max_steps configure the default initialiser; with "
            "`initialiser` given, set them on it (fj.WindowLeastSquares(drift=True, ...))."
        )
    elif not isinstance(initialiser, AbstractInitialiser):
        raise TypeError(
            f"initialise: `initialiser` must be an fj.AbstractInitialiser (fj.WindowLeastSquares(), fj.AtRest()), got "
            f"{type(initialiser).__name__}."
        )
    physical = unwrap(model)
    if isinstance(physical, AbstractModel):
        physical.check_inputs(window.motion)
    return initialiser(physical, window)


@eqx.filter_jit
def _offset_share(loss: RecordsLoss, model: Any, extra: RecordExtra, batch: RecordBatch) -> Array:
    """How much of the offset's effect on the window's residuals the initial state cannot reproduce: the relative
    norm of the offset's Jacobian column left after its least-squares fit by the state's columns (0: the offset is
    indistinguishable from a change of the initial state)."""
    flat_state, unravel = jax.flatten_util.ravel_pytree(extra.state)

    def residuals(offset: Array, theta: Array) -> Array:
        e = RecordExtra(offset, extra.rate, unravel(theta), extra.inner)
        return loss.residuals(model, e, batch)

    by_offset, by_state = jax.jacfwd(residuals, argnums=(0, 1))(extra.offset, flat_state)
    column = by_offset.reshape(-1)
    states = by_state.reshape(column.shape[0], -1)
    fit, *_ = jnp.linalg.lstsq(states, column)
    return jnp.linalg.norm(column - states @ fit) / jnp.maximum(jnp.linalg.norm(column), 1e-300)


@eqx.filter_jit
def _solve_nuisances(
    loss: RecordsLoss, model: Any, extra: RecordExtra, batch: RecordBatch, max_steps: int, solver: Any
) -> tuple[RecordExtra, Array]:
    import optimistix as optx

    solution: Any = optx.least_squares(
        lambda e, args: loss.residuals(args, e, batch), solver, extra, args=model, max_steps=max_steps, throw=False
    )
    return solution.value, solution.stats["num_steps"]
