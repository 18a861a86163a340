"""Command line: `fricjax demo`, `fricjax compare` and `fricjax predict` (also `python -m fricjax ...`): parse the
arguments, run the command (`fricjax._protocols._demo`, `fricjax._protocols.compare`), turn its input errors into one
line on stderr and an exit status."""

from __future__ import annotations

import argparse
import difflib
import os
import sys
import warnings
from collections.abc import Sequence

from ._compilation_cache import cache_disabled, default_cache_dir, enable_compilation_cache
from ._protocols.compare._names import MODEL_NAMES
from ._protocols.compare._names import PHYSICS_MODELS as DEFAULT_MODELS

# the protocols (and JAX) are imported in `main` once the arguments are parsed: `--help` and argument errors answer
# before JAX loads


_NO_CACHE_HELP = (
    f"do not keep compiled programs for the next run (default: kept in {default_cache_dir()}; "
    "FRICJAX_NO_CACHE=1 does the same, FRICJAX_CACHE_DIR moves the folder)"
)


def main(argv: Sequence[str] | None = None) -> int:
    """The `fricjax` command line: `fj.main(["compare", "--data", "tribometer:mixed"])` runs as the shell does.

    **Returns:** the exit status (0 success, 2 a one-line input error, 130 interrupted: Ctrl-C or SIGTERM,
    after which nothing was written to the output folder).
    """
    from ._estimation.loop._interrupts import check_interrupt, stop_on_signals  # no JAX: installed in milliseconds

    # first of all, before the arguments are parsed and long before JAX loads: from here on SIGINT / SIGTERM only
    # set a flag, and the run stops at its next check (before the command starts, between models, within a fit,
    # before each file is written) by raising `Interrupted`: an exception raised by the handler itself could land
    # inside JAX (module _interrupts says what went wrong). Run as the program (argv None), the signals stay ignored
    # on the way out: one after the files are published does not turn a finished run into a death by signal
    with stop_on_signals(restore=argv is not None):
        command, out = "fricjax", "the output folder"
        try:
            args = _parse(argv)
            command, out = f"fricjax {args.command}", args.out
            check_interrupt()
            with warnings.catch_warnings():  # a warning as one line among the run's own ("warning: ..."), not
                warnings.showwarning = _print_warning  # Python's two lines with a source path and a line of code
                return _run(args)
        except KeyboardInterrupt:  # `Interrupted`; the staging folder is removed on the way out
            print(f"{command}: interrupted; nothing was written to {out}", file=sys.stderr)
            return 130


def _print_warning(message: Warning | str, category: type[Warning], *_: object, **__: object) -> None:
    """`warnings.showwarning` for the command line: `warning: MESSAGE` on stdout, with the run's other lines."""
    print("warning: " + " ".join(str(message).split()), flush=True)


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    """The arguments; an unknown option is reported by its command's parser (its usage, not the top level's),
    with the closest option names (`--modles`: did you mean --models?)."""
    parser = _parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        command = parser.commands[args.command]  # type: ignore[attr-defined]
        known = [o[2:] for action in command._actions for o in action.option_strings if o.startswith("--")]
        hints = {
            u: difflib.get_close_matches(u.split("=")[0].lstrip("-"), known, n=1, cutoff=0.75)
            for u in unknown
            if u.startswith("-")
        }
        said = "; ".join(f"did you mean --{h[0]} for {u}?" for u, h in hints.items() if h)
        command.error(f"unrecognized arguments: {' '.join(unknown)}" + (f" ({said})" if said else ""))
    return args


