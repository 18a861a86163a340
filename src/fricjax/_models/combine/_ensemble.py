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
- `select_forward`: orthogonal forward regression over the members' predictions with the PRESS
  (leave-one-out) statistic (worden2007 §7, after Chen, Hong, Harris & Sharkey 2004): add the member that
  most reduces PRESS, stop when none does.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..._constraints import as_float_array, model_dtype, real, unwrap
from ..._data._record import FrictionData
from ..._inputs import Motion, MotionSample
from ..._simulate import simulate
from ..._smoothing import is_concrete
from .._base import AbstractFrictionModel


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
        return simulate(self, motion)

    def member_predictions(self, motion: Motion) -> Float[Array, "N T"]:
        """Each member's simulated force along `motion`, stacked: shape `(N, T)` (for residual plots and for
        `WeightedEnsemble.fit(..., predictions=...)`)."""
        return simulate_members(self.members, motion)


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
        data.motion)`, by an SVD least-squares solve on centred and norm-scaled regressors (so members whose
        forces differ by orders of magnitude are weighted accurately). Collinear members (e.g. two copies of
        one model, or a member predicting a constant, which the intercept already spans) get the minimum-norm
        split of their shared weight. Fit on data the members were *not* trained on (the validation split):
        on their training data, overfitted members would draw too much weight. Since every single member
        (weight 1, intercept 0) is one candidate solution, the ensemble's squared error on `data` is never
        larger than the best member's. Jittable when `predictions` is given (value checks are skipped when
        traced).

        **Arguments:**

        - `members`: N >= 1 fitted friction models.
        - `data`: a `FrictionData` (motion and measured force) to fit the weights on.
        - `predictions`: the members' forces on `data.motion`, shape `(N, T)`, if already simulated
          (e.g. `AverageEnsemble(members).member_predictions(data.motion)`); simulated when `None`.
        - `rcond`: relative cut-off for small singular values (see `jnp.linalg.lstsq`).

        **Returns:** a `WeightedEnsemble` with the fitted `weights` (N,) and `intercept` [N].
        """
        members = _as_members(members, "WeightedEnsemble.fit")
        forces, target = _design(members, data, predictions, "WeightedEnsemble.fit")
        weights, intercept = _lstsq_with_intercept(forces, target, rcond)
        return cls(members, weights, intercept)


class ForwardSelection(NamedTuple):
    """The result of `select_forward`.

    - `indices`: the chosen members' indices into the given list, in the order they were selected.
    - `ensemble`: the `WeightedEnsemble` of the chosen members, least-squares weights with intercept.
    - `press`: the criterion (PRESS or residual sum of squares [N^2]) of the intercept-only predictor, then
      after each selected member: `len(press) == len(indices) + 1`, decreasing.
    """

    indices: tuple[int, ...]
    ensemble: WeightedEnsemble
    press: tuple[float, ...]


def select_forward(
    members: Sequence[AbstractFrictionModel],
    data: FrictionData,
    max_members: int | None = None,
    criterion: Literal["press", "rss"] = "press",
    *,
    predictions: ArrayLike | None = None,
) -> ForwardSelection:
    """Choose ensemble members by orthogonal forward regression with the PRESS statistic (worden2007 §7).

    The regressors are the members' simulated forces `F_i` on `data` plus a constant (the intercept, always in).
    Starting from the intercept alone, each step orthogonalises every remaining member against the chosen
    basis (Gram-Schmidt: `w_i = F_i - Q Q^T F_i`, `q_i = w_i / ||w_i||`) and computes, for the model with
    `q_i` added, the residuals `e - q_i (q_i^T e)` and leverages `h + q_i^2`, hence the leave-one-out
    statistic `PRESS = sum_k (e_k / (1 - h_kk))^2` (Chen, Hong, Harris & Sharkey 2004, ref. 41 of worden2007).
    The member with the smallest PRESS is added; selection stops when no member lowers PRESS by more than
    round-off (`100 * eps * PRESS_0`), when every member is in, or at `max_members`. A member that the chosen
    ones already span (a constant force, a copy, a zero force) is never added. Since PRESS is a cross-validation
    error, members that only fit noise are left out; `criterion="rss"` (the plain error-reduction ranking of
    orthogonal forward regression, which stops only when the residual reaches round-off) needs `max_members`
    to be meaningful.

    **Arguments:**

    - `members`: N >= 1 fitted friction models (the candidates).
    - `data`: a `FrictionData` to select and fit the weights on (a validation split, or the whole record:
      PRESS is itself a leave-one-out estimate, worden2007 §7).
    - `max_members`: the most members to choose (default: all).
    - `criterion`: `"press"` (default) or `"rss"`.
    - `predictions`: the members' forces on `data.motion`, shape `(N, T)`, if already simulated.

    **Returns:** a `ForwardSelection(indices, ensemble, press)`.

    **Raises:** `ValueError` when no member improves on the intercept-only (mean force) predictor.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 12, 400)), dt=1e-3)
    >>> members = [fj.Coulomb(Fc=1.0), fj.CoulombViscous(Fc=1e-3, Fv=20.0), fj.Coulomb(Fc=2.0)]
    >>> target = 0.1 + fj.simulate(members[0], motion) + 0.5 * fj.simulate(members[1], motion)
    >>> fj.select_forward(members, fj.FrictionData(motion, target)).indices  # member 2 is member 0 scaled
    (0, 1)
    ```
    """
    members = _as_members(members, "select_forward")
    if criterion not in ("press", "rss"):
        raise ValueError(f"select_forward: `criterion` must be 'press' or 'rss', got {criterion!r}.")
    if max_members is None:
        max_members = len(members)
    if isinstance(max_members, bool) or not isinstance(max_members, (int, np.integer)) or max_members < 1:
        raise ValueError(f"select_forward: `max_members` must be a positive integer or None, got {max_members!r}.")
    forces, target = _design(members, data, predictions, "select_forward")
    if not (is_concrete(forces) and is_concrete(target)):
        raise ValueError("select_forward: selection is a greedy loop on values; call it outside jit / vmap.")
    indices, history = _orthogonal_forward(
        np.asarray(forces, np.float64), np.asarray(target, np.float64), max_members, criterion
    )
    if not indices:
        raise ValueError(
            f"select_forward: no member lowers the {criterion.upper()} of the intercept-only (mean force) "
            f"predictor ({history[0]:.6g}); the members do not explain the data."
        )
    chosen = [members[i] for i in indices]
    ensemble = WeightedEnsemble.fit(chosen, data, predictions=forces[jnp.asarray(indices)])
    return ForwardSelection(indices=tuple(indices), ensemble=ensemble, press=tuple(history))


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------


def simulate_members(members: Sequence[AbstractFrictionModel], motion: Motion) -> Float[Array, "N T"]:
    """The simulated force of each member along `motion`, stacked to shape `(N, T)`."""
    return jnp.stack([simulate(member, motion) for member in members])


def _design(members: tuple[AbstractFrictionModel, ...], data: Any, predictions: Any, where: str) -> tuple[Array, Array]:
    """The members' forces (N, T) on `data` and the measured force (T,), checked."""
    if not isinstance(data, FrictionData):
        raise TypeError(
            f"{where}: `data` must be a fricjax.FrictionData (motion and measured force), got "
            f"{type(data).__name__}; build it as fj.FrictionData(motion, force)."
        )
    target = data.force
    if target.ndim != 1:
        raise ValueError(f"{where}: `data` must be a single record of shape (T,), got force shape {target.shape}.")
    if predictions is None:
        forces = simulate_members(members, data.motion)
    else:
        forces = as_float_array(predictions)
        expected = (len(members), data.length)
        if forces.shape != expected:
            raise ValueError(
                f"{where}: `predictions` must hold one simulated force per member and data sample, shape "
                f"{expected}, got {forces.shape}; simulate the members on `data.motion` (same length)."
            )
    if is_concrete(forces):
        finite = np.isfinite(np.asarray(forces))
        bad = [i for i in range(len(members)) if not finite[i].all()]
        if bad:
            i = bad[0]
            raise ValueError(
                f"{where}: member {i} ({type(members[i]).__name__}) predicts NaN or inf on `data` (first at sample "
                f"{int(np.flatnonzero(~finite[i])[0])}); check its parameters, or drop it from the ensemble."
            )
    if data.length <= len(members) + 1:
        raise ValueError(
            f"{where}: {data.length} samples cannot fit {len(members)} weights and an intercept; use a longer record."
        )
    return forces, target


