"""Command line: `fricjax demo` (also `python -m fricjax demo`)."""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np


def demo_motion(duration: float = 8.0, dt: float = 1e-3, frequency: float = 1.0) -> Any:
    """Displacement from pre-sliding into gross sliding: a 1 Hz sine whose amplitude grows geometrically from
    0.5 um (well inside the pre-sliding range) to 1 mm (gross sliding), sampled at 1 kHz."""
    import fricjax as fj

    t = np.arange(int(round(duration / dt))) * dt
    amplitude = 5e-7 * (1e-3 / 5e-7) ** (t / t[-1])
    return fj.Motion.from_position(amplitude * np.sin(2 * np.pi * frequency * t), dt=dt)


def demo_models() -> dict[str, Any]:
    """Every physics model with typical parameters for a small dry contact (Fc = 1 N, Fs = 1.5 N)."""
    import fricjax as fj

    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0)
    return {
        "BoPavelescu (static)": fj.BoPavelescu(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0, Fv=40.0),
        "Dahl": fj.Dahl(sigma0=1e5, Fc=1.0),
        "LuGre": fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=40.0),
        "GMS (N=4)": fj.GMS(stribeck, k=[6e4, 2.5e4, 1e4, 5e3], alpha=[0.1, 0.2, 0.3, 0.4], C=50.0, sigma2=40.0),
        "Maxwell-slip NLR(5)": fj.MaxwellSlip.nlr(
            k=[4e4, 3e4, 2e4, 1e4, 5e3], thresholds=[2e-6, 5e-6, 1e-5, 2e-5, 4e-5]
        ),
        "Maxwell-slip DNLRX(5,2,1)": fj.MaxwellSlip.dnlrx(
            thresholds=[2e-6, 5e-6, 1e-5, 2e-5, 4e-5],
            theta=np.outer([0.7, 0.2, 0.1], [0.08, 0.15, 0.2, 0.2, 0.2]),
            c=[2e3, -2e3],
        ),
    }


def run_demo(out: pathlib.Path, *, figure: bool = True) -> dict[str, Any]:
    import fricjax as fj

    motion = demo_motion()
    rows = []
    forces = {}
    presliding = slice(0, motion.length // 4)
    for name, model in demo_models().items():
        start = time.perf_counter()
        force = np.asarray(fj.simulate(model, motion))  # type: ignore[arg-type]
        elapsed = time.perf_counter() - start
        exact_vs_smooth = float(
            fj.nrmse(force, fj.simulate(fj.with_smoothing(model, fj.Smooth(_demo_eps(model))), motion))  # type: ignore[arg-type]
        )
        forces[name] = force
        x = np.asarray(motion.x)
        rows.append(
            {
                "model": name,
                "peak_force_N": float(np.max(np.abs(force))),
                "presliding_peak_N": float(np.max(np.abs(force[presliding]))),
                "presliding_stiffness_N_per_m": float(np.polyfit(x[:200], force[:200] - force[0], 1)[0]),
                "smooth_vs_exact_nrmse": exact_vs_smooth,
                "simulate_s": elapsed,
            }
        )
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"fricjax {fj.__version__} demo: {motion.length} samples at {1 / float(motion.dt):.0f} Hz, "
        "displacement amplitude 0.5 um -> 1 mm (pre-sliding into gross sliding)"
    )
    print(
        f"{'model':28s} {'peak F [N]':>10s} {'pre-slide F':>11s} {'k0 [N/m]':>10s} "
        f"{'smooth~exact':>12s} {'time [s]':>8s}"
    )
    for row in rows:
        print(
            f"{row['model']:28s} {row['peak_force_N']:10.3f} {row['presliding_peak_N']:11.3f} "
            f"{row['presliding_stiffness_N_per_m']:10.3g} {row['smooth_vs_exact_nrmse']:12.2e} {row['simulate_s']:8.2f}"
        )
    report = {"fricjax": fj.__version__, "samples": motion.length, "dt": float(motion.dt), "models": rows}
    (out / "demo.json").write_text(json.dumps(report, indent=2))
    if figure:
        from ._plot import plot_loops

        fig = plot_loops(
            motion,
            forces,
            presliding_window=(0, int(0.45 * motion.length)),
            velocity_only=[name for name in forces if "static" in name],
            title="fricjax demo: every physics model under the same displacement",
        )
        fig.savefig(out / "demo_hysteresis.png", dpi=110)
        print(f"figure: {out / 'demo_hysteresis.png'}")
    print(f"report: {out / 'demo.json'}")
    return report


def _demo_eps(model: Any) -> float:
    import fricjax as fj

    if isinstance(model, fj.GMS):
        return 1e-11  # metres
    if isinstance(model, fj.MaxwellSlip):
        return 1e-3  # fraction of a threshold
    return 1e-8  # m/s


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fricjax", description="Friction models as JAX scan simulators.")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="simulate every physics model from pre-sliding into gross sliding")
    demo.add_argument(
        "--out", default="fricjax-demo", help="output folder for the figure and JSON (default: %(default)s)"
    )
    demo.add_argument("--no-figure", action="store_true", help="skip the figure")
    args = parser.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    if args.command == "demo":
        out = pathlib.Path(args.out)
        try:
            out.mkdir(parents=True, exist_ok=True)
            probe = out / ".write-test"
            probe.write_text("")
            probe.unlink()
        except OSError as err:
            print(f"fricjax demo: cannot write to --out {out}: {err.strerror}", file=sys.stderr)
            return 2
        run_demo(out, figure=not args.no_figure)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
