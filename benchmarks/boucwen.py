"""Bouc-Wen hysteretic benchmark (Noël & Schoukens 2016): fits on the training realisation, official test scores.

Protocol (see `fj.score_boucwen`): fit on `load_boucwen().train` (5 periods x 8192 samples of a 5-150 Hz
multisine, output noise 8e-6 m RMS); the first periods train, the last one validates (model selection and
early stopping); the test records are used only for the final scores: free-run simulation RMSE [m] on the
multisine test (3 periods from rest, the last scored) and on the sine sweep (from rest). One JSON line per
model with the machine and the versions:

- `true model`: `fj.BoucWen.benchmark()` (published parameters, RK4 at 15 kHz): the floor of the protocol;
- `linear ARX`: y_k = sum a_i y_{k-i} + sum b_j u_{k-j}, least squares (`fj.lstsq`), orders chosen by the
  free-run RMSE on the validation period, simulated with `scipy.signal.lfilter`;
- `grey-box Bouc-Wen (OE)`: `fj.BoucWen` with all parameters but `nu` free (m, c, k, alpha, beta, gamma, delta),
  started from rough guesses (each off the published value by 20-50 %), fitted by `fj.fit` with `fj.BoucWenLoss`
  (free-run output error), Levenberg-Marquardt with `fj.ParameterScaling()`, RK4 with 4 steps per sample
  (the fitted model is scored with the same integrator). With nu = 1 only the products beta*gamma and
  beta*delta are identifiable, so beta, gamma, delta separately need not match the published values;
- `MLP NARX (NOE)`: a black box, `fj.MLPNARX` (16 tanh units and a linear part) on the regressors
  `u_k .. u_{k-4}, y_{k-1} .. y_{k-4}` (normalised by the training record), run on the force by
  `fj.InputOutputModel(narx, "u")`: teacher forcing (`fj.OneStepLoss`, Levenberg-Marquardt), then free-run output
  error (`fj.SimulationLoss`, Levenberg-Marquardt), the model of least validation error kept;
- `GSNN (NOE)`: the papers' generalised shunting neural network (`fj.GSNN`, worden2007 §6; 5 units and a linear
  part) on the same regressors, trained the same way.

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
        "fit_result": noe.result,
        "parameters": int(
            sum(np.size(leaf) for leaf in jax.tree_util.tree_leaves(eqx.filter(noe.model, eqx.is_inexact_array)))
        ),
    }


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
        full = data.sinesweep
        sweep = fj.BoucWenRecord(full.u[:7500], full.y[:7500], full.dt, "sinesweep (first 10 s)", full.source)
    else:
        n_train, steps, substeps, orders = 4 * P, 80, 4, [2, 3, 4, 6, 8, 10]
        narx_steps, gsnn_steps = (30, 400), (30, 200)
        sweep = data.sinesweep
    train = fj.BoucWenRecord(data.train.u[:n_train], data.train.y[:n_train], data.train.dt, "train", data.train.source)
    valid_burn = 4 * P  # the last period of train.h5 validates, entered from the state its history gives
    lines = []

    true = fj.BoucWen.benchmark()
    scores = fj.score_boucwen(true, data.multisine, sweep)
    train_true = rmse(fj.simulate(true, fj.boucwen_inputs(train.u)), train.y)
    lines.append(line("true model (published parameters, RK4 15 kHz)", scores[:2], train_true, 0.0))

    fit_arx = arx(train, data.train.u, data.train.y, valid_burn, orders)
    n, theta, scale = fit_arx["order"], fit_arx["theta"], fit_arx["scale"]
    ms = arx_simulate(theta, n, n, np.tile(data.multisine.u, fj.BOUCWEN_STEADY_PERIODS))[-P:] / scale
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
    t0 = time.perf_counter()
    result = fj.fit(
        start,
        train,
        loss=fj.BoucWenLoss(validation_burn_in=valid_burn),
        validation=data.train,
        solver=fj.levenberg_marquardt(),
        steps=steps,
        freeze=("nu",),
        scaling=fj.ParameterScaling(),
    )
    fit_s = time.perf_counter() - t0
    fitted = fj.unwrap(result.model)
    params = {name: float(getattr(fitted, name)) for name in GREY_START}
    model = result.model  # scored with the integrator it was fitted with (RK4, `substeps` per sample)
    scores = fj.score_boucwen(model, data.multisine, sweep)
    train_fit = rmse(fj.simulate(model, fj.boucwen_inputs(train.u)), train.y)
    lines.append(
        line(
            "grey-box Bouc-Wen (OE, Levenberg-Marquardt)",
            scores[:2],
            train_fit,
            fit_s,
            steps=steps,
            substeps=substeps,
            valid_rmse_m=float(result.val_loss) ** 0.5 * float(np.std(data.train.y[valid_burn:])),
            fit_result=result.result,
            start=GREY_START,
            parameters=params,
        )
    )
    for kind, name, kind_steps in (("mlp", "MLP NARX", narx_steps), ("gsnn", "GSNN", gsnn_steps)):
        narx = black_box_narx(kind, train, data.train, valid_burn, kind_steps)
        model = narx.pop("model")
        scores = fj.score_boucwen(model, data.multisine, sweep)
        train_fit = rmse(fj.simulate(model, fj.boucwen_inputs(train.u)), train.y)
        valid = fj.simulate(model, fj.boucwen_inputs(data.train.u))[valid_burn:]
        narx["valid_rmse_m"] = rmse(valid, data.train.y[valid_burn:])
        label = f"{name} (teacher forcing, then NOE)"
        lines.append(line(label, scores[:2], train_fit, narx.pop("fit_s"), **narx))
    for entry in lines:
        text = json.dumps(entry)
        print(text, flush=True)
        if args.out:
            with open(args.out, "a") as handle:
                handle.write(text + "\n")


if __name__ == "__main__":
    sys.exit(main())