def _parser() -> argparse.ArgumentParser:
    """The command line's arguments (`--help` and argument errors answer before JAX loads)."""
    parser = argparse.ArgumentParser(prog="fricjax", description="Friction models as JAX scan simulators.")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="simulate every physics model from pre-sliding into gross sliding")
    demo.add_argument(
        "--out", default="fricjax-demo", help="output folder for the figure and JSON (default: %(default)s)"
    )
    demo.add_argument("--no-figure", action="store_true", help="skip the figure")
    demo.add_argument("--no-cache", action="store_true", help=_NO_CACHE_HELP)
    compare = sub.add_parser(
        "compare", help="fit every model to a record, compare them on held-out data, add ensembles, report"
    )
    compare.add_argument(
        "--data",
        nargs="+",
        default=["tribometer:mixed"],
        metavar="RECORD",
        help="the training record(s): tribometer:presliding|mixed|sliding[:seed=N,offset=F,drift=F,duration=S] "
        "(synthetic), emps (real EMPS data), or FILE.npz/.csv with columns t (time) or dt, x (position, "
        "displacement) and/or v (velocity), force (F, friction); units in brackets, e.g. 'x [um]', or as a suffix, "
        "e.g. displacement_in. Several records (quoted globs allowed: 'char/*.npz') are fitted together: one "
        "model, each record with its own force offset, initial state and drift, validated on the last 20 %% of "
        "each (or on --validation records) (default: tribometer:mixed)",
    )
    compare.add_argument(
        "--validation",
        nargs="+",
        metavar="RECORD",
        help="whole validation records (choice among starts) for several --data records, which are then trained "
        "on whole",
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
        "--init",
        choices=("state", "offset"),
        default="state",
        help="how a model starts on a --test record: state (the force offset and the model's initial state fitted "
        "on the initialisation window, fj.initialise) or offset (a run from rest, the window's mean error as the "
        "offset) (default: %(default)s)",
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
        help="Levenberg-Marquardt step budget per fit (GMS: twice that) (default: %(default)s)",
    )
    compare.add_argument(
        "--gms-elements",
        type=_count_or_auto,
        default="auto",
        help="GMS elements, or auto: 4, or more where the training record asks for more (fj.element_count: the "
        "fewest, 2-8, whose Maxwell-slip regression fits it within 2 %% of the best count's residual) and the "
        "validation part prefers them significantly (default: %(default)s)",
    )
    compare.add_argument(
        "--starts",
        type=int,
        default=2,
        help="starts of the Levenberg-Marquardt fits (static curve, LuGre, Maxwell-slip): more than 2 are drawn "
        "log-uniformly around the data-driven start, screened in one vmap-ed program, the best 2 polished; --seed "
        "changes the draws. GMS: 256 draws (or --starts if more) around fj.initial_guess's start, screened by their "
        "loss at the start, the best 4 fitted (default: %(default)s)",
    )
    compare.add_argument(
        "--maxwell-elements", type=int, default=5, help="Maxwell-slip NLR / DNLRX elements (default: %(default)s)"
    )
    compare.add_argument(
        "--fix",
        nargs="+",
        metavar="NAME=VALUE",
        type=_named_value,
        help="hold a parameter of the physics models at VALUE (SI units: N, m, s) in every model that has it: NAME "
        "is its field or the end of its path, e.g. sigma2=0 or stribeck.vs=1e-3 (printed models mark it fixed)",
    )
    compare.add_argument(
        "--bounds",
        nargs="+",
        metavar="NAME=LO:HI",
        type=_named_interval,
        help="keep a parameter of the physics models inside (LO, HI) (SI units), e.g. sigma0=1e4:1e8; a start "
        "outside is moved inside",
    )
    compare.add_argument(
        "--drift",
        default="auto",
        choices=("auto", "linear", "leaky", "none"),
        help="force-sensor drift fitted with every model (fj.SensorDrift; with several --data records one drift "
        "per record), so that it stays out of the friction parameters; it belongs to its record: see --test-drift. "
        "auto: linear for one training record, none for several (per-record drifts did not generalise on the "
        "damper's records) (default: %(default)s)",
    )
    compare.add_argument(
        "--test-drift",
        choices=("auto", "none", "window", "carry"),
        default="auto",
        help="a training record's drift on --test records: none (a drift belongs to its record), window (estimated "
        "on the initialisation window with --init state), carry (the training drift carried over, restarting at 0, "
        "scaled by the ratio of the force ranges the model predicts on the two records; one training record), "
        "auto: carry on the built-in tribometer's records (its simulated force cell drifts by one law in every "
        "record), none on file records (default: %(default)s)",
    )
    compare.add_argument(
        "--normal-force-column",
        nargs="+",
        metavar="COLUMN",
        help="the column(s) of the file records that give the normal load (several are summed); default: a column "
        "normal_force / N if present. A load that follows the friction force itself (|correlation| >= 0.97 with the "
        "force or its magnitude: a drive force) is refused",
    )
    compare.add_argument(
        "--accept-correlated-load",
        action="store_true",
        help="take a normal load that follows the friction force (refused otherwise: as an input it hands the "
        "models the force they should predict)",
    )
    compare.add_argument(
        "--velocity",
        choices=("auto", "file", "derive"),
        default="auto",
        help="the velocity of file records: auto (the file's if it agrees with the displacement's derivative, an "
        "error otherwise), file, derive (from the displacement) (default: %(default)s)",
    )
    compare.add_argument("--dt", type=float, default=None, help="sample time [s] of the file records (overrides t)")
    compare.add_argument("--x-unit", default=None, help="displacement unit of the file records (m, mm, um, nm, in)")
    compare.add_argument("--force-unit", default=None, help="force unit of the file records (N, kN, mN, lbf, kip)")
    compare.add_argument("--t-unit", default=None, help="time unit of the file records' t / dt columns (s, ms, us)")
    _add_column_options(compare)
    compare.add_argument("--out", default="fricjax-compare", help="output folder (default: %(default)s)")
    compare.add_argument("--seed", type=int, default=0, help="seed for the synthetic data and multi-starts")
    compare.add_argument("--no-progress", action="store_true", help="no progress bars")
    compare.add_argument("--no-cache", action="store_true", help=_NO_CACHE_HELP)
    compare.add_argument(
        "--device",
        choices=("auto", "cpu", "gpu"),
        default="auto",
        help="where the fits run: auto (the host CPU: the fastest for this command's single-start fits of records "
        "of thousands of samples, even on a GPU machine), cpu, gpu (the accelerator; each model's fit still runs on "
        "the host CPU when it has no time-parallel form or its record is short, as fj.fit(device='auto') chooses; "
        "stated in the log) (default: %(default)s)",
    )
    predict = sub.add_parser(
        "predict", help="run saved models on records they were not fitted on, score them as compare does, report"
    )
    predict.add_argument(
        "--model", nargs="+", required=True, metavar="FILE", help="model files (compare writes them to OUT/models)"
    )
    predict.add_argument(
        "--data", nargs="+", required=True, metavar="RECORD", help="records to predict (files, quoted globs)"
    )
    predict.add_argument(
        "--init-window",
        type=int,
        default=None,
        help="samples at the start of each record that estimate its force offset and the model's state and are not "
        "scored (default: 10 %% of the record)",
    )
    predict.add_argument("--init", choices=("state", "offset"), default="state", help="as compare's --init")
    predict.add_argument(
        "--test-drift",
        choices=("none", "window"),
        default="none",
        help="none: the models as fitted, a training record's sensor drift left behind; window: a linear drift fitted "
        "on the initialisation window with the offset and the state (--init state), and extrapolated",
    )
    for option, text in (
        ("--dt", "sample time [s]"),
        ("--x-unit", "displacement unit"),
        ("--force-unit", "force unit"),
    ):
        predict.add_argument(
            option, type=float if option == "--dt" else str, default=None, help=f"as compare's: {text}"
        )
    predict.add_argument("--t-unit", default=None, help="time unit of the t / dt columns (s, ms, us)")
    _add_column_options(predict)
    predict.add_argument("--velocity", choices=("auto", "file", "derive"), default="auto", help="as compare's")
    predict.add_argument("--normal-force-column", nargs="+", metavar="COLUMN", help="as compare's")
    predict.add_argument("--accept-correlated-load", action="store_true", help="as compare's")
    predict.add_argument("--out", default="fricjax-predict", help="output folder (default: %(default)s)")
    predict.add_argument("--no-cache", action="store_true", help=_NO_CACHE_HELP)
    parser.commands = {"demo": demo, "compare": compare, "predict": predict}  # type: ignore[attr-defined]
    return parser


