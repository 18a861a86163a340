"""The checks `compare` makes of its records before any fit, each one line naming the record and the fix: records
fitted together (one sample time, the normal load in all or none, scales that agree unless every file declares its
units), test records (a force that varies where scored and, with `--init state`, over the initialisation window), and
the warnings of records that are not held out or of unused columns that look like a normal load."""

from __future__ import annotations

import pathlib
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._data._record import LOAD_FOLLOWS_FORCE, load_force_correlation
from ..._metrics import numpy_std
from ..._validation import same_sample_time
from ._records import TestRecord, is_built_in
from ._settings import CompareError


def unused_load_columns(split: Any, cards: Sequence[dict[str, Any]]) -> list[str]:
    """A line where the training records hold no normal load but their files have unused columns whose names
    suggest one (a force or a load: the damper's `actuator_force1_lb`), which change the fits a lot when named; a
    column is suggested only when checked: read from every training file, it does not follow the friction force
    (`load_force_correlation`; the damper's actuator forces do: they are named as not suggested)."""
    if split.train.motion.normal_force is not None:
        return []
    names = dict.fromkeys(
        name for card in cards for name in card.get("ignored", ()) if re.search(r"force|load|normal", name, re.I)
    )
    suggested: list[tuple[str, float]] = []
    follows: list[tuple[str, float]] = []
    for name in names:
        correlation = _column_follows_force(name, cards)
        if correlation is None:
            continue  # not readable as a load from every training file: not suggested
        (follows if correlation >= LOAD_FOLLOWS_FORCE else suggested).append((name, correlation))
    lines = []
    if suggested:
        listed = ", ".join(repr(n) for n, _ in suggested)
        lines.append(
            f"columns {listed} are not used; if they hold the normal load, name them with " + "--normal-force-column"
        )
    if follows:
        listed = ", ".join(f"{n!r} ({c:.3f})" for n, c in follows)
        lines.append(
            f"columns {listed} are not used and follow the friction force (|correlation| with the force or its "
            "magnitude): not a normal load to name (a model fed them is fed its own output)"
        )
    return lines


def _column_follows_force(name: str, cards: Sequence[dict[str, Any]]) -> float | None:
    """The largest `load_force_correlation` of column `name` read as a normal load from each training file that has
    it, read as the run read it (its column names, velocity and time unit; a constant column counts 0; None: a file
    that cannot give it)."""
    import warnings

    from ..._data._io import read_record

    found = []
    for card in cards:
        if name not in card.get("ignored", ()):
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                options = card.get("read_with", {})
                record, _ = read_record(card["source"], dt=card.get("dt_s"), normal_force_column=name, **options)
        except (ValueError, OSError, KeyError):
            return None
        if record.motion.normal_force is None:
            return None
        correlation = load_force_correlation(record.force, record.motion.normal_force)
        found.append(correlation if np.isfinite(correlation) else 0.0)  # a constant column follows nothing
    return max(found) if found else None


def check_load_leaks(records: Sequence[tuple[str, Any]]) -> None:
    """A record whose normal load follows its friction force (`load_force_correlation` at or above
    `LOAD_FOLLOWS_FORCE`): one line naming it, before any fit. Fed to a load-scaled model, such a column hands it
    the force it should predict (the damper's actuator forces named as the load made every model 7x better)."""
    for label, data in records:
        if data.motion.normal_force is None:
            continue
        correlation = load_force_correlation(data.force, data.motion.normal_force)
        if correlation >= LOAD_FOLLOWS_FORCE:
            raise CompareError(
                f"{label}: its normal load follows the friction force itself (|correlation| {correlation:.3f} with "
                "the force or its magnitude): a drive or reaction force, not the load pressing the surfaces, and "
                "as an input it hands the models the force they should predict; name the column that holds the "
                "normal load with --normal-force-column, or pass --accept-correlated-load if it truly is the load"
            )


