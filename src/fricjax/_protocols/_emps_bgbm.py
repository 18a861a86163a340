"""EMPS black + grey-box model (BGBM, emps-ensemble §3.2): the grey-box free run plus a model of its error.

The grey-box model (an `EMPSPlant` fitted by `fit_emps_open_loop`) simulates the position `y1`; the simulation
error `e1 = qm - y1` is modelled by a black box driven by the record's force (and optionally by the grey box's
own simulated signals), and the BGBM's output is `y2 = y1 + e1_hat` (emps-ensemble Fig. 3, §3.2; the paper uses
a NARX network with the EMPS force as input and `e1` as output).

Here the error model is a linear **output-error** filter,

    e1_hat(k) = sum_j B_j(q^-1) / A(q^-1) u_j(k),   A = 1 + a_1 q^-1 + ... + a_na q^-na,

with inputs `u_j` from `"force"` (the drive force `gtau * vir` [N]), `"qd"` / `"q"` (the grey box's simulated
velocity [m/s] / position [m]) and `"bias"` (a constant), each divided by its standard deviation on the
training record. It is fitted by simulation error (the filter runs free over the record, as `e1_hat` is used),
not by one-step equation error: on EMPS the equation-error (ARX) fit of `e1` makes the free run worse than the
grey box alone on the very part it was fitted on. `A` is parametrised by its reflection coefficients
`k_i = tanh(r_i)` (Levinson step-up), so every iterate is a stable filter; the numerators start from the
least-squares solution for the start denominator (the filter is linear in them), then Levenberg-Marquardt
(optimistix) refines all coefficients.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from .._data._emps import EMPSRecord
from .._estimation.loop._least_squares import least_squares
from .._models._base import AbstractModel
from .._simulate import run
from .._systems._emps import EMPSPlant, emps_open_loop_rmse_mm
from .._validation import fraction, nonnegative_int, positive_int
from ._emps_hybrid import _split
from ._emps_open_loop import INIT_WINDOW, _check_plant, _check_record, predict_emps_open_loop, score_emps_open_loop

ERROR_MODEL_INPUTS = ("force", "qd", "q", "bias")
"""The signals an `EMPSErrorModel` may read: drive force [N], the grey box's simulated velocity [m/s] and
position [m], a constant."""


def denominator_from_reflection(reflection: Float[Array, " na"]) -> Float[Array, " na+1"]:
    """`A(q^-1) = [1, a_1, ..., a_na]` from reflection coefficients `k_i = tanh(reflection_i)` by the Levinson
    step-up recursion `A_i(z) = A_{i-1}(z) + k_i z^-i A_{i-1}(1/z)`; stable (all roots inside the unit circle)
    for any real `reflection`."""
    a = jnp.ones((1,), jnp.result_type(reflection, float))
    for k in jnp.tanh(reflection):
        padded = jnp.concatenate([a, jnp.zeros((1,), a.dtype)])
        a = padded + k * padded[::-1]
    return a


def _lags(x: Array, n: int) -> Array:
    """`(T, ...) -> (T, ..., n)`: `x` delayed by 0 ... n-1 samples, zeros before the start."""
    padded = jnp.concatenate([jnp.zeros((n - 1, *x.shape[1:]), x.dtype), x])
    return jnp.stack([padded[n - 1 - i : n - 1 - i + x.shape[0]] for i in range(n)], axis=-1)


class AllPoleFilter(AbstractModel):
    """The all-pole filter `y_k = x_k - a_1 y_(k-1) - ... - a_na y_(k-na)` (`y = x / A`) as a model, so that its
    recursion runs in `fj.simulate`'s loop (`run`), the one scan over time. State: the last `na` outputs, newest
    first (zeros at rest). Input: the signal `x`, shape `(T,)`."""

    a: Float[Array, " na+1"]

    def init_state(self) -> Array:
        return jnp.zeros((self.a.shape[0] - 1,), self.a.dtype)

    def step(self, past: Array, xk: Array) -> tuple[Array, Array]:
        y = xk - jnp.dot(self.a[1:], past)
        return jnp.concatenate([y[None], past[:-1]]), y

    def samples(self, inputs: Array) -> Array:
        return inputs

    def check_inputs(self, inputs: Any) -> None:
        if jnp.ndim(inputs) != 1:
            raise ValueError(f"AllPoleFilter: the input must be one signal of shape (T,), got {jnp.shape(inputs)}.")


def _all_pole(a: Array, x: Array) -> Array:
    """`y = x / A` from rest, `a` (na+1,) with `a[0] = 1`, `x` (T,)."""
    if a.shape[0] == 1:
        return x
    return run(AllPoleFilter(a), x, jnp.zeros((a.shape[0] - 1,), x.dtype))[1]


def _filter(a: Array, b: Array, u: Array) -> Array:
    """`y = sum_j B_j / A u_j` from rest: `a` (na+1,) with `a[0] = 1`, `b` (m, nb), `u` (T, m)."""
    return _all_pole(a, jnp.einsum("tmi,mi->t", _lags(u, b.shape[1]), b))


class EMPSErrorModel(eqx.Module):
    """A BGBM (emps-ensemble §3.2): the grey-box plant's free run `y1` plus a linear output-error model of its
    error, `y2 = y1 + sum_j B_j / A u_j` (see the module docstring). Built by `fit_emps_bgbm`.

    - `plant`: the grey-box `EMPSPlant` (its free run by the official protocol, `predict_emps_open_loop`).
    - `reflection`: `(na,)` raw reflection coefficients of `A` (`denominator` gives `A`).
    - `numerators`: `(m, nb)` coefficients of `B_j` on the normalised inputs [m of position per unit].
    - `inputs`: the input names (`ERROR_MODEL_INPUTS`); `scales`: `(m,)` their normalisers (training std).
    """

    plant: EMPSPlant
    reflection: Float[Array, " na"]
    numerators: Float[Array, "m nb"]
    scales: Float[Array, " m"]
    inputs: tuple[str, ...] = eqx.field(static=True)

    @property
    def denominator(self) -> Float[Array, " na+1"]:
        return denominator_from_reflection(self.reflection)

    def error(self, record: EMPSRecord, signals: Any = None) -> Float[Array, " T"]:
        """The modelled error `e1_hat` [m] over `record` (the filter starts from rest at the first sample)."""
        u = _signals(record, self.plant, self.inputs, signals) / self.scales
        return _filter(self.denominator, self.numerators, u)

    def predict(self, record: EMPSRecord) -> Float[Array, " T"]:
        """The BGBM position `y2 = y1 + e1_hat` [m] (samples before `INIT_WINDOW - 1` as `y1` holds them)."""
        sim = predict_emps_open_loop(self.plant, record)
        return sim.q + self.error(record, sim)

    def score(self, record: EMPSRecord) -> float:
        """The official score of `y2`: free-run position RMSE [mm] on `qm[20:]`."""
        q = self.predict(record)
        return float(emps_open_loop_rmse_mm(jnp.asarray(record.qm, q.dtype), q, skip=INIT_WINDOW))


def _signals(record: EMPSRecord, plant: EMPSPlant, inputs: Sequence[str], sim: Any = None) -> Array:
    if sim is None and any(name in ("q", "qd") for name in inputs):
        sim = predict_emps_open_loop(plant, record)
    columns = []
    for name in inputs:
        if name == "force":
            columns.append(jnp.asarray(record.force, float))
        elif name == "bias":
            columns.append(jnp.ones((record.length,), float))
        else:
            columns.append(jnp.asarray(sim.q if name == "q" else sim.qd))
    return jnp.stack(columns, axis=-1)


class EMPSBGBMFit(NamedTuple):
    """What `fit_emps_bgbm` returns.

    - `model`: the fitted `EMPSErrorModel`.
    - `train_rmse_mm`: the official score of `model` on the part it was fitted on.
    - `val_rmse_mm`: its score on the held-out part (run from that part's own initialisation window), NaN
      without one; `val_physics_mm`: the grey box's own score there.
    - `result`: how the Levenberg-Marquardt solve ended: `"successful"`, `"max_steps"` or `"failed"` (optimistix's
      other codes); `"nonfinite: returned the start"` when it produced NaN or inf.
    """

    model: EMPSErrorModel
    train_rmse_mm: float
    val_rmse_mm: float
    val_physics_mm: float
    result: str


def fit_emps_bgbm(
    record: EMPSRecord,
    plant: EMPSPlant,
    *,
    inputs: Sequence[str] = ("force",),
    order: int = 2,
    validation: float | EMPSRecord | None = 0.3,
    steps: int = 200,
    pole: float = 0.95,
) -> EMPSBGBMFit:
    """Fit the BGBM error model of a grey-box EMPS plant by output error (emps-ensemble §3.2).

    **Arguments:**

    - `record`: the training `EMPSRecord` (`DATA_EMPS.mat`); never the test file.
    - `plant`: the grey-box `EMPSPlant` (e.g. `fit_emps_open_loop(train, law).plant`); kept fixed.
    - `inputs`: the error model's inputs from `ERROR_MODEL_INPUTS` (the paper: `("force",)`).
    - `order`: `na`, the denominator order (`nb = order + 1` numerator taps per input).
    - `validation`: a fraction in (0, 1) held out at the end of `record` (default 0.3), another `EMPSRecord`,
      or `None` (fit on the whole record).
    - `steps`: Levenberg-Marquardt's maximum steps. `pole`: the start denominator `(1 - pole q^-1)^order`.

    **Returns:** an `EMPSBGBMFit(model, train_rmse_mm, val_rmse_mm, val_physics_mm, result)`.

    ```python
    >>> import fricjax as fj
    >>> train = fj.load_emps(fj.data_folder("emps") / "DATA_EMPS.mat")  # doctest: +SKIP
    >>> grey = fj.emps.fit_emps_open_loop(train, fj.Tustin, asymmetric=True).plant  # doctest: +SKIP
    >>> bgbm = fj.emps.fit_emps_bgbm(train, grey, inputs=("force",), order=2)  # doctest: +SKIP
    >>> bgbm.model.score(fj.load_emps(fj.data_folder("emps") / "DATA_EMPS_PULSES.mat"))  # doctest: +SKIP
    ```
    """
    _check_record(record, "record", INIT_WINDOW)
    _check_plant(plant)
    inputs = tuple(inputs)
    if not inputs or any(name not in ERROR_MODEL_INPUTS for name in inputs) or len(set(inputs)) != len(inputs):
        raise ValueError(f"`inputs` must be distinct names from {ERROR_MODEL_INPUTS}, got {inputs!r}.")
    order = nonnegative_int(order, "order", "fit_emps_bgbm")
    steps = positive_int(steps, "steps", "fit_emps_bgbm")
    pole = fraction(pole, "pole", "fit_emps_bgbm", hint="(the start pole, e.g. 0.95)")
    train, val = _split(record, validation, INIT_WINDOW)

    sim = predict_emps_open_loop(plant, train)
    u = _signals(train, plant, inputs, sim)
    std = jnp.std(u, axis=0)
    scales = jnp.where(std > 0, std, 1.0)  # the bias (std 0) keeps scale 1
    un = u / scales
    target = jnp.asarray(train.qm, un.dtype) - sim.q
    scored = slice(INIT_WINDOW, None)

    # start: A = (1 - pole q^-1)^order through its reflection coefficients, B by least squares (linear in B)
    start_a = np.poly(np.full(order, pole))
    reflection0 = jnp.asarray(_reflection_from_denominator(start_a), un.dtype)
    nb = order + 1
    filtered = jax.vmap(_all_pole, in_axes=(None, 1), out_axes=1)(jnp.asarray(start_a, un.dtype), un)
    basis = _lags(filtered, nb).reshape(un.shape[0], len(inputs) * nb)  # B/A u is linear in B
    b0, *_ = jnp.linalg.lstsq(basis[scored], target[scored])
    params0 = (reflection0, b0.reshape(len(inputs), nb))

    def residuals(params: tuple[Array, Array], _: Any) -> Array:
        reflection, b = params
        return 1000.0 * (_filter(denominator_from_reflection(reflection), b, un) - target)[scored]  # mm

    solution = least_squares(residuals, params0, solver=optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10), steps=steps)
    reflection, b = solution.model  # the start where the solve met only non-finite values
    model = EMPSErrorModel(plant=plant, reflection=reflection, numerators=b, scales=scales, inputs=inputs)
    result = {"solver_failed": "failed", "diverged": "nonfinite: returned the start"}.get(solution.code, solution.code)
    train_q = sim.q + model.error(train, sim)  # the grey box's free run of the head, simulated once
    nan = float("nan")
    return EMPSBGBMFit(
        model=model,
        train_rmse_mm=float(emps_open_loop_rmse_mm(jnp.asarray(train.qm, train_q.dtype), train_q, skip=INIT_WINDOW)),
        val_rmse_mm=nan if val is None else model.score(val),
        val_physics_mm=nan if val is None else score_emps_open_loop(plant, val),
        result=result,
    )


def _reflection_from_denominator(a: np.ndarray) -> np.ndarray:
    """Raw reflection coefficients (`atanh k_i`) of a stable monic `A` (Levinson step-down)."""
    a = np.asarray(a, float)
    ks = []
    while a.size > 1:
        k = a[-1]
        if abs(k) >= 1:
            raise ValueError("the start denominator is not stable")
        ks.append(k)
        a = (a - k * a[::-1])[:-1] / (1.0 - k * k)
    return np.arctanh(np.asarray(ks[::-1]))
