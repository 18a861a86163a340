"""Where `compare` writes: a check that the output folder takes files (`check_writable`), one run at a time in it
(`lock_output`, within a run decorated with `releasing_output_locks`), a file replaced in one rename
(`write_atomic`), a run's files staged and published as one unit (`Staging`) with the staging folders of killed
runs removed (`remove_stale_staging`), strict JSON with non-finite numbers as `null` (`strict_json`), and the
versions a report records (`versions`)."""

from __future__ import annotations

import contextlib
import contextvars
import errno
import functools
import json
import os
import pathlib
import shutil
import socket
import tempfile
import time
import uuid
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from ..._estimation.loop._interrupts import check_interrupt, hold_signals, on_abandon
from ._settings import CompareError

STAGING_PREFIX = ".partial-"  # the staging folders inside --out
STALE_AFTER = 3600.0  # seconds: a staging folder this old belongs to no live run (a run stages for seconds)
LOCK_NAME = ".fricjax-compare.lock"  # inside --out while a run writes there: its owner (pid, host)
JOURNAL_NAME = "publishing.json"  # in a staging folder while its files move into --out: what to undo if killed
UNFINISHED_LOCK_AFTER = 10.0  # seconds: an empty lock file this old was left by a run killed as it created it


def output_folder(text: str | os.PathLike[str], option: str = "`out`") -> pathlib.Path:
    """The output folder named by `--out`: an empty name is refused (read as a path it would be the working folder)."""
    if not str(os.fspath(text)).strip():
        raise CompareError(f"{option}: an empty name; give a folder (created if missing), or {option} . for this one")
    return pathlib.Path(text)


def earlier_outputs(out: pathlib.Path) -> set[str]:
    """The files in `out` that an earlier fricjax run wrote, as its `report.json` lists them: the report itself, its
    figures and its models' files (`models/NAME.eqx`); nothing where `out` holds no fricjax report. Any other file a
    run would replace is the user's, and is kept (`keep_copies`)."""
    try:
        report = json.loads((out / "report.json").read_text())
    except (OSError, ValueError, RecursionError):
        return set()
    if not isinstance(report, dict) or "fricjax" not in report:
        return set()
    figures = report.get("figures")
    models = report.get("models")
    names = {"report.json"}
    names |= {f for f in figures if isinstance(f, str)} if isinstance(figures, list) else set()
    if isinstance(models, list):
        names |= {f"models/{m['name']}.eqx" for m in models if isinstance(m, dict) and isinstance(m.get("name"), str)}
    return names


def backups(out: pathlib.Path, names: list[str], ours: set[str]) -> list[tuple[str, pathlib.Path]]:
    """For each file of `out` that a run is about to replace and that no earlier fricjax run wrote (not in `ours`),
    the free name to keep it under: `NAME.bak` (`NAME.bak2`, ... where taken)."""
    planned: list[tuple[str, pathlib.Path]] = []
    for name in names:
        target = out / name
        if name in ours or not target.is_file():
            continue
        backup = target.with_name(f"{target.name}.bak")
        number = 1
        while os.path.lexists(backup) or backup in (b for _, b in planned):
            number += 1
            backup = target.with_name(f"{target.name}.bak{number}")
        planned.append((name, backup))
    return planned


def keep_copies(out: pathlib.Path, planned: list[tuple[str, pathlib.Path]]) -> list[pathlib.Path]:
    """Copy the user's files `planned` (`backups`) to their backup names, saying so: nothing of the user's is lost.
    **Returns:** the copies (none when one fails: the error says so)."""
    copies: list[pathlib.Path] = []
    for name, backup in planned:
        try:
            shutil.copy2(out / name, backup)
        except OSError as err:
            for copy in copies:
                copy.unlink(missing_ok=True)
            raise CompareError(
                f"`out` {out}: {name} is not from an earlier run and could not be kept as {backup.name} "
                f"({_reason(err)}); move it away or choose another `out` (nothing was written)"
            ) from None
        print(f"note: --out {out}: your {name} is kept as {backup.relative_to(out)} (this run writes its own {name})")
        copies.append(backup)
    return copies