def trained_on(training: Sequence[str], tests: Sequence[str], validation: Sequence[str] = ()) -> list[str]:
    """A line for each --validation record that is also a --data (`training`) record, and each --test record that is
    also a --data or --validation record (the same file, or the same built-in record): its score is not held out."""

    def key(spec: str) -> str:
        return spec if is_built_in(spec) else str(pathlib.Path(spec).resolve())

    roles = {key(spec): role for role, specs in (("validation", validation), ("training", training)) for spec in specs}
    trained = {key(spec) for spec in training}
    return [
        f"{spec}: a training record too; its validation score is not held out (the choice among starts and models "
        "is then made on data the fits have seen: name other records with --validation)"
        for spec in dict.fromkeys(validation)
        if key(spec) in trained
    ] + [
        f"{spec}: a {roles[key(spec)]} record too; its test score is not held out (test on records the fit has not "
        "seen)"
        for spec in dict.fromkeys(tests)
        if key(spec) in roles
    ]


def check_test_record(test: TestRecord, init: str) -> None:
    """A test record's force must vary where it is scored, and, with `--init state`, over its initialisation window
    (the offset and the initial state are fitted there, relative to the force's spread): one line naming the record
    and the options that fix it, before any fit."""
    force = np.asarray(test.record.force)
    scored = force[test.scored_start :]
    if not np.ptp(scored) > 0:
        raise CompareError(
            f"{test.name}: the force is {scored[0]:.6g} N in every scored row; nothing to score a model on (check the "
            "force column)"
        )
    window = force[test.start : test.scored_start]
    if init == "state" and window.size and not np.ptp(window) > 0:
        raise CompareError(
            f"{test.name}: the force is {window[0]:.6g} N throughout its {window.size}-sample initialisation window "
            "(a sensor at rest before the motion?), where the offset and the initial state are fitted; move the "
            "window into the motion with a larger --init-window, or use --init offset, or --init-window 0"
        )


def check_records_together(records: Sequence[Any]) -> None:
    """Records fitted together: one sample time, the normal load in all or none, and scales that agree (a record
    read in the wrong units shows as a force or displacement 10x / 100x off the others'); one line naming the file
    and the fix."""
    first = records[0]
    loaded = [r for r in records if r.data.motion.normal_force is not None]
    if loaded and len(loaded) < len(records):
        bare = next(r for r in records if r.data.motion.normal_force is None)
        raise CompareError(
            f"{loaded[0].name} holds a normal load and {bare.name} none; records fitted together need it in every "
            "file or in none (name its column with --normal-force-column, or drop it)"
        )
    for other in records[1:]:
        dt, reference = (float(np.asarray(r.data.motion.dt).reshape(-1)[0]) for r in (other, first))
        if not same_sample_time(dt, reference):
            raise CompareError(
                f"{other.name}: sampled at dt = {dt:.9g} s, {first.name} at {reference:.9g} s; records fitted together "
                "need one sample time (`resample` HZ resamples every record to one rate; or pass `dt` when the files' "
                "time columns are rounded)"
            )
    force = [float(numpy_std(r.data.force)) for r in records]
    travel = [float(np.ptp(np.asarray(r.data.motion.samples().x))) for r in records]
    for values, what, limit, option, quantity in (
        (force, "force spread", 10.0, "--force-unit", "force"),
        (travel, "travel", 100.0, "--x-unit", "x"),
    ):
        fix = f"(a unit in the column header, e.g. 'force [kN]'; {option} sets the unit of every record)"
        # every file declares the unit (or the option sets it): a ratio is the experiment's (loads, amplitudes, a
        # short record), not a unit mistake; said, not refused
        declared = all(quantity not in r.card.get("units_assumed_si", ()) for r in records)
        # each against the others' median (a record's own value would pull it: of two records, half-way); the most
        # distant one is named (of three, an outlier drags the others' median of the two sound ones towards it)
        middles = [float(np.median([v for j, v in enumerate(values) if j != i])) for i in range(len(values))]
        ratios = [value / middle if middle > 0 else 1.0 for value, middle in zip(values, middles, strict=True)]
        i = int(np.argmax([abs(np.log(r)) if r > 0 else np.inf for r in ratios]))
        record, ratio = records[i], ratios[i]
        if 1 / limit < ratio < limit:
            continue
        if declared:
            print(
                f"note: {record.name}: its {what} is {ratio:.3g}x the other records' (in SI units); every record "
                "declares its unit, so the records are fitted as they are"
            )
            continue
        if len(records) == 2:
            raise CompareError(
                f"{record.name}: its {what} is {ratio:.3g}x that of {records[1 - i].name} (in SI "
                f"units): check the units of both {fix}"
            )
        raise CompareError(
            f"{record.name}: its {what} is {ratio:.3g}x the other records' median (in SI units): check its units {fix}"
        )
