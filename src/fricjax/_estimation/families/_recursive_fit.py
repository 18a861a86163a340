"""Recursive (online) estimation of the linear parameters of any friction model: `recursive_fit`.

The parameters that enter the simulated force linearly (the force map of Maxwell-slip LR / DNLRX models,
offsets, FIR coefficients, the coefficients of a polynomial NARX or the output layer of a network) give the
regression `F_k = f_k(0) + J_k theta`, with `J` the Jacobian of the simulated force (exact, from one forward-mode
pass, as `fj.solve_linear`). `recursive_fit` runs the U-D factorised recursive least squares
(`fj.RecursiveLeastSquares`, amthor §III-C) along it, sample by sample, with a forgetting factor: the parameters
then follow a system whose friction changes over time (amthor: the stage's friction varies with position, dust,
temperature). With forgetting 1 the final estimate is the batch least-squares one.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._data._record import FrictionData
from ..._simulate import simulate
from ..._systems._recursive import RecursiveLeastSquares, RegressionData
from ..loop._solution import Solution
from ..problem._problem import _where


class RecursiveFitTrace(eqx.Module):
    """What `recursive_fit` returns besides the model, as its `fj.Solution`'s typed `aux` (the fields read
    through: `solution.theta` is `solution.aux.theta`; the solution's `model` holds the final estimate): `theta`
    `(T, P)`, the estimate after every sample (flattened in tree order of the selected fields);
    `prediction` `(T,)` [N], the a-priori one-step prediction of the force (with the estimate before the sample);
    `regression`, the `fj.RegressionData`."""

    theta: np.ndarray
    prediction: np.ndarray
    regression: RegressionData


def recursive_fit(
    model: Any,
    data: FrictionData,
    linear: str | Sequence[str],
    *,
    forgetting: float = 1.0,
    p0: float = 1e4,
    method: str = "ud",
    one_step: bool = False,
) -> Solution:
    """Estimate the parameters of `model` selected by `linear` (dotted paths, e.g. `"force_map.theta"`, or
    `where` callables; they must enter the force linearly) online along `data`, by recursive least squares.

    **Arguments:** `model` any friction model; `data` an `fj.FrictionData`; `linear` the fields; `forgetting` in
    (0, 1]; `p0` the initial covariance (scalar, in squared parameter units: large means a weak prior at the
    model's current values); `method` `"ud"` (U-D factorised, default) or `"plain"`; `one_step`: regress the
    one-step-ahead prediction (teacher forcing: the measured force fed back) instead of the free run, as for the
    coefficients of a polynomial NARX with past forces, which are linear only under teacher forcing.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 20, 500)), dt=1e-3)
    >>> truth = fj.MaxwellSlip.dnlrx(thresholds=[1e-4, 5e-4], theta=[[0.4, 0.7]], c=[0.0])
    >>> data = fj.FrictionData(motion, fj.simulate(truth, motion))
    >>> start = fj.MaxwellSlip.dnlrx(thresholds=[1e-4, 5e-4], theta=[[0.0, 0.0]], c=[0.0])
    >>> result = fj.recursive_fit(start, data, "force_map.theta", p0=1e8)
    >>> np.asarray(result.model.force_map.theta, dtype=float).round(6).tolist()
    [[0.4, 0.7]]
    ```
    """
    if not isinstance(data, FrictionData):
        raise TypeError(f"recursive_fit: `data` must be an fj.FrictionData, got {type(data).__name__}.")
    spec = jax.tree_util.tree_map(lambda _: False, model)
    selected = _where(linear, model, "linear")
    if not selected:
        raise ValueError("recursive_fit: name the linear fields, e.g. linear='force_map.theta'.")
    for _, where in selected:
        spec = eqx.tree_at(where, spec, replace_fn=lambda sub: jax.tree_util.tree_map(lambda _: True, sub))
    parameters, rest = eqx.partition(model, spec)
    flat, unravel = jax.flatten_util.ravel_pytree(parameters)

    def force(theta: jax.Array) -> jax.Array:
        measured = data.force if one_step else None
        return simulate(eqx.combine(unravel(theta), rest), data.motion, measured=measured)

    zero = jnp.zeros_like(flat)
    f0 = force(zero)
    J = jax.jacfwd(force)(zero)
    probe = jnp.asarray(np.random.default_rng(1).normal(size=flat.shape), flat.dtype) * (jnp.abs(flat) + 1.0)
    curvature = float(jnp.max(jnp.abs(force(2 * probe) - 2 * force(probe) + f0)))
    scale = float(jnp.max(jnp.abs(force(2 * probe)))) + float(jnp.max(jnp.abs(f0))) + 1e-300
    if not (np.isfinite(curvature) and curvature <= 1e-6 * scale):  # a diverging free run is not linear
        raise ValueError(
            f"recursive_fit: the fields {[label for label, _ in selected]} do not enter the force linearly for "
            f"{type(model).__name__}; name only force-map weights, offsets, FIR or output coefficients (for a NARX "
            "with past forces, pass one_step=True)."
        )
    regression = RegressionData(J, jnp.asarray(data.force) - f0)
    estimator = RecursiveLeastSquares(flat, p0, forgetting, method=method)  # type: ignore[arg-type]
    out = simulate(estimator, regression)
    theta = out["theta"]
    fitted = eqx.combine(unravel(theta[-1]), rest)
    return Solution(
        model=fitted,
        message=f"recursive least squares ({method}) over {data.length} samples; the model holds the final estimate",
        aux=RecursiveFitTrace(
            theta=np.asarray(theta),
            prediction=np.asarray(out["prediction"] + f0),
            regression=regression,
        ),
    )