def _add_column_options(command: argparse.ArgumentParser) -> None:
    """--t-column, --x-column, --v-column, --force-column: a file's columns whose names are no alias of their role;
    --resample: every file record at one sample rate."""
    command.add_argument(
        "--resample",
        type=float,
        default=None,
        metavar="HZ",
        help="resample every file record to HZ (a polyphase anti-alias filter, fj.resample): records sampled at "
        "different rates are fitted and scored together",
    )
    for role, what in (("t", "time"), ("x", "displacement"), ("v", "velocity"), ("force", "friction force")):
        command.add_argument(
            f"--{role}-column",
            default=None,
            metavar="COLUMN",
            help=f"the column of the file records that holds the {what} (when its name is none of the aliases; a "
            "unit in brackets or as a suffix counts)",
        )


def _named_value(text: str) -> tuple[str, float]:
    """`NAME=VALUE` of `--fix` as `(name, value)`."""
    name, sep, value = text.partition("=")
    try:
        if not (sep and name.strip()):
            raise ValueError
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give NAME=VALUE, e.g. sigma2=0") from None


def _named_interval(text: str) -> tuple[str, tuple[float, float]]:
    """`NAME=LO:HI` of `--bounds` as `(name, (low, high))`."""
    name, sep, interval = text.partition("=")
    low, colon, high = interval.partition(":")
    try:
        if not (sep and colon and name.strip()):
            raise ValueError
        return name.strip(), (float(low), float(high))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give NAME=LO:HI, e.g. sigma0=1e4:1e8") from None


