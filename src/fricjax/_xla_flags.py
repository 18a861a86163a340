"""The one XLA setting fricjax makes: XLA:CPU compiles every small `lax.scan` (up to 64 KiB per step) into one function.

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
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import MutableMapping

SMALL_WHILE_LOOP_KEY = "xla_cpu_small_while_loop_byte_threshold"
# 64 KiB per iteration: every friction model's loop and its reverse pass (16 KiB suffice for LuGre, GMS and
# Maxwell-slip gradients), not the loops over large arrays (k-nearest-neighbour searches over the training set,
# kernel models, wide batches), which keep XLA's op-by-op execution and its intra-op threads: with no limit, a
# notebook's k-nearest-neighbour free run hung once in a CI run (a wait inside XLA that never returned)
SMALL_WHILE_LOOP_BYTES = 1 << 16
_EXTRA_OPTIONS = "--xla_backend_extra_options="


def add_small_while_loop_flag(environ: MutableMapping[str, str]) -> bool:
    """Add the small-while-loop threshold to `environ["XLA_FLAGS"]` (merged into an existing
    `--xla_backend_extra_options=` list). Returns whether `environ` was changed."""
    if environ.get("FRICJAX_KEEP_XLA_FLAGS"):
        return False
    flags = environ.get("XLA_FLAGS", "")
    if SMALL_WHILE_LOOP_KEY in flags:
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


def configure() -> None:
    """Called once by `import fricjax`: set the flag, and warn when JAX's backends already started without it."""
    if not add_small_while_loop_flag(os.environ):
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
            "fricjax was imported after JAX started its backends, so its XLA:CPU setting "
            f"(--xla_backend_extra_options={SMALL_WHILE_LOOP_KEY}=...) does not apply in this process: gradients "
            "of long simulations run up to 20x slower on CPU (benchmarks/README.md). Import fricjax before the "
            "first JAX computation, or set FRICJAX_KEEP_XLA_FLAGS=1 to silence this.",
            stacklevel=3,
        )


configure()
