"""Adaptive friction compensation of a nanometre positioning stage (amthor §III-IV, Figs. 6-7).

The paper's scenario in a synthetic stage (`fj.PositioningStage`): a 24.5 kg slider tracks a 10 um, 1 Hz sine at
10 kHz under PID control (30 Hz bandwidth), its position read to 0.1 nm; the "true" friction is a GMS model
(4 elements, Stribeck curve 1.0 -> 1.2 N, pre-sliding over about 2 um). Four runs of `--seconds` (default 20 s):

1. PID only (`uncompensated`);
2. a static feed-forward (Coulomb + viscous, identified offline by least squares on the samples above 60 % of
   the peak velocity);
3. the inverse model (12 Maxwell-slip elements, a bank of 5 Stribeck terms, viscous, offset) identified offline
   (`offline`): its parameters are the least-squares fit of the applied force on the model's regressors over an
   identification run (PID only, another excitation: 0.7 Hz + 1.9 Hz sines), computed by the recursive
   estimator with forgetting 1 (equal to batch least squares);
4. the same model adapted online by U-D factorised recursive least squares (forgetting 0.9995, starting from
   zero: it learns while the PID alone runs) (`adaptive`).

The compensators are switched on at 25 % of the run (amthor's Fig. 6: before / after) and the plant friction is
raised by 20 % at 60 % of the run (robustness: the adaptive model recovers, the offline one does not). The
tracking RMS is taken over the last 25 % of the run. Prints JSON lines `{"kind": "run", ...}` per compensator and
a summary `{"kind": "summary", "tracking_rms_uncompensated": ..., "tracking_rms_static": ...,
"tracking_rms_offline": ..., "tracking_rms_adaptive": ..., "ratio": ...}` (RMS in nm, ratio = uncompensated /
adaptive), and writes the figure `benchmarks/results/adaptive_tracking.png` (tracking errors and the adapted
parameters, the paper's Figs. 6-7).

Run: `python benchmarks/adaptive.py [--seconds 20] [--smoke]`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402

DT = 1e-4  # 10 kHz
MASS = 24.5  # kg
BANDWIDTH = 30.0  # Hz
RESOLUTION = 1e-10  # m
THRESHOLDS = np.linspace(0.2e-6, 3e-6, 12)  # m
STRIBECK_VELOCITIES = np.geomspace(5e-6, 8e-5, 5)  # m/s


def plant() -> fj.GMS:
    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.2, vs=2e-5, delta=2.0)
    return fj.GMS(stribeck, k=[3e5, 1.5e5, 1e5, 5e4], alpha=[0.4, 0.3, 0.2, 0.1], C=200.0, sigma2=50.0)


def gains() -> dict[str, float]:
    w = 2 * np.pi * BANDWIDTH
    return {"kp": MASS * w**2, "ki": MASS * w**3 / 10, "kd": 2 * 0.7 * MASS * w}


def run(compensator: fj.StageCompensator, reference: np.ndarray, scale: np.ndarray) -> dict[str, np.ndarray]:
    stage = fj.PositioningStage(MASS, plant(), **gains(), compensator=compensator, resolution=RESOLUTION)
    out = fj.simulate(stage, fj.InputRecord(dt=DT, reference=reference, friction_scale=scale))
    return {name: np.asarray(value) for name, value in out.items()}


def identify(seconds: float) -> tuple[np.ndarray, tuple[float, float]]:
    """The offline inverse model and static law from a PID-only identification run (another excitation)."""
    t = np.arange(int(round(seconds / DT))) * DT
    reference = 12e-6 * (0.6 * np.sin(2 * np.pi * 0.7 * t) + 0.4 * np.sin(2 * np.pi * 1.9 * t))  # from rest
    estimator = fj.StageCompensator(
        "adaptive",
        mass=MASS,
        thresholds=THRESHOLDS,
        stribeck_velocities=STRIBECK_VELOCITIES,
        forgetting=1.0,
        p0=1e4,
        feedforward_from=np.inf,  # PID only: the estimator only listens
    )
    out = run(estimator, reference, np.ones_like(t))
    theta = out["theta"][-1]
    # the static law by least squares on the same run, in sliding (|v| above 60 % of its peak, where a static
    # law holds): u - m a = Fc sign(v) + Fv v + b
    v = np.gradient(out["x"], DT)
    v_reference = np.gradient(reference, DT)
    a = np.gradient(v_reference, DT)
    sliding = np.abs(v) > 0.6 * np.max(np.abs(v_reference))
    design = np.column_stack([np.sign(v), v, np.ones_like(v)])[sliding]
    (Fc, Fv, _), *_ = np.linalg.lstsq(design, (out["u"] - MASS * a)[sliding], rcond=None)
    return theta, (float(Fc), float(Fv))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--smoke", action="store_true", help="a 4 s run and a 4 s identification (CI)")
    parser.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "adaptive_tracking.png"))
    args = parser.parse_args()
    seconds = 4.0 if args.smoke else args.seconds
    env = environment()
    start = time.perf_counter()
    theta, (Fc, Fv) = identify(4.0 if args.smoke else 10.0)
    t = np.arange(int(round(seconds / DT))) * DT
    reference = 1e-5 * np.sin(2 * np.pi * 1.0 * t)
    on, change = 0.25 * seconds, 0.6 * seconds
    scale = np.where(t < change, 1.0, 1.2)
    model = {"thresholds": THRESHOLDS, "stribeck_velocities": STRIBECK_VELOCITIES, "mass": MASS}
    compensators = {
        "uncompensated": fj.StageCompensator(),
        "static": fj.StageCompensator("static", mass=MASS, Fc=Fc, Fv=Fv, feedforward_from=on),
        "offline": fj.StageCompensator("model", theta=theta, feedforward_from=on, **model),
        "adaptive": fj.StageCompensator("adaptive", forgetting=0.9995, p0=1.0, feedforward_from=on, **model),
    }
    scored = t >= 0.75 * seconds
    before_change = (t >= on + 0.1 * seconds) & (t < change)
    results, outputs = {}, {}
    for name, compensator in compensators.items():
        began = time.perf_counter()
        out = run(compensator, reference, scale)
        elapsed = time.perf_counter() - began
        error = out["error"]
        results[name] = float(np.sqrt(np.mean(error[scored] ** 2)))
        outputs[name] = out
        line = {
            "kind": "run",
            "compensator": name,
            "tracking_rms_nm": 1e9 * results[name],
            "tracking_nrmse_percent": fj.tracking_nrmse(error[scored], reference[scored]),
            "tracking_rms_before_change_nm": 1e9 * float(np.sqrt(np.mean(error[before_change] ** 2))),
            "simulate_s": round(elapsed, 2),
            "samples": int(t.size),
            **env,
        }
        print(json.dumps(line), flush=True)
    summary = {
        "kind": "summary",
        "scenario": f"10 um 1 Hz sine, {seconds:g} s at 10 kHz, GMS plant, compensation on at {on:g} s, friction "
        f"+20 % at {change:g} s; RMS [nm] over the last 25 %",
        **{f"tracking_rms_{name}": round(1e9 * value, 4) for name, value in results.items()},
        "ratio": results["uncompensated"] / results["adaptive"],
        "ratio_static": results["uncompensated"] / results["static"],
        "ratio_offline": results["uncompensated"] / results["offline"],
        "static_law": {"Fc_N": Fc, "Fv_Ns_per_m": Fv},
        "wall_s": round(time.perf_counter() - start, 1),
        **env,
    }
    print(json.dumps(summary), flush=True)
    figure(t, outputs, on, change, args.out)


def figure(t: np.ndarray, outputs: dict[str, dict[str, np.ndarray]], on: float, change: float, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for name, out in outputs.items():
        axes[0].plot(t, 1e9 * out["error"], lw=0.7, label=name)
    axes[0].set_ylabel("tracking error [nm]")
    axes[0].legend(loc="upper right", fontsize=8, ncol=4)
    axes[0].set_title(
        "PID with friction feed-forward (amthor Fig. 6): on at the first line, friction +20 % at the second"
    )
    for name, color in (("offline", "C2"), ("adaptive", "C3")):
        axes[1].plot(t, 1e9 * outputs[name]["error"], lw=0.7, label=name, color=color)
    axes[1].set_ylim(-150, 150)
    axes[1].set_ylabel("tracking error [nm] (zoom)")
    axes[1].legend(loc="upper right", fontsize=8, ncol=2)
    theta = outputs["adaptive"]["theta"]
    axes[2].plot(t, theta[:, :-2], lw=0.8)
    axes[2].set_ylabel("adapted forces [N]")
    axes[2].set_xlabel("time [s]")
    axes[2].set_title("parameter evolution of the adaptive inverse model (amthor Fig. 7)")
    for ax in axes:
        ax.axvline(on, color="k", lw=0.8, ls="--")
        ax.axvline(change, color="r", lw=0.8, ls=":")
    fig.tight_layout()
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
