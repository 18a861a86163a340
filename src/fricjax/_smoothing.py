"""Exact and smooth sign / abs / clip / step functions, and safe division.

Every model with stick/slip or sign switching holds a *smoothing strategy* as a field: `Exact()` gives the
literature's non-smooth equations (for evaluation), `Smooth(eps)` a differentiable approximation with an
explicit width `eps` (for training) that converges to the exact one as `eps -> 0`. What `eps` is measured in
(m/s, or a dimensionless fraction of a threshold) is stated by each model.
"""

from __future__ import annotations

import abc
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike


def safe_div(num: ArrayLike, den: ArrayLike, fallback: ArrayLike = 0.0) -> Array:
    """`num / den` where `den != 0`, else `fallback`; NaN-free in value and gradient (double-`where`)."""
    den = jnp.asarray(den)
    nonzero = den != 0
    return jnp.where(nonzero, jnp.asarray(num) / jnp.where(nonzero, den, 1), fallback)


class AbstractSmoothing(eqx.Module):
    """A strategy for the non-smooth elementary functions of friction models."""

    @abc.abstractmethod
    def sign(self, x: ArrayLike) -> Array:
        """sign(x), in [-1, 1]."""

    def abs(self, x: ArrayLike) -> Array:
        """|x| = x * sign(x): zero at zero in both modes."""
        return jnp.asarray(x) * self.sign(x)

    def step(self, x: ArrayLike) -> Array:
        """Heaviside step H(x) = (1 + sign(x)) / 2, in [0, 1]."""
        return 0.5 * (1.0 + self.sign(x))

    def clip(self, x: ArrayLike, bound: ArrayLike) -> Array:
        """Saturation of `x` to `[-bound, bound]` (`bound > 0`): (|x + b| - |x - b|) / 2."""
        x = jnp.asarray(x)
        return 0.5 * (self.abs(x + bound) - self.abs(x - bound))

    def relu(self, x: ArrayLike) -> Array:
        """max(x, 0) = (x + |x|) / 2."""
        return 0.5 * (jnp.asarray(x) + self.abs(x))


class Exact(AbstractSmoothing):
    """The exact, non-smooth functions of the literature equations (`sign(0) = 0`)."""

    def sign(self, x: ArrayLike) -> Array:
        return jnp.sign(x)

    def step(self, x: ArrayLike) -> Array:
        """Strict step: 1 where x > 0, else 0 (a stick/slip test that holds with equality does not switch)."""
        x = jnp.asarray(x)
        return jnp.where(x > 0, jnp.ones_like(x), jnp.zeros_like(x))

    def clip(self, x: ArrayLike, bound: ArrayLike) -> Array:
        bound = jnp.asarray(bound)
        return jnp.clip(x, -bound, bound)


class Smooth(AbstractSmoothing):
    """Smooth functions of width `eps`: sign(x) ~ tanh(x / eps), differentiable everywhere.

    `eps` is an array leaf (not static), so sweeping or annealing it never recompiles. It converges to
    `Exact()` as `eps -> 0`; the error of `abs` is at most about 0.28 * eps.

    **Arguments:**

    - `eps`: positive width, in the units of the argument being smoothed (stated by each model).

    ```python
    >>> import fricjax as fj
    >>> float(fj.Smooth(1e-3).sign(1.0))
    1.0
    ```
    """

    eps: Array

    def __init__(self, eps: ArrayLike):
        if is_concrete(eps) and not bool(np.all(np.asarray(eps) > 0)):
            raise ValueError(f"Smooth: `eps` must be positive, got {eps!r}; pass a small width, e.g. 1e-4.")
        eps_array = jnp.asarray(eps)
        if not jnp.issubdtype(eps_array.dtype, jnp.floating):
            eps_array = eps_array.astype(jnp.result_type(float))
        self.eps = eps_array

    def sign(self, x: ArrayLike) -> Array:
        x = jnp.asarray(x)
        return jnp.tanh(x / self.eps.astype(x.dtype))  # the width follows the signal's dtype


def is_concrete(x: object) -> bool:
    """True when `x` holds values (not a tracer): value checks run only then, at the entry points."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def on_host(op: Any, *values: Any) -> Any:
    """`op(xp, *values)`: in NumPy when every value is concrete, the result placed on the device in the values'
    dtype (an eager JAX operation compiles a program of its own, once per shape), else in `jax.numpy` (traced)."""
    if is_concrete(values):
        result = np.asarray(op(np, *(np.asarray(v) for v in values)))
        return jax.device_put(result.astype(jnp.result_type(*values)))
    return op(jnp, *values)


def exact(model: eqx.Module) -> eqx.Module:
    """Return `model` with every smoothing strategy inside it replaced by `Exact()`.

    ```python
    >>> import fricjax as fj
    >>> m = fj.exact(fj.Coulomb(Fc=1.0, smoothing=fj.Smooth(1e-3)))
    >>> type(m.smoothing).__name__
    'Exact'
    ```
    """
    return jax.tree_util.tree_map(
        lambda leaf: Exact() if isinstance(leaf, AbstractSmoothing) else leaf,
        model,
        is_leaf=lambda leaf: isinstance(leaf, AbstractSmoothing),
    )


def check_smoothing(smoothing: Any, where: str) -> None:
    """Refuse a `smoothing` that is not a strategy: a plain number for `Smooth(eps)` is the likely slip."""
    if not isinstance(smoothing, AbstractSmoothing):
        raise TypeError(
            f"{where}: `smoothing` must be fj.Smooth(eps) or fj.Exact(), got {smoothing!r}"
            + (f"; pass smoothing=fj.Smooth({smoothing!r})." if isinstance(smoothing, (int, float)) else ".")
        )


def with_smoothing(model: eqx.Module, smoothing: AbstractSmoothing) -> eqx.Module:
    """Return `model` with every smoothing strategy inside it replaced by `smoothing` (e.g. `Smooth(1e-4)`)."""
    check_smoothing(smoothing, "with_smoothing")
    return jax.tree_util.tree_map(
        lambda leaf: smoothing if isinstance(leaf, AbstractSmoothing) else leaf,
        model,
        is_leaf=lambda leaf: isinstance(leaf, AbstractSmoothing),
    )
