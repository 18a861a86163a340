"""Stribeck curves s(v) [N]: the steady sliding friction magnitude as a function of velocity.

Every coefficient may be a scalar (symmetric curve) or a pair `(positive, negative)` (asymmetric dynamic friction,
as the static curves of `_static.py`): the curve is then made of two branches, `s+(v)` with the first values and
`s-(v)` with the second ones, each even in v, and `s(v) = H(v) s+(v) + (1 - H(v)) s-(v)` with `H` the step of the
direction of motion (exact: 1 for v > 0, else 0; a model passes its smooth step in smooth mode).
"""

from __future__ import annotations

import abc
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from ..._constraints import Fixed, ParamLike, SidedParameter, model_dtype, positive, unwrap


def abs_pow(u: ArrayLike, p: ArrayLike) -> Array:
    """|u|**p with finite value and gradient (also w.r.t. p) at u = 0, capped at exp(50) ~ 5e21.

    The cap keeps `exp(-|u|**p)` and `1 / (1 + |u|**p)` (already 0 to double precision there) free of
    inf * 0 = NaN in their gradients when an optimiser tries a large exponent.
    """
    au = jnp.abs(u)
    nonzero = au > 0
    log_power = jnp.asarray(p) * jnp.log(jnp.where(nonzero, au, 1.0))
    return jnp.where(nonzero, jnp.exp(jnp.minimum(log_power, 50.0)), 0.0)


def sided_positive(value: ParamLike, name: str, dtype: Any = None) -> Any:
    """A positive coefficient that is one number (symmetric) or a pair (value for v > 0, value for v < 0)."""
    raw = value.value if isinstance(value, Fixed) else value
    shape = tuple(np.shape(raw))  # no conversion yet: `positive` refuses strings by name
    if shape not in ((), (2,)):
        raise ValueError(
            f"`{name}` must be a scalar (symmetric curve) or a pair (value for v > 0, value for v < 0), "
            f"got shape {shape}."
        )
    return positive(value, name, dtype)


def side(c: Array, i: int) -> Array:
    """Coefficient `c` for side `i` (0: v > 0, 1: v < 0): a scalar applies to both."""
    return c if jnp.ndim(c) == 0 else c[i]


class AbstractStribeck(eqx.Module):
    """A Stribeck curve: `s(v) > 0`, the friction magnitude in steady sliding at velocity `v`; even in v for
    scalar coefficients, two even branches `s+` (v > 0) and `s-` (v < 0) when a coefficient is a (+, -) pair."""

    Fc: SidedParameter
    Fs: SidedParameter
    vs: SidedParameter

    @abc.abstractmethod
    def _coefficients(self) -> tuple[Array, ...]:
        """The unwrapped coefficients, in the order `_curve` takes them."""

    @abc.abstractmethod
    def _curve(self, v: Array, *coefficients: Array) -> Array:
        """One even branch of the curve for scalar coefficients."""

    @property
    def asymmetric(self) -> bool:
        """True when any coefficient is a (+, -) pair (decided by structure, never by values)."""
        return any(jnp.ndim(c) == 1 for c in unwrap(self)._coefficients())

    def branches(self, v: ParamLike) -> tuple[Array, Array]:
        """The two branches `(s+(v), s-(v))` [N], each even in `v` (equal for a symmetric curve)."""
        coefficients = unwrap(self)._coefficients()
        v = jnp.asarray(v)
        return self._curve(v, *(side(c, 0) for c in coefficients)), self._curve(v, *(side(c, 1) for c in coefficients))

    def __call__(self, v: ParamLike, up: ArrayLike | None = None) -> Array:
        """s(v) in N, same shape as `v`. `up` in [0, 1] weights the positive branch for an asymmetric curve
        (default: the exact step, 1 for v > 0); a symmetric curve ignores it."""
        coefficients = unwrap(self)._coefficients()
        v = jnp.asarray(v)
        if not any(jnp.ndim(c) == 1 for c in coefficients):
            return self._curve(v, *coefficients)
        plus, minus = self.branches(v)
        weight = jnp.where(v > 0, 1.0, 0.0).astype(plus.dtype) if up is None else jnp.asarray(up)
        return weight * plus + (1.0 - weight) * minus


