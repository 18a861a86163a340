"""JAX's persistent compilation cache for fricjax: compiled programs kept on disk, so that a second run of the
command line (or a new notebook kernel) loads them instead of compiling again.

`fricjax compare` and `fricjax demo` turn it on by default, in `default_cache_dir()` (`$FRICJAX_CACHE_DIR`, else
`$XDG_CACHE_HOME/fricjax/jax`, else `~/.cache/fricjax/jax`); `--no-cache` or `FRICJAX_NO_CACHE=1` turn it off. In a
notebook, one line: `fj.enable_compilation_cache()`. Every program is stored, however fast it compiles
(`MIN_COMPILE_SECONDS`): a default `fricjax compare` compiles about 300, 270 of them in under 0.2 s each, 8 s in
all; read back from the cache they cost a fraction of that (second run 16 s against 24 s with a 0.2 s threshold, the
first 37-44 s; 3.5 MB on disk; benchmarks/README.md). The cache is JAX's own
(`jax_compilation_cache_dir`), keyed by the program, the JAX version, the backend and the XLA flags; delete the
folder to clear it.

**The folder holds executable code**: JAX loads a program from it and runs it in place of the one it would compile.
So, as pip does with its own cache, fricjax creates the folders it needs with mode 0700 and uses a folder only when
it is private: a real folder (symbolic links followed) owned by the user and writable by no one else, in parents that
no other user can rename or replace. Otherwise the cache stays off and one line says why (`private_folder_problem`).
Entries that cannot be read back (a crash while writing, a full disk) are removed when the cache is turned on, with
one line, instead of a warning per program on every run.
"""

from __future__ import annotations

import os
import pathlib
import stat
import sys

MIN_COMPILE_SECONDS = 0.0  # JAX's default is 1 s: most of fricjax's programs compile faster
_ENTRY_SUFFIX = "-cache"  # JAX's LRU file cache: one `<key>-cache` file a program (`jax._src.lru_cache`)


def default_cache_dir() -> pathlib.Path:
    """Where fricjax keeps compiled programs: `$FRICJAX_CACHE_DIR`, else `$XDG_CACHE_HOME/fricjax/jax` (an absolute
    path only, as the XDG specification says: a relative one is ignored), else `~/.cache/fricjax/jax`."""
    if os.environ.get("FRICJAX_CACHE_DIR"):
        return pathlib.Path(os.environ["FRICJAX_CACHE_DIR"]).expanduser()
    xdg = pathlib.Path(os.environ.get("XDG_CACHE_HOME") or "").expanduser()
    base = xdg if xdg.is_absolute() else pathlib.Path.home() / ".cache"
    return base / "fricjax" / "jax"


def cache_disabled() -> bool:
    """Whether the user turned the command line's cache off (`FRICJAX_NO_CACHE` set to a non-empty value)."""
    return bool(os.environ.get("FRICJAX_NO_CACHE"))


def enable_compilation_cache(path: str | os.PathLike[str] | None = None) -> pathlib.Path | None:
    """Keep JAX's compiled programs in `path` (default: `default_cache_dir()`), for this process and the next ones.

    The folder holds native code that JAX runs, so it must be private: missing folders are created with mode 0700, and
    a folder that another user owns or can write (itself, through a symbolic link, or through a parent) leaves the cache
    off, with one line on standard error naming the folder and the fix.

    **Returns:** the folder, or None when it cannot be created or is not private (the cache then stays off; nothing
    else changes).

    ```python
    >>> import fricjax as fj
    >>> folder = fj.enable_compilation_cache()  # doctest: +SKIP
    ```
    """
    import jax

    try:
        folder = default_cache_dir() if path is None else pathlib.Path(path).expanduser()
    except RuntimeError as err:  # no home folder to put the default under
        _off(f"no folder for it ({err}); set FRICJAX_CACHE_DIR to a private folder")
        return None
    if not folder.is_absolute():
        _off(f"{str(folder)!r} is a relative path (it would follow the working folder); give an absolute one")
        return None
    try:
        _make_private_folders(folder)
        problem = private_folder_problem(folder)
    except OSError as err:
        _off(f"{folder} cannot be used ({err.strerror or err})")
        return None
    if problem:
        _off(problem)
        return None
    removed = remove_unreadable_entries(folder)
    if removed:
        print(
            f"fricjax: removed {removed} unreadable compiled program{'s' * (removed > 1)} from the compilation cache "
            f"({folder}); they are compiled again",
            file=sys.stderr,
        )
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder


