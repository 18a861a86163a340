"""Fitting ensembles: least-squares weights with intercept (emps-ensemble §3.3, eq. 16) and the PRESS forward
selection of members (worden2007 §7), on the shared linear-algebra kernel (`fj.lstsq`, `fj.select_terms`).

The ensemble classes live in `fricjax._models.combine._ensemble` (below this layer: they know nothing of fitting).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from ..._constraints import as_float_array
from ..._data._record import FrictionData
from ..._models._base import AbstractFrictionModel
from ..._models.combine._ensemble import DEPRECATED_FIT, WeightedEnsemble, _as_members
from ..._simulate import simulate
from ..._smoothing import is_concrete
from ..._validation import optional, positive_int
from ..linear._lstsq import lstsq
from ..linear._term_selection import select_terms


def fit_weights(
    members: Sequence[AbstractFrictionModel],
    data: Any,
    predictions: ArrayLike | None,
    rcond: float | None,
    where: str,
) -> tuple[Array, Array]:
    """Least-squares `weights` (N,) and `intercept` of `data.force ~ intercept + sum_i weights_i F_i`.

    The intercept is taken out by centring (the least-squares intercept makes the residual mean zero), so only
    the weights go through `lstsq`, on the centred member forces: a member with a constant force (spanned by
    the intercept) centres to a zero column and gets weight 0. Jittable when `predictions` is given.
    """
    forces, target = _design(members, data, predictions, where)
    mean_f = jnp.mean(forces, axis=-1)
    mean_y = jnp.mean(target)
    weights = lstsq((forces - mean_f[:, None]).T, target - mean_y, rcond=rcond).x
    return weights, mean_y - jnp.dot(mean_f, weights)


def fit_weighted_ensemble(
    members: Sequence[AbstractFrictionModel],
    data: FrictionData,
    *,
    predictions: ArrayLike | None = None,
    rcond: float | None = None,
) -> WeightedEnsemble:
    """Least-squares weights and intercept of the members' simulated forces on `data` (emps-ensemble §3.3, eq. 16).

    Solves `min || data.force - intercept - sum_i weights_i * F_i ||^2` with `F_i = fj.simulate(member_i,
    data.motion)`: `fj.lstsq` (an SVD solve on norm-scaled regressors, so members whose forces differ by orders of
    magnitude are weighted accurately) of the centred forces on the centred measured force. Collinear members (e.g.
    two copies of one model, or a member predicting a constant, which the intercept already spans) get the
    minimum-norm split of their shared weight. Fit on data the members were *not* trained on (the validation
    split): on their training data, overfitted members would draw too much weight. Since every single member
    (weight 1, intercept 0) is one candidate solution, the ensemble's squared error on `data` is never larger than
    the best member's. Jittable when `predictions` is given (value checks are skipped when traced).

    **Arguments:**

    - `members`: N >= 1 fitted friction models.
    - `data`: a `FrictionData` (motion and measured force) to fit the weights on.
    - `predictions`: the members' forces on `data.motion`, shape `(N, T)`, if already simulated
      (`jnp.stack([fj.simulate(member, data.motion) for member in members])`); simulated when `None`.
    - `rcond`: relative cut-off for small singular values (see `fj.lstsq`).

    **Returns:** a `fj.WeightedEnsemble` with the fitted `weights` (N,) and `intercept` [N].

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
    members = _as_members(members, "fit_weighted_ensemble")
    weights, intercept = fit_weights(members, data, predictions, rcond, "fit_weighted_ensemble")
    return WeightedEnsemble(members, weights, intercept)


DEPRECATED_FIT["fit_weighted_ensemble"] = fit_weighted_ensemble  # for the deprecated `WeightedEnsemble.fit`


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

    This is `fj.select_terms` (FROLS) on the members' simulated forces `F_i` on `data` as candidate regressors,
    with a constant (the intercept) always in. Starting from the intercept alone, each step orthogonalises every
    remaining member against the chosen basis (Gram-Schmidt: `w_i = F_i - Q Q^T F_i`, `q_i = w_i / ||w_i||`) and
    computes, for the model with `q_i` added, the residuals `e - q_i (q_i^T e)` and leverages `h + q_i^2`, hence
    the leave-one-out statistic `PRESS = sum_k (e_k / (1 - h_kk))^2` (Chen, Hong, Harris & Sharkey 2004, ref. 41
    of worden2007).
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
    max_members = optional(positive_int, max_members, "max_members", "select_forward", hint="(all)")
    forces, target = _design(members, data, predictions, "select_forward")
    if not (is_concrete(forces) and is_concrete(target)):
        raise ValueError("select_forward: selection is a greedy loop on values; call it outside jit / vmap.")
    selection = select_terms(
        np.asarray(forces, np.float64).T,
        np.asarray(target, np.float64),
        criterion="press" if criterion == "press" else "err",
        max_terms=max_members,
        intercept=True,
    )
    history = selection.press if criterion == "press" else selection.rss
    if not selection.indices:
        raise ValueError(
            f"select_forward: no member lowers the {criterion.upper()} of the intercept-only (mean force) "
            f"predictor ({history[0]:.6g}); the members do not explain the data."
        )
    indices = selection.indices
    chosen = [members[i] for i in indices]
    weights, intercept = fit_weights(chosen, data, forces[jnp.asarray(indices)], None, "select_forward")
    ensemble = WeightedEnsemble(chosen, weights, intercept)
    return ForwardSelection(indices=indices, ensemble=ensemble, press=tuple(float(v) for v in history))


def _design(members: Sequence[AbstractFrictionModel], data: Any, predictions: Any, where: str) -> tuple[Array, Array]:
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
        forces = jnp.stack([simulate(member, data.motion) for member in members])
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
    dtype = jnp.result_type(forces, target)
    return forces.astype(dtype), target.astype(dtype)
