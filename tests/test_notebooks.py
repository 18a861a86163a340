"""Execute every notebook in its smoke size (FRICJAX_SMOKE=1); each ends with an assertion on a metric.

A cell that runs past `CELL_TIMEOUT` fails the test. Every `STACK_DUMP_EVERY` seconds of one cell, the kernel's
stacks are written to the test's captured stderr (shown when it fails): the Python stack of every thread
(`faulthandler`, armed by a first cell the test adds) and, where gdb is installed, the native ones. A cell that
loops in Python and a computation that waits forever inside XLA look alike from outside; these tell them apart.
"""

from __future__ import annotations

import os
import pathlib
import re
import shutil
import signal
import subprocess
import sys
import threading
import time

import pytest

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
CELL_TIMEOUT = 900  # s; smoke-size cells take seconds to a few minutes on 2 cores
STACK_DUMP_EVERY = 300  # s
# arms the kernel's faulthandler without leaving names in the notebook's namespace (a notebook must import its own)
ARM_FAULTHANDLER = (
    '__import__("faulthandler").register(__import__("signal").SIGUSR1, file=__import__("sys").__stderr__, '
    "all_threads=True)  # added by tests/test_notebooks.py: the stack dumps of a stalled cell"
)


def _kernel_pid(client) -> int | None:
    provisioner = getattr(getattr(client, "km", None), "provisioner", None)
    return getattr(provisioner, "pid", None) or getattr(getattr(provisioner, "process", None), "pid", None)


def _compact_stacks(gdb_output: str, frames: int = 14) -> str:
    """gdb's `thread apply all bt` reduced to each thread's name and its innermost function names."""
    lines = []
    for line in gdb_output.splitlines():
        frame = re.match(r"#(\d+)\s+(?:0x[0-9a-f]+ in )?(\S+)", line)
        if line.startswith("Thread "):
            lines.append(line[:120])
        elif frame and int(frame.group(1)) < frames:
            lines.append("    " + frame.group(2)[:150])
    return "\n".join(lines)


def _dump_stacks(pid: int | None, cell_source: str, elapsed: float) -> None:
    write = sys.stderr.write
    write(f"\n==== notebook cell still running after {elapsed:.0f} s (kernel pid {pid}) ====\n{cell_source[:300]}\n")
    if pid is None:
        write("(no kernel pid: stacks not dumped)\n")
        return
    write("---- Python stacks (faulthandler, written by the kernel to its stderr) ----\n")
    sys.stderr.flush()
    try:
        os.kill(pid, signal.SIGUSR1)
    except OSError as error:
        write(f"(SIGUSR1 not delivered: {error})\n")
    gdb = shutil.which("gdb")
    if gdb is None:
        write("(gdb not installed: native stacks not dumped)\n")
        return
    command = [gdb, "-nx", "-batch", "-ex", "set debuginfod enabled off", "-p", str(pid), "-ex", "thread apply all bt"]
    try:
        stacks = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    except (subprocess.TimeoutExpired, OSError) as error:
        write(f"(gdb failed: {error})\n")
        return
    compact = _compact_stacks(stacks.stdout)
    if "Thread " not in compact:
        compact = f"(no stacks from gdb, exit {stacks.returncode}: {stacks.stderr[-500:]})"
    write("---- native stacks (gdb) ----\n" + compact + "\n")


class _Watchdog:
    """Dumps the kernel's stacks every `STACK_DUMP_EVERY` s while one cell runs."""

    def __init__(self):
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, pid: int | None, source: str) -> None:
        self.stop()
        stop = self._stop = threading.Event()

        def watch() -> None:
            began = time.monotonic()
            while not stop.wait(STACK_DUMP_EVERY):
                _dump_stacks(pid, source, time.monotonic() - began)

        self._thread = threading.Thread(target=watch, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop watching; a dump under way (gdb may take up to 2 minutes) finishes first."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=180)
            self._thread = None


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_in_smoke_size(path, data_dir, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("FRICJAX_SMOKE", "1")
    monkeypatch.setenv("FRICJAX_DATA", str(data_dir))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read(path, as_version=4)
    notebook.cells.insert(0, nbformat.v4.new_code_cell(ARM_FAULTHANDLER))
    watchdog = _Watchdog()
    client = nbclient.NotebookClient(
        notebook,
        timeout=CELL_TIMEOUT,
        kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
        on_cell_execute=lambda cell, **_: watchdog.start(_kernel_pid(client), cell.source),
        on_cell_executed=lambda **_: watchdog.stop(),
    )
    try:
        client.execute()  # raises CellExecutionError when a cell (the final metric assertion included) fails
    finally:
        watchdog.stop()
