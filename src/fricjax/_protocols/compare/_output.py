"""Where `compare` writes: a check that the output folder takes files (`check_writable`), a file replaced in one
rename (`write_atomic`), strict JSON with non-finite numbers as `null` (`strict_json`), and the versions a report
records (`fricjax_version`, `versions`)."""

from __future__ import annotations

import json
import os
import pathlib
import tempfile
import uuid
import warnings
from typing import Any

import numpy as np

from ._settings import CompareError


def check_writable(out: pathlib.Path) -> None:
    """Raise `CompareError` unless `out` (created if missing) takes new files and its `models` entry, if any, is
    a folder."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        handle, probe = tempfile.mkstemp(prefix=".fricjax-write-test-", dir=out)  # a fresh name: nothing overwritten
        os.close(handle)
        os.unlink(probe)
    except OSError as err:
        raise CompareError(f"--out {out}: not writable ({err.strerror})") from err
    models = out / "models"
    if models.exists() and not models.is_dir():
        raise CompareError(f"--out {out}: 'models' exists and is not a folder; move it away or choose another --out")


def write_atomic(path: pathlib.Path, text: str) -> None:
    """Write `text` to a temporary file beside `path`, then rename it over `path`. The file gets the mode of any
    new file (0o666 less the umask, as the other outputs), not `tempfile.mkstemp`'s 0o600."""
    temporary = path.with_name(f".fj-{uuid.uuid4().hex[:12]}.tmp")  # short: a long `path.name` stays legal
    handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(handle, "w") as stream:
            stream.write(text)
        os.replace(temporary, path)
    except BaseException:
        pathlib.Path(temporary).unlink(missing_ok=True)
        raise


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
