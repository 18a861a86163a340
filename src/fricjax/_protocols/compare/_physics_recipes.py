"""The physics models of `compare` (`physics_models`): a static Stribeck curve, LuGre, LuGre behind a linkage with
backlash, GMS and the Maxwell-slip NLR / DNLRX models, each started from the training record's scales (`DataScales`:
force levels, pre-sliding stiffness, breakaway displacement; the linkage's gap from `fj.initial_guess`; the
Maxwell-slip elements from `fj.initial_guess`'s regression or spread up to the breakaway displacement, the validation
part choosing; GMS from `fj.initial_guess` with screened starts) and fitted by Levenberg-Marquardt, with the linear
parameters solved by least squares where the model allows (static curve, LuGre, Maxwell-slip)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from ..._constraints import unwrap
from ..._estimation._fit import fit
from ..._estimation.initial._elements import element_count, maxwell_slip_elements
from ..._estimation.initial._initial_guess import initial_guess, initial_guesses
from ..._estimation.initial._record_scales import RecordScales
from ..._estimation.loop._levenberg_marquardt import levenberg_marquardt
from ..._estimation.loop._solution import FitResult
from ..._estimation.loop._strategies import Continuation, MultiStart, ParameterScaling
from ..._models.combine._wrapper import inner_friction, with_inner_friction, wrapper_path
from ..._models.physics._gms import GMS
from ..._models.physics._lugre import LuGre
from ..._models.physics._lugre_backlash import LuGreBacklash
from ..._models.physics._maxwell_slip import MaxwellSlip
from ..._models.physics._static import BoPavelescu
from ..._models.physics._stribeck import ExponentialStribeck
from ..._smoothing import Smooth
from ._recipes import ModelSpec, constrained, lm_recipe
from ._records import Split, TrainingRecords
from ._scoring import SIGNIFICANT_T, paired_validation_gain
from ._settings import DataScales, FitSettings


def physics_models(settings: FitSettings) -> dict[str, ModelSpec]:
    """The physics models of `compare` (`PHYSICS_MODELS`), keyed by their command-line names."""
    n_gms, n_ms = settings.gms_elements, settings.maxwell_elements

    def spread_elements(s: DataScales, m: int) -> tuple[np.ndarray, np.ndarray]:
        """`m` Maxwell-slip thresholds [m] spread up to the breakaway displacement, sharing the static level."""
        thresholds = s.breakaway * np.geomspace(0.05, 1.0, m)
        return thresholds, s.Fs / m / thresholds

    regressed: dict[
        tuple[int, int], tuple[Any, tuple[np.ndarray, np.ndarray]]
    ] = {}  # by training data: NLR and DNLRX share it

    def elements(s: DataScales, m: int) -> tuple[np.ndarray, np.ndarray]:
        """`m` Maxwell-slip thresholds [m] and stiffnesses [N/m]: those of `fj.initial_guess` (a dense LR model
        of the training record(s) merged down to `m` elements), else `spread_elements`; one regression per
        training set."""
        parts = s.parts
        if not parts:
            return spread_elements(s, m)
        key = (id(s.train), m)  # the record is kept with its result: its id is not reused meanwhile
        if key not in regressed:
            found = maxwell_slip_elements(parts, RecordScales.from_data(parts), m)
            regressed[key] = (s.train, spread_elements(s, m) if found is None else (found[0], found[1]))
        return regressed[key][1]

    def dnlrx_start(thresholds: np.ndarray, k: np.ndarray) -> MaxwellSlip:
        theta = np.outer([1.0, 0.0, 0.0], k * thresholds)  # on the normalised deflections: the NLR element forces
        return MaxwellSlip.dnlrx(thresholds=thresholds, theta=theta, c=[0.0, 0.0], smoothing=Smooth(1e-3))

    def gms_structure(s: DataScales) -> GMS:
        """GMS with `n_gms` elements (`"auto"`: `DEFAULT_GMS_ELEMENTS`, or more where `fj.element_count` reads more
        off the training record(s); `_gms_fit` keeps them only where the validation part prefers them)."""
        if n_gms != "auto":
            return _gms_structure(s, int(n_gms))
        parts = s.parts
        return _gms_structure(s, max(DEFAULT_GMS_ELEMENTS, element_count(parts) if parts else 0))

    return {
        "stribeck": ModelSpec(
            "Stribeck (static)",
            lambda s: BoPavelescu(
                Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0, Fv=0.0, smoothing=Smooth(max(1e-3 * s.vs, 1e-9))
            ),
            lm_recipe(("Fv", "offset"), settings.starts, settings),
        ),
        "lugre": ModelSpec(
            "LuGre",
            lambda s: LuGre(
                _stribeck(s), sigma0=s.stiffness, sigma1=0.0, sigma2=0.0, smoothing=Smooth(max(1e-3 * s.vs, 1e-9))
            ),
            lm_recipe(("sigma1", "sigma2", "offset"), settings.starts, settings),
        ),
        "lugre-backlash": ModelSpec(
            "LuGre with backlash",
            lambda s: _lugre_backlash(s, Smooth(max(1e-3 * s.vs, 1e-9))),
            lm_recipe(("sigma1", "sigma2", "offset"), settings.starts, settings),
        ),
        "gms": ModelSpec("GMS (N={elements})", gms_structure, _gms_fit(settings)),
        "nlr": ModelSpec(
            f"Maxwell-slip NLR({n_ms})",
            lambda s: MaxwellSlip.nlr(*reversed(elements(s, n_ms)), smoothing=Smooth(1e-3)),  # k, thresholds
            _validation_chooses(
                lambda s: MaxwellSlip.nlr(*reversed(spread_elements(s, n_ms)), smoothing=Smooth(1e-3)),
                lm_recipe(("force_map.offset",), settings.starts, settings),
            ),
        ),
        "dnlrx": ModelSpec(
            f"Maxwell-slip DNLRX({n_ms},2,1)",
            lambda s: dnlrx_start(*elements(s, n_ms)),
            _validation_chooses(
                lambda s: dnlrx_start(*spread_elements(s, n_ms)),
                lm_recipe(("force_map.theta", "force_map.c", "force_map.offset"), settings.starts, settings),
            ),
        ),
    }


def _validation_chooses(
    alternative: Callable[[DataScales], Any], recipe: Callable[..., FitResult]
) -> Callable[..., FitResult]:
    """`recipe` from the given start (the regression's elements) and from `alternative(scales)` (the elements spread
    up to the breakaway displacement), in the given start's wrappers; the fit with the lower validation loss is kept
    and its message says which. Neither start wins everywhere: on the synthetic tribometer the regression's (default
    mixed record: NLR 3.25 -> 0.343 % test NMSE), on the friction damper's 1 Hz record the spread one (NLR from the
    regression's: 3.54 / 3.68 % on the 0.25 Hz / 0.5 Hz records, from the spread one 2.59 / 2.53 %)."""

    def run(start: Any, split: Split | TrainingRecords, seed: int, progress: bool) -> FitResult:
        other = with_inner_friction(start, alternative(DataScales.from_data(split.train_records)))
        results = []
        for name, begin in (("the regression's elements", start), ("elements spread to the breakaway", other)):
            result = recipe(begin, split, seed, progress)
            results.append(dataclasses.replace(result, message=f"start: {name}; {result.message}"))
        best = min(results, key=_choice_key)
        return dataclasses.replace(best, wall_time=sum(r.wall_time for r in results))

    return run


