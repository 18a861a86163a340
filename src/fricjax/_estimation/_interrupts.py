"""Stopping where it is safe, not where a signal lands: `stop_on_signals` installs handlers for SIGINT and SIGTERM
that only record the signal; long runs call `check_interrupt` between their stages (`fricjax compare` between
models and before it writes, `fit` between chunks of solver steps), which raises `Interrupted` there, in the main
thread's ordinary code.

Why not raise from the handler, as Python's own SIGINT handler does: a handler runs wherever the main thread
happens to be, and an exception raised there is lost or leaves JAX half-way. Inside JAX's garbage-collection
callback it is dropped ("Exception ignored in _xla_gc_callback": the run went on and wrote its report). While the
main thread waits for a compilation, jaxlib checks for signals and gives up waiting, but the compilation goes on in
XLA's thread pool; the interpreter then exits and frees the client under it: a segmentation fault on the compiling
thread (`xla::ifrt::SingleDeviceSharding::Create` in `PjRtCompiler::CompileAndLoad`) after `main` returned 130.
"""

from __future__ import annotations

import contextlib
import os
import signal

TYPE_CHECKING = False  # no `typing` (10 ms) before the `fricjax` program's first statement; type checkers read True
if TYPE_CHECKING:
    from collections.abc import Iterator
    from typing import Any

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """Raised by `check_interrupt` after SIGINT or SIGTERM. A `KeyboardInterrupt`, so that no `except Exception`
    on the way out (a recipe's fallback, a retry) takes it for a failure and goes on."""


class _State:
    received: int | None = None  # the first signal received while the handlers are installed
    hold: int = 0  # > 0: inside `hold_signals` (a second signal is recorded too, not fatal)


def check_interrupt() -> None:
    """Raise `Interrupted` if SIGINT or SIGTERM arrived since `stop_on_signals` installed its handlers (without
    them, never)."""
    if _State.received is not None:
        raise Interrupted(signal.Signals(_State.received).name)


def interrupted() -> bool:
    """Whether SIGINT or SIGTERM arrived since the handlers were installed."""
    return _State.received is not None


def _record(signum: int, frame: Any) -> None:
    """The handler: records the signal. A second one (Ctrl-C twice) ends the process at once, by the signal's
    default action, unless inside `hold_signals`."""
    if _State.received is not None and not _State.hold:
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    if _State.received is None:
        _State.received = signum


def catch_signals() -> None:
    """Install the flag-setting handlers now, for the program's whole life: the first statement of the `fricjax`
    program (`fricjax.__main__`), milliseconds after Python starts, so that a Ctrl-C while Python imports the
    command line is a recorded signal too (exit 130, no traceback). `stop_on_signals` keeps such a signal."""
    for number in _SIGNALS:
        if signal.getsignal(number) is not signal.SIG_IGN:
            signal.signal(number, _record)


@contextlib.contextmanager
def stop_on_signals(*, restore: bool = True) -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM only set the flag that `check_interrupt` raises on (where a signal is
    ignored, as for a background job's SIGINT, it stays ignored). `restore=False` leaves the signals ignored on the
    way out, for a program that exits next: a signal after the work is done does not turn success into a death by
    signal. Outside the main thread (where handlers cannot be set) nothing changes."""
    previous: dict[signal.Signals, Any] = {}
    try:
        for number in _SIGNALS:
            if signal.getsignal(number) is not signal.SIG_IGN:
                previous[number] = signal.signal(number, _record)
    except ValueError:  # not the main thread
        for number, handler in previous.items():
            signal.signal(number, handler)
        previous = {}
    if not any(handler is _record for handler in previous.values()):  # else kept: `catch_signals` came first
        _State.received = None
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler if restore else signal.SIG_IGN)
        _State.received = None


@contextlib.contextmanager
def hold_signals() -> Iterator[None]:
    """Within the block (a few renames that must happen together), even a second signal is only recorded."""
    _State.hold += 1
    try:
        yield
    finally:
        _State.hold -= 1
