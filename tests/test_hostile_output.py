"""Hostile conditions for `fricjax compare`'s output (issue 31 item 2): its files are published into --out as one
unit. A move that fails part-way, a folder where a file must go and a full disk while drawing the figures leave
--out exactly as it was, with one line on stderr that names the file and what to do (exit 2); the staging folders
of killed runs are removed by the next run; a second run into a folder that a live run writes to fails at once,
naming it (a lock file, taken over from a killed run). The tests that need a fit are slow (its compilation: 10-25 s
on the 2-core machine, once per test process; each one after the first takes about a second)."""

from __future__ import annotations

import errno
import json
import os
import pathlib
import socket
import subprocess
import sys
import time

import matplotlib.figure
import numpy as np
import pytest

import fricjax as fj

# one quick model on a short synthetic record (the programs compile once per test process)
RUN = ["compare", "--models", "stribeck", "--steps", "2", "--data", "tribometer:mixed:duration=0.5", "--no-progress"]


def _compare(out: pathlib.Path) -> int:
    return fj.main([*RUN, "--no-cache", "--out", str(out)])


def _previous_run(out: pathlib.Path) -> dict[str, bytes | None]:
    """Fill `out` with the files of an earlier run and one of the user's; returns its snapshot."""
    files = {
        "report.json": b'{"old": true}',
        "test_errors.png": b"old figure",
        "hysteresis_loops.png": b"old loops",
        "models/stribeck.eqx": b"old model",
        "models/gms.eqx": b"a model of another run",
        "notes.txt": b"the user's",
    }
    for name, content in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(content)
    return _snapshot(out)


def _snapshot(out: pathlib.Path) -> dict[str, bytes | None]:
    """Every entry under `out`, hidden ones included: a file's bytes, None for a folder."""
    return {str(path.relative_to(out)): None if path.is_dir() else path.read_bytes() for path in sorted(out.rglob("*"))}


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.slow
def test_a_move_that_fails_part_way_is_undone(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    before = _previous_run(out)
    replace = os.replace

    def busy_report(source, target, *args, **kwargs):  # the last move (the report's) fails: the others are undone
        if pathlib.Path(target) == out / "report.json" and ".partial-" in str(source) and "previous" not in str(source):
            raise OSError(errno.EBUSY, "Device or resource busy", str(target))
        return replace(source, target, *args, **kwargs)

    monkeypatch.setattr(os, "replace", busy_report)
    assert _compare(out) == 2
    line = _one_line(capsys.readouterr().err)
    assert "report.json" in line and "nothing was changed" in line and "close the program" in line, line
    assert _snapshot(out) == before


def test_a_folder_where_a_file_goes_is_refused_before_the_fit(tmp_path, capsys):
    out = tmp_path / "out"
    (out / "hysteresis_loops.png").mkdir(parents=True)
    (out / "hysteresis_loops.png" / "mine.txt").write_text("the user's")
    (out / "report.json").write_text("{}")
    before = _snapshot(out)
    started = time.perf_counter()
    assert _compare(out) == 2
    assert time.perf_counter() - started < 5  # not after a fit
    line = _one_line(capsys.readouterr().err)
    assert "hysteresis_loops.png is a folder" in line and "move it away" in line, line
    assert _snapshot(out) == before


@pytest.mark.slow
def test_a_folder_where_a_model_goes_changes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    _previous_run(out)
    (out / "models" / "stribeck.eqx").unlink()
    (out / "models" / "stribeck.eqx").mkdir()  # found only when the fitted models are known
    before = _snapshot(out)
    assert _compare(out) == 2
    line = _one_line(capsys.readouterr().err)
    assert "models/stribeck.eqx is a folder" in line and "nothing was written" in line, line
    assert _snapshot(out) == before


@pytest.mark.slow
def test_a_full_disk_while_drawing_is_one_line_and_changes_nothing(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    before = _previous_run(out)

    def full_disk(self, path, *args, **kwargs):
        pathlib.Path(path).write_bytes(b"\x89PNG half")  # a part written, as PIL does before it fails
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full_disk)
    assert _compare(out) == 2
    line = _one_line(capsys.readouterr().err)
    assert "test_errors.png" in line and "No space left" in line and "free some space" in line, line
    assert _snapshot(out) == before


def test_staging_folders_of_killed_runs_are_removed(tmp_path, capsys):
    out = tmp_path / "out"
    host = socket.gethostname()
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(gone.stdout)
    folders = {
        ".partial-abc123": None,  # an older fricjax's (no owner): removed once an hour old
        f".partial-{dead_pid}-x1": {"pid": dead_pid, "host": host},  # its process has ended: removed at once
        f".partial-{os.getpid()}-x2": {"pid": os.getpid(), "host": host},  # a live run's: kept
        ".partial-1-x3": {"pid": 1, "host": "another-machine"},  # another host's, recent: kept
        ".partial-1-x4": {"pid": dead_pid, "host": host},  # killed while publishing: holds the user's files
    }
    for name, owner in folders.items():
        (out / name / "new").mkdir(parents=True)
        (out / name / "new" / "report.json").write_text("{}")
        if owner is not None:
            (out / name / "owner.json").write_text(json.dumps(owner))
    (out / ".partial-1-x4" / "previous").mkdir()
    (out / ".partial-1-x4" / "previous" / "0").write_text("an earlier report")
    hour_ago = time.time() - 2 * 3600
    os.utime(out / ".partial-abc123", (hour_ago, hour_ago))
    # the next run cleans up before anything else (this one then stops at its missing record)
    assert fj.main(["compare", "--data", str(tmp_path / "missing.csv"), "--out", str(out)]) == 2
    left = sorted(path.name for path in out.iterdir())
    assert left == [".partial-1-x3", ".partial-1-x4", f".partial-{os.getpid()}-x2"], left
    assert ".partial-1-x4" in capsys.readouterr().out  # a warning says where the moved-aside files are


@pytest.mark.slow
def test_a_complete_run_replaces_its_own_files_and_keeps_the_users(tmp_path):
    out = tmp_path / "out"
    before = _previous_run(out)
    assert _compare(out) == 0
    after = _snapshot(out)
    for name in ("report.json", "test_errors.png", "hysteresis_loops.png", "models/stribeck.eqx"):
        assert after[name] != before[name]  # replaced by this run's
    assert after["notes.txt"] == before["notes.txt"] and after["models/gms.eqx"] == before["models/gms.eqx"]
    assert not list(out.glob(".partial-*")) and not (out / ".fricjax-compare.lock").exists()


LOCK = ".fricjax-compare.lock"


def _lock(out: pathlib.Path, pid: int) -> bytes:
    out.mkdir(parents=True, exist_ok=True)
    (out / LOCK).write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "token": "theirs"}))
    return (out / LOCK).read_bytes()