def _lstsq_with_intercept(forces: Array, target: Array, rcond: float | None) -> tuple[Array, Array]:
    """Least-squares `target ~ intercept + weights @ forces`, on centred, unit-norm regressors."""
    dtype = jnp.result_type(forces, target)
    forces, target = forces.astype(dtype), target.astype(dtype)
    mean_f = jnp.mean(forces, axis=-1)
    mean_y = jnp.mean(target)
    centred = (forces - mean_f[:, None]).T  # (T, N)
    scale = jnp.linalg.norm(centred, axis=0)
    safe = jnp.where(scale > 0, scale, jnp.ones_like(scale))
    solution, *_ = jnp.linalg.lstsq(centred / safe, target - mean_y, rcond=rcond)
    weights = jnp.where(scale > 0, solution / safe, jnp.zeros_like(solution))
    intercept = mean_y - jnp.dot(mean_f, weights)
    return weights, intercept


def _criterion(residual: np.ndarray, leverage: np.ndarray, criterion: str) -> float:
    if criterion == "rss":
        return float(residual @ residual)
    denominator = 1.0 - leverage
    if np.any(denominator <= 1e-12):
        return float("inf")  # a sample fitted exactly by its own regressor: no leave-one-out information
    return float(np.sum((residual / denominator) ** 2))