def check_writable(out: pathlib.Path, files: tuple[str, ...] = ()) -> None:
    """Raise `CompareError` unless `out` (created if missing) takes new files, its `models` entry, if any, is a
    folder, and none of the `files` it is to receive is a folder (said before a fit of minutes, not after it).
    Within a run decorated with `releasing_output_locks`, an `out` it created is removed again at the run's end if
    the run left it empty (interrupted, or stopped by an error: nothing written, not even the folder)."""
    created = not os.path.lexists(out)
    if os.path.lexists(out) and not out.is_dir():
        raise CompareError(f"`out` {out}: a file, not a folder; choose another `out` (a folder, created if missing)")
    try:
        out.mkdir(parents=True, exist_ok=True)
        locks = _LOCKS.get()
        if created and locks is not None:
            locks.callback(_remove_if_empty, out)
            locks.callback(on_abandon(functools.partial(_remove_if_empty, out)))  # also when the process is ended
        handle, probe = tempfile.mkstemp(prefix=".fricjax-write-test-", dir=out)  # a fresh name: nothing overwritten
        os.close(handle)
        os.unlink(probe)
    except OSError as err:
        raise CompareError(f"`out` {out}: not writable ({err.strerror})") from err
    models = out / "models"
    if models.exists() and not models.is_dir():
        raise CompareError(f"`out` {out}: 'models' exists and is not a folder; move it away or choose another `out`")
    for name in files:
        if (out / name).is_dir() and not (out / name).is_symlink():
            raise CompareError(f"`out` {out}: {name} is a folder; move it away or choose another `out`")


def _remove_if_empty(out: pathlib.Path) -> None:
    with contextlib.suppress(OSError):
        out.rmdir()  # fails where the run (or anyone) put something in it


_Run = TypeVar("_Run", bound=Callable[..., Any])
_LOCKS: contextvars.ContextVar[contextlib.ExitStack | None] = contextvars.ContextVar("fricjax_locks", default=None)


def releasing_output_locks(run: _Run) -> _Run:
    """Decorate a run (`run_compare`) so that the `--out` locks it takes (`lock_output`) are released when it
    returns or raises, wherever in its body it took them."""

    @functools.wraps(run)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with contextlib.ExitStack() as locks:
            token = _LOCKS.set(locks)
            try:
                return run(*args, **kwargs)
            finally:
                _LOCKS.reset(token)

    return wrapper  # type: ignore[return-value]


def lock_output(out: pathlib.Path) -> None:
    """Make this run the only one writing to `out` until the decorated run (`releasing_output_locks`) ends: a
    second `fricjax compare` into the same folder fails at once with a one-line `CompareError` naming the folder
    and the run that holds it, before its fit (two runs publishing together would mix their files, and one's undo
    could move the other's). The lock is the file `out/.fricjax-compare.lock`, created with `O_EXCL` and holding
    its owner's process id and host; it is removed when the run ends. One left by a killed run (its process is
    gone) is taken over."""
    locks = _LOCKS.get()
    if locks is None:
        raise RuntimeError("lock_output: call it within a run decorated with releasing_output_locks")
    locks.enter_context(_OutputLock(out))