def _record_options(args: argparse.Namespace) -> dict:  # type: ignore[type-arg]
    """How compare and predict read the record files: units, column names (`load_record`'s `columns`), velocity,
    the normal load and whether a load that follows the force is taken."""
    given = {role: getattr(args, f"{role}_column") for role in ("t", "x", "v", "force")}
    return {
        "dt": args.dt,
        "x_unit": args.x_unit,
        "force_unit": args.force_unit,
        "t_unit": args.t_unit,
        "columns": {role: name for role, name in given.items() if name is not None} or None,
        "velocity": args.velocity,
        "normal_force_column": args.normal_force_column,
        "accept_correlated_load": args.accept_correlated_load,
        "resample": args.resample,
    }


def _count_or_auto(text: str) -> int | str:
    """A command-line count that may be `auto`: an int (checked by `FitSettings`, one line) or "auto"."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer or auto, got {text!r}") from None


def _run(args: argparse.Namespace) -> int:
    """`main` after the arguments are parsed."""
    import jax

    if getattr(args, "device", "auto") == "auto" and not os.environ.get("JAX_PLATFORMS"):
        # the command's records (thousands of samples) and single-start fits run fastest on the host CPU, and an
        # accelerator's start-up alone costs seconds (benchmarks/README.md, "Accelerators"): leave it uninitialised
        jax.config.update("jax_platforms", "cpu")
        if _accelerator_installed():
            print("fricjax: running on the host CPU (--device gpu runs the fits on the accelerator)")

    from . import _lapack_threads  # noqa: F401  (OpenBLAS on one thread, as `import fricjax`'s public names do)

    if not (args.no_cache or cache_disabled()):
        enable_compilation_cache()

    from ._protocols._demo import run_demo
    from ._protocols.compare._config import CompareConfig, as_flags
    from ._protocols.compare._output import check_writable, output_folder
    from ._protocols.compare._run import run_compare
    from ._protocols.compare._settings import CompareError

    jax.config.update("jax_enable_x64", True)
    if args.command == "demo":
        try:
            out = output_folder(args.out)
            check_writable(out)
        except CompareError as err:
            print(f"fricjax demo: {as_flags(str(err))}", file=sys.stderr)
            return 2
        run_demo(out, figure=not args.no_figure)
        return 0
    if args.command == "predict":
        from ._protocols.compare._predict import run_predict

        try:
            run_predict(
                models=args.model,
                data=args.data,
                init_window=args.init_window,
                init=args.init,
                test_drift=args.test_drift,
                **_record_options(args),
                out=args.out,
            )
        except CompareError as err:
            print("fricjax predict: " + " ".join(as_flags(str(err)).split()), file=sys.stderr)
            return 2
        return 0
    if args.device == "gpu" and not [d for d in jax.devices() if d.platform != "cpu"]:
        print(
            f"fricjax compare: --device gpu but JAX sees only CPU devices ({jax.devices()}); use --device cpu or auto "
            "(or install JAX for your accelerator)",
            file=sys.stderr,
        )
        return 2
    try:
        config = CompareConfig(
            data=args.data,
            test=args.test,
            validation=args.validation,
            split_at=args.split,
            init_window=args.init_window,
            models=args.models,
            steps=args.steps,
            gms_elements=args.gms_elements,
            maxwell_elements=args.maxwell_elements,
            starts=args.starts,
            drift=args.drift,
            neural_steps=args.neural_steps,
            **_record_options(args),
            init=args.init,
            test_drift=args.test_drift,
            fix=dict(args.fix or ()),
            bounds=dict(args.bounds or ()),
            out=args.out,
            seed=args.seed,
            progress=not args.no_progress,
            # gpu: the accelerator is JAX's default device and each model's fit goes where fj.fit(device="auto")
            # puts it (the host CPU without a time-parallel form or on a short record; stated in the log)
            device="cpu" if args.device == "cpu" else "auto",
        )
        run_compare(config)
        return 0
    except CompareError as err:  # named as the configuration's fields: shown as this command's flags
        print("fricjax compare: " + " ".join(as_flags(str(err)).split()), file=sys.stderr)
        return 2


def _accelerator_installed() -> bool:
    """Whether a JAX accelerator plugin (CUDA, ROCm, TPU) is installed (without starting JAX's backends)."""
    import importlib.metadata

    names = {(dist.metadata["Name"] or "").lower() for dist in importlib.metadata.distributions()}
    return any(name.startswith(("jax-cuda", "jax_cuda", "jax-rocm", "jax_rocm", "libtpu")) for name in names)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