def _choice_key(result: FitResult) -> tuple[bool, float]:
    """How fits of one model from different starts are ranked: by validation loss; a fit without a finite one
    after every fit that has one, by its training loss; a fit with neither finite last."""
    if np.isfinite(result.val_loss):
        return False, float(result.val_loss)
    return True, float(result.train_loss) if np.isfinite(result.train_loss) else np.inf


SCREENED_GMS_STARTS = 256  # draws around GMS's data-driven start, screened by their loss at the start
GMS_STEP_FACTOR = 2  # GMS's LM budget: twice `--steps` (the tolerance is judged over an eighth of it: `--steps / 4`)
SCREENED_GMS_KEEP = 4  # of them fitted (benchmarks/README.md "Global search", rounds 6-7)
GMS_POLISH_WIDTH = 10.0  # the polish's first smoothing width, in units of the fit's (benchmarks/README.md round 7)


def _gms_fit(settings: FitSettings) -> Callable[..., FitResult]:
    """GMS from `fj.initial_guess`'s start (the elements of a Maxwell-slip regression of the training record, its
    sliding law screened), `max(SCREENED_GMS_STARTS, starts)` log-uniform draws around it (a factor e either way)
    screened by their loss at the start (one vmap-ed free run of all, `fj.MultiStart(screen=0)`), the best
    `SCREENED_GMS_KEEP` and the start itself fitted by Levenberg-Marquardt, the validation part choosing. Where
    the start has elements of less than 2 % of the force (faint kinks near the reversals: a true element seen
    faintly, or none), the same from `fj.initial_guess(..., without_small_elements=True)` too, the validation part
    choosing between the two (benchmarks/README.md, "Global search, round 6").

    On the records of benchmarks/global_search.py this reaches 1.2x of the true model's held-out error for 9 of 10
    random GMS models of each family, and with the polish below for 9 of 10 (`gms`: another minimum 0.009 % above
    the truth-started loss) and 10 of 10 (`gms-spread`) at this budget (the former recipe, Adam with
    smoothing continuation from both ends of the Stribeck velocity range then an LM polish, compiled two more
    programs and cost twice the time; on the default mixed record it lost to this start on validation). The viscous
    coefficient moves on the scale `0.1 Fc / v_fast` (a viscous force of 10 % of the Coulomb level at the fast end),
    not 1 N s/m; the offset is fitted with the other parameters.

    The budget is `GMS_STEP_FACTOR` x `--steps`, so the tolerance, judged over an eighth of the budget, spans
    `--steps / 4` steps (10), not the `--steps / 8` (5) of the other fits: GMS's LM rejects runs of 5 steps in a
    flat valley of the Stribeck parameters and then moves on, so the 5-step rule stopped it early
    (benchmarks/held_out_compare.py, six-element truth: Fc 4-6 % off and 4.7x the true model's error on a
    gross-sliding record, 1.7x when converged; default mixed record 1.33x -> 1.09x the noise floor).

    Each screened fit is then **polished** by a smoothing continuation (`fj.Continuation`, two stages: LM at
    `GMS_POLISH_WIDTH` x the fit's width, then at the fit's width) and the polished model is kept where the validation
    part prefers it. At the fit's width (a thousandth of the median sample step) the stick/slip switching leaves kinks
    in the loss on which LM stalls; at ten times it the kinks are rounded, and the fit moves on (benchmarks/
    global_search.py, `gms-spread` seed 7: stalled 15 % above the truth-started training loss, polished to it;
    benchmarks/README.md, "Global search, round 7")."""

    def polish(result: FitResult, train: Any, lm: dict[str, Any], eps: float) -> FitResult:
        """`result` polished by LM through a two-stage smoothing continuation back to `eps` [m], where the validation
        part prefers the polished model (else `result`, saying so); a fit without a finite training loss is left as
        it is. The polish starts from `result`'s model; with several training records each record's nuisances
        (offset, drift, initial state) start again from their least-squares start, as in any `fj.fit`. `lm`: the
        screened fit's own arguments (scaling, solver, budget, tolerance, records)."""
        if not np.isfinite(result.train_loss):
            return result
        polished = fit(
            constrained(result.model, settings),
            train,
            continuation=Continuation(GMS_POLISH_WIDTH * eps, eps, stages=2),
            **lm,
        )
        wall_time = result.wall_time + polished.wall_time
        if _choice_key(polished) < _choice_key(result):
            how = f"polished by a smoothing continuation ({GMS_POLISH_WIDTH:g}x the width, then 1x)"
            message = f"{result.message}; {how}: {polished.message}"
            return dataclasses.replace(
                polished,
                message=message,
                wall_time=wall_time,
                num_starts=result.num_starts,
                best_start=result.best_start,
                evaluations=result.evaluations + polished.evaluations,
            )
        message = (
            f"{result.message}; a smoothing-continuation polish was not preferred by the validation part (not kept)"
        )
        return dataclasses.replace(result, message=message, wall_time=wall_time)

    def fit_from(start: Any, split: Split | TrainingRecords, seed: int, progress: bool) -> FitResult:
        """The screened fit from `fj.initial_guess`'s start and, where it differs, from the start with its small
        elements replaced (`without_small_elements`); the validation part chooses."""
        train, records = split.fit_arguments(start, drift=settings.drift != "none")
        scales = DataScales.from_data(split.train_records)
        eps = max(1e-3 * scales.dx, 1e-12)
        prefix = wrapper_path(start)
        guesses = initial_guesses(
            inner_friction(start), split.train_records, smoothing=Smooth(eps), without_small_elements=True
        )
        count = max(SCREENED_GMS_STARTS, settings.starts)
        names = ("data-driven start", "data-driven start, its small elements replaced")
        lm = {  # the arguments of the screened fits and of their polish
            "scaling": ParameterScaling({f"{prefix}sigma2": 0.1 * scales.Fc / scales.v_fast}),
            "solver": levenberg_marquardt(),
            "steps": GMS_STEP_FACTOR * settings.steps,
            "tolerance": settings.tolerance,
            "progress": progress,
            "compute_std": True,
            **records,
        }
        multistart = MultiStart(count, spread=1.0, distribution="log-uniform", keep=SCREENED_GMS_KEEP, screen=0.0)
        results = []
        for name, begin in zip(names, guesses, strict=False):
            begin = constrained(with_inner_friction(start, begin), settings)
            result = fit(begin, train, multistart=multistart, seed=seed, **lm)
            result = dataclasses.replace(result, message=f"{name}, {count} screened starts, LM: {result.message}")
            results.append(polish(result, train, lm, eps))
        best = min(results, key=_choice_key)
        note = "; the other start was fitted too and not chosen" if len(results) > 1 else ""
        return dataclasses.replace(best, message=best.message + note, wall_time=sum(r.wall_time for r in results))

    def run(start: Any, split: Split | TrainingRecords, seed: int, progress: bool) -> FitResult:
        result = fit_from(start, split, seed, progress)
        elements = int(np.shape(unwrap(inner_friction(start)).k)[-1])
        if settings.gms_elements != "auto" or elements <= DEFAULT_GMS_ELEMENTS:
            return result
        fewer = with_inner_friction(
            start, _gms_structure(DataScales.from_data(split.train_records), DEFAULT_GMS_ELEMENTS)
        )
        smaller = fit_from(fewer, split, seed, progress)
        keep, why = _significantly_better(smaller, result, split)
        chosen = result if keep else smaller
        note = (
            f"{elements} elements read off the record (fj.element_count), "
            f"{'kept' if keep else f'not kept: {DEFAULT_GMS_ELEMENTS} elements chosen'} ({why})"
        )
        return dataclasses.replace(
            chosen, message=f"{note}; {chosen.message}", wall_time=result.wall_time + smaller.wall_time
        )

    return run


