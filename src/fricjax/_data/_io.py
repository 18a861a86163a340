"""Reading friction records from files: CSV (a header row naming the columns) and NPZ archives, with column
aliases and units (what each column holds: `_columns`); the returned data are always SI (m, m/s, N, s)."""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._inputs import Motion
from .._metrics import numpy_rmse, numpy_std
from ._columns import (
    FORCE_UNITS,
    RecordError,
    Units,
    column_named,
    column_role,
    declare_unit,
    force_unit_of,
    mapped_unit,
    parse_units_entry,
    refuse_other_quantity,
    resolve_unit,
    sample_time_of,
    scaled_values,
    warn_if_time_disagrees,
    warn_if_time_unit_doubtful,
)
from ._csv import CSVError, read_csv
from ._record import LOAD_FOLLOWS_FORCE, FrictionData, load_force_correlation

_VELOCITY_POLICIES = ("auto", "file", "derive")


@dataclasses.dataclass(frozen=True)
class RecordInfo:
    """What `read_record` found in a file.

    `columns` maps each role used (`"t"`, `"dt"`, `"x"`, `"v"`, `"force"`, `"normal_force"`) to the column
    name or NPZ key as written in the file (a normal force summed from several columns: their names joined by
    `" + "`); `ignored` lists the columns and keys not used (a velocity column replaced by `velocity="derive"`
    among them); `units` the file's units of displacement and friction force (the data returned with it are
    SI); `samples` the record length; `dt` the sample time used [s]; `assumed_si` the quantities (`"x"`,
    `"force"`) whose unit neither the file nor an argument gave, read as SI (m, N).
    """

    path: str
    columns: dict[str, str]
    ignored: tuple[str, ...]
    units: Units
    samples: int
    dt: float
    assumed_si: tuple[str, ...] = ()


