"""What `compare` is configured by: the scales of the training record that starting models are built from
(`DataScales`), the budgets and model sizes (`FitSettings`), what the fits' result codes mean (`RESULT_CODES`),
and the one-line error for bad input (`CompareError`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..._data._record import FrictionData, concatenate
from ..._estimation.initial._record_scales import as_records
from ..._validation import nonnegative_float, positive_int


@dataclasses.dataclass(frozen=True)
class DataScales:
    """Scales read off a training record, used to build starting models.

    `force` [N]: half the 1-99 % range of the force; `Fc`, `Fs` [N]: the median and the 99.5 % level of
    |F| while sliding; `vs` [m/s]: a velocity below which sliding is rare; `stiffness` [N/m]: the typical
    |dF/dx| right after reversals (pre-sliding); `breakaway` [m] = Fs / stiffness; `dx` [m]: the median step;
    `duration` [s]: the record's length; `v_fast` [m/s]: the 90 % level of |v| (the fast end of the record);
    `train`: the record itself (black-box models normalise by it); `records`: the training records one by one
    where there are several (the train part joined end to end is `train`).
    """

    force: float
    Fc: float
    Fs: float
    vs: float
    stiffness: float
    breakaway: float
    dx: float
    duration: float = 1.0
    v_fast: float = 1e-3
    train: FrictionData | None = dataclasses.field(default=None, repr=False, compare=False)
    records: tuple[FrictionData, ...] = dataclasses.field(default=(), repr=False, compare=False)

    @classmethod
    def from_data(cls, data: FrictionData | Sequence[FrictionData]) -> DataScales:
        """The scales of a record, or of several records of one device (a list, a dict of them or an
        `fj.RecordBatch`: each record read on its own, its force centred on its own median, the readings pooled, so
        that their order and the seams between them do not count; `train` is then the records joined end to end and
        `records` holds them one by one)."""
        records = as_records(data, "DataScales.from_data")
        signals = [(np.asarray(s.x), np.asarray(s.v)) for s in (r.motion.samples() for r in records)]
        x_of, v_of = [x for x, _ in signals], [v for _, v in signals]
        force_of = [np.asarray(r.force) - np.median(np.asarray(r.force)) for r in records]
        v, force = np.concatenate(v_of), np.concatenate(force_of)
        scale = 0.5 * float(np.percentile(force, 99) - np.percentile(force, 1))
        fast = np.abs(v) > np.percentile(np.abs(v), 70)
        Fc = float(np.median(np.abs(force[fast]))) if fast.any() else scale
        Fs = max(float(np.percentile(np.abs(force), 99.5)), 1.05 * Fc)
        vs = float(np.percentile(np.abs(v), 30)) or 1e-3
        window = 3
        dxw = np.concatenate([x[window:] - x[:-window] for x in x_of])
        dfw = np.concatenate([f[window:] - f[:-window] for f in force_of])
        moving = np.abs(dxw) > np.percentile(np.abs(dxw), 20) + 1e-15
        slopes = np.abs(dfw[moving] / dxw[moving])
        stiffness = float(np.percentile(slopes, 90)) if slopes.size else 0.0
        stiffness = stiffness if stiffness > 0 else max(scale, 1e-12) / 1e-5  # no force slope read: a guess
        steps = np.abs(np.concatenate([np.diff(x) for x in x_of]))
        dx = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1e-9
        duration = sum(r.length * float(np.asarray(r.motion.dt)) for r in records)
        v_fast = float(np.percentile(np.abs(v), 90)) or 1e-3
        several: tuple[FrictionData, ...] = tuple(records) if len(records) > 1 else ()
        train = concatenate(records) if several else records[0]
        return cls(scale, Fc, Fs, vs, stiffness, Fs / stiffness, dx, duration, v_fast, train, several)

    @property
    def parts(self) -> list[FrictionData]:
        """The training records one by one (one record: `[train]`; none: `[]`), for what is read off each record
        from its own start (`fj.initial_guess`)."""
        return list(self.records) or ([] if self.train is None else [self.train])


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """Budgets and model sizes of `compare` (the command line's `--steps`, `--gms-elements`,
    `--maxwell-elements`).

    - `steps`: the Levenberg-Marquardt step budget of every fit (GMS: twice that). An LM fit ends earlier, as
      converged (`successful`), when its training loss falls by less than `tolerance` (relative) over `steps / 8`
      steps (GMS: `steps / 4`; at least 5); `max_steps` means not converged.
    - `gms_elements`, `maxwell_elements`: the element counts of GMS and of Maxwell-slip NLR / DNLRX; GMS's
      `"auto"` (default): 4, or more where `fj.element_count` reads more off the training record (the fewest
      elements, 2-8, whose Maxwell-slip regression fits it within 2 % of the best count's residual) and the
      validation part prefers them significantly.
    - `starts`: starts of the Levenberg-Marquardt fits of the static curve, LuGre and Maxwell-slip (`--starts`):
      2 draws around the data-driven start (spread 0.5); more are drawn log-uniformly over a factor e either way,
      screened for a quarter of the steps in one vmap-ed program, and the best 2 (and the data-driven start)
      polished (`fj.MultiStart(keep=2)`).
    - `neural_steps`: the output-error (NOE) Adam steps of the neural models (`mlp`, `gsnn`, `rnn`, `avd`; see
      `neural_models`), after their teacher-forced stage.
    - `drift`: the force sensor's drift fitted with every model (`fj.SensorDrift`): `"linear"` (default),
      `"leaky"` (a leaky integrator, its time constant fitted from the training record's duration) or
      `"none"`. With several training records, a linear drift per record (a nuisance of the fit). A drift belongs
      to its record: on other records it is not carried (`test_drift`).
    - `init`: how a model starts on a test record it was not fitted on (`--init`): `"state"` the force offset and
      the model's initial state fitted on the initialisation window (`fj.initialise`), `"offset"` a run from rest
      with the mean error over the window as the offset.
    - `test_drift`: the drift on such test records: `"auto"` (default: carried to records of the built-in
      tribometer, whose simulated force cell drifts by the same law in every record, left out of file records,
      whose drift belongs to each record), `"none"` (left out), `"window"` (estimated on the window with the
      offset, `init="state"` only) or `"carry"` (the training record's drift model carried over, restarting at 0,
      scaled by the ratio of the force ranges the model predicts on the two records: a drift that is a fixed
      fraction of the range, as the tribometer's; records of equal length assumed, the tribometer's drift reaching
      its level at each record's end).
    - `fix`: `(name, value)` pairs: the parameter `name` (a field name or the end of a dotted path: `sigma2`,
      `stribeck.vs`) held at `value` (SI units) in every physics model that has it (`fj.Fixed`); `bounds`: `(name,
      low, high)` triples: the parameter kept inside `(low, high)` (`fj.Bounded`; a start outside moved inside).
    """

    steps: int = 40
    gms_elements: int | str = "auto"
    maxwell_elements: int = 5
    starts: int = 2
    tolerance: float = 1e-4
    drift: str = "linear"
    neural_steps: int = 600
    init: str = "state"
    test_drift: str = "auto"
    fix: tuple[tuple[str, float], ...] = ()
    bounds: tuple[tuple[str, float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.drift not in ("linear", "leaky", "none"):
            raise CompareError(f"`drift` must be linear, leaky or none, got {self.drift!r}")
        if self.init not in ("state", "offset"):
            raise CompareError(f"`init` must be state or offset, got {self.init!r}")
        if self.test_drift not in ("auto", "none", "window", "carry"):
            raise CompareError(f"`test_drift` must be auto, none, window or carry, got {self.test_drift!r}")
        object.__setattr__(self, "fix", tuple((str(n), float(v)) for n, v in self.fix))
        object.__setattr__(self, "bounds", tuple((str(n), float(lo), float(hi)) for n, lo, hi in self.bounds))
        for name, low, high in self.bounds:
            if not (np.isfinite(low) and np.isfinite(high) and low < high):
                raise CompareError(f"`bounds` {name}={low:g}:{high:g}: give finite LOW < HIGH")
        for name, value in self.fix:
            if not np.isfinite(value):
                raise CompareError(f"`fix` {name}={value}: give a finite value (SI units)")
        try:  # named as `CompareConfig`'s fields (the command line shows its flags: `as_flags`)
            for name in ("steps", "gms_elements", "maxwell_elements", "starts", "neural_steps"):
                if name == "gms_elements" and self.gms_elements == "auto":
                    continue
                hint = "(or auto)" if name == "gms_elements" else ""
                value = positive_int(getattr(self, name), name, "", hint=hint)
                object.__setattr__(self, name, value)
            object.__setattr__(self, "tolerance", nonnegative_float(self.tolerance, "tolerance", "FitSettings"))
        except ValueError as error:
            raise CompareError(str(error)) from None


RESULT_CODES = {
    "successful": "the solver stopped by its tolerance (converged)",
    "max_steps": "the step budget ran out first: not converged (raise --steps)",
    "early_stopped": "stopped when the validation loss stopped improving",
    "diverged": "the loss became non-finite; the last good model was kept",
}


class CompareError(ValueError):
    """A problem with the user's input to `compare`, reported as one line."""
