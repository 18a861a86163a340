"""Losses as objects: simulation error (NOE), one-step (teacher-forced) error, multiple shooting.

Every loss gives a residual vector (for Gauss-Newton / Levenberg-Marquardt solvers) and the scalar
`mean(residuals**2)`. Residuals are divided by the standard deviation of the measured force by default, so a
loss value of 0.01 is an NMSE of 1 % (worden2007 eq. 1).
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._constraints import unwrap
from .._data._record import FrictionData
from .._inputs import MotionSample
from .._simulate import motion_samples, scan_samples


class AbstractLoss(eqx.Module):
    """A loss: `residuals(model, extra, data)` and `value = mean(residuals ** 2)`.

    `extra` holds decision variables that belong to the loss rather than the model (the segment initial
    states of multiple shooting); `init_extra(model, data)` gives their starting values (`None` if none).
    """

    data_type: ClassVar[type] = FrictionData

    def init_extra(self, model: Any, data: Any) -> Any:
        return None

    def validation_loss(self) -> AbstractLoss:
        """The loss that scores validation data (free-run simulation by default; it takes no `extra`)."""
        return SimulationLoss(burn_in=getattr(self, "burn_in", 0))

    @abc.abstractmethod
    def residuals(self, model: Any, extra: Any, data: Any) -> Float[Array, " R"]:
        """The residual vector (prediction - measurement, scaled)."""

    def __call__(self, model: Any, extra: Any, data: Any) -> Array:
        return jnp.mean(self.residuals(model, extra, data) ** 2)

    def _scale(self, data: FrictionData) -> Array:
        normalise = getattr(self, "normalise", True)
        return jnp.std(data.force) if normalise else jnp.ones((), data.force.dtype)


class SimulationLoss(AbstractLoss):
    """Output error (NOE): the model simulated over the whole record from its initial state, scored against the
    measured force. The first `burn_in` samples are simulated but not scored (they let an unknown initial
    state settle).

    **Arguments:** `burn_in` samples not scored (default 0); `normalise` divide by std(force) (default True).
    """

    burn_in: int = eqx.field(static=True, default=0)
    normalise: bool = eqx.field(static=True, default=True)

    def __check_init__(self) -> None:
        if self.burn_in < 0:
            raise ValueError(f"SimulationLoss: `burn_in` must be >= 0, got {self.burn_in}.")

    def residuals(self, model: Any, extra: Any, data: FrictionData) -> Array:
        model = unwrap(model)
        _, force = scan_samples(model, motion_samples(data.motion), model.init_state())
        return (force - data.force)[self.burn_in :] / self._scale(data)


class OneStepLoss(AbstractLoss):
    """One-step-ahead (teacher-forced) error for models whose regressors include measured past outputs.

    The model must provide `predict_one_step(motion, force) -> force_hat`, the prediction of each sample from
    measured data up to the previous one (NARX-type models; a pure friction simulator has no past outputs in
    its regressors, so use `SimulationLoss` for it).

    **Arguments:** `burn_in` samples not scored; `normalise` as `SimulationLoss`.
    """

    burn_in: int = eqx.field(static=True, default=0)
    normalise: bool = eqx.field(static=True, default=True)

    def residuals(self, model: Any, extra: Any, data: FrictionData) -> Array:
        model = unwrap(model)
        predict = getattr(model, "predict_one_step", None)
        if predict is None:
            raise TypeError(
                f"OneStepLoss: {type(model).__name__} has no `predict_one_step` (its regressors contain no measured "
                "past outputs); use fj.SimulationLoss() or fj.MultipleShootingLoss(...) for it."
            )
        return (predict(data.motion, data.force) - data.force)[self.burn_in :] / self._scale(data)


class MultipleShootingLoss(AbstractLoss):
    """Multiple shooting: the record is cut into segments of `segment_length` samples, each simulated from its
    own initial state, which is an extra decision variable (`extra`), all segments in one `vmap`. A continuity
    penalty ties each segment's final state to the next segment's initial state.

    Residuals: the scaled force errors of all segments, then `sqrt(continuity_weight)` times the state
    mismatches (each state leaf divided by its RMS over the segments). The first segment starts from the
    model's own initial state. Samples beyond the last whole segment are not scored.

    **Arguments:** `segment_length` L (>= 2); `continuity_weight` (default 1.0); `normalise`.
    """

    segment_length: int = eqx.field(static=True)
    continuity_weight: float = eqx.field(static=True, default=1.0)
    normalise: bool = eqx.field(static=True, default=True)

    def __check_init__(self) -> None:
        if self.segment_length < 2:
            raise ValueError(f"MultipleShootingLoss: `segment_length` must be >= 2, got {self.segment_length}.")
        if self.continuity_weight < 0:
            raise ValueError(f"MultipleShootingLoss: `continuity_weight` must be >= 0, got {self.continuity_weight}.")

    def _segments(self, data: FrictionData) -> tuple[MotionSample, Array, int]:
        samples = motion_samples(data.motion)
        count = data.length // self.segment_length
        if count < 2:
            raise ValueError(
                f"MultipleShootingLoss: a record of {data.length} samples holds fewer than 2 segments of "
                f"{self.segment_length}; use a shorter `segment_length` or fj.SimulationLoss()."
            )
        used = count * self.segment_length

        def cut(a: Array) -> Array:
            return a[:used].reshape(count, self.segment_length)

        segments = MotionSample(x=cut(samples.x), v=cut(samples.v), dx=cut(samples.dx), dt=samples.dt)
        return segments, cut(data.force), count

    def init_extra(self, model: Any, data: FrictionData) -> Any:
        """Initial states of segments 2..K: the states a simulation of the whole record passes through."""
        model = unwrap(model)
        segments, _, count = self._segments(data)

        def run(state: Any, segment: tuple[Array, Array, Array]) -> tuple[Any, Any]:
            x, v, dx = segment
            final, _ = scan_samples(model, MotionSample(x=x, v=v, dx=dx, dt=segments.dt), state)
            return final, final

        _, finals = jax.lax.scan(run, model.init_state(), (segments.x, segments.v, segments.dx))
        return jax.tree_util.tree_map(lambda leaf: leaf[:-1], finals)

    def residuals(self, model: Any, extra: Any, data: FrictionData) -> Array:
        model = unwrap(model)
        segments, force, count = self._segments(data)
        first = model.init_state()
        starts = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), first, extra)

        def run(state: Any, x: Array, v: Array, dx: Array) -> tuple[Any, Array]:
            return scan_samples(model, MotionSample(x=x, v=v, dx=dx, dt=segments.dt), state)

        finals, predicted = jax.vmap(run)(starts, segments.x, segments.v, segments.dx)
        errors = ((predicted - force) / self._scale(data)).reshape(-1)
        gaps = []
        for final, start in zip(jax.tree_util.tree_leaves(finals), jax.tree_util.tree_leaves(extra), strict=True):
            gap = (final[:-1] - start).reshape(count - 1, -1)
            scale = jax.lax.stop_gradient(jnp.sqrt(jnp.mean(start**2)) + 1e-30)
            gaps.append((gap / scale).reshape(-1))
        continuity = jnp.sqrt(self.continuity_weight) * jnp.concatenate(gaps) if gaps else jnp.zeros((0,))
        return jnp.concatenate([errors, continuity.astype(errors.dtype)])
