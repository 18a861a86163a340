"""What the columns of a record file hold: their roles by name (`x`, `velocity`, `F`, ...), their units (in the
header, a `units` entry, or the caller's options; `Units` for the figures and reports), and the sample time a time
column gives (`sample_time_of`). Everything is read in SI (m, m/s, N, s)."""

from __future__ import annotations

import dataclasses
import math
import pathlib
import re
import sys
import warnings
from typing import Any

import numpy as np


class RecordError(ValueError):
    """A record file that cannot be read as friction data; the message names the file and the fix."""


# the names each column role answers to (compared case-insensitively, whitespace trimmed)
_ALIASES = {
    "t": ("t", "time"),
    "dt": ("dt",),
    "x": ("x", "position", "displacement", "pos"),
    "v": ("v", "velocity", "vel"),
    "force": ("force", "f", "friction", "friction_force"),
    "normal_force": ("normal_force", "normal", "normal_load"),  # and `N`, upper case only (see _role_of)
}
_ROLE = {alias: role for role, aliases in _ALIASES.items() for alias in aliases}
_NORMAL_SYMBOL = "N"  # case-sensitive: a lower-case `n` column is usually a sample index

# SI factor of each unit name; the names are case-sensitive (mN is not MN), other spellings in _SPELLINGS
_X_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "nm": 1e-9, "in": 0.0254}
FORCE_UNITS = {"N": 1.0, "kN": 1e3, "mN": 1e-3, "uN": 1e-6, "lbf": 4.4482216152605, "kip": 4448.2216152605}
_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
_SPELLINGS = {
    "µm": "um",  # micro sign
    "μm": "um",  # Greek mu
    "micron": "um",
    "inch": "in",
    "µN": "uN",
    "μN": "uN",
    "µs": "us",
    "μs": "us",
    "lb": "lbf",
}
_TABLES = {"x": _X_UNITS, "force": FORCE_UNITS, "t": _TIME_UNITS, "normal_force": FORCE_UNITS}
_KIND = {"x": "displacement", "force": "force", "t": "time", "normal_force": "normal force"}


@dataclasses.dataclass(frozen=True)
class Units:
    """The units a record file is written in: displacement `x` (velocity in `x` per second) and `force`.

    Unit names are checked and spelled canonically (`"µm"` becomes `"um"`). Known displacement units: m, cm,
    mm, um (µm), nm, in; force units: N, kN, mN, uN (µN), lbf (lb), kip.

    ```python
    >>> Units(x="µm", force="kN").v, Units(x="mm").x_factor
    ('um/s', 0.001)
    ```
    """

    x: str = "m"
    force: str = "N"

    def __post_init__(self):
        object.__setattr__(self, "x", self.check("x", self.x))
        object.__setattr__(self, "force", self.check("force", self.force))

    @staticmethod
    def check(quantity: str, name: str) -> str:
        """The canonical spelling of unit `name` for `quantity` (`"x"`, `"force"`, `"normal_force"` or `"t"`);
        a ValueError listing the known units if there is none."""
        table = _TABLES[quantity]
        name = str(name).strip()
        name = _SPELLINGS.get(name, name)
        if name not in table:
            others = {
                canonical: [alias for alias, target in _SPELLINGS.items() if target == canonical] for canonical in table
            }
            known = ", ".join(f"{c} ({', '.join(a)})" if a else c for c, a in others.items())
            raise ValueError(f"unknown {_KIND[quantity]} unit {name!r} (known: {known})")
        return name

    @property
    def x_factor(self) -> float:
        """Metres per displacement unit."""
        return _X_UNITS[self.x]

    @property
    def force_factor(self) -> float:
        """Newtons per force unit."""
        return FORCE_UNITS[self.force]

    @property
    def v(self) -> str:
        """The velocity unit, displacement unit per second (e.g. `"um/s"`)."""
        return f"{self.x}/s"


