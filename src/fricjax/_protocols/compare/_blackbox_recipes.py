"""The black-box models of `compare`: the neural models (`neural_models`: the output layer by least squares, then
output error) and the models linear in their parameters once a structure is chosen (`linear_in_parameters_models`:
polynomial NARX by term selection, kernel NARX, local kNN models, wavelet network), each identified on the
training part with the validation part choosing among structures and settings."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..._estimation._fit import fit
from ..._estimation.loop._solution import FitResult
from ..._metrics import nmse
from ..._models.combine._sensor import SensorDrift
from ..._smoothing import Smooth
from ._recipes import ModelSpec, identified_result, least_squares_then_noe, lm_recipe, structure_by_validation
from ._records import Split
from ._scoring import free_run
from ._settings import DataScales, FitSettings


def neural_models(settings: FitSettings) -> dict[str, ModelSpec]:
    """The neural black-box models of `compare` (worden2007 §5-6, parlitz2004 §III-G, the kernel paper §4.2).

    A NARX network with a few lags cannot hold the state of a hysteretic system with non-local memory, so the
    memory of `mlp`, `gsnn` and `rnn` is a bank of 20 play operators of the displacement (thresholds log-spaced
    over 0.03-3 x the breakaway displacement): see `fj.NARXRegressors(plays=)` and
    `fj.RecurrentNetwork.hysteretic`. The papers' NARX structures (lags of x, v, a and of the force) are
    available as classes; on the mixed regime they stay about 20x the noise floor (benchmarks/README.md).

    - `mlp`: `MLPNARX`, 10 tanh units and a linear part on the velocity and the play states;
    - `gsnn`: `GSNN`, 5 generalised shunting neurons (tanh / logistic sigmoid) and a linear part, same inputs;
    - `rnn`: `RecurrentNetwork.hysteretic`, 20 play elements and 8 static velocity elements, linear readout;
    - `avd`: `AVDNetwork`, 10 tanh units on acceleration, velocity and displacement (no memory).

    Training: the output layer (linear: `d`, `d0`, `theta`, or the readout) by least squares with the hidden
    weights at their random start (echo-state / extreme-learning-machine style), then every weight by output
    error through the whole free run (NOE, Adam with warm-up, cosine decay and gradient clipping), the
    validation part keeping the best model. The NOE model replaces the least-squares one only when its gain on
    the validation part is significant (`paired_validation_gain`, t >= 2 over 16 blocks): on the built-in
    mixed regime NOE gained 1-2 % at t = 0.2-0.7 for `mlp`, `gsnn` and `rnn`, and which NOE iterate won then
    moved with round-off (the recurrent network's test error went from 2.5x to 3.9x the floor with records
    changed at 1e-16), so there the least-squares models are kept and the row's message says so.
    """
    import jax

    from ..._models.blackbox._narx import GSNN, MLPNARX, AVDNetwork
    from ..._models.blackbox._regressors import NARXRegressors
    from ..._models.blackbox._rnn import RecurrentNetwork

    key = jax.random.PRNGKey(0)

    def thresholds(scales: DataScales) -> np.ndarray:
        return scales.breakaway * np.geomspace(0.03, 3.0, 20)

    def with_plays(scales: DataScales) -> NARXRegressors:
        assert scales.train is not None  # networks normalise by the training record itself
        return NARXRegressors.from_data(scales.train, ("v",), 0, 0, plays=thresholds(scales), smoothing=Smooth(1e-3))

    def rnn(scales: DataScales) -> Any:
        assert scales.train is not None
        return RecurrentNetwork.hysteretic(scales.train, thresholds(scales), 8, key=key, smoothing=Smooth(1e-3))

    def avd(scales: DataScales) -> Any:
        assert scales.train is not None
        return AVDNetwork(scales.train, 10, key=key)

    output_layer = ("d", "d0", "theta")
    return {
        "mlp": ModelSpec(
            "MLP (10) on 20 plays",
            lambda s: MLPNARX.init(with_plays(s), 10, key=key, linear=True),
            least_squares_then_noe(output_layer, settings),
        ),
        "gsnn": ModelSpec(
            "GSNN (5) on 20 plays",
            lambda s: GSNN.init(with_plays(s), 5, key=key, linear=True),
            least_squares_then_noe(output_layer, settings),
        ),
        "rnn": ModelSpec("recurrent network (20 play + 8)", rnn, least_squares_then_noe(("theta", "theta0"), settings)),
        "avd": ModelSpec("AVD network (10)", avd, least_squares_then_noe(("d", "d0"), settings)),
    }


def linear_in_parameters_models(settings: FitSettings) -> dict[str, ModelSpec]:
    """Black boxes linear in their parameters once the structure is chosen (issue 11; so far the polynomial NARX):

    - `narx`: `PolynomialNARX`, its terms chosen by forward orthogonal least squares with the PRESS stopping rule
      on the teacher-forced regression (parlitz2004 §III-D, worden2007 §5.1), the sensor drift a fixed column of
      that regression (`identify_polynomial_narx(drift=)`). Three structures compete, the validation part's
      free-run NMSE choosing: the papers' (degree 3 in the displacement step and the velocity at lags 0-2 and 2
      past forces), and, as for the neural models, degree 1 and 2 in the velocity and 20 play operators of the
      displacement (thresholds 0.03-3 x the breakaway displacement; an extension: a few lags cannot hold the
      state of a hysteresis with non-local memory). The chosen model's coefficients are then refined by output
      error (Levenberg-Marquardt, as the physics models).
    """
    from ..._estimation.families._polynomial_narx import identify_polynomial_narx
    from ..._models.blackbox._regressors import NARXRegressors

    def drift(scales: DataScales) -> Any:
        return {"linear": "linear", "leaky": scales.duration, "none": None}[settings.drift]

    def papers(scales: DataScales) -> Any:
        assert scales.train is not None
        return identify_polynomial_narx(
            scales.train, signals=("dx", "v"), input_lags=2, output_lags=2, degree=3, drift=drift(scales)
        ).model

    def on_plays(scales: DataScales, degree: int) -> Any:
        assert scales.train is not None
        thresholds = scales.breakaway * np.geomspace(0.03, 3.0, 20)
        regressors = NARXRegressors.from_data(scales.train, ("v",), 0, 0, plays=thresholds)
        return identify_polynomial_narx(scales.train, regressors=regressors, degree=degree, drift=drift(scales)).model

    structures = {
        "lags of dx, v and F, degree 3": papers,
        "v and 20 plays, degree 1": lambda scales: on_plays(scales, 1),
        "v and 20 plays, degree 2": lambda scales: on_plays(scales, 2),
    }
    return {
        "narx": ModelSpec(
            "polynomial NARX (FROLS/PRESS)", papers, structure_by_validation(structures, lm_recipe((), 1, settings))
        ),
        "kernel": ModelSpec("kernel NARX (exponential, 20 plays)", None, _kernel_narx(settings)),
        "knn": ModelSpec("local models (kNN, 20 plays)", None, _local_models(settings)),
        "wavelet": _wavelet_network(settings),
    }


def _kernel_narx(settings: FitSettings) -> Callable[..., FitResult]:
    """`kernel`: the kernel-method paper's kernel NARX (`identify_kernel_narx`) with the infinite-degree
    exponential kernel on the velocity and, as for the neural models, 20 play operators of the displacement
    (thresholds 0.03-3 x the breakaway displacement; the paper's lags of the displacement alone stay 50-100x the
    noise floor on the built-in regimes, benchmarks/README.md), 1 000 Nystrom landmarks as the centres. The
    validation part's free-run NMSE chooses the width (10, 30, 100), the ridge (1e-4 ... 1e-1) and whether one
    past force is fed back (N_AR 0 or 1). Without a fed-back force the model is linear in its weights along the
    free run, so the sensor drift (`--drift`) is then fitted with them by least squares, the validation part
    keeping it only if it predicts better."""
    from ..._estimation.families._kernel_narx import identify_kernel_narx

    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        began = time.perf_counter()
        train = split.train
        scales = DataScales.from_data(train)
        validation: dict[str, Any] = {"validation": split.until_validation_end, "validation_burn_in": split.train_end}
        result = identify_kernel_narx(
            train,
            signals=("v",),
            plays=scales.breakaway * np.geomspace(0.03, 3.0, 20),
            input_lags=0,
            output_lags=[0, 1],
            kernel="exponential",
            width=[10.0, 30.0, 100.0],
            ridge=[1e-4, 1e-3, 1e-2, 1e-1],
            solver="nystrom",
            landmarks=min(1000, split.train_end),
            seed=seed,
            **validation,
        )
        best = min(result.candidates, key=lambda candidate: candidate.free_run_nmse)
        model, score = result.model, float(result.validation_nmse)
        described = (
            f"width {best.width:g}, ridge {best.ridge:g}, N_AR {best.output_lags} (validation NMSE {score:.3g} %, "
            f"best of {len(result.candidates)})"
        )
        if settings.drift != "none" and best.output_lags == 0:
            tau = None if settings.drift == "linear" else scales.duration
            paths = ("model.alpha", "model.b", "rate")
            drifting = fit(SensorDrift(model, 0.0, tau), train, train=paths, separable=paths, steps=1).model
            measured = np.asarray(split.until_validation_end.force)[split.train_end :]
            prediction = free_run(drifting, split.until_validation_end)[split.train_end :]
            with_drift = float(nmse(measured, prediction))
            if with_drift < score:
                model, score = drifting, with_drift
                described += f"; with the sensor drift by least squares {score:.3g} %"
        return identified_result(model, described + "; identified, no iterations", time.perf_counter() - began, score)

    return run


def _wavelet_network(settings: FitSettings) -> ModelSpec:
    """`wavelet`: the wavelet-network NARX (MATLAB's `wavenet`, the emps-ensemble paper's nonlinear ARX): 10
    wavelet / scaling units chosen by orthogonal least squares among data-placed candidates and a linear part
    (`identify_wavelet_narx`), on the papers' regressors (lags 0-2 of x and v, 2 past forces) or on the velocity
    and 20 play operators (as the neural models), the validation part choosing; then the output weights by least
    squares (with play regressors; they enter the free run linearly) and every weight by output error (NOE, as the
    neural models)."""
    from ..._estimation.families._wavelet_narx import identify_wavelet_narx

    def papers(scales: DataScales) -> Any:
        assert scales.train is not None
        return identify_wavelet_narx(scales.train, signals=("x", "v"), input_lags=2, output_lags=2, units=10).model

    def on_plays(scales: DataScales) -> Any:
        assert scales.train is not None
        plays = scales.breakaway * np.geomspace(0.03, 3.0, 20)
        return identify_wavelet_narx(
            scales.train, signals=("v",), input_lags=0, output_lags=0, units=10, plays=plays, smoothing=Smooth(1e-3)
        ).model

    def refine(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        model = start
        if settings.drift != "none":
            tau = None if settings.drift == "linear" else DataScales.from_data(split.train).duration
            model = SensorDrift(start, 0.0, tau)
        linear = ("L", "a", "s", "d") if start.regressors.output_lags == 0 else ()
        return least_squares_then_noe(linear, settings)(model, split, seed, progress)

    structures: dict[str, Callable[[DataScales], Any]] = {
        "lags of x, v and F, 10 units": papers,
        "v and 20 plays, 10 units": on_plays,
    }
    return ModelSpec("wavelet network NARX", None, structure_by_validation(structures, refine))


def _local_models(settings: FitSettings) -> Callable[..., FitResult]:
    """`knn`: parlitz2004 §III-F local models, k nearest neighbours of the current coordinates among the training
    record's, locally constant and locally linear (TPCR), the embedding, delay and k chosen on the validation part
    (`identify_local_model`). Coordinates: the displacement and velocity at lags 0..(m-1) tau and, as for the
    neural models, 20 play operators of the displacement (thresholds 0.01-1 x the record's half range; the papers'
    displacement delays alone stay at 15-35 % on the mixed regime); a linear sensor drift (`--drift none`: none)."""
    from ..._estimation.families._local_models import identify_local_model

    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        began = time.perf_counter()
        train = split.train
        x = np.asarray(train.motion.samples(frozenset({"x"})).x)
        thresholds = float(np.max(np.abs(x - np.median(x)))) * np.geomspace(0.01, 1.0, 20)
        common: dict[str, Any] = {
            "validation": split.until_validation_end,
            "validation_burn_in": split.train_end,
            "signals": ("x", "v"),
            "plays": thresholds,
            "embedding": (1, 2, 4),
            "delay": (1, 10),
            "drift": settings.drift != "none",
        }
        results = {
            "linear": identify_local_model(train, kind="linear", neighbours=(30, 100, 300), rcond=1e-2, **common),
            "constant": identify_local_model(train, kind="constant", neighbours=(3, 10, 30), **common),
        }
        scores = {kind: float(np.min(result.scores)) for kind, result in results.items()}
        kind = min(scores, key=lambda k: scores[k])
        chosen = results[kind]
        m, tau, k = chosen.best
        message = (
            f"locally {kind}, m = {m}, tau = {tau}, k = {k} (validation NMSE: linear {scores['linear']:.3g} %, "
            f"constant {scores['constant']:.3g} %); identified, no iterations"
        )
        return identified_result(chosen.model, message, time.perf_counter() - began, scores[kind])

    return run
