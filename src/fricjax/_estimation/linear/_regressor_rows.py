"""The teacher-forced regressor rows of a NARX model along a record, for the fits that are linear in parameters
(least squares and term selection, kernel, wavelet and local models): the play operators' states by `run`, the
loop of `fj.simulate` (the one scan over time), the rest by shifts (`NARXRegressors.teacher_forced`)."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._constraints import unwrap
from ..._inputs import MotionSample
from ..._models.blackbox._regressors import NARXRegressors, PlayOperators
from ..._simulate import run


def play_states(operators: PlayOperators, samples: MotionSample) -> Float[Array, "T K"] | None:
    """The states of the play operators `operators` after each sample of a record (`samples`: the record's
    per-step signals, with `dx`), from rest, `(T, K)`; `None` for an empty bank. The state follows the dtype of
    the displacement and of the thresholds."""
    if not operators.num_plays:
        return None
    model = unwrap(operators)
    state = jnp.zeros((operators.num_plays,), jnp.result_type(samples.dx, model.thresholds))
    return run(model, samples, state, unroll=1)[1]  # unrolled once: the rows to the bit as before the move to `run`


def teacher_forced_rows(regressors: NARXRegressors, samples: MotionSample, measured: Any) -> Float[Array, "T P"]:
    """The regressor vectors of a record under teacher forcing, as rows `(T, regressors.size)`: the inputs to
    `NARXRegressors.teacher_forced` with the play states (if any) run by `play_states`."""
    return regressors.teacher_forced(samples, measured, play_states(regressors.play_operators, samples))
