"""Abstract interfaces shared by every friction model."""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import equinox as eqx
from jaxtyping import Array

from .._inputs import MotionSample


class AbstractFrictionModel(eqx.Module):
    """A friction model: parameters as array leaves, state threaded explicitly.

    `init_state()` gives the state at rest; `step(state, sample) -> (state, force)` advances one sample of a
    `MotionSample` (x, v, dx, dt) and returns the friction force [N] at the end of the step. A model never
    stores state. `requires` names the signals `step` reads: `"x"` (displacement or its increment),
    `"v"` (velocity), `"dt"` (the sample time, for time integration).
    """

    requires: ClassVar[frozenset[str]]

    @abc.abstractmethod
    def init_state(self) -> Any:
        """The state at rest (a pytree of arrays)."""

    @abc.abstractmethod
    def step(self, state: Any, sample: MotionSample) -> tuple[Any, Array]:
        """One sample: `(state_k-1, sample_k) -> (state_k, force_k)`."""
