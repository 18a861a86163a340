"""Several records in one fit: a padded batch (`RecordBatch`), the per-record nuisances (`Nuisances`: force offset,
sensor drift, initial state) and the loss that scores every record by its own force spread (`RecordsLoss`).

A real rig gives many records (amplitudes, frequencies, loads, days) of one device. Their model parameters are
shared, but each record has its own force-cell offset, possibly its own sensor drift, and starts from its own
state (a hysteretic model's memory at the first sample). `fj.fit(model, [record, ...])` estimates the shared
parameters and these per-record nuisances jointly: the records are padded to one length and simulated side by side
by `jax.vmap` (one compiled program, no Python loop over records), the padding masked out of the loss, and the loss
is the mean over records of each record's NMSE (each normalised by its own force variance), so a loss of 0.01 is a
mean NMSE of 1 %.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._constraints import compact_value, unwrap
from ..._data._record import FrictionData
from ..._inputs import Motion
from ..._metrics import scaled_std
from ..._models._base import AbstractModel, feeds_back
from ..._simulate import check_force_shape, run
from ..._smoothing import is_concrete
from ..._validation import got_model, same_sample_time
from ._losses import AbstractLoss, JacobianGroups, OneStepLoss, leading_groups

__all__ = [
    "Nuisances",
    "RecordBatch",
    "RecordNuisances",
    "RecordsLoss",
    "as_record_batch",
]


class Nuisances(eqx.Module):
    """Which per-record nuisance parameters a fit to several records estimates beside the shared model
    parameters.

    - `offset`: the force-cell offset of each record [N] (default True). The model's own `offset` fields are then
      held at their initial values (one offset per record replaces them), as, with `initial_state`, the fields that
      only set the state at rest (LuGre `z0`, Dahl `F0`).
    - `drift`: a linear sensor drift of each record [N/s], zero at the record's first sample (default False: a
      drift is a property of one record and is never carried to another).
    - `initial_state`: each record's initial state (the model's memory at the first sample; default True), as
      `init_state() + delta * scale`, with `scale` the RMS of the state along the record under the initial model.
    """

    offset: bool = eqx.field(static=True, default=True)
    drift: bool = eqx.field(static=True, default=False)
    initial_state: bool = eqx.field(static=True, default=True)

    def __check_init__(self) -> None:
        for name in ("offset", "drift", "initial_state"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"Nuisances: `{name}` must be True or False, got {getattr(self, name)!r}.")


class RecordBatch(eqx.Module):
    """Records of different lengths as one padded batch (leading axis: record), for `jax.vmap`.

    - `data`: a `FrictionData` whose signals have shape `(R, T)` (`T` the longest record; shorter ones are padded
      at the end by holding the last position at rest, velocity 0); `dt` has shape `(R,)` (equal values).
    - `mask`: `(R, T)` bool, the samples that are scored (padding and any unscored head excluded).
    - `scale`: `(R,)` each record's force spread (std) over its scored samples [N].
    - `lengths`: each record's length in samples; `names`: labels of the records (for reports).

    Build it with `RecordBatch.from_records(records, score_from=..., names=...)`; `fj.fit` builds it from a list.
    """

    data: FrictionData
    mask: Array
    scale: Array
    lengths: tuple[int, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)

    @classmethod
    def from_records(
        cls,
        records: Sequence[FrictionData],
        *,
        score_from: Sequence[int] | None = None,
        names: Sequence[str] | None = None,
        requires: frozenset[str] = frozenset(),
        argument: str = "data",
    ) -> RecordBatch:
        """Pad and stack `records` (one sample time). `score_from`: per record, the first scored sample (the
        samples before it are simulated, not scored: the validation part of a record simulated from its start).
        `requires`: the signals the model reads (`"a"` and `"normal_force"` are kept where asked)."""
        records = list(records)
        if not records:
            raise ValueError(f"fit: `{argument}` is an empty list; give at least one fj.FrictionData record.")
        names = tuple(str(n) for n in names) if names is not None else tuple(f"record {i}" for i in range(len(records)))
        if len(names) != len(records):
            raise ValueError(f"fit: {len(names)} names for {len(records)} records in `{argument}`.")
        for name, record in zip(names, records, strict=True):
            if not isinstance(record, FrictionData):
                raise TypeError(
                    f"fit: {name} of `{argument}` is a {type(record).__name__}; every record must be an "
                    "fj.FrictionData(motion, force)."
                )
            if record.force.ndim != 1:
                raise ValueError(f"fit: {name} of `{argument}` has force of shape {record.force.shape}; give (T,).")
        dts = [None if r.motion.dt is None else float(np.asarray(r.motion.dt)) for r in records]
        if any(dt is None for dt in dts):
            missing = names[dts.index(None)]
            raise ValueError(f"fit: {missing} of `{argument}` has no sample time; build its Motion with dt=... [s].")
        reference = dts[0]
        for name, dt in zip(names, dts, strict=True):
            assert dt is not None and reference is not None
            if not same_sample_time(dt, reference):
                raise ValueError(
                    f"fit: {name} of `{argument}` is sampled at dt = {dt:.9g} s, {names[0]} at {reference:.9g} s; "
                    "records fitted together need one sample time: resample them first (scipy.signal.resample_poly)."
                )
        with_normal = [r.motion.normal_force is not None for r in records]
        if "normal_force" in requires and not all(with_normal):
            missing = names[with_normal.index(False)]
            raise ValueError(
                f"fit: the model needs the normal load and {missing} of `{argument}` has none; load it with "
                "normal_force_column=... or pass Motion(..., normal_force=...)."
            )
        if "normal_force" in requires:
            for name, record in zip(names, records, strict=True):
                check_load(record, f"{name} of `{argument}`", "fit")
        lengths = tuple(r.length for r in records)
        starts = [0] * len(records) if score_from is None else [int(s) for s in score_from]
        for name, start, length in zip(names, starts, lengths, strict=True):
            if not 0 <= start < length:
                raise ValueError(f"fit: {name} of `{argument}` scores from sample {start} of {length}: nothing left.")
        total = max(lengths)
        padded = [padded_record(r, total, requires, all(with_normal)) for r in records]
        data = jax.tree_util.tree_map(
            lambda *leaves: jax.device_put(np.stack([np.asarray(a) for a in leaves])), *padded
        )
        index = np.arange(total)
        mask = np.stack([(index >= s) & (index < n) for s, n in zip(starts, lengths, strict=True)])
        scale = np.array(
            [float(scaled_std(np.asarray(r.force)[s:])) for r, s in zip(records, starts, strict=True)], dtype=float
        )
        for name, value in zip(names, scale, strict=True):
            if not value > 0:
                raise ValueError(
                    f"fit: the measured force of {name} in `{argument}` is constant over its scored samples (std = 0); "
                    "drop the record or check its force column."
                )
        dtype = np.dtype(jnp.asarray(records[0].force).dtype)
        return cls(data, jax.device_put(mask), jax.device_put(scale.astype(dtype)), lengths, names)

    @property
    def count(self) -> int:
        """Number of records R."""
        return len(self.lengths)

    @property
    def length(self) -> int:
        """The padded length T."""
        return int(self.mask.shape[1])

    def record(self, index: int) -> FrictionData:
        """Record `index` unpadded."""
        one = jax.tree_util.tree_map(lambda a: a[index], self.data)
        m = one.motion
        cut = slice(0, self.lengths[index])
        motion = Motion(
            x=m.x[cut],
            v=m.v[cut],
            dt=m.dt,
            a=None if m.a is None else m.a[cut],
            normal_force=None if m.normal_force is None else m.normal_force[cut],
        )
        return FrictionData(motion, one.force[cut])


def padded_record(record: FrictionData, total: int, requires: frozenset[str], normal: bool) -> FrictionData:
    """`record` with its position, velocity (and acceleration where the model reads it) derived once at its own
    length, then padded to `total` samples at rest (last position held, velocity 0); its normal load with `normal`
    (every record of the batch holds one). All on the host (NumPy): no XLA program per record length."""
    x, v, a, load = record.motion.host_signals((requires & {"a"}) | ({"normal_force"} if normal else set()))
    extra = total - record.length

    def hold(signal: Any) -> Any:
        return None if signal is None else np.concatenate([signal, np.broadcast_to(signal[-1:], (extra,))])

    def zero(signal: Any) -> Any:
        return None if signal is None else np.concatenate([signal, np.zeros((extra,), signal.dtype)])

    motion = Motion(x=hold(x), v=zero(v), dt=record.motion.dt, a=zero(a), normal_force=hold(load))
    return FrictionData(motion, hold(np.asarray(record.force)))


def check_records(model: Any, data: Any, validation: Any, loss: Any, where: str = "fit") -> None:
    """The model is a fricjax model, and `data` / `validation` are records it can read (their type, the signals
    its step needs, a force it can score): `where` names the entry point in the message."""
    if not isinstance(model, eqx.Module):
        raise TypeError(f"{where}: `model` must be a fricjax model (an equinox Module), got {got_model(model)}.")
    data_type = getattr(loss, "data_type", FrictionData)
    for name, value in (("data", data), ("validation", validation)):
        if value is not None and not isinstance(value, data_type):
            raise TypeError(
                f"{where}: `{name}` must be a {data_type.__name__} for {type(loss).__name__}, "
                f"got {type(value).__name__}"
                + (" (wrap motion and force as fj.FrictionData(motion, force))." if data_type is FrictionData else ".")
            )
    if isinstance(model, AbstractModel):  # the signals the model needs are in the records (dt, x / v, ...)
        for name, record in (("data", data), ("validation", validation)):
            if isinstance(record, FrictionData):
                model.check_inputs(record.motion)
                if "normal_force" in model.requires:
                    check_load(record, f"`{name}`", where)
        if isinstance(data, FrictionData):  # one model, one trace of its step: the data's motion suffices
            check_force_shape(model, data.motion)
    for name, record in (("data", data), ("validation", validation)):
        if isinstance(record, FrictionData) and getattr(loss, "normalise", False) and is_concrete(record.force):
            if not float(scaled_std(np.asarray(record.force))) > 0:  # scaled: 1e-200 N is not constant
                raise ValueError(
                    f"{where}: the measured force of `{name}` is constant (std = 0), so the normalised loss (error / "
                    "std) is undefined; check the record, or use a loss with normalise=False."
                )


def check_load(record: FrictionData, name: str, where: str) -> None:
    """Refuse a record whose normal load is 0 in every sample, for a model that scales its force with it: the model
    predicts no force there and its gradient is 0, so a fit ends where it started without a word."""
    load = record.motion.normal_force
    if load is not None and is_concrete(load) and not np.any(np.asarray(load)):
        raise ValueError(
            f"{where}: the normal load of {name} is 0 N in every sample, so a load-scaled model predicts no force "
            "there and cannot be fitted; check the load column and its unit, or drop the record."
        )


def check_burn_in(loss: Any, records: Any, argument: str, where: str, option: str | None = None) -> None:
    """Refuse a loss whose unscored head (`burn_in`) covers a whole record of `records` (a `FrictionData` or a
    `RecordBatch`): such a record would score nothing, and count as a perfect fit or make the loss NaN. `option`:
    the argument that set the burn-in (default: the loss's own)."""
    inner = loss.loss if isinstance(loss, RecordsLoss) else loss
    burn_in = int(getattr(inner, "burn_in", 0) or 0)
    option = f"the loss's burn_in ({type(inner).__name__}(burn_in=...))" if option is None else f"`{option}`"
    if isinstance(records, FrictionData):
        named = [(f"`{argument}`", records.length)]
    elif isinstance(records, RecordBatch):
        pairs = zip(records.names, records.lengths, strict=True)
        named = [(f"{name} of `{argument}`", length) for name, length in pairs]
    else:
        return
    for name, length in named:
        if burn_in >= length:
            raise ValueError(
                f"{where}: {option} leaves {burn_in} samples unscored, all of {name} ({length} samples), so it "
                "would score nothing; lower it or pass a longer record."
            )


def as_record_batch(value: Any, model: Any, argument: str, score_from: Sequence[int] | None = None) -> Any:
    """`value` as a `RecordBatch` where it is a list / tuple of records, or a dict `{name: record}` (the names label
    the records in reports); a `RecordBatch` as it is."""
    names = None
    if isinstance(value, dict):
        names, value = [str(name) for name in value], list(value.values())
    if isinstance(value, RecordBatch) or not isinstance(value, (list, tuple)):
        return value
    if isinstance(model, AbstractModel):
        for index, record in enumerate(value):
            if isinstance(record, FrictionData):
                try:
                    model.check_inputs(record.motion)
                    if index == 0:
                        check_force_shape(model, record.motion)
                except ValueError as err:  # which record: "simulate: ..." says only what is missing
                    label = repr(names[index]) if names is not None else f"record {index}"
                    raise ValueError(f"fit: {label} of `{argument}`: {str(err).removeprefix('simulate: ')}") from None
            else:
                raise TypeError(
                    f"fit: record {index} of `{argument}` is a {type(record).__name__}; every record must be an "
                    "fj.FrictionData(motion, force)."
                )
    requires = frozenset(getattr(model, "requires", frozenset()))
    return RecordBatch.from_records(value, score_from=score_from, names=names, requires=requires, argument=argument)


# ----------------------------------------------------------------------------------------------------------------
# the model as it sees one record
# ----------------------------------------------------------------------------------------------------------------


class RecordedModel(AbstractModel):
    """`model` as it reads on one record: starting from `state0`, its force plus the record's `offset` [N] and
    drift `rate * t` [N/s] (t = 0 at the record's first sample). Teacher forcing feeds the model the measurement
    less offset and drift."""

    model: Any
    state0: Any
    offset: Array
    rate: Array

    @property
    def requires(self) -> frozenset[str]:  # type: ignore[override]
        return frozenset(getattr(self.model, "requires", frozenset())) | {"dt"}

    def init_state(self) -> Any:
        zero = jnp.zeros((), self.offset.dtype)
        return self.state0, zero, zero  # the model's state, the time of the next sample [s], the last nuisance [N]

    def samples(self, inputs: Any) -> Any:
        return self.model.samples(inputs)

    def check_inputs(self, inputs: Any) -> None:
        self.model.check_inputs(inputs)

    def step(self, state: Any, sample: Any) -> tuple[Any, Any]:
        inner, t, _ = state
        inner, force = self.model.step(inner, sample)
        nuisance = self.offset + self.rate * t
        return (inner, t + sample.dt, nuisance), force + nuisance

    def feedback(self, state: Any, y_measured: Any) -> Any:
        inner, t, nuisance = state
        return self.model.feedback(inner, y_measured - nuisance), t, nuisance


class RecordExtra(eqx.Module):
    """The per-record decision variables of a fit to several records, in units of each record's force spread:
    `offset` (R,), `rate` (R,) (drift over the record's duration) or None, `state` (the initial-state deltas, leaves
    (R, ...)) or None, and `inner` (the wrapped loss's own extra, per record) or None."""

    offset: Array | None
    rate: Array | None
    state: Any
    inner: Any


class RecordsLoss(AbstractLoss):
    """A friction loss (`SimulationLoss`, `OneStepLoss`, `MultipleShootingLoss`) summed over a `RecordBatch`: every
    record simulated side by side (`jax.vmap`), each with its own nuisances (`Nuisances`), each record's errors
    divided by its own force spread, the padding masked out. The value is the mean over records of each record's
    NMSE of `loss`. `fj.fit` builds it when given a list of records.

    Without `extra` (the validation score) each record's offset is its least-squares value (the mean error over
    its scored samples) and its state the model's own initial state.
    """

    loss: AbstractLoss
    nuisances: Nuisances = Nuisances()
    state_scale: Any = None  # leaves (R, ...): RMS of each state leaf along each record under the initial model
    data_type = RecordBatch  # type: ignore[assignment]

    def __check_init__(self) -> None:
        if type(self.loss).scaled_residuals is AbstractLoss.scaled_residuals:  # its error names the losses that do
            self.loss.scaled_residuals(None, None, None, jnp.ones(()), None)

    def validation_loss(self) -> AbstractLoss:
        return RecordsLoss(self.loss.validation_loss(), self.nuisances)

    def bind(self, model: Any, batch: RecordBatch) -> RecordsLoss:
        """This loss with the initial-state scales of `model` on `batch` (the RMS of each state leaf along each
        record, from one simulation)."""
        return self.bind_and_start(model, batch)[0]

    def bind_and_start(self, model: Any, batch: RecordBatch) -> tuple[RecordsLoss, RecordExtra]:
        """`bind(model, batch)` and the bound loss's `init_extra(model, batch)` from one simulation of every record,
        in one compiled program (what `fj.fit` and `fj.sweep` call)."""
        if isinstance(self.loss, OneStepLoss) and not feeds_back(unwrap(model)):
            self.loss.residuals(model, None, batch.record(0))  # the loss's own error (no fed-back outputs)
        scales, extra = _bound_start(self, unwrap(model), batch)
        return dataclasses.replace(self, state_scale=scales), extra

    def init_extra(self, model: Any, batch: RecordBatch) -> RecordExtra:
        return _initial_extra(self, unwrap(model), batch)

    def jacobian_groups(self, extra: Any, batch: RecordBatch) -> JacobianGroups | None:
        """Record i's residuals (one equal block each, in record order) depend on the shared parameters and on
        record i's nuisances only (every leaf of `extra` has the records along its first axis)."""
        if not jax.tree_util.tree_leaves(extra):
            return None
        count = batch.count
        return JacobianGroups(rows=lambda n: [(0, n, n // count, 0)], columns=leading_groups(extra))

    def _init_extra(self, physical: Any, batch: RecordBatch, forces: Array | None = None) -> RecordExtra:
        """The starting nuisances (inside a compiled program); `forces`: the initial model's run, if made."""
        if forces is None:
            forces, _ = _record_states(physical, batch, states=False)
        count = jnp.maximum(jnp.sum(batch.mask, axis=1), 1)
        offset = None
        if self.nuisances.offset:  # least-squares offsets of the initial model
            offset = jnp.sum(jnp.where(batch.mask, batch.data.force - forces, 0.0), axis=1) / count / batch.scale
        rate = jnp.zeros_like(batch.scale) if self.nuisances.drift else None
        state = None
        if self.nuisances.initial_state:
            state = jax.tree_util.tree_map(
                lambda s: None if s is None else jnp.zeros_like(s), self.state_scale, is_leaf=lambda x: x is None
            )
        extras = None
        if type(self.loss).init_extra is not AbstractLoss.init_extra:
            partial = RecordExtra(offset, rate, state, None)

            def one(record: FrictionData, index: Array) -> Any:
                return self.loss.init_extra(self._recorded(physical, partial, batch, index), record)

            extras = jax.vmap(one)(batch.data, jnp.arange(batch.count))
        return RecordExtra(offset, rate, state, extras)

    def _recorded(self, model: Any, extra: RecordExtra | None, batch: RecordBatch, index: Array) -> RecordedModel:
        """The model as it reads on record `index` (inside the vmap over records: `index` traced)."""
        scale = batch.scale[index]
        zero = jnp.zeros((), batch.scale.dtype)
        state0 = model.init_state()
        offset, rate = zero, zero
        if extra is not None:
            if extra.offset is not None:
                offset = extra.offset[index] * scale
            if extra.rate is not None:
                duration = jnp.asarray(batch.lengths, scale.dtype)[index] * jnp.asarray(batch.data.motion.dt)[index]
                rate = extra.rate[index] * scale / duration
            if extra.state is not None and self.state_scale is not None:
                state0 = jax.tree_util.tree_map(
                    lambda s, d, c: s if d is None else s + d[index] * c[index],
                    state0,
                    extra.state,
                    self.state_scale,
                    is_leaf=lambda x: x is None,
                )
        return RecordedModel(model, state0, offset, rate)

    def residuals(self, model: Any, extra: Any, batch: RecordBatch) -> Array:
        physical = unwrap(model)
        positions = self.loss.scored_samples(batch.length)
        window = jnp.zeros(batch.length, bool).at[positions].set(True)
        scored = batch.mask & window
        counts = jnp.maximum(jnp.sum(scored, axis=1), 1).astype(batch.scale.dtype)
        width = len(range(batch.length)[positions])
        # each record's errors divided by its spread and by sqrt(its share of the positions): the mean of the
        # squared residuals is the mean of the records' NMSEs
        scales = batch.scale * jnp.sqrt(counts / width)

        def one(record: FrictionData, mask: Array, scale: Array, index: Array, inner: Any) -> Array:
            recorded = self._recorded(physical, extra, batch, index)
            return self.loss.scaled_residuals(recorded, inner, record, scale, mask)

        inner = None if extra is None else extra.inner
        in_axes = (0, 0, 0, 0, None if inner is None else 0)
        residuals = jax.vmap(one, in_axes=in_axes)(batch.data, scored, scales, jnp.arange(batch.count), inner)
        if extra is None and self.nuisances.offset:  # validation: each record's least-squares offset
            errors = residuals[:, :width]
            weights = scored[:, positions].astype(errors.dtype)
            mean = jnp.sum(errors * weights, axis=1, keepdims=True) / counts[:, None]
            residuals = residuals.at[:, :width].add(-mean * weights)
        return residuals.reshape(-1)


@eqx.filter_jit
def _bound_start(loss: RecordsLoss, model: Any, batch: RecordBatch) -> tuple[Any, RecordExtra]:
    """The initial-state scales of `model` on `batch` (the RMS of each state leaf along each record over its scored
    samples: leaves (R, ...), None for leaves that are not inexact arrays; None without initial-state nuisances)
    and the bound loss's starting nuisances, from one run of the initial model along every record."""
    if not loss.nuisances.initial_state:
        return None, loss._init_extra(model, batch)
    forces, states = _record_states(model, batch)

    def rms(leaf: Array) -> Array:
        mask = batch.mask.reshape(batch.mask.shape + (1,) * (leaf.ndim - 2)).astype(leaf.dtype)
        mean = jnp.sum(mask * leaf**2, axis=1) / jnp.maximum(jnp.sum(mask, axis=1), 1.0)
        return jnp.sqrt(mean) + 1e-30

    scales = jax.tree_util.tree_map(lambda leaf: rms(leaf) if eqx.is_inexact_array(leaf) else None, states)
    return scales, dataclasses.replace(loss, state_scale=scales)._init_extra(model, batch, forces)


@eqx.filter_jit
def _initial_extra(loss: RecordsLoss, model: Any, batch: RecordBatch) -> RecordExtra:
    """`RecordsLoss.init_extra` as one compiled program (the initial model's run along every record included)."""
    return loss._init_extra(model, batch)


def _record_states(model: Any, batch: RecordBatch, states: bool = True) -> tuple[Array, Any]:
    """The initial model's forces (R, T) and, with `states`, its states (leaves (R, T, ...)) along every record
    (inside a compiled program)."""

    def one(record: FrictionData) -> Any:
        samples = model.samples(record.motion)
        _, out = run(model, samples, model.init_state(), return_states=states)
        return out if states else (out, None)

    forces, trajectory = jax.vmap(one)(batch.data)
    return forces, trajectory


@dataclasses.dataclass(frozen=True)
class RecordNuisances:
    """The per-record nuisances a fit to several records estimated, in SI units: `names`; `offset` [N] (R,) or
    None; `drift` [N/s] (R,) or None; `initial_state` (the model's state pytree, leaves (R, ...)) or None;
    `train_nmse` (R,) each record's training NMSE [%] (as `fj.nmse`)."""

    names: tuple[str, ...]
    offset: np.ndarray | None
    drift: np.ndarray | None
    initial_state: Any
    train_nmse: np.ndarray

    def lines(self, force_unit: str = "N", newtons_per_unit: float = 1.0) -> list[str]:
        """One line per record: its name, training NMSE and the nuisances estimated, offset and drift in
        `force_unit` (`newtons_per_unit` N each; default N, N/s), and the model's initial state (SI units of its
        fields: LuGre's `z` in m)."""
        out = []
        for row in self.table():
            text = f"{row['name']}: train NMSE {row['train_nmse_percent']:.4g} %"
            if row["offset_N"] is not None:
                text += f", offset {row['offset_N'] / newtons_per_unit:.4g} {force_unit}"
            if row["drift_N_per_s"] is not None:
                text += f", drift {row['drift_N_per_s'] / newtons_per_unit:.4g} {force_unit}/s"
            if row["initial_state"]:
                text += ", initial state " + ", ".join(
                    f"{name} {compact_value(value)}" for name, value in row["initial_state"].items()
                )
            out.append(text)
        return out

    def table(self) -> list[dict[str, Any]]:
        """One row per record: `name`, `offset_N`, `drift_N_per_s`, `train_nmse_percent`, `initial_state` ({field of
        the model's state: its value(s) on this record}; empty when none was estimated)."""
        rows = []
        leaves = [] if self.initial_state is None else jax.tree_util.tree_leaves_with_path(self.initial_state)
        for i, name in enumerate(self.names):
            rows.append(
                {
                    "name": name,
                    "offset_N": None if self.offset is None else float(self.offset[i]),
                    "drift_N_per_s": None if self.drift is None else float(self.drift[i]),
                    "train_nmse_percent": float(self.train_nmse[i]),
                    "initial_state": {
                        jax.tree_util.keystr(path).lstrip("."): np.asarray(leaf)[i].tolist()
                        for path, leaf in leaves
                        if np.ndim(leaf) >= 1 and np.shape(leaf)[0] == len(self.names)
                    },
                }
            )
        return rows


def record_nuisances(loss: RecordsLoss, model: Any, extra: RecordExtra, batch: RecordBatch) -> RecordNuisances:
    """The nuisances of a fitted `model` in SI units, with each record's training NMSE."""
    offset, drift, state, nmse = jax.tree_util.tree_map(np.asarray, _nuisance_values(loss, model, extra, batch))
    return RecordNuisances(
        batch.names,
        offset if extra.offset is not None else None,
        drift if extra.rate is not None else None,
        state if extra.state is not None else None,
        100 * nmse,  # [%]
    )


@eqx.filter_jit
def _nuisance_values(loss: RecordsLoss, model: Any, extra: RecordExtra, batch: RecordBatch) -> tuple[Any, ...]:
    """Every record's offset [N], drift [N/s], initial state (leaves (R, ...)) and training NMSE, in one program."""
    physical = unwrap(model)

    def one(index: Array) -> tuple[Any, ...]:
        recorded = loss._recorded(physical, extra, batch, index)
        return recorded.offset, recorded.rate, recorded.state0

    offset, rate, state = jax.vmap(one)(jnp.arange(batch.count))
    return offset, rate, state, record_nmse(loss, model, extra, batch)


@eqx.filter_jit
def record_nmse(loss: RecordsLoss, model: Any, extra: Any, batch: RecordBatch) -> Array:
    width = len(range(batch.length)[loss.loss.scored_samples(batch.length)])
    residuals = loss.residuals(model, extra, batch).reshape(batch.count, -1)[:, :width]
    # a record's residuals are its errors / (spread * sqrt(scored / width)): their squares sum to width x its NMSE
    return jnp.sum(residuals**2, axis=1) / width


# ----------------------------------------------------------------------------------------------------------------
# test-time initialisation
