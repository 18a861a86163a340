"""Neural NARX models: a static network of the NARX regressors (worden2007 §5-6): `AbstractNARX`, `MLPNARX`,
`GSNN`, and `AVDNetwork` (no fed-back outputs, Chen and Tomlinson 1996 in the kernel-method paper §4.2).

Each is smooth (tanh, sigmoid, exp): its exact and smooth modes coincide, and `fj.exact(model)` is the model.
Train one-step-ahead (`fj.OneStepLoss()`, teacher forcing) first, then by output error (`fj.SimulationLoss()`,
the gradient through the whole free run: the papers' NOE with an untruncated Jacobian), both by `fj.fit`.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any, ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import Fixed, Positive, as_float_array, unwrap
from ..._inputs import MotionSample
from ..._validation import positive_int
from .._base import AbstractFrictionModel
from ._regressors import NARXRegressors, NARXState, fixed_array


class AbstractNARX(AbstractFrictionModel):
    """A NARX friction model `y_k = regressors.denormalise(network(phi_k))`; state: the regressor history
    (`NARXState`). Subclasses give `regressors` and `network(phi) -> normalised force`."""

    regressors: eqx.AbstractVar[NARXRegressors]
    unit_mask: eqx.AbstractVar[Fixed[Float[Array, " units"]]]  # 0/1 per unit (hidden unit, term, centre)

    units: ClassVar[dict[str, str] | None] = {}  # network weights and coefficients: no units

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return self.regressors.requires

    @abc.abstractmethod
    def network(self, phi: Float[Array, " P"]) -> Array:
        """The normalised force for the regressor vector `phi` (parameters unwrapped)."""

    def init_state(self) -> NARXState:
        return self.regressors.init_state(jnp.result_type(unwrap(self.regressors).output_scale))

    def step(self, state: NARXState, sample: MotionSample) -> tuple[NARXState, Array]:
        p = unwrap(self)
        phi, partial = p.regressors(state, sample)
        y = p.regressors.denormalise(p.network(phi))
        return p.regressors.advance(partial, y), y

    def feedback(self, state: NARXState, y_measured: Array) -> NARXState:
        return self.regressors.feedback(state, y_measured)


def unit_mask_field(value: Any, units: int, owner: str, per: str = "unit") -> Fixed:
    """The fixed 0/1 mask of a model's units or terms (default ones): sweeps over sizes switch them off with it."""
    mask = np.ones(units) if value is None else (value.value if isinstance(value, Fixed) else value)
    if np.shape(mask) != (units,):
        raise ValueError(f"{owner}: `unit_mask` must have shape ({units},), one entry per {per}; got {np.shape(mask)}.")
    return fixed_array(mask, (units,), "unit_mask", owner)


def _linear_part(theta: Any, regressors: NARXRegressors, name: str) -> Array | None:
    if theta is None:
        return None
    array = as_float_array(theta)
    if array.shape != (regressors.size,):
        raise ValueError(f"{name}: `theta` (the linear part) must have shape ({regressors.size},), got {array.shape}.")
    return array


def _linear(theta: Array | None, phi: Array) -> Array | float:
    return 0.0 if theta is None else jnp.dot(theta, phi)


def _normal(key: Array, shape: tuple[int, ...], std: float) -> Array:
    return std * jax.random.normal(key, shape, dtype=jnp.result_type(float))