def load_record(
    path: str | pathlib.Path,
    *,
    dt: float | None = None,
    x_unit: str | None = None,
    force_unit: str | None = None,
    velocity: str = "auto",
    normal_force_column: str | Sequence[str] | None = None,
    t_unit: str | None = None,
    columns: Mapping[str, str] | None = None,
) -> FrictionData:
    """Read a friction record from a `.csv` (header row) or `.npz` file, in SI units.

    **Columns** (CSV header names or NPZ keys, case-insensitive, whitespace trimmed):

    - `force` [force unit], also `F`, `friction`, `friction_force`;
    - `x` displacement [x unit], also `position`, `displacement`, `pos`; and/or `v` velocity [x unit per second],
      also `velocity`, `vel`. A missing `v` is derived by central differences, a missing `x` by zero-order hold;
    - `t` uniformly sampled time [s], also `time`; or `dt` the sample time [s] (one value, or a column of equal
      values; with `t` too, they must agree); or the `dt` argument, which wins over both (use it when `t` is
      rounded or absent). A zero, negative, non-finite or subnormal sample time is an error naming its column;
    - `normal_force` the normal load [force unit], also `normal`, `normal_load` and `N` (upper case only: a
      lower-case `n` is usually a sample index); or the columns named by `normal_force_column`, summed. It
      becomes `Motion.normal_force` [N] (for models that take the normal load, e.g. `NormalLoad`).

    Other columns and keys are ignored, as are NPZ keys that are not numeric (strings, metadata); an NPZ key
    holding a 2-D table under a column name is an error. Two columns with the same role (`x` and `position`)
    are an error. At least 100 samples.

    **NPZ tables.** An NPZ file holding `data` (a 2-D numeric array, one row per sample) and `columns` (one name
    per column of `data`) is read as if each column were its own key, as in the friction-damper records of
    `shared/data/damper` (`time_s`, `displacement_in`, `friction_force_kip`, `velocity_in_per_s`,
    `actuator_force1_lb`, ...; its other keys, such as `meta_json`, are ignored).

    **Units.** A column name may carry its unit in brackets, `x [um]`, `force (kN)`, `v [mm/s]`, `t [ms]`, or
    as a suffix after an underscore, `x_um`, `friction_force_kip`, `velocity_in_per_s`, `time_ms`. A suffix
    that is not a unit of the column's quantity is part of the name (`x_raw`, `force_filtered`: not used).
    An NPZ file may hold a key `units` with a string such as `"x=um,force=kN"`. The `x_unit` and `force_unit`
    arguments win over the file's units. Without any, the file is SI (m, N, s). Displacement units: m, cm, mm,
    um (µm), nm, in; force units: N, kN, mN, uN (µN), lbf (lb), kip; time units: s, ms, us (µs). Unit names are
    case-sensitive (`mN` is not `MN`). A velocity is in the displacement unit per second (`v [mm/s]` with
    `x [mm]`; other pairings are an error). A normal-force column without a unit of its own is in the unit of
    a `normal_force=` units entry, else in the friction force's unit.

    **Velocity.** When the file holds both `x` and `v`, `velocity` decides which velocity the record gets:
    `"auto"` (default) the file's, after checking that it agrees with `x` (an error naming both columns when
    the RMS ratio of `v`, integrated over short windows, to the change of `x` over the same windows is outside
    [0.5, 2] or its sign is opposite, e.g. a column in other units); `"file"` the file's, unchecked;
    `"derive"` recomputed from `x` by central differences, the velocity column ignored (the damper's
    dataset-4 records need it: their velocity column is about 1/125 of dx/dt).

    **CSV files** are separated by `,`, `;` or tabs (found from the header and the first row; in `;` and tab
    files a decimal comma is read as a point), may quote numbers (`"1.5"`), and are read in chunks: the memory
    taken is about the table's (8 bytes per number of the columns used), not a multiple of the file's size.

    Errors are one line naming the file and the fix, and the first offending line by its number (`RecordError`,
    a ValueError).

    **Arguments:** `path` the file; `columns` {role: column name} for columns whose names are no alias of their
    role (roles `t`, `dt`, `x`, `v`, `force`; e.g. `{"force": "F_meas [kN]", "x": "lvdt_mm"}`: a unit in brackets
    or as the name's suffix counts; a column that an alias gives the same role is then not used); `dt` the sample
    time [s]; `x_unit`, `force_unit`, `t_unit` the file's units (a
    time column without a unit that gives a sample time above 50 ms, below 20 Hz, is warned about: milliseconds
    read as seconds);
    `velocity` `"auto"`, `"file"` or `"derive"` (above); `normal_force_column` a column name, or several whose
    sum is the normal load (matched case-insensitively, units in brackets or suffixes as above); a name the
    file lacks is an error listing the columns found.

    **Returns:** a `FrictionData` in m, m/s and N (the normal load, if any, in N).

    ```python
    >>> import numpy as np, tempfile, pathlib, fricjax as fj
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "record.csv"
    >>> t = np.arange(200) * 1e-3
    >>> np.savetxt(path, np.c_[t, np.sin(t), np.sin(t)], delimiter=",", header="time,x [mm],F [N]", comments="")
    >>> data = fj.load_record(path)
    >>> data.length, round(float(data.motion.x[100] / np.sin(t[100])), 6)  # mm -> m
    (200, 0.001)
    >>> table = pathlib.Path(tempfile.mkdtemp()) / "damper.npz"  # a table in inches, kip and pounds
    >>> columns = ["time_s", "displacement_in", "friction_force_kip", "actuator_force1_lb", "actuator_force2_lb"]
    >>> np.savez(table, data=np.c_[t, np.sin(t), np.sin(t), np.full(200, 30.0), np.full(200, 20.0)],
    ...          columns=np.array(columns))
    >>> data = fj.load_record(table, normal_force_column=("actuator_force1_lb", "actuator_force2_lb"))
    >>> round(float(data.motion.x[100] / np.sin(t[100])), 6), round(float(data.motion.normal_force[0]), 3)
    (0.0254, 222.411)
    ```
    """
    return read_record(
        path,
        dt=dt,
        x_unit=x_unit,
        force_unit=force_unit,
        velocity=velocity,
        normal_force_column=normal_force_column,
        t_unit=t_unit,
        columns=columns,
    )[0]