class _StdoutAt:
    """Standard output that calls `action` once, at the run's first line (records loaded, nothing fitted yet)."""

    def __init__(self, stream, action):
        self.stream, self.action = stream, action

    def write(self, text: str) -> int:
        if self.action is not None and "compare:" in text:
            action, self.action = self.action, None
            action()
        return self.stream.write(text)

    def __getattr__(self, name):
        return getattr(self.stream, name)


def test_a_second_run_into_the_folder_of_a_live_run_fails_at_once(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    t = np.arange(500) * 1e-3
    record = tmp_path / "record.csv"
    np.savetxt(record, np.c_[t, 1e-5 * np.sin(20 * t), np.sin(20 * t)], delimiter=",", header="t,x,force", comments="")
    seen = {}

    def second_run():  # while the first run holds --out (its records loaded), a second one into the same folder
        seen["lock"] = json.loads((out / LOCK).read_text())
        started = time.perf_counter()
        seen["code"] = fj.main(["compare", "--data", str(record), "--out", str(out), "--no-progress"])
        seen["seconds"] = time.perf_counter() - started
        seen["err"] = capsys.readouterr().err
        raise fj.compare.CompareError("stopped by the test before the fit")

    monkeypatch.setattr(sys, "stdout", _StdoutAt(sys.stdout, second_run))
    assert fj.main(["compare", "--models", "stribeck", "--data", str(record), "--out", str(out)]) == 2
    assert seen["lock"]["pid"] == os.getpid()
    assert seen["code"] == 2 and seen["seconds"] < 2, seen
    line = _one_line(seen["err"])
    assert f"--out {out}: another fricjax compare (pid {os.getpid()}) is writing there" in line, line
    assert "stopped by the test" in capsys.readouterr().err
    assert not (out / LOCK).exists()  # the first run removed its lock as it ended

    with subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) as other:  # another process's
        try:
            held = _lock(out, other.pid)
            assert fj.main(["compare", "--data", str(record), "--out", str(out)]) == 2
            line = _one_line(capsys.readouterr().err)
            assert f"--out {out}: another fricjax compare (pid {other.pid}) is writing there" in line, line
            assert f"delete {out / LOCK}" in line and (out / LOCK).read_bytes() == held  # left to its owner
        finally:
            other.kill()


def test_the_lock_of_a_killed_run_is_taken_over(tmp_path, capsys):
    out = tmp_path / "out"
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    for pid in (int(gone.stdout), 0, 2**80):  # a process that has ended; damaged files
        _lock(out, pid)
        # taken over: the run goes on to its missing record, and removes its own lock as it ends
        assert fj.main(["compare", "--data", str(tmp_path / "missing.csv"), "--out", str(out)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert "missing.csv" in line and "another fricjax compare" not in line, line
        assert sorted(path.name for path in out.iterdir()) == [], pid


_KILLED_WHILE_PUBLISHING = """
import os, signal, sys
import fricjax
out, kill_at = sys.argv[1], int(sys.argv[2])
replace, moves = os.replace, []
def killing_replace(source, target):
    if ".partial-" not in str(target) or "previous" in str(target):  # a move into --out, or one aside
        moves.append(target)
        if len(moves) == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)
    return replace(source, target)
os.replace = killing_replace
sys.exit(fricjax.main([*sys.argv[3:], "--out", out]))
"""


@pytest.mark.slow  # three runs killed while publishing (a compile each: 15-30 s) and three that roll them back
@pytest.mark.parametrize("kill_at", [2, 4, 7])  # the first file moved aside, not replaced / a model / the report
def test_a_run_killed_while_publishing_is_rolled_back_by_the_next(tmp_path, kill_at, capsys):
    """Before, a SIGKILL in the middle of the final renames left `out` with some new files beside old ones and the
    replaced files in `.partial-*/previous` (kept, with a warning). Now the next run rolls the publishing back from
    the staging folder's journal: `out` is exactly as before the killed run."""
    out = tmp_path / "out"
    before = _previous_run(out)
    killed = subprocess.run(
        [sys.executable, "-c", _KILLED_WHILE_PUBLISHING, str(out), str(kill_at), *RUN],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert killed.returncode == -9, killed.stderr[-2000:]
    visible = {name: data for name, data in _snapshot(out).items() if not name.startswith(".partial-")}
    assert visible != before  # part-way: something was moved
    # the next run (stopping at its missing record) rolls the killed one back before anything else
    assert fj.main(["compare", "--data", str(tmp_path / "missing.csv"), "--out", str(out)]) == 2
    assert _snapshot(out) == before
    assert "was undone" in capsys.readouterr().out
