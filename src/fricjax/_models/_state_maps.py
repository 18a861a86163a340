"""State maps for the time-parallel free run: a model's step written as a map of its state, one per sample.

When the map that takes a model's state across one sample belongs to a family closed under composition, the
states after every sample are the prefix compositions of those maps applied to the initial state, and a prefix
composition is what `jax.lax.associative_scan` computes in O(log T) depth (Blelloch 1990; for linear recurrences
the parallel-scan form of Martin & Cundy 2018, for the time-parallel evaluation of sequential models Lim et al.
2024, "DEER"). Two families cover fricjax's models:

- `AffineMaps`: `s -> scale * s + shift`, elementwise: LuGre's bristle update (linear in `z` for the velocity held
  over a sample, whatever the smoothing), the linear parts of models;
- `ClampMaps`: `s -> min(max(s + shift, lower), upper)`: an exact Maxwell-slip element or play operator. A clamp
  of a shifted clamp is again one: `clamp(clamp(s + a1, l1, h1) + a2, l2, h2) = clamp(s + a1 + a2, L, H)` with
  `L = clamp(l1 + a2, l2, h2)`, `H = clamp(h1 + a2, l2, h2)`.

A model declares its form by `AbstractModel.parallel_maps(samples)`: a pytree shaped like its state whose leaves
are such maps, every array with the leading time axis. `fj.simulate(..., scan="parallel")` composes them and then
evaluates the model's own `step` at every sample, in parallel, from the state entering it.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array


class AbstractStateMaps(eqx.Module):
    """Maps of one state array, one per sample along the leading axis (every field shaped `(T, *state.shape)`, or
    broadcastable to it after the time axis), acting elementwise on the state (component i of the result depends
    on component i of the state only). Subclasses define composition, application and `IDENTITY`, the values of
    their fields that make the identity map."""

    IDENTITY: ClassVar[tuple[float, ...]] = ()

    def delayed(self, places: int | Array, axis: int = 0) -> Any:
        """The maps moved `places` samples later along `axis`, the first `places` being identity maps (the last
        `places` dropped): one pad of every field, which XLA fuses into the composition that reads it; a traced
        `places` (inside a loop) rolls every field and puts identity maps in front."""
        fields = [getattr(self, field.name) for field in dataclasses.fields(self)]

        def delay(value: Array, fill: float) -> Array:
            if not isinstance(places, int):
                index = jax.lax.broadcasted_iota(jnp.int32, value.shape, axis)
                return jnp.where(index < places, jnp.asarray(fill, value.dtype), jnp.roll(value, places, axis))
            config = [(0, 0, 0)] * value.ndim
            config[axis] = (places, -places, 0)
            return jax.lax.pad(value, jnp.asarray(fill, value.dtype), config)

        return type(self)(*(delay(value, fill) for value, fill in zip(fields, self.IDENTITY, strict=True)))

    @abc.abstractmethod
    def then(self, later: Any) -> Any:
        """The composition `later o self` (apply `self` first), elementwise over the leading axes."""

    @abc.abstractmethod
    def __call__(self, state: Array) -> Array:
        """The maps applied to `state` (broadcast along the leading axes)."""

    def linearised(self, state: Array, tangent: Any) -> AffineMaps:
        """The maps' first-order change at `state`: `AffineMaps(ds_out/ds, d_out along tangent)`, the derivative
        with respect to the state entering them and along `tangent` (maps of the same fields), which the tangent of
        the states follows (`_simulate/_parallel.py`), by JAX's own derivatives (a clamp's at a tie: half to each side,
        as the sequential scan's `minimum` / `maximum`)."""
        _, scale = jax.jvp(self, (state,), (jnp.ones_like(state),))
        _, shift = jax.jvp(lambda maps: maps(state), (self,), (tangent,))
        return AffineMaps(scale, shift)


class AffineMaps(AbstractStateMaps):
    """`s -> scale * s + shift`, elementwise (`scale`, `shift` of the state's shape after the time axis)."""

    scale: Array
    shift: Array
    IDENTITY: ClassVar[tuple[float, ...]] = (1.0, 0.0)

    def then(self, later: AffineMaps) -> AffineMaps:
        return AffineMaps(later.scale * self.scale, later.scale * self.shift + later.shift)

    def __call__(self, state: Array) -> Array:
        return self.scale * state + self.shift


class ClampMaps(AbstractStateMaps):
    """`s -> min(max(s + shift, lower), upper)`, elementwise, with `lower <= upper`: a play operator, or an exact
    elasto-slide element of deflection limits `+-Delta` driven by the displacement increments `shift`."""

    shift: Array
    lower: Array
    upper: Array
    IDENTITY: ClassVar[tuple[float, ...]] = (0.0, -jnp.inf, jnp.inf)

    def then(self, later: ClampMaps) -> ClampMaps:
        def clamp(value: Array) -> Array:
            return jnp.minimum(jnp.maximum(value, later.lower), later.upper)

        return ClampMaps(self.shift + later.shift, clamp(self.lower + later.shift), clamp(self.upper + later.shift))

    def __call__(self, state: Array) -> Array:
        return jnp.minimum(jnp.maximum(state + self.shift, self.lower), self.upper)


def is_state_maps(node: Any) -> bool:
    """`is_leaf` for trees of state maps."""
    return isinstance(node, AbstractStateMaps)


def compose(earlier: Any, later: Any) -> Any:
    """Elementwise composition of two trees of state maps (`later o earlier`): the operator of the associative
    scan."""
    return jax.tree_util.tree_map(lambda first, second: first.then(second), earlier, later, is_leaf=is_state_maps)


def delayed(maps: Any, places: int | Array, axis: int = 0) -> Any:
    """A tree of state maps moved `places` samples later along `axis`, identity maps first."""
    return jax.tree_util.tree_map(lambda m: m.delayed(places, axis), maps, is_leaf=is_state_maps)


def full_fields(maps: Any, state: Any) -> Any:
    """A tree of state maps with every field broadcast to `(T, *state.shape)` of its state leaf and of one dtype
    (fields may be given broadcastable, e.g. `(T, 1)`, or of mixed precision; the blocked prefix stacks
    compositions, and the doubling rounds on a CPU carry them through a loop, which need both)."""

    def full(m: AbstractStateMaps, s: Any) -> AbstractStateMaps:
        fields = [getattr(m, field.name) for field in dataclasses.fields(m)]
        dtype = jnp.result_type(*fields)
        return type(m)(*(jnp.broadcast_to(v, (jnp.shape(v)[0], *jnp.shape(s))).astype(dtype) for v in fields))

    return jax.tree_util.tree_map(full, maps, state, is_leaf=is_state_maps)


def apply(maps: Any, state: Any) -> Any:
    """A tree of state maps applied to the state tree it is shaped like."""
    return jax.tree_util.tree_map(lambda m, s: m(jnp.asarray(s)), maps, state, is_leaf=is_state_maps)


def shaped_like(state: Any, maps: list[AbstractStateMaps]) -> Any:
    """The maps, one per leaf of `state` in its flattening order, arranged as `state` is (the return value of
    `parallel_maps`)."""
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(state), maps)


def held(value: Any, length: int) -> Array:
    """`value` broadcast along a new leading time axis of `length` samples (a map field constant over time)."""
    value = jnp.asarray(value)
    return jnp.broadcast_to(value, (length, *value.shape))
