"""Command line: `fricjax demo` (also `python -m fricjax demo`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import signal
import sys
import tempfile
import time
import warnings
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


def _model_names() -> tuple[tuple[str, ...], tuple[str, ...]]:
    from ._protocols._compare import MODEL_NAMES, PHYSICS_MODELS

    return MODEL_NAMES, PHYSICS_MODELS


MODEL_NAMES, DEFAULT_MODELS = _model_names()


def run_compare(args: argparse.Namespace) -> int:
    """`fricjax compare`: fit every model on the training record, score each by free run on the test records
    (or the record's own test part), add ensembles, write the report."""
    import shutil
    import tempfile

    import fricjax as fj

    from ._plot import plot_prediction_errors, plot_test_loops
    from ._protocols import _compare as cmp

    out = pathlib.Path(args.out)
    args.models = [m.lower() for m in args.models]  # model names are case-insensitive
    if args.models == ["all"]:
        args.models = list(MODEL_NAMES)
    unknown = [m for m in args.models if m not in MODEL_NAMES]
    if unknown:
        raise cmp.CompareError(f"--models: unknown model {unknown[0]!r}; choose from {', '.join(MODEL_NAMES)}")
    if args.init_window is not None and args.init_window < 0:
        raise cmp.CompareError(f"--init-window must be >= 0 samples, got {args.init_window}")
    settings = cmp.FitSettings(
        steps=args.steps,
        gms_elements=args.gms_elements,
        maxwell_elements=args.maxwell_elements,
        drift=args.drift,
        neural_steps=args.neural_steps,
    )
    _check_writable(out)
    if args.data == "emps":
        return _compare_emps(out, args)
    units_kw = {"dt": args.dt, "x_unit": args.x_unit, "force_unit": args.force_unit}
    training = cmp.load_record_spec(args.data, seed=args.seed, **units_kw)
    test_specs = list(args.test or [])
    split = cmp.split_record(training, args.split, tested_elsewhere=bool(test_specs))
    tests: list[cmp.TestRecord] = []
    cards: dict[str, Any] = {}  # the data cards of the other test records, by test name
    if split.validation_end < training.data.length:
        tests.append(split.test_record(args.init_window, training.reference))
    for spec in test_specs:
        loaded = cmp.load_record_spec(spec, seed=args.seed, **units_kw)
        name = loaded.name if loaded.name not in {t.name for t in tests} else f"{loaded.name} #{len(tests) + 1}"
        tests.append(cmp.TestRecord.whole(loaded, args.init_window, name))
        cards[name] = loaded.card
    if not tests:
        raise cmp.CompareError("nothing to test on: the split leaves no test part; pass --test records")
    units = training.units
    print(
        f"fricjax {fj.__version__} compare: {args.data}, {split.full.length} samples (train {split.train_end}, "
        f"validation {split.validation_end - split.train_end}); test: "
        + "; ".join(
            f"{t.name} ({t.record.length - t.scored_start} scored after a {t.init_window}-sample initialisation window)"
            for t in tests
        )
        + f"; models: {', '.join(args.models)}"
    )
    for line in cmp.statistics_warnings(split, tests, units):
        print("warning: " + line)
    started = time.perf_counter()
    rows = cmp.fit_and_score(
        list(args.models), split, tests=tests, settings=settings, seed=args.seed, progress=not args.no_progress
    )
    rows += cmp.add_ensembles(rows, split, tests)
    floor = cmp.reference_scores(tests)
    print()
    print(cmp.format_table(rows, floor))
    staging = pathlib.Path(tempfile.mkdtemp(prefix=".partial-", dir=out))
    try:
        (staging / "models").mkdir()
        for row in rows:
            fj.save_model(staging / "models" / f"{row.name}.eqx", row.model)
        plot_prediction_errors(rows, tests[0], staging / "test_errors.png", units=units)
        plot_test_loops(rows, tests[0], staging / "hysteresis_loops.png", units=units)
        report = {
            "fricjax": fj.__version__,
            "versions": _versions(),
            "data": args.data,
            "seed": args.seed,
            "data_card": training.card,
            "units": {"x": units.x, "v": units.v, "force": units.force, "internal": "SI (m, m/s, N)"},
            "split": {
                "train": [0, split.train_end],
                "validation": [split.train_end, split.validation_end],
                "test_part": [split.validation_end, split.full.length]
                if split.validation_end < split.full.length
                else None,
            },
            "test_records": [
                {
                    "name": t.name,
                    "samples": t.record.length,
                    "init_window": [t.start, t.scored_start],
                    "scored": [t.scored_start, t.record.length],
                    "noise_floor_nmse_percent": floor[t.name].nmse if t.name in floor else None,
                    "card": cards.get(t.name),
                }
                for t in tests
            ],
            "settings": {
                **dataclasses.asdict(settings),
                "solvers": "Levenberg-Marquardt (optimistix) with separable least squares for linear parameters; "
                "GMS: Adam with smoothing continuation from gms_starts starts, then a Levenberg-Marquardt polish",
                "scoring": "free run in exact mode from each record's first sample; the force offset is the mean "
                "error over the initialisation window, which is not scored",
            },
            "result_codes": cmp.RESULT_CODES,
            "reference": {
                "model": "true model + sensor drift and offset (noise-free sensor reading)",
                "scores": {name: dataclasses.asdict(value) for name, value in floor.items()},
            }
            if floor
            else None,
            "models": [
                {
                    "name": r.name,
                    "label": r.label,
                    "nmse_percent": r.nmse,
                    "max_error_over_std": r.max_error,
                    "validation_nmse_percent": r.validation_nmse,
                    "test_scores": {name: dataclasses.asdict(value) for name, value in r.tests.items()},
                    "fit_time_s": r.fit_time,
                    "num_parameters": r.num_parameters,
                    "result": r.result,
                    "result_message": r.message,
                    "parameters": _parameters(r.model),
                    "parameter_std": _estimated_std(r.std) if r.std is not None else None,
                }
                for r in sorted(rows, key=cmp.by_score)
            ],
            "total_time_s": time.perf_counter() - started,
        }
        (staging / "report.json").write_text(_strict_json(report))
        # move in file by file (each an atomic rename); nothing in `out` that this run did not write is touched
        (out / "models").mkdir(exist_ok=True)
        for item in sorted((staging / "models").iterdir()):
            item.replace(out / "models" / item.name)
        for name in ("test_errors.png", "hysteresis_loops.png", "report.json"):  # the report last
            (staging / name).replace(out / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    print(
        f"\nreport: {out / 'report.json'}; figures: {out / 'test_errors.png'}, {out / 'hysteresis_loops.png'}; "
        f"models: {out / 'models'} ({time.perf_counter() - started:.0f} s)"
    )
    return 0


def _compare_emps(out: pathlib.Path, args: argparse.Namespace) -> int:
    """`--data emps`: the EMPS table (IDM for the 8 laws of the emps-ensemble paper, train and test errors)."""
    import os

    import fricjax as fj

    from ._protocols import _compare as cmp

    root = pathlib.Path(os.environ.get("FRICJAX_DATA", pathlib.Path.cwd().parent / "shared" / "data")) / "emps"
    train_path, test_path = root / "DATA_EMPS.mat", root / "DATA_EMPS_PULSES.mat"
    if not train_path.is_file() or not test_path.is_file():
        raise cmp.CompareError(f"--data emps: EMPS files not found in {root}; set FRICJAX_DATA to the data folder")
    try:
        train, test = fj.load_emps(train_path), fj.load_emps(test_path)
    except (ValueError, OSError) as err:
        raise cmp.CompareError(f"--data emps: {err}") from err
    laws: list[tuple[str, Any]] = [
        ("Coulomb + viscous", fj.CoulombViscous),
        ("Threlfall", fj.Threlfall),
        ("Tustin", fj.Tustin),
        ("Bo-Pavelescu", fj.BoPavelescu),
    ]
    rows = []
    print(f"{'law':34s} {'train rel. error %':>18s} {'test rel. error %':>18s}  parameters")
    for label, law in laws:
        for asymmetric in (False, True):
            result = fj.fit_emps_idm(train, law, asymmetric=asymmetric)
            name = f"{label} ({'asymmetric' if asymmetric else 'symmetric'})"
            test_error = float(result.relative_error_on(test))
            params = {
                "M": float(result.M),
                "offset": float(result.offset),
                **{k: np.asarray(v).tolist() for k, v in result.params.items()},
            }
            rows.append(
                {
                    "law": name,
                    "train_relative_error_percent": float(result.relative_error),
                    "test_relative_error_percent": test_error,
                    "parameters": params,
                }
            )
            text = ", ".join(f"{k}={np.round(np.asarray(v), 4).tolist()}" for k, v in params.items())
            print(f"{name:34s} {float(result.relative_error):18.4f} {test_error:18.4f}  {text}")
    _write_atomic(
        out / "report.json",
        _strict_json({"data": "emps", "fricjax": fj.__version__, "versions": _versions(), "idm": rows}),
    )
    print(f"report: {out / 'report.json'}")
    return 0


def _check_writable(out: pathlib.Path) -> None:
    from ._protocols._compare import CompareError

    try:
        out.mkdir(parents=True, exist_ok=True)
        handle, probe = tempfile.mkstemp(prefix=".fricjax-write-test-", dir=out)  # a fresh name: nothing overwritten
        os.close(handle)
        os.unlink(probe)
    except OSError as err:
        raise CompareError(f"--out {out}: not writable ({err.strerror})") from err
    models = out / "models"
    if models.exists() and not models.is_dir():
        raise CompareError(f"--out {out}: 'models' exists and is not a folder; move it away or choose another --out")


def _parameters(model: Any) -> dict[str, Any]:
    from ._constraints import parameter_arrays, unwrap
    from ._smoothing import exact

    return {path: value.tolist() for path, value in parameter_arrays(unwrap(exact(model))).items()}


def _estimated_std(std: Any) -> dict[str, Any]:
    """The Gauss-Newton standard deviations that were estimated: fixed and untrained leaves (NaN) are left out."""
    import numpy as np

    from ._constraints import parameter_arrays

    return {path: value.tolist() for path, value in parameter_arrays(std).items() if not np.all(np.isnan(value))}


def _versions() -> dict[str, str]:
    import platform

    import equinox
    import jax
    import optax
    import optimistix

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "equinox": equinox.__version__,
        "optax": optax.__version__,
        "optimistix": optimistix.__version__,
        "numpy": np.__version__,
    }


def _write_atomic(path: pathlib.Path, text: str) -> None:
    """Write `text` to a temporary file beside `path`, then rename it over `path`."""
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(handle, "w") as stream:
            stream.write(text)
        os.replace(temporary, path)
    except BaseException:
        pathlib.Path(temporary).unlink(missing_ok=True)
        raise


def _strict_json(report: Any) -> str:
    """The report as strict JSON: non-finite numbers become `null` (with a warning naming where), never
    `NaN` / `Infinity`, which strict parsers reject."""
    bad: list[str] = []

    def clean(value: Any, where: str) -> Any:
        value = _jsonable(value) if isinstance(value, np.generic) or hasattr(value, "tolist") else value
        if isinstance(value, float) and not np.isfinite(value):
            bad.append(where)
            return None
        if isinstance(value, dict):
            return {key: clean(item, f"{where}.{key}") for key, item in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(item, f"{where}[{i}]") for i, item in enumerate(value)]
        if value is None or isinstance(value, (bool, int, float, str)):
            return value
        return str(value)

    text = json.dumps(clean(report, "report"), indent=2, allow_nan=False)
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        warnings.warn(f"report.json: non-finite values written as null at {shown}", RuntimeWarning, stacklevel=2)
        print(f"warning: non-finite scores or parameters (written as null in report.json): {shown}")
    return text


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def main(argv: Sequence[str] | None = None) -> int:
    """The `fricjax` command line: `fj.main(["compare", "--data", "tribometer:mixed"])` runs as the shell does.

    **Returns:** the exit status (0 success, 2 a one-line input error, 130 interrupted: Ctrl-C or SIGTERM,
    after which nothing was written to the output folder).
    """
    parser = argparse.ArgumentParser(prog="fricjax", description="Friction models as JAX scan simulators.")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="simulate every physics model from pre-sliding into gross sliding")
    demo.add_argument(
        "--out", default="fricjax-demo", help="output folder for the figure and JSON (default: %(default)s)"
    )
    demo.add_argument("--no-figure", action="store_true", help="skip the figure")
    compare = sub.add_parser(
        "compare", help="fit every model to a record, compare them on held-out data, add ensembles, report"
    )
    compare.add_argument(
        "--data",
        default="tribometer:mixed",
        help="the training record: tribometer:presliding|mixed|sliding[:seed=N,offset=F,drift=F,duration=S] "
        "(synthetic), emps (real EMPS data), or FILE.npz/.csv with columns t (time) or dt, x (position, "
        "displacement) and/or v (velocity), force (F, friction); units in brackets, e.g. 'x [um]' "
        "(default: %(default)s)",
    )
    compare.add_argument(
        "--test",
        nargs="+",
        metavar="RECORD",
        help="test records (same forms as --data): the models fitted on --data run free on each; the first "
        "--init-window samples of each estimate the force offset and settle the state and are not scored. "
        "With --test, --data is split 80/20 into training and validation unless --split says otherwise",
    )
    compare.add_argument(
        "--split",
        nargs=2,
        type=float,
        metavar=("TRAIN_END", "VALIDATION_END"),
        help="split --data at these fractions: train, validation (choice among starts), test part (default "
        "0.6 0.8: 60/20/20; 0.8 1.0 with --test)",
    )
    compare.add_argument(
        "--init-window",
        type=int,
        default=None,
        metavar="N",
        help="samples at the start of each test part that initialise the model's state and estimate the "
        "record's force offset; never scored (default: 10 %% of the test part; 0: no offset estimate)",
    )
    compare.add_argument(
        "--models",
        nargs="+",
        default=list(DEFAULT_MODELS),
        help=f"models to fit, any of {', '.join(MODEL_NAMES)} (case-insensitive), or all (default: the physics "
        f"models {', '.join(DEFAULT_MODELS)}; the neural ones take a few minutes each)",
    )
    compare.add_argument(
        "--neural-steps",
        type=int,
        default=600,
        metavar="N",
        help="output-error (NOE) Adam steps of the neural models mlp, gsnn, rnn, avd (default: %(default)s)",
    )
    compare.add_argument(
        "--steps",
        type=int,
        default=40,
        help="Levenberg-Marquardt step budget per fit (GMS Adam stage: 8x) (default: %(default)s)",
    )
    compare.add_argument("--gms-elements", type=int, default=4, help="GMS elements (default: %(default)s)")
    compare.add_argument(
        "--maxwell-elements", type=int, default=5, help="Maxwell-slip NLR / DNLRX elements (default: %(default)s)"
    )
    compare.add_argument(
        "--drift",
        default="linear",
        choices=("linear", "leaky", "none"),
        help="force-sensor drift fitted with every model (fj.SensorDrift), restarting at 0 on each test record "
        "(default: %(default)s)",
    )
    compare.add_argument("--dt", type=float, default=None, help="sample time [s] of the file records (overrides t)")
    compare.add_argument("--x-unit", default=None, help="displacement unit of the file records (m, mm, um, nm, in)")
    compare.add_argument("--force-unit", default=None, help="force unit of the file records (N, kN, mN, lbf, kip)")
    compare.add_argument("--out", default="fricjax-compare", help="output folder (default: %(default)s)")
    compare.add_argument("--seed", type=int, default=0, help="seed for the synthetic data and multi-starts")
    compare.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from ._protocols._compare import CompareError

    if args.command == "demo":
        out = pathlib.Path(args.out)
        try:
            _check_writable(out)
        except CompareError as err:
            print(f"fricjax demo: {err}", file=sys.stderr)
            return 2
        run_demo(out, figure=not args.no_figure)
        return 0
    previous = _terminate_as_interrupt()
    try:
        return run_compare(args)
    except CompareError as err:
        print("fricjax compare: " + " ".join(str(err).split()), file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # the staging folder is removed on the way out (finally in run_compare)
        print(f"fricjax compare: interrupted; nothing was written to {args.out}", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _terminate_as_interrupt() -> Any:
    """SIGTERM raises KeyboardInterrupt (so the clean-up of a half-written report runs); returns the previous
    handler, or None where signals cannot be set (not the main thread)."""

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    try:
        return signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not in the main thread
        return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