class _OutputLock:
    """The lock file of `out` (`lock_output`), as a context manager."""

    def __init__(self, out: pathlib.Path):
        self.out, self.path = out, out / LOCK_NAME
        self.text = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "token": uuid.uuid4().hex})
        self.forget: Callable[[], None] = lambda: None  # unregisters the clean-up `abandonable` would run

    def __enter__(self) -> _OutputLock:
        for _ in range(5):  # each turn: create it, or take over a dead run's (another run may be doing the same)
            try:
                handle = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            except FileExistsError:
                pass
            except OSError as err:
                raise CompareError(f"`out` {self.out}: could not create {LOCK_NAME} ({_reason(err)})") from None
            else:
                with os.fdopen(handle, "w") as stream:
                    stream.write(self.text)
                self.forget = on_abandon(self._release)  # removed also when `abandonable` ends the process
                return self
            try:
                seen = self.path.read_bytes()
                age = time.time() - self.path.stat().st_mtime
            except FileNotFoundError:
                continue  # its run just ended
            except OSError as err:
                raise CompareError(f"`out` {self.out}: could not read {LOCK_NAME} ({_reason(err)})") from None
            owner = _lock_owner(seen)
            if owner is None and age < UNFINISHED_LOCK_AFTER:
                owner = {"pid": "?", "host": socket.gethostname()}  # being written by a run starting now
            if owner is not None and _alive(owner["pid"], owner["host"]) is not False:
                where = "" if owner["host"] == socket.gethostname() else f" on {owner['host']}"
                raise CompareError(
                    f"`out` {self.out}: another fricjax compare (pid {owner['pid']}{where}) is writing there; wait "
                    f"for it to end or choose another `out` (if no such run is going on, delete {self.path})"
                )
            _take_over(self.path, seen)
        raise CompareError(f"`out` {self.out}: other runs keep taking {LOCK_NAME}; run again")

    def __exit__(self, *exc: Any) -> None:
        self._release()
        self.forget()

    def _release(self) -> None:
        try:
            if self.path.read_text() == self.text:  # ours still (not one a user deleted and another run made)
                self.path.unlink()
        except OSError:
            pass


def _lock_owner(text: bytes) -> dict[str, Any] | None:
    """The `pid` and `host` a lock file records, or None where it records none (being written, or damaged)."""
    try:
        owner = json.loads(text)
        return {"pid": int(owner["pid"]), "host": str(owner["host"])}
    except (ValueError, KeyError, TypeError):
        return None


def _take_over(path: pathlib.Path, seen: bytes) -> None:
    """Remove the lock file `path` of a run that has ended, if it still holds `seen`. It is first renamed aside
    (one atomic step, which one run only can do), then compared: when another run has replaced it meanwhile with
    a lock of its own, that one is linked back (`os.link` fails rather than overwrite a third run's)."""
    aside = path.with_name(f"{LOCK_NAME}.{uuid.uuid4().hex[:12]}.stale")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return
    except OSError as err:
        raise CompareError(f"`out` {path.parent}: could not remove the stale {LOCK_NAME} ({_reason(err)})") from None
    try:
        if aside.read_bytes() != seen:
            os.link(aside, path)
    except OSError:
        pass
    finally:
        aside.unlink(missing_ok=True)


def _alive(pid: int | str, host: str) -> bool | None:
    """Whether process `pid` runs: True or False on this host, None where that cannot be told (another host)."""
    if host != socket.gethostname() or not isinstance(pid, int):
        return None
    if pid == os.getpid():
        return True
    if not 0 < pid < 2**31:
        return False  # no process has it (a damaged file)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # it exists (another user's process)
    return True


def write_atomic(path: pathlib.Path, text: str) -> None:
    """Write `text` to a temporary file beside `path`, then rename it over `path`. The file gets the mode of any
    new file (0o666 less the umask, as the other outputs), not `tempfile.mkstemp`'s 0o600. Under `fricjax compare`
    a SIGINT / SIGTERM received so far stops it before anything is written (`Interrupted`)."""
    check_interrupt()
    temporary = path.with_name(f".fj-{uuid.uuid4().hex[:12]}.tmp")  # short: a long `path.name` stays legal
    handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(handle, "w") as stream:
            stream.write(text)
        os.replace(temporary, path)
    except BaseException:
        pathlib.Path(temporary).unlink(missing_ok=True)
        raise


