"""The model contract shared by every fricjax model: physics, black-box, combinations and systems.

A model is an `equinox.Module` whose array leaves are its parameters. It never stores state: `init_state()`
gives the state at rest and `step(state, sample) -> (state, y)` advances one sample. A model whose state holds
its own past outputs (NARX-type models) overrides `feedback(state, y_measured) -> state`, which replaces the
fed-back prediction by the measurement (teacher forcing); for every other model it is the identity.
`samples(inputs)` turns an input record into the per-step signals (leading axis: time; scalar leaves such as `dt`
are constants of the record) that `fj.simulate` scans over, deriving what the model declares in `requires` once,
before the scan.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax
from jaxtyping import Array

from .._inputs import InputRecord, Motion, MotionSample
from .._smoothing import check_smoothing
from ._display import model_text


class AbstractModel(eqx.Module):
    """Any model `fj.simulate` can run: `init_state`, `step`, optionally `feedback`, and `samples`.

    - `init_state()`: the state at rest (a pytree of arrays).
    - `step(state, sample) -> (state, y)`: one sample; `y` the model output (a scalar force for friction
      models, any pytree for systems).
    - `feedback(state, y_measured) -> state`: replace the model's own past output held in `state` by the
      measured one (one-step / k-step-ahead prediction). The identity unless the model feeds back outputs.
    - `samples(inputs)`: the per-step signals of an input record, each leaf with a leading time axis, or a
      scalar (a constant of the record, such as `dt`).
    - `requires`: the signals `step` reads (checked once, at the entry point).
    """

    requires: ClassVar[frozenset[str]] = frozenset()

    def __check_init__(self) -> None:
        """A `smoothing` field holds a smoothing strategy (`fj.Smooth(eps)`, `fj.Exact()`), or None where the
        model allows it; a plain number there is the likely slip, refused at construction."""
        smoothing = getattr(self, "smoothing", None)
        if smoothing is not None:
            check_smoothing(smoothing, type(self).__name__)

    # real (not reparametrised) fields that are physically >= 0 (damping coefficients): separable least squares
    # keeps them >= 0 (`fj.fit(..., separable=...)`)
    nonnegative_fields: ClassVar[frozenset[str]] = frozenset()
    # fields that only set the state at rest (`init_state`: LuGre `z0`, Dahl `F0`): a fit to several records, which
    # estimates each record's initial state, holds them (`fj.Nuisances(initial_state=True)`)
    initial_state_fields: ClassVar[frozenset[str]] = frozenset()
    # the SI units of the class's own fields by name, where they are not the literature symbols of
    # `fricjax._constraints.PARAMETER_UNITS` (None: those symbols); `{}` for networks, whose weights have no units
    # (`parameter_units`: printed models, `Solution.parameter_table`, compare's report)
    units: ClassVar[dict[str, str] | None] = None
    # performance only: when set, the free run outside derivatives runs with the parameters packed into one
    # vector that the loop body unpacks, at this scan unrolling (faster loops on XLA:CPU for some models; see
    # `fricjax._simulate.run` and benchmarks/README.md). Derivatives are those of the plain scan.
    packed_unroll: ClassVar[int | None] = None

    def __repr__(self) -> str:
        """The model's class, its smoothing and one line per parameter array with its unit (physical values:
        constraint wrappers resolved). Traced or shape-only leaves print as equinox prints a Module; so does
        `eqx.tree_pformat(model)` always (the structural view).

        ```python
        >>> import fricjax as fj
        >>> print(fj.Dahl(sigma0=1e5, Fc=fj.Fixed(1.0), smoothing=fj.Smooth(1e-3)))
        Dahl (smooth, eps 0.001)
          sigma0 = 100000 [N/m]
          Fc = 1 [N] (fixed)
          alpha = 1 [-]
          offset = 0 [N]
          F0 = 0 [N]
        ```
        """
        return model_text(self)

    def parameter_ranges(self) -> dict[str, float]:
        """The physical magnitude of real fields that may start at 0 (`{field: magnitude}` in the field's
        units, e.g. LuGre `z0` ~ Fc / sigma0 [m]): `fj.ParameterScaling` divides such fields by it, so that one
        learning rate moves them by a physically small step. Empty by default."""
        return {}

    @abc.abstractmethod
    def init_state(self) -> Any:
        """The state at rest (a pytree of arrays)."""

    @abc.abstractmethod
    def step(self, state: Any, sample: Any) -> tuple[Any, Any]:
        """One sample: `(state_k-1, sample_k) -> (state_k, y_k)`."""

    def feedback(self, state: Any, y_measured: Any) -> Any:
        """Teacher forcing: the state with the fed-back output replaced by `y_measured` (identity by default)."""
        return state

    def tangent_gradients(self) -> bool:
        """Whether `fj.simulate(..., derivatives="auto")` differentiates this model's free run through the
        tangent-linear recurrence (a custom JVP of the scan: per-step state Jacobians computed in parallel over time,
        then one small linear scan; reverse mode transposes it) instead of the scan's own derivative. The
        derivatives are the same to round-off; the choice is speed only, and belongs to the driver
        (`derivatives="tangent"`). False for every model; True only for the older `fj.TangentGradients` wrapper."""
        return False

    def batch_minor(self) -> bool:
        """Whether this model supports the batch-minor layout: `fj.simulate`'s free run, batched by `jax.vmap` and
        not differentiated, keeps the batch as the last (minor) axis of the loop's arrays and writes its outputs in
        `(batch, time)` order directly (`fricjax._simulate._batch_minor_scan`) instead of vmap's own batching. The
        driver chooses (`fj.simulate(..., batching="auto" | "batch_minor" | "vmap")`; "auto" uses it where declared).
        Speed only (faster for a state that is a vector of elements, as Maxwell-slip's; benchmarks/README.md);
        derivatives are unchanged."""
        return False

    def parallel_maps(self, samples: Any) -> Any:
        """The time-parallel form of the free run, or `None` (no such form): a pytree shaped like the state whose leaves
        are state maps (`AffineMaps`, `ClampMaps` in `fricjax._models._state_maps`, acting elementwise on the state),
        map k taking the state entering sample k to the state leaving it, every array with the leading time axis of
        `samples`. The maps must agree with `step` to round-off; `fj.simulate(..., scan="parallel")` composes them by a
        parallel prefix and evaluates `step` at every sample from the state entering it. Whether a model has the form
        must not depend on parameter values (only on its type, structure and smoothing). Default: `()` for a model
        without state (a static friction law), `None` otherwise."""
        return () if not jax.tree_util.tree_leaves(self.init_state()) else None

    @abc.abstractmethod
    def samples(self, inputs: Any) -> Any:
        """The per-step signals of `inputs` (leaves of shape `(T, ...)`, or scalars constant over the record)."""

    @abc.abstractmethod
    def check_inputs(self, inputs: Any) -> None:
        """Raise a clear error when `inputs` lacks what `step` needs (structure only, never values)."""


def feeds_back(model: AbstractModel) -> bool:
    """True when teacher forcing changes `model`'s state: it overrides `feedback` (its state holds past
    outputs), or, for a model made of members (ensembles), one of its members does."""
    members = getattr(model, "members", None)
    if members is not None:
        return any(feeds_back(member) for member in members)
    return type(model).feedback is not AbstractModel.feedback


MOTION_SIGNALS = frozenset({"x", "v", "dx", "dt", "a", "normal_force"})  # what `requires` may name
NEGLIGIBLE = 1e-3  # a fraction of the force or of the elements below which a part of a model does nothing
FS_BELOW_FC = "Fs < Fc (a Stribeck curve falling towards standstill)"


class AbstractFrictionModel(AbstractModel):
    """A friction model: motion in (`fj.Motion`), friction force [N] out.

    `step(state, sample: MotionSample) -> (state, force)` advances one sample and returns the friction force at
    the end of the step. `requires` names the signals `step` reads: `"x"` (displacement or its increment),
    `"v"` (velocity), `"dt"` (the sample time, for time integration), `"a"` (acceleration), `"normal_force"`.
    """

    @abc.abstractmethod
    def step(self, state: Any, sample: MotionSample) -> tuple[Any, Array]:
        """One sample: `(state_k-1, sample_k) -> (state_k, force_k)`."""

    def samples(self, inputs: Motion) -> MotionSample:
        return inputs.samples(self.requires)

    # What only a model family knows, asked by generic code (the tribometer, the demo, compare's notes and recipes)
    # instead of switching on classes; each default says "none" and the families override it (DESIGN.md, v4).

    drifts: ClassVar[bool] = False  # a force sensor's drift around the friction model (`fj.SensorDrift`)
    presliding: ClassVar[bool] = False  # a pre-sliding stiffness (read off a record's reversals)
    has_elements: ClassVar[bool] = False  # elements whose count a record may set (`fj.element_count`)
    replaces_small_elements: ClassVar[bool] = False  # a second start without its small elements (`fj.initial_guess`)

    @classmethod
    def start_from_scales(
        cls, reader: Any, *, elements: int, smoothing: Any, without_small_elements: bool = False
    ) -> Sequence[AbstractFrictionModel] | None:
        """Starting models of this family read off records (`fj.initial_guess`): `reader.scales` holds the record's
        scales (`fj.RecordScales`: offset, Fc, Fs, vs, Fv, stiffness, `thresholds(n)`), and `reader` the readings of
        the estimation layer (`maxwell_elements`, `linkage_gap`, `screen_gms_sliding_law`,
        `replace_small_elements`). None: the family has no data-driven start."""
        return None

    def without_drift(self) -> AbstractFrictionModel:
        """The model without its sensor drift (itself where it has none)."""
        return self

    def breakaway_displacement(self) -> float | None:
        """The displacement scale [m] over which the model goes from sticking to gross sliding; None where it has
        no pre-sliding scale."""
        return None

    def breakaway_force(self) -> float | None:
        """The static (breakaway) force [N]; None where the model has none."""
        return None

    def force_offset(self) -> float:
        """The constant force [N] the model adds (its `offset` field; 0 without one)."""
        offset = getattr(self, "offset", None)
        return 0.0 if offset is None else float(jax.numpy.asarray(offset))

    @property
    def num_elements(self) -> int | None:
        """The number of elements of a multi-element model (GMS, Maxwell-slip); None for others."""
        return None

    def slipping(self, state: Any, new_state: Any, sample: MotionSample) -> Array | None:
        """Per element, 1.0 where it slips in the step from `state` to `new_state`; None without elements."""
        return None

    def smoothing_scale(self) -> float:
        """A smoothing width that is small for this family, in the unit it smooths (velocity: 1e-8 m/s)."""
        return 1e-8

    def stribeck_levels(self) -> tuple[Any, Any]:
        """The Coulomb and static levels `(Fc, Fs)` [N] of the model's Stribeck curve, or None where it has none."""
        stribeck = getattr(self, "stribeck", None)
        levels = stribeck if stribeck is not None and hasattr(stribeck, "Fs") else self
        return getattr(levels, "Fc", None), getattr(levels, "Fs", None)

    def implausible(self, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
        """What is implausible in the model's values once fitted (empty when nothing is): here a Stribeck curve whose
        static level is below its Coulomb level (`Fs < Fc`); families add their own (a damping held at its bound
        0, elements that carry no force or never slip on a record whose reversals span `record_excursion` [m]).
        `bounds=False` leaves out the "held at its bound" notes. Call it on the unwrapped model (`fj.unwrap`)."""
        Fc, Fs = self.stribeck_levels()
        if Fc is not None and Fs is not None and bool(jax.numpy.any(jax.numpy.asarray(Fs) < jax.numpy.asarray(Fc))):
            return [FS_BELOW_FC]
        return []

    def held_at_zero(self, names: tuple[str, ...], bounds: bool) -> list[str]:
        """The notes for the coefficients `names` that a fit left at their bound 0 (none with `bounds=False`)."""
        if not bounds:
            return []
        return [f"{name} = 0 (held at its bound)" for name in names if float(jax.numpy.min(getattr(self, name))) <= 0.0]

    def check_inputs(self, inputs: Any) -> None:
        name = type(self).__name__
        if not isinstance(inputs, Motion):
            raise TypeError(
                f"simulate: {name} takes a fricjax.Motion, got {type(inputs).__name__}; "
                "wrap your arrays as fj.Motion(x=..., v=..., dt=...)."
            )
        signal = inputs.x if inputs.x is not None else inputs.v
        if signal is not None and signal.ndim != 1:
            raise ValueError(
                f"simulate: the motion's signals must have shape (T,), got {signal.shape}; "
                "for a batch of motions use jax.vmap(lambda m: fj.simulate(model, m))(motions)."
            )
        needs = self.requires
        unknown = sorted(set(needs) - MOTION_SIGNALS)
        if unknown:
            raise ValueError(
                f"simulate: {name}.requires names {', '.join(map(repr, unknown))}, not a signal of a motion sample; "
                f"use {', '.join(map(repr, sorted(MOTION_SIGNALS)))} (the fields of fj.MotionSample)."
            )
        if "dt" in needs and inputs.dt is None:
            raise ValueError(
                f"simulate: {name} integrates in time and needs the sample time; pass Motion(..., dt=...)."
            )
        if "x" in needs and inputs.x is None and inputs.dt is None:
            raise ValueError(
                f"simulate: {name} needs the displacement `x`; the motion has only `v` and no `dt` to integrate it. "
                "Pass Motion(x=...) or Motion(v=..., dt=...)."
            )
        if "v" in needs and inputs.v is None and inputs.dt is None:
            raise ValueError(
                f"simulate: {name} needs the velocity `v`; the motion has only `x` and no `dt` to differentiate it. "
                "Pass Motion(v=...) or Motion(x=..., dt=...)."
            )
        if "a" in needs and inputs.a is None and inputs.dt is None:
            raise ValueError(f"simulate: {name} needs the acceleration; pass Motion(a=...) or Motion(..., dt=...).")
        if "normal_force" in needs and inputs.normal_force is None:
            raise ValueError(f"simulate: {name} needs the normal load; pass Motion(..., normal_force=...) [N].")


class AbstractSystem(AbstractModel):
    """A system model (a plant with its controller and friction): an `fj.InputRecord` in, any pytree out.

    `requires` names the input signals `step` reads; each step sees a dict `{name: value_k, "dt": dt}`.
    """

    def samples(self, inputs: InputRecord) -> dict[str, Array]:
        return inputs.samples()

    def check_inputs(self, inputs: Any) -> None:
        name = type(self).__name__
        if not isinstance(inputs, InputRecord):
            raise TypeError(
                f"simulate: {name} takes a fricjax.InputRecord(dt=..., "
                + ", ".join(f"{signal}=..." for signal in sorted(self.requires))
                + f"), got {type(inputs).__name__}."
            )
        missing = sorted(set(self.requires) - set(inputs.signals))
        if missing:
            raise ValueError(
                f"simulate: {name} needs the input signals {missing}; the record has {sorted(inputs.signals)}."
            )
