"""Backlash: a play of width `gap` between the measured displacement and any friction model.

Real devices transmit the measured motion to the rubbing surfaces through joints with clearance (the banded
rotary friction damper of `shared/data/damper/`, README section 3, shows a plateau near zero force after every
reversal). The clearance is the play (backlash) operator of hysteresis modelling (Tao & Kokotović 1996; the
rate-independent element of Prandtl-Ishlinskii and Maxwell-slip models, parlitz2004 §III-B): the element stays
put while the measured displacement crosses the gap, and follows it once the slack is taken up.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from ..._constraints import Parameter, ParamLike, model_dtype, positive, unwrap
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact, safe_div
from ..._validation import got_model
from .._base import AbstractFrictionModel
from ..blackbox._regressors import advance_plays
from ._wrapper import AbstractWrapper


class BacklashState(eqx.Module):
    """The wrapped model's state and the position in the gap `play = (x - y) / (gap / 2)` in [-1, 1]
    (dimensionless; `x` the measured displacement, `y` the friction element's; 0: centred in the gap)."""

    inner: Any  # the wrapped model's state: any pytree, as its `init_state` returns
    play: Array


class Backlash(AbstractWrapper):
    """`model` driven through a play (backlash, dead zone) of total width `gap` [m].

    The element position `y` stays within `gap / 2` of the measured displacement `x`; with the normalised slack
    `p = (x - y) / (gap / 2)` the exact play operator is

    `p_k = clip(p_{k-1} + dx_k / (gap / 2), -1, 1)`,  `y_k = x_k - (gap / 2) p_k`,

    so after a reversal `x` travels `gap` before the element moves again (the lost motion), and while the element
    is engaged (`|p| = 1`, pushed in the direction of motion) it follows `x` shifted by `gap / 2`. The wrapped model
    sees the transmitted motion: `x = y_k`, `dx = y_k - y_{k-1}` and the velocity (and acceleration) of the
    sample times the transmitted fraction `dx_y / dx_x` of the step's displacement: the measured `v_k` once
    engaged, 0 inside the gap (where the friction element rests and a dynamic model keeps its state). A model of
    the transmitted force (friction of the element) then gives 0 force change inside the gap: a static law gives 0,
    a bristle / spring model holds its pre-sliding force. A play in the *load* path (a linkage that transmits no
    force while its gap is open, the force falling to 0 after each reversal) is `fj.LuGreBacklash`.

    The slack needs no absolute position: the record's zero of `x` is arbitrary. A record starts centred in the
    gap (`p = 0`) unless a state is given (`fj.simulate(..., state0=...)`, `BacklashState(inner, play)`).

    Smooth mode (`smoothing=Smooth(eps)`, `eps` dimensionless, a fraction of `gap / 2`, as the play operators
    of `fj.PlayOperators`): the clip is the smooth clip; it converges to the exact operator as eps -> 0.
    `fj.exact` / `fj.with_smoothing` set it together with the wrapped model's.

    **Arguments:**

    - `model`: any friction model.
    - `gap`: the total play (lost motion on a reversal) [m] (> 0; e.g. 1e-5 to 1e-2).
    - `smoothing`: `Exact()` (default) or `Smooth(eps)`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(np.array([0.0, 0.5e-3, 3e-3, 2e-3, 0.0]), dt=1e-3)
    >>> model = fj.Backlash(fj.Coulomb(Fc=1.0), gap=2e-3)  # 1 mm of slack each way from the centre
    >>> np.asarray(fj.simulate(model, motion)).tolist()  # in the gap, engaged, in the gap, engaged
    [0.0, 0.0, 1.0, 0.0, -1.0]
    ```
    """

    model: AbstractFrictionModel
    gap: Parameter
    smoothing: AbstractSmoothing

    def __init__(self, model: AbstractFrictionModel, gap: ParamLike, *, smoothing: AbstractSmoothing = Exact()):
        if not isinstance(model, AbstractFrictionModel):
            raise TypeError(f"Backlash: `model` must be a fricjax friction model, got {got_model(model)}.")
        self.model = model
        self.gap = positive(gap, "gap", model_dtype(gap), scalar=True)
        self.smoothing = smoothing

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return self.model.requires | {"x"}

    def init_state(self) -> BacklashState:
        return BacklashState(unwrap(self.model).init_state(), jnp.zeros((), unwrap(self.gap).dtype))

    def transmit(self, play: Array, sample: MotionSample) -> tuple[Array, MotionSample]:
        """One step of the play: the new slack and the motion sample transmitted to the friction element."""
        p = unwrap(self)
        half = 0.5 * p.gap
        new_play = advance_plays(play, sample.dx, half, p.smoothing)
        # the part of dx that the play does not take up, written as the excess beyond the clip, so that it is
        # exactly 0 inside the gap in exact mode (dx - half * (new_play - play) leaves round-off there)
        dy = half * (play + sample.dx / half - new_play)
        fraction = safe_div(dy, sample.dx)  # 1 engaged, 0 in the gap (and at dx = 0)
        transmitted = sample._replace(
            x=sample.x - half * new_play,
            dx=dy,
            v=sample.v * fraction,
            a=None if sample.a is None else sample.a * fraction,
        )
        return new_play, transmitted

    def step(self, state: BacklashState, sample: MotionSample) -> tuple[BacklashState, Array]:
        play, transmitted = self.transmit(state.play, sample)
        inner, force = unwrap(self.model).step(state.inner, transmitted)
        return BacklashState(inner, play), force

    def feedback(self, state: BacklashState, y_measured: Array) -> BacklashState:
        """Teacher forcing of the wrapped model (the play holds no output)."""
        return BacklashState(unwrap(self.model).feedback(state.inner, y_measured), state.play)
