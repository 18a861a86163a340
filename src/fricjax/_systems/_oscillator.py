"""A mass-spring-damper whose hysteretic restoring force is any fricjax friction model of its displacement.

    m y'' + c y' + k y + F[y](t) = u(t),

input force u [N], output displacement y [m]; `F` [N] is the output of a friction model (Maxwell-slip, GMS,
LuGre, Dahl, a recurrent network, ...) driven by the displacement history y. The Bouc-Wen oscillator of the
Noël & Schoukens (2016) benchmark is the case where `F` is the Bouc-Wen variable z; this system fits the
benchmark with the rate-independent hysteresis models of the friction literature instead (the "Maxwell-slip,
GMS-type elements on displacement" of the Bouc-Wen protocol, `fj.boucwen.score_boucwen`).

**Discretisation.** The force `u` is linear between samples (`fj.boucwen_inputs`). Each sample is divided into
`substeps` steps of `h = dt / substeps`, each a velocity-Verlet step: a half kick with the forces at the start,
`v' = v + h/2 (u(t) - c v - k y - F) / m`; the drift `y <- y + h v'`; the friction model steps over that
displacement increment (its `x` = the new y, `dx` the increment, `v` the step's mean velocity v', `dt` = h) and
gives the force `F` at the new displacement; the second half kick with the forces at the end, the damping taken
implicitly: `v <- (v' + h/2 (u(t + h) - k y - F) / m) / (1 + h c / (2 m))`. Second order (tested against the
exact linear oscillator), one element step per substep, so a few substeps per sample suffice at the
benchmark's 750 Hz (8: 6 kHz).
"""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._constraints import Parameter, ParamLike, model_dtype, positive, unwrap
from .._inputs import MotionSample
from .._models._base import AbstractFrictionModel, AbstractSystem
from .._validation import positive_int


class OscillatorState(eqx.Module):
    """State of a `HystereticOscillator`: displacement `y` [m], velocity `v` [m/s], the element's state and
    its force `F` [N] at `y`."""

    y: Array
    v: Array
    element: Any  # the element model's state: any pytree, as its `init_state` returns
    F: Array


class HystereticOscillator(AbstractSystem):
    """`m y'' + c y' + k y + F[y] = u`: a mass-spring-damper with a friction model of the displacement as its
    hysteretic restoring force (see the module docstring for the equations and the discretisation).

    Input record: `fj.boucwen_inputs(u)` (force [N] at samples k and k+1, linear in between). Output at sample
    k: the displacement `y(k)` [m]; the state (at rest by default) is then advanced to k+1.

    **Arguments:** `m` mass [kg], `c` damping [N s/m], `k` linear stiffness [N/m] (all positive, stored as
    logs); `element`, any fricjax friction model that needs at most `x`, `v`, `dx` and `a` (its force [N] enters
    the equation of motion; its parameters are fitted with the others); `substeps` (static, default 8).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> element = fj.MaxwellSlip.nlr(k=[2e4, 1e4], thresholds=[1e-4, 3e-4])
    >>> system = fj.HystereticOscillator(m=2.0, c=10.0, k=5e4, element=element)
    >>> fj.simulate(system, fj.boucwen_inputs(np.full(100, 10.0))).shape
    (100,)
    ```
    """

    m: Parameter
    c: Parameter
    k: Parameter
    element: AbstractFrictionModel
    substeps: int = eqx.field(static=True, default=8)

    requires: ClassVar[frozenset[str]] = frozenset({"u", "u_next"})
    units: ClassVar[dict[str, str] | None] = {"m": "kg", "c": "N s/m", "k": "N/m"}

    def __init__(self, m: ParamLike, c: ParamLike, k: ParamLike, element: AbstractFrictionModel, substeps: int = 8):
        if not isinstance(element, AbstractFrictionModel):
            raise TypeError(
                "HystereticOscillator: `element` must be a fricjax friction model (e.g. fj.MaxwellSlip.nlr, fj.GMS), "
                f"got {type(element).__name__}."
            )
        unsupported = sorted(set(element.requires) - {"x", "v", "dx", "a", "dt"})
        if unsupported:
            raise ValueError(
                f"HystereticOscillator: the element {type(element).__name__} needs {unsupported}, which the "
                "oscillator does not provide (it gives x, v, dx and a of the displacement)."
            )
        substeps = positive_int(substeps, "substeps", "HystereticOscillator", hint="(integration steps per sample)")
        dtype = model_dtype(m, c, k)
        self.m = positive(m, "m", dtype, scalar=True)
        self.c = positive(c, "c", dtype, scalar=True)
        self.k = positive(k, "k", dtype, scalar=True)
        self.element = element
        self.substeps = substeps

    def init_state(self) -> OscillatorState:
        p = unwrap(self)
        zero = jnp.zeros((), jnp.result_type(p.m))
        element_state = p.element.init_state()
        # the element's force at rest: one step of zero motion from its initial state
        _, F = p.element.step(element_state, self._sample(zero, zero, zero, zero, jnp.ones((), zero.dtype)))
        return OscillatorState(y=zero, v=zero, element=element_state, F=jnp.asarray(F, zero.dtype))

    def _sample(self, y: Array, v: Array, dx: Array, a: Array, h: Array) -> MotionSample:
        needs_a = "a" in self.element.requires
        return MotionSample(x=y, v=v, dx=dx, dt=h, a=a if needs_a else None)

    def step(self, state: OscillatorState, sample: dict[str, Array]) -> tuple[OscillatorState, Array]:
        p = unwrap(self)
        u0, u1 = sample["u"], sample["u_next"]
        h = sample["dt"] / self.substeps
        du = (u1 - u0) / self.substeps

        def substep(i: Any, s: OscillatorState) -> OscillatorState:
            u_start = u0 + i * du
            a = (u_start - p.c * s.v - p.k * s.y - s.F) / p.m
            v_mean = s.v + 0.5 * h * a
            dy = h * v_mean
            y = s.y + dy
            element, F = p.element.step(s.element, self._sample(y, v_mean, dy, a, h))
            v = (v_mean + 0.5 * h * (u_start + du - p.k * y - F) / p.m) / (1.0 + 0.5 * h * p.c / p.m)
            return OscillatorState(y=y, v=v, element=element, F=F)

        new = jax.lax.fori_loop(0, self.substeps, substep, state)
        return new, state.y
