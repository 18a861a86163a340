"""Stribeck curves s(v) [N]: the steady sliding friction magnitude as a function of velocity."""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from ..._constraints import Parameter, ParamLike, model_dtype, positive, unwrap


def abs_pow(u: ArrayLike, p: ArrayLike) -> Array:
    """|u|**p with finite value and gradient (also w.r.t. p) at u = 0, capped at exp(50) ~ 5e21.

    The cap keeps `exp(-|u|**p)` and `1 / (1 + |u|**p)` (already 0 to double precision there) free of
    inf * 0 = NaN in their gradients when an optimiser tries a large exponent.
    """
    au = jnp.abs(u)
    nonzero = au > 0
    log_power = jnp.asarray(p) * jnp.log(jnp.where(nonzero, au, 1.0))
    return jnp.where(nonzero, jnp.exp(jnp.minimum(log_power, 50.0)), 0.0)


class AbstractStribeck(eqx.Module):
    """A Stribeck curve: `s(v) > 0`, the friction magnitude in steady sliding at velocity `v` (even in v)."""

    Fc: Parameter
    Fs: Parameter
    vs: Parameter

    @abc.abstractmethod
    def __call__(self, v: ParamLike) -> Array:
        """s(v) in N, same shape as `v`."""


class ExponentialStribeck(AbstractStribeck):
    """Exponential Stribeck curve with shape exponent (Bo–Pavelescu; worden2007 eq. 5 for delta = 1).

    `s(v) = Fc + (Fs - Fc) * exp(-|v / vs| ** delta)`

    **Arguments:** `Fc` Coulomb force [N] (> 0); `Fs` static (breakaway) force [N] (> 0); `vs` Stribeck velocity
    [m/s] (> 0, typically 1e-4 to 1e-1); `delta` shape exponent (> 0; 1 Tustin, 2 Gaussian).

    ```python
    >>> import fricjax as fj
    >>> float(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3)(0.0))
    1.5
    ```
    """

    delta: Parameter

    def __init__(self, Fc: ParamLike, Fs: ParamLike, vs: ParamLike, delta: ParamLike = 1.0):
        dtype = model_dtype(Fc, Fs, vs, delta)
        self.Fc = positive(Fc, "Fc", dtype)
        self.Fs = positive(Fs, "Fs", dtype)
        self.vs = positive(vs, "vs", dtype)
        self.delta = positive(delta, "delta", dtype)

    def __call__(self, v: ParamLike) -> Array:
        p = unwrap(self)
        return p.Fc + (p.Fs - p.Fc) * jnp.exp(-abs_pow(v / p.vs, p.delta))


class RationalStribeck(AbstractStribeck):
    """Rational Stribeck curve with exponent mu (worden2007 §4.2, eq. 10, written in force units).

    `s(v) = Fc + (Fs - Fc) / (1 + |v / vs| ** mu)`; worden2007's `a1 = Fc / sigma0`, `a2 = (Fs - Fc) / sigma0`.

    **Arguments:** `Fc` [N] (> 0); `Fs` [N] (> 0); `vs` [m/s] (> 0); `mu` exponent (> 0).
    """

    mu: Parameter

    def __init__(self, Fc: ParamLike, Fs: ParamLike, vs: ParamLike, mu: ParamLike = 2.0):
        dtype = model_dtype(Fc, Fs, vs, mu)
        self.Fc = positive(Fc, "Fc", dtype)
        self.Fs = positive(Fs, "Fs", dtype)
        self.vs = positive(vs, "vs", dtype)
        self.mu = positive(mu, "mu", dtype)

    def __call__(self, v: ParamLike) -> Array:
        p = unwrap(self)
        return p.Fc + (p.Fs - p.Fc) / (1.0 + abs_pow(v / p.vs, p.mu))
