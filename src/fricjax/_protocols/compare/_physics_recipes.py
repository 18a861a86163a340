"""The physics models of `compare` (`physics_models`): a static Stribeck curve, LuGre, GMS and the Maxwell-slip
NLR / DNLRX models, each started from the training record's scales (`DataScales`: force levels, pre-sliding
stiffness, breakaway displacement; the Maxwell-slip elements from `fj.initial_guess`'s regression) and fitted by
Levenberg-Marquardt with the linear parameters solved by least squares where the model allows (static curve, LuGre,
Maxwell-slip), or, for GMS (whose stick/slip landscape defeats a cold Gauss-Newton start), by Adam with smoothing
continuation then a Levenberg-Marquardt polish."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import equinox as eqx
import numpy as np
import optax

from ..._constraints import Positive
from ..._estimation._fit import fit, levenberg_marquardt
from ..._estimation._initial_guess import RecordScales, maxwell_slip_elements
from ..._estimation._losses import SimulationLoss
from ..._estimation._solution import FitResult
from ..._estimation._strategies import Continuation, MultiStart, ParameterScaling
from ..._models.physics._gms import GMS
from ..._models.physics._lugre import LuGre
from ..._models.physics._maxwell_slip import MaxwellSlip
from ..._models.physics._static import BoPavelescu
from ..._models.physics._stribeck import ExponentialStribeck
from ..._smoothing import Smooth
from ._recipes import ModelSpec, friction_of, lm_recipe, with_friction, wrapper_prefix
from ._records import Split, TrainingRecords
from ._settings import DataScales, FitSettings


def physics_models(settings: FitSettings) -> dict[str, ModelSpec]:
    """The physics models of `compare` (`PHYSICS_MODELS`), keyed by their command-line names."""
    n_gms, n_ms = settings.gms_elements, settings.maxwell_elements

    def stribeck(s: DataScales) -> ExponentialStribeck:
        return ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)

    def elements(s: DataScales, m: int) -> tuple[np.ndarray, np.ndarray]:
        """`m` Maxwell-slip thresholds [m] and stiffnesses [N/m]: those of `fj.initial_guess` (a dense LR model
        of the training record merged down to `m` elements), else spread up to the breakaway displacement."""
        found = None if s.train is None else maxwell_slip_elements(s.train, RecordScales.from_data(s.train), m)
        if found is None:
            thresholds = s.breakaway * np.geomspace(0.05, 1.0, m)
            return thresholds, s.Fs / m / thresholds
        return found[0], found[1]

    def dnlrx_start(thresholds: np.ndarray, k: np.ndarray) -> MaxwellSlip:
        theta = np.outer([1.0, 0.0, 0.0], k * thresholds)  # on the normalised deflections: the NLR element forces
        return MaxwellSlip.dnlrx(thresholds=thresholds, theta=theta, c=[0.0, 0.0], smoothing=Smooth(1e-3))

    shares = np.arange(n_gms, 0, -1, dtype=float)  # stiffer elements first: k_i ~ N, N-1, ..., 1
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
                stribeck(s), sigma0=s.stiffness, sigma1=0.0, sigma2=0.0, smoothing=Smooth(max(1e-3 * s.vs, 1e-9))
            ),
            lm_recipe(("sigma1", "sigma2", "offset"), settings.starts, settings),
        ),
        "gms": ModelSpec(
            f"GMS (N={n_gms})",
            lambda s: GMS(
                stribeck(s),
                k=s.stiffness * shares / shares.sum(),
                alpha=np.full(n_gms, 1.0 / n_gms),
                C=10.0 * s.Fs,
                sigma2=0.0,
            ),
            _gms_fit(settings),
        ),
        "nlr": ModelSpec(
            f"Maxwell-slip NLR({n_ms})",
            lambda s: MaxwellSlip.nlr(*reversed(elements(s, n_ms)), smoothing=Smooth(1e-3)),  # k, thresholds
            lm_recipe(("force_map.offset",), settings.starts, settings),
        ),
        "dnlrx": ModelSpec(
            f"Maxwell-slip DNLRX({n_ms},2,1)",
            lambda s: dnlrx_start(*elements(s, n_ms)),
            lm_recipe(("force_map.theta", "force_map.c", "force_map.offset"), settings.starts, settings),
        ),
    }


def _with_stribeck_velocity(model: Any, vs: float) -> Any:
    """`model` (a GMS, possibly inside its wrappers) with its Stribeck velocity set to `vs` [m/s]."""
    gms = friction_of(model)
    old = gms.stribeck.vs
    new = Positive(vs, transform=old.transform, name="vs", dtype=old.raw.dtype)
    return with_friction(model, eqx.tree_at(lambda g: g.stribeck.vs, gms, new))


def _gms_fit(settings: FitSettings) -> Callable[..., FitResult]:
    """From each end of the record's velocity range: Adam with smoothing continuation, then a Levenberg-Marquardt
    polish; the polished model with the lower validation loss is kept.

    The Stribeck velocity starts once at the slow end (`DataScales.vs`) and once at the fast end (`v_fast`) of the
    record: from the wrong end the fit settles in a flat curve (small vs and delta) that costs ~2x in test NMSE, and
    which end is wrong depends on the record (the default mixed record: the slow one). The end of the Adam stage does
    not tell them apart, the polished models' validation loss does. `max(gms_starts, starts)` starts are split
    between the two ends (at least one each); more than 2 per end are drawn log-uniformly and screened. Only
    first-order derivatives: the Adam stage differentiates the free run through the
    tangent-linear recurrence (`SimulationLoss(derivatives="tangent")`, chosen when the scan's own reverse pass cost
    ~20x the forward pass; with fricjax's XLA setting both cost 3-5x, and the choice stays so that the documented
    results hold), and both stages fit the offset with the other parameters (`separable=` would nest a forward
    Jacobian inside each derivative: slower to compile and run, no more accurate here). The viscous coefficient, which
    starts at 0, moves on the scale `0.1 Fc / v_fast` (a viscous force of 10 % of the Coulomb level at the fast end)
    instead of 1 N s/m (with `Fc / v_fast` the sliding record's fit stopped at 1.7x the noise floor). The second end
    reuses the first's compiled programs (benchmarks/README.md).
    """

    def run(start: Any, split: Split | TrainingRecords, seed: int, progress: bool) -> FitResult:
        train, records = split.fit_arguments(start, drift=settings.drift != "none")
        scales = DataScales.from_data(split.train)
        eps_end = max(1e-3 * scales.dx, 1e-12)
        prefix = wrapper_prefix(start)
        viscous_scale = 0.1 * scales.Fc / scales.v_fast  # a viscous force of 10 % of Fc at the fast end
        per_end = max(max(settings.gms_starts, settings.starts) // 2, 1)
        if per_end <= 2:
            multistart = MultiStart(per_end, spread=0.3) if per_end > 1 else None
        else:  # many starts: log-uniform draws screened down to the best 2 (and the data-driven one)
            multistart = MultiStart(per_end, spread=1.0, distribution="log-uniform", keep=2)
        results, wall_time = [], 0.0
        adam, lm = optax.adam(3e-2), levenberg_marquardt()  # one solver object each: the second end reuses the jit
        tangent = SimulationLoss(derivatives="tangent")
        for vs in (scales.vs, scales.v_fast):
            begin = _with_stribeck_velocity(start, vs)
            coarse = fit(
                begin,
                train,
                loss=tangent,  # the documented results' derivative path
                scaling=ParameterScaling({f"{prefix}sigma2": viscous_scale}),
                solver=adam,
                steps=8 * settings.steps,
                continuation=Continuation(100 * eps_end, eps_end, stages=3),
                multistart=multistart,
                seed=seed,
                progress=progress,
                **records,
            )
            polished = fit(
                coarse.model,
                train,
                scaling=ParameterScaling({f"{prefix}sigma2": viscous_scale}),
                solver=lm,
                steps=settings.steps,
                tolerance=settings.tolerance,
                compute_std=True,
                **records,
            )
            end = "slow" if vs == scales.vs else "fast"
            if polished.success and polished.train_loss <= coarse.train_loss:
                chosen = dataclasses.replace(
                    polished, message=f"Stribeck velocity from the {end} end; Adam then LM polish: {polished.message}"
                )
            else:
                chosen = dataclasses.replace(
                    coarse,
                    message=f"Stribeck velocity from the {end} end; the LM polish could not improve the Adam result "
                    f"(polish: {polished.message}); Adam: {coarse.message}",
                )
            results.append(chosen)
            wall_time += coarse.wall_time + polished.wall_time
        best = min(results, key=lambda r: r.val_loss if np.isfinite(r.val_loss) else r.train_loss)
        return dataclasses.replace(best, wall_time=wall_time)

    return run
