"""Gradient / Levenberg-Marquardt fits against scipy's Nelder-Mead (the papers' method) from the same start.

For LuGre and GMS (N = 4) on 40 000 samples of synthetic data from the exact model (an excitation going
from pre-sliding into gross sliding), the same loss (simulation NMSE, smooth model) is minimised by
`fj.fit(..., solver=fj.levenberg_marquardt())` and by `scipy.optimize.minimize(method="Nelder-Mead")` over the
same unconstrained parameter vector, starting 50 % off. Nelder-Mead gets the jit-compiled fricjax loss as its
black box (the fastest evaluator it could have). Printed, one JSON line per model: each method's final loss,
wall time (compile time separately), the time fricjax needs to reach Nelder-Mead's final loss, the speed-up,
and the parameter errors.

Run: `python benchmarks/fit.py [--steps 40000] [--nm-evals 4000] [--models lugre gms4]`; first-call latency against
scipy's TRF recipe: `python benchmarks/fit.py --latency [--repeats 3]` (each call in a fresh process).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.flatten_util  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
import scipy.optimize  # noqa: E402

import fricjax as fj  # noqa: E402


def excitation(steps: int, dt: float = 1e-3) -> fj.Motion:
    """1 Hz sine whose amplitude rises from 2 um (pre-sliding) to 1 mm (sliding) and back."""
    t = np.arange(steps) * dt
    amplitude = 2e-6 * (1e-3 / 2e-6) ** (0.5 * (1 - np.cos(2 * np.pi * t / t[-1])))
    return fj.Motion.from_position(amplitude * np.sin(2 * np.pi * t), dt=dt)


def models(name: str) -> tuple[Any, Any, float]:
    """(truth, start 50 % off, smoothing eps) for a benchmark model."""
    if name == "lugre":
        truth = fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 2e-3, 2.0), sigma0=1e5, sigma1=300.0, sigma2=40.0)
        start = fj.LuGre(fj.ExponentialStribeck(1.5, 0.75, 1e-3, 3.0), sigma0=5e4, sigma1=450.0, sigma2=20.0)
        return truth, start, 1e-6
    if name == "gms4":
        stribeck = fj.ExponentialStribeck(1.0, 1.5, 2e-3, 2.0)
        truth = fj.GMS(stribeck, k=[6e4, 2.5e4, 1e4, 5e3], alpha=[0.1, 0.2, 0.3, 0.4], C=50.0, sigma2=40.0)
        start = fj.GMS(
            fj.ExponentialStribeck(1.5, 0.75, 1e-3, 3.0),
            k=[9e4, 3.75e4, 1.5e4, 7.5e3],
            alpha=[0.15, 0.3, 0.2, 0.35],
            C=75.0,
            sigma2=20.0,
        )
        return truth, start, 1e-9
    raise ValueError(name)


def parameter_errors(fitted: Any, truth: Any) -> dict[str, float]:
    """Max relative error per field (GMS elements compared after sorting by stiffness)."""
    f, t = fj.unwrap(fj.exact(fitted)), fj.unwrap(fj.exact(truth))
    out = {}
    for (path, a), (_, b) in zip(
        jax.tree_util.tree_leaves_with_path(f), jax.tree_util.tree_leaves_with_path(t), strict=True
    ):
        name = "".join(str(p) for p in path).lstrip(".")
        a, b = np.asarray(a), np.asarray(b)
        if name in ("k", "alpha") and isinstance(fitted, fj.GMS):
            order_a = np.argsort(np.asarray(f.k))
            order_b = np.argsort(np.asarray(t.k))
            a, b = a[order_a], b[order_b]
        if np.all(b == 0):
            continue
        out[name] = float(np.max(np.abs(a - b) / np.abs(b)))
    return out


def bench(name: str, steps: int, nm_evals: int) -> dict[str, Any]:
    truth, start, eps = models(name)
    max_lm_steps = 200 if name == "lugre" else 64
    motion = excitation(steps)
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    start = fj.with_smoothing(start, fj.Smooth(eps))

    # Nelder-Mead on the same loss over the same unconstrained vector
    params, static = eqx.partition(start, fj.trainable_filter(start))
    flat0, unravel = jax.flatten_util.ravel_pytree(params)
    loss_fn = fj.SimulationLoss()
    objective = jax.jit(lambda f: loss_fn(eqx.combine(unravel(f), static), None, data))
    objective(flat0).block_until_ready()
    trace: list[tuple[float, float]] = []
    t0 = time.perf_counter()

    def f(x: np.ndarray) -> float:
        value = float(objective(jnp.asarray(x)))
        trace.append((time.perf_counter() - t0, value))
        return value

    nm = scipy.optimize.minimize(
        f, np.asarray(flat0), method="Nelder-Mead", options={"maxfev": nm_evals, "xatol": 1e-10, "fatol": 1e-16}
    )
    nm_time = time.perf_counter() - t0
    nm_loss = float(nm.fun)
    nm_model = eqx.combine(unravel(jnp.asarray(nm.x)), static)

    # Levenberg-Marquardt; time to reach Nelder-Mead's final loss from LM runs of growing max_steps, each timed
    # on its second (compiled) call
    solver = fj.levenberg_marquardt()
    t0 = time.perf_counter()
    result = fj.fit(start, data, solver=solver, steps=max_lm_steps, scaling=fj.ParameterScaling(), compute_std=False)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = fj.fit(start, data, solver=solver, steps=max_lm_steps, scaling=fj.ParameterScaling(), compute_std=False)
    fj_time = time.perf_counter() - t0
    method = f"LevenbergMarquardt (max {max_lm_steps} steps)"
    reach_time, reach_steps = (fj_time, result.evaluations) if result.train_loss <= nm_loss else (None, None)
    for max_steps in (1, 2, 4, 8, 16, 32):
        fj.fit(start, data, solver=solver, steps=max_steps, scaling=fj.ParameterScaling(), compute_std=False)  # compile
        t0 = time.perf_counter()
        partial = fj.fit(start, data, solver=solver, steps=max_steps, scaling=fj.ParameterScaling(), compute_std=False)
        elapsed = time.perf_counter() - t0
        if partial.train_loss <= nm_loss:
            reach_time, reach_steps = elapsed, max_steps
            break
    fj_loss = result.train_loss
    nm_reach = next((t for t, v in trace if v <= fj_loss), None)
    speedup = nm_time / reach_time if reach_time else None
    return {
        "benchmark": "fit",
        "model": name,
        "steps": steps,
        "fricjax_solver": method,
        "fricjax_loss": fj_loss,
        "fricjax_exact_nmse_percent": float(fj.nmse(data.force, fj.simulate(fj.exact(result.model), motion))),
        "fricjax_time_s": fj_time,
        "fricjax_first_call_s": first,
        "fricjax_evaluations": result.evaluations,
        "fricjax_result": result.code,
        "fricjax_param_rel_errors": parameter_errors(result.model, truth),
        "nm_loss": nm_loss,
        "nm_time_s": nm_time,
        "nm_evaluations": int(nm.nfev),
        "nm_param_rel_errors": parameter_errors(nm_model, truth),
        "nm_time_to_fricjax_loss_s": nm_reach,
        "fricjax_time_to_nm_loss_s": reach_time,
        "fricjax_steps_to_nm_loss": reach_steps,
        "speedup_to_nm_loss": speedup,
        "target_speedup": 20.0,
        "pass": bool(speedup is not None and speedup >= 20.0),
        "jax": jax.__version__,
        "scipy": scipy.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "cpu": platform.processor() or platform.machine(),
    }


LATENCY_METHODS = ("fricjax_lm", "fricjax_lm_tol_1e-8", "scipy_trf_jacfwd", "fricjax_optimistix_lm")


def latency_once(method: str, steps: int) -> dict[str, Any]:
    """One method's first call (compilation included) and warm call, in this process (run it in a fresh one).

    The same problem for every method: LuGre on `steps` samples of the exact model, fitted (smoothed, eps 1e-6)
    from 50 % off; the same trained parameters (`fj.trainable_filter`: the smoothing width stays fixed) and the same
    loss (mean squared error / force variance). `fricjax_lm`: `fj.fit` with `fj.levenberg_marquardt()` (its
    tolerances, rtol 1e-10, atol 1e-12) and `fj.ParameterScaling()`; `fricjax_lm_tol_1e-8`: the same at scipy's
    default tolerance level (`fj.levenberg_marquardt(rtol=1e-8, atol=1e-8)`: parameters in log or scaled units, so
    both are relative changes, as scipy's `xtol`); `fricjax_optimistix_lm`: `fj.fit` with optimistix's
    Levenberg-Marquardt (the solver `fj.levenberg_marquardt()` returned before); `scipy_trf_jacfwd`: the savvy
    user's recipe, scipy's `least_squares` (TRF, its default tolerances 1e-8) with `jax.jit` of the residuals and
    of their `jax.jacfwd`."""
    import optimistix as optx

    motion = excitation(steps)
    truth, start, eps = models("lugre")
    data = fj.FrictionData(motion, fj.simulate(truth, motion))  # compiles the simulator once (both methods)
    start = fj.with_smoothing(start, fj.Smooth(eps))
    times, losses, evaluations = [], [], []
    if method.startswith("fricjax"):
        solver = {
            "fricjax_lm": fj.levenberg_marquardt(),
            "fricjax_lm_tol_1e-8": fj.levenberg_marquardt(rtol=1e-8, atol=1e-8),
            "fricjax_optimistix_lm": optx.LevenbergMarquardt(1e-10, 1e-12),
        }[method]
        for _ in range(2):
            t0 = time.perf_counter()
            result = fj.fit(start, data, solver=solver, steps=60, scaling=fj.ParameterScaling())
            times.append(time.perf_counter() - t0)
            losses.append(float(result.train_loss))
            evaluations.append(int(result.evaluations))
    else:
        params, static = eqx.partition(start, fj.trainable_filter(start))
        flat, unravel = jax.flatten_util.ravel_pytree(params)
        force = jnp.asarray(data.force)
        scale = float(jnp.std(force))

        def residuals(p: Any) -> Any:
            return (fj.simulate(eqx.combine(unravel(p), static), motion) - force) / scale

        res, jac = jax.jit(residuals), jax.jit(jax.jacfwd(residuals))  # compiled at the first call
        for _ in range(2):
            t0 = time.perf_counter()
            solution = scipy.optimize.least_squares(
                lambda p: np.asarray(res(p)), np.asarray(flat), jac=lambda p: np.asarray(jac(p)), method="trf"
            )
            times.append(time.perf_counter() - t0)
            losses.append(float(np.mean(solution.fun**2)))
            evaluations.append(int(solution.nfev + solution.njev))
    return {
        "method": method,
        "first_s": times[0],
        "warm_s": times[1],
        "loss": losses[-1],
        "evaluations": evaluations[-1],
    }


def latency(steps: int, repeats: int) -> dict[str, Any]:
    """First-call and warm wall time of each method, each call in a fresh process (`repeats` processes per method,
    the methods interleaved), medians reported."""
    import subprocess
    import sys

    runs: dict[str, list[dict[str, Any]]] = {method: [] for method in LATENCY_METHODS}
    for _ in range(repeats):
        for method in LATENCY_METHODS:
            out = subprocess.run(
                [sys.executable, __file__, "--latency-method", method, "--steps", str(steps)],
                check=True, capture_output=True, text=True,
            ).stdout  # fmt: skip
            runs[method].append(json.loads(out.strip().splitlines()[-1]))
    median = lambda method, key: round(float(np.median([run[key] for run in runs[method]])), 3)  # noqa: E731
    return {
        "bench": "fit_latency",
        "samples": steps,
        "processes_per_method": repeats,
        "first_call_s": {method: median(method, "first_s") for method in LATENCY_METHODS},
        "warm_s": {method: median(method, "warm_s") for method in LATENCY_METHODS},
        "first_call_runs_s": {method: [round(run["first_s"], 3) for run in runs[method]] for method in LATENCY_METHODS},
        "loss": {method: runs[method][-1]["loss"] for method in LATENCY_METHODS},
        "evaluations": {method: runs[method][-1]["evaluations"] for method in LATENCY_METHODS},
        "loss_note": "mean squared error / force variance, the same trained parameters (smoothing width fixed)",
        "evaluations_note": "fricjax: solver steps (each one residual + Jacobian evaluation); scipy: nfev + njev",
        "jax": jax.__version__,
        "scipy": scipy.__version__,
        "python": platform.python_version(),
        "device": str(jax.devices()[0]),
        "cpu_count": os.cpu_count(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=40000)
    parser.add_argument("--nm-evals", type=int, default=4000)
    parser.add_argument("--models", nargs="+", default=["lugre", "gms4"])
    parser.add_argument("--latency", action="store_true", help="first-call and warm LM fit vs scipy TRF + jacfwd")
    parser.add_argument("--repeats", type=int, default=3, help="fresh processes per method for --latency")
    parser.add_argument("--latency-method", choices=LATENCY_METHODS, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.latency_method:
        print(json.dumps(latency_once(args.latency_method, args.steps)), flush=True)
        return
    if args.latency:
        print(json.dumps(latency(args.steps, args.repeats)), flush=True)
        return
    for name in args.models:
        print(json.dumps(bench(name, args.steps, args.nm_evals)), flush=True)


if __name__ == "__main__":
    main()
