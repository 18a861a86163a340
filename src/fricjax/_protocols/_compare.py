"""The identification exercise of the papers as one function: fit a set of models to a record, score them in
exact mode on held-out data, add ensembles, and report (parlitz2004 Fig. 6, worden2007 Fig. 11, the kernel
paper's Table 1).

`default_models(train)` proposes starting models from the data itself (force levels, pre-sliding stiffness,
breakaway displacement), and `fit_model(name, train, validation)` fits one with settings chosen for that
family: Levenberg-Marquardt with the linear parameters solved by least squares where the model allows
(static curve, LuGre, Maxwell-slip), Adam with smoothing continuation then a Levenberg-Marquardt polish for
GMS (whose stick/slip landscape defeats a cold Gauss-Newton start).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np
import optax

from .._data._io import read_record
from .._data._record import FrictionData
from .._estimation._fit import fit, levenberg_marquardt
from .._estimation._result import FitResult
from .._estimation._strategies import Continuation, MultiStart, ParameterScaling
from .._metrics import max_error, nmse
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
    |dF/dx| right after reversals (pre-sliding); `breakaway` [m] = Fs / stiffness; `dx` [m]: the median step.
    """

    force: float
    Fc: float
    Fs: float
    vs: float
    stiffness: float
    breakaway: float
    dx: float

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
        return cls(scale, Fc, Fs, vs, stiffness, Fs / stiffness, dx)


@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """How to start and fit one model family in `compare`."""

    label: str
    build: Callable[[DataScales], Any]
    fit: Callable[[Any, Split, int, bool], FitResult]


@dataclasses.dataclass(frozen=True)
class Split:
    """A record and its train / validation / test boundaries: train = [0, train_end), validation =
    [train_end, validation_end), test = [validation_end, T). Hysteretic models are always simulated from the
    start of the record, and scored on their part only, so they enter each part in the state their history
    gives them (parlitz2004 and worden2007 simulate the whole record in the same way)."""

    full: FrictionData
    train_end: int
    validation_end: int

    @property
    def train(self) -> FrictionData:
        return self.full.slice(0, self.train_end)

    @property
    def until_validation_end(self) -> FrictionData:
        return self.full.slice(0, self.validation_end)

    @property
    def test(self) -> FrictionData:
        return self.full.slice(self.validation_end, self.full.length)