class Staging:
    """A run's files, written into a hidden folder inside `out` (`write`), then moved into `out` as one unit
    (`publish`): with `with Staging(out) as staging:` the folder is removed on the way out, whatever happens.

    The folder (`.partial-<pid>-*`) records its owner (process id and host, for `remove_stale_staging`); the files
    are written under its `new/`, and the files of `out` they replace are moved under its `previous/` while
    publishing, so that a failure part-way moves everything back. Files in `out` that the run does not write are
    never touched (`out` may be a folder of the user's: only file-by-file renames are safe there, not a swap of
    whole folders)."""

    def __init__(self, out: pathlib.Path):
        self.out = out
        self.root = pathlib.Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-", dir=out))
        self.new, self.previous = self.root / "new", self.root / "previous"
        try:
            (self.root / "owner.json").write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}))
            self.new.mkdir()
        except OSError as err:
            shutil.rmtree(self.root, ignore_errors=True)
            raise CompareError(f"`out` {out}: could not start writing ({_reason(err)}); nothing was written") from None
        self.names: list[str] = []  # the staged files, relative to `out`, in the order they are published
        self.keep = False  # a rollback failed: `previous/` holds files of `out` (said in the error)

    def __enter__(self) -> Staging:
        return self

    def __exit__(self, *exc: Any) -> None:
        if not self.keep:
            shutil.rmtree(self.root, ignore_errors=True)

    def write(self, name: str, write: Callable[[pathlib.Path], Any]) -> None:
        """Stage `out/name` (a relative path): `write(path)` writes it to its place in the staging folder. A
        SIGINT / SIGTERM received so far stops the run here (`Interrupted`); a failed write (a full disk) is a
        one-line `CompareError` naming the file."""
        check_interrupt()
        path = self.new / name
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write(path)
        except (OSError, ValueError) as err:
            cause = err if isinstance(err, OSError) else err.__cause__  # save_model: a ValueError from an OSError
            if not isinstance(cause, OSError):
                raise
            reason = _reason(cause)
            raise CompareError(f"`out` {self.out}: could not write {name} ({reason}); nothing was written") from None
        self.names.append(name)

    def publish(self) -> None:
        """Move the staged files into `out`, in the order they were written (the report last), as one unit: each
        file of `out` that a staged one replaces is first moved aside into the staging folder, and when any move
        fails every move is undone, so that `out` is left as it was. A SIGINT / SIGTERM received so far stops the
        run before the first move; once the moves begin, signals wait until they end (even a second one)."""
        check_interrupt()
        for name in self.names:  # refuse what is bound to fail before anything moves
            for folder in self._folders(name):
                if os.path.lexists(folder) and not folder.is_dir():
                    raise CompareError(
                        f"`out` {self.out}: {folder.name} is not a folder, but {name} must go in it; move it away "
                        "or choose another `out` (nothing was written)"
                    )
            if (self.out / name).is_dir() and not (self.out / name).is_symlink():
                raise CompareError(
                    f"`out` {self.out}: {name} is a folder; move it away or choose another `out` (nothing was written)"
                )
        planned = backups(self.out, self.names, earlier_outputs(self.out))
        moves: list[tuple[pathlib.Path, pathlib.Path]] = []  # the renames done, to undo in reverse
        created: list[pathlib.Path] = []  # the folders made in `out`, to remove again
        current = ""
        self._write_journal(planned)
        copies = keep_copies(self.out, planned)  # after the journal: a run killed from here on is undone, copies too
        with hold_signals():
            try:
                for index, current in enumerate(self.names):
                    for folder in self._folders(current):
                        if not folder.exists():
                            folder.mkdir()
                            created.append(folder)
                    target = self.out / current
                    if os.path.lexists(target):
                        self.previous.mkdir(exist_ok=True)
                        os.replace(target, self.previous / str(index))
                        moves.append((target, self.previous / str(index)))
                    os.replace(self.new / current, target)
                    moves.append((self.new / current, target))
                (self.root / JOURNAL_NAME).unlink()  # published: nothing for a later run to roll back
            except BaseException as err:
                failed = _undo(moves, created)
                for copy in copies if not failed else ():  # the user's files are back in place
                    copy.unlink(missing_ok=True)
                self.keep = bool(failed)
                if failed:
                    raise CompareError(
                        f"`out` {self.out}: could not move {current} into place ({err}), nor put back {failed[0]}; "
                        f"the previous files are in {self.previous}: move them back by hand"
                    ) from None
                if not isinstance(err, OSError):
                    raise
                raise CompareError(
                    f"`out` {self.out}: could not move {current} into place ({_reason(err)}); nothing was changed "
                    "(the previous files are back)"
                ) from None

    def _write_journal(self, planned: list[tuple[str, pathlib.Path]]) -> None:
        """Record, before the first move, what publishing will do (`JOURNAL_NAME`: the names in order, each staged
        file's identity, the folders of `out` it creates, the backups of the user's files it makes, `planned`), so
        that a run killed part-way (SIGKILL, a power cut) can be rolled back by the next one
        (`remove_stale_staging`)."""
        staged = {}
        for name in self.names:
            info = (self.new / name).stat()
            staged[name] = [info.st_ino, info.st_size, info.st_mtime_ns]
        folders = {str(f.relative_to(self.out)) for name in self.names for f in self._folders(name) if not f.exists()}
        journal = {
            "names": self.names,
            "staged": staged,
            "created": sorted(folders, key=len),
            "copies": [str(backup.relative_to(self.out)) for _, backup in planned],
        }
        try:
            (self.root / JOURNAL_NAME).write_text(json.dumps(journal))
        except OSError as err:
            raise CompareError(
                f"`out` {self.out}: could not start publishing ({_reason(err)}); nothing was written"
            ) from None

    def _folders(self, name: str) -> list[pathlib.Path]:
        """The folders in `out` that `out/name` goes in (`models`), outermost first."""
        return [self.out / parent for parent in reversed(pathlib.PurePath(name).parents) if parent.parts]


