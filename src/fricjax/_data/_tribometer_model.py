"""The synthetic tribometer's true friction model: the default one (an exact GMS), the displacement and force
scales its regimes are measured against (breakaway displacement, breakaway force), which of its elements slip, and
its parameters as plain numbers for the data card.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import numpy as np
from jaxtyping import Array

from .._constraints import parameter_arrays, unwrap
from .._inputs import Motion, MotionSample
from .._models._base import AbstractFrictionModel
from .._models.physics._gms import GMS
from .._models.physics._stribeck import ExponentialStribeck
from .._simulate import simulate


def default_tribometer_model() -> GMS:
    """The default true model of `make_tribometer`: an exact GMS, N = 4, for a small dry steel contact.

    `ExponentialStribeck(Fc=1.0 N, Fs=1.4 N, vs=1e-3 m/s, delta=1)` (worden2007 eq. 5),
    `k = [1.4e5, 1.12e5, 8.4e4, 5.6e4] N/m`, `alpha = [0.1, 0.2, 0.3, 0.4]`, `C = 20 N/s`, `sigma2 = 10 N·s/m`.
    The element breakaway displacements `alpha_i Fs / k_i` are 1, 2.5, 5 and 10 um (the pre-sliding range of a
    dry contact, Lampaert et al. 2003); the initial pre-sliding stiffness is `sum k_i = 3.92e5 N/m`.
    """
    return GMS(
        ExponentialStribeck(Fc=1.0, Fs=1.4, vs=1e-3, delta=1.0),
        k=[1.4e5, 1.12e5, 8.4e4, 5.6e4],
        alpha=[0.1, 0.2, 0.3, 0.4],
        C=20.0,
        sigma2=10.0,
    )


# ---------------------------------------------------------------------------------------------------------------
# What the regimes are measured against


def _breakaway_displacement(model: AbstractFrictionModel) -> float:
    """The displacement scale [m] over which `model` goes from sticking to gross sliding, as its family says
    (`AbstractFrictionModel.breakaway_displacement`: GMS `max_i alpha_i s(0) / k_i`, Maxwell-slip `max_i Delta_i`,
    LuGre `s(0) / sigma0`, Dahl `Fc / sigma0`). Other models have no pre-sliding scale: pass
    `breakaway_displacement=` to `make_tribometer`.
    """
    value = unwrap(model).breakaway_displacement()
    if value is None:
        raise ValueError(
            f"make_tribometer: {type(model).__name__} has no pre-sliding displacement scale to set the regime's "
            "amplitude from; pass `breakaway_displacement=` (metres), e.g. 1e-5."
        )
    return value


def _breakaway_force(model: AbstractFrictionModel) -> float | None:
    """The static (breakaway) force [N] (`AbstractFrictionModel.breakaway_force`: `s(0)` for GMS / LuGre, `Fc` for
    Dahl, `sum k_i Delta_i` for an LR/NLR Maxwell-slip model); `None` where the model has none."""
    return unwrap(model).breakaway_force()


def _offset(model: AbstractFrictionModel) -> float:
    return unwrap(model).force_offset()


class _SlipIndicator(AbstractFrictionModel):
    """Wraps a model with elements (GMS, Maxwell-slip): the same state, and as output 1.0 per element where it slips
    (`AbstractFrictionModel.slipping`), so `simulate` gives the slip pattern `(T, N)`."""

    model: AbstractFrictionModel

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return self.model.requires

    def init_state(self) -> Any:
        return self.model.init_state()

    def step(self, state: Any, sample: MotionSample) -> tuple[Any, Array]:
        new_state, _ = self.model.step(state, sample)
        slipping = self.model.slipping(state, new_state, sample)
        assert slipping is not None, "a model with elements says where they slip"
        return new_state, slipping


def slipping_elements(model: AbstractFrictionModel, motion: Motion) -> np.ndarray | None:
    """Which elements of a GMS or Maxwell-slip `model` slip at each sample of `motion`: bool `(T, N)`.

    Re-simulates the model's state from rest. `None` for models without elements (LuGre, Dahl, static curves).
    For a smooth model an element counts as slipping when its slip weight exceeds 1/2.
    """
    if model.num_elements is None:
        return None
    return np.asarray(simulate(_SlipIndicator(model), motion)) > 0.5


def model_parameters(model: eqx.Module) -> dict[str, Any]:
    """The physical parameter values of `model` (constraint wrappers resolved) as plain floats / lists, keyed by
    their path (`"stribeck.Fc"`, `"k"`, ...), rounded to 12 significant digits (6 for float32).

    ```python
    >>> import fricjax as fj
    >>> fj.model_parameters(fj.Dahl(sigma0=1e5, Fc=1.0))["sigma0"]
    100000.0
    ```
    """
    out: dict[str, Any] = {}
    for key, value in parameter_arrays(unwrap(model)).items():
        # round away the last-digit noise of the log / softmax reparametrisations (1e5 -> 100000.00000000003)
        digits = 12 if value.dtype == np.float64 else 6
        rounded = [float(f"{v:.{digits}g}") for v in value.reshape(-1).tolist()]
        out[key] = rounded[0] if value.ndim == 0 else np.reshape(rounded, value.shape).tolist()
    return out