class ExponentialStribeck(AbstractStribeck):
    """Exponential Stribeck curve with shape exponent (Bo–Pavelescu; worden2007 eq. 5 for delta = 1).

    `s(v) = Fc + (Fs - Fc) * exp(-|v / vs| ** delta)`

    **Arguments:** `Fc` Coulomb force [N] (> 0); `Fs` static (breakaway) force [N] (> 0); `vs` Stribeck velocity
    [m/s] (> 0, typically 1e-4 to 1e-1); `delta` shape exponent (> 0; 1 Tustin, 2 Gaussian). Each a scalar or a
    (+, -) pair (asymmetric dynamic friction: the branch for v > 0, then for v < 0; emps-ensemble eqs. 5-7 for the
    static laws).

    ```python
    >>> import fricjax as fj
    >>> float(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3)(0.0))
    1.5
    >>> float(fj.ExponentialStribeck(Fc=(1.0, 0.8), Fs=(1.5, 1.2), vs=1e-3)(-1.0))  # the negative branch
    0.8
    ```
    """

    delta: SidedParameter

    def __init__(self, Fc: ParamLike, Fs: ParamLike, vs: ParamLike, delta: ParamLike = 1.0):
        dtype = model_dtype(Fc, Fs, vs, delta)
        self.Fc = sided_positive(Fc, "Fc", dtype)
        self.Fs = sided_positive(Fs, "Fs", dtype)
        self.vs = sided_positive(vs, "vs", dtype)
        self.delta = sided_positive(delta, "delta", dtype)

    def _coefficients(self) -> tuple[Array, ...]:
        return self.Fc, self.Fs, self.vs, self.delta

    def _curve(self, v: Array, *coefficients: Array) -> Array:
        Fc, Fs, vs, delta = coefficients
        return Fc + (Fs - Fc) * jnp.exp(-abs_pow(v / vs, delta))


class RationalStribeck(AbstractStribeck):
    """Rational Stribeck curve with exponent mu (worden2007 §4.2, eq. 10, written in force units).

    `s(v) = Fc + (Fs - Fc) / (1 + |v / vs| ** mu)`; worden2007's `a1 = Fc / sigma0`, `a2 = (Fs - Fc) / sigma0`.

    **Arguments:** `Fc` [N] (> 0); `Fs` [N] (> 0); `vs` [m/s] (> 0); `mu` exponent (> 0); each a scalar or a
    (+, -) pair (asymmetric branches, as for `ExponentialStribeck`).
    """

    mu: SidedParameter

    def __init__(self, Fc: ParamLike, Fs: ParamLike, vs: ParamLike, mu: ParamLike = 2.0):
        dtype = model_dtype(Fc, Fs, vs, mu)
        self.Fc = sided_positive(Fc, "Fc", dtype)
        self.Fs = sided_positive(Fs, "Fs", dtype)
        self.vs = sided_positive(vs, "vs", dtype)
        self.mu = sided_positive(mu, "mu", dtype)

    def _coefficients(self) -> tuple[Array, ...]:
        return self.Fc, self.Fs, self.vs, self.mu

    def _curve(self, v: Array, *coefficients: Array) -> Array:
        Fc, Fs, vs, mu = coefficients
        return Fc + (Fs - Fc) / (1.0 + abs_pow(v / vs, mu))


def checked_stribeck(stribeck: Any, owner: str) -> AbstractStribeck:
    """`stribeck`, or a TypeError naming `owner` (the model being built) when it is not a Stribeck curve."""
    if not isinstance(stribeck, AbstractStribeck):
        raise TypeError(
            f"{owner}: `stribeck` must be a Stribeck curve (fj.ExponentialStribeck / fj.RationalStribeck), "
            f"got {type(stribeck).__name__}."
        )
    return stribeck