def _orthogonal_forward(
    forces: np.ndarray, target: np.ndarray, max_members: int, criterion: str
) -> tuple[list[int], list[float]]:
    """Greedy orthogonal forward regression (float64) from the intercept; returns chosen indices and history."""
    n_members, n_samples = forces.shape
    eps = np.finfo(np.float64).eps
    residual = target - target.mean()  # after the intercept basis q_0 = 1 / sqrt(T)
    leverage = np.full(n_samples, 1.0 / n_samples)
    remainders = forces - forces.mean(axis=1, keepdims=True)  # members orthogonalised against the basis so far
    sizes = np.linalg.norm(forces, axis=1)
    basis: list[np.ndarray] = [np.full(n_samples, 1.0 / np.sqrt(n_samples))]
    history = [_criterion(residual, leverage, criterion)]
    floor = 100.0 * eps * history[0]
    chosen: list[int] = []
    while len(chosen) < max_members:
        best, best_value, best_q = -1, np.inf, None
        for i in range(n_members):
            if i in chosen:
                continue
            w = remainders[i]
            for q in basis:  # re-orthogonalise: classical Gram-Schmidt twice is accurate to round-off
                w = w - q * (q @ w)
            norm = np.linalg.norm(w)
            if sizes[i] == 0 or norm <= np.sqrt(eps) * sizes[i]:
                continue  # spanned by the chosen members and the intercept: adds nothing
            q = w / norm
            value = _criterion(residual - q * (q @ residual), leverage + q**2, criterion)
            if value < best_value:
                best, best_value, best_q = i, value, q
        if best_q is None or not best_value < history[-1] - floor:
            break
        chosen.append(best)
        basis.append(best_q)
        residual = residual - best_q * (best_q @ residual)
        leverage = leverage + best_q**2
        remainders = remainders - np.outer(remainders @ best_q, best_q)
        history.append(best_value)
    return chosen, history
