"""A grey-box + black-box friction law: a static physics law plus a small neural residual on the force path.

The grey and black-box combination of the emps-ensemble paper (§3.2, BGBM) models the *output* error of the
physics model with a NARX network added to the simulated position. `HybridFriction` puts the black box inside
the physics instead: the force that the drive must overcome is

    F(v, q, u) = F_law(v) + F_res(v, q, u) + offset,
    F_res = force_scale * d . tanh(W x + b),   x = (inputs - center) / scale,

with `F_law` any fricjax static law (the eight laws of the emps-ensemble paper), `inputs` a chosen subset of
the velocity `v` [m/s], the position `q` [m] and the drive force `u` [N] (e.g. `gtau * vir` on EMPS), and one
hidden layer of tanh units. With `d = 0` (the default start of `HybridFriction.init`) the hybrid *is* the
law. Since it is a static friction law, `EMPSPlant` accepts it as its friction, so the open- and closed-loop
simulators and the output-error fits run it unchanged (the plant passes `q` and `u` when the residual reads
them); trained by simulation error, the residual learns the force the law misses as seen through the plant.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..._constraints import Fixed, FixedScalar, ParamLike, as_float_array, unwrap
from ..._inputs import MotionSample
from ..._validation import positive_int
from ..blackbox._regressors import fixed_array
from ..physics._static import AbstractStaticFriction

HYBRID_INPUTS = ("v", "q", "u")
"""The signals a `HybridFriction` residual may read: velocity [m/s], position [m], drive force [N]."""


def _check_inputs(inputs: Any) -> tuple[str, ...]:
    if isinstance(inputs, str) or not isinstance(inputs, Sequence):
        raise TypeError(f"HybridFriction: `inputs` must be a tuple of names from {HYBRID_INPUTS}, got {inputs!r}.")
    inputs = tuple(inputs)
    if not inputs or len(set(inputs)) != len(inputs) or any(name not in HYBRID_INPUTS for name in inputs):
        raise ValueError(
            f"HybridFriction: `inputs` must be distinct names from {HYBRID_INPUTS} (at least one), got {inputs!r}."
        )
    return tuple(name for name in HYBRID_INPUTS if name in inputs)  # canonical order


class HybridFriction(AbstractStaticFriction):
    """A static friction law plus a one-hidden-layer tanh network residual (grey + black box).

    `F(v, q, u) = law(v) + force_scale * d . tanh(W (x - center) / scale + b) + offset`, `x` the `inputs`
    among velocity `v` [m/s], position `q` [m] and drive force `u` [N] (see the module docstring; after the
    emps-ensemble paper §3.2, with the black box on the force path rather than on the output).

    **Arguments:**

    - `law`: a fricjax static friction law (`CoulombViscous`, `Tustin`, ..., symmetric or asymmetric).
    - `W` `(width, P)`, `b` `(width,)`, `d` `(width,)`: the network's weights (normalised units; `P =
      len(inputs)`). `d = 0` gives the law exactly.
    - `inputs`: the residual's signals, a tuple from `("v", "q", "u")` (static; stored in that order).
    - `center`, `scale` `(P,)`: the input normalisation (fixed, in the inputs' units; `scale > 0`).
    - `force_scale`: the residual's force unit [N] (fixed, > 0; default 1).

    Calling it: `friction(v)` when the residual reads `v` only, else `friction(v, q=..., u=...)`; under
    `fj.simulate` on a `Motion` it reads `q` from the position `x` (a residual on `u` needs a plant).
    Build it with `HybridFriction.init(law, inputs, width, key=..., center=..., scale=...)`.

    ```python
    >>> import jax, fricjax as fj
    >>> law = fj.CoulombViscous(Fc=20.0, Fv=200.0)
    >>> hybrid = fj.HybridFriction.init(law, ("v",), 8, key=jax.random.PRNGKey(0))
    >>> float(hybrid(0.1)) == float(law(0.1))  # d = 0 at the start
    True
    ```
    """

    law: AbstractStaticFriction
    W: Array
    b: Array
    d: Array
    center: Fixed[Float[Array, " P"]]
    scale: Fixed[Float[Array, " P"]]
    force_scale: FixedScalar
    inputs: tuple[str, ...] = eqx.field(static=True)

    def __init__(
        self,
        law: AbstractStaticFriction,
        W: ArrayLike,
        b: ArrayLike,
        d: ArrayLike,
        *,
        inputs: Sequence[str] = ("v",),
        center: ParamLike | None = None,
        scale: ParamLike | None = None,
        force_scale: ParamLike = 1.0,
    ):
        if not isinstance(law, AbstractStaticFriction) or isinstance(law, HybridFriction):
            raise TypeError(
                "HybridFriction: `law` must be a fricjax static friction law (e.g. fj.CoulombViscous(Fc, Fv)), got "
                f"{type(law).__name__}."
            )
        self.inputs = _check_inputs(inputs)
        size = len(self.inputs)
        self.law = law
        self.W, self.b, self.d = as_float_array(W), as_float_array(b), as_float_array(d)
        width = self.b.shape[0] if self.b.ndim == 1 else -1
        if self.W.shape != (width, size) or self.d.shape != (width,):
            raise ValueError(
                f"HybridFriction: shapes W {self.W.shape}, b {self.b.shape}, d {self.d.shape} do not match "
                f"(width, {size} inputs); build it with HybridFriction.init(law, inputs, width, key=...)."
            )
        self.center = fixed_array(np.zeros(size) if center is None else center, (size,), "center", "HybridFriction")
        self.scale = fixed_array(
            np.ones(size) if scale is None else scale, (size,), "scale", "HybridFriction", positive=True
        )
        self.force_scale = fixed_array(force_scale, (), "force_scale", "HybridFriction", positive=True)
        self.offset = Fixed(jnp.zeros((), self.W.dtype))  # the law carries the offset
        self.smoothing = law.smoothing

    @classmethod
    def init(
        cls,
        law: AbstractStaticFriction,
        inputs: Sequence[str] = ("v",),
        width: int = 16,
        *,
        key: Array,
        center: ParamLike | None = None,
        scale: ParamLike | None = None,
        force_scale: ParamLike = 1.0,
    ) -> HybridFriction:
        """The law with a zero residual: `W ~ N(0, 1/P)`, `b ~ N(0, 1)`, `d = 0` (so the hybrid equals `law`
        and training starts from the physics). `width`: hidden tanh units (>= 1)."""
        width = positive_int(width, "width", "HybridFriction.init", hint="(hidden units)")
        size = len(_check_inputs(inputs))
        dtype = jnp.result_type(float)
        k1, k2 = jax.random.split(key)
        W = jax.random.normal(k1, (width, size), dtype) / np.sqrt(size)
        b = jax.random.normal(k2, (width,), dtype)
        return cls(
            law,
            W,
            b,
            jnp.zeros((width,), dtype),
            inputs=inputs,
            center=center,
            scale=scale,
            force_scale=force_scale,
        )

    @property
    def width(self) -> int:
        """The number of hidden units."""
        return int(self.b.shape[0])

    @property
    def asymmetric(self) -> bool:
        """True when the law has separate coefficients for positive and negative velocity."""
        return bool(self.law.asymmetric)

    def parameter_ranges(self) -> dict[str, float]:
        return {f"law.{name}": value for name, value in self.law.parameter_ranges().items()}

    def residual(self, v: ParamLike, q: ParamLike | None = None, u: ParamLike | None = None) -> Array:
        """The network's force `F_res(v, q, u)` [N] (broadcast over the shapes of the signals it reads)."""
        p = unwrap(self)
        given = {"v": v, "q": q, "u": u}
        missing = [name for name in p.inputs if given[name] is None]
        if missing:
            raise ValueError(
                f"HybridFriction: the residual reads {p.inputs}; pass {', '.join(f'{m}=...' for m in missing)} "
                "(in an EMPSPlant the simulators pass the position and the drive force)."
            )
        signals = jnp.broadcast_arrays(*(jnp.asarray(given[name]) for name in p.inputs))
        x = (jnp.stack(signals, axis=-1) - p.center) / p.scale
        hidden = jnp.tanh(x @ p.W.T + p.b)
        return p.force_scale * (hidden @ p.d)

    reads_plant: ClassVar[bool] = True

    def plant_force(self, v: ParamLike, q: ParamLike | None = None, u: ParamLike | None = None) -> Array:
        return self(v, q, u)

    def __call__(self, v: ParamLike, q: ParamLike | None = None, u: ParamLike | None = None) -> Array:  # type: ignore[override]
        """Friction force `law(v) + F_res(v, q, u) + offset` [N] (velocity [m/s], position [m], force [N])."""
        p = unwrap(self)
        return p.law(v) + p.residual(v, q, u) + p.offset

    def _law(self, v: Array, sign: Array, pick: Any) -> Array:  # the abstract hook; __call__ is overridden
        raise NotImplementedError("HybridFriction is evaluated by __call__ (law + residual).")

    def step(self, state: tuple[()], sample: MotionSample) -> tuple[tuple[()], Array]:
        if "u" in self.inputs:
            raise ValueError(
                "HybridFriction: a residual on the drive force `u` runs inside a plant (fj.EMPSPlant), not under "
                "fj.simulate on a Motion; build it with inputs=('v',) or ('v', 'q')."
            )
        return state, self(sample.v, q=sample.x)