def sample_time_of(
    path: pathlib.Path,
    data: dict[str, np.ndarray],
    columns: dict[str, str],
    declared: dict[str, list],
    t_unit: str | None = None,
) -> float:
    """The sample time [s] from the columns 'dt' and / or 't' (which must agree when both are given), in the unit
    `t_unit` if given (it wins over the file's), else the one the file declares, else seconds."""
    seconds = {role: _TIME_UNITS[resolve_unit(path, "t", declared[role], t_unit)] for role in ("t", "dt")}
    fix = "pass the sample time in seconds (dt= in load_record, --dt on the command line)"
    dt = None
    if "dt" in data:
        dts = data["dt"] * seconds["dt"]
        bad = np.flatnonzero(~(np.isfinite(dts) & (dts >= sys.float_info.min)))  # zero, negative, NaN, subnormal
        if bad.size:
            raise RecordError(
                f"{path}: column {columns['dt']!r} holds {float(data['dt'][bad[0]])!r} in data row {bad[0] + 1}; "
                f"the sample time must be a positive finite number of seconds: correct it or {fix}"
            )
        if not np.allclose(dts, dts[0], rtol=1e-9, atol=0):
            raise RecordError(
                f"{path}: column {columns['dt']!r} must hold one sample time (all rows equal); resample the record "
                "to a uniform rate first"
            )
        dt = float(dts[0])
    if "t" in data:
        t = data["t"] * seconds["t"]
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise RecordError(f"{path}: column {columns['t']!r} holds {float(t[bad[0]])!r} in data row {bad[0] + 1}")
        if dt is not None:  # both: the time `t` spans must be (rows - 1) * dt, to 0.1 % or to the rounding of `t`
            span, expected = float(t[-1] - t[0]), (t.size - 1) * dt
            rounding = min(2 * float(np.max(np.abs(np.diff(t) - dt))), 2 * dt) if t.size > 1 else 0.0
            if not abs(span - expected) <= max(1e-3 * expected, rounding):
                step = span / (t.size - 1) if t.size > 1 else math.nan
                raise RecordError(
                    f"{path}: columns {columns['t']!r} and {columns['dt']!r} disagree: {columns['t']!r} advances "
                    f"{step:.6g} s per row, {columns['dt']!r} gives {dt:.6g} s; drop the wrong column or {fix}"
                )
            return dt
        steps = np.diff(t)
        if steps.size and not steps[0] >= sys.float_info.min:
            raise RecordError(
                f"{path}: column {columns['t']!r} must increase, but goes from {float(t[0])!r} to {float(t[1])!r} "
                f"s in its first step; correct it or {fix}"
            )
        if steps.size == 0:  # one time stamp (an NPZ's scalar `t`, say): a sample time is what was meant
            raise RecordError(
                f"{path}: column {columns['t']!r} holds one time stamp, not a time per sample; if it is the sample "
                f"time, name it 'dt', or {fix}"
            )
        backwards = np.flatnonzero(steps < 0)  # (a step of 0 is a rounded time stamp: the message below)
        if backwards.size:
            row = int(backwards[0]) + 1
            raise RecordError(
                f"{path}: column {columns['t']!r} goes back at data row {row + 1} ({float(t[row - 1])!r} -> "
                f"{float(t[row])!r} s): sort or clean the record, or {fix}"
            )
        if _float32_stamps(t):  # each stamp rounded to float32 (or summed in it): steps differ by its rounding
            mean = float(t[-1] - t[0]) / steps.size
            rounding = 4.0 * float(np.spacing(np.float32(np.max(np.abs(t)))))
            if np.all(np.abs(steps - mean) <= rounding + 1e-6 * mean):
                return mean
        if not np.allclose(steps, steps[0], rtol=1e-6, atol=0):
            raise RecordError(
                f"{path}: column {columns['t']!r} must be uniformly sampled; if it is only rounded, {fix} or a "
                "column 'dt' holding it"
            )
        return float(steps[0])
    if dt is None:
        raise RecordError(f"{path}: need a time column 't' (or time) or a sample-time column 'dt', or {fix}")
    return dt


def _float32_stamps(t: np.ndarray) -> bool:
    """Whether the time stamps `t` [s] are float32 numbers (as a float32 column, or one written from float32, reads):
    each within a quarter of its float32 rounding step of a float32 value (nine significant digits keep that; of
    float64 stamps, about half are, so a record of hundreds of samples cannot pass by chance)."""
    single = t.astype(np.float32)
    return bool(np.all(np.abs(t - single) <= 0.25 * np.spacing(np.abs(single))))


def warn_if_time_disagrees(
    path: pathlib.Path,
    dt: float,
    data: dict[str, np.ndarray],
    columns: dict[str, str],
    declared: Any,
    t_unit: str | None = None,
) -> None:
    """The `dt` argument wins over the file's time columns; a warning where they disagree by more than 0.1 %
    (a sample time in the wrong unit makes every rate parameter wrong)."""
    try:
        found = sample_time_of(path, data, columns, declared, t_unit)
    except RecordError:  # the columns cannot give one: the argument is the sample time
        return
    if abs(found - dt) > 1e-3 * dt:
        named = " / ".join(repr(columns[role]) for role in ("t", "dt") if role in columns)
        warnings.warn(
            f"{path}: dt = {dt:.6g} s (the argument, used) disagrees with {named} in the file ({found:.6g} s, "
            f"{dt / found:.3g}x); check the sample time's unit",
            stacklevel=4,
        )


