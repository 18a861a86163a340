"""The models `compare` can fit, by command-line name (`MODEL_NAMES`; `PHYSICS_MODELS` by default), and their
recipes (`default_models`): each one's start built from the training record and its fit, with the force sensor's
drift (`FitSettings.drift`) wrapped around every model."""

from __future__ import annotations

from typing import Any

from ..._models.combine._normal_load import NormalLoad
from ..._models.combine._sensor import SensorDrift
from ._blackbox_recipes import linear_in_parameters_models, neural_models
from ._names import LINEAR_MODELS as LINEAR_MODELS
from ._names import MODEL_NAMES as MODEL_NAMES
from ._names import NEURAL_MODELS as NEURAL_MODELS
from ._names import PHYSICS_MODELS as PHYSICS_MODELS
from ._physics_recipes import physics_models
from ._recipes import ModelSpec
from ._settings import DataScales, FitSettings


def default_models(
    settings: FitSettings | None = None, several: bool = False, normal_load: float | None = None
) -> dict[str, ModelSpec]:
    """Every model `compare` can fit (`MODEL_NAMES`: the physics, neural and linear-in-parameters models), keyed by
    their command-line names; `settings` sets the step budgets and element counts (`FitSettings()` by default).
    `several`: fitted on several records, where a drift is a per-record nuisance of the fit, not a model wrapper.
    `normal_load` [N]: the records hold the normal load (`Motion.normal_force`), and each physics model is wrapped in
    `fj.NormalLoad(model, reference=normal_load)` (its forces scale with the load; the mean training load)."""
    settings = FitSettings() if settings is None else settings
    specs = physics_models(settings)
    if normal_load is not None:
        specs = {name: _with_normal_load(spec, normal_load) for name, spec in specs.items()}
    specs.update(neural_models(settings))
    specs.update(linear_in_parameters_models(settings))
    if settings.drift == "none" or several:
        return specs
    return {name: _with_drift(spec, settings.drift) for name, spec in specs.items()}


def _with_normal_load(spec: ModelSpec, reference: float) -> ModelSpec:
    """The spec with its model wrapped in `NormalLoad` (forces proportional to the measured normal load)."""
    inner = spec.build
    assert inner is not None  # the physics models are built from the data scales
    return ModelSpec(f"{spec.label} x N", lambda scales: NormalLoad(inner(scales), reference), spec.fit)


def _with_drift(spec: ModelSpec, kind: str) -> ModelSpec:
    """The spec with its model wrapped in `SensorDrift` (rate 0; leaky: tau = the training record's duration)."""

    inner = spec.build
    if inner is None:  # identified with its drift from the split itself
        return spec

    def build(scales: DataScales) -> Any:
        model = inner(scales)
        if getattr(model, "drifts", False):  # identified with its drift (the linear-in-parameters models)
            return model
        return SensorDrift(model, 0.0, None if kind == "linear" else scales.duration)

    return ModelSpec(spec.label, build, spec.fit)
