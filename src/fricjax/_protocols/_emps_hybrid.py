"""EMPS grey + black-box hybrids, ensembles of fitted plants and closed-loop errors (emps-ensemble §3.2-3.3).

- `fit_emps_hybrid`: an `EMPSPlant` whose friction is a `HybridFriction` (a static law plus a small tanh
  network residual on the force path, reading velocity, position and / or drive force), trained by the
  official open-loop simulation error (`EMPSOpenLoopLoss`, output error through the simulator's `lax.scan`),
  the physics parameters free or frozen; Adam (`fit` with optax), then optionally Levenberg-Marquardt; its
  free-run error on a held-out tail of the *training* record compares variants.
- `EMPSEnsemble` / `fit_emps_ensemble`: ensembles of fitted plants that combine their simulated **positions**
  (as the paper's EGBB, eq. 16, combines the predicted outputs): the simple average, least-squares weights
  with an intercept, or PRESS forward selection (orthogonal forward regression with the leave-one-out
  statistic, worden2007 §7) on `fj.lstsq` / `fj.select_terms`; weights from a training record only.
- `emps_closed_loop_errors`: the relative errors [%] of position, velocity and force of a plant run under the
  PD controller (`simulate_closed_loop`), as the benchmark's reference model is scored (Janot et al. 2019).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Float

from .._data._emps import EMPSRecord
from .._data._preprocessing import butter_filtfilt
from .._estimation._fit import fit
from .._estimation.linear._lstsq import lstsq
from .._estimation.linear._term_selection import select_terms
from .._estimation.loop._levenberg_marquardt import levenberg_marquardt
from .._estimation.loop._solution import FitResult
from .._estimation.loop._strategies import ParameterScaling
from .._metrics import numpy_rmse
from .._models.combine._hybrid import HybridFriction
from .._smoothing import Smooth, with_smoothing
from .._systems._emps import EMPSPlant, simulate_closed_loop
from .._validation import nonnegative_int, positive_float
from ._emps_open_loop import (
    EMPSOpenLoopLoss,
    _check_plant,
    _check_record,
    predict_emps_open_loop,
    score_emps_open_loop,
    split_emps_record,
)

_SHAPE = ("v0", "vs", "delta")
_NETWORK = ("friction.W", "friction.b", "friction.d")


class EMPSHybridFit(NamedTuple):
    """What `fit_emps_hybrid` returns.

    - `plant`: the fitted `EMPSPlant` with its `HybridFriction` (smooth law, as trained).
    - `result`: the `FitResult` of the Adam stage (losses in mm^2: `sqrt(result.train_loss)` is the training
      RMSE in mm on the part it was trained on, `sqrt(result.val_loss)` the held-out tail's).
    - `refined`: the `FitResult` of the Levenberg-Marquardt stage, or `None` (`lm_steps=0`).
    - `start`: the start plant (the physics with a zero residual: it simulates exactly as `physics`).
    - `val_rmse_mm`: the official free-run RMSE [mm] of `plant` on the held-out part (NaN without one).
    """

    plant: EMPSPlant
    result: FitResult
    refined: FitResult | None
    start: EMPSPlant
    val_rmse_mm: float


def emps_hybrid_start(
    physics: EMPSPlant,
    record: EMPSRecord,
    inputs: Sequence[str] = ("v", "q"),
    width: int = 16,
    *,
    key: Array,
    force_scale: float = 1.0,
) -> EMPSPlant:
    """`physics` with its friction law wrapped in a `HybridFriction` of zero residual (so it simulates exactly
    as `physics`), the network's inputs normalised by the training record: velocity by its standard deviation
    (centred at 0, m/s), position by its mean and standard deviation (m), drive force `gtau * vir` by its
    standard deviation (centred at 0, N); `force_scale` the residual's force unit [N]."""
    _check_plant(physics)
    _check_record(record, "record", 2)
    if physics.friction.reads_plant:
        raise TypeError("emps_hybrid_start: `physics` already has a HybridFriction; give the plant of a static law.")
    qm = np.asarray(record.qm, np.float64)
    stats = {
        "v": (0.0, float(np.std(np.gradient(qm) / record.dt))),
        "q": (float(np.mean(qm)), float(np.std(qm))),
        "u": (0.0, float(np.std(record.gtau * np.asarray(record.vir, np.float64)))),
    }
    chosen = [name for name in ("v", "q", "u") if name in tuple(inputs)]
    if len(chosen) != len(tuple(inputs)):
        raise ValueError(f"`inputs` must be distinct names from ('v', 'q', 'u'), got {tuple(inputs)!r}.")
    friction = HybridFriction.init(
        physics.friction,
        chosen,
        width,
        key=key,
        center=[stats[n][0] for n in chosen],
        scale=[max(stats[n][1], 1e-12) for n in chosen],
        force_scale=force_scale,
    )
    return eqx.tree_at(lambda p: p.friction, physics, friction)


def fit_emps_hybrid(
    record: EMPSRecord,
    physics: EMPSPlant,
    *,
    inputs: Sequence[str] = ("v", "q"),
    width: int = 16,
    freeze_physics: bool = False,
    steps: int = 400,
    learning_rate: float = 3e-3,
    lm_steps: int = 0,
    validation: float | EMPSRecord | None = 0.3,
    early_stopping: bool = False,
    eps: float = 1e-4,
    seed: int = 0,
    loss: EMPSOpenLoopLoss | None = None,
    **fit_options: Any,
) -> EMPSHybridFit:
    """Fit a grey + black-box EMPS plant (a static law plus a network residual) by open-loop simulation error.

    1. The start is `physics` (e.g. `fit_emps_open_loop(train, law).plant`, any of the eight laws) with its
       law made smooth (`Smooth(eps)`) and wrapped in a `HybridFriction` of zero residual
       (`emps_hybrid_start`): it simulates exactly as the physics.
    2. Adam (`fit` with `optax.adam(learning_rate)`, `steps` steps; 3e-3 by default: 1e-2 made the fits with free
       physics jump at the start on the head of DATA_EMPS) on the official criterion
       (`EMPSOpenLoopLoss`: the free run of the position from the initialisation window, in mm), gradients by
       reverse mode through the simulator's `lax.scan`; the physics parameters are scaled by their magnitude
       (`ParameterScaling`), the network's weights are not. The last model is kept, or with
       `early_stopping=True` the one with the lowest free-run error on the held-out part (the tail of EMPS is
       not stationary, so that choice over the iterations can pick a model that fits the tail by chance and
       the head badly: off by default; the held-out error serves to compare variants).
    3. With `lm_steps > 0`, Levenberg-Marquardt on the same residuals refines every trained parameter.

    The physics parameters are either frozen (`freeze_physics=True`: `M`, the law and the offsets keep the
    values of `physics`; only the network trains) or free (trained with the network, except, as in
    `fit_emps_open_loop`, the plant's own offset, the shape parameters `v0`, `vs`, `delta`, and the law's
    offset for the asymmetric laws).

    **Arguments:**

    - `record`: the training `EMPSRecord` (`DATA_EMPS.mat`); never the test file.
    - `physics`: the start `EMPSPlant` of a static law.
    - `inputs`: the residual's signals from `("v", "q", "u")` (velocity, position, drive force `gtau * vir`).
    - `width`: hidden tanh units (16). `seed`: for the network's initial weights.
    - `freeze_physics`: train only the network (default False).
    - `steps`, `learning_rate`: the Adam stage. `lm_steps`: the Levenberg-Marquardt stage (0: none).
    - `validation`: a fraction in (0, 1) of the record held out at its end (default 0.3: trained on the head,
      the tail scored in free run from its own window), another `EMPSRecord`, or `None`.
    - `early_stopping`: keep the iterate with the best held-out error instead of the last one.
    - `eps`: the smoothing width of the law during training [m/s] (1e-4, the end of `fit_emps_open_loop`'s
      continuation).
    - `loss`: an `EMPSOpenLoopLoss` (default: window 20, cubic initial state, one step per sample).
    - `fit_options`: passed on to both `fit` calls (`eval_every`, `progress`, ...; `patience` with
      `early_stopping=True`).

    **Returns:** an `EMPSHybridFit(plant, result, refined, start, val_rmse_mm)`.

    ```python
    >>> import fricjax as fj
    >>> train = fj.load_emps(fj.data_folder("emps") / "DATA_EMPS.mat")  # doctest: +SKIP
    >>> physics = fj.emps.fit_emps_open_loop(train, fj.CoulombViscous).plant  # doctest: +SKIP
    >>> hybrid = fj.emps.fit_emps_hybrid(train, physics, inputs=("v", "q"))  # doctest: +SKIP
    >>> test = fj.load_emps(fj.data_folder("emps") / "DATA_EMPS_PULSES.mat")  # doctest: +SKIP
    >>> fj.emps.score_emps_open_loop(hybrid.plant, test)  # doctest: +SKIP
    ```
    """
    loss = EMPSOpenLoopLoss() if loss is None else loss
    if not isinstance(loss, EMPSOpenLoopLoss):
        raise TypeError(f"`loss` must be an EMPSOpenLoopLoss, got {type(loss).__name__}.")
    _check_record(record, "record", loss.init_window)
    _check_plant(physics)
    eps = positive_float(eps, "eps", "fit_emps_hybrid", hint="(a smoothing width in m/s, e.g. 1e-4)")
    steps = nonnegative_int(steps, "steps", "fit_emps_hybrid", hint="(solver steps)")
    lm_steps = nonnegative_int(lm_steps, "lm_steps", "fit_emps_hybrid", hint="(solver steps)")
    train, val = _split(record, validation, loss.init_window)
    if "patience" in fit_options and not (early_stopping and val is not None):
        raise ValueError(
            "fit_emps_hybrid: `patience` stops on the held-out error, which is watched only with "
            "`early_stopping=True` and a `validation` part; pass both, or drop `patience`."
        )
    smooth: Any = with_smoothing(physics, Smooth(eps))
    start = emps_hybrid_start(smooth, train, inputs, width, key=jax.random.PRNGKey(seed))
    freeze = _frozen(start, freeze_physics)
    scaling = ParameterScaling(scale={path: 1.0 for path in _NETWORK})
    watched = val if early_stopping else None
    result = fit(
        start,
        train,
        loss=loss,
        solver=optax.adam(learning_rate),
        steps=max(int(steps), 1),
        validation=watched,
        freeze=freeze,
        scaling=scaling,
        **fit_options,
    )
    plant, refined = result.model, None
    if lm_steps > 0:
        refined = fit(
            plant,
            train,
            loss=loss,
            solver=levenberg_marquardt(),
            steps=int(lm_steps),
            validation=watched,
            freeze=freeze,
            scaling=scaling,
            **fit_options,
        )
        plant = refined.model
    val_rmse = float("nan")
    if val is not None:
        val_rmse = score_emps_open_loop(
            plant, val, init_window=loss.init_window, degree=loss.degree, substeps=loss.substeps
        )
    return EMPSHybridFit(plant=plant, result=result, refined=refined, start=start, val_rmse_mm=val_rmse)


def _split(record: EMPSRecord, validation: Any, window: int) -> tuple[EMPSRecord, EMPSRecord | None]:
    if validation is None:
        return record, None
    if isinstance(validation, EMPSRecord):
        _check_record(validation, "validation", window)
        return record, validation
    if isinstance(validation, (float, np.floating)) and 0.0 < float(validation) < 1.0:
        cut = int(round(record.length * (1.0 - float(validation))))
        train, val = split_emps_record(record, 0, cut), split_emps_record(record, cut)
        _check_record(train, "record (head)", window)
        _check_record(val, "validation (tail)", window)
        return train, val
    raise ValueError(
        f"`validation` must be None, a fraction in (0, 1) of the record to hold out, or an EMPSRecord; got "
        f"{validation!r}."
    )


def _frozen(plant: EMPSPlant, freeze_physics: bool) -> tuple[str, ...]:
    if freeze_physics:
        return ("mass", "offset", "friction.law")
    law = plant.friction.law  # type: ignore[attr-defined]
    frozen = ["offset", *(f"friction.law.{name}" for name in _SHAPE if hasattr(law, name))]
    if law.asymmetric:
        frozen.append("friction.law.offset")
    return tuple(frozen)


# ---------------------------------------------------------------------------------------------------------------
# Ensembles of simulated positions


class EMPSEnsemble(eqx.Module):
    """An ensemble of fitted EMPS plants that combines their free-run **positions** (emps-ensemble §3.3, eq. 16):

        q_hat(k) = intercept + sum_i weights_i * q_i(k),

    `q_i` the official free run of plant i (`predict_emps_open_loop`: from the state the initialisation
    window gives). The average ensemble has `weights = 1/N`, `intercept = 0`.

    **Arguments:** `plants` (N >= 1 `EMPSPlant`s, static laws or hybrids); `weights` `(N,)`; `intercept` [m].
    """

    plants: tuple[EMPSPlant, ...]
    weights: Float[Array, "N"]
    intercept: Float[Array, ""]

    def __init__(self, plants: Sequence[EMPSPlant], weights: Any = None, intercept: Any = 0.0):
        plants = tuple(plants)
        if not plants:
            raise ValueError("EMPSEnsemble: `plants` is empty; give at least one fitted EMPSPlant.")
        for plant in plants:
            _check_plant(plant)
        self.plants = plants
        n = len(plants)
        self.weights = jnp.full((n,), 1.0 / n) if weights is None else jnp.asarray(weights, jnp.result_type(float))
        self.intercept = jnp.asarray(intercept, jnp.result_type(float))
        if self.weights.shape != (n,) or self.intercept.shape != ():
            raise ValueError(
                f"EMPSEnsemble: `weights` must have shape ({n},) and `intercept` be a scalar [m], got "
                f"{self.weights.shape} and {self.intercept.shape}."
            )

    def member_positions(self, record: EMPSRecord) -> Float[Array, "N T"]:
        """Each plant's official free-run position on `record` [m], shape `(N, T)`."""
        return jnp.stack([predict_emps_open_loop(plant, record).q for plant in self.plants])

    def predict(self, record: EMPSRecord, positions: Any = None) -> Float[Array, "T"]:
        """The ensemble's position on `record` [m] (`positions`: the members' `(N, T)`, if already simulated)."""
        q = self.member_positions(record) if positions is None else jnp.asarray(positions)
        return self.intercept + jnp.tensordot(self.weights, q, axes=1)

    def score(self, record: EMPSRecord, positions: Any = None) -> float:
        """The official score of the ensemble on `record`: position RMSE [mm] after the window (20 samples)."""
        q = self.predict(record, positions)
        error = np.asarray(record.qm, np.float64)[20:] - np.asarray(q, np.float64)[20:]
        return float(1000.0 * numpy_rmse(error))


class EMPSEnsembleFit(NamedTuple):
    """What `fit_emps_ensemble` returns: the `ensemble`, the chosen members' `indices` into the given plants,
    and `press` (the PRESS history of the forward selection [m^2], empty for the other methods)."""

    ensemble: EMPSEnsemble
    indices: tuple[int, ...]
    press: tuple[float, ...]


def fit_emps_ensemble(
    plants: Sequence[EMPSPlant],
    record: EMPSRecord,
    method: Literal["average", "lstsq", "nonnegative", "press"] = "lstsq",
    *,
    positions: Any = None,
    max_members: int | None = None,
) -> EMPSEnsembleFit:
    """Combine fitted EMPS plants by their simulated positions on a *training* record (emps-ensemble §3.3).

    - `"average"`: `q_hat = mean_i q_i` (nothing fitted).
    - `"lstsq"`: `min || qm - intercept - sum_i w_i q_i ||^2` over `qm[20:]` (the scored samples), `fj.lstsq`
      of the centred free runs on the centred measured position (eq. 16, with intercept).
    - `"nonnegative"`: the same with `w_i >= 0` (`fj.lstsq(..., nonnegative=True)`): the free runs of good
      members are nearly collinear, and unconstrained weights of opposite signs and large magnitudes (seen on
      EMPS: +-3 for eight laws) fit the training drift and extrapolate badly.
    - `"press"`: orthogonal forward regression with the PRESS statistic (`fj.select_terms`, worden2007 §7):
      add the member that most lowers the leave-one-out error, stop when none does; then least squares.

    The members' positions are simulated on `record` (the file the plants were fitted on: the weights are
    in-sample, as in the paper) unless `positions` `(N, T)` is given.

    **Returns:** an `EMPSEnsembleFit(ensemble, indices, press)`.
    """
    plants = tuple(plants)
    if not plants:
        raise ValueError("fit_emps_ensemble: `plants` is empty; give at least one fitted EMPSPlant.")
    _check_record(record, "record", 20)
    if method not in ("average", "lstsq", "nonnegative", "press"):
        raise ValueError(
            f"fit_emps_ensemble: `method` must be 'average', 'lstsq', 'nonnegative' or 'press', got {method!r}."
        )
    if method == "average":
        return EMPSEnsembleFit(EMPSEnsemble(plants), tuple(range(len(plants))), ())
    q = EMPSEnsemble(plants).member_positions(record) if positions is None else jnp.asarray(positions)
    if q.shape != (len(plants), record.length):
        raise ValueError(
            f"fit_emps_ensemble: `positions` must have shape ({len(plants)}, {record.length}), got {q.shape}."
        )
    forces = np.asarray(q, np.float64)[:, 20:]
    target = np.asarray(record.qm, np.float64)[20:]
    if not np.all(np.isfinite(forces)):
        raise ValueError("fit_emps_ensemble: a member's free run is not finite on `record`; drop that plant.")
    indices: tuple[int, ...] = tuple(range(len(plants)))
    press: tuple[float, ...] = ()
    if method == "press":
        selection = select_terms(forces.T, target, criterion="press", max_terms=max_members, intercept=True)
        if not selection.indices:
            raise ValueError("fit_emps_ensemble: no member lowers the PRESS of the mean position.")
        indices, press = tuple(selection.indices), tuple(float(v) for v in selection.press)
    chosen = forces[list(indices)]
    mean_f, mean_y = chosen.mean(axis=1), target.mean()
    weights = np.asarray(lstsq((chosen - mean_f[:, None]).T, target - mean_y, nonnegative=method == "nonnegative").x)
    intercept = float(mean_y - mean_f @ weights)
    return EMPSEnsembleFit(EMPSEnsemble([plants[i] for i in indices], weights, intercept), indices, press)


# ---------------------------------------------------------------------------------------------------------------
# Closed loop


def emps_closed_loop_errors(
    plant: EMPSPlant, record: EMPSRecord, *, start: int = 49, cutoff_hz: float = 100.0
) -> dict[str, float]:
    """Relative errors [%] of `plant` run under the benchmark's PD controller, as the reference model is scored.

    The plant tracks `record.qg` in `simulate_closed_loop` (with the record's `pulses` added to the command,
    from `q0 = qm[0]`); against the measured position filtered by `butter_filtfilt(qm, dt, cutoff_hz)`, its
    central-difference velocity and the measured force `gtau * vir`, from sample `start` (MATLAB's sample 50):
    `100 ||y - y_sim|| / ||y||` for `position`, `velocity` and `force` (Janot et al. 2019, §3.4: the
    published model gives 0.0138 % / 0.0080 % position error on the training / test file, on the Simulink
    time base; 0.0010 % / 0.0016 % here).
    """
    _check_plant(plant)
    _check_record(record, "record", start + 2)
    sim = simulate_closed_loop(
        plant,
        record.qg,
        record.gtau,
        record.kp,
        record.kv,
        record.dt,
        q0=record.qm[0],
        disturbance=record.pulses,
    )
    q_f = np.asarray(butter_filtfilt(record.qm, record.dt, cutoff_hz), np.float64)
    measured = {
        "position": q_f,
        "velocity": np.gradient(q_f) / record.dt,
        "force": np.asarray(record.force, np.float64),
    }
    simulated = {
        "position": np.asarray(sim.q, np.float64),
        "velocity": np.asarray(sim.qd, np.float64),
        "force": record.gtau * np.asarray(sim.vir, np.float64),
    }
    return {
        f"{name}_pct": float(
            100.0 * numpy_rmse(measured[name][start:] - simulated[name][start:]) / numpy_rmse(measured[name][start:])
        )
        for name in measured
    }
