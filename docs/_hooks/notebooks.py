"""Execute the notebooks for the documentation site (nbclient), caching each executed copy by its inputs.

The build runs every `notebooks/*.ipynb` in a fresh kernel, in the smoke size (`FRICJAX_SMOKE=1`) unless the
environment sets `FRICJAX_SMOKE` itself, with matplotlib's inline backend so that `plt.show()` leaves its figure
in the notebook. A cell that raises fails the build (`nbclient.exceptions.CellExecutionError`). An executed copy
is kept in `build/docs-notebooks/` under a key of the notebook, the fricjax sources and the settings, so a second
build with nothing changed executes nothing.

Run alone: `python docs/_hooks/notebooks.py` executes (or reuses) every notebook and prints the times.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import shutil
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
NOTEBOOKS = ROOT / "notebooks"
CACHE = ROOT / "build" / "docs-notebooks"
TIMEOUT = 1200  # seconds per cell


def kernel_environment() -> dict[str, str]:
    """The environment of the notebooks' kernels: smoke size, the shared data, the inline figure backend."""
    env = dict(os.environ)
    env.setdefault("FRICJAX_SMOKE", "1")
    env.setdefault("FRICJAX_DATA", str(ROOT.parent / "shared" / "data"))
    env["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"  # CI sets Agg, which would drop the figures
    return env


def _key(path: pathlib.Path, env: dict[str, str]) -> str:
    digest = hashlib.sha256(path.read_bytes())
    for source in sorted((ROOT / "src" / "fricjax").rglob("*.py")):
        digest.update(source.relative_to(ROOT).as_posix().encode())
        digest.update(source.read_bytes())
    digest.update(f"smoke={env['FRICJAX_SMOKE']} data={env['FRICJAX_DATA']}".encode())
    return digest.hexdigest()[:16]


# what a notebook that reads the data folder calls (its page is a note when the folder is absent)
_READS_DATA = ("data_folder(", "load_emps", "load_boucwen", "load_damper", "FRICJAX_DATA")


def needs_data(path: pathlib.Path) -> bool:
    """Whether the notebook reads fricjax's data folder (the real records: EMPS, Bouc-Wen, the damper)."""
    text = path.read_text()
    return any(call in text for call in _READS_DATA)


def missing_data(path: pathlib.Path) -> str | None:
    """Why the notebook at `path` cannot run here (it reads the data folder and there is none), or None."""
    data = pathlib.Path(kernel_environment()["FRICJAX_DATA"])
    if needs_data(path) and not data.is_dir():
        return (
            f"this notebook reads the real records of fricjax's data folder, and the site was built without it "
            f"(FRICJAX_DATA={data} is no folder): set FRICJAX_DATA to the `shared/data` folder and build again"
        )
    return None


def execute(path: pathlib.Path, log=print) -> pathlib.Path | str:
    """The executed copy of the notebook at `path` (executed now, or reused from the cache), or the reason it cannot
    run here (a notebook that reads the data folder, on a machine without it: its page says so)."""
    import nbclient
    import nbformat

    env = kernel_environment()
    target = CACHE / f"{path.stem}-{_key(path, env)}.ipynb"
    if target.exists():
        log(f"notebook {path.name}: executed copy reused ({target.relative_to(ROOT)})")
        return target
    reason = missing_data(path)
    if reason is not None:
        log(f"notebook {path.name}: not executed: {reason}")
        return reason
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        notebook,
        timeout=TIMEOUT,
        kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
    )
    start = time.perf_counter()
    client.execute(env=env)  # raises CellExecutionError when a cell (the final assertion included) fails
    CACHE.mkdir(parents=True, exist_ok=True)
    for stale in CACHE.glob(f"{path.stem}-*.ipynb"):
        stale.unlink()
    partial = target.with_suffix(".partial")
    nbformat.write(notebook, partial)
    partial.replace(target)
    log(f"notebook {path.name}: executed in {time.perf_counter() - start:.0f} s (FRICJAX_SMOKE={env['FRICJAX_SMOKE']})")
    return target


def execute_all(log=print) -> dict[str, pathlib.Path | str]:
    """Every notebook's executed copy (or the reason it could not run here), by file name."""
    return {path.name: execute(path, log) for path in sorted(NOTEBOOKS.glob("*.ipynb"))}


def clear_cache() -> None:
    shutil.rmtree(CACHE, ignore_errors=True)


if __name__ == "__main__":
    start = time.perf_counter()
    execute_all()
    print(f"all notebooks: {time.perf_counter() - start:.0f} s")
