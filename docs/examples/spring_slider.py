"""A model of your own: an elasto-plastic spring-slider with viscous damping (a one-element Maxwell-slip model).

The spring force `Fs` is the state: it follows the displacement with stiffness `k` until it reaches the slip
force `Fc`, where the contact slips and the spring force saturates:

    Fs_k = clip(Fs_{k-1} + k dx_k, -Fc, Fc),    F_k = Fs_k + c v_k

This file is included in docs/write-your-own-model.md and run by tests/test_docs_site.py, which checks it against
the contract every fricjax model meets (jit == no jit, vmap == loop, gradients, fit, model files).
"""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import fricjax as fj


class SpringSliderState(eqx.Module):
    """The spring force `Fs` [N]."""

    Fs: jax.Array


class SpringSlider(fj.AbstractFrictionModel):
    """Elasto-plastic spring-slider: stiffness `k` [N/m], slip force `Fc` [N], viscous coefficient `c` [N·s/m]."""

    k: fj.Positive  # stored as log(k): an unconstrained optimiser cannot make it negative
    Fc: fj.Positive
    c: jax.Array  # real: enters the force linearly (separable)
    smoothing: fj.AbstractSmoothing  # Exact() for evaluation, Smooth(eps) for training; eps in newtons here

    requires: ClassVar[frozenset[str]] = frozenset({"x", "v"})  # step reads dx (from x) and v
    units: ClassVar[dict[str, str]] = {"k": "N/m", "Fc": "N", "c": "N s/m"}  # printed beside the parameters

    def __init__(self, k, Fc, c=0.0, *, smoothing=fj.Exact()):  # noqa: B008 - Exact() is immutable, as in fricjax's own models
        self.k = fj.Positive(k, name="k")
        self.Fc = fj.Positive(Fc, name="Fc")
        self.c = jnp.asarray(c, dtype=float)
        self.smoothing = smoothing

    def init_state(self) -> SpringSliderState:
        return SpringSliderState(Fs=jnp.zeros(()))  # at rest, no spring force

    def step(self, state: SpringSliderState, sample: fj.MotionSample) -> tuple[SpringSliderState, jax.Array]:
        p = fj.unwrap(self)  # the physical values of the wrapped parameters
        spring = p.smoothing.clip(state.Fs + p.k * sample.dx, p.Fc)  # stick, or slip at +/- Fc
        return SpringSliderState(Fs=spring), spring + p.c * sample.v


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    t = np.arange(2000) * 1e-3
    motion = fj.Motion.from_position(2e-5 * np.sin(2 * np.pi * t) * (1 + 4 * t), dt=1e-3)  # x [m], dt [s]
    true = SpringSlider(k=1e5, Fc=1.0, c=5.0)
    data = fj.FrictionData(motion, fj.simulate(true, motion))

    start = SpringSlider(k=5e4, Fc=1.5, c=0.0, smoothing=fj.Smooth(1e-2))  # smooth for training
    result = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=50, separable=("c",))
    fitted = fj.exact(result.model)  # exact for evaluation
    print(result.code, "NMSE %:", float(fj.nmse(data.force, fj.simulate(fitted, motion))))
    fj.save_model("spring_slider.eqx", fitted)
    again = fj.load_model("spring_slider.eqx", classes=(SpringSlider, SpringSliderState))
