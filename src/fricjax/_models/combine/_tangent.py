"""`TangentGradients`: run any model with the tangent-linear derivative of `fj.simulate`'s scan."""

from __future__ import annotations

from typing import Any

from ..._validation import got_model
from .._base import AbstractFrictionModel, feeds_back


class TangentGradients(AbstractFrictionModel):
    """`model`, differentiated through the tangent-linear recurrence: the older form of
    `fj.simulate(model, motion, derivatives="tangent")` / `fj.SimulationLoss(derivatives="tangent")`, kept so that
    code written for it runs unchanged (the choice belongs to the driver, not to the model: prefer the option).

    The outputs and the derivatives are those of `model` (to round-off, tested); only their cost changes. For the
    free run `fj.simulate` then computes the per-step Jacobians `A_k = df/ds` (state) and `C_k = dg/ds` (output)
    at the stored states in one `vmap` over time, the parameter and input forcings by one `vmap` of `jvp`, and
    runs only the small linear recurrence `ds_k = A_k ds_k-1 + b_k` step by step; reverse mode transposes it
    into the adjoint recurrence.

    When it pays (benchmarks/README.md, 2-core CPU, 40 000 steps, exact mode): since `import fricjax` makes XLA:CPU
    compile each scan into one function (src/fricjax/_xla_flags.py), the plain reverse pass costs 1.6-4.3x the
    forward pass and this wrapper gains nothing (value_and_grad LuGre 101 against 96 ns/step, GMS N=4 339 against
    372, Maxwell-slip 72 against 174). It pays where XLA runs the scan op by op, i.e. in a process where
    `FRICJAX_KEEP_XLA_FLAGS` is set or JAX started before fricjax was imported: value_and_grad / forward LuGre
    59x -> 1.5x, GMS 22x -> 2.6x, Dahl 31x -> 1.3x, Bo-Pavelescu 10x -> 2.2x there. It does not pay for fits whose
    loss is itself differentiated twice (Levenberg-Marquardt with `separable=` parameters: mostly compilation of
    the nested derivatives), nor for Maxwell-slip with many elements or FIR histories. Parameter
    paths gain a `model.` prefix (`fj.fit(..., train=("model.sigma0",))`).

    **Arguments:** `model` any friction model that does not feed back its outputs (not a NARX).

    ```python
    >>> import jax, numpy as np, fricjax as fj
    >>> motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6, 400)), dt=1e-3)
    >>> lugre = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4)
    >>> loss = lambda m: (fj.simulate(m, motion) ** 2).mean()
    >>> a = jax.grad(loss)(lugre).sigma1
    >>> b = jax.grad(loss)(fj.TangentGradients(lugre)).model.sigma1
    >>> bool(abs(a - b) <= 1e-4 * abs(a))  # float32 here; equal to 1e-10 relative in float64 (tested)
    True
    ```
    """

    model: AbstractFrictionModel

    def __init__(self, model: AbstractFrictionModel):
        if not isinstance(model, AbstractFrictionModel):
            raise TypeError(f"TangentGradients: `model` must be a fricjax friction model, got {got_model(model)}.")
        if feeds_back(model):
            raise ValueError(
                f"TangentGradients: {type(model).__name__} feeds back its outputs; the tangent path covers free runs "
                "of models without feedback (pass the model itself for one-step or k-step prediction)."
            )
        self.model = model

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return self.model.requires

    def tangent_gradients(self) -> bool:
        """True (the point of the wrapper)."""
        return True

    def init_state(self) -> Any:
        return self.model.init_state()

    def step(self, state: Any, sample: Any) -> tuple[Any, Any]:
        return self.model.step(state, sample)