def _lm(separable: tuple[str, ...], starts: int, steps: int = 40) -> Callable[..., FitResult]:
    def run(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
        return fit(
            start,
            split.train,
            scaling=ParameterScaling(),
            validation=split.until_validation_end,
            validation_burn_in=split.train_end,
            solver=levenberg_marquardt(),
            steps=steps,
            separable=separable,
            multistart=MultiStart(starts, spread=0.5) if starts > 1 else None,
            seed=seed,
            progress=progress,
        )

    return run


def _gms_fit(start: Any, split: Split, seed: int, progress: bool) -> FitResult:
    train, validation = split.train, split.until_validation_end
    scales = DataScales.from_data(train)
    eps_end = max(1e-3 * scales.dx, 1e-12)
    coarse = fit(
        start,
        train,
        scaling=ParameterScaling(),
        validation=validation,
        validation_burn_in=split.train_end,
        solver=optax.adam(3e-2),
        steps=300,
        continuation=Continuation(100 * eps_end, eps_end, stages=3),
        separable=("offset",),
        seed=seed,
        progress=progress,
    )
    polished = fit(
        coarse.model,
        train,
        scaling=ParameterScaling(),
        validation=validation,
        validation_burn_in=split.train_end,
        solver=levenberg_marquardt(),
        steps=30,
        separable=("offset",),
    )
    better = polished if polished.success and polished.train_loss <= coarse.train_loss else coarse
    return dataclasses.replace(better, wall_time=coarse.wall_time + polished.wall_time)


def default_models() -> dict[str, ModelSpec]:
    """The physics models `compare` fits by default, keyed by their command-line names."""

    def stribeck(s: DataScales) -> ExponentialStribeck:
        return ExponentialStribeck(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0)

    def thresholds(s: DataScales, m: int) -> np.ndarray:
        return s.breakaway * np.geomspace(0.05, 1.0, m)

    return {
        "stribeck": ModelSpec(
            "Stribeck (static)",
            lambda s: BoPavelescu(
                Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0, Fv=0.0, smoothing=Smooth(max(1e-3 * s.vs, 1e-9))
            ),
            _lm(("Fv", "offset"), starts=2),
        ),
        "lugre": ModelSpec(
            "LuGre",
            lambda s: LuGre(
                stribeck(s), sigma0=s.stiffness, sigma1=0.0, sigma2=0.0, smoothing=Smooth(max(1e-3 * s.vs, 1e-9))
            ),
            _lm(("sigma1", "sigma2", "offset"), starts=2),
        ),
        "gms": ModelSpec(
            "GMS (N=4)",
            lambda s: GMS(
                stribeck(s),
                k=s.stiffness * np.array([0.4, 0.3, 0.2, 0.1]),
                alpha=[0.25, 0.25, 0.25, 0.25],
                C=10.0 * s.Fs,
                sigma2=0.0,
            ),
            _gms_fit,
        ),
        "nlr": ModelSpec(
            "Maxwell-slip NLR(5)",
            lambda s: MaxwellSlip.nlr(
                k=s.Fs / 5 / thresholds(s, 5), thresholds=thresholds(s, 5), smoothing=Smooth(1e-3)
            ),
            _lm(("force_map.offset",), starts=2),
        ),
        "dnlrx": ModelSpec(
            "Maxwell-slip DNLRX(5,2,1)",
            lambda s: MaxwellSlip.dnlrx(
                thresholds=thresholds(s, 5),
                theta=np.outer([1.0, 0.0, 0.0], np.full(5, s.Fs / 5)),
                c=[0.0, 0.0],
                smoothing=Smooth(1e-3),
            ),
            _lm(("force_map.theta", "force_map.c", "force_map.offset"), starts=2),
        ),
    }


@dataclasses.dataclass
class ModelScore:
    """One row of the comparison table."""

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


def score(model: Any, split: Split) -> tuple[float, float, np.ndarray]:
    """Exact-mode NMSE [%] and normalised MAX error of `model` on the test part (simulated from the record's
    start), and its prediction over the whole record."""
    full_prediction = np.asarray(simulate(exact(model), split.full.motion))  # type: ignore[arg-type]
    prediction = full_prediction[split.validation_end :]
    measured = np.asarray(split.full.force)[split.validation_end :]
    return float(nmse(measured, prediction)), float(max_error(measured, prediction)), full_prediction


def count_parameters(model: Any) -> int:
    import equinox as eqx
    import jax

    from .._constraints import trainable_filter

    params = eqx.filter(model, trainable_filter(model))
    return int(sum(np.size(leaf) for leaf in jax.tree_util.tree_leaves(params)))


def fit_and_score(
    names: list[str],
    split: Split,
    *,
    seed: int = 0,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> list[ModelScore]:
    """Fit each named model on the train part (validation part for the choice among starts), score it in exact
    mode on the test part."""
    specs = default_models()
    scales = DataScales.from_data(split.train)
    rows = []
    for name in names:
        spec = specs[name]
        start_time = time.perf_counter()
        log(f"fitting {spec.label} ...")
        result = spec.fit(spec.build(scales), split, seed, progress)
        elapsed = time.perf_counter() - start_time
        model = result.model
        test_nmse, test_max, full_prediction = score(model, split)
        rows.append(
            ModelScore(
                name,
                spec.label,
                test_nmse,
                test_max,
                elapsed,
                count_parameters(model),
                result.result,
                model,
                full_prediction[split.validation_end :],
                full_prediction,
                result.message,
            )
        )
        log(f"  {spec.label}: test NMSE {test_nmse:.3f} %, MAX {test_max:.3f}, {elapsed:.1f} s: {result.message}")
    return rows


# ----------------------------------------------------------------------------------------------------------------
# data sources for `fricjax compare`
# ----------------------------------------------------------------------------------------------------------------


class CompareError(ValueError):
    """A problem with the user's input to `compare`, reported as one line."""


def load_split(spec: str, *, seed: int = 0) -> tuple[Split, dict[str, Any], Any]:
    """Resolve `--data`: `tribometer:REGIME`, or a `.npz` / `.csv` file with columns `t` or `dt`, `x` and/or
    `v`, and `force`. **Returns:** `(split, data card, true model or None)`."""
    import pathlib

    from .._data._tribometer import make_tribometer

    if spec.startswith("tribometer"):
        regime = spec.split(":", 1)[1] if ":" in spec else "mixed"
        try:
            data = make_tribometer(regime, seed=seed)
        except ValueError as err:
            raise CompareError(f"--data {spec}: {err}") from err
        edges = data.card["split_edges"]
        return Split(data.full, int(edges[1]), int(edges[2])), dict(data.card), data.true_model
    path = pathlib.Path(spec)
    if not path.is_file():
        raise CompareError(f"--data {spec}: no such file (use tribometer:presliding|mixed|sliding, emps, or a file)")
    try:
        full, info = read_record(path)
    except ValueError as err:
        raise CompareError(f"--data {err}") from err
    n = full.length
    card = {
        "source": str(path),
        "samples": n,
        "columns": dict(info.columns),
        "ignored": list(info.ignored),
        "units": {"x": info.units.x, "force": info.units.force},
        "dt_s": float(np.asarray(full.motion.dt)),
    }
    return Split(full, int(0.6 * n), int(0.8 * n)), card, None


# ----------------------------------------------------------------------------------------------------------------
# ensembles, the table, the report
# ----------------------------------------------------------------------------------------------------------------


def add_ensembles(rows: list[ModelScore], split: Split) -> list[ModelScore]:
    """Average and least-squares-weighted ensembles (weights with intercept fitted on the validation part,
    parlitz2004 §IV-H, emps-ensemble §3.3), and the PRESS forward selection of worden2007 §7."""
    from .._estimation._ensemble_fit import select_forward
    from .._models.combine._ensemble import AverageEnsemble, WeightedEnsemble

    if len(rows) < 2:
        return []
    members = [row.model for row in rows]
    full = split.full
    # the members' whole-record predictions were already simulated while scoring them
    predictions = np.stack(
        [row.full_prediction if row.full_prediction is not None else score(row.model, split)[2] for row in rows]
    )
    val = slice(split.train_end, split.validation_end)
    test = slice(split.validation_end, full.length)
    measured = np.asarray(full.force)
    val_data = full.slice(split.train_end, split.validation_end)
    out = []

    def row(name: str, label: str, ensemble: Any, prediction: np.ndarray, elapsed: float) -> ModelScore:
        return ModelScore(
            name,
            label,
            float(nmse(measured[test], prediction)),
            float(max_error(measured[test], prediction)),
            elapsed,
            len(members) if name != "ensemble_press" else int(np.size(ensemble.weights)) + 1,
            "successful",
            ensemble,
            prediction,
        )

    start = time.perf_counter()
    average = AverageEnsemble(members)
    out.append(row("ensemble_average", "Ensemble: average", average, predictions[:, test].mean(axis=0), 0.0))
    weighted = WeightedEnsemble.fit(members, val_data, predictions=predictions[:, val])
    prediction = np.asarray(weighted.combine(jnp.asarray(predictions[:, test].T)))
    out.append(row("ensemble_weighted", "Ensemble: LS weights", weighted, prediction, time.perf_counter() - start))
    start = time.perf_counter()
    selection = select_forward(members, val_data, predictions=predictions[:, val])
    chosen = predictions[list(selection.indices)][:, test]
    prediction = np.asarray(selection.ensemble.combine(jnp.asarray(chosen.T)))
    names = "+".join(rows[i].name for i in selection.indices)
    out.append(
        row("ensemble_press", f"Ensemble: PRESS ({names})", selection.ensemble, prediction, time.perf_counter() - start)
    )
    return out


def by_score(row: ModelScore) -> tuple[bool, float]:
    """Sort key of the table: by test NMSE, non-finite scores last."""
    return (not np.isfinite(row.nmse), float(row.nmse) if np.isfinite(row.nmse) else 0.0)


def label_width(rows: list[ModelScore]) -> int:
    """The width of the table's first column: the longest label (at least 44 characters)."""
    return max([44, *(len(r.label) for r in rows)])


def format_table(rows: list[ModelScore]) -> str:
    """The comparison table, sorted by test NMSE (kernel paper Table 1 / worden2007 Fig. 11 layout); MAX is the
    largest absolute error divided by the standard deviation of the measured force."""
    w = label_width(rows)
    lines = [f"{'model':{w}s} {'params':>6s} {'NMSE %':>9s} {'MAX/std':>7s} {'fit s':>7s}  result"]
    for r in sorted(rows, key=by_score):
        lines.append(
            f"{r.label:{w}s} {r.num_parameters:6d} {r.nmse:9.4f} {r.max_error:7.3f} {r.fit_time:7.1f}  {r.result}"
        )
    return "\n".join(lines)