def read_record(
    path: str | pathlib.Path,
    *,
    dt: float | None = None,
    x_unit: str | None = None,
    force_unit: str | None = None,
    velocity: str = "auto",
    normal_force_column: str | Sequence[str] | None = None,
    t_unit: str | None = None,
    columns: Mapping[str, str] | None = None,
) -> tuple[FrictionData, RecordInfo]:
    """`load_record`, also returning a `RecordInfo` (columns used and ignored, units, samples, dt)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise RecordError(f"{path}: no such file")
    if dt is not None:
        try:
            dt = math.nan if isinstance(dt, bool) else float(dt)
        except (TypeError, ValueError):
            dt = math.nan
        if not (math.isfinite(dt) and dt >= sys.float_info.min):  # subnormal: 1 / dt overflows
            raise RecordError(f"{path}: dt must be a positive finite sample time in seconds, got {dt!r}")
    if velocity not in _VELOCITY_POLICIES:
        raise RecordError(f"{path}: velocity must be 'auto', 'file' or 'derive', got {velocity!r}")
    named = _normal_force_names(path, normal_force_column)
    mapped = _mapped_columns(path, columns)
    entries, units_entry = _read_table(path, {**named, **{key: key for key in mapped}})
    columns = {}  # role -> the name as written in the file
    data: dict[str, np.ndarray] = {}  # role -> the values as written
    declared: dict[str, list[tuple[str, str]]] = {role: [] for role in ("x", "force", "t", "dt", "normal_force")}
    normal: dict[str, tuple[str, np.ndarray, str | None]] = {}  # lower-case name -> (name, values, own unit)
    ignored = []
    for raw, values in entries:
        role, unit = column_role(raw)
        if column_named(raw, mapped):  # a column the caller named for a role: that role, whatever its name says
            role = mapped[column_named(raw, mapped)]
            unit = mapped_unit(raw, role)
        elif role in mapped.values():  # the role is another column's, by the caller's word: this one is not used
            ignored.append(raw)
            continue
        key = column_named(raw, named)
        if key:
            if role not in (None, "normal_force"):
                raise RecordError(
                    f"{path}: column {raw!r} gives {role!r}; it cannot also be the normal force "
                    "(normal_force_column, --normal-force-column)"
                )
            values = _one_signal(path, raw, values)
            own = force_unit_of(raw) if role is None else unit
            if own is None:
                refuse_other_quantity(path, raw)
            normal[key] = (raw, values, own)
            continue
        if role is None or (role == "normal_force" and named):
            if raw.strip():
                ignored.append(raw)
            continue
        if role in columns:
            raise RecordError(f"{path}: columns {columns[role]!r} and {raw!r} both give {role!r}; keep one of them")
        columns[role] = raw
        data[role] = _one_signal(path, raw, values)
        if unit is not None:
            declare_unit(declared, role, unit, repr(raw), path)
    found_mapped = {column_named(raw, mapped) for raw, _ in entries}
    absent = [name for name in mapped if name not in found_mapped]
    if absent:
        found = ", ".join(repr(raw) for raw, _ in entries) or "nothing"
        raise RecordError(
            f"{path}: no column {absent[0]!r} for {mapped[absent[0]]!r} (columns="
            + ("" if mapped[absent[0]] == "dt" else f", --{mapped[absent[0]]}-column")
            + "); "
            f"found: {found}"
        )
    if units_entry is not None:
        for role, unit in parse_units_entry(units_entry, path):
            declare_unit(declared, role, unit, f"the units entry {role}={unit}", path)
    if "force" not in data:
        found = ", ".join(repr(raw) for raw, _ in entries) or "nothing"
        raise RecordError(f"{path}: missing column 'force' (or F, friction, friction_force; found: {found})")
    if "x" not in data and "v" not in data:
        raise RecordError(
            f"{path}: need a displacement column 'x' (or position, displacement, pos) and/or a velocity column 'v' "
            "(or velocity, vel)"
        )
    missing = [name for name in named if name not in normal]
    if missing:
        found = ", ".join(repr(raw) for raw, _ in entries) or "nothing"
        raise RecordError(
            f"{path}: no column {named[missing[0]]!r} for the normal force (normal_force_column, "
            f"--normal-force-column); found: {found}"
        )
    units = Units(
        x=resolve_unit(path, "x", declared["x"], x_unit),
        force=resolve_unit(path, "force", declared["force"], force_unit),
    )
    if dt is None:
        dt = sample_time_of(path, data, columns, declared, t_unit)
        warn_if_time_unit_doubtful(path, dt, columns, declared, t_unit)
    elif "t" in data or "dt" in data:
        warn_if_time_disagrees(path, dt, data, columns, declared, t_unit)
    force = scaled_values(data["force"], units.force_factor)
    if force.size < 100:
        raise RecordError(f"{path}: only {force.size} samples; need at least 100")
    normal_force = None
    if "normal_force" in data:  # found by its alias: its unit is declared like any column's
        entry_unit = resolve_unit(path, "normal_force", declared["normal_force"], None, units.force)
        normal_force = scaled_values(data["normal_force"], FORCE_UNITS[entry_unit])
    elif normal:
        default = resolve_unit(path, "normal_force", declared["normal_force"], None, units.force)
        normal_force = np.zeros(force.size)
        for raw, values, own in normal.values():
            unit = default if own is None else resolve_unit(path, "normal_force", [(own, repr(raw))], None)
            if values.size != force.size:
                raise RecordError(
                    f"{path}: column {raw!r} has {values.size} values but the record {force.size}; give one per sample"
                )
            normal_force += values * FORCE_UNITS[unit]
        columns["normal_force"] = " + ".join(raw for raw, _, _ in normal.values())
    if normal_force is not None:
        follows = load_force_correlation(force, normal_force)
        if follows >= LOAD_FOLLOWS_FORCE:
            warnings.warn(
                f"{path}: the normal load {columns.get('normal_force', 'normal_force')!r} follows the friction force "
                f"itself (|correlation| {follows:.3f} with the force or its magnitude): a drive or reaction force, "
                "not the load pressing the surfaces? As a model's input it hands the model the force it should "
                "predict; name the column that holds the normal load",
                stacklevel=3,
            )
    if velocity == "file" and "v" not in data:
        raise RecordError(
            f"{path}: velocity='file' (--velocity file) keeps the file's velocity, but it has no velocity column "
            "(v, velocity, vel); drop the option to derive the velocity from the displacement"
        )
    if velocity == "derive" and "v" in data:
        if "x" not in data:
            raise RecordError(
                f"{path}: velocity='derive' (--velocity derive) needs a displacement column 'x' (or position, "
                f"displacement, pos) to recompute the velocity from; the file has only {columns['v']!r}"
            )
        del data["v"]
        ignored.append(columns.pop("v"))
    x = scaled_values(data["x"], units.x_factor) if "x" in data else None
    v = scaled_values(data["v"], units.x_factor) if "v" in data else None
    try:
        if x is not None:
            motion = Motion(x=x, v=v, dt=dt) if v is not None else Motion.from_position(x, dt)
        else:
            assert v is not None  # checked above: x and/or v
            motion = Motion.from_velocity(v, dt)
        if normal_force is not None:
            motion = Motion(x=motion.x, v=motion.v, dt=motion.dt, normal_force=normal_force)
        record = FrictionData(motion, force)
    except (ValueError, TypeError) as err:
        raise RecordError(f"{path}: {err}") from err
    if velocity == "auto" and x is not None and v is not None:
        ratio = _velocity_ratio(x, v, dt)
        if not 0.5 <= ratio <= 2.0:
            raise RecordError(
                f"{path}: velocity column {columns['v']!r} disagrees with displacement column {columns['x']!r}: it "
                f"is {ratio:.3g} times the rate of change of {columns['x']!r} (RMS); drop the velocity column or pass "
                "velocity='derive' (--velocity derive) to recompute it from the displacement (velocity='file', "
                "--velocity file, keeps it unchecked)"
            )
    given = {"x": x_unit, "force": force_unit}
    assumed = tuple(q for q in ("x", "force") if given[q] is None and not declared[q])
    return record, RecordInfo(str(path), columns, tuple(ignored), units, int(force.size), float(dt), assumed)


_MAPPABLE = ("t", "dt", "x", "v", "force")


def _mapped_columns(path: pathlib.Path, columns: Any) -> dict[str, str]:
    """The `columns` argument ({role: column name}) as {lower-case trimmed name: role}."""
    if columns is None:
        return {}
    if not isinstance(columns, Mapping):
        raise RecordError(
            f"{path}: columns must map roles to column names, e.g. {{'force': 'F_meas'}}; got {columns!r}"
        )
    out: dict[str, str] = {}
    for role, name in columns.items():
        if role not in _MAPPABLE:
            raise RecordError(f"{path}: columns: unknown role {role!r}; the roles are {', '.join(_MAPPABLE)}")
        if not isinstance(name, str) or not name.strip():
            raise RecordError(f"{path}: columns[{role!r}] must be a column name, got {name!r}")
        key = name.strip().lower()
        if key in out:
            raise RecordError(f"{path}: columns names {name!r} for both {out[key]!r} and {role!r}; one column a role")
        out[key] = role
    return out


def _normal_force_names(path: pathlib.Path, names: str | Sequence[str] | None) -> dict[str, str]:
    """The `normal_force_column` argument as {lower-case trimmed name: name as given}."""
    if names is None:
        return {}
    listed = [names] if isinstance(names, str) else list(names)
    if not listed or not all(isinstance(name, str) and name.strip() for name in listed):
        raise RecordError(
            f"{path}: normal_force_column must be a column name or a sequence of column names, got {names!r}"
        )
    out: dict[str, str] = {}
    for name in listed:
        key = name.strip().lower()
        if key in out:
            raise RecordError(f"{path}: normal_force_column names {out[key]!r} twice; name each column once")
        out[key] = name
    return out


def _one_signal(path: pathlib.Path, raw: str, values: np.ndarray | None) -> np.ndarray:
    """The values of column `raw` as a 1-D array; an error if they are not numbers or not one per sample."""
    if values is None:
        raise RecordError(f"{path}: {raw!r} does not hold numbers; give a numeric column or rename it")
    if np.squeeze(values).ndim > 1:
        raise RecordError(f"{path}: {raw!r} has shape {values.shape}; give one value per sample (a 1-D array)")
    return values.reshape(-1)


def _velocity_ratio(x: np.ndarray, v: np.ndarray, dt: float) -> float:
    """How many times the rate of change of `x` the velocity `v` is: an RMS ratio, negative where they
    anti-correlate.

    The change of `x` over windows of L samples is compared with the integral of `v` (trapezoidal) over the
    same windows, L the first of 1, 2, 4, ... over which `x` changes by a quarter of its standard deviation
    (RMS): long enough that sensor noise, which differences over short windows amplify, does not dominate the
    change of `x`, and short enough that no window spans a period of an oscillation or lets a bias in `v` add up.
    """
    swept = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1])) * dt))
    spread = float(numpy_std(x))
    if spread == 0:  # `x` that never moves agrees only with `v` = 0
        return 1.0 if not np.any(v) else math.inf
    lag = 1
    while True:
        moved = x[lag:] - x[:-lag]
        scale = float(numpy_rmse(moved))
        if scale >= 0.25 * spread or 2 * lag >= x.size:
            break
        lag *= 2
    integral = swept[lag:] - swept[:-lag]
    swept_rms = float(numpy_rmse(integral))
    ratio = swept_rms / scale
    agree = float(np.dot(moved / scale, integral / swept_rms)) if swept_rms > 0 and scale > 0 else 0.0
    return -ratio if agree < 0 else ratio


def _read_table(path: pathlib.Path, named: dict[str, str]) -> tuple[list[tuple[str, np.ndarray | None]], str | None]:
    """The file's columns in order, `(name as written, values or None where not numeric)`, and an NPZ `units`
    entry if there is one. Of a CSV file only the columns with a role or `named` are parsed."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            return _read_npz(path)
        if suffix == ".csv":
            return read_csv(
                path, lambda name: column_role(name)[0] is not None or bool(column_named(name, named))
            ), None
    except RecordError:
        raise
    except CSVError as err:
        raise RecordError(str(err)) from None
    except Exception as err:  # noqa: BLE001 - any parse failure becomes one line
        detail = " ".join(str(err).split())  # one line, and short
        detail = detail if len(detail) <= 200 else detail[:197] + "..."
        raise RecordError(f"{path}: cannot read the file ({type(err).__name__}: {detail})") from err
    hint = (
        " (the EMPS benchmark's .mat files: fj.load_emps, or `fricjax compare --data emps`)" if suffix == ".mat" else ""
    )
    raise RecordError(f"{path}: unsupported file type {suffix!r}; use .npz or .csv{hint}")


