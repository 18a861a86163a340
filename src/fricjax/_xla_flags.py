"""The three XLA settings fricjax makes: XLA:CPU compiles every small `lax.scan` (up to 64 KiB per step) into one
function, the host CPU is seen as one JAX device per core, so that batched work (sweeps, multi-starts) is spread
over every core, and XLA:CPU schedules a program's operations without its concurrency-optimized scheduler, which
gave wrong results at random (below).

XLA:CPU runs a while loop (a `lax.scan`) either op by op, each fused kernel of every iteration dispatched by its
runtime, or, when XLA's cost analysis finds that the loop body accesses fewer than
`xla_cpu_small_while_loop_byte_threshold` bytes (default 1 024), as one compiled function ("small call"). Friction
models sit at that limit: the GMS free run that returns only the force is under it, the same loop storing its
states, as every reverse-mode derivative of a scan does, is over it and ran 4x slower per step. On the 2-core CPU
of benchmarks/README.md, value_and_grad / forward is 27.5x for LuGre, 21.4x for GMS and 17.4x for Maxwell-slip
with XLA's default and 1.6x, 3.1x and 4.3x with the threshold raised, the forward passes unchanged
(benchmarks/simulate.py, `results/cpu-2core-small-call.jsonl` and `...-off.jsonl`, one session).

`import fricjax` therefore adds `xla_cpu_small_while_loop_byte_threshold=SMALL_WHILE_LOOP_BYTES` to the
`--xla_backend_extra_options` of the `XLA_FLAGS` environment variable, which XLA reads when JAX starts its
backends (at the first computation, not at `import jax`). It leaves `XLA_FLAGS` alone when the key is already
there (set it yourself, e.g. to XLA's default 1024, to opt out) or when `FRICJAX_KEEP_XLA_FLAGS` is set to a
non-empty value. Only the CPU compiler reads the key (`xla::cpu::options`).

Every core for batched work: XLA:CPU runs one program on one device, and a vmap-ed batch on one device uses the
cores only as far as XLA's intra-op threads split its operations (little, for a batch of scans). `import fricjax`
therefore also adds `--xla_force_host_platform_device_count=N` (N the cores this process may use, at most
`MAX_HOST_DEVICES`, and at most the CPUs of a cgroup CPU quota, as `docker --cpus` sets; `FRICJAX_HOST_DEVICES=N`
to choose, 1 for one device), and `fj.shard_batch` spreads a batch of
at least `MIN_ROWS_PER_DEVICE` rows per device over them (`_estimation/loop/_sharding.py`). A single computation runs on
the first device as before. On the 2-core CPU of benchmarks/README.md: a vmap over 1024 LuGre models 5.4x a numba
trajectory's throughput sharded over two devices against 2.5x on one; the default `fricjax compare` 38 s against 40 s.
Left alone when `XLA_FLAGS` already sets the device count, or with `FRICJAX_KEEP_XLA_FLAGS`.

**Same program, same inputs, different results.** XLA:CPU (jaxlib 0.10.2) runs the independent operations of a
program at once on its thread pool, in the order its scheduler chose; with the default, concurrency-optimized
scheduler, a program stepping optimistix's Levenberg-Marquardt or Dogleg (a QR factorisation through LAPACK in a
while loop, the solver state returned) gave a different answer in 3-30 % of the calls of one compiled executable on
2 cores (8 steps of a three-parameter exponential fit: 2.0010 / 3.0134 / 0.5025 in most calls, 2.0063 / 2.8594 /
0.4733 or one of some 20 other iterates in the rest; a fast-tier test failed twice that way). It is a race between
operations run at once: on one core, or with `--xla_cpu_enable_concurrency_optimized_scheduler=false`, 300-1 500
calls of each program gave one answer. `import fricjax` therefore adds that flag (`SCHEDULER_FLAG`) unless
`XLA_FLAGS` names the option already or `FRICJAX_KEEP_XLA_FLAGS` is set. Its price on the 2-core CPU
(`benchmarks/records.py`, warm; benchmarks/README.md): the ten-record fit 0.78-0.82 s with XLA's scheduler against
0.76-1.03 s with the flag, the loop of ten single fits 2.40-2.59 against 2.73-2.86 s, the concatenated record
0.87-0.89 against 1.05-1.11 s: up to about 20 %.
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Mapping, MutableMapping

SMALL_WHILE_LOOP_KEY = "xla_cpu_small_while_loop_byte_threshold"
# 64 KiB per iteration: every friction model's loop and its reverse pass (16 KiB suffice for LuGre, GMS and
# Maxwell-slip gradients), not the loops over large arrays (k-nearest-neighbour searches over the training set,
# kernel models, wide batches), which keep XLA's op-by-op execution and its intra-op threads: with no limit, a
# notebook's k-nearest-neighbour free run hung once in a CI run (a wait inside XLA that never returned)
SMALL_WHILE_LOOP_BYTES = 1 << 16
_EXTRA_OPTIONS = "--xla_backend_extra_options="
HOST_DEVICES_FLAG = "--xla_force_host_platform_device_count"
# more host devices than this gain nothing measured here and multiply the per-device buffers of sharded programs
MAX_HOST_DEVICES = 8
# where the cgroup CPU quota is read (`FRICJAX_CGROUP_ROOT` for another mount point)
CGROUP_ROOT = "/sys/fs/cgroup"
# XLA:CPU's concurrency-optimized scheduler off: operations run at once in its order raced (module docstring)
SCHEDULER_KEY = "xla_cpu_enable_concurrency_optimized_scheduler"
SCHEDULER_FLAG = f"--{SCHEDULER_KEY}=false"


def host_device_count(environ: MutableMapping[str, str]) -> int:
    """The host devices fricjax asks XLA for: `FRICJAX_HOST_DEVICES`, else the cores this process may run on (at
    most `MAX_HOST_DEVICES`)."""
    chosen = environ.get("FRICJAX_HOST_DEVICES", "").strip()
    if chosen:
        try:
            count = int(chosen)
        except ValueError:
            raise ValueError(
                f"FRICJAX_HOST_DEVICES={chosen!r}: expected a whole number of host devices (1 for one device)"
            ) from None
        if count < 1:
            raise ValueError(f"FRICJAX_HOST_DEVICES={chosen!r}: expected at least 1")
        return count
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        cores = os.cpu_count() or 1
    quota = cpu_quota(environ.get("FRICJAX_CGROUP_ROOT", "").strip() or CGROUP_ROOT)
    if quota is not None:  # a container limited to 2 CPUs of a 64-core host runs on 64 cores' affinity
        cores = min(cores, quota)
    return max(1, min(cores, MAX_HOST_DEVICES))


def cpu_quota(root: str) -> int | None:
    """The CPUs a cgroup CPU quota gives this process, `ceil(quota / period)`, or None without a quota (or without
    readable cgroup files): cgroup v2's `cpu.max` ("200000 100000"; "max 100000" is no quota), else cgroup v1's
    `cpu/cpu.cfs_quota_us` and `cpu/cpu.cfs_period_us` (a quota of -1 is none), under `root` (a container's own
    cgroup is mounted there). Never raises: `import fricjax` reads it."""
    try:
        try:
            fields = _read(root, "cpu.max").split()
        except FileNotFoundError:
            quota = int(_read(root, "cpu", "cpu.cfs_quota_us"))
            period = int(_read(root, "cpu", "cpu.cfs_period_us"))
        else:
            quota, period = (-1, 1) if fields[0] == "max" else (int(fields[0]), int(fields[1]))
    except (OSError, ValueError, IndexError):  # unreadable, not UTF-8, not numbers
        return None
    return max(1, -(-quota // period)) if quota > 0 and period > 0 else None


def _read(*parts: str) -> str:
    """A text file's contents (`os.path`, not `pathlib`: this runs at the `fricjax` program's start, where importing
    pathlib took 9 ms of the ~30 ms before the program's signal handlers are set)."""
    with open(os.path.join(*parts), encoding="utf-8") as file:
        return file.read()


