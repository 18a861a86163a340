"""`fricjax demo`: every physics model simulated under one displacement that grows from pre-sliding into gross
sliding, with a table of forces, pre-sliding stiffness and smooth-vs-exact error, `demo.json` and a figure of the
hysteresis loops (`run_demo`)."""

from __future__ import annotations

import json
import pathlib
import time
from typing import Any

import numpy as np

from .._estimation.loop._interrupts import check_interrupt
from .._inputs import Motion
from .._metrics import nrmse
from .._models.physics._dahl import Dahl
from .._models.physics._gms import GMS
from .._models.physics._lugre import LuGre
from .._models.physics._maxwell_slip import MaxwellSlip
from .._models.physics._static import BoPavelescu
from .._models.physics._stribeck import ExponentialStribeck
from .._plot import plot_loops
from .._simulate import simulate
from .._smoothing import Smooth, with_smoothing
from .._version import fricjax_version


def demo_motion(duration: float = 8.0, dt: float = 1e-3, frequency: float = 1.0) -> Any:
    """Displacement from pre-sliding into gross sliding: a 1 Hz sine whose amplitude grows geometrically from
    0.5 um (well inside the pre-sliding range) to 1 mm (gross sliding), sampled at 1 kHz."""
    t = np.arange(int(round(duration / dt))) * dt
    amplitude = 5e-7 * (1e-3 / 5e-7) ** (t / t[-1])
    return Motion.from_position(amplitude * np.sin(2 * np.pi * frequency * t), dt=dt)


def demo_models() -> dict[str, Any]:
    """Every physics model with typical parameters for a small dry contact (Fc = 1 N, Fs = 1.5 N)."""
    stribeck = ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0)
    return {
        "BoPavelescu (static)": BoPavelescu(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0, Fv=40.0),
        "Dahl": Dahl(sigma0=1e5, Fc=1.0),
        "LuGre": LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=40.0),
        "GMS (N=4)": GMS(stribeck, k=[6e4, 2.5e4, 1e4, 5e3], alpha=[0.1, 0.2, 0.3, 0.4], C=50.0, sigma2=40.0),
        "Maxwell-slip NLR(5)": MaxwellSlip.nlr(k=[4e4, 3e4, 2e4, 1e4, 5e3], thresholds=[2e-6, 5e-6, 1e-5, 2e-5, 4e-5]),
        "Maxwell-slip DNLRX(5,2,1)": MaxwellSlip.dnlrx(
            thresholds=[2e-6, 5e-6, 1e-5, 2e-5, 4e-5],
            theta=np.outer([0.7, 0.2, 0.1], [0.08, 0.15, 0.2, 0.2, 0.2]),
            c=[2e3, -2e3],
        ),
    }


def run_demo(out: pathlib.Path, *, figure: bool = True) -> dict[str, Any]:
    """Simulate `demo_models()` under `demo_motion()` (exact, and smoothed to measure the difference), print the
    table, write `out/demo.json` and, with `figure`, `out/demo_hysteresis.png`. **Returns:** the report."""
    motion = demo_motion()
    rows = []
    forces = {}
    presliding = slice(0, motion.length // 4)
    for name, model in demo_models().items():
        check_interrupt()  # Ctrl-C / SIGTERM (`fricjax demo` sets the flag): stop before the next model
        start = time.perf_counter()
        force = np.asarray(simulate(model, motion))  # type: ignore[arg-type]
        elapsed = time.perf_counter() - start
        exact_vs_smooth = float(
            nrmse(force, simulate(with_smoothing(model, Smooth(_demo_eps(model))), motion))  # type: ignore[arg-type]
        )
        forces[name] = force
        x = np.asarray(motion.x)
        rows.append(
            {
                "model": name,
                "peak_force_N": float(np.max(np.abs(force))),
                "presliding_peak_N": float(np.max(np.abs(force[presliding]))),
                # a static law has no pre-sliding spring: its slope in x is meaningless (None)
                "presliding_stiffness_N_per_m": None
                if "static" in name
                else float(np.polyfit(x[:200], force[:200] - force[0], 1)[0]),
                "smooth_vs_exact_nrmse": exact_vs_smooth,
                "simulate_s": elapsed,
            }
        )
    check_interrupt()  # nothing written yet
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"fricjax {fricjax_version()} demo: {motion.length} samples at {1 / float(motion.dt):.0f} Hz, "
        "displacement amplitude 0.5 um -> 1 mm (pre-sliding into gross sliding)"
    )
    print(
        f"{'model':28s} {'peak F [N]':>10s} {'pre-slide F':>11s} {'k0 [N/m]':>10s} "
        f"{'smooth~exact':>12s} {'time [s]':>8s}"
    )
    for row in rows:
        stiffness = row["presliding_stiffness_N_per_m"]
        print(
            f"{row['model']:28s} {row['peak_force_N']:10.3f} {row['presliding_peak_N']:11.3f} "
            f"{'-' if stiffness is None else f'{stiffness:.3g}':>10s} {row['smooth_vs_exact_nrmse']:12.2e} "
            f"{row['simulate_s']:8.2f}"
        )
    print(
        "pre-slide F: the largest force in the first quarter (displacements below 3.5 um); k0: the initial slope of "
        "force in displacement (a static law has none); smooth~exact: RMS difference between the smoothed and the "
        "exact model, relative to the force's standard deviation"
    )
    report = {"fricjax": fricjax_version(), "samples": motion.length, "dt": float(motion.dt), "models": rows}
    (out / "demo.json").write_text(json.dumps(report, indent=2))
    if figure:
        fig = plot_loops(
            motion,
            forces,
            presliding_window=(0, int(0.45 * motion.length)),
            velocity_only=[name for name in forces if "static" in name],
            title="fricjax demo: every physics model under the same displacement",
            pyplot=False,
        )
        fig.savefig(out / "demo_hysteresis.png", dpi=110)
        print(f"figure: {out / 'demo_hysteresis.png'}")
    print(f"report: {out / 'demo.json'}")
    return report


def _demo_eps(model: Any) -> float:
    """A small smoothing width for `model`'s family, in the unit it smooths (`smoothing_scale`)."""
    return model.smoothing_scale()
