"""Losses as objects: simulation error (NOE), one-step (teacher-forced) error, multiple shooting.

Every loss gives a residual vector (for Gauss-Newton / Levenberg-Marquardt solvers) and the scalar
`mean(residuals**2)`. Residuals are divided by the standard deviation of the measured force by default, so a
loss value of 0.01 is an NMSE of 1 % (worden2007 eq. 1).
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import unwrap
from ..._data._record import FrictionData
from ..._metrics import scaled_std
from ..._models._base import feeds_back
from ..._simulate import check_options, run, split_time_signals
from ..._validation import integer, nonnegative_float, nonnegative_int


class JacobianGroups(NamedTuple):
    """Which residuals each element of a loss's `extra` moves (the model's parameters move every residual).

    - `rows(n)`: the groups of the `n` residuals, as runs `(start, stop, block, first)` covering `0 ... n` in order:
      the rows of a run are consecutive blocks of `block` rows, the k-th of group `first + k` (a group < 0: rows no
      element of `extra` moves);
    - `columns`: a pytree like `extra` of integer NumPy arrays, the group of each element (>= 0);
    - `reach`: an element of group g moves only residuals of groups `g + r`, r in `reach` (a superset is safe).

    Several records: group = record, reach (0,). Multiple shooting: the start of segment m + 1 moves that segment's
    errors and the continuity gaps m and m + 1: reach (0, 1).
    """

    rows: Callable[[int], Any]
    columns: Any
    reach: tuple[int, ...] = (0,)


def leading_groups(extra: Any) -> Any:
    """`JacobianGroups.columns` where each element's group is its index along the leading axis of its leaf (a
    record, a segment start)."""
    return jax.tree_util.tree_map(
        lambda leaf: np.broadcast_to(np.arange(leaf.shape[0]).reshape((-1,) + (1,) * (leaf.ndim - 1)), leaf.shape),
        extra,
    )


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

    def scaled_residuals(self, model: Any, extra: Any, data: Any, scale: Array, mask: Array | None) -> Array:
        """The residuals with the force errors divided by `scale` (a scalar or one value per sample) instead of
        the record's force spread, and zero where `mask` (one bool per sample, or None) is False: how a padded
        batch of records (`fj.fit(model, [record, ...])`) scores each record by its own spread. Friction losses
        implement it; others cannot be fitted to several records."""
        raise TypeError(
            f"{type(self).__name__} scores one record only; fit several records with fj.SimulationLoss, "
            "fj.OneStepLoss or fj.MultipleShootingLoss."
        )

    def scored_samples(self, length: int) -> slice:
        """Which samples of a record of `length` the force errors of `residuals` cover (in order)."""
        return slice(0, length)

    def jacobian_groups(self, extra: Any, data: Any) -> JacobianGroups | None:
        """The sparsity of the residuals' Jacobian in `extra`, where the loss knows it (`JacobianGroups`); None (the
        default): every residual may depend on every element of `extra`. Forward-mode Jacobians then share one
        tangent among the elements whose residuals do not overlap (`Problem.gauss_newton`)."""
        return None

    def __call__(self, model: Any, extra: Any, data: Any) -> Array:
        return jnp.mean(self.residuals(model, extra, data) ** 2)

    def _scale(self, data: FrictionData) -> Array:
        normalise = getattr(self, "normalise", True)
        # scaled before squaring: forces of 1e200 N do not overflow the variance (a loss of 0.0)
        return scaled_std(data.force) if normalise else jnp.ones((), data.force.dtype)


class SimulationLoss(AbstractLoss):
    """Output error (NOE): the model simulated over the whole record from its initial state, scored against the
    measured force. The first `burn_in` samples are simulated but not scored (they let an unknown initial
    state settle).

    **Arguments:** `burn_in` samples not scored (default 0); `normalise` divide by std(force) (default True);
    `derivatives`, `batching`: how the free run is differentiated and batched (`fj.simulate`'s options; speed
    only, e.g. `SimulationLoss(derivatives="tangent")`).
    """

    burn_in: int = eqx.field(static=True, default=0)
    normalise: bool = eqx.field(static=True, default=True)
    derivatives: str = eqx.field(static=True, default="auto")
    batching: str = eqx.field(static=True, default="auto")

    def __check_init__(self) -> None:
        nonnegative_int(self.burn_in, "burn_in", "SimulationLoss", hint="(samples not scored)")
        check_options(None, self.derivatives, self.batching, "SimulationLoss")

    def validation_loss(self) -> AbstractLoss:
        return SimulationLoss(burn_in=self.burn_in, batching=self.batching)

    def residuals(self, model: Any, extra: Any, data: FrictionData) -> Array:
        return self.scaled_residuals(model, extra, data, self._scale(data), None)

    def scaled_residuals(self, model: Any, extra: Any, data: FrictionData, scale: Array, mask: Array | None) -> Array:
        model = unwrap(model)
        _, force = run(
            model, model.samples(data.motion), model.init_state(), derivatives=self.derivatives, batching=self.batching
        )
        return _masked((force - data.force) / scale, mask)[self.burn_in :]

    def scored_samples(self, length: int) -> slice:
        return slice(self.burn_in, length)


class OneStepLoss(AbstractLoss):
    """One-step-ahead (teacher-forced, equation-error) loss for models that feed back their own outputs.

    The prediction of each sample from measured data up to the previous one: `fj.simulate(model, motion,
    measured=force)`, i.e. the model's `feedback(state, y_measured)` replaces its fed-back output after every
    step (NARX-type models). A model without fed-back outputs (every physics model) has no one-step
    prediction different from its simulation: use `SimulationLoss` for it (this loss refuses it).

    **Arguments:** `burn_in` samples not scored; `normalise` as `SimulationLoss`.
    """

    burn_in: int = eqx.field(static=True, default=0)
    normalise: bool = eqx.field(static=True, default=True)

    def __check_init__(self) -> None:
        nonnegative_int(self.burn_in, "burn_in", "OneStepLoss", hint="(samples not scored)")

    def residuals(self, model: Any, extra: Any, data: FrictionData) -> Array:
        if not feeds_back(model):
            raise TypeError(
                f"OneStepLoss: {type(model).__name__} feeds back no outputs (it has no `feedback`), so its one-step "
                "prediction is its simulation; use fj.SimulationLoss() or fj.MultipleShootingLoss(...) for it."
            )
        return self.scaled_residuals(model, extra, data, self._scale(data), None)

    def scaled_residuals(self, model: Any, extra: Any, data: FrictionData, scale: Array, mask: Array | None) -> Array:
        model = unwrap(model)
        _, force = run(model, model.samples(data.motion), model.init_state(), data.force)
        return _masked((force - data.force) / scale, mask)[self.burn_in :]

    def scored_samples(self, length: int) -> slice:
        return slice(self.burn_in, length)


class MultipleShootingLoss(AbstractLoss):
    """Multiple shooting: the record is cut into segments of `segment_length` samples, each simulated from its
    own initial state, which is an extra decision variable (`extra`), all segments in one `vmap`. A continuity
    penalty ties each segment's final state to the next segment's initial state.

    Residuals: the scaled force errors of all segments, then `sqrt(continuity_weight)` times the state
    mismatches (each state leaf divided by its RMS over the segments). The first segment starts from the
    model's own initial state. Samples beyond the last whole segment are not scored.

    **Arguments:** `segment_length` L (>= 2); `continuity_weight` (default 1.0); `normalise`; `derivatives` as
    `SimulationLoss` (the segments' free runs).
    """

    segment_length: int = eqx.field(static=True)
    continuity_weight: float = eqx.field(static=True, default=1.0)
    normalise: bool = eqx.field(static=True, default=True)
    derivatives: str = eqx.field(static=True, default="auto")

    def __check_init__(self) -> None:
        integer(self.segment_length, "segment_length", "MultipleShootingLoss", minimum=2, hint="(samples)")
        nonnegative_float(self.continuity_weight, "continuity_weight", "MultipleShootingLoss")
        check_options(None, self.derivatives, "auto", "MultipleShootingLoss")

    def _segments(self, model: Any, data: FrictionData) -> tuple[Any, Any, Array, int]:
        """The model's per-step samples of the whole record, its K segments as a function of a segment's
        signals with the list of segmented signals (leaves `(K, L, ...)`), the segmented force, and K."""
        samples = model.samples(data.motion)
        count = data.length // self.segment_length
        if count < 2:
            raise ValueError(
                f"MultipleShootingLoss: a record of {data.length} samples holds fewer than 2 segments of "
                f"{self.segment_length}; use a shorter `segment_length` or fj.SimulationLoss()."
            )
        used = count * self.segment_length

        def cut(a: Array) -> Array:
            return a[:used].reshape((count, self.segment_length) + a.shape[1:])

        steps, rebuild = split_time_signals(samples)
        segments = [None if a is None else cut(a) for a in steps]
        return samples, (segments, rebuild), cut(data.force), count

    def init_extra(self, model: Any, data: FrictionData) -> Any:
        """Initial states of segments 2..K: the states a simulation of the whole record passes through."""
        model = unwrap(model)
        samples, _, _, count = self._segments(model, data)
        _, (_, states) = run(model, samples, model.init_state(), return_states=True)
        ends = jnp.arange(1, count) * self.segment_length - 1  # the state after the last sample of segments 1..K-1
        return jax.tree_util.tree_map(lambda leaf: leaf[ends], states)

    def residuals(self, model: Any, extra: Any, data: FrictionData) -> Array:
        return self.scaled_residuals(model, extra, data, self._scale(data), None)

    def scored_samples(self, length: int) -> slice:
        return slice(0, (length // self.segment_length) * self.segment_length)

    def jacobian_groups(self, extra: Any, data: FrictionData) -> JacobianGroups | None:
        """The start of segment m + 1 (`extra[m]`, group m) moves that segment's force errors (group m) and the
        continuity gaps m (its own) and m + 1 (the segment's end); the first segment's errors depend on no extra."""
        leaves = jax.tree_util.tree_leaves(extra)
        if not leaves:
            return None
        gaps = len(leaves[0])  # K - 1
        width = [int(np.prod(leaf.shape[1:], dtype=int)) for leaf in leaves]
        length = self.segment_length

        def rows(n: int) -> list[tuple[int, int, int, int]]:
            start = (gaps + 1) * length
            runs = [(0, start, length, -1)]  # segment j's errors: group j - 1
            for w in width:  # each state leaf's gaps, (K - 1, w) flattened: gap m is group m
                runs.append((start, start + gaps * w, max(w, 1), 0))
                start += gaps * w
            return runs

        return JacobianGroups(rows, leading_groups(extra), (0, 1))

    def scaled_residuals(self, model: Any, extra: Any, data: FrictionData, scale: Array, mask: Array | None) -> Array:
        model = unwrap(model)
        _, (segments, rebuild), force, count = self._segments(model, data)
        first = model.init_state()
        starts = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([jnp.asarray(a)[None], b]), first, extra)
        finals, predicted = jax.vmap(
            lambda state, part: run(model, rebuild(part), state, derivatives=self.derivatives)
        )(starts, segments)
        used = count * self.segment_length
        scale = scale[:used].reshape(force.shape) if jnp.ndim(scale) else scale
        errors = _masked((predicted - force) / scale, None if mask is None else mask[:used].reshape(force.shape))
        errors = errors.reshape(-1)
        gaps = []
        for final, start in zip(jax.tree_util.tree_leaves(finals), jax.tree_util.tree_leaves(extra), strict=True):
            gap = (final[:-1] - start).reshape(count - 1, -1)
            # a constant scale for the derivatives: without stop_gradient every gap would depend on every segment's
            # start, and `jacobian_groups` (a start moves its own segment and the two gaps beside it) would not hold
            scale = jax.lax.stop_gradient(jnp.sqrt(jnp.mean(start**2)) + 1e-30)
            gaps.append((gap / scale).reshape(-1))
        continuity = jnp.sqrt(self.continuity_weight) * jnp.concatenate(gaps) if gaps else jnp.zeros((0,))
        return jnp.concatenate([errors, continuity.astype(errors.dtype)])


def _masked(errors: Array, mask: Array | None) -> Array:
    return errors if mask is None else jnp.where(mask, errors, 0.0)