def _undo(moves: list[tuple[pathlib.Path, pathlib.Path]], created: list[pathlib.Path]) -> list[pathlib.Path]:
    """Undo `moves` (renames) and remove the `created` folders, last first; returns the paths it could not restore."""
    failed = []
    for source, target in reversed(moves):
        try:
            os.replace(target, source)
        except OSError:
            failed.append(source)
    for folder in reversed(created):
        try:
            folder.rmdir()
        except OSError:
            pass
    return failed


def _reason(err: OSError) -> str:
    """Why a write or a rename failed, with what to do about it, in a few words."""
    text = err.strerror or str(err)
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"{text}: free some space or choose another `out`"
    if err.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"{text}: check the folder's permissions or choose another `out`"
    if err.errno in (errno.EBUSY, errno.ETXTBSY):
        return f"{text}: close the program that holds it and run again"
    if err.errno == errno.EXDEV:
        return f"{text}: 'models' is on another file system than `out`; choose another `out`"
    return f"{text}: check `out` and run again"


def remove_stale_staging(out: pathlib.Path, *, now: float | None = None) -> None:
    """Remove the staging folders that runs left in `out` when they were killed: those of a process that no longer
    runs on this host, and any older than `STALE_AFTER`. A run killed in the middle of its renames is rolled back
    first, from its journal (`_roll_back`: the earlier files back in `out`, its own removed); a folder that still
    holds files moved aside (no journal, or the undo failed) is kept, with a warning: those files were the user's."""
    now = time.time() if now is None else now
    for folder in sorted(out.glob(STAGING_PREFIX + "*")):
        try:
            if not folder.is_dir() or folder.is_symlink() or not _stale(folder, now):
                continue
            if (folder / JOURNAL_NAME).exists() and not _roll_back(folder, out):
                continue
            previous = folder / "previous"
            if previous.is_dir() and any(previous.iterdir()):
                print(
                    f"warning: {folder} holds files that a killed run had moved aside from {out}; move back the "
                    "ones you need, then delete the folder"
                )
                continue
            shutil.rmtree(folder)
        except OSError:
            continue  # someone else's, or going away: not ours to insist on


