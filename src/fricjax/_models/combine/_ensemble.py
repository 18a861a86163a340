"""Ensembles of fitted friction models: simple average, least-squares weights, PRESS forward selection.

An ensemble is itself a friction model: its state is the tuple of its members' states and its `step` advances
every member by one sample and combines their forces, so `fj.simulate(ensemble, motion)` runs all members in
one `lax.scan` (jit, vmap and gradients as for any model). Members may be of any family and read different
signals; the ensemble `requires` their union.

- `AverageEnsemble`: the simple average of the members' forces (parlitz2004 §IV-H: averaging the DLR, DN and
  NLR-EXP models cut the MSE from 0.75 % to 0.28 %; worden2007 §7).
- `WeightedEnsemble`: `F = intercept + sum_i weights_i * F_i`; `fj.fit_weighted_ensemble` solves the weights
  and intercept by linear least squares on data the members were not trained on (emps-ensemble §3.3, eq. 16:
  the grey-box and grey + black-box predictions as regressors of the measured output).
- `select_forward`: orthogonal forward regression over the members' predictions with the PRESS (leave-one-out)
  statistic (worden2007 §7, after Chen, Hong, Harris & Sharkey 2004): add the member that most reduces PRESS,
  stop when none does.

The fitting (`fit_weighted_ensemble`, `select_forward`) lives in the estimation layer
(`fricjax._estimation.families._ensemble_fit`, on `fj.lstsq` and `fj.select_terms`), which this module does not import.
"""

from __future__ import annotations

import abc
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..._constraints import model_dtype, real, unwrap
from ..._inputs import MotionSample
from .._base import AbstractFrictionModel

# The deprecated `WeightedEnsemble.fit` reaches `fj.fit_weighted_ensemble` through this slot: the fitting lives in the
# estimation layer, which this module may not import (DESIGN.md: no import runs upward); that layer's
# `fricjax._estimation.families._ensemble_fit` fills the slot when it is imported, as `import fricjax` does. It goes
# with the method once no caller is left.
DEPRECATED_FIT: dict[str, Callable[..., Any]] = {}


def _as_members(members: Any, where: str) -> tuple[AbstractFrictionModel, ...]:
    if isinstance(members, AbstractFrictionModel) or not isinstance(members, Sequence):
        raise TypeError(
            f"{where}: `members` must be a list or tuple of fricjax friction models, got {type(members).__name__}."
        )
    members = tuple(members)
    if not members:
        raise ValueError(f"{where}: `members` is empty; give at least one fitted friction model.")
    for i, member in enumerate(members):
        if not isinstance(member, AbstractFrictionModel):
            raise TypeError(
                f"{where}: member {i} must be a fricjax friction model (fj.LuGre, fj.GMS, fj.Coulomb, ...), "
                f"got {type(member).__name__}."
            )
    return members


class AbstractEnsemble(AbstractFrictionModel):
    """A friction model that runs `members` side by side and combines their forces sample by sample.

    State: the tuple of the members' states. `requires`: the union of the members' signals. Subclasses define
    `combine(forces)` for the vector of member forces at one sample.
    """

    members: tuple[AbstractFrictionModel, ...]

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        """The union of the signals the members read."""
        return frozenset().union(*(member.requires for member in self.members))

    @abc.abstractmethod
    def combine(self, forces: Float[Array, "... N"]) -> Float[Array, "..."]:
        """The ensemble force from the members' forces (last axis: one entry per member)."""

    def init_state(self) -> tuple[Any, ...]:
        return tuple(unwrap(member).init_state() for member in self.members)

    def step(self, state: tuple[Any, ...], sample: MotionSample) -> tuple[tuple[Any, ...], Array]:
        states, forces = [], []
        for member, member_state in zip(self.members, state, strict=True):
            member_state, force = unwrap(member).step(member_state, sample)
            states.append(member_state)
            forces.append(force)
        return tuple(states), unwrap(self).combine(jnp.stack(forces, axis=-1))

    def feedback(self, state: tuple[Any, ...], y_measured: Array) -> tuple[Any, ...]:
        """Teacher forcing of every member with the measured force (members without feedback are unchanged)."""
        return tuple(
            unwrap(member).feedback(member_state, y_measured)
            for member, member_state in zip(self.members, state, strict=True)
        )


