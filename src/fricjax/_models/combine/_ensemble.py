"""Ensembles of fitted friction models: simple average, least-squares weights, PRESS forward selection.

An ensemble is itself a friction model: its state is the tuple of its members' states and its `step` advances
every member by one sample and combines their forces, so `fj.simulate(ensemble, motion)` runs all members in
one `lax.scan` (jit, vmap and gradients as for any model). Members may be of any family and read different
signals; the ensemble `requires` their union.

- `AverageEnsemble`: the simple average of the members' forces (parlitz2004 §IV-H: averaging the DLR, DN and
  NLR-EXP models cut the MSE from 0.75 % to 0.28 %; worden2007 §7).
- `WeightedEnsemble`: `F = intercept + sum_i weights_i * F_i`, with `WeightedEnsemble.fit` solving the weights
  and intercept by linear least squares on data the members were not trained on (emps-ensemble §3.3, eq. 16:
  the grey-box and grey + black-box predictions as regressors of the measured output).
- `select_forward` (in `fricjax._estimation._ensemble_fit`): orthogonal forward regression over the members'
  predictions with the PRESS (leave-one-out) statistic (worden2007 §7, after Chen, Hong, Harris & Sharkey 2004):
  add the member that most reduces PRESS, stop when none does.

The fitting (`WeightedEnsemble.fit`, `select_forward`) lives in `_estimation`, on `fj.lstsq` and
`fj.select_terms`.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..._constraints import model_dtype, real, unwrap
from ..._inputs import Motion, MotionSample
from .._base import AbstractFrictionModel

if TYPE_CHECKING:  # annotations only: _models does not depend on _data
    from ..._data._record import FrictionData


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

    def predict(self, motion: Motion) -> Float[Array, "T"]:
        """The ensemble force along `motion`: shorthand for `fj.simulate(self, motion)`."""
        from ..._simulate import simulate  # deferred: _simulate sits above _models (it runs them)

        return simulate(self, motion)

    def member_predictions(self, motion: Motion) -> Float[Array, "N T"]:
        """Each member's simulated force along `motion`, stacked: shape `(N, T)` (for residual plots and for
        `WeightedEnsemble.fit(..., predictions=...)`)."""
        from ..._simulate import simulate  # deferred: _simulate sits above _models (it runs them)

        return jnp.stack([simulate(member, motion) for member in self.members])


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

    Build it from known weights, or fit them with `WeightedEnsemble.fit(members, data)` (least squares with
    intercept) or choose members and weights with `select_forward`. `weights` and `intercept` are real array
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
    >>> ensemble = fj.WeightedEnsemble.fit(members, fj.FrictionData(motion, target))
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
        cls,
        members: Sequence[AbstractFrictionModel],
        data: FrictionData,
        *,
        predictions: ArrayLike | None = None,
        rcond: float | None = None,
    ) -> WeightedEnsemble:
        """Least-squares weights and intercept of the members' simulated forces on `data` (emps-ensemble §3.3).

        Solves `min || data.force - intercept - sum_i weights_i * F_i ||^2` with `F_i = fj.simulate(member_i,
        data.motion)`: `fj.lstsq` (an SVD solve on norm-scaled regressors, so members whose forces differ by
        orders of magnitude are weighted accurately) of the centred forces on the centred measured force.
        Collinear members (e.g. two copies of one model, or a member predicting a constant, which the intercept
        already spans) get the minimum-norm split of their shared weight. Fit on data the members were *not*
        trained on (the validation split): on their training data, overfitted members would draw too much
        weight. Since every single member (weight 1, intercept 0) is one candidate solution, the ensemble's
        squared error on `data` is never larger than the best member's. Jittable when `predictions` is given
        (value checks are skipped when traced).

        **Arguments:**

        - `members`: N >= 1 fitted friction models.
        - `data`: a `FrictionData` (motion and measured force) to fit the weights on.
        - `predictions`: the members' forces on `data.motion`, shape `(N, T)`, if already simulated
          (e.g. `AverageEnsemble(members).member_predictions(data.motion)`); simulated when `None`.
        - `rcond`: relative cut-off for small singular values (see `fj.lstsq`).

        **Returns:** a `WeightedEnsemble` with the fitted `weights` (N,) and `intercept` [N].
        """
        # deferred: _models sits below _estimation in the dependency order and must not import it at load time
        from ..._estimation._ensemble_fit import fit_weights

        members = _as_members(members, "WeightedEnsemble.fit")
        weights, intercept = fit_weights(members, data, predictions, rcond, "WeightedEnsemble.fit")
        return cls(members, weights, intercept)


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------
