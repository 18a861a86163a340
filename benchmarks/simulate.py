#!/usr/bin/env python
"""Benchmark `fj.simulate` against hand-written numba loops of the same exact discrete equations.

Run as `python benchmarks/simulate.py [--steps N] [--batch B] [--batch-steps T] [--quick]`; see
benchmarks/README.md for what each figure means. Prints one JSON object per line:

- `single`: one trajectory, `eqx.filter_jit(fj.simulate)` with `unroll` in {1, 2, 4, 8} (and the default), the
  default call's program through `jax.jit` on the array leaves (`"call": "jax.jit"`: the loop without equinox's
  per-call dispatch, the figure the target compares), and the numba `@njit` loop of the same equations (checked
  to agree to 1e-9 relative, else the script fails);
- `vmap`: `eqx.filter_vmap` of `fj.simulate` over a batch of perturbed models (trajectory-steps per second), in
  two output layouts (`"layout"`): rows `(batch, time)` as vmap returns them by default (the target's figure), and
  time-major `(time, batch)` (`out_axes=1`);
- `value_and_grad`: `eqx.filter_value_and_grad` of a mean-squared-error loss vs the forward loss, for the model
  and for `fj.TangentGradients(model)` (`"impl": "fricjax-tangent"`, the tangent-linear derivative);
- `summary`: the three targets, pass / fail per model, and the unroll that minimises the time per step.

`--host-devices N` splits the CPU into N XLA host devices (`--xla_force_host_platform_device_count`, set before
jax starts) and adds `vmap_sharded`: the same batch placed along the devices with `fj.shard_batch` (each device
runs its share on its own thread), the way `fj.sweep` and multi-start fits use every core.

All models are in exact mode (`fj.Exact()`, the default smoothing) and float64. Wall-time figures are
informational: nothing here is a test, and no test asserts on them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any


def _host_devices(argv: list[str]) -> int:
    """`--host-devices N` (read before jax starts: XLA fixes the device count at its first use)."""
    for i, arg in enumerate(argv):
        if arg == "--host-devices" and i + 1 < len(argv):
            return int(argv[i + 1])
        if arg.startswith("--host-devices="):
            return int(arg.split("=", 1)[1])
    return 1


if _host_devices(sys.argv) > 1:
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={_host_devices(sys.argv)}"
    ).strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment as shared_environment  # noqa: E402
from fricjax._simulate import DEFAULT_UNROLL  # noqa: E402

DT = 1e-3
UNROLLS = (1, 2, 4, 8)
MATCH_RTOL = 1e-9  # numba vs fricjax: max |difference| / max |force|

# targets (summary line)
TARGET_SINGLE_RATIO = {"lugre": 1.3, "gms4": 2.0, "maxwell_nlr7": 1.3}  # time per step <= this x numba (issue 12)
TARGET_VMAP_RATIO = 3.0  # vmap throughput >= 3 x numba single-trajectory throughput (issue 12)
TARGET_GRAD_RATIO = 5.0  # value_and_grad time <= 5 x forward time


# --------------------------------------------------------------------------------------------------------------
# Environment
# --------------------------------------------------------------------------------------------------------------


def environment() -> dict[str, Any]:
    return shared_environment(numba=numba.__version__)


ENV: dict[str, Any] = {}


def emit(record: dict[str, Any]) -> None:
    print(json.dumps({**record, **ENV}), flush=True)


# --------------------------------------------------------------------------------------------------------------
# Problem set-up: models and motion
# --------------------------------------------------------------------------------------------------------------


def stribeck(Fc: Any = 1.0, Fs: Any = 1.5) -> fj.ExponentialStribeck:
    return fj.ExponentialStribeck(Fc=Fc, Fs=Fs, vs=1e-3, delta=2.0)


GMS_K = np.array([4e4, 2e4, 1e4, 5e3])
GMS_ALPHA = np.array([0.4, 0.3, 0.2, 0.1])
MS_THRESHOLDS = np.geomspace(1e-6, 3e-5, 7)  # Delta_i [m], 1 um .. 30 um
MS_K = 1.5 / MS_THRESHOLDS / 7  # each element carries ~0.21 N when fully slipped: ~1.5 N in gross sliding


def make_lugre(p: Any) -> fj.LuGre:
    """p = (Fc, Fs, sigma0, sigma1, sigma2)."""
    return fj.LuGre(stribeck(p[0], p[1]), sigma0=p[2], sigma1=p[3], sigma2=p[4])


def make_gms(p: Any) -> fj.GMS:
    """p = (Fc, Fs, C, sigma2, k_scale)."""
    return fj.GMS(stribeck(p[0], p[1]), k=p[4] * GMS_K, alpha=GMS_ALPHA, C=p[2], sigma2=p[3])


def make_maxwell(p: Any) -> fj.MaxwellSlip:
    """p = (k_scale, threshold_scale, offset)."""
    return fj.MaxwellSlip.nlr(k=p[0] * MS_K, thresholds=p[1] * MS_THRESHOLDS, offset=p[2])


# nominal parameter vectors of each model (the models named in the brief)
NOMINAL = {
    "lugre": (make_lugre, np.array([1.0, 1.5, 1e5, 300.0, 0.4])),
    "gms4": (make_gms, np.array([1.0, 1.5, 20.0, 0.4, 1.0])),
    "maxwell_nlr7": (make_maxwell, np.array([1.0, 1.0, 0.0])),
}


def growing_sine(steps: int, dt: float = DT, amplitude: float = 3e-3, cycles: float = 20.0) -> np.ndarray:
    """Displacement [m]: a sine whose amplitude grows from 1 um (pre-sliding) to `amplitude` (gross sliding)."""
    t = np.arange(steps) * dt
    envelope = amplitude * (t / t[-1]) ** 2 + 1e-6
    return envelope * np.sin(2 * np.pi * cycles * t / (steps * dt))


def make_motion(steps: int) -> fj.Motion:
    return fj.Motion.from_position(growing_sine(steps), dt=DT)


# --------------------------------------------------------------------------------------------------------------
# numba reference loops: the same exact discrete equations as the models' `step` methods
# --------------------------------------------------------------------------------------------------------------


@njit(cache=False)
def _sign(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@njit(cache=False)
def _stribeck_exp(v: float, Fc: float, Fs: float, vs: float, delta: float) -> float:
    """ExponentialStribeck.__call__ with abs_pow(u, p) = exp(p log|u|) (0 at u = 0)."""
    au = abs(v / vs)
    ap = math.exp(delta * math.log(au)) if au > 0.0 else 0.0
    return Fc + (Fs - Fc) * math.exp(-ap)


@njit(cache=False)
def _relax(y: float, rate: float, forcing: float, dt: float) -> float:
    """_lugre.relax: y exp(-h) + forcing dt phi1(h), h = rate dt; phi1(h) = -expm1(-h) / h (1 - h/2 for h < 1e-6)."""
    h = rate * dt
    if h < 1e-6:
        phi = 1.0 - 0.5 * h
    else:
        phi = -math.expm1(-h) / h
    return y * math.exp(-h) + forcing * dt * phi


@njit(cache=False)
def lugre_numba(v, dx, dt, Fc, Fs, vs, delta, sigma0, sigma1, sigma2, offset, z0):
    n = v.shape[0]
    out = np.empty(n)
    z = z0
    for i in range(n):
        vi = dx[i] / dt  # velocity held over the step
        rate = sigma0 * (vi * _sign(vi)) / _stribeck_exp(vi, Fc, Fs, vs, delta)
        z = _relax(z, rate, vi, dt)
        dz = vi - rate * z
        out[i] = sigma0 * z + sigma1 * dz + sigma2 * v[i] + offset
    return out


@njit(cache=False)
def gms_numba(v, dx, dt, Fc, Fs, vs, delta, k, alpha, C, sigma2, offset):
    n = v.shape[0]
    m = k.shape[0]
    out = np.empty(n)
    F = np.zeros(m)
    slipping = np.zeros(m, dtype=np.bool_)
    for i in range(n):
        vi = v[i]
        dxi = dx[i]
        s = _stribeck_exp(dxi / dt, Fc, Fs, vs, delta)
        direction = _sign(dxi)
        rate = C / s
        total = 0.0
        for j in range(m):
            Fj = F[j]
            bound = alpha[j] * s
            if slipping[j] and direction * Fj / k[j] > 0.0:
                # keeps slipping: exact relaxation towards alpha_j s(v) sgn(dx)
                Fj = _relax(Fj, rate, C * alpha[j] * direction, dt)
            else:
                # sticks: F + k dx, clipped to +/- alpha_j s(v); the clip starts slipping
                trial = Fj + k[j] * dxi
                slipping[j] = (abs(trial) - bound) / k[j] > 0.0
                Fj = min(max(trial, -bound), bound)
            F[j] = Fj
            total += Fj
        out[i] = total + sigma2 * vi + offset
    return out


@njit(cache=False)
def maxwell_nlr_numba(dx, k, thresholds, offset):
    n = dx.shape[0]
    m = k.shape[0]
    out = np.empty(n)
    delta = np.zeros(m)
    for i in range(n):
        dxi = dx[i]
        total = 0.0
        for j in range(m):
            dbar = min(max((delta[j] + dxi) / thresholds[j], -1.0), 1.0)
            delta[j] = dbar * thresholds[j]
            total += k[j] * delta[j]
        out[i] = total + offset
    return out


def numba_runner(name: str, model: Any, motion: fj.Motion) -> Callable[[], np.ndarray]:
    """A no-argument callable running the numba loop of `model` on `motion`.

    Parameters are read from `fj.unwrap(model)` (the constrained values the JAX step sees, e.g. exp(log k)),
    and the per-step signals are those `fj.simulate` derives (v from the motion, dx = diff(x), dx_0 = 0).
    """
    p = fj.unwrap(model)
    x = np.asarray(motion.x)
    v = np.asarray(motion.v)
    dx = np.diff(x, prepend=x[:1])
    dt = float(motion.dt)

    def f64(a: Any) -> Any:
        a = np.asarray(a, dtype=np.float64)
        return float(a) if a.ndim == 0 else np.ascontiguousarray(a)

    if name == "lugre":
        s = p.stribeck
        args = (v, dx, dt, *map(f64, (s.Fc, s.Fs, s.vs, s.delta, p.sigma0, p.sigma1, p.sigma2, p.offset, p.z0)))
        return lambda: lugre_numba(*args)
    if name == "gms4":
        s = p.stribeck
        args = (v, dx, dt, *map(f64, (s.Fc, s.Fs, s.vs, s.delta, p.k, p.alpha, p.C, p.sigma2, p.offset)))
        return lambda: gms_numba(*args)
    if name == "maxwell_nlr7":
        args = (dx, *map(f64, (p.force_map.k, p.thresholds, p.force_map.offset)))
        return lambda: maxwell_nlr_numba(*args)
    raise ValueError(name)


# --------------------------------------------------------------------------------------------------------------
# Timing helpers
# --------------------------------------------------------------------------------------------------------------


def block(out: Any) -> Any:
    return jax.block_until_ready(out)


def first_call(fn: Callable[[], Any]) -> tuple[float, Any]:
    """Wall time of the first call (trace + compile + one run for a jitted function) and its output."""
    t0 = time.perf_counter()
    out = block(fn())
    return time.perf_counter() - t0, out


def steady(fns: dict[str, Callable[[], Any]], repeats: int, budget_s: float) -> dict[str, dict[str, float]]:
    """Time several no-argument callables round-robin (so a change in machine load hits all of them alike).

    Up to `repeats` rounds, at least 3, stopping once `budget_s` seconds have passed. Returns, per callable,
    the median and the minimum wall time [s] of one call (`block_until_ready` included).
    """
    times: dict[str, list[float]] = {key: [] for key in fns}
    start = time.perf_counter()
    rounds = 0
    while rounds < repeats and (rounds < 3 or time.perf_counter() - start < budget_s):
        for key, fn in fns.items():
            t0 = time.perf_counter()
            block(fn())
            times[key].append(time.perf_counter() - t0)
        rounds += 1
    return {key: {"median": statistics.median(ts), "min": min(ts), "n": len(ts)} for key, ts in times.items()}


def load_average() -> float | None:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


# --------------------------------------------------------------------------------------------------------------
# Benchmarks
# --------------------------------------------------------------------------------------------------------------


def bench_single(name: str, model: Any, motion: fj.Motion, cfg: argparse.Namespace) -> dict[str, Any]:
    """Single trajectory: numba loop vs `filter_jit(fj.simulate)` at the default unroll and at each of UNROLLS."""
    steps = motion.length

    run_numba = numba_runner(name, model, motion)
    numba_compile, force_numba = first_call(run_numba)

    variants: dict[str, Callable[[], Any]] = {"numba": run_numba}
    compile_s: dict[str, float] = {"numba": numba_compile}
    forces: dict[str, np.ndarray] = {}
    for unroll in (None, *UNROLLS):
        key = "default" if unroll is None else f"unroll{unroll}"
        kwargs = {} if unroll is None else {"unroll": unroll}
        jitted = eqx.filter_jit(lambda m, mo, kw=kwargs: fj.simulate(m, mo, **kw))
        variants[key] = lambda fn=jitted: fn(model, motion)
        compile_s[key], out = first_call(variants[key])
        forces[key] = np.asarray(out)
    # the same program called through `jax.jit` on the array leaves: no per-call pytree flattening and hashing by
    # `eqx.filter_jit` (~0.1 ms per call here), so the loop itself is compared with the numba loop
    dynamic, static = eqx.partition((model, motion), eqx.is_array)
    compiled = jax.jit(lambda leaves: fj.simulate(*eqx.combine(leaves, static)))
    variants["compiled"] = lambda: compiled(dynamic)
    compile_s["compiled"], out = first_call(variants["compiled"])
    forces["compiled"] = np.asarray(out)

    timing = steady(variants, cfg.repeats, cfg.budget)
    ns = {key: t["median"] / steps * 1e9 for key, t in timing.items()}
    ns_min = {key: t["min"] / steps * 1e9 for key, t in timing.items()}
    load = load_average()

    # the numba loop must reproduce fj.simulate (exact mode: same equations, same parameters, same signals)
    force_ref = forces["default"]
    diff = float(np.max(np.abs(np.asarray(force_numba) - force_ref)))
    scale = float(np.max(np.abs(force_ref)))
    rel = diff / scale
    match = bool(np.isfinite(rel) and rel <= MATCH_RTOL)
    unroll_spread = max(float(np.max(np.abs(f - force_ref))) for f in forces.values())

    for key in variants:
        if key == "numba":
            continue
        emit(
            {
                "benchmark": "single",
                "model": name,
                "impl": "fricjax",
                "call": "jax.jit" if key == "compiled" else "eqx.filter_jit",
                "unroll": DEFAULT_UNROLL if key in ("default", "compiled") else int(key.removeprefix("unroll")),
                "default_call": key in ("default", "compiled"),
                "steps": steps,
                "ns_per_step": round(ns[key], 2),
                "ns_per_step_min": round(ns_min[key], 2),
                "compile_s": round(compile_s[key], 3),
                "ratio_vs_numba": round(ns[key] / ns["numba"], 3),
                "repeats": timing[key]["n"],
                "loadavg_1min": load,
            }
        )
    emit(
        {
            "benchmark": "single",
            "model": name,
            "impl": "numba",
            "steps": steps,
            "ns_per_step": round(ns["numba"], 2),
            "ns_per_step_min": round(ns_min["numba"], 2),
            "compile_s": round(numba_compile, 3),
            "ratio_vs_numba": 1.0,
            "max_abs_diff": diff,
            "max_rel_diff": rel,
            "max_abs_force": scale,
            "match": match,
            "max_abs_diff_between_unrolls": unroll_spread,
            "repeats": timing["numba"]["n"],
            "loadavg_1min": load,
        }
    )
    if not match:
        raise SystemExit(
            f"FAIL: the numba loop for {name} does not reproduce fj.simulate: max |diff| = {diff:.3e} N "
            f"(relative {rel:.3e} > {MATCH_RTOL:g}); the reference equations are out of sync with the model's step()."
        )
    return {
        "numba_ns": ns["numba"],
        "default_ns": ns["default"],
        "compiled_ns": ns["compiled"],
        "dispatch_us": (timing["default"]["median"] - timing["compiled"]["median"]) * 1e6,
        "unroll_ns": {u: ns[f"unroll{u}"] for u in UNROLLS},
        "run_numba": run_numba,
    }


def batch_parameters(name: str, batch: int, seed: int = 0) -> np.ndarray:
    """`batch` parameter vectors: the nominal one first, the others with each entry scaled by U(0.8, 1.2)."""
    _, nominal = NOMINAL[name]
    rng = np.random.default_rng(seed)
    params = nominal * rng.uniform(0.8, 1.2, size=(batch, nominal.size))
    if name in ("lugre", "gms4"):
        params[:, 1] = np.maximum(params[:, 1], 1.1 * params[:, 0])  # keep Fs > Fc
    if name == "maxwell_nlr7":
        params[:, 2] = rng.uniform(-0.1, 0.1, size=batch)  # offset [N] (nominal 0)
    params[0] = nominal
    return params


@eqx.filter_jit
def vmap_simulate(models: Any, motion: fj.Motion, time_major: bool = False) -> jax.Array:
    """`fj.simulate` of a batch of models (leading axis B) on one motion: forces `(B, T)`, or `(T, B)` with
    `time_major` (`out_axes=1`: the scan's own stacking, no transposition)."""
    return eqx.filter_vmap(lambda m: fj.simulate(m, motion), out_axes=1 if time_major else 0)(models)


def bench_vmap(name: str, run_numba: Callable[[], Any], steps_numba: int, cfg: argparse.Namespace) -> dict[str, Any]:
    """`filter_vmap(fj.simulate)` over `cfg.batch` models on a `cfg.batch_steps` record, vs one numba trajectory.

    Two output layouts, timed in the same rounds: rows `(batch, time)`, what `vmap` returns by default (the
    figure the target is judged on), and time-major `(time, batch)` (`out_axes=1`), the scan's own stacking: the
    difference is XLA's transposition of the whole output (benchmarks/vmap_layout.py splits it further)."""
    make, nominal = NOMINAL[name]
    models = eqx.filter_vmap(make)(jnp.asarray(batch_parameters(name, cfg.batch)))
    motion = make_motion(cfg.batch_steps)

    compile_s, forces = first_call(lambda: vmap_simulate(models, motion))
    compile_time_major_s, forces_tm = first_call(lambda: vmap_simulate(models, motion, time_major=True))
    # spot check: the first trajectory of the batch is the nominal model's, in both layouts
    single = np.asarray(fj.simulate(make(nominal), motion))
    spot = float(np.max(np.abs(np.asarray(forces[0]) - single)))
    spot = max(spot, float(np.max(np.abs(np.asarray(forces_tm[:, 0]) - single))))
    traj_steps = cfg.batch * cfg.batch_steps

    def records(key: str, placed: Any, benchmark: str, extra: dict[str, Any]) -> dict[str, Any]:
        timing = steady(
            {
                key: lambda: vmap_simulate(placed, motion),
                "time_major": lambda: vmap_simulate(placed, motion, time_major=True),
                "numba": run_numba,
            },
            cfg.repeats,
            cfg.budget,
        )
        numba_throughput = steps_numba / timing["numba"]["median"]
        out: dict[str, Any] = {}
        for layout, timed in (("rows (batch, time)", key), ("time-major (time, batch), out_axes=1", "time_major")):
            throughput = traj_steps / timing[timed]["median"]
            out[timed] = {
                "benchmark": benchmark,
                "model": name,
                "impl": "fricjax",
                "layout": layout,
                "batch": cfg.batch,
                "steps": cfg.batch_steps,
                **extra,
                "note": f"batch record of {cfg.batch_steps} steps; numba: one trajectory of {steps_numba} steps",
                "run_s": round(timing[timed]["median"], 4),
                "compile_s": round(compile_s if timed == key else compile_time_major_s, 3),
                "ns_per_step": round(timing[timed]["median"] / traj_steps * 1e9, 3),
                "traj_steps_per_s": round(throughput),
                "numba_traj_steps_per_s": round(numba_throughput),
                "ratio_vs_numba": round(throughput / numba_throughput, 3),
                "max_abs_diff_vs_single": spot,
                "repeats": timing[timed]["n"],
                "loadavg_1min": load_average(),
            }
            emit(out[timed])
        return out

    timed = records("vmap", models, "vmap", {})
    record = {**timed["vmap"], "time_major": timed["time_major"]}
    if jax.local_device_count() > 1:
        sharded = fj.shard_batch(models)
        devices = len(fj.batch_devices(cfg.batch))
        vmap_simulate(sharded, motion)  # compile for this placement
        vmap_simulate(sharded, motion, time_major=True)
        timed = records("vmap_sharded", sharded, "vmap_sharded", {"devices": devices})
        record["sharded"] = {**timed["vmap_sharded"], "time_major": timed["time_major"]}
    return record


def bench_grad(
    name: str, model: Any, motion: fj.Motion, cfg: argparse.Namespace, *, tangent: bool = False
) -> dict[str, Any]:
    """`filter_value_and_grad` of a mean-squared-error loss w.r.t. the model vs the forward loss alone; with
    `tangent`, of `fj.TangentGradients(model)` (the tangent-linear derivative of the scan)."""
    if name in NOMINAL:
        make, nominal = NOMINAL[name]
        target_params = nominal * 1.05
        if name == "maxwell_nlr7":
            target_params[2] = 0.02
        target = jnp.asarray(fj.simulate(make(target_params), motion))
    else:  # a black-box model: its own output, perturbed
        target = 1.05 * jnp.asarray(fj.simulate(model, motion)) + 0.01
    if tangent:
        model = fj.TangentGradients(model)

    def loss(m: Any, motion: fj.Motion, target: jax.Array) -> jax.Array:
        return jnp.mean((fj.simulate(m, motion) - target) ** 2)

    forward = eqx.filter_jit(loss)
    value_and_grad = eqx.filter_jit(eqx.filter_value_and_grad(loss))

    fwd_compile, _ = first_call(lambda: forward(model, motion, target))
    vg_compile, (value, grads) = first_call(lambda: value_and_grad(model, motion, target))
    timing = steady(
        {"forward": lambda: forward(model, motion, target), "vg": lambda: value_and_grad(model, motion, target)},
        cfg.repeats,
        cfg.budget,
    )
    grad_leaves = jax.tree_util.tree_leaves(eqx.filter(grads, eqx.is_inexact_array))
    finite = all(bool(jnp.all(jnp.isfinite(g))) for g in grad_leaves)
    steps = motion.length
    fwd_s, vg_s = timing["forward"]["median"], timing["vg"]["median"]
    record = {
        "benchmark": "value_and_grad",
        "model": name,
        "impl": "fricjax-tangent" if tangent else "fricjax",
        "steps": steps,
        "forward_ns_per_step": round(fwd_s / steps * 1e9, 2),
        "ns_per_step": round(vg_s / steps * 1e9, 2),
        "forward_compile_s": round(fwd_compile, 3),
        "compile_s": round(vg_compile, 3),
        "ratio_vs_forward": round(vg_s / fwd_s, 3),
        "loss": float(value),
        "grad_finite": finite,
        "repeats": timing["vg"]["n"],
        "loadavg_1min": load_average(),
    }
    emit(record)
    return record


def blackbox_models(steps: int) -> dict[str, Any]:
    """A neural and a kernel model of `fricjax compare`'s kind, built on the first 4 000 samples of a tribometer
    record (mixed regime, 2 kHz) long enough for `steps`: an MLP NARX (10 tanh units, linear part) and a kernel
    Volterra model (exponential kernel, 500 Nystrom centres), both on the velocity and 20 play operators, with
    no fed-back force (so the free run needs no feedback)."""
    data = fj.make_tribometer("mixed", seed=0, duration=max(steps, 4000) / 2000.0)
    train = data.full.slice(0, 4000)
    scales = fj.compare.DataScales.from_data(train)
    plays = scales.breakaway * np.geomspace(0.03, 3.0, 20)
    regressors = fj.NARXRegressors.from_data(train, ("v",), 0, 0, plays=plays)
    mlp = fj.MLPNARX.init(regressors, 10, key=jax.random.PRNGKey(0), linear=True)
    kernel = fj.identify_kernel_narx(
        train, signals=("v",), plays=plays, input_lags=0, output_lags=0, kernel="exponential", width=30.0,
        ridge=1e-3, solver="nystrom", landmarks=500,
    ).model  # fmt: skip
    return {"mlp_narx_plays": (mlp, data.full.motion), "kernel_plays": (kernel, data.full.motion)}


def recommend_unroll(unroll_ns: dict[str, dict[int, float]]) -> tuple[int, dict[int, float]]:
    """The unroll minimising the geometric mean (over models) of the time per step, and those means."""
    geo = {u: math.exp(statistics.fmean(math.log(per_model[u]) for per_model in unroll_ns.values())) for u in UNROLLS}
    return min(geo, key=geo.__getitem__), geo


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=40_000, help="single-trajectory record length")
    parser.add_argument("--batch", type=int, default=1024, help="number of parameter sets for the vmap benchmark")
    parser.add_argument("--batch-steps", type=int, default=4_000, help="record length for the vmap benchmark")
    parser.add_argument("--repeats", type=int, default=41, help="max timed rounds (the median is reported)")
    parser.add_argument("--budget", type=float, default=4.0, help="seconds of timed rounds per benchmark (>= 3 rounds)")
    parser.add_argument("--models", nargs="*", default=list(NOMINAL), choices=list(NOMINAL))
    parser.add_argument(
        "--no-blackbox", action="store_true", help="skip the value_and_grad of the MLP NARX and kernel models"
    )
    parser.add_argument("--quick", action="store_true", help="short records and a small batch (smoke run, < 1 min)")
    parser.add_argument(
        "--host-devices", type=int, default=1, help="XLA host devices; > 1 adds the sharded vmap (vmap_sharded)"
    )
    cfg = parser.parse_args(argv)
    if cfg.quick:
        cfg.steps = min(cfg.steps, 8_000)
        cfg.batch = min(cfg.batch, 128)
        cfg.batch_steps = min(cfg.batch_steps, 1_000)
        cfg.repeats = min(cfg.repeats, 5)
        cfg.budget = min(cfg.budget, 0.3)

    ENV.update(environment())
    motion = make_motion(cfg.steps)
    t_start = time.perf_counter()

    summary_models: dict[str, Any] = {}
    unroll_ns: dict[str, dict[int, float]] = {}
    for name in cfg.models:
        make, nominal = NOMINAL[name]
        model = make(nominal)
        single = bench_single(name, model, motion, cfg)
        unroll_ns[name] = single["unroll_ns"]
        vmap = bench_vmap(name, single["run_numba"], cfg.steps, cfg)
        grad = bench_grad(name, model, motion, cfg)
        tangent = bench_grad(name, model, motion, cfg, tangent=True)
        single_ratio = single["compiled_ns"] / single["numba_ns"]
        best_unroll = min(single["unroll_ns"], key=single["unroll_ns"].__getitem__)
        summary_models[name] = {
            "single_ratio_vs_numba": round(single_ratio, 3),
            "single_pass": single_ratio <= TARGET_SINGLE_RATIO[name],
            "single_filter_jit_ratio_vs_numba": round(single["default_ns"] / single["numba_ns"], 3),
            "filter_jit_dispatch_us": round(single["dispatch_us"], 1),
            "single_best_unroll": best_unroll,
            "single_best_ratio_vs_numba": round(single["unroll_ns"][best_unroll] / single["numba_ns"], 3),
            "vmap_ratio_vs_numba": vmap["ratio_vs_numba"],
            "vmap_sharded_ratio_vs_numba": vmap.get("sharded", {}).get("ratio_vs_numba"),
            "vmap_time_major_ratio_vs_numba": vmap["time_major"]["ratio_vs_numba"],
            "vmap_time_major_sharded_ratio_vs_numba": vmap.get("sharded", {})
            .get("time_major", {})
            .get("ratio_vs_numba"),
            "vmap_pass": max(vmap["ratio_vs_numba"], vmap.get("sharded", {}).get("ratio_vs_numba", 0.0))
            >= TARGET_VMAP_RATIO,
            "grad_ratio_vs_forward": grad["ratio_vs_forward"],
            "grad_pass": grad["ratio_vs_forward"] <= TARGET_GRAD_RATIO,
            "grad_tangent_ratio_vs_forward": tangent["ratio_vs_forward"],
            "grad_tangent_pass": tangent["ratio_vs_forward"] <= TARGET_GRAD_RATIO,
        }

    blackbox: dict[str, Any] = {}
    if not cfg.no_blackbox:
        for name, (model, record) in blackbox_models(cfg.steps).items():
            grad = bench_grad(name, model, record, cfg)  # NARX classes feed back: no tangent path for them
            blackbox[name] = {
                "grad_ratio_vs_forward": grad["ratio_vs_forward"],
                "grad_pass": grad["ratio_vs_forward"] <= TARGET_GRAD_RATIO,
                "forward_compile_s": grad["forward_compile_s"],
                "compile_s": grad["compile_s"],
            }

    recommended, geo = recommend_unroll(unroll_ns)
    all_pass = all(m[k] for m in summary_models.values() for k in ("single_pass", "vmap_pass", "grad_pass"))
    all_pass = all_pass and all(m["grad_pass"] for m in blackbox.values())
    emit(
        {
            "benchmark": "summary",
            "targets": {
                "single_ratio_vs_numba_max": TARGET_SINGLE_RATIO,
                "vmap_ratio_vs_numba_min": TARGET_VMAP_RATIO,
                "grad_ratio_vs_forward_max": TARGET_GRAD_RATIO,
            },
            "models": summary_models,
            "blackbox_models": blackbox,
            "all_pass": all_pass,
            "default_unroll": DEFAULT_UNROLL,
            "recommended_unroll": recommended,
            "unroll_geomean_ns_per_step": {str(u): round(ns, 2) for u, ns in geo.items()},
            "steps": cfg.steps,
            "batch": cfg.batch,
            "batch_steps": cfg.batch_steps,
            "total_s": round(time.perf_counter() - t_start, 1),
            "loadavg_1min": load_average(),
        }
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
