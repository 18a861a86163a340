"""Reading a CSV table of numbers by streaming: the separator sniffed, quotes stripped, errors short.

`read_csv(path, wanted)` reads the header row itself (NumPy would rewrite the names, `"x [um]"` -> `"x_um"`, and
lose the units) and the rows in chunks of 256 KiB with `numpy.loadtxt`, into one preallocated array per
column: the memory is the table's (8 bytes per number) plus one chunk, never a Python list of strings per row.

- Separator: `,`, `;` or tab, the one that splits the header and the first data row into the same number (> 1)
  of fields. In `;` and tab files a decimal comma (`1,5`) is read as a decimal point.
- Quoted fields (`"1.5"`) are read without their quotes; blank lines and lines starting with `#` are skipped (a
  header row may start with `#`, as `numpy.savetxt` writes it).
- Only the columns `wanted` selects are parsed; the others may hold anything but the separator (text, dates).
- Errors name the first offending line, by its line number in the file, and show it cut to 80 characters.
"""

from __future__ import annotations

import csv
import pathlib
import re
import warnings
from collections.abc import Callable

import numpy as np

from ._memory import memory_problem

_CHUNK_BYTES = 1 << 18
_SEPARATORS = (",", ";", "\t")
_SHOWN = 80
_QUOTE = re.compile(r'\s*"\s*')


class CSVError(ValueError):
    """A CSV file that cannot be read as a table of numbers (the message starts with the file's path)."""


def read_csv(path: pathlib.Path, wanted: Callable[[str], bool]) -> list[tuple[str, np.ndarray | None]]:
    """The columns of the CSV file at `path`, in order: `(name as written, values)`, the values `None` for the
    columns `wanted(name)` rejects (not parsed)."""
    with path.open("rb") as handle:
        bound = sum(block.count(b"\n") for block in iter(lambda: handle.read(_CHUNK_BYTES), b"")) + 1
        handle.seek(0)
        number = 0  # line number of the last line read
        header = None
        while header is None:
            line = handle.readline()
            if not line:
                raise CSVError(f"{path}: the file is empty; give a header row and one row per sample")
            number += 1
            if line.strip():
                header = _decode(line).lstrip("\ufeff").strip().lstrip("#")
        start = handle.tell()
        first = handle.readline()
        while first and (not first.strip() or first.lstrip().startswith(b"#")):
            first = handle.readline()
        handle.seek(start)
        separator = _sniff(header, _decode(first))
        names = [name.strip().strip("\"'").strip() for name in next(csv.reader([header], delimiter=separator))]
        if all(_is_number(name) for name in names):
            raise CSVError(f"{path}: the CSV needs a header row naming its columns (e.g. t,x,force)")
        keep = [wanted(name) for name in names]
        if not any(keep):  # nothing to read: the caller names the missing columns
            return [(name, None) for name in names]
        problem = memory_problem(2 * 8 * sum(keep) * bound)  # the table, then the record made from it
        if problem:
            raise CSVError(f"{path}: its {bound} lines need {problem}; split the record into several files")
        table = np.empty((sum(keep), bound))
        rows = 0
        while block := handle.read(_CHUNK_BYTES):
            block += handle.readline()  # to the end of the line
            lines = _decode(block).split("\n")  # on \n only, as the line numbers count
            values = _parse(lines, separator, keep, names, path, number)
            if rows + values.shape[0] > table.shape[1]:  # other line ends than \n (a lone \r) may hold more rows
                table = np.concatenate([table, np.empty((table.shape[0], rows + values.shape[0]))], axis=1)
            table[:, rows : rows + values.shape[0]] = values.T
            rows += values.shape[0]
            number += block.count(b"\n")
    if rows == 0:
        raise CSVError(f"{path}: the CSV has a header but no data rows")
    columns = iter(table[:, :rows])
    return [(name, next(columns) if use else None) for name, use in zip(names, keep, strict=True)]


def _decode(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # an 8-bit export (µ as 0xB5); junk then fails as "not a number"


def _sniff(header: str, first: str) -> str:
    """The separator that splits the header and the first data row alike into most fields (`,` by default)."""
    best, fields = ",", 1
    for separator in _SEPARATORS:
        count = len(next(csv.reader([header], delimiter=separator), []))
        data_count = len(next(csv.reader([first], delimiter=separator), [])) if first.strip() else count
        if count > fields and count == data_count:
            best, fields = separator, count
    if fields == 1:  # no separator agrees: the one the header holds most of, so that the first row's error shows
        best = max(_SEPARATORS, key=header.count) if any(s in header for s in _SEPARATORS) else ","
    return best


def _parse(
    lines: list[str], separator: str, keep: list[bool], names: list[str], path: pathlib.Path, before: int
) -> np.ndarray:
    """The wanted columns of one chunk of data lines (`before` lines of the file precede it), shape (rows, k)."""
    if separator != ",":
        lines = [line.replace(",", ".") for line in lines]  # a decimal comma
    if any('"' in line for line in lines):
        lines = [_QUOTE.sub('"', line) for line in lines]  # ` "1.5" ` -> `"1.5"`, which loadtxt unquotes
    skip: dict[int | str, Callable[[str], float]] = {k: _zero for k, use in enumerate(keep) if not use}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # a chunk of comment lines only: "input contained no data"
            table = np.loadtxt(
                lines, delimiter=separator, comments="#", quotechar='"', ndmin=2, dtype=float, converters=skip or None
            )
    except ValueError:
        raise CSVError(_first_error(lines, separator, keep, names, path, before)) from None
    if table.size == 0:
        return np.empty((0, sum(keep)))
    if table.shape[1] != len(names):
        raise CSVError(_first_error(lines, separator, keep, names, path, before))
    return table[:, np.flatnonzero(keep)]


def _zero(_: str) -> float:
    return 0.0


def _first_error(
    lines: list[str], separator: str, keep: list[bool], names: list[str], path: pathlib.Path, before: int
) -> str:
    """One line naming the first line of `lines` that does not hold a number in each wanted column."""
    for offset, line in enumerate(lines):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        where = f"{path}: line {before + offset + 1}"
        shown = line if len(line) <= _SHOWN else line[: _SHOWN - 3] + "..."
        fields = next(csv.reader([line], delimiter=separator))
        if len(fields) != len(names):
            count = f"{len(fields)} field{'' if len(fields) == 1 else 's'}"
            return f"{where} has {count} where the header names {len(names)} columns: {shown!r}"
        for name, field, use in zip(names, fields, keep, strict=True):
            if use and not _is_number(field):
                value = field if len(field) <= 30 else field[:27] + "..."
                return f"{where}: column {name!r} holds {value!r}, not a number: {shown!r}"
    return f"{path}: cannot read the rows after line {before} as numbers"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