class MLPNARX(AbstractNARX):
    """A multi-layer perceptron NARX (worden2007 §5, parlitz2004 §IV-C): one hidden layer of tanh units and a
    linear output,

    `y_k = d . (mask * tanh(W phi_k + b)) + d0` (normalised), `phi_k` the NARX regressors
    (`fj.NARXRegressors`: displacement, velocity, acceleration, their lags and lagged outputs).

    **Arguments:** `regressors` (`fj.NARXRegressors`); `W` `(width, P)`, `b` `(width,)`, `d` `(width,)`, `d0`
    (weights in normalised units); `unit_mask` 0/1 per hidden unit (default ones; for sweeps over widths);
    `theta` `(P,)` or None: an optional linear part `+ theta . phi_k` (as MATLAB's nonlinear ARX networks).
    Build from random weights with `MLPNARX.init(regressors, width, key)`. The output layer `(d, d0, theta)`
    is linear: `fj.fit(..., separable=("d", "d0", "theta"))` solves it by least squares.

    ```python
    >>> import jax, numpy as np, fricjax as fj
    >>> model = fj.MLPNARX.init(fj.NARXRegressors(("x", "v"), 0, 2), width=8, key=jax.random.PRNGKey(0))
    >>> fj.simulate(model, fj.Motion.from_position(np.linspace(0, 1e-3, 50), dt=1e-3)).shape
    (50,)
    ```
    """

    regressors: NARXRegressors
    W: Array
    b: Array
    d: Array
    d0: Array
    unit_mask: Fixed[Float[Array, " width"]]
    theta: Array | None

    def __init__(
        self,
        regressors: NARXRegressors,
        W: Any,
        b: Any,
        d: Any,
        d0: Any = 0.0,
        unit_mask: Any = None,
        theta: Any = None,
    ):
        self.regressors = regressors
        self.theta = _linear_part(theta, regressors, "MLPNARX")
        self.W, self.b, self.d = as_float_array(W), as_float_array(b), as_float_array(d)
        self.d0 = as_float_array(d0)
        width = self.b.shape[0] if self.b.ndim == 1 else -1
        if self.W.shape != (width, regressors.size) or self.d.shape != (width,) or self.d0.shape != ():
            raise ValueError(
                f"MLPNARX: shapes W {self.W.shape}, b {self.b.shape}, d {self.d.shape}, d0 {self.d0.shape} do not "
                f"match (width, {regressors.size} regressors); use MLPNARX.init(regressors, width, key)."
            )
        self.unit_mask = unit_mask_field(unit_mask, width, "MLPNARX")

    @classmethod
    def init(
        cls, regressors: NARXRegressors, width: int = 10, *, key: Array, unit_mask: Any = None, linear: bool = False
    ) -> MLPNARX:
        """Random weights: `W ~ N(0, 1/P)`, `b ~ N(0, 0.1)`, `d ~ N(0, 0.1/width)`, `d0 = 0`; `linear=True` adds
        the linear part (`theta = 0`)."""
        width = positive_int(width, "width", "MLPNARX.init")
        k1, k2, k3 = jax.random.split(key, 3)
        size = regressors.size
        return cls(
            regressors,
            _normal(k1, (width, size), 1.0 / np.sqrt(size)),
            _normal(k2, (width,), 0.1),
            _normal(k3, (width,), 0.1 / np.sqrt(width)),
            0.0,
            unit_mask,
            np.zeros(size) if linear else None,
        )

    def network(self, phi: Array) -> Array:
        hidden = jnp.tanh(self.W @ phi + self.b) * unwrap(self.unit_mask)
        return jnp.dot(self.d, hidden) + self.d0 + _linear(self.theta, phi)


def AVDNetwork(  # noqa: N802 - a model constructor, named as the model
    data: Any, width: int = 10, *, key: Array, signals: Sequence[str] = ("a", "v", "x"), unit_mask: Any = None
) -> MLPNARX:
    """The acceleration-velocity-displacement (AVD) network (Chen and Tomlinson 1996; the kernel-method paper
    §4.2): a feed-forward network of the current displacement, velocity and acceleration, no lags and no fed-back
    output (`MLPNARX` with `input_lags=0`, `output_lags=0`), normalised by the training record `data`. Give the
    motion an acceleration from the Al-Alaoui differentiator (`fj.al_alaoui_derivative`) as the paper does;
    otherwise `a` is the central difference of `v`."""
    regressors = NARXRegressors.from_data(data, signals, input_lags=0, output_lags=0)
    return MLPNARX.init(regressors, width, key=key, unit_mask=unit_mask)


_DENOMINATORS: dict[str, tuple[Any, float]] = {
    # g and its infimum: a_j = p - inf g + (a positive excess) keeps a_j + g(.) > p for every input (eq. 32)
    "logsig": (jax.nn.sigmoid, 0.0),
    "exp": (jnp.exp, 0.0),
    "tanh": (jnp.tanh, -1.0),
}