def _roll_back(folder: pathlib.Path, out: pathlib.Path) -> bool:
    """Undo the publishing of a run that was killed in the middle of it (its staging `folder` still holds the
    journal): the files it had moved aside go back into `out`, the files it had moved in (recognised by their
    identity, so that nothing written since is touched) and the folders it created are removed. Says what it did;
    returns whether everything is back (else the folder is kept, with a warning naming it)."""
    try:
        journal = json.loads((folder / JOURNAL_NAME).read_text())
        names, staged, created = list(journal["names"]), dict(journal["staged"]), list(journal["created"])
    except (OSError, ValueError, KeyError, TypeError):
        print(f"warning: {folder} holds an unreadable record of a killed run's files; check {out}, then delete it")
        return False
    # the renames the killed run did, in its order (a file of `out` moved aside, then the staged one moved in), for
    # `_undo` as if the run itself had failed there; a moved-in file is recognised by its identity, so that nothing
    # written into `out` since is taken for it
    moves: list[tuple[pathlib.Path, pathlib.Path]] = []
    for index, name in enumerate(names):
        target, aside, staged_path = out / name, folder / "previous" / str(index), folder / "new" / name
        if os.path.lexists(aside):
            moves.append((target, aside))
        if not os.path.lexists(staged_path) and os.path.lexists(target):
            info = target.lstat()
            if [info.st_ino, info.st_size, info.st_mtime_ns] == staged.get(name):
                moves.append((staged_path, target))
    failed = _undo(moves, [out / relative for relative in created])
    if failed:
        print(
            f"warning: could not undo the files a killed run was publishing into {out} (not restored: "
            f"{failed[0]}); the files it had moved aside are in {folder / 'previous'}: move back the ones you need, "
            f"then delete {folder}"
        )
        return False
    for copy in journal.get("copies", []) if isinstance(journal.get("copies"), list) else []:
        if isinstance(copy, str) and copy.endswith(tuple(f".bak{n}" for n in ("", *range(2, 100)))):
            (out / copy).unlink(missing_ok=True)  # the user's file is back in place: its copy goes
    (folder / JOURNAL_NAME).unlink(missing_ok=True)
    if moves:
        print(f"note: a run killed while publishing into {out} was undone: {len(moves)} renames reversed")
    return True


def _stale(folder: pathlib.Path, now: float) -> bool:
    if now - folder.stat().st_mtime > STALE_AFTER:
        return True
    try:
        owner = json.loads((folder / "owner.json").read_text())
        pid, host = int(owner["pid"]), str(owner["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return False  # being created, or written by an older fricjax: the age decides
    return _alive(pid, host) is False


def strict_json(report: Any) -> str:
    """The report as strict JSON: non-finite numbers become `null` (with a warning naming where), never
    `NaN` / `Infinity`, which strict parsers reject."""
    bad: list[str] = []

    def clean(value: Any, where: str) -> Any:
        value = _jsonable(value) if isinstance(value, np.generic) or hasattr(value, "tolist") else value
        if isinstance(value, float) and not np.isfinite(value):
            bad.append(where)
            return None
        if isinstance(value, dict):
            return {key: clean(item, f"{where}.{key}") for key, item in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(item, f"{where}[{i}]") for i, item in enumerate(value)]
        if value is None or isinstance(value, (bool, int, float, str)):
            return value
        return str(value)

    text = json.dumps(clean(report, "report"), indent=2, allow_nan=False)
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        warnings.warn(f"report.json: non-finite values written as null at {shown}", RuntimeWarning, stacklevel=2)
        print(f"warning: non-finite scores or parameters (written as null in report.json): {shown}")
    return text


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def versions() -> dict[str, str]:
    """The versions of Python and of the libraries behind the numbers of a report."""
    import platform

    import equinox
    import jax
    import optax
    import optimistix

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "equinox": equinox.__version__,
        "optax": optax.__version__,
        "optimistix": optimistix.__version__,
        "numpy": np.__version__,
    }
