"""Friction models around another friction model (`AbstractWrapper`: a sensor drift, a normal-load scaling, a
backlash), and the walk through them that generic code uses instead of switching on their classes."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx

from ..._constraints import unwrap
from .._base import AbstractFrictionModel


class AbstractWrapper(AbstractFrictionModel):
    """A friction model built around another one, `model` (an `eqx.AbstractVar`: each wrapper declares the field).

    `transparent`: the inner model sees the same motion and its force reaches the output changed only by a sensor or
    a load (`fj.SensorDrift`, `fj.NormalLoad`): compare fits and reports the inner friction model through it
    (`inner_friction`, `wrapper_path`). A backlash changes the motion the inner model sees, so it is not transparent.
    What is implausible in a wrapped model is what is implausible in the model inside.
    """

    model: eqx.AbstractVar[AbstractFrictionModel]
    transparent: ClassVar[bool] = False

    def implausible(self, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
        return unwrap(self.model).implausible(record_excursion, bounds=bounds)


def _is_transparent(model: Any) -> bool:
    return isinstance(model, AbstractWrapper) and model.transparent


def inner_friction(model: Any) -> Any:
    """The friction model inside `model`'s transparent wrappers (a sensor drift, a normal load); `model` itself where
    it has none."""
    while _is_transparent(model):
        model = model.model
    return model


def wrapper_path(model: Any) -> str:
    """The dotted prefix of the friction model inside `model`'s transparent wrappers (`"model."` for each)."""
    prefix = ""
    while _is_transparent(model):
        prefix, model = prefix + "model.", model.model
    return prefix


def with_inner_friction(model: Any, friction: Any) -> Any:
    """`model` with the friction model inside its transparent wrappers replaced by `friction`."""
    if _is_transparent(model):
        return eqx.tree_at(lambda m: m.model, model, with_inner_friction(model.model, friction))
    return friction
