"""The identification exercise of the papers as one function: fit a set of models to a record, score them in
exact mode on held-out data, add ensembles, and report (parlitz2004 Fig. 6, worden2007 Fig. 11, the kernel
paper's Table 1).

`default_models(settings)` is the recipe registry: for each model name, a start built from the training record
(`DataScales`: force levels, pre-sliding stiffness, breakaway displacement; the networks normalise by the record
itself) and a fit recipe. Physics models (`PHYSICS_MODELS`, fitted by default): Levenberg-Marquardt with the
linear parameters solved by least squares where the model allows (static curve, LuGre, Maxwell-slip), Adam with
smoothing continuation then a Levenberg-Marquardt polish for GMS (whose stick/slip landscape defeats a cold
Gauss-Newton start). Neural models (`NEURAL_MODELS`): the output layer by least squares, then output error
(`neural_models`). Linear-in-parameters models (`LINEAR_MODELS`): term selection, then output error.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optax

from .._constraints import Positive
from .._data._io import Units, read_record
from .._data._record import FrictionData
from .._estimation._fit import fit, levenberg_marquardt
from .._estimation._result import FitResult
from .._estimation._strategies import Continuation, MultiStart, ParameterScaling
from .._metrics import max_error, nmse
from .._models.combine._sensor import SensorDrift
from .._models.combine._tangent import TangentGradients
from .._models.physics._gms import GMS
from .._models.physics._lugre import LuGre
from .._models.physics._maxwell_slip import MaxwellSlip
from .._models.physics._static import BoPavelescu
from .._models.physics._stribeck import ExponentialStribeck
from .._simulate import simulate
from .._smoothing import Smooth, exact


@dataclasses.dataclass(frozen=True)
class DataScales:
    """Scales read off a training record, used to build starting models.

    `force` [N]: half the 1-99 % range of the force; `Fc`, `Fs` [N]: the median and the 99.5 % level of
    |F| while sliding; `vs` [m/s]: a velocity below which sliding is rare; `stiffness` [N/m]: the typical
    |dF/dx| right after reversals (pre-sliding); `breakaway` [m] = Fs / stiffness; `dx` [m]: the median step;
    `duration` [s]: the record's length; `v_fast` [m/s]: the 90 % level of |v| (the fast end of the record);
    `train`: the record itself (black-box models normalise by it).
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

    @classmethod
    def from_data(cls, data: FrictionData) -> DataScales:
        samples = data.motion.samples()
        x, v = np.asarray(samples.x), np.asarray(samples.v)
        force = np.asarray(data.force)
        force = force - np.median(force)
        scale = 0.5 * float(np.percentile(force, 99) - np.percentile(force, 1))
        fast = np.abs(v) > np.percentile(np.abs(v), 70)
        Fc = float(np.median(np.abs(force[fast]))) if fast.any() else scale
        Fs = max(float(np.percentile(np.abs(force), 99.5)), 1.05 * Fc)
        vs = float(np.percentile(np.abs(v), 30)) or 1e-3
        window = 3
        dxw = x[window:] - x[:-window]
        dfw = force[window:] - force[:-window]
        moving = np.abs(dxw) > np.percentile(np.abs(dxw), 20) + 1e-15
        slopes = np.abs(dfw[moving] / dxw[moving])
        stiffness = float(np.percentile(slopes, 90)) if slopes.size else scale / 1e-5
        steps = np.abs(np.diff(x))
        dx = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1e-9
        duration = data.length * float(np.asarray(data.motion.dt))
        v_fast = float(np.percentile(np.abs(v), 90)) or 1e-3
        return cls(scale, Fc, Fs, vs, stiffness, Fs / stiffness, dx, duration, v_fast, data)


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """Budgets and model sizes of `compare` (the command line's `--steps`, `--gms-elements`,
    `--maxwell-elements`).

    - `steps`: the Levenberg-Marquardt step budget of every fit (GMS: its Adam stage gets 8 x as many steps,
      then an LM polish of `steps`). An LM fit ends earlier, as converged (`successful`), when its training
      loss falls by less than `tolerance` (relative) over `steps / 8` steps; `max_steps` means not converged.
    - `gms_elements`, `maxwell_elements`: the element counts of GMS and of Maxwell-slip NLR / DNLRX.
    - `gms_starts`: starts of the GMS fit, split between its two Stribeck-velocity ends (at least one each).
    - `neural_steps`: the output-error (NOE) Adam steps of the neural models (`mlp`, `gsnn`, `rnn`, `avd`; see
      `neural_models`), after their teacher-forced stage.
    - `drift`: the force sensor's drift fitted with every model (`fj.SensorDrift`): `"linear"` (default),
      `"leaky"` (a leaky integrator, its time constant fitted from the training record's duration) or
      `"none"`. It restarts at 0 on each test record; the record's offset is the initialisation window's.
    """

    steps: int = 40
    gms_elements: int = 4
    maxwell_elements: int = 5
    gms_starts: int = 2
    tolerance: float = 1e-4
    drift: str = "linear"
    neural_steps: int = 600

    def __post_init__(self) -> None:
        if self.drift not in ("linear", "leaky", "none"):
            raise CompareError(f"--drift must be linear, leaky or none, got {self.drift!r}")
        for name in ("steps", "gms_elements", "maxwell_elements", "gms_starts", "neural_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise CompareError(f"--{name.replace('_', '-')} must be a positive integer, got {value!r}")


RESULT_CODES = {
    "successful": "the solver stopped by its tolerance (converged)",
    "max_steps": "the step budget ran out first: not converged (raise --steps)",
    "early_stopped": "stopped when the validation loss stopped improving",
    "diverged": "the loss became non-finite; the last good model was kept",
}


class CompareError(ValueError):
    """A problem with the user's input to `compare`, reported as one line."""


@dataclasses.dataclass(frozen=True)
class TestRecord:
    """A record a fitted model is scored on by free-run simulation in exact mode from the record's first sample.

    Samples `[start, start + init_window)` are the initialisation window: the model runs through them (its
    state settles from the record's history) and the record's force-cell offset is estimated there, as the mean
    of measured minus predicted force, and added to the prediction. Samples `[start + init_window, T)` are
    scored; the window never is. `start` > 0 when the test part follows training data in the same record
    (`Split.test_record`).

    `reference`: where the record is synthetic, the force its sensor reads without white noise (the true model
    plus drift and offset): scored the same way, it is the noise floor.
    """

    __test__ = False  # not a pytest test class

    name: str
    record: FrictionData
    start: int = 0
    init_window: int = 0
    reference: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not (self.start >= 0 and self.init_window >= 0 and self.start + self.init_window < self.record.length):
            raise CompareError(
                f"{self.name}: an initialisation window of {self.init_window} samples leaves nothing to score in a "
                f"test part of {self.record.length - self.start} samples; lower --init-window"
            )

    @classmethod
    def whole(cls, loaded: LoadedRecord, init_window: int | None = None, name: str | None = None) -> TestRecord:
        """A whole record loaded on the command line as a test record (default window: `default_init_window`)."""
        window = default_init_window(loaded.data.length) if init_window is None else int(init_window)
        return cls(loaded.name if name is None else name, loaded.data, 0, window, loaded.reference)

    @property
    def scored_start(self) -> int:
        return self.start + self.init_window


@dataclasses.dataclass(frozen=True)
class Score:
    """A model's score on one test record: NMSE [%] and MAX / std of the measured force on the scored part, and
    the force offset [N] estimated in the initialisation window."""

    nmse: float
    max_error: float
    offset: float


def score_prediction(prediction: Any, test: TestRecord) -> tuple[Score, np.ndarray]:
    """Score a prediction over the whole test record: the offset is the mean error in the initialisation window
    (0 without one). **Returns:** `(Score, the offset-corrected prediction on the scored part)`."""
    prediction = np.asarray(prediction, dtype=float)
    measured = np.asarray(test.record.force, dtype=float)
    window = slice(test.start, test.scored_start)
    offset = float(np.mean(measured[window] - prediction[window])) if test.init_window > 0 else 0.0
    scored = prediction[test.scored_start :] + offset
    truth = measured[test.scored_start :]
    return Score(float(nmse(truth, scored)), float(max_error(truth, scored)), offset), scored


def default_init_window(samples: int) -> int:
    """The default initialisation window: 10 % of a test part's samples (at least 1)."""
    return max(1, int(round(0.1 * samples)))


@dataclasses.dataclass(frozen=True)
class Split:
    """A record and its train / validation / test boundaries: train = [0, train_end), validation =
    [train_end, validation_end), test = [validation_end, T) (empty when the models are tested on other
    records). Hysteretic models are always simulated from the start of the record, and scored on their part
    only, so they enter each part in the state their history gives them (parlitz2004 and worden2007 simulate the
    whole record in the same way)."""

    full: FrictionData
    train_end: int
    validation_end: int

    def __post_init__(self) -> None:
        if not 0 < self.train_end < self.validation_end <= self.full.length:
            raise CompareError(
                f"the split edges {self.train_end}, {self.validation_end} of a {self.full.length}-sample record leave "
                "an empty training or validation part; use --split TRAIN_END VALIDATION_END as fractions, e.g. 0.6 0.8"
            )

    @classmethod
    def fractions(cls, full: FrictionData, train_end: float, validation_end: float) -> Split:
        """Split at fractions of the record (`0 < train_end < validation_end <= 1`)."""
        if not 0 < train_end < validation_end <= 1:
            raise CompareError(
                f"--split {train_end} {validation_end}: need 0 < TRAIN_END < VALIDATION_END <= 1 (fractions of the "
                "training record)"
            )
        n = full.length
        return cls(full, int(round(train_end * n)), int(round(validation_end * n)))

    @property
    def train(self) -> FrictionData:
        return self.full.slice(0, self.train_end)

    @property
    def until_validation_end(self) -> FrictionData:
        return self.full.slice(0, self.validation_end)

    @property
    def test(self) -> FrictionData:
        return self.full.slice(self.validation_end, self.full.length)

    def test_record(self, init_window: int | None = None, reference: Any = None) -> TestRecord:
        """The test part as a `TestRecord` simulated from the record's start; `init_window` samples of it (default
        `default_init_window`) initialise the model and estimate the offset."""
        samples = self.full.length - self.validation_end
        if samples <= 0:
            raise CompareError("the training record has no test part (its split ends at 1); pass --test records")
        window = default_init_window(samples) if init_window is None else int(init_window)
        ref = None if reference is None else np.asarray(reference, dtype=float)
        return TestRecord("test part", self.full, self.validation_end, window, ref)


@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """How to start and fit one model family in `compare`: `build(scales)` and
    `fit(start, split, seed, progress)`. `build` is None for models identified from the split as a whole (their
    `fit` gets `start=None`: structure and parameters chosen on the training and validation parts together)."""

    label: str
    build: Callable[[DataScales], Any] | None
    fit: Callable[[Any, Split, int, bool], FitResult]


def _separable(start: Any, paths: tuple[str, ...]) -> tuple[str, ...]:
    """The linear parameters of a (possibly drift-wrapped) model: the friction model's, and the drift rate."""
    if isinstance(start, SensorDrift):
        return (*(f"model.{path}" for path in paths), "rate")
    return paths


def _lm(separable: tuple[str, ...], starts: int, settings: FitSettings) -> Callable[..., FitResult]:
    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        return fit(
            start,
            split.train,
            scaling=ParameterScaling(),
            validation=split.until_validation_end,
            validation_burn_in=split.train_end,
            solver=levenberg_marquardt(),
            steps=settings.steps,
            tolerance=settings.tolerance,
            separable=_separable(start, separable),
            multistart=MultiStart(starts, spread=0.5) if starts > 1 else None,
            seed=seed,
            progress=progress,
            compute_std=True,
        )

    return run


def _friction(model: Any) -> Any:
    """The friction model of a start: `model` itself, or the one inside its `SensorDrift`."""
    return model.model if isinstance(model, SensorDrift) else model


def _with_friction(model: Any, friction: Any) -> Any:
    """`model` with its friction model (`_friction`) replaced by `friction`."""
    return eqx.tree_at(lambda m: m.model, model, friction) if isinstance(model, SensorDrift) else friction


def _with_stribeck_velocity(model: Any, vs: float) -> Any:
    """`model` (a GMS, possibly inside a `SensorDrift`) with its Stribeck velocity set to `vs` [m/s]."""
    gms = _friction(model)
    old = gms.stribeck.vs
    new = Positive(vs, transform=old.transform, name="vs", dtype=old.raw.dtype)
    return _with_friction(model, eqx.tree_at(lambda g: g.stribeck.vs, gms, new))


def _gms_fit(settings: FitSettings) -> Callable[..., FitResult]:
    """From each end of the record's velocity range: Adam with smoothing continuation, then a Levenberg-Marquardt
    polish; the polished model with the lower validation loss is kept.

    The Stribeck velocity starts once at the slow end (`DataScales.vs`) and once at the fast end (`v_fast`) of the
    record: from the wrong end the fit settles in a flat curve (small vs and delta) that costs ~2x in test NMSE, and
    which end is wrong depends on the record (the default mixed record: the slow one). The end of the Adam stage does
    not tell them apart, the polished models' validation loss does. `gms_starts` starts are split between the two ends
    (at least one each). Only first-order derivatives: the Adam stage trains the model wrapped in `TangentGradients`
    (chosen when the scan's own reverse pass cost ~20x the forward pass; with fricjax's XLA setting both cost 3-5x, and
    the wrapper stays so that the documented results hold), and both stages fit the offset with the other parameters
    (`separable=` would nest a forward Jacobian inside each derivative: slower to compile and run, no more accurate
    here). The viscous coefficient, which starts at 0, moves on the scale `0.1 Fc / v_fast` (a viscous force of 10 % of
    the Coulomb level at the fast end) instead of 1 N s/m (with `Fc / v_fast` the sliding record's fit stopped at 1.7x
    the noise floor). The second end reuses the first's compiled programs (benchmarks/README.md).
    """

    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        train, validation = split.train, split.until_validation_end
        scales = DataScales.from_data(train)
        eps_end = max(1e-3 * scales.dx, 1e-12)
        prefix = "model." if isinstance(start, SensorDrift) else ""
        viscous_scale = 0.1 * scales.Fc / scales.v_fast  # a viscous force of 10 % of Fc at the fast end
        per_end = max(settings.gms_starts // 2, 1)
        results, wall_time = [], 0.0
        adam, lm = optax.adam(3e-2), levenberg_marquardt()  # one solver object each: the second end reuses the jit
        for vs in (scales.vs, scales.v_fast):
            begin = _with_stribeck_velocity(start, vs)
            coarse = fit(
                _with_friction(begin, TangentGradients(_friction(begin))),  # the documented results' derivative path
                train,
                scaling=ParameterScaling({f"{prefix}model.sigma2": viscous_scale}),
                validation=validation,
                validation_burn_in=split.train_end,
                solver=adam,
                steps=8 * settings.steps,
                continuation=Continuation(100 * eps_end, eps_end, stages=3),
                multistart=MultiStart(per_end, spread=0.3) if per_end > 1 else None,
                seed=seed,
                progress=progress,
            )
            coarse = dataclasses.replace(coarse, model=_with_friction(coarse.model, _friction(coarse.model).model))
            polished = fit(
                coarse.model,
                train,
                scaling=ParameterScaling({f"{prefix}sigma2": viscous_scale}),
                validation=validation,
                validation_burn_in=split.train_end,
                solver=lm,
                steps=settings.steps,
                tolerance=settings.tolerance,
                compute_std=True,
            )
            results.append(polished if polished.success and polished.train_loss <= coarse.train_loss else coarse)
            wall_time += coarse.wall_time + polished.wall_time
        best = min(results, key=lambda r: r.val_loss if np.isfinite(r.val_loss) else r.train_loss)
        return dataclasses.replace(best, wall_time=wall_time)

    return run


def default_models(settings: FitSettings | None = None) -> dict[str, ModelSpec]:
    """The physics models `compare` fits by default, keyed by their command-line names; `settings` sets the step
    budgets and element counts (`FitSettings()` by default)."""
    settings = FitSettings() if settings is None else settings
    n_gms, n_ms = settings.gms_elements, settings.maxwell_elements

    def stribeck(s: DataScales) -> ExponentialStribeck:
        return ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)

    def thresholds(s: DataScales, m: int) -> np.ndarray:
        return s.breakaway * np.geomspace(0.05, 1.0, m)

    shares = np.arange(n_gms, 0, -1, dtype=float)  # stiffer elements first: k_i ~ N, N-1, ..., 1
    specs = {
        "stribeck": ModelSpec(
            "Stribeck (static)",
            lambda s: BoPavelescu(
                Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0, Fv=0.0, smoothing=Smooth(max(1e-3 * s.vs, 1e-9))
            ),
            _lm(("Fv", "offset"), 2, settings),
        ),
        "lugre": ModelSpec(
            "LuGre",
            lambda s: LuGre(
                stribeck(s), sigma0=s.stiffness, sigma1=0.0, sigma2=0.0, smoothing=Smooth(max(1e-3 * s.vs, 1e-9))
            ),
            _lm(("sigma1", "sigma2", "offset"), 2, settings),
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
            lambda s: MaxwellSlip.nlr(
                k=s.Fs / n_ms / thresholds(s, n_ms), thresholds=thresholds(s, n_ms), smoothing=Smooth(1e-3)
            ),
            _lm(("force_map.offset",), 2, settings),
        ),
        "dnlrx": ModelSpec(
            f"Maxwell-slip DNLRX({n_ms},2,1)",
            lambda s: MaxwellSlip.dnlrx(
                thresholds=thresholds(s, n_ms),
                theta=np.outer([1.0, 0.0, 0.0], np.full(n_ms, s.Fs / n_ms)),
                c=[0.0, 0.0],
                smoothing=Smooth(1e-3),
            ),
            _lm(("force_map.theta", "force_map.c", "force_map.offset"), 2, settings),
        ),
    }
    specs.update(neural_models(settings))
    specs.update(linear_in_parameters_models(settings))
    if settings.drift == "none":
        return specs
    return {name: _with_drift(spec, settings.drift) for name, spec in specs.items()}


PHYSICS_MODELS = ("stribeck", "lugre", "gms", "nlr", "dnlrx")
NEURAL_MODELS = ("mlp", "gsnn", "rnn", "avd")
LINEAR_MODELS = ("narx", "kernel", "knn", "wavelet")
MODEL_NAMES = PHYSICS_MODELS + NEURAL_MODELS + LINEAR_MODELS
"""Every model `compare` can fit; the command line fits `PHYSICS_MODELS` unless told otherwise."""


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

    from .._models.blackbox._narx import GSNN, MLPNARX, AVDNetwork
    from .._models.blackbox._regressors import NARXRegressors
    from .._models.blackbox._rnn import RecurrentNetwork

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
            _least_squares_then_noe(output_layer, settings),
        ),
        "gsnn": ModelSpec(
            "GSNN (5) on 20 plays",
            lambda s: GSNN.init(with_plays(s), 5, key=key, linear=True),
            _least_squares_then_noe(output_layer, settings),
        ),
        "rnn": ModelSpec(
            "recurrent network (20 play + 8)", rnn, _least_squares_then_noe(("theta", "theta0"), settings)
        ),
        "avd": ModelSpec("AVD network (10)", avd, _least_squares_then_noe(("d", "d0"), settings)),
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
    from .._estimation._polynomial_narx import identify_polynomial_narx
    from .._models.blackbox._regressors import NARXRegressors

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
            "polynomial NARX (FROLS/PRESS)", papers, _structure_by_validation(structures, _lm((), 1, settings))
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
    from .._estimation._kernel_narx import identify_kernel_narx

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
    from .._estimation._wavelet_narx import identify_wavelet_narx

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
        return _least_squares_then_noe(linear, settings)(model, split, seed, progress)

    structures: dict[str, Callable[[DataScales], Any]] = {
        "lags of x, v and F, 10 units": papers,
        "v and 20 plays, 10 units": on_plays,
    }
    return ModelSpec("wavelet network NARX", None, _structure_by_validation(structures, refine))


