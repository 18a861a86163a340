"""Recursive least squares with a forgetting factor, U-D factorised (Bierman), as a model `fj.simulate` runs.

amthor §III-C: the linear parameters of an (extended) DNLRX friction model were adapted online by recursive least
squares; the plain covariance update "tends to become unstable during runtime" and the U-D factorised form
(Bierman 1977, *Factorization Methods for Discrete Sequential Estimation*, §V.3; Thornton & Bierman 1978) was
stable. With the covariance `P = U D U^T` (U unit upper triangular, D diagonal > 0), each sample's update keeps
D positive by construction, where the plain update `P - K phi^T P` loses positive-definiteness to round-off
when P is ill-conditioned (long forgetting of directions the data do not excite).

For a regression `y_k = phi_k^T theta + e_k` with forgetting factor `lambda` in (0, 1]:

    K_k = P phi_k / (lambda + phi_k^T P phi_k),  theta_k = theta_{k-1} + K_k (y_k - phi_k^T theta_{k-1}),
    P_k = (P - K_k phi_k^T P) / lambda,

which with `lambda = 1` and `P_0 = p0 I`, `theta_0` gives the batch regularised least-squares solution
`argmin sum_k (y_k - phi_k^T theta)^2 + |theta - theta_0|^2 / p0` after every sample.

The estimator is a system (a regression record in, estimates out) rather than part of `_estimation`: the U-D
update also runs inside other systems' steps (the adaptive compensator of `fj.PositioningStage`), and systems sit
below estimation in the layering.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._constraints import Fixed, FixedScalar, as_float_array, unwrap
from .._models._base import AbstractModel
from .._smoothing import is_concrete


class RegressionData(eqx.Module):
    """A regression record for recursive estimation: `regressors` `(T, P)` (one row `phi_k` per sample) and
    `target` `(T,)` (the measured output `y_k`, e.g. a force [N])."""

    regressors: Float[Array, "T P"]
    target: Float[Array, " T"]

    def __init__(self, regressors: Any, target: Any):
        phi, y = as_float_array(regressors), as_float_array(target)
        if phi.ndim != 2 or y.shape != phi.shape[:1]:
            raise ValueError(
                f"RegressionData: `regressors` must be (T, P) and `target` (T,), got {phi.shape} and {y.shape}."
            )
        if is_concrete((phi, y)) and not (np.all(np.isfinite(np.asarray(phi))) and np.all(np.isfinite(np.asarray(y)))):
            raise ValueError("RegressionData: `regressors` and `target` must be finite (drop or fill the bad samples).")
        self.regressors, self.target = phi, y

    @property
    def length(self) -> int:
        return int(self.target.shape[0])


class RLSState(eqx.Module):
    """The estimator's state: `theta` (P,), and the covariance as `U` (P, P; unit upper triangular) and `d`
    (P,; > 0) with `P = U diag(d) U^T` (the U-D form), or `U` the full covariance and `d` unused (plain form)."""

    theta: Float[Array, " P"]
    U: Float[Array, "P P"]
    d: Float[Array, " P"]


class RecursiveLeastSquares(AbstractModel):
    """Recursive least squares with exponential forgetting, as a model: `fj.simulate(rls, fj.RegressionData(Phi,
    y))` runs the estimator over the record in one scan and returns, per sample, the a-priori prediction
    `phi_k^T theta_{k-1}` and the estimate `theta_k` (a dict `{"prediction": (T,), "theta": (T, P)}`).

    **Arguments:**

    - `theta0`: the initial estimate, shape `(P,)`.
    - `p0`: the initial covariance, a positive scalar (`p0 I`) or a positive vector (its diagonal).
    - `forgetting`: the forgetting factor `lambda` in (0, 1] (1: no forgetting; 0.999 at 1 kHz forgets with a
      time constant of about 1 s).
    - `method`: `"ud"` (default: Bierman's U-D factorised update, amthor §III-C) or `"plain"` (the covariance
      update `P - K phi^T P`, kept for comparison: it can lose positive-definiteness).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> rng = np.random.default_rng(0)
    >>> Phi = rng.standard_normal((200, 2))
    >>> out = fj.simulate(fj.RecursiveLeastSquares(np.zeros(2), 1e6), fj.RegressionData(Phi, Phi @ [2.0, -1.0]))
    >>> np.round(np.asarray(out["theta"][-1]), 6).tolist()
    [2.0, -1.0]
    ```
    """

    theta0: Fixed[Float[Array, " P"]]
    p0: Fixed[Float[Array, " P"]]
    forgetting: FixedScalar
    method: str = eqx.field(static=True)

    requires: ClassVar[frozenset[str]] = frozenset({"regressors", "target"})

    def __init__(self, theta0: Any, p0: Any = 1e4, forgetting: Any = 1.0, *, method: Literal["ud", "plain"] = "ud"):
        theta0 = as_float_array(theta0)
        if theta0.ndim != 1 or theta0.shape[0] < 1:
            raise ValueError(f"RecursiveLeastSquares: `theta0` must be a vector (P,), got shape {theta0.shape}.")
        size = theta0.shape[0]
        p0 = jnp.broadcast_to(as_float_array(p0), (size,)) if np.ndim(p0) == 0 else as_float_array(p0)
        if p0.shape != (size,):
            raise ValueError(f"RecursiveLeastSquares: `p0` must be a scalar or ({size},), got shape {p0.shape}.")
        forgetting = as_float_array(forgetting)
        if is_concrete((p0, forgetting)):
            if not np.all(np.asarray(p0) > 0):
                raise ValueError("RecursiveLeastSquares: `p0` (the initial covariance) must be positive, e.g. 1e4.")
            if not (forgetting.ndim == 0 and 0 < float(forgetting) <= 1):
                raise ValueError(
                    f"RecursiveLeastSquares: `forgetting` must be a scalar in (0, 1], got {forgetting!r}; "
                    "1 means no forgetting, 0.999 a memory of about 1000 samples."
                )
        if method not in ("ud", "plain"):
            raise ValueError(f"RecursiveLeastSquares: `method` must be 'ud' or 'plain', got {method!r}.")
        self.theta0 = Fixed(theta0)
        self.p0 = Fixed(p0)
        self.forgetting = Fixed(forgetting)
        self.method = method

    @property
    def size(self) -> int:
        """The number P of parameters."""
        return int(unwrap(self.theta0).shape[0])

    def init_state(self) -> RLSState:
        p = unwrap(self)
        if self.method == "ud":
            return RLSState(p.theta0, jnp.eye(self.size, dtype=p.p0.dtype), p.p0)
        return RLSState(p.theta0, jnp.diag(p.p0), jnp.zeros_like(p.p0))

    def samples(self, inputs: RegressionData) -> dict[str, Array]:
        return {"regressors": inputs.regressors, "target": inputs.target}

    def check_inputs(self, inputs: Any) -> None:
        if not isinstance(inputs, RegressionData):
            raise TypeError(
                f"simulate: RecursiveLeastSquares takes an fj.RegressionData(regressors, target), got "
                f"{type(inputs).__name__}."
            )
        if inputs.regressors.shape[1] != self.size:
            raise ValueError(
                f"simulate: the regressors have {inputs.regressors.shape[1]} columns, the estimator {self.size} "
                "parameters (theta0)."
            )

    def step(self, state: RLSState, sample: dict[str, Array]) -> tuple[RLSState, dict[str, Array]]:
        p = unwrap(self)
        phi, y = sample["regressors"], sample["target"]
        prediction = jnp.dot(phi, state.theta)
        if self.method == "ud":
            gain, U, d = ud_update(state.U, state.d, phi, p.forgetting)
        else:
            gain, U = _plain_update(state.U, phi, p.forgetting)
            d = state.d
        theta = state.theta + gain * (y - prediction)
        return RLSState(theta, U, d), {"prediction": prediction, "theta": theta}

    @staticmethod
    def covariance(state: RLSState, method: str = "ud") -> Array:
        """The covariance `P` held by a state (`U diag(d) U^T` in the U-D form)."""
        if method == "plain":
            return state.U
        return (state.U * state.d) @ state.U.T


def ud_update(U: Array, d: Array, phi: Array, forgetting: Array) -> tuple[Array, Array, Array]:
    """Bierman's U-D measurement update with forgetting: `(gain K, U', d')` for `P = U diag(d) U^T`, the
    regressor `phi` and the forgetting factor `lambda` (the measurement variance of the Kalman form).

    With `f = U^T phi`, `v = d * f`: `alpha_0 = lambda`, and for j = 0..P-1: `alpha_j = alpha_{j-1} + v_j f_j`,
    `d_j' = d_j alpha_{j-1} / (alpha_j lambda)`, `U_ij' = U_ij - (f_j / alpha_{j-1}) b_i` and `b_i += U_ij v_j`
    (i < j, b = v on entry), `K = b / alpha_{P-1}`. Each `d_j'` is a ratio of positive numbers: positive."""
    size = d.shape[0]
    f = U.T @ phi
    v = d * f
    index = jnp.arange(size)

    def column(j: Array, carry: tuple[Array, Array, Array, Array]) -> tuple[Array, Array, Array, Array]:
        U, d_new, b, alpha = carry
        f_j, v_j = f[j], v[j]
        alpha_j = alpha + v_j * f_j
        d_new = d_new.at[j].set(d[j] * alpha / (alpha_j * forgetting))
        above = index < j
        u_j = U[:, j]
        U = U.at[:, j].set(jnp.where(above, u_j - (f_j / alpha) * b, u_j))
        b = jnp.where(above, b + u_j * v_j, b)
        return U, d_new, b, alpha_j

    U, d_new, b, alpha = jax.lax.fori_loop(0, size, column, (U, d, v, jnp.asarray(forgetting, d.dtype)))
    return b / alpha, U, d_new


def _plain_update(P: Array, phi: Array, forgetting: Array) -> tuple[Array, Array]:
    """The covariance-form update: `K = P phi / (lambda + phi^T P phi)`, `P' = (P - K phi^T P) / lambda`."""
    Pphi = P @ phi
    gain = Pphi / (forgetting + jnp.dot(phi, Pphi))
    return gain, (P - jnp.outer(gain, Pphi)) / forgetting
