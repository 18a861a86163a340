"""Bouc-Wen hysteretic benchmark (Noël & Schoukens 2016): fits on the training realisation, official test scores.

Protocol (see `fj.boucwen.score_boucwen`): fit on `load_boucwen().train` (5 periods x 8192 samples of a 5-150 Hz
multisine, output noise 8e-6 m RMS); the first periods train, the last one validates (model selection and
early stopping); the test records are used only for the final scores: free-run simulation RMSE [m] on the
multisine test (3 periods from rest, the last scored) and on the sine sweep (from rest). One JSON line per
model with the machine and the versions:

- `true model`: `fj.BoucWen.benchmark()` (published parameters, RK4 at 15 kHz): the floor of the protocol;
- `linear ARX`: y_k = sum a_i y_{k-i} + sum b_j u_{k-j}, least squares (`fj.lstsq`), orders chosen by the
  free-run RMSE on the validation period, simulated with `scipy.signal.lfilter`;
- `grey-box Bouc-Wen (OE)`: `fj.BoucWen` with all parameters but `nu` free (m, c, k, alpha, beta, gamma, delta),
  started from rough guesses (each off the published value by 20-50 %), fitted by `fj.fit` with `fj.boucwen.BoucWenLoss`
  (free-run output error), Levenberg-Marquardt with `fj.ParameterScaling()`, RK4 with 4 steps per sample
  (the fitted model is scored with the same integrator). With nu = 1 only the products beta*gamma and
  beta*delta are identifiable, so beta, gamma, delta separately need not match the published values;
- `MLP NARX (NOE)`: a black box, `fj.MLPNARX` (16 tanh units and a linear part) on the regressors
  `u_k .. u_{k-4}, y_{k-1} .. y_{k-4}` (normalised by the training record), run on the force by
  `fj.InputOutputModel(narx, "u")`: teacher forcing (`fj.OneStepLoss`, Levenberg-Marquardt), then free-run output
  error (`fj.SimulationLoss`, Levenberg-Marquardt), the model of least validation error kept;
- `GSNN (NOE)`: the papers' generalised shunting neural network (`fj.GSNN`, worden2007 §6; 5 units and a linear
  part) on the same regressors, trained the same way;
- `recurrent network (NOE)`: a black box, `fj.RecurrentNetwork` (parlitz2004 eqs. 26-28; 45 leaky elements, 20 %
  connectivity, spectral radius 0.95, the force and its copies delayed by 1 and 2 samples as inputs) run on the
  force by `fj.InputOutputModel`: readout by least squares, then every weight by free-run output error (Adam,
  learning rate 3e-3), the model of least validation error kept;
- `oscillator + <element>`: `fj.HystereticOscillator`, the benchmark's mass-spring-damper with a friction model of
  the displacement in place of the Bouc-Wen force z: no element (the linear oscillator, the reference of the
  family), Maxwell-slip NLR(8) (stiffnesses and thresholds free), Maxwell-slip DLR(12) (preassigned thresholds,
  signed weights), GMS(4) with an exponential Stribeck curve, Dahl, and a hybrid: a tanh network (8 units and a
  linear part) of the displacement, the velocity and 8 play operators of the displacement. All started from
  m = 2 kg, c = 10 N s/m, k = 5e4 N/m and fitted like the grey box (OE, Levenberg-Marquardt, element offsets
  frozen at 0), 8 velocity-Verlet substeps per sample.

Anchors (multisine test RMSE): PNLSS 1.87e-5 m, dynoNet 4.52e-5 m, NFIR 16.3e-5 m.

Run: `python benchmarks/boucwen.py [--smoke] [--out FILE]`; the data folder is `$FRICJAX_DATA` (default
`../shared/data` beside the repository).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time
from typing import Any

import equinox as eqx
import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import optax  # noqa: E402
import scipy.signal  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
GREY_START = {"m": 2.4, "c": 15.0, "k": 6e4, "alpha": 4e4, "beta": 1.5e3, "gamma": 0.6, "delta": -0.8, "nu": 1.0}


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def line(name: str, model_scores: tuple[float, float], train_rmse: float, fit_s: float, **extra: Any) -> dict:
    return {
        "kind": "boucwen",
        "name": name,
        "test_rmse_m": model_scores[0],
        "sweep_rmse_m": model_scores[1],
        "train_rmse_m": train_rmse,
        "fit_s": fit_s,
        **extra,
        **environment(fricjax=fj.__version__),
    }


# ---------------------------------------------------------------------------------------------------------------
# linear ARX


def arx_rows(u: np.ndarray, y: np.ndarray, na: int, nb: int) -> tuple[np.ndarray, np.ndarray]:
    lag = max(na, nb)
    rows = [y[lag - i : len(y) - i] for i in range(1, na + 1)] + [u[lag - j : len(u) - j] for j in range(1, nb + 1)]
    return np.stack(rows, axis=1), y[lag:]


def arx_simulate(theta: np.ndarray, na: int, nb: int, u: np.ndarray) -> np.ndarray:
    a = np.concatenate([[1.0], -theta[:na]])
    b = np.concatenate([[0.0], theta[na:]])
    return scipy.signal.lfilter(b, a, u)


def arx(train: fj.BoucWenRecord, valid_u: np.ndarray, valid_y: np.ndarray, burn: int, orders: list[int]) -> dict:
    t0 = time.perf_counter()
    best: tuple[float, int, np.ndarray] | None = None
    scale = np.std(train.u) / np.std(train.y)
    for n in orders:
        X, target = arx_rows(train.u, train.y * scale, n, n)
        theta = np.asarray(fj.lstsq(X, target).x)
        val = arx_simulate(theta, n, n, valid_u)[burn:] / scale
        score = rmse(val, valid_y[burn:])
        if np.isfinite(score) and (best is None or score < best[0]):
            best = (score, n, theta)
    assert best is not None
    return {"order": best[1], "theta": best[2], "scale": scale, "fit_s": time.perf_counter() - t0, "valid": best[0]}


def scored_line(
    name: str,
    model: Any,
    data: fj.BoucWenData,
    sweep: fj.BoucWenRecord,
    train: fj.BoucWenRecord,
    fit_s: float,
    **extra: Any,
) -> dict:
    """The JSON line of a fitted model: the official test scores and the training free-run RMSE."""
    scores = fj.boucwen.score_boucwen(model, data.multisine, sweep)
    return line(name, scores[:2], rmse(fj.simulate(model, fj.boucwen_inputs(train.u)), train.y), fit_s, **extra)


def fit_output_error(
    start: Any, train: fj.BoucWenRecord, whole: fj.BoucWenRecord, valid_burn: int, steps: int, freeze: tuple
) -> tuple[Any, float, float]:
    """Free-run output error (`fj.boucwen.BoucWenLoss`), Levenberg-Marquardt with `ParameterScaling`, the 5th training
    period validating: (fit result, fit seconds, validation RMSE [m])."""
    t0 = time.perf_counter()
    result = fj.fit(
        start,
        train,
        loss=fj.boucwen.BoucWenLoss(validation_burn_in=valid_burn),
        validation=whole,
        solver=fj.levenberg_marquardt(),
        steps=steps,
        freeze=freeze,
        scaling=fj.ParameterScaling(),
    )
    fit_s = time.perf_counter() - t0
    return result, fit_s, float(result.val_loss) ** 0.5 * float(np.std(whole.y[valid_burn:]))


def black_box_narx(
    kind: str, train: fj.BoucWenRecord, whole: fj.BoucWenRecord, valid_burn: int, steps: tuple[int, int]
) -> dict:
    """A black-box NARX (`kind` "mlp": 16 tanh units, "gsnn": 5 GSNN units; both with a linear part): teacher
    forcing, then NOE, both by Levenberg-Marquardt; `steps` of each."""
    lags, width = 4, (16 if kind == "mlp" else 5)
    data = fj.input_output_data(train.u, train.y, train.dt)
    validation = fj.input_output_data(whole.u, whole.y, whole.dt)
    regressors = fj.NARXRegressors.from_data(data, ("x",), input_lags=lags, output_lags=lags)
    network = fj.MLPNARX if kind == "mlp" else fj.GSNN
    start = network.init(regressors, width, key=jax.random.PRNGKey(0), linear=True)
    t0 = time.perf_counter()
    teacher = fj.fit(start, data, loss=fj.OneStepLoss(), solver=fj.levenberg_marquardt(), steps=steps[0])
    noe = fj.fit(
        teacher.model,
        data,
        loss=fj.SimulationLoss(),
        solver=fj.levenberg_marquardt(),
        steps=steps[1],
        validation=validation,
        validation_burn_in=valid_burn,
    )
    return {
        "model": fj.InputOutputModel(noe.model, "u"),
        "fit_s": time.perf_counter() - t0,
        "lags": lags,
        "width": width,
        "steps": list(steps),
        "fit_result": noe.code,
        "parameters": int(
            sum(np.size(leaf) for leaf in jax.tree_util.tree_leaves(eqx.filter(noe.model, eqx.is_inexact_array)))
        ),
    }


def recurrent_network(
    train: fj.BoucWenRecord, whole: fj.BoucWenRecord, valid_burn: int, elements: int, steps: int
) -> dict:
    """The parlitz2004 dynamical network as a black box on the force: readout by least squares, then NOE (Adam)."""
    data = fj.input_output_data(train.u, train.y, train.dt)
    validation = fj.input_output_data(whole.u, whole.y, whole.dt)
    start = fj.RecurrentNetwork.init(
        data,
        elements,
        key=jax.random.PRNGKey(0),
        signals=("x",),
        delays=(0, 1, 2),
        connectivity=0.2,
        spectral_radius=0.95,
    )
    t0 = time.perf_counter()
    readout = fj.fit(start, data, train=("theta", "theta0"), separable=("theta", "theta0"), steps=1)
    noe = fj.fit(
        readout.model,
        data,
        loss=fj.SimulationLoss(),
        solver=optax.adam(3e-3),
        steps=steps,
        validation=validation,
        validation_burn_in=valid_burn,
    )
    return {
        "model": fj.InputOutputModel(noe.model, "u"),
        "fit_s": time.perf_counter() - t0,
        "elements": elements,
        "steps": steps,
        "fit_result": noe.code,
    }


def oscillator_elements(train: fj.BoucWenRecord) -> list[tuple[str, Any, tuple[str, ...]]]:
    """The restoring-force elements of the `fj.HystereticOscillator` rows: (name, element, frozen fields)."""
    y_scale = float(np.std(train.y))
    v_scale = float(np.std(np.diff(train.y)) / train.dt)
    hybrid = fj.NARXRegressors(
        ("x", "v"),
        input_lags=0,
        output_lags=0,
        input_mean=[0.0, 0.0],
        input_scale=[y_scale, v_scale],
        output_scale=50.0,  # N, the size of the Bouc-Wen force z
        plays=np.geomspace(5e-5, 2e-3, 8),
    )
    no_element = fj.MaxwellSlip.nlr(k=[1.0], thresholds=fj.Fixed(np.array([1e3])))  # never slips: k + 1 N/m
    return [
        ("none (linear oscillator)", no_element, ("element.force_map.k", "element.force_map.offset")),
        (
            "Maxwell-slip NLR(8)",
            fj.MaxwellSlip.nlr(k=np.full(8, 5e4 / 8), thresholds=np.geomspace(2e-5, 2e-3, 8)),
            ("element.force_map.offset",),
        ),
        (
            "Maxwell-slip DLR(12, signed weights)",
            fj.MaxwellSlip.dlr(theta=np.full((1, 12), 5e4 * 2e-3 / 12), max_deflection=2e-3),
            ("element.force_map.offset",),
        ),
        (
            "GMS(4)",
            fj.GMS(fj.ExponentialStribeck(Fc=20.0, Fs=25.0, vs=0.01), k=[1e5, 5e4, 2e4, 1e4], alpha=[0.25] * 4, C=1e3),
            ("element.offset",),
        ),
        ("Dahl", fj.Dahl(sigma0=5e4, Fc=60.0, alpha=1.0), ("element.offset", "element.F0")),
        ("hybrid: MLP of y, v and 8 plays", fj.MLPNARX.init(hybrid, 8, key=jax.random.PRNGKey(0), linear=True), ()),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="tiny sizes for CI (< 60 s)")
    parser.add_argument("--out", default=None, help="append the JSON lines to this file")
    args = parser.parse_args()
    os.environ.setdefault("FRICJAX_DATA", str(HERE.parent.parent / "shared" / "data"))
    data = fj.load_boucwen()
    P = fj.BOUCWEN_PERIOD
    if args.smoke:
        n_train, steps, substeps, orders, narx_steps, gsnn_steps = 2048, 3, 2, [2, 3], (3, 3), (3, 3)
        oscillator_steps, oscillator_substeps, rnn_elements, rnn_steps = 2, 2, 8, 3
        full = data.sinesweep
        sweep = fj.BoucWenRecord(full.u[:7500], full.y[:7500], full.dt, "sinesweep (first 10 s)", full.source)
    else:
        n_train, steps, substeps, orders = 4 * P, 80, 4, [2, 3, 4, 6, 8, 10]
        narx_steps, gsnn_steps = (30, 400), (30, 200)
        oscillator_steps, oscillator_substeps, rnn_elements, rnn_steps = 80, 8, 45, 3000
        sweep = data.sinesweep
    train = fj.BoucWenRecord(data.train.u[:n_train], data.train.y[:n_train], data.train.dt, "train", data.train.source)
    valid_burn = 4 * P  # the last period of train.h5 validates, entered from the state its history gives
    lines = []

    true = fj.BoucWen.benchmark()
    scores = fj.boucwen.score_boucwen(true, data.multisine, sweep)
    train_true = rmse(fj.simulate(true, fj.boucwen_inputs(train.u)), train.y)
    lines.append(line("true model (published parameters, RK4 15 kHz)", scores[:2], train_true, 0.0))

    fit_arx = arx(train, data.train.u, data.train.y, valid_burn, orders)
    n, theta, scale = fit_arx["order"], fit_arx["theta"], fit_arx["scale"]
    ms = arx_simulate(theta, n, n, np.tile(data.multisine.u, fj.boucwen.BOUCWEN_STEADY_PERIODS))[-P:] / scale
    sw = arx_simulate(theta, n, n, sweep.u) / scale
    tr = arx_simulate(theta, n, n, train.u) / scale
    lines.append(
        line(
            f"linear ARX({n},{n}) (least squares, order by validation)",
            (rmse(ms, data.multisine.y), rmse(sw, sweep.y)),
            rmse(tr, train.y),
            fit_arx["fit_s"],
            valid_rmse_m=fit_arx["valid"],
        )
    )

    start = fj.BoucWen(**GREY_START, substeps=substeps)
    result, fit_s, valid_rmse = fit_output_error(start, train, data.train, valid_burn, steps, ("nu",))
    fitted = fj.unwrap(result.model)
    lines.append(
        scored_line(  # scored with the integrator it was fitted with (RK4, `substeps` per sample)
            "grey-box Bouc-Wen (OE, Levenberg-Marquardt)",
            result.model,
            data,
            sweep,
            train,
            fit_s,
            steps=steps,
            substeps=substeps,
            valid_rmse_m=valid_rmse,
            fit_result=result.code,
            start=GREY_START,
            parameters={name: float(getattr(fitted, name)) for name in GREY_START},
        )
    )
    black_boxes = [
        (
            f"{name} (teacher forcing, then NOE)",
            lambda kind=kind, st=st: black_box_narx(kind, train, data.train, valid_burn, st),
        )
        for kind, name, st in (("mlp", "MLP NARX", narx_steps), ("gsnn", "GSNN", gsnn_steps))
    ]
    black_boxes.append(
        (
            "recurrent network (readout by least squares, then NOE)",
            lambda: recurrent_network(train, data.train, valid_burn, rnn_elements, rnn_steps),
        )
    )
    for label, fit_black_box in black_boxes:
        fitted_box = fit_black_box()
        model = fitted_box.pop("model")
        valid = fj.simulate(model, fj.boucwen_inputs(data.train.u))[valid_burn:]
        fitted_box["valid_rmse_m"] = rmse(valid, data.train.y[valid_burn:])
        lines.append(scored_line(label, model, data, sweep, train, fitted_box.pop("fit_s"), **fitted_box))
    for name, element, frozen in oscillator_elements(train):
        if args.smoke and name.startswith(("Maxwell-slip DLR", "GMS", "Dahl")):
            continue  # the smoke run keeps one element of each kind (linear, Maxwell-slip, network)
        start = fj.HystereticOscillator(m=2.0, c=10.0, k=5e4, element=element, substeps=oscillator_substeps)
        result, fit_s, valid_rmse = fit_output_error(start, train, data.train, valid_burn, oscillator_steps, frozen)
        fitted = fj.unwrap(result.model)
        lines.append(
            scored_line(
                f"oscillator + {name} (OE, Levenberg-Marquardt)",
                result.model,
                data,
                sweep,
                train,
                fit_s,
                steps=oscillator_steps,
                substeps=oscillator_substeps,
                valid_rmse_m=valid_rmse,
                fit_result=result.code,
                m_c_k=[float(fitted.m), float(fitted.c), float(fitted.k)],
            )
        )
    for entry in lines:
        text = json.dumps(entry)
        print(text, flush=True)
        if args.out:
            with open(args.out, "a") as handle:
                handle.write(text + "\n")


if __name__ == "__main__":
    sys.exit(main())