DEFAULT_GMS_ELEMENTS = 4  # GMS's element count unless the validation part significantly prefers the record's count
SIGNIFICANT_GAIN = 0.05  # the least relative drop of the validation error for more GMS elements (several records)


def _stribeck(s: DataScales) -> ExponentialStribeck:
    """The Stribeck curve of the starts: the record's levels and Stribeck velocity, a Gaussian shape."""
    return ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)


def _lugre_backlash(s: DataScales, smoothing: Smooth) -> LuGreBacklash:
    """LuGre behind a linkage with backlash, its gap and bristle stiffness read off the training record's reversals
    (`fj.initial_guess`, the reversals of every training record; without a record, the record's scales and a gap of
    a tenth of the breakaway displacement), its Coulomb and static levels (positive, negative) pairs that start
    equal. Behind a play the two sliding levels are told apart from the force offset (the force is the offset alone
    while the play is crossed), and the asymmetric form is what the validation parts prefer: the friction damper's
    six records 1.82 % validation NMSE against 2.37 % symmetric, its 1 Hz record 1.41 against 2.06 %, the default
    tribometer record (a symmetric truth) 2.27 against 2.31 % (benchmarks/README.md, "asymmetric levels")."""
    if s.parts:
        guess = unwrap(initial_guess(LuGreBacklash, s.parts, smoothing=smoothing))
        gap, sigma0 = float(guess.gap), float(guess.sigma0)
    else:
        gap, sigma0 = 0.1 * s.breakaway, s.stiffness
    levels = ExponentialStribeck(Fc=(s.Fc, s.Fc), Fs=(s.Fs, s.Fs), vs=s.vs, delta=2.0)
    return LuGreBacklash(levels, sigma0=sigma0, sigma1=0.0, sigma2=0.0, gap=gap, smoothing=smoothing)


