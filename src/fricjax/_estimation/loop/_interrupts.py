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

Checks between steps are not enough where one call takes long: a compilation, or a solver step on a long record,
runs in native code, and Python's handler runs only when it returns. Within `abandonable(message)` (the command line's
fits, before anything is staged) a watcher thread learns of the signal at once (`signal.set_wakeup_fd`); when the main
thread has not stopped `GRACE_S` seconds later (or at a second signal), the watcher runs the hooks registered with
`on_abandon` (the output folder's lock, a folder the run created), prints the message and ends the process with
`os._exit(130)`: no interpreter teardown, so nothing frees the JAX client under a compiling thread.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time

TYPE_CHECKING = False  # no `typing` (10 ms) before the `fricjax` program's first statement; type checkers read True
if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from typing import Any

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
GRACE_S = 3.0  # seconds the main thread has to stop by itself within `abandonable` before the process is ended


class Interrupted(KeyboardInterrupt):
    """Raised by `check_interrupt` after SIGINT or SIGTERM. A `KeyboardInterrupt`, so that no `except Exception`
    on the way out (a recipe's fallback, a retry) takes it for a failure and goes on."""


class _State:
    received: int | None = None  # the first signal received while the handlers are installed
    hold: int = 0  # > 0: inside `hold_signals` (a second signal is recorded too, not fatal)
    abandonable: list[str] = []  # the messages of the `abandonable` blocks the main thread is in, innermost last
    hooks: list[Callable[[], None]] = []  # `on_abandon`'s clean-ups, run last first
    guard = threading.Lock()  # the watcher ends the process only while holding it, and blocks leave under it


def check_interrupt() -> None:
    """Raise `Interrupted` if SIGINT or SIGTERM arrived since `stop_on_signals` installed its handlers (without
    them, never)."""
    if _State.received is not None:
        raise Interrupted(signal.Signals(_State.received).name)


def interruptible() -> bool:
    """Whether `stop_on_signals` (or `catch_signals`) handles SIGINT here: a long run should then check often."""
    return any(signal.getsignal(number) is _record for number in _SIGNALS)


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


def on_abandon(hook: Callable[[], None]) -> Callable[[], None]:
    """Register `hook` (a clean-up that must happen even when the process is ended by `abandonable`'s watcher: remove
    a lock file); **returns** the function that unregisters it (call it when the clean-up is done by the usual way)."""
    _State.hooks.append(hook)

    def remove() -> None:
        with contextlib.suppress(ValueError):
            _State.hooks.remove(hook)

    return remove


@contextlib.contextmanager
def abandonable(message: str) -> Iterator[None]:
    """Within the block, a SIGINT / SIGTERM that the main thread does not act on within `GRACE_S` (it waits in one
    long native call) ends the process: the `on_abandon` hooks run, `message` is printed, exit status 130. Use it
    only around work whose loss costs nothing (no file written but those the hooks remove). Outside the main thread,
    or where the handlers are not installed (a library call), nothing changes."""
    if threading.current_thread() is not threading.main_thread() or not interruptible():
        yield
        return
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    try:
        previous = signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    except ValueError:
        os.close(read_end)
        os.close(write_end)
        yield
        return
    _State.abandonable.append(message)
    depth = len(_State.abandonable)
    watcher = threading.Thread(target=_watch, args=(read_end, depth), name="fricjax-interrupt-watcher", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        with _State.guard:
            del _State.abandonable[depth - 1 :]
        signal.set_wakeup_fd(previous)
        os.close(write_end)  # the watcher reads end-of-file and returns
        watcher.join(timeout=1.0)
        os.close(read_end)


def _watch(read_end: int, depth: int) -> None:
    """The watcher of one `abandonable` block: wait for a signal's byte, give the main thread `GRACE_S` seconds (less
    at a second signal), then end the process if the block is still running."""
    while True:
        byte = os.read(read_end, 1)
        if not byte:
            return  # the block ended
        if byte[0] in _SIGNALS:  # another handled signal (none of fricjax's) wakes it too
            break
    deadline = time.monotonic() + GRACE_S
    os.set_blocking(read_end, False)
    while time.monotonic() < deadline:
        with contextlib.suppress(BlockingIOError):
            if os.read(read_end, 1)[:1] in [bytes([n]) for n in _SIGNALS]:
                break  # a second signal: at once
        if len(_State.abandonable) < depth:
            return  # the main thread stopped by itself
        time.sleep(0.05)
    with _State.guard:
        if len(_State.abandonable) < depth or _State.hold:
            return
        for hook in reversed(_State.hooks):
            with contextlib.suppress(Exception):
                hook()
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            print(_State.abandonable[-1], file=sys.stderr, flush=True)
        os._exit(130)
