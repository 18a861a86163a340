"""The compilation cache holds native code that JAX runs: fricjax uses a folder only when it is private to the user
(issue 52, "Security"), creates its folders 0700, and repairs entries it cannot read with one line."""

import os
import pathlib
import stat
import subprocess
import sys

import pytest

from fricjax import _compilation_cache as cache

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
def test_a_world_writable_folder_turns_the_cache_off_with_one_line(tmp_path):
    folder = tmp_path / "shared-cache"
    folder.mkdir()
    folder.chmod(0o777)
    proc = _run(ENABLE_AND_JIT, {"FRICJAX_CACHE_DIR": str(folder)}, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "FOLDER None" in proc.stdout and "RESULT 2" in proc.stdout
    lines = [line for line in proc.stderr.splitlines() if "compilation cache" in line]
    assert len(lines) == 1 and "can be written by other users" in lines[0] and "chmod 700" in lines[0], proc.stderr
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
def test_a_folder_of_another_user_and_a_link_to_it_are_refused(tmp_path):
    folder = tmp_path / "theirs"
    folder.mkdir(mode=0o700)
    os.chown(folder, OTHER_UID, OTHER_UID)
    link = tmp_path / "link"
    link.symlink_to(folder)
    for given in (folder, link):
        problem = cache.private_folder_problem(given)
        assert problem is not None and f"belongs to user {OTHER_UID}" in problem, problem
    assert "a link to" in (cache.private_folder_problem(link) or "")


@pytest.mark.skipif(not POSIX, reason="POSIX owners and modes")
def test_a_link_to_a_writable_folder_and_a_writable_parent_are_refused(tmp_path):
    open_folder = tmp_path / "open"
    open_folder.mkdir()
    open_folder.chmod(0o777)
    link = tmp_path / "to-open"
    link.symlink_to(open_folder)
    assert "can be written by other users" in (cache.private_folder_problem(link) or "")
    parent = tmp_path / "parent"
    parent.mkdir()
    (parent / "jax").mkdir(mode=0o700)
    parent.chmod(0o777)  # not sticky: another user could rename jax/ and put their own in its place
    assert "its parent" in (cache.private_folder_problem(parent / "jax") or "")
    parent.chmod(0o1777)  # sticky, as /tmp: they cannot
    assert cache.private_folder_problem(parent / "jax") is None


def test_relative_paths_never_put_the_cache_in_the_working_folder(tmp_path, monkeypatch):
    monkeypatch.delenv("FRICJAX_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", "relative-cache")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache.default_cache_dir() == tmp_path / "home" / ".cache" / "fricjax" / "jax"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.default_cache_dir() == tmp_path / "xdg" / "fricjax" / "jax"
    monkeypatch.chdir(tmp_path)
    assert cache.enable_compilation_cache("relative/jax") is None
    assert not (tmp_path / "relative").exists()


def test_created_folders_are_private_and_pass_the_check(tmp_path):
    folder = tmp_path / "a" / "b" / "jax"
    cache._make_private_folders(folder)
    for made in (folder, folder.parent, folder.parent.parent):
        assert stat.S_IMODE(made.stat().st_mode) & 0o077 == 0, (made, oct(made.stat().st_mode))
    assert cache.private_folder_problem(folder) is None


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