def _read_npz(path: pathlib.Path) -> tuple[list[tuple[str, np.ndarray | None]], str | None]:
    entries: list[tuple[str, np.ndarray | None]] = []
    units = None
    with np.load(path) as archive:
        table = _npz_table(path, archive)
        for key in archive.files:
            if table is not None and key in ("data", "columns"):
                if key == "data":  # the table's columns in its place, as if each were a key
                    entries.extend(table)
                continue
            try:
                value = archive[key]
            except ValueError:  # an object array (pickled metadata), which allow_pickle=False refuses
                value = None
            if key.strip().lower() == "units":
                if value is None or value.dtype.kind not in "US":
                    raise RecordError(f"{path}: key {key!r} must hold a string such as 'x=um,force=kN'")
                units = ",".join(str(item.decode() if isinstance(item, bytes) else item) for item in value.flat)
            elif value is not None and value.dtype.kind in "iuf":
                entries.append((key, value.astype(float)))
            else:
                entries.append((key, None))
    return entries, units


def _npz_table(path: pathlib.Path, archive: Any) -> list[tuple[str, np.ndarray]] | None:
    """The columns of an NPZ table (`data`, 2-D numeric, and `columns`, one name per column of `data`) as
    `(name, values)`, the values views of one float array; None if the archive holds no such table."""
    if not {"data", "columns"} <= set(archive.files):
        return None
    try:
        names, data = archive["columns"], archive["data"]
    except ValueError:  # pickled objects: not a table of numbers and names
        return None
    if names.ndim != 1 or names.dtype.kind not in "US" or data.ndim != 2 or data.dtype.kind not in "iuf":
        return None
    if names.size != data.shape[1]:
        raise RecordError(
            f"{path}: the table 'data' has {data.shape[1]} columns but 'columns' names {names.size}; give one name "
            "per column"
        )
    data = data.astype(float, copy=False)  # the reader's own array: scaled in place later
    return [
        (str(name.decode() if isinstance(name, bytes) else name), data[:, j]) for j, name in enumerate(names.tolist())
    ]
