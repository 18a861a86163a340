"""Normal-load scaling: friction proportional to a measured normal force, around any friction model.

Coulomb's law makes the friction force proportional to the normal load, `F_C = mu |F_N|` (emps-ensemble eq. 3).
Devices whose clamping force varies during a record (the banded rotary friction damper of `shared/data/damper/`,
README section 3: two actuators set the band tension, and dataset-4 varies it during the test) need the load as
an input of the model rather than a constant folded into its force levels.
"""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from ..._constraints import Fixed, FixedScalar, ParamLike, check_normal, model_dtype, real, unwrap
from ..._inputs import MotionSample
from ..._smoothing import is_concrete, safe_div
from ..._validation import got_model
from .._base import AbstractFrictionModel
from .._state_maps import AffineMaps
from ._wrapper import AbstractWrapper


class NormalLoadState(eqx.Module):
    """The wrapped model's state and the load ratio `|N| / reference` of the last output (dimensionless)."""

    inner: Any  # the wrapped model's state: any pytree, as its `init_state` returns
    scale: Array


class NormalLoad(AbstractWrapper):
    """`model`'s friction force scaled by the measured normal load: `F = (|N(t)| / reference) (F_model - b) + b`.

    `model` describes the device at the constant load `reference` [N]; at load `N(t)` (`Motion.normal_force`)
    every friction force level scales with the load, as Coulomb's `F_C = mu |F_N|` (emps-ensemble eq. 3) extended
    to the whole friction force. `b` is the wrapped model's own `offset` field where it has one (a force-sensor
    offset is not friction and is not scaled); for a sensor drift, wrap the other way round:
    `fj.SensorDrift(fj.NormalLoad(model, reference))`.

    Assumption (stated, not derived from a paper on these models): the load multiplies the force, the state of
    `model` is independent of it. For a constant load this is `model` with every force parameter (Coulomb and
    static forces, stiffnesses, damping and viscous coefficients) multiplied by `|N| / reference`: the number of
    load-bearing junctions and so the contact's strength and tangential stiffness grow with the load, while the
    pre-sliding (breakaway) displacement and the Stribeck velocity do not. A load step while sticking scales the
    sticking force at once. Lubricated viscous friction that does not depend on the load is not separated out.

    `reference` is held fixed (it only sets the unit of the wrapped model's force levels, which are trained).

    **Arguments:**

    - `model`: any friction model (its forces are those at the load `reference`).
    - `reference`: the reference normal load [N] (> 0), e.g. the mean load of the training records.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion(v=np.full(3, 0.1), dt=1e-3, normal_force=np.array([50.0, 100.0, 200.0]))
    >>> np.asarray(fj.simulate(fj.NormalLoad(fj.Coulomb(Fc=2.0), reference=100.0), motion)).tolist()
    [1.0, 2.0, 4.0]
    ```
    """

    model: AbstractFrictionModel
    reference: FixedScalar
    transparent: ClassVar[bool] = True

    def __init__(self, model: AbstractFrictionModel, reference: ParamLike):
        if not isinstance(model, AbstractFrictionModel):
            raise TypeError(f"NormalLoad: `model` must be a fricjax friction model, got {got_model(model)}.")
        self.model = model
        self.reference = Fixed(real(reference, "reference", model_dtype(reference), scalar=True))

    def __check_init__(self):
        # here, not only in __init__: fj.load_model runs it on a model read from a file (no constructor runs there)
        value = unwrap(self.reference)
        if is_concrete(value):
            if not float(value) > 0:
                raise ValueError(
                    f"NormalLoad: `reference` must be a positive normal load in newtons, got {float(value)}."
                )
            try:
                check_normal(value, "reference")
            except ValueError as err:
                raise ValueError(f"NormalLoad: {err}") from None

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return self.model.requires | {"normal_force"}

    def init_state(self) -> NormalLoadState:
        return NormalLoadState(unwrap(self.model).init_state(), jnp.ones((), unwrap(self.reference).dtype))

    def _scale(self, samples: MotionSample) -> Array:
        """The load ratio `|N| / reference` of a sample (or of stacked samples)."""
        if samples.normal_force is None:  # structure, at trace time: `simulate` checks `requires` first
            raise ValueError("NormalLoad: the motion has no normal load; pass Motion(..., normal_force=...) [N].")
        return jnp.abs(samples.normal_force) / unwrap(self.reference)

    def _offset(self) -> Any:
        return getattr(unwrap(self.model), "offset", 0.0)

    def step(self, state: NormalLoadState, sample: MotionSample) -> tuple[NormalLoadState, Array]:
        inner, force = unwrap(self.model).step(state.inner, sample)
        scale = self._scale(sample)
        offset = self._offset()
        return NormalLoadState(inner, scale), scale * (force - offset) + offset

    def feedback(self, state: NormalLoadState, y_measured: Array) -> NormalLoadState:
        """Teacher forcing of the wrapped model with the measurement brought back to the reference load."""
        offset = self._offset()
        inner = unwrap(self.model).feedback(state.inner, safe_div(y_measured - offset, state.scale) + offset)
        return NormalLoadState(inner, state.scale)

    def parallel_maps(self, samples: MotionSample) -> Any:
        """The wrapped model's maps; the load ratio is set by each sample (the time-parallel free run)."""
        inner = unwrap(self.model).parallel_maps(samples)
        if inner is None:
            return None
        scale = self._scale(samples)
        return NormalLoadState(inner, AffineMaps(jnp.zeros_like(scale), scale))  # type: ignore[arg-type]
