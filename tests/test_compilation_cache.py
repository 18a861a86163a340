"""The compilation cache holds native code that JAX runs: fricjax uses a folder only when it is private to the user
(issue 52, "Security"), creates its folders 0700, and repairs entries it cannot read with one line."""

import os
import pathlib
import stat
import subprocess
import sys

import pytest

import fricjax as fj

ROOT = pathlib.Path(__file__).resolve().parents[1]
POSIX = hasattr(os, "getuid")
IS_ROOT = POSIX and os.getuid() == 0
OTHER_UID = 65534  # nobody


def _run(code: str, env_extra: dict[str, str], cwd: pathlib.Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("FRICJAX_NO_CACHE", "FRICJAX_CACHE_DIR", "XDG_CACHE_HOME")}
    env.update(env_extra)
    return subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True, timeout=120, check=False
    )


def _refused(path, capsys) -> str:
    """The one line `fj.enable_compilation_cache(path)` prints where it refuses `path` (it returns None and leaves
    JAX's configuration alone, so the test process's own cache setting is untouched)."""
    assert fj.enable_compilation_cache(path) is None
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fricjax: compilation cache off: "), lines
    return lines[0]


ENABLE_AND_JIT = """
import jax, fricjax as fj
folder = fj.enable_compilation_cache()
print("FOLDER", folder)
print("RESULT", int(jax.jit(lambda x: x + 1)(1)))
"""


@pytest.mark.slow
def test_missing_folders_are_created_private(tmp_path):
    folder = tmp_path / "a" / "b" / "jax"
    proc = _run(ENABLE_AND_JIT, {"FRICJAX_CACHE_DIR": str(folder)}, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert f"FOLDER {folder}" in proc.stdout and "RESULT 2" in proc.stdout
    for made in (folder, folder.parent, folder.parent.parent):
        assert stat.S_IMODE(made.stat().st_mode) & 0o077 == 0, (made, oct(made.stat().st_mode))
    assert list(folder.glob("*-cache")), "the program was not stored"


@pytest.mark.skipif(not POSIX, reason="POSIX owners and modes")
def test_a_world_writable_folder_turns_the_cache_off_with_one_line(tmp_path, capsys):
    folder = tmp_path / "shared-cache"
    folder.mkdir()
    folder.chmod(0o777)
    line = _refused(folder, capsys)
    assert "can be written by other users" in line and "chmod 700" in line and "holds code that JAX runs" in line
    assert not list(folder.iterdir()), "nothing may be read from or written to a folder others can write"


@pytest.mark.slow
@pytest.mark.skipif(not POSIX, reason="POSIX owners and modes")
def test_a_planted_program_in_a_shared_folder_is_never_run(tmp_path):
    """The attack of issue 52: a program compiled from other code, stored under the key of `x + 1`."""
    folder = tmp_path / "planted"
    planting = _run(
        "import jax, fricjax as fj\nfj.enable_compilation_cache()\nprint(int(jax.jit(lambda x: x + 1)(1)))",
        {"FRICJAX_CACHE_DIR": str(folder)},
        tmp_path,
    )
    assert planting.returncode == 0, planting.stderr
    (entry,) = folder.glob("*-cache")
    other = tmp_path / "other"
    assert (
        _run(
            "import jax, fricjax as fj\nfj.enable_compilation_cache()\nprint(int(jax.jit(lambda x: x + 100)(1)))",
            {"FRICJAX_CACHE_DIR": str(other)},
            tmp_path,
        ).returncode
        == 0
    )
    (evil,) = other.glob("*-cache")
    entry.write_bytes(evil.read_bytes())  # the key of x + 1 now holds x + 100
    folder.chmod(0o777)
    proc = _run(ENABLE_AND_JIT, {"FRICJAX_CACHE_DIR": str(folder)}, tmp_path)
    assert "RESULT 2" in proc.stdout, (proc.stdout, proc.stderr)


@pytest.mark.skipif(not IS_ROOT, reason="needs root to give a folder to another user")
def test_a_folder_of_another_user_and_a_link_to_it_are_refused(tmp_path, capsys):
    folder = tmp_path / "theirs"
    folder.mkdir(mode=0o700)
    os.chown(folder, OTHER_UID, OTHER_UID)
    link = tmp_path / "link"
    link.symlink_to(folder)
    assert f"belongs to user {OTHER_UID}" in _refused(folder, capsys)
    assert "a link to" in _refused(link, capsys)


@pytest.mark.skipif(not POSIX, reason="POSIX owners and modes")
def test_a_link_to_a_writable_folder_and_a_writable_parent_are_refused(tmp_path, capsys):
    open_folder = tmp_path / "open"
    open_folder.mkdir()
    open_folder.chmod(0o777)
    link = tmp_path / "to-open"
    link.symlink_to(open_folder)
    assert "can be written by other users" in _refused(link, capsys)
    parent = tmp_path / "parent"
    parent.mkdir()
    (parent / "jax").mkdir(mode=0o700)
    parent.chmod(0o777)  # not sticky: another user could rename jax/ and put their own in its place
    assert "its parent" in _refused(parent / "jax", capsys)
    assert not os.listdir(parent / "jax")


def test_a_relative_folder_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert "relative path" in _refused("relative/jax", capsys)
    assert not (tmp_path / "relative").exists()


DEFAULT_FOLDER = """
import fricjax as fj
print("FOLDER", fj.enable_compilation_cache())
"""


@pytest.mark.slow
def test_a_relative_xdg_cache_home_is_ignored_and_a_sticky_parent_is_private(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    env = {"HOME": str(home), "XDG_CACHE_HOME": "relative-cache"}
    proc = _run(DEFAULT_FOLDER, env, tmp_path)
    assert f"FOLDER {home / '.cache' / 'fricjax' / 'jax'}" in proc.stdout, proc.stderr
    assert not (tmp_path / "relative-cache").exists()
    assert stat.S_IMODE((home / ".cache").stat().st_mode) & 0o077 == 0
    sticky = tmp_path / "sticky"
    sticky.mkdir()
    sticky.chmod(0o1777)  # as /tmp: others may not rename what is not theirs
    proc = _run(DEFAULT_FOLDER, {"XDG_CACHE_HOME": str(sticky)}, tmp_path)
    assert f"FOLDER {sticky / 'fricjax' / 'jax'}" in proc.stdout, proc.stderr


@pytest.mark.slow
def test_unreadable_entries_are_removed_once_with_one_line(tmp_path):
    folder = tmp_path / "jax"
    env = {"FRICJAX_CACHE_DIR": str(folder)}
    assert _run(ENABLE_AND_JIT, env, tmp_path).returncode == 0
    entries = list(folder.glob("*-cache"))
    assert entries
    for entry in entries:
        entry.write_bytes(b"not a compressed program")
    proc = _run(ENABLE_AND_JIT, env, tmp_path)
    assert proc.returncode == 0 and "RESULT 2" in proc.stdout, proc.stderr
    assert proc.stderr.count("\n") == 1 and "removed" in proc.stderr, proc.stderr
    again = _run(ENABLE_AND_JIT, env, tmp_path)
    assert again.returncode == 0 and again.stderr == "", again.stderr