def _flags_open_to(environ: Mapping[str, str], key: str) -> str | None:
    """`environ["XLA_FLAGS"]` ("" when unset) if fricjax may add `key` to it, else None: the user opted out
    (`FRICJAX_KEEP_XLA_FLAGS`) or the flags name `key` already (the user's own value, or a parent process's
    inherited with XLA_FLAGS, wins)."""
    if environ.get("FRICJAX_KEEP_XLA_FLAGS"):
        return None
    flags = environ.get("XLA_FLAGS", "")
    return None if key in flags else flags


def add_host_devices_flag(environ: MutableMapping[str, str]) -> bool:
    """Add `--xla_force_host_platform_device_count=N` (`host_device_count`) to `environ["XLA_FLAGS"]` unless it
    is there or N is 1. Returns whether `environ` was changed."""
    flags = _flags_open_to(environ, HOST_DEVICES_FLAG)
    if flags is None:
        return False
    count = host_device_count(environ)
    if count == 1:
        return False
    environ["XLA_FLAGS"] = " ".join([*flags.split(), f"{HOST_DEVICES_FLAG}={count}"])
    return True


def add_small_while_loop_flag(environ: MutableMapping[str, str]) -> bool:
    """Add the small-while-loop threshold to `environ["XLA_FLAGS"]` (merged into an existing
    `--xla_backend_extra_options=` list). Returns whether `environ` was changed."""
    flags = _flags_open_to(environ, SMALL_WHILE_LOOP_KEY)
    if flags is None:
        return False
    option = f"{SMALL_WHILE_LOOP_KEY}={SMALL_WHILE_LOOP_BYTES}"
    tokens = flags.split()
    for i, token in enumerate(tokens):
        if token.startswith(_EXTRA_OPTIONS):
            existing = token[len(_EXTRA_OPTIONS) :]
            tokens[i] = _EXTRA_OPTIONS + (f"{existing},{option}" if existing else option)
            break
    else:
        tokens.append(_EXTRA_OPTIONS + option)
    environ["XLA_FLAGS"] = " ".join(tokens)
    return True


