"""`fricjax compare --data emps`: the EMPS table, the inverse dynamic model (IDM) identified with each of the 8
friction laws of the emps-ensemble paper (4 laws, symmetric and asymmetric), with its relative error on the
training and the test file (`emps_table`)."""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np

from ..._constraints import parameter_unit
from ..._data._emps import load_emps
from ..._data._folder import data_folder
from ..._estimation.loop._plausibility import FS_BELOW_FC
from ..._models.physics._static import BoPavelescu, CoulombViscous, Threlfall, Tustin
from ..._version import fricjax_version
from .._emps_idm import fit_emps_idm
from ._output import backups, earlier_outputs, keep_copies, strict_json, versions, write_atomic
from ._settings import CompareError


def emps_table(out: pathlib.Path) -> None:
    """Fit the IDM with every law on `DATA_EMPS.mat`, score it on `DATA_EMPS_PULSES.mat` (both read from
    `fj.data_folder("emps")`: `$FRICJAX_DATA/emps`, else `shared/data/emps` beside the checkout), print the table
    and write `out/report.json`.

    **Raises:** `CompareError` when the EMPS files are missing or unreadable.
    """
    try:
        root = data_folder("emps")
    except FileNotFoundError as err:
        raise CompareError(f"--data emps: {err}") from None
    train_path, test_path = root / "DATA_EMPS.mat", root / "DATA_EMPS_PULSES.mat"
    if not train_path.is_file() or not test_path.is_file():
        raise CompareError(f"--data emps: EMPS files not found in {root}; set FRICJAX_DATA to the data folder")
    try:
        train, test = load_emps(train_path), load_emps(test_path)
    except (ValueError, OSError) as err:
        raise CompareError(f"--data emps: {err}") from err
    laws: list[tuple[str, Any]] = [
        ("Coulomb + viscous", CoulombViscous),
        ("Threlfall", Threlfall),
        ("Tustin", Tustin),
        ("Bo-Pavelescu", BoPavelescu),
    ]
    rows = []
    print(f"{'law':34s} {'train rel. error %':>18s} {'test rel. error %':>18s}  parameters")
    for label, law in laws:
        for asymmetric in (False, True):
            result = fit_emps_idm(train, law, asymmetric=asymmetric)
            name = f"{label} ({'asymmetric' if asymmetric else 'symmetric'})"
            test_error = float(result.relative_error_on(test))
            params = {
                "M": float(result.M),
                # the asymmetric laws have no offset: it is collinear with their two Coulomb levels
                **({} if asymmetric else {"offset": float(result.offset)}),
                **{k: np.asarray(v).tolist() for k, v in result.params.items()},
            }
            rows.append(
                {
                    "law": name,
                    "train_relative_error_percent": float(result.relative_error),
                    "test_relative_error_percent": test_error,
                    "parameters": params,
                    "parameter_units": {k: parameter_unit(k) or None for k in params},
                }
            )
            text = ", ".join(
                f"{k}={_significant(v)}" + (f" {parameter_unit(k)}" if parameter_unit(k) else "")
                for k, v in params.items()
            )
            if "Fs" in params and np.any(np.asarray(params["Fs"]) < np.asarray(params["Fc"])):
                text += f"; {FS_BELOW_FC}"
            print(f"{name:34s} {float(result.relative_error):18.4f} {test_error:18.4f}  {text}")
    keep_copies(out, backups(out, ["report.json"], earlier_outputs(out)))
    write_atomic(
        out / "report.json",
        strict_json({"data": "emps", "fricjax": fricjax_version(), "versions": versions(), "idm": rows}),
    )
    print("the asymmetric laws have no offset: it is collinear with their two Coulomb levels (Fc+, Fc-)")
    print(f"report: {out / 'report.json'} (the IDM's table: no free-run figures; benchmarks/emps.py runs them)")


def _significant(value: Any) -> str:
    """A parameter value to 5 significant digits (a pair as `[a, b]`): 0.00021, not 0.0002 or 0.0."""
    values = np.atleast_1d(np.asarray(value, dtype=float))
    text = [f"{v:.5g}" for v in values]
    return text[0] if np.ndim(value) == 0 else "[" + ", ".join(text) + "]"