# a sample time above this [s] (below 20 Hz) is slow for a friction record: a time column in milliseconds read as
# seconds gives 1 kHz records a sample time of 1 s
SLOW_SAMPLE_TIME = 0.05


def warn_if_time_unit_doubtful(
    path: pathlib.Path, dt: float, columns: dict[str, str], declared: Any, t_unit: str | None
) -> None:
    """A warning where the file's time column has no unit (none in its name, no units entry, no `t_unit`) and gives
    a sample time slower than friction records are sampled (`SLOW_SAMPLE_TIME`): a time in milliseconds read as
    seconds makes every rate parameter 1000x wrong, and the fit still "succeeds"."""
    if t_unit is not None or declared["t"] or declared["dt"] or dt <= SLOW_SAMPLE_TIME:
        return
    named = " / ".join(repr(columns[role]) for role in ("t", "dt") if role in columns)
    warnings.warn(
        f"{path}: the time column {named} has no unit and gives a sample time of {dt:.4g} s ({1 / dt:.3g} Hz), slow "
        "for a friction record: if it is in milliseconds, pass t_unit='ms' (--t-unit ms); a time in seconds can "
        "say so in its name ('t [s]', 'time_s')",
        stacklevel=4,
    )


def scaled_values(values: np.ndarray, factor: float) -> np.ndarray:
    """`values * factor`, in place (the arrays are the reader's own): a record is not copied for its units."""
    if factor != 1.0:
        values *= factor
    return values


def _role_of(name: str) -> str | None:
    """The role of a column name without its unit (`"Position"` -> `"x"`), or None."""
    name = name.strip()
    return "normal_force" if name == _NORMAL_SYMBOL else _ROLE.get(name.lower())


def column_role(raw: str) -> tuple[str | None, str | None]:
    """The role and declared unit of a column: `"x [um]"` -> `("x", "um")`, `"displacement_in"` ->
    `("x", "in")`, `"velocity_in_per_s"` -> `("v", "in/s")`, `"temperature"` -> `(None, None)`. A suffix is a
    unit only if it is one of the role's quantity, else part of the name (`"x_raw"` -> `(None, None)`)."""
    name, unit = _split_unit(raw)
    role = _role_of(name)
    if role is not None or unit is not None:
        return role, unit
    for cut in range(len(name)):
        if name[cut] != "_":
            continue
        role, suffix = _role_of(name[:cut]), name[cut + 1 :]
        if role is None:
            continue
        if role == "v":
            base, sep, per = suffix.rpartition("_per_")
            base, per = (base, per) if sep else suffix.partition("/")[::2]
            if per == "s" and _is_unit("x", base):
                return role, f"{base}/s"
        elif _is_unit("force" if role == "normal_force" else "t" if role == "dt" else role, suffix):
            return role, suffix
    return None, None


def mapped_unit(raw: str, role: str) -> str | None:
    """The unit a column named for `role` by the caller declares: in brackets (`"F_meas [kN]"`), or as the suffix its
    name would carry in that role (`"load_cell_kN"` as the force: `"kN"`), else None."""
    name, unit = _split_unit(raw)
    if unit is not None:
        return unit
    quantity = "force" if role == "normal_force" else "t" if role == "dt" else role
    head, sep, suffix = name.rpartition("_")
    if role == "v":  # `speed_mm_per_s` or `speed_mm/s`
        base, per_sep, per = name.rpartition("_per_")
        if not per_sep:
            base, per_sep, per = name.rpartition("/")
        if per_sep and per == "s":
            unit = base.rpartition("_")[2]
            return f"{unit}/s" if _is_unit("x", unit) else None
        return None
    return suffix if sep and head and _is_unit(quantity, suffix) else None


def _is_unit(quantity: str, name: str) -> bool:
    try:
        Units.check(quantity, name)
    except ValueError:
        return False
    return True


def force_unit_of(raw: str) -> str | None:
    """The unit a column named for the normal force declares: in brackets (any text, checked later) or as a
    force-unit suffix (`"actuator_force1_lb"` -> `"lb"`); None if it declares none."""
    name, unit = _split_unit(raw)
    if unit is not None:
        return unit
    head, sep, suffix = name.rpartition("_")
    return suffix if sep and head and _is_unit("force", suffix) else None