def _local_models(settings: FitSettings) -> Callable[..., FitResult]:
    """`knn`: parlitz2004 §III-F local models, k nearest neighbours of the current coordinates among the training
    record's, locally constant and locally linear (TPCR), the embedding, delay and k chosen on the validation part
    (`identify_local_model`). Coordinates: the displacement and velocity at lags 0..(m-1) tau and, as for the
    neural models, 20 play operators of the displacement (thresholds 0.01-1 x the record's half range; the papers'
    displacement delays alone stay at 15-35 % on the mixed regime); a linear sensor drift (`--drift none`: none)."""
    from .._estimation._local_models import identify_local_model

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


def identified_result(model: Any, message: str, wall_time: float, validation_nmse: float) -> FitResult:
    """A `FitResult` for a model identified in closed form or by a grid (no optimiser steps)."""
    empty = np.zeros(0)
    history = {"step": empty, "train_loss": empty, "val_loss": empty, "eps": empty, "time": empty}
    nan = float("nan")
    return FitResult(model, "successful", message, history, nan, validation_nmse, validation_nmse, 0, wall_time, 1, 0)


def _structure_by_validation(
    structures: dict[str, Callable[[DataScales], Any]], refine: Callable[..., FitResult]
) -> Callable[..., FitResult]:
    """Identify each structure on the training part, keep the one whose free run (exact) has the least NMSE on the
    validation part, then `refine` it; the fit's message names the structure and every validation score."""

    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        began = time.perf_counter()
        scales = DataScales.from_data(split.train)
        measured = np.asarray(split.until_validation_end.force)[split.train_end :]
        scores = {}
        candidates = {}
        for name, build in structures.items():
            model = build(scales)
            prediction = free_run(model, split.until_validation_end)[split.train_end :]
            value = float(nmse(measured, prediction))
            candidates[name], scores[name] = model, value if np.isfinite(value) else np.inf
        chosen = min(scores, key=lambda name: scores[name])
        refined = refine(candidates[chosen], split, seed, progress)
        listed = ", ".join(f"{name} {value:.3g} %" for name, value in scores.items())
        message = f"structure: {chosen} (validation NMSE before refinement: {listed}); {refined.message}"
        return dataclasses.replace(refined, message=message, wall_time=time.perf_counter() - began)

    return run