def add_scheduler_flag(environ: MutableMapping[str, str]) -> bool:
    """Add `SCHEDULER_FLAG` to `environ["XLA_FLAGS"]` unless the option is there. Returns whether `environ` was
    changed."""
    flags = _flags_open_to(environ, SCHEDULER_KEY)
    if flags is None:
        return False
    environ["XLA_FLAGS"] = " ".join([*flags.split(), SCHEDULER_FLAG])
    return True


def configure() -> None:
    """Called once by `import fricjax`: set the flags, and warn when JAX's backends already started without them."""
    add_host_devices_flag(os.environ)  # without effect, and without a warning, once JAX's backends have started
    changed = [add_small_while_loop_flag(os.environ), add_scheduler_flag(os.environ)]
    if not any(changed):
        return
    if "jax" not in sys.modules:  # JAX not imported yet: its backends cannot have started (and importing it is slow)
        return
    try:
        from jax._src import xla_bridge  # private: only to tell whether the setting can still take effect

        started = xla_bridge.backends_are_initialized()
    except (ImportError, AttributeError):  # pragma: no cover - other JAX versions
        return
    if started:
        warnings.warn(
            "fricjax was imported after JAX started its backends, so its XLA:CPU settings "
            f"(--xla_backend_extra_options={SMALL_WHILE_LOOP_KEY}=..., {SCHEDULER_FLAG}) do not apply in this "
            "process: gradients of long simulations run up to 20x slower on CPU, and programs that factorise "
            "matrices in a loop (optimistix's trust-region solvers) can give different results from run to run "
            "(fricjax/_xla_flags.py). Import fricjax before the first JAX computation, or set "
            "FRICJAX_KEEP_XLA_FLAGS=1 to silence this.",
            stacklevel=3,
        )


configure()