class GSNN(AbstractNARX):
    """A generalised shunting neural network NARX (worden2007 §6.1, eqs. 29-32): hidden neurons

    `x_j = (b_j + f(w_j . phi_k + w_j0)) / (a_j + g(c_j . phi_k + c_j0))`, `f = tanh`,
    `g` the logistic sigmoid (`"logsig"`, default), `exp` or `tanh`, and a linear output
    `y_k = sum_j d_j x_j + d0` (eq. 30), in normalised units, `phi_k` the NARX regressors.

    The denominator's lower bound `p` (eq. 32: `a_j + g(.) > p` for the network to stay stable) is enforced by a
    reparametrisation, not a penalty: `a_j = p - inf(g) + e_j` with `e_j > 0` stored as a positive parameter.
    worden2007's best GSNN had 3 neurons, autoregressive order 4, no input delays: `GSNN.init(regressors,
    units=3)` with `fj.NARXRegressors(("x", "v", "a"), 0, 4)`.

    **Arguments:** `regressors`; `w` `(J, P)`, `w0` `(J,)`, `c` `(J, P)`, `c0` `(J,)`, `b` `(J,)`, `a` `(J,)`
    (each `a_j > p - inf g`), `d` `(J,)`, `d0`; `denominator` (`"logsig"`, `"exp"`, `"tanh"`); `bound` `p > 0`;
    `unit_mask` (sweeps over the number of neurons); `theta` `(P,)` or None, an optional linear part
    `+ theta . phi_k` (not in worden2007). The output layer `(d, d0, theta)` is linear (separable).
    """

    regressors: NARXRegressors
    w: Array
    w0: Array
    c: Array
    c0: Array
    b: Array
    a_excess: Positive
    d: Array
    d0: Array
    unit_mask: Fixed[Float[Array, " J"]]
    theta: Array | None
    denominator: str = eqx.field(static=True)
    bound: float = eqx.field(static=True)

    def __init__(
        self,
        regressors: NARXRegressors,
        w: Any,
        w0: Any,
        c: Any,
        c0: Any,
        b: Any,
        a: Any,
        d: Any,
        d0: Any = 0.0,
        *,
        denominator: Literal["logsig", "exp", "tanh"] = "logsig",
        bound: float = 0.1,
        unit_mask: Any = None,
        theta: Any = None,
    ):
        if denominator not in _DENOMINATORS:
            raise ValueError(f"GSNN: `denominator` must be one of {sorted(_DENOMINATORS)}, got {denominator!r}.")
        self.theta = _linear_part(theta, regressors, "GSNN")
        if not np.isfinite(bound) or bound <= 0:
            raise ValueError(f"GSNN: `bound` (the denominator's lower bound p, eq. 32) must be > 0, got {bound!r}.")
        self.regressors = regressors
        self.denominator, self.bound = denominator, float(bound)
        self.w, self.w0, self.c, self.c0 = (as_float_array(t) for t in (w, w0, c, c0))
        self.b, self.d, self.d0 = as_float_array(b), as_float_array(d), as_float_array(d0)
        units = self.b.shape[0] if self.b.ndim == 1 else -1
        size = regressors.size
        shapes = {"w": self.w.shape, "c": self.c.shape, "w0": self.w0.shape, "c0": self.c0.shape, "d": self.d.shape}
        expected = {"w": (units, size), "c": (units, size), "w0": (units,), "c0": (units,), "d": (units,)}
        if shapes != expected or self.d0.shape != ():
            raise ValueError(f"GSNN: shapes {shapes} do not match {expected}; use GSNN.init(regressors, units, key).")
        excess = as_float_array(a) - (self.bound - _DENOMINATORS[denominator][1])
        if np.shape(excess) != (units,):
            raise ValueError(f"GSNN: `a` must have shape ({units},), got {np.shape(excess)}.")
        if not bool(np.all(np.asarray(excess) > 0)):
            raise ValueError(
                f"GSNN: every a_j must exceed p - inf(g) = {self.bound - _DENOMINATORS[denominator][1]} "
                f"(eq. 32, denominator {denominator!r}), got {np.asarray(a)!r}."
            )
        self.a_excess = Positive(excess, name="a")
        self.unit_mask = unit_mask_field(unit_mask, units, "GSNN")

    @classmethod
    def init(
        cls,
        regressors: NARXRegressors,
        units: int = 3,
        *,
        key: Array,
        denominator: Literal["logsig", "exp", "tanh"] = "logsig",
        bound: float = 0.1,
        unit_mask: Any = None,
        linear: bool = False,
    ) -> GSNN:
        """Random weights (`w ~ N(0, 1/P)`, `c ~ N(0, 0.1/P)`), `b = 0`, denominators near 1, output `d ~ N(0,
        0.1/J)`; `linear=True` adds the linear part (`theta = 0`)."""
        units = positive_int(units, "units", "GSNN.init")
        if denominator not in _DENOMINATORS:
            raise ValueError(f"GSNN: `denominator` must be one of {sorted(_DENOMINATORS)}, got {denominator!r}.")
        size = regressors.size
        keys = jax.random.split(key, 5)
        g, g_min = _DENOMINATORS[denominator]
        a = bound - g_min + np.maximum(1.0 - float(g(0.0)) - bound + g_min, 0.1) * np.ones(units)
        return cls(
            regressors,
            _normal(keys[0], (units, size), 1.0 / np.sqrt(size)),
            _normal(keys[1], (units,), 0.1),
            _normal(keys[2], (units, size), 0.1 / np.sqrt(size)),
            jnp.zeros(units),
            jnp.zeros(units),
            a,
            _normal(keys[3], (units,), 0.1 / np.sqrt(units)),
            0.0,
            denominator=denominator,
            bound=bound,
            unit_mask=unit_mask,
            theta=np.zeros(size) if linear else None,
        )

    @property
    def a(self) -> Array:
        """The passive decay rates `a_j` (each `> p - inf g`)."""
        return self.bound - _DENOMINATORS[self.denominator][1] + unwrap(self.a_excess)

    def network(self, phi: Array) -> Array:
        g, _ = _DENOMINATORS[self.denominator]
        numerator = self.b + jnp.tanh(self.w @ phi + self.w0)
        denominator = self.a + g(self.c @ phi + self.c0)
        return jnp.dot(self.d, numerator / denominator * unwrap(self.unit_mask)) + self.d0 + _linear(self.theta, phi)