def _gms_structure(s: DataScales, elements: int) -> GMS:
    """A GMS of `elements` elements on the record's scales (`_gms_fit` starts from `fj.initial_guess` in it)."""
    shares = np.arange(elements, 0, -1, dtype=float)  # stiffer elements first: k_i ~ N, N-1, ..., 1
    return GMS(
        _stribeck(s),
        k=s.stiffness * shares / shares.sum(),
        alpha=np.full(elements, 1.0 / elements),
        C=10.0 * s.Fs,
        sigma2=0.0,
    )


def _significantly_better(smaller: FitResult, larger: FitResult, split: Split | TrainingRecords) -> tuple[bool, str]:
    """Whether the larger model predicts the validation part significantly better than the smaller one: one record,
    the paired t statistic of the drops of the squared error over blocks >= `SIGNIFICANT_T` (as the neural models'
    output-error stage is judged); several records, the validation loss lower by `SIGNIFICANT_GAIN`. More elements
    that fit the record's loops no better let the Stribeck parameters wander along the valley the record leaves
    flat (on the default tribometer, trained on 80 % of the mixed record: GMS(5) 4.2-4.7x the noise floor on gross
    sliding records, GMS(4) 1.08-1.11x, validation errors 0.1168 / 0.1179 %)."""
    if not np.isfinite(smaller.val_loss) or not np.isfinite(larger.val_loss):  # a fit that diverged loses
        return bool(np.isfinite(larger.val_loss)), "a validation loss is not finite"
    if isinstance(split, Split):
        gain, t = paired_validation_gain(smaller.model, larger.model, split)
        if not np.isfinite(t):
            return False, "the validation errors are not finite"
        return bool(t >= SIGNIFICANT_T and gain > 0), f"validation error {-100 * gain:+.1f} %, t = {t:.1f}"
    gain = 1.0 - float(larger.val_loss) / float(smaller.val_loss) if smaller.val_loss > 0 else 0.0
    return bool(gain >= SIGNIFICANT_GAIN), f"validation loss {-100 * gain:+.1f} %"