def refuse_other_quantity(path: Any, raw: str) -> None:
    """A column named for the normal force whose name ends in a unit of another quantity (`"actuator_pos1_in"`:
    a displacement in inches) is refused: it would be read as a force in the friction force's unit."""
    head, sep, suffix = _split_unit(raw)[0].rpartition("_")
    if not (sep and head):
        return
    for quantity in ("x", "t"):
        if _is_unit(quantity, suffix):
            raise RecordError(
                f"{path}: column {raw!r} is named in a {_KIND[quantity]} unit ({suffix!r}), not a force unit; name "
                "the normal-force column(s) (normal_force_column, --normal-force-column)"
            )


def column_named(raw: str, named: dict[str, str]) -> str:
    """The key of `named` (lower-case names given for the normal force) that column `raw` matches, as written or
    without its bracketed unit ('press_a' names the column 'press_a [N]'); `""` for none."""
    for key in (raw.strip().lower(), _split_unit(raw)[0].strip().lower()):
        if key in named:
            return key
    return ""


def _split_unit(raw: str) -> tuple[str, str | None]:
    """`"x [um]"` -> `("x", "um")`, `"force (kN)"` -> `("force", "kN")`, `"t"` -> `("t", None)`."""
    match = re.fullmatch(r"\s*(.*?)\s*(?:\[([^\]]*)\]|\(([^)]*)\))\s*", raw)
    if match is None:
        return raw.strip(), None
    return match[1], (match[2] if match[2] is not None else match[3]).strip()


def parse_units_entry(entry: str, path: pathlib.Path) -> list[tuple[str, str]]:
    """`"x=um,force=kN"` -> `[("x", "um"), ("force", "kN")]`, names resolved through the column aliases."""
    out = []
    for item in re.split(r"[,;]", entry):
        if not item.strip():
            continue
        name, sep, unit = item.partition("=")
        role = _role_of(name)
        if not sep or role is None or not unit.strip():
            raise RecordError(
                f"{path}: cannot read {item.strip()!r} in the units entry; write it as 'x=um,force=kN' "
                "(names: x, v, force, t, dt, normal_force or their aliases)"
            )
        out.append((role, unit.strip()))
    return out


def declare_unit(declared: dict[str, list[tuple[str, str]]], role: str, unit: str, where: str, path: Any) -> None:
    """Note a unit the file gives for `role`; a velocity unit `<x unit>/s` declares the displacement unit."""
    if role == "v":
        x_unit, sep, per = unit.partition("/")
        if not sep or per.strip() != "s":
            raise RecordError(
                f"{path}: velocity unit {unit!r} in {where} must be a displacement unit per second (e.g. um/s)"
            )
        role, unit = "x", x_unit
    declared[role].append((unit, where))


_DEFAULTS = {"x": "m", "force": "N", "t": "s", "normal_force": "N"}
_OPTIONS = {"x": "x_unit= (--x-unit)", "force": "force_unit= (--force-unit)", "t": "t_unit= (--t-unit)"}


def resolve_unit(
    path: Any, quantity: str, declared: list[tuple[str, str]], override: str | None, default: str | None = None
) -> str:
    """The unit of `quantity`: the argument `override` if given, else the one the file declares, else `default`
    (SI if None)."""
    if override is not None:
        try:
            chosen = Units.check(quantity, override)
        except ValueError as err:
            raise RecordError(f"{path}: {err}") from None
        for unit, where in declared:
            if _is_unit(quantity, unit) and Units.check(quantity, unit) != chosen:
                warnings.warn(
                    f"{path}: {_OPTIONS[quantity].replace('= ', f'={chosen!r} ')} overrides the {_KIND[quantity]} unit "
                    f"{unit!r} that {where} gives; the data are read in {chosen!r}",
                    stacklevel=4,
                )
                break
        return chosen
    found: dict[str, str] = {}
    fix = f", or pass {_OPTIONS[quantity]}" if quantity in _OPTIONS else ""
    for unit, where in declared:
        try:
            found.setdefault(Units.check(quantity, unit), where)
        except ValueError as err:
            raise RecordError(f"{path}: {err} in {where}; correct it{fix}") from None
    if len(found) > 1:
        listed = " and ".join(f"{unit} ({where})" for unit, where in found.items())
        raise RecordError(f"{path}: the file gives the {_KIND[quantity]} unit as {listed}; make them agree{fix}")
    return next(iter(found), default if default is not None else _DEFAULTS[quantity])