def _off(reason: str) -> None:
    """Say in one line why the cache stays off."""
    print(f"fricjax: compilation cache off: {reason}", file=sys.stderr)


def _make_private_folders(folder: pathlib.Path) -> None:
    """Create `folder` and its missing parents with mode 0700 (only the user may list, read or write them)."""
    missing = []
    for candidate in (folder, *folder.parents):
        if os.path.lexists(candidate):
            break
        missing.append(candidate)
    for candidate in reversed(missing):
        try:
            candidate.mkdir(mode=0o700)
        except FileExistsError:  # made meanwhile by another process: checked below like any existing folder
            pass


def private_folder_problem(folder: pathlib.Path) -> str | None:
    """Why `folder` is not private to this user (a sentence naming it and the fix), or None when it is.

    Private: its real path is a folder that the user owns and no group or other user can write; each symbolic link on
    the way is the user's or root's; each parent of the real folder is the user's or root's and either writable by no
    one else or sticky (as /tmp, where others cannot rename what is not theirs). Without POSIX owners (Windows) only
    the folder's existence is checked."""
    real = pathlib.Path(os.path.realpath(folder))
    info = os.stat(real)
    if not stat.S_ISDIR(info.st_mode):
        return f"{folder} is not a folder"
    if not hasattr(os, "getuid"):
        return None
    me = os.getuid()
    named = f"{folder}" + (f" (a link to {real})" if real != folder else "")
    if info.st_uid != me:
        return f"{named} belongs to user {info.st_uid}, not to you; use a folder of your own (FRICJAX_CACHE_DIR)"
    if info.st_mode & 0o022:
        return (
            f"{named} can be written by other users (mode {stat.S_IMODE(info.st_mode):o}) and holds code that JAX "
            f"runs; make it private (chmod 700 {real}) or use another folder (FRICJAX_CACHE_DIR)"
        )
    if not os.access(real, os.W_OK | os.X_OK):
        return f"{named} cannot be written by you; make it writable or use another folder (FRICJAX_CACHE_DIR)"
    for link in (p for p in (folder, *folder.parents) if p.is_symlink()):
        owner = os.lstat(link).st_uid
        if owner not in (me, 0):
            return f"{named}: the link {link} belongs to user {owner}, who can point it elsewhere; use another folder"
    for parent in real.parents:
        parent_info = os.stat(parent)
        if parent_info.st_uid not in (me, 0):
            return f"{named}: its parent {parent} belongs to user {parent_info.st_uid}; use a folder of your own"
        if parent_info.st_mode & 0o022 and not parent_info.st_mode & stat.S_ISVTX:
            return (
                f"{named}: its parent {parent} can be written by other users (mode "
                f"{stat.S_IMODE(parent_info.st_mode):o}), who could replace the folder; use another folder"
            )
    return None


def remove_unreadable_entries(folder: pathlib.Path) -> int:
    """Delete the cache entries in `folder` whose compressed program cannot be decompressed (truncated or overwritten
    files), so that JAX compiles and stores them again instead of warning on every run. **Returns:** how many."""
    try:
        from jax._src.compilation_cache import decompress_executable
    except ImportError:  # another JAX layout: leave the folder to JAX
        return 0
    removed = 0
    for entry in folder.glob(f"*{_ENTRY_SUFFIX}"):
        try:
            decompress_executable(entry.read_bytes())
        except OSError:
            continue
        except Exception:  # the decompressor's own error types differ between zstd, zstandard and zlib
            try:
                entry.unlink()
                removed += 1
            except OSError:
                pass
    return removed
