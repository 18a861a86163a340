"""Identification of a local (nearest-neighbour) model: its embedding and neighbourhood chosen by validation.

parlitz2004 §III-F: a local model has no parameters to fit, only choices: the embedding (dimension and delay),
the number of neighbours, the regularisation. parlitz2004 chose them by minimising the leave-one-out error
(a genetic algorithm for the delays and the number of neighbours). Here a grid of (embedding dimension, delay,
neighbours) is scored by the free-run error on a validation record, the way the model will be judged, and the
best configuration is returned. Optionally the force sensor's drift is fitted with it (parlitz2004 §IV-F: the
local model "is unable to extrapolate the trend in the force time series"; their LM-DT detrended the force).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._constraints import Fixed
from ..._data._record import FrictionData
from ..._metrics import numpy_nmse
from ..._models.blackbox._local import KINDS, LocalModel, delay_columns
from ..._models.blackbox._regressors import PlayOperators
from ..._models.combine._sensor import SensorDrift
from ..._simulate import simulate
from ..._validation import integer, integers
from .._sweep import stack_models
from ..linear._regressor_rows import play_states, teacher_forced_rows
from ..loop._solution import Solution


class LocalModelSearch(eqx.Module):
    """What `identify_local_model` returns besides the model, as its `fj.Solution`'s typed `aux` (the fields read
    through: `solution.scores` is `solution.aux.scores`):

    - `scores`: the validation free-run NMSE [%] of every configuration, shape
      `(len(embedding), len(delay), len(neighbours))` (`inf` where the prediction was not finite).
    - `rates`: the fitted drift rates [N/s], same shape (zeros without `drift`).
    - `embedding`, `delay`, `neighbours`: the grid's values along each axis.
    - `best`: the chosen `(embedding, delay, neighbours)`.
    """

    scores: np.ndarray
    rates: np.ndarray
    embedding: tuple[int, ...]
    delay: tuple[int, ...]
    neighbours: tuple[int, ...]
    best: tuple[int, int, int]


def identify_local_model(
    data: Any,
    *,
    validation: Any,
    validation_burn_in: int = 0,
    embedding: int | Sequence[int] = (2, 4, 8),
    delay: int | Sequence[int] = (1, 5, 20),
    neighbours: int | Sequence[int] = (5, 20, 100),
    kind: Literal["constant", "linear"] = "constant",
    rank: int | None = None,
    rcond: float = 1e-3,
    signals: Sequence[str] = ("x",),
    output_embedding: int = 0,
    output_delay: int = 1,
    plays: Any = None,
    drift: bool = False,
    burn_in: int | None = None,
) -> Solution:
    """Identify a local model (`fj.LocalModel`, parlitz2004 §III-F) by a grid search scored on a validation record.

    1. Training set: the record `data`'s delay vectors (`LocalModel.from_data`: each of `signals` at lags
       `0, tau, ..., (m - 1) tau`, the play states of `plays`, `output_embedding` past forces) and forces, from
       sample `burn_in` on (default: the largest lag of the grid, so every configuration has the same points).
    2. Grid: every `(m, tau, k)` of `embedding x delay x neighbours`. The configurations share one maximal shape
       (unused coordinates switched off by the metric, unused neighbours by the neighbour mask), so one compiled
       program scores them all: configurations of `(m, tau)` one after the other (`lax.map`), the neighbour
       counts side by side (`vmap`; one neighbour search serves every `k`).
    3. Score: the free-run NMSE [%] on `validation` after its first `validation_burn_in` samples. For hysteretic
       data pass the record from the start of training to the end of the validation part, with
       `validation_burn_in` = the training part's length, so that the model enters the validation part in the
       state its history gives it. Without fed-back forces the free run is the prediction at the record's
       (teacher-forced) delay vectors, all evaluated at once; with them, `fj.simulate` runs each configuration.
    4. Drift (`drift=True`, models without fed-back forces): the sensor drift `rate * t` (t from each record's
       first sample) is fitted with each configuration: the local model is trained on `F_n - rate t_n` and
       `fj.SensorDrift` adds `rate t` back. The prediction is linear in the training forces (a local model is a
       linear smoother, `LocalModel.predict(..., targets=)`), so the validation error is affine in `rate`, and
       `rate` is its least-squares solution on the validation part (one number per configuration, fitted
       where the configuration is scored). parlitz2004's LM-DT subtracted a line fitted to the force itself,
       which the excitation biases.

    The best configuration (lowest validation NMSE) is rebuilt on the same training set and returned.

    **Arguments:**

    - `data`: the training record (`fj.FrictionData`).
    - `validation`: the validation record (`fj.FrictionData`), starting at the training record's first sample
      when `drift=True` (its time origin is the drift's).
    - `validation_burn_in`: samples of `validation` simulated but not scored (default 0).
    - `embedding`, `delay`, `neighbours`: an integer or a sequence of integers each (>= 1): the grid.
    - `kind`, `rank`, `rcond`: the local model (`"constant"` or `"linear"` with TPCR), as in `fj.LocalModel`.
    - `signals`, `output_embedding`, `output_delay`, `plays`: the coordinates, as in `LocalModel.from_data`.
    - `drift`: fit the sensor drift (returns `fj.SensorDrift(local_model, rate)`).
    - `burn_in`: training samples not used as points (default: the grid's largest lag).

    **Returns:** a `fj.Solution`: its `model` is the best `LocalModel`, its training set the whole training record
    (from `burn_in` on); with `drift=True` wrapped in `fj.SensorDrift(model, rate)` (the local model then holds the
    detrended forces); its `aux` a `LocalModelSearch` (scores, rates, embedding, delay, neighbours, best).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> x = 1e-5 * np.sin(np.linspace(0, 40, 2000)) * np.linspace(0.2, 1, 2000)
    >>> data = fj.FrictionData(fj.Motion.from_position(x, dt=1e-3), np.tanh(2e5 * x))
    >>> result = fj.identify_local_model(
    ...     data.slice(0, 1500), validation=data, validation_burn_in=1500, embedding=(1, 2), delay=1,
    ...     neighbours=(1, 4))
    >>> result.scores.shape, result.best
    ((2, 1, 2), (1, 1, 1))
    ```
    """
    where = "identify_local_model"
    grids = {
        name: integers(value, name, where)
        for name, value in (("embedding", embedding), ("delay", delay), ("neighbours", neighbours))
    }
    if kind not in KINDS:
        raise ValueError(f"{where}: `kind` must be 'constant' or 'linear', got {kind!r}.")
    if not isinstance(drift, bool):
        raise TypeError(f"{where}: `drift` must be True or False, got {drift!r}.")
    for name, record in (("data", data), ("validation", validation)):
        if not (hasattr(record, "motion") and hasattr(record, "force")):
            raise TypeError(f"{where}: `{name}` must be an fj.FrictionData, got {type(record).__name__}.")
    if output_embedding and drift:
        raise ValueError(
            f"{where}: `drift=True` needs a model without fed-back forces (its prediction is then linear in the "
            "training forces); set output_embedding=0, or drift=False."
        )
    validation_burn_in = integer(
        validation_burn_in,
        "validation_burn_in",
        where,
        minimum=0,
        maximum=validation.length - 1,
        hint="(samples of the validation record)",
    )

    # one maximal structure: the largest input and output lags of the grid
    input_lags = max((m - 1) * tau for m in grids["embedding"] for tau in grids["delay"])
    output_lags = 1 + (output_embedding - 1) * output_delay if output_embedding else 0
    burn_in = max(input_lags, output_lags) if burn_in is None else burn_in
    k_max = max(grids["neighbours"])
    states = None if plays is None else play_states(PlayOperators(plays), data.motion.samples(frozenset({"x"})))
    template = LocalModel.from_data(
        data,
        embedding=max(grids["embedding"]),
        delay=max(grids["delay"]),
        signals=signals,
        output_embedding=output_embedding,
        output_delay=output_delay,
        plays=plays,
        play_states=states,
        neighbours=k_max,
        kind=kind,
        rank=rank,
        rcond=rcond,
        burn_in=burn_in,
    )  # checks the structure and the sizes (burn-in, k_max <= points)
    regressors = template.regressors
    rows = regressors.teacher_forced(data.motion.samples(regressors.requires), data.force, states)[burn_in:]
    width = template.dimension
    configs = []
    for m in grids["embedding"]:
        for tau in grids["delay"]:
            used = delay_columns(regressors, m, tau, output_embedding, output_delay)
            columns = np.zeros(width, np.int32)
            columns[: used.size] = used
            metric = (np.arange(width) < used.size).astype(float)
            configs.append(
                LocalModel(
                    regressors,
                    rows[:, columns],
                    template.forces.value,
                    columns=columns,
                    neighbours=k_max,
                    kind=kind,
                    rank=rank,
                    rcond=rcond,
                    metric=metric,
                )
            )
    masks = jnp.asarray(np.arange(k_max)[None, :] < np.asarray(grids["neighbours"])[:, None], rows.dtype)
    dt = float(np.asarray(data.motion.dt))
    times = dt * np.arange(data.length)[burn_in:]
    measured = np.asarray(validation.force, dtype=float)[validation_burn_in:]
    if output_embedding:
        predictions = np.asarray(_free_runs(stack_models(configs), masks, validation.motion))[..., validation_burn_in:]
        rates = np.zeros(predictions.shape[:2])
    else:
        queries = teacher_forced_rows(regressors, validation.motion.samples(regressors.requires), validation.force)
        targets = jnp.stack([template.forces.value, jnp.asarray(times, rows.dtype)], axis=1)
        both = np.asarray(_predictions(stack_models(configs), masks, queries[validation_burn_in:], targets))
        t_val = dt * np.arange(validation.length)[validation_burn_in:]
        rates = _drift_rates(measured, both[..., 0], t_val - both[..., 1]) if drift else np.zeros(both.shape[:2])
        predictions = both[..., 0] + rates[..., None] * (t_val - both[..., 1])
    scores = numpy_nmse(measured, predictions)  # scaled before squaring: forces of 1e200 N score too
    scores = np.where(np.isfinite(scores), scores, np.inf)
    shape = (len(grids["embedding"]), len(grids["delay"]), len(grids["neighbours"]))
    scores, rates = scores.reshape(shape), rates.reshape(shape)
    if not np.isfinite(scores).any():
        raise ValueError(f"{where}: no configuration gave a finite validation error; check the records for NaN.")
    i, j, l = np.unravel_index(int(np.argmin(scores)), shape)
    best = (grids["embedding"][i], grids["delay"][j], grids["neighbours"][l])
    rate = float(rates[i, j, l])
    force = np.asarray(data.force, dtype=float) - (rate * dt * np.arange(data.length) if drift else 0.0)
    model: Any = LocalModel.from_data(
        FrictionData(data.motion, jnp.asarray(force, rows.dtype)),
        embedding=best[0],
        delay=best[1],
        signals=signals,
        output_embedding=output_embedding,
        output_delay=output_delay,
        plays=plays,
        play_states=states,
        neighbours=best[2],
        kind=kind,
        rank=rank,
        rcond=rcond,
        burn_in=burn_in,
    )
    if drift:
        model = SensorDrift(model, rate)
    return Solution(
        model=model,
        message=f"(embedding, delay, neighbours) = {best}: the lowest validation free-run NMSE of {scores.size} "
        "configurations",
        val_loss=float(scores[i, j, l]) / 100.0,
        aux=LocalModelSearch(
            scores=scores,
            rates=rates,
            embedding=grids["embedding"],
            delay=grids["delay"],
            neighbours=grids["neighbours"],
            best=best,
        ),
    )


@eqx.filter_jit
def _predictions(configs: Any, masks: Any, queries: Any, targets: Any) -> Any:
    """`(C, Kn, T, 2)`: each configuration's prediction of the targets at the query rows, for each neighbour mask
    (one search per query and configuration: the distances do not depend on the mask)."""

    def one(config: LocalModel) -> Any:
        rows = queries[:, config.columns.value]

        def with_mask(mask: Any) -> Any:
            return eqx.tree_at(lambda m: m.neighbour_mask, config, Fixed(mask)).predict(rows, targets)

        return jax.vmap(with_mask)(masks)

    return jax.lax.map(one, configs)


@eqx.filter_jit
def _free_runs(configs: Any, masks: Any, motion: Any) -> Any:
    """`(C, Kn, T)`: the free run of each configuration and neighbour mask along `motion`."""

    def one(config: LocalModel) -> Any:
        def with_mask(mask: Any) -> Any:
            return simulate(eqx.tree_at(lambda m: m.neighbour_mask, config, Fixed(mask)), motion)

        return jax.vmap(with_mask)(masks)

    return jax.lax.map(one, configs)


def _drift_rates(measured: np.ndarray, predicted: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """Per configuration, the rate minimising `|measured - predicted - rate * lever|^2` (closed form)."""
    residual = measured - predicted
    denominator = np.sum(np.square(lever), axis=-1)
    return np.where(denominator > 0, np.sum(residual * lever, axis=-1) / np.where(denominator > 0, denominator, 1), 0)