class AverageEnsemble(AbstractEnsemble):
    """The simple-average ensemble: `F = (1 / N) * sum_i F_i` (parlitz2004 §IV-H, worden2007 §7).

    Nothing is fitted: average models that are each good and whose errors differ (physics-based and black-box,
    say); adding worse members makes the average worse again (parlitz2004 §IV-H).

    **Arguments:** `members`, a list of N >= 1 fitted friction models of any families.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6.28, 200)), dt=1e-3)
    >>> ensemble = fj.AverageEnsemble([fj.Coulomb(Fc=1.0), fj.Coulomb(Fc=3.0)])
    >>> float(fj.simulate(ensemble, motion)[20])
    2.0
    ```
    """

    def __init__(self, members: Sequence[AbstractFrictionModel]):
        self.members = _as_members(members, "AverageEnsemble")

    def combine(self, forces: Float[Array, "... N"]) -> Float[Array, "..."]:
        return jnp.mean(forces, axis=-1)


class WeightedEnsemble(AbstractEnsemble):
    """The linearly weighted ensemble: `F = intercept + sum_i weights_i * F_i` (emps-ensemble §3.3, eq. 16).

    Build it from known weights, or fit them with `fj.fit_weighted_ensemble(members, data)` (least squares with
    intercept) or choose members and weights with `fj.select_forward`. `weights` and `intercept` are real array
    leaves, so the combination can also be refined by gradients together with (or, wrapping members in
    `fj.Fixed`, instead of) the members' parameters.

    **Arguments:**

    - `members`: a list of N >= 1 fitted friction models of any families.
    - `weights`: the N weights (dimensionless; a good member in a good ensemble has a weight near 1 / N..1).
    - `intercept`: a constant force [N] (beta_0 of eq. 16), default 0.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6.28, 200)), dt=1e-3)
    >>> members = [fj.Coulomb(Fc=1.0), fj.CoulombViscous(Fc=0.5, Fv=20.0)]
    >>> target = 0.5 + 0.3 * fj.simulate(members[0], motion) + 0.8 * fj.simulate(members[1], motion)
    >>> ensemble = fj.fit_weighted_ensemble(members, fj.FrictionData(motion, target))
    >>> [round(float(w), 6) for w in ensemble.weights], round(float(ensemble.intercept), 6)
    ([0.3, 0.8], 0.5)
    ```
    """

    weights: Float[Array, "N"]
    intercept: Float[Array, ""]

    def __init__(self, members: Sequence[AbstractFrictionModel], weights: ArrayLike, intercept: ArrayLike = 0.0):
        self.members = _as_members(members, "WeightedEnsemble")
        dtype = model_dtype(*jax.tree_util.tree_leaves(self.members), weights, intercept)
        self.weights = real(weights, "weights", dtype)
        self.intercept = real(intercept, "intercept", dtype)
        if self.weights.shape != (len(self.members),):
            raise ValueError(
                f"WeightedEnsemble: `weights` must have one entry per member, shape ({len(self.members)},), "
                f"got {self.weights.shape}."
            )
        if self.intercept.shape != ():
            raise ValueError(f"WeightedEnsemble: `intercept` must be a scalar force [N], got {self.intercept.shape}.")

    def combine(self, forces: Float[Array, "... N"]) -> Float[Array, "..."]:
        return self.intercept + jnp.sum(forces * self.weights, axis=-1)

    @classmethod
    def fit(
        cls, members: Sequence[AbstractFrictionModel], data: Any, *, predictions: Any = None, rcond: Any = None
    ) -> WeightedEnsemble:
        """Deprecated: `fj.fit_weighted_ensemble(members, data, predictions=..., rcond=...)`, which takes the same
        arguments and returns the same ensemble."""
        warnings.warn(
            "fj.WeightedEnsemble.fit is deprecated; call fj.fit_weighted_ensemble(members, data, ...) (same "
            "arguments, same result).",
            DeprecationWarning,
            stacklevel=2,
        )
        return DEPRECATED_FIT["fit_weighted_ensemble"](members, data, predictions=predictions, rcond=rcond)


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------
