"""Reading friction records from files: CSV (a header row naming the columns) and NPZ archives."""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np

from .._inputs import Motion
from ._record import FrictionData


class RecordError(ValueError):
    """A record file that cannot be read as friction data; the message names the file and the fix."""


def load_record(path: str | pathlib.Path) -> FrictionData:
    """Read a friction record from a `.csv` (header row) or `.npz` file.

    Columns (case-insensitive): `t` (uniformly sampled time [s]) or `dt` (sample time [s]); `x` displacement [m]
    and/or `v` velocity [m/s]; `force` [N]. A missing `v` is derived by central differences, a missing `x` by
    zero-order hold. At least 100 samples. Errors name the file and the fix (`RecordError`, a ValueError).

    ```python
    >>> import numpy as np, tempfile, pathlib, fricjax as fj
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "record.csv"
    >>> t = np.arange(200) * 1e-3
    >>> np.savetxt(path, np.c_[t, 1e-3 * np.sin(t), np.sin(t)], delimiter=",", header="t,x,force", comments="")
    >>> fj.load_record(path).length
    200
    ```
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise RecordError(f"{path}: no such file")
    return _record_from_columns(_read_columns(path), path)


def _read_columns(path: Any) -> dict[str, np.ndarray]:
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path) as archive:
                return {key.lower(): np.asarray(archive[key], dtype=float).reshape(-1) for key in archive.files}
        if suffix == ".csv":
            if not path.read_text(encoding="utf-8-sig", errors="replace").strip():
                raise RecordError(f"{path}: the file is empty; give a header row and one row per sample")
            # utf-8-sig: a byte-order mark (Excel's CSV export) is not part of the first column name
            table = np.genfromtxt(path, delimiter=",", names=True, dtype=float, encoding="utf-8-sig")
            if table.dtype.names is None:
                raise RecordError(f"{path}: the CSV needs a header row naming its columns")
            columns = {name.lower(): np.asarray(table[name], dtype=float).reshape(-1) for name in table.dtype.names}
            if any(column.size == 0 for column in columns.values()):
                raise RecordError(f"{path}: the CSV has a header but no data rows")
            return columns
    except RecordError:
        raise
    except Exception as err:  # noqa: BLE001 - any parse failure becomes one line
        detail = " ".join(str(err).split())  # one line
        raise RecordError(f"{path}: cannot read the file ({type(err).__name__}: {detail})") from err
    raise RecordError(f"{path}: unsupported file type {suffix!r}; use .npz or .csv")


def _record_from_columns(columns: dict[str, np.ndarray], path: Any) -> FrictionData:
    if "force" not in columns:
        raise RecordError(f"{path}: missing column 'force' (found: {', '.join(sorted(columns))})")
    if "x" not in columns and "v" not in columns:
        raise RecordError(f"{path}: need a displacement column 'x' and/or a velocity column 'v'")
    if "dt" in columns:
        dts = columns["dt"].reshape(-1)
        if dts.size == 0 or not np.allclose(dts, dts[0], rtol=1e-9, atol=0):
            raise RecordError(
                f"{path}: column 'dt' must hold one sample time (all rows equal); resample the record to a uniform "
                "rate first"
            )
        dt = float(dts[0])
    elif "t" in columns:
        steps = np.diff(columns["t"])
        if steps.size == 0 or not np.allclose(steps, steps[0], rtol=1e-6, atol=0):
            raise RecordError(
                f"{path}: column 't' must be uniformly sampled; if it is only rounded, replace it by a column 'dt' "
                "holding the sample time in seconds"
            )
        dt = float(steps[0])
    else:
        raise RecordError(f"{path}: need a time column 't' or a sample-time column 'dt'")
    force = columns["force"]
    if force.size < 100:
        raise RecordError(f"{path}: only {force.size} samples; need at least 100")
    try:
        x, v = columns.get("x"), columns.get("v")
        if x is not None:
            motion = Motion(x=x, v=v, dt=dt) if v is not None else Motion.from_position(x, dt)
        else:
            assert v is not None
            motion = Motion.from_velocity(v, dt)
        return FrictionData(motion, force)
    except (ValueError, TypeError) as err:
        raise RecordError(f"{path}: {err}") from err