def _least_squares_then_noe(linear: tuple[str, ...], settings: FitSettings) -> Callable[..., FitResult]:
    """The output layer `linear` (and the drift rate) by least squares, then every weight by output error; the
    output-error model is kept only when it predicts the validation part significantly better
    (`paired_validation_gain`)."""

    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        validation: dict[str, Any] = {"validation": split.until_validation_end, "validation_burn_in": split.train_end}
        paths = _separable(start, linear)
        if not paths:  # nothing enters the free run linearly (a NARX with fed-back forces and no drift)
            first = identified_result(start, "", 0.0, float("nan"))
        else:
            first = fit(start, split.train, train=paths, separable=paths, steps=1, **validation)
        rate = 3e-3
        warmup = min(30, settings.neural_steps // 5)  # 30 steps, less for short budgets (decay needs > warm-up)
        schedule = optax.warmup_cosine_decay_schedule(rate / 10, rate, warmup, settings.neural_steps, rate / 30)
        noe = fit(
            first.model,
            split.train,
            solver=optax.chain(optax.clip_by_global_norm(1.0), optax.adam(schedule)),
            steps=settings.neural_steps,
            separable=_separable(start, ()),
            seed=seed,
            progress=progress,
            **validation,
        )
        wall_time = first.wall_time + noe.wall_time
        if not noe.val_loss < first.val_loss:  # the NOE stage returned its start
            return dataclasses.replace(noe, wall_time=wall_time)
        improvement, t = paired_validation_gain(first.model, noe.model, split)
        gain = f"; output error improved the validation error by {100 * improvement:.2g} % (paired t = {t:.2f}"
        if t >= SIGNIFICANT_T:
            return dataclasses.replace(noe, message=f"{noe.message}{gain}): kept", wall_time=wall_time)
        noise = f" over {VALIDATION_BLOCKS} blocks, < {SIGNIFICANT_T:g}: within the noise)"
        within = noise + ", so the least-squares start is kept"
        return dataclasses.replace(
            noe,
            model=first.model,
            message=noe.message + gain + within,
            train_loss=first.train_loss,
            val_loss=first.val_loss,
            exact_val_loss=first.exact_val_loss,
            std=first.std,
            wall_time=wall_time,
        )

    return run


VALIDATION_BLOCKS = 16
SIGNIFICANT_T = 2.0


def paired_validation_gain(reference: Any, candidate: Any, split: Split) -> tuple[float, float]:
    """How much better `candidate` predicts the validation part than `reference` (exact-mode free runs from the
    record's start): the relative drop of the mean squared error, and the paired t statistic of the drops over
    `VALIDATION_BLOCKS` consecutive blocks (blocks, not samples: the errors of a free run are correlated over
    many samples). The neural models keep their output-error (NOE) stage only when t >= `SIGNIFICANT_T`:
    measured on the mixed regime, NOE improved their validation error by 1-2 % at t = 0.2-0.7, and such
    iterates scored from 0.75x to 4x the least-squares start's test error as the records changed by round-off
    or the learning rate and the trained weights were varied (benchmarks/README.md)."""
    record = split.until_validation_end
    measured = np.asarray(record.force)[split.train_end :]
    size = max(len(measured) // VALIDATION_BLOCKS, 1)
    count = len(measured) // size

    def block_errors(model: Any) -> np.ndarray:
        error = free_run(model, record)[split.train_end :] - measured
        return np.mean(error[: count * size].reshape(count, size) ** 2, axis=1)

    before, after = block_errors(reference), block_errors(candidate)
    drops = before - after
    spread = np.std(drops, ddof=1) / np.sqrt(count) if count > 1 else 0.0
    t = float(np.mean(drops) / spread) if spread > 0 else (np.inf if np.mean(drops) > 0 else 0.0)
    return float(np.mean(drops) / np.mean(before)), t


def _with_drift(spec: ModelSpec, kind: str) -> ModelSpec:
    """The spec with its model wrapped in `SensorDrift` (rate 0; leaky: tau = the training record's duration)."""

    inner = spec.build
    if inner is None:  # identified with its drift from the split itself
        return spec

    def build(scales: DataScales) -> Any:
        model = inner(scales)
        if isinstance(model, SensorDrift):  # identified with its drift (the linear-in-parameters models)
            return model
        return SensorDrift(model, 0.0, None if kind == "linear" else scales.duration)

    return ModelSpec(spec.label, build, spec.fit)


@dataclasses.dataclass
class ModelScore:
    """One row of the comparison table: `nmse`, `max_error` and `prediction` (offset-corrected, on the scored
    part) are those of the first test record; `tests` holds the `Score` on every test record by name,
    `test_predictions` the raw free-run prediction over each whole test record, `full_prediction` the one over
    the training record (for ensemble weights), `validation_nmse` the NMSE [%] on the validation part."""

    name: str
    label: str
    nmse: float
    max_error: float
    fit_time: float
    num_parameters: int
    result: str
    model: Any
    prediction: np.ndarray
    full_prediction: np.ndarray | None = None
    message: str = ""
    tests: dict[str, Score] = dataclasses.field(default_factory=dict)
    test_predictions: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    validation_nmse: float = float("nan")
    std: Any = None


def free_run(model: Any, record: FrictionData) -> np.ndarray:
    """`model`'s exact-mode free-run force over the whole `record` (from its first sample), as NumPy."""
    return np.asarray(simulate(exact(model), record.motion))  # type: ignore[arg-type]


def score(model: Any, test: TestRecord | Split) -> tuple[float, float, np.ndarray]:
    """Exact-mode NMSE [%] and normalised MAX error of `model` on a test record (a `Split` stands for its test
    part without an initialisation window), and its free-run prediction over the whole record."""
    if isinstance(test, Split):
        test = test.test_record(init_window=0)
    full_prediction = free_run(model, test.record)
    result, _ = score_prediction(full_prediction, test)
    return result.nmse, result.max_error, full_prediction


def count_parameters(model: Any) -> int:
    """The number of trainable scalars of `model` (`fj.trainable_filter`: `Fixed` leaves and smoothing widths
    excluded), the parameter count of the comparison table."""
    import equinox as eqx
    import jax

    from .._constraints import trainable_filter

    params = eqx.filter(model, trainable_filter(model))
    return int(sum(np.size(leaf) for leaf in jax.tree_util.tree_leaves(params)))


def _row(
    name: str,
    label: str,
    model: Any,
    full_prediction: np.ndarray,
    test_predictions: dict[str, np.ndarray],
    split: Split,
    tests: list[TestRecord],
    **extra: Any,
) -> ModelScore:
    scores, corrected = {}, {}
    for test in tests:
        scores[test.name], corrected[test.name] = score_prediction(test_predictions[test.name], test)
    measured = np.asarray(split.full.force)
    val = slice(split.train_end, split.validation_end)
    first = scores[tests[0].name]
    return ModelScore(
        name,
        label,
        first.nmse,
        first.max_error,
        model=model,
        prediction=corrected[tests[0].name],
        full_prediction=full_prediction,
        tests=scores,
        test_predictions=test_predictions,
        validation_nmse=float(nmse(measured[val], full_prediction[val])),
        **extra,
    )


def fit_and_score(
    names: list[str],
    split: Split,
    *,
    tests: list[TestRecord] | None = None,
    settings: FitSettings | None = None,
    seed: int = 0,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> list[ModelScore]:
    """Fit each named model on the train part (the validation part chooses among starts), then score it by
    free-run simulation in exact mode on every test record (default: the split's test part, with the default
    initialisation window)."""
    specs = default_models(settings)
    tests = [split.test_record()] if tests is None else list(tests)
    scales = DataScales.from_data(split.train)
    rows = []
    for name in names:
        spec = specs[name]
        start_time = time.perf_counter()
        log(f"fitting {spec.label} ...")
        result = spec.fit(None if spec.build is None else spec.build(scales), split, seed, progress)
        elapsed = time.perf_counter() - start_time
        model = result.model
        full_prediction = free_run(model, split.full)
        predictions = {
            test.name: full_prediction if test.record is split.full else free_run(model, test.record) for test in tests
        }
        row = _row(
            name,
            spec.label,
            model,
            full_prediction,
            predictions,
            split,
            tests,
            fit_time=elapsed,
            num_parameters=count_parameters(model),
            result=result.result,
            message=result.message,
            std=result.std,
        )
        rows.append(row)
        log(f"  {spec.label}: test NMSE {row.nmse:.3f} %, MAX {row.max_error:.3f}, {elapsed:.1f} s: {result.message}")
    return rows


def reference_scores(tests: list[TestRecord]) -> dict[str, Score]:
    """The noise floor: each synthetic test record's `reference` force (true model + sensor drift and offset),
    scored like the models (same initialisation window)."""
    return {t.name: score_prediction(t.reference, t)[0] for t in tests if t.reference is not None}


# ----------------------------------------------------------------------------------------------------------------
# data sources for `fricjax compare`
# ----------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class LoadedRecord:
    """A record named on the command line: the data (SI), its data card, its units, and for built-in synthetic
    records the true model and the noise-free sensor reading (`reference`)."""

    name: str
    data: FrictionData
    card: dict[str, Any]
    units: Units
    truth: Any = None
    reference: np.ndarray | None = None


_TRIBOMETER_KEYS = {"seed": int, "offset": float, "duration": float, "drift": float}


def load_record_spec(
    spec: str, *, seed: int = 0, dt: float | None = None, x_unit: str | None = None, force_unit: str | None = None
) -> LoadedRecord:
    """Resolve a record named on the command line: `tribometer:REGIME[:key=value,...]` (keys `seed`, `offset`
    [N] force-cell offset, `drift` [N], `duration` [s]; e.g. `tribometer:mixed:seed=1,offset=0.3`), or a `.npz`
    / `.csv` file (`fj.load_record`: column aliases, units, `dt`)."""
    import pathlib

    from .._data._tribometer import make_tribometer

    if spec.startswith("tribometer"):
        parts = spec.split(":")
        regime = parts[1] if len(parts) > 1 and parts[1] else "mixed"
        options: dict[str, Any] = {"seed": seed}
        for item in ",".join(parts[2:]).split(",") if len(parts) > 2 else []:
            key, _, value = item.partition("=")
            if key not in _TRIBOMETER_KEYS or not value:
                raise CompareError(
                    f"{spec}: options are key=value pairs of {', '.join(_TRIBOMETER_KEYS)} (e.g. "
                    "tribometer:mixed:seed=1,offset=0.3), got {item!r}"
                )
            try:
                options[key] = _TRIBOMETER_KEYS[key](value)
            except ValueError:
                raise CompareError(f"{spec}: {key}={value!r} is not a number") from None
        seed_value = options.pop("seed")
        kwargs = {
            "force_offset": options.get("offset", 0.0),
            **({"drift": options["drift"]} if "drift" in options else {}),
            **({"duration": options["duration"]} if "duration" in options else {}),
        }
        try:
            data = make_tribometer(regime, seed=seed_value, **kwargs)
        except (ValueError, TypeError) as err:
            raise CompareError(f"{spec}: {err}") from err
        return LoadedRecord(
            spec, data.full, dict(data.card), Units(), data.true_model, np.asarray(data.sensor_force, dtype=float)
        )
    path = pathlib.Path(spec)
    if not path.is_file():
        raise CompareError(f"{spec}: no such file (use tribometer:presliding|mixed|sliding, emps, or a .csv / .npz)")
    try:
        full, info = read_record(path, dt=dt, x_unit=x_unit, force_unit=force_unit)
    except ValueError as err:
        raise CompareError(str(err)) from err
    card = {
        "source": str(path),
        "samples": full.length,
        "columns": dict(info.columns),
        "ignored": list(info.ignored),
        "units": {"x": info.units.x, "force": info.units.force},
        "dt_s": float(np.asarray(full.motion.dt)),
    }
    return LoadedRecord(spec, full, card, info.units)


def split_record(
    loaded: LoadedRecord, fractions: Sequence[float] | None = None, *, tested_elsewhere: bool = False
) -> Split:
    """The training record's split: `fractions` (TRAIN_END, VALIDATION_END) where given; else 0.8 / 1.0 when the
    models are tested on other records (`tested_elsewhere`), the tribometer's own edges for built-in records, and
    60 / 20 / 20 otherwise."""
    edges = loaded.card.get("split_edges")
    if fractions is not None:
        return Split.fractions(loaded.data, *fractions)
    if tested_elsewhere:
        return Split.fractions(loaded.data, 0.8, 1.0)
    if edges is not None:
        return Split(loaded.data, int(edges[1]), int(edges[2]))
    return Split.fractions(loaded.data, 0.6, 0.8)


def load_split(spec: str, *, seed: int = 0) -> tuple[Split, dict[str, Any], Any]:
    """Resolve `--data` and split it 60 / 20 / 20 (the tribometer's own edges for built-in records).
    **Returns:** `(split, data card, true model or None)`."""
    loaded = load_record_spec(spec, seed=seed)
    return split_record(loaded), loaded.card, loaded.truth


def statistics_warnings(split: Split, tests: list[TestRecord], units: Units) -> list[str]:
    """Warnings when a test record's scored part differs sharply from the training part: force spread 3x
    (its NMSE is then normalised by a very different variance) or displacement range 10x (the model is
    extrapolated)."""
    out = []
    train_force = float(np.std(np.asarray(split.train.force)))
    train_x = float(np.ptp(np.asarray(split.train.motion.samples().x)))
    for test in tests:
        force = np.asarray(test.record.force)[test.scored_start :]
        x = np.asarray(test.record.motion.samples().x)[test.scored_start :]
        for what, ours, theirs, unit, factor, limit in (
            ("force std", float(np.std(force)), train_force, units.force, units.force_factor, 3.0),
            ("displacement range", float(np.ptp(x)), train_x, units.x, units.x_factor, 10.0),
        ):
            if theirs > 0 and ours > 0 and not 1 / limit <= ours / theirs <= limit:
                out.append(
                    f"{test.name}: {what} {ours / factor:.3g} {unit} against {theirs / factor:.3g} {unit} in training "
                    f"({ours / theirs:.2g}x): its scores are not comparable with the training fit's"
                )
    return out


# ----------------------------------------------------------------------------------------------------------------
# ensembles, the table, the report
# ----------------------------------------------------------------------------------------------------------------


def add_ensembles(rows: list[ModelScore], split: Split, tests: list[TestRecord] | None = None) -> list[ModelScore]:
    """Average and least-squares-weighted ensembles (weights with intercept fitted on the validation part,
    parlitz2004 §IV-H, emps-ensemble §3.3), and the PRESS forward selection of worden2007 §7, scored on every
    test record like the single models (default: the split's test part)."""
    from .._estimation._ensemble_fit import select_forward
    from .._models.combine._ensemble import AverageEnsemble, WeightedEnsemble

    if len(rows) < 2:
        return []
    tests = [split.test_record()] if tests is None else list(tests)
    members = [row.model for row in rows]
    full_predictions = np.stack(
        [row.full_prediction if row.full_prediction is not None else free_run(row.model, split.full) for row in rows]
    )

    def member_predictions(test: TestRecord) -> np.ndarray:
        if all(test.name in row.test_predictions for row in rows):
            return np.stack([row.test_predictions[test.name] for row in rows])
        return np.stack([free_run(row.model, test.record) for row in rows])

    per_test = {test.name: member_predictions(test) for test in tests}
    val = slice(split.train_end, split.validation_end)
    val_data = split.full.slice(split.train_end, split.validation_end)

    def row(
        name: str, label: str, ensemble: Any, combine: Callable[[np.ndarray], np.ndarray], count: int, start: float
    ) -> Any:
        """The ensemble's row; `start`: when its fit (weights, selection) began, for the fit time."""
        full = combine(full_predictions)
        predictions = {key: combine(value) for key, value in per_test.items()}
        return _row(
            name,
            label,
            ensemble,
            full,
            predictions,
            split,
            tests,
            fit_time=time.perf_counter() - start,
            num_parameters=count,
            result="successful",
        )

    start = time.perf_counter()
    out = [row("ensemble_average", "Ensemble: average", AverageEnsemble(members), lambda p: p.mean(axis=0), 0, start)]
    start = time.perf_counter()
    weighted = WeightedEnsemble.fit(members, val_data, predictions=full_predictions[:, val])
    out.append(
        row(
            "ensemble_weighted",
            "Ensemble: LS weights",
            weighted,
            lambda p: np.asarray(weighted.combine(jnp.asarray(p.T))),
            len(members) + 1,
            start,
        )
    )
    start = time.perf_counter()
    selection = select_forward(members, val_data, predictions=full_predictions[:, val])
    chosen = list(selection.indices)
    names = "+".join(rows[i].name for i in chosen)
    out.append(
        row(
            "ensemble_press",
            f"Ensemble: PRESS ({names})",
            selection.ensemble,
            lambda p: np.asarray(selection.ensemble.combine(jnp.asarray(p[chosen].T))),
            len(chosen) + 1,
            start,
        )
    )
    return out


def by_score(row: ModelScore) -> tuple[bool, float]:
    """Sort key of the table: by test NMSE (the first test record), non-finite scores last."""
    return (not np.isfinite(row.nmse), float(row.nmse) if np.isfinite(row.nmse) else 0.0)


def label_width(rows: list[ModelScore]) -> int:
    """The width of the table's first column: the longest label (at least 44 characters)."""
    return max([44, *(len(r.label) for r in rows)])


def format_table(rows: list[ModelScore], reference: dict[str, Score] | None = None) -> str:
    """The comparison table, sorted by test NMSE (kernel paper Table 1 / worden2007 Fig. 11 layout): one NMSE
    column per test record (where there are several), MAX as the largest absolute error divided by the standard
    deviation of the measured force, the noise-floor reference row where there is one, and what the result
    codes mean."""
    w = label_width(rows)
    names = list(rows[0].tests) if rows and rows[0].tests else ["test"]
    several = len(names) > 1
    heads = [f"NMSE % {i + 1}" for i in range(len(names))] if several else ["NMSE %"]
    lines = [
        f"{'model':{w}s} {'params':>6s} "
        + " ".join(f"{h:>10s}" for h in heads)
        + f" {'MAX/std':>7s} {'fit s':>7s}  result"
    ]

    def values(tests: dict[str, Score], fallback: float) -> list[float]:
        return [tests[n].nmse if n in tests else fallback for n in names] if tests else [fallback]

    for r in sorted(rows, key=by_score):
        cells = " ".join(f"{v:10.4f}" for v in values(r.tests, r.nmse))
        lines.append(f"{r.label:{w}s} {r.num_parameters:6d} {cells} {r.max_error:7.3f} {r.fit_time:7.1f}  {r.result}")
    if reference:
        floor = [reference[n].nmse if n in reference else float("nan") for n in names]
        cells = " ".join(f"{v:10.4f}" for v in floor)
        first = reference.get(names[0])
        lines.append(
            f"{'noise floor (true model + sensor model)':{w}s} {'':6s} {cells} "
            f"{(first.max_error if first else float('nan')):7.3f}"
        )
    if several:
        lines.append("test records: " + "; ".join(f"{i + 1} = {n}" for i, n in enumerate(names)))
    codes = sorted({r.result for r in rows if r.result in RESULT_CODES})
    lines.append("result: " + "; ".join(f"{c} = {RESULT_CODES[c]}" for c in codes))
    return "\n".join(lines)
