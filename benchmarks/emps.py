"""EMPS benchmark: IDM (IDIM-LS) and open-loop (simulation-error) fits of the eight static friction laws.

For each law of the emps-ensemble paper (Coulomb + viscous, Threlfall, Tustin, Bo-Pavelescu; symmetric and
asymmetric) one JSON line: the IDM parameters fitted on DATA_EMPS.mat (`fj.emps.fit_emps_idm`) with their relative
errors on the training and test files; the open-loop fit that starts from them (`fj.emps.fit_emps_open_loop`,
Levenberg-Marquardt on the official simulation error) with its parameters; the official test score (free-run
position RMSE in mm on DATA_EMPS_PULSES.mat, the first 20 samples only initialising the state) of the fitted
plant, of its IDM start and of the published reference parameters run through the same simulator; and the
fit wall times (compilation included). Every line carries the machine and the versions.

`--hybrid` runs the grey + black-box part instead (`fj.emps.fit_emps_hybrid`: each law's open-loop plant plus a
tanh-network residual on the force path, physics free or frozen, trained by simulation error on the first
70 % of DATA_EMPS.mat, the model and the variant chosen by the free-run error on the last 30 %; then ensembles
of the laws and hybrids combining their simulated positions, weights from the training file; then the
closed-loop relative errors). One line per model: `{"kind": "hybrid" | "ensemble" | "member" | "closed_loop",
"name", "test_rmse_mm", "train_rmse_mm", "fit_s", ...}`; `--smoke` is the CI size (< 90 s).

`--bgbm` runs only the laws and their BGBM (`fj.emps.fit_emps_bgbm`, emps-ensemble §3.2): the grey box's free run plus
a linear output-error model of its position error driven by the force and / or the simulated velocity, fitted
on the first 70 % of DATA_EMPS.mat, chosen on the last 30 %, refitted on the whole file (`{"kind": "bgbm" |
"bgbm_choice", ...}`); `--hybrid` includes them.

`--study` runs the sensitivity study behind the settings of `fit_emps_open_loop` instead (initial state, input
timing, sub-steps, offset drift, and the fit settings compared by two-fold cross-validation over the halves of
the training file); its test scores are printed for the record only (`"used_for_choice": false`).

`--crossfile` asks whether the two records describe the same axis (diagnosis, not a protocol): the mean drive force
on each constant-velocity plateau of both files, then each law fitted on each file and scored on both
(`{"kind": "plateau_force" | "crossfile", ...}`, every line `"used_for_choice": false`).

Run: `python benchmarks/emps.py [--quick] [--laws CoulombViscous Tustin] [--study | --bgbm | --crossfile |
--hybrid [--smoke]]`;
the data folder is `$FRICJAX_DATA` (default: `../shared/data` beside the repository).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402
import optimistix  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment as shared_environment  # noqa: E402

LAWS = {
    "CoulombViscous": fj.CoulombViscous,
    "Threlfall": fj.Threlfall,
    "Tustin": fj.Tustin,
    "BoPavelescu": fj.BoPavelescu,
}
REFERENCE = fj.EMPSPlant(95.1089, fj.CoulombViscous(Fc=20.3935, Fv=203.5034, offset=-3.1648))
"""The published IDIM-LS model of the benchmark (Janot et al. 2019, §3.4)."""


def data_dir() -> pathlib.Path:
    default = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
    path = pathlib.Path(os.environ.get("FRICJAX_DATA", default))
    if not (path / "emps" / "DATA_EMPS.mat").is_file():
        sys.exit(f"EMPS data not found under {path}; set FRICJAX_DATA to the shared/data folder.")
    return path


def environment() -> dict[str, Any]:
    return {**shared_environment(optimistix=optimistix.__version__), "loadavg_1min": round(os.getloadavg()[0], 2)}


def emit(record: dict[str, Any]) -> None:
    print(json.dumps({**record, **environment()}), flush=True)


def rounded(value: Any, digits: int = 6) -> Any:
    array = np.asarray(value, dtype=float)
    return round(float(array), digits) if array.ndim == 0 else [round(float(x), digits) for x in array]


def plant_parameters(plant: fj.EMPSPlant) -> dict[str, Any]:
    """Physical parameters of a plant: M, the friction law's coefficients and the total offset."""
    p = fj.unwrap(fj.exact(plant))
    out = {"M": rounded(p.mass)}
    for name in ("Fc", "Fs", "vs", "delta", "Fv", "v0"):
        if hasattr(p.friction, name):
            out[name] = rounded(getattr(p.friction, name))
    out["offset"] = rounded(p.friction.offset + p.offset)
    return out


def idm_parameters(idm: Any) -> dict[str, Any]:
    return {"M": rounded(idm.M), **{k: rounded(v) for k, v in idm.params.items()}, "offset": rounded(idm.offset)}


# --------------------------------------------------------------------------------------------------------------
# The eight laws


def run_laws(train: fj.EMPSRecord, test: fj.EMPSRecord, laws: list[str], steps: int) -> None:
    score = fj.emps.score_emps_open_loop
    reference_test = score(REFERENCE, test)
    reference_train = score(REFERENCE, train)
    rows = []
    for name in laws:
        for asymmetric in (False, True):
            law = LAWS[name]
            t0 = time.perf_counter()
            idm = fj.emps.fit_emps_idm(train, law, asymmetric=asymmetric)
            idm_s = time.perf_counter() - t0
            start = idm.plant()
            t0 = time.perf_counter()
            fitted = fj.emps.fit_emps_open_loop(train, law, asymmetric=asymmetric, idm=idm, steps=steps)
            fit_s = time.perf_counter() - t0
            row = {
                "kind": "law",
                "law": name,
                "asymmetric": asymmetric,
                "idm": {
                    "params": idm_parameters(idm),
                    "rel_error_train_pct": round(idm.relative_error, 4),
                    "rel_error_test_pct": round(idm.relative_error_on(test), 4),
                    "condition_number": round(idm.condition_number, 4),
                    "fit_s": round(idm_s, 3),
                    "train_rmse_mm": round(score(start, train), 4),
                    "test_rmse_mm": round(score(start, test), 4),
                },
                "open_loop": {
                    "params": plant_parameters(fitted.plant),
                    "train_rmse_mm": round(float(np.sqrt(fitted.result.train_loss)), 4),
                    "test_rmse_mm": round(score(fitted.plant, test), 4),
                    "test_rmse_exact_law_mm": round(score(fj.exact(fitted.plant), test), 4),
                    "result": fitted.result.code,
                    "solver_steps": fitted.result.evaluations,
                    "steps_budget": steps,
                    "smoothing": "continuation 1e-2 -> 1e-4 m/s, 3 stages",
                    "fit_s": round(fit_s, 2),
                    "fit_s_note": "fit_emps_open_loop wall time: compilation, 3 Levenberg-Marquardt stages, std devs",
                },
                "reference_test_rmse_mm": round(reference_test, 4),
                "reference_train_rmse_mm": round(reference_train, 4),
                "beats_reference": bool(score(fitted.plant, test) < reference_test),
            }
            rows.append(row)
            emit(row)
    emit(
        {
            "kind": "summary",
            "reference_test_rmse_mm": round(reference_test, 4),
            "test_rmse_mm": {
                f"{r['law']}{'-asym' if r['asymmetric'] else ''}": [
                    r["idm"]["test_rmse_mm"],
                    r["open_loop"]["test_rmse_mm"],
                ]
                for r in rows
            },
            "test_rmse_note": "[IDM start, open-loop fit]",
            "all_beat_reference": all(r["beats_reference"] for r in rows),
        }
    )


# --------------------------------------------------------------------------------------------------------------
# The sensitivity study (training file only for the choices)


def shifted(record: fj.EMPSRecord, shift: int) -> fj.EMPSRecord:
    """The record with `vir` delayed by `shift` samples (advanced for shift < 0), edges repeated."""
    vir = np.roll(record.vir, shift)
    if shift > 0:
        vir[:shift] = record.vir[0]
    elif shift < 0:
        vir[shift:] = record.vir[-1]
    return eqx.tree_at(lambda r: r.vir, record, vir)


def windows_rmse(plant: fj.EMPSPlant, record: fj.EMPSRecord, horizon: int, stride: int = 250, **options: Any) -> float:
    """RMS of the official free-run error over many short windows (20 initialisation + `horizon` samples)."""
    errors = []
    for start in range(0, record.length - horizon - 20, stride):
        part = fj.emps.split_emps_record(record, start, start + horizon + 20)
        errors.append(fj.emps.score_emps_open_loop(plant, part, **options) ** 2)
    return float(np.sqrt(np.mean(errors)))


def run_study(train: fj.EMPSRecord, test: fj.EMPSRecord) -> None:
    score = fj.emps.score_emps_open_loop
    n = train.length
    halves = (fj.emps.split_emps_record(train, 0, n // 2), fj.emps.split_emps_record(train, n // 2))

    # 1. initial state, input timing and sub-steps, with the reference parameters
    for degree in (1, 2, 3, 5):
        emit(
            {
                "kind": "study",
                "group": "initial_state",
                "degree": degree,
                "train_rmse_mm": round(score(REFERENCE, train, degree=degree), 4),
                "test_rmse_mm": round(score(REFERENCE, test, degree=degree), 4),
                "train_windows_200ms_rmse_mm": round(windows_rmse(REFERENCE, train, 200, degree=degree), 4),
            }
        )
    for record in (train, test):
        sim = fj.simulate_open_loop(REFERENCE, record.vir[19:], record.gtau, record.dt, q0=record.qm[19], qd0=0.0)
        emit(
            {
                "kind": "study",
                "group": "initial_state",
                "degree": "at rest (qd0 = 0)",
                "record": record.name,
                "rmse_mm": round(float(fj.emps_open_loop_rmse_mm(record.qm[19:], sim.q, skip=1)), 4),
            }
        )
    for shift in (-1, 0, 1):
        emit(
            {
                "kind": "study",
                "group": "input_timing",
                "vir_delay_samples": shift,
                "train_rmse_mm": round(score(REFERENCE, shifted(train, shift)), 4),
                "train_windows_200ms_rmse_mm": round(windows_rmse(REFERENCE, shifted(train, shift), 200), 4),
                "train_windows_1s_rmse_mm": round(windows_rmse(REFERENCE, shifted(train, shift), 1000), 4),
            }
        )
    for substeps in (1, 10):
        for label, plant in (("exact", REFERENCE), ("smooth 1e-4", fj.with_smoothing(REFERENCE, fj.Smooth(1e-4)))):
            emit(
                {
                    "kind": "study",
                    "group": "substeps",
                    "substeps": substeps,
                    "law": label,
                    "train_rmse_mm": round(score(plant, train, substeps=substeps), 4),
                    "test_rmse_mm": round(score(plant, test, substeps=substeps), 4),
                }
            )

    # 2. the offset that balances the drift, per part of the records (reference M, Fc, Fv)
    period = 6210  # the reference trajectory repeats 4 times in 24 841 samples
    parts = {f"train period {i + 1}": fj.emps.split_emps_record(train, i * period, (i + 1) * period) for i in range(4)}
    cut = int(round(0.7 * n))
    parts |= {
        "train first 70 %": fj.emps.split_emps_record(train, 0, cut),
        "train last 30 %": fj.emps.split_emps_record(train, cut),
        "train half 1": halves[0],
        "train half 2": halves[1],
        "train": train,
        "test": test,
    }
    offsets = np.round(np.arange(-3.45, -2.90, 0.005), 3)
    for label, record in parts.items():
        values = [
            score(fj.EMPSPlant(95.1089, fj.CoulombViscous(Fc=20.3935, Fv=203.5034, offset=o)), record) for o in offsets
        ]
        i = int(np.argmin(values))
        emit(
            {
                "kind": "study",
                "group": "best_offset",
                "part": label,
                "best_offset_N": float(offsets[i]),
                "rmse_at_best_mm": round(values[i], 4),
                "rmse_reference_mm": round(score(REFERENCE, record), 4),
                "at_grid_edge": i in (0, len(offsets) - 1),
            }
        )

    # 3. fit settings, by two-fold cross-validation over the halves of the training file
    def cv(**options: Any) -> dict[str, Any]:
        t0 = time.perf_counter()
        folds = [fj.emps.fit_emps_open_loop(h, compute_std=False, **options) for h in halves]
        cv_scores = [score(folds[0].plant, halves[1]), score(folds[1].plant, halves[0])]
        head = fj.emps.fit_emps_open_loop(train, validation=0.3, compute_std=False, **options)
        full = fj.emps.fit_emps_open_loop(train, compute_std=False, **options)
        return {
            "cv_rmse_mm": [round(s, 4) for s in cv_scores],
            "cv_mean_mm": round(float(np.mean(cv_scores)), 4),
            "tail30_rmse_mm": round(float(np.sqrt(head.result.val_loss)), 4),
            "fold_results": [f.result.code for f in folds],
            "full_fit": plant_parameters(full.plant),
            "full_train_rmse_mm": round(score(full.plant, train), 4),
            "full_result": full.result.code,
            "test_rmse_mm": round(score(full.plant, test), 4),
            "test_rmse_exact_law_mm": round(score(fj.exact(full.plant), test), 4),
            "used_for_choice": ["cv_mean_mm"],
            "wall_s": round(time.perf_counter() - t0, 1),
        }

    idm_folds = [fj.emps.fit_emps_idm(h, fj.CoulombViscous).plant() for h in halves]
    emit(
        {
            "kind": "study",
            "group": "fit_settings",
            "setting": "IDM start (no open-loop fit)",
            "cv_rmse_mm": [round(score(idm_folds[0], halves[1]), 4), round(score(idm_folds[1], halves[0]), 4)],
            "test_rmse_mm": round(score(REFERENCE, test), 4),
        }
    )
    settings: list[tuple[str, dict[str, Any]]] = [
        ("default: continuation 1e-2 -> 1e-4, 150 steps", {}),
        ("continuation 1e-2 -> 1e-4, 300 steps", {"steps": 300}),
        ("eps 1e-2", {"eps": 1e-2, "steps": 200}),
        ("eps 1e-3", {"eps": 1e-3, "steps": 200}),
        ("eps 3e-4", {"eps": 3e-4, "steps": 200}),
        ("eps 1e-4", {"eps": 1e-4, "steps": 200}),
        ("continuation 1e-2 -> 1e-5", {"eps": fj.Continuation(1e-2, 1e-5, 3)}),
        ("segments 1 s, eps 1e-3", {"eps": 1e-3, "steps": 200, "loss": fj.emps.EMPSOpenLoopLoss(segment_length=1000)}),
        (
            "segments 2.5 s, eps 1e-3",
            {"eps": 1e-3, "steps": 200, "loss": fj.emps.EMPSOpenLoopLoss(segment_length=2500)},
        ),
        ("segments 5 s, eps 1e-3", {"eps": 1e-3, "steps": 200, "loss": fj.emps.EMPSOpenLoopLoss(segment_length=5000)}),
        ("freeze M", {"freeze": ("mass",)}),
        ("freeze M, Fv", {"freeze": ("mass", "friction.Fv")}),
    ]
    for label, options in settings:
        emit({"kind": "study", "group": "fit_settings", "setting": label, **cv(**options)})

    # 4. the profile of the training criterion along M (Fc, Fv, offset fitted for each M)
    idm = fj.emps.fit_emps_idm(train, fj.CoulombViscous)
    for mass in (82.0, 86.0, 90.0, 95.1089, 100.0):
        start = eqx.tree_at(lambda p: p.mass, idm.plant(), fj.Positive(mass))
        fitted = fj.emps.fit_emps_open_loop(train, start=start, freeze=("mass",), compute_std=False)
        emit(
            {
                "kind": "study",
                "group": "mass_profile",
                "M": mass,
                "train_rmse_mm": round(score(fitted.plant, train), 4),
                "test_rmse_mm": round(score(fitted.plant, test), 4),
                "params": plant_parameters(fitted.plant),
            }
        )


# --------------------------------------------------------------------------------------------------------------
# Do the two records describe the same axis? (diagnosis only: nothing here chooses a model)


def run_crossfile(train: fj.EMPSRecord, test: fj.EMPSRecord, laws: list[str], steps: int) -> None:
    """The plateau forces of both records (`fj.emps.emps_plateau_forces`: the mean drive force on each constant-velocity
    plateau, per quarter of the record), then each law fitted on each record and scored on both.

    The official protocol fits on `DATA_EMPS.mat` and scores on `DATA_EMPS_PULSES.mat`; fitting on the test file
    is not a model of this benchmark, only a measure of how far apart the two records are for a model class: a
    law fitted on one record scored on the other. Every line says `"used_for_choice": false`."""
    plateaus = {record.name: fj.emps.emps_plateau_forces(record) for record in (train, test)}
    # the test file's pulses (a 5 V square wave, ~1 s period) are in its drive force: the plateaus again from
    # the samples with the pulse off for at least 300 ms, to show the change is not the pulses'
    pulse = np.asarray(test.pulses) != 0
    recent = np.convolve(pulse.astype(float), np.ones(300))[: test.length] > 0
    pulse_off = fj.emps.emps_plateau_forces(test, where=~recent)
    for on_train, on_test, off in zip(plateaus[train.name], plateaus[test.name], pulse_off, strict=True):
        emit(
            {
                "kind": "plateau_force",
                "velocity_m_s": on_train.velocity,
                "train_force_N": round(on_train.force, 3),
                "test_force_N": round(on_test.force, 3),
                "test_minus_train_N": round(on_test.force - on_train.force, 3),
                "test_pulse_off_force_N": round(off.force, 3),
                "test_pulse_off_minus_train_N": round(off.force - on_train.force, 3),
                "test_pulse_off_samples": off.samples,
                "train_per_quarter_N": [round(f, 3) for f in on_train.force_per_part],
                "test_per_quarter_N": [round(f, 3) for f in on_test.force_per_part],
                "samples": [on_train.samples, on_test.samples],
            }
        )
    score = fj.emps.score_emps_open_loop
    fits: dict[tuple[str, bool, str], fj.EMPSPlant] = {}
    for name in laws:
        for asymmetric in (False, True):
            for fit_on in (train, test):
                t0 = time.perf_counter()
                fitted = fj.emps.fit_emps_open_loop(
                    fit_on, LAWS[name], asymmetric=asymmetric, steps=steps, compute_std=False
                )
                fits[(name, asymmetric, fit_on.name)] = fitted.plant
                emit(
                    {
                        "kind": "crossfile",
                        "name": law_name(name, asymmetric),
                        "fitted_on": fit_on.name,
                        "train_rmse_mm": round(score(fitted.plant, train), 4),
                        "test_rmse_mm": round(score(fitted.plant, test), 4),
                        "params": plant_parameters(fitted.plant),
                        "result": fitted.result.code,
                        "fit_s": round(time.perf_counter() - t0, 2),
                        "used_for_choice": False,
                    }
                )
    # the test file's friction, read off its plateaus: the train-fitted symmetric Coulomb + viscous model with its
    # Coulomb force raised by the mean change of the plateau force magnitudes and its offset moved by their mean
    # signed change (both from the data, no fit)
    changes = [b.force - a.force for a, b in zip(plateaus[train.name], plateaus[test.name], strict=True)]
    signs = np.sign([a.velocity for a in plateaus[train.name]])
    magnitude, offset = float(np.mean(signs * changes)), float(np.mean(changes))
    key = ("CoulombViscous", False, train.name)
    if key not in fits:
        fits[key] = fj.emps.fit_emps_open_loop(train, fj.CoulombViscous, steps=steps, compute_std=False).plant
    base = fj.exact(fits[key])
    p = fj.unwrap(base)
    shifted_plant = fj.EMPSPlant(
        p.mass, fj.CoulombViscous(Fc=p.friction.Fc + magnitude, Fv=p.friction.Fv, offset=p.friction.offset + offset)
    )
    emit(
        {
            "kind": "plateau_shift",
            "name": "CoulombViscous fitted on DATA_EMPS, Fc and offset moved by the plateau changes",
            "delta_Fc_N": round(magnitude, 3),
            "delta_offset_N": round(offset, 3),
            "train_rmse_mm": round(score(shifted_plant, train), 4),
            "test_rmse_mm": round(score(shifted_plant, test), 4),
            "unshifted_train_rmse_mm": round(score(base, train), 4),
            "unshifted_test_rmse_mm": round(score(base, test), 4),
            "used_for_choice": False,
        }
    )


# --------------------------------------------------------------------------------------------------------------
# Grey + black-box hybrids, ensembles, closed loop (training file only for every fit and choice)

HYBRID_VARIANTS = {
    "mlp(v,q)/free": {"inputs": ("v", "q"), "freeze_physics": False, "learning_rate": 3e-3},
    "mlp(v,q)/frozen": {"inputs": ("v", "q"), "freeze_physics": True, "learning_rate": 1e-2},
    "mlp(v)/free": {"inputs": ("v",), "freeze_physics": False, "learning_rate": 3e-3},
    "mlp(v,q,u)/free": {"inputs": ("v", "q", "u"), "freeze_physics": False, "learning_rate": 3e-3},
}
"""Residual inputs, physics free or frozen, Adam learning rate (1e-2 made the free fits jump at the start on the
70 % head of the training file; the frozen ones train only the network)."""


BGBM_CONFIGS = [(inputs, order) for inputs in (("force",), ("force", "qd"), ("qd",)) for order in (1, 2, 4)]
"""The BGBM error models tried per law: inputs (the paper's force; the grey box's simulated velocity) x order."""


def run_bgbm(
    train: fj.EMPSRecord,
    test: fj.EMPSRecord,
    members: dict[str, fj.EMPSPlant],
    configs: list[tuple[tuple[str, ...], int]],
) -> None:
    """Per law: the BGBM (emps-ensemble §3.2) error models of `configs`, each fitted by output error on the first
    70 % of the training file and scored on its last 30 %; the one with the lowest tail error is refitted on the
    whole training file and scored on the test file (`bgbm_choice`)."""
    for label, plant in members.items():
        best: tuple[float, tuple[str, ...], int] | None = None
        for inputs, order in configs:
            t0 = time.perf_counter()
            fitted = fj.emps.fit_emps_bgbm(train, plant, inputs=inputs, order=order, validation=0.3)
            fit_s = time.perf_counter() - t0
            emit(
                {
                    "kind": "bgbm",
                    "name": f"{label}+bgbm({','.join(inputs)};{order})",
                    "test_rmse_mm": round(fitted.model.score(test), 4),
                    "train_rmse_mm": round(fitted.model.score(train), 4),
                    "fit_s": round(fit_s, 2),
                    "val_tail30_rmse_mm": round(fitted.val_rmse_mm, 4),
                    "val_tail30_physics_mm": round(fitted.val_physics_mm, 4),
                    "head70_rmse_mm": round(fitted.train_rmse_mm, 4),
                    "result": fitted.result,
                    "used_for_choice": ["val_tail30_rmse_mm"],
                }
            )
            if best is None or fitted.val_rmse_mm < best[0]:
                best = (fitted.val_rmse_mm, inputs, order)
        if best is None:
            continue
        _, inputs, order = best
        t0 = time.perf_counter()
        final = fj.emps.fit_emps_bgbm(train, plant, inputs=inputs, order=order, validation=None)
        emit(
            {
                "kind": "bgbm_choice",
                "name": f"{label}+bgbm({','.join(inputs)};{order})",
                "by": "val_tail30_rmse_mm, then refitted on the whole training file",
                "test_rmse_mm": round(final.model.score(test), 4),
                "train_rmse_mm": round(final.train_rmse_mm, 4),
                "fit_s": round(time.perf_counter() - t0, 2),
                "physics_test_rmse_mm": round(fj.emps.score_emps_open_loop(plant, test), 4),
                "denominator": rounded(final.model.denominator, 6),
                "result": final.result,
            }
        )


def fit_members(train: fj.EMPSRecord, test: fj.EMPSRecord, laws: list[str], steps: int) -> dict[str, fj.EMPSPlant]:
    """The open-loop fits of `laws`, symmetric and asymmetric, one `member` line each."""
    members: dict[str, fj.EMPSPlant] = {}
    for name in laws:
        for asymmetric in (False, True):
            label = law_name(name, asymmetric)
            t0 = time.perf_counter()
            fitted = fj.emps.fit_emps_open_loop(
                train, LAWS[name], asymmetric=asymmetric, steps=steps, compute_std=False
            )
            fit_s = time.perf_counter() - t0
            members[label] = fitted.plant
            emit(
                {
                    "kind": "member",
                    "name": label,
                    "test_rmse_mm": round(fj.emps.score_emps_open_loop(fitted.plant, test), 4),
                    "train_rmse_mm": round(fj.emps.score_emps_open_loop(fitted.plant, train), 4),
                    "fit_s": round(fit_s, 2),
                }
            )
    return members


def law_name(name: str, asymmetric: bool) -> str:
    return f"{name}{'-asym' if asymmetric else ''}"


def run_hybrid(
    train: fj.EMPSRecord,
    test: fj.EMPSRecord,
    laws: list[str],
    steps: int,
    hybrid_steps: int,
    variants: list[str],
    width: int,
    bgbm_configs: list[tuple[tuple[str, ...], int]] = BGBM_CONFIGS,
) -> None:
    score = fj.emps.score_emps_open_loop
    members = fit_members(train, test, laws, steps)
    run_bgbm(train, test, members, bgbm_configs)
    hybrids: dict[str, fj.EMPSPlant] = {}
    for label, plant in members.items():
        best: tuple[float, str] | None = None
        for variant in variants:
            t0 = time.perf_counter()
            hybrid = fj.emps.fit_emps_hybrid(train, plant, steps=hybrid_steps, width=width, **HYBRID_VARIANTS[variant])
            fit_s = time.perf_counter() - t0
            val = hybrid.val_rmse_mm
            cut = int(round(0.7 * train.length))
            start_val = score(plant, fj.emps.split_emps_record(train, cut))
            key = f"{label}+{variant}"
            hybrids[key] = hybrid.plant
            emit(
                {
                    "kind": "hybrid",
                    "name": key,
                    "test_rmse_mm": round(score(hybrid.plant, test), 4),
                    "train_rmse_mm": round(score(hybrid.plant, train), 4),
                    "fit_s": round(fit_s, 2),
                    "val_tail30_rmse_mm": round(val, 4),
                    "val_tail30_physics_mm": round(start_val, 4),
                    "head70_rmse_mm": round(float(np.sqrt(hybrid.result.train_loss)), 4),
                    "adam_steps": hybrid_steps,
                    "width": width,
                    "result": hybrid.result.code,
                    "used_for_choice": ["val_tail30_rmse_mm"],
                }
            )
            if best is None or val < best[0]:
                best = (val, key)
        if best is not None:
            emit(
                {
                    "kind": "hybrid_choice",
                    "law": label,
                    "chosen": best[1],
                    "by": "val_tail30_rmse_mm",
                    "test_rmse_mm": round(score(hybrids[best[1]], test), 4),
                    "train_rmse_mm": round(score(hybrids[best[1]], train), 4),
                }
            )

    # ensembles of the simulated positions, weights fitted on the training file
    everything = {**members, **hybrids}
    positions_train = {k: np.asarray(fj.emps.predict_emps_open_loop(p, train).q) for k, p in everything.items()}
    positions_test = {k: np.asarray(fj.emps.predict_emps_open_loop(p, test).q) for k, p in everything.items()}
    pools = {"laws": list(members), "laws+hybrids": list(everything)}
    if hybrids:
        pools["hybrids"] = list(hybrids)
    for pool, keys in pools.items():
        plants = [everything[k] for k in keys]
        q_train = np.stack([positions_train[k] for k in keys])
        q_test = np.stack([positions_test[k] for k in keys])
        for method in ("average", "lstsq", "nonnegative", "press"):
            t0 = time.perf_counter()
            try:
                ens = fj.emps.fit_emps_ensemble(plants, train, method, positions=q_train)
            except ValueError as error:
                emit({"kind": "ensemble", "name": f"{pool}:{method}", "error": str(error)})
                continue
            fit_s = time.perf_counter() - t0
            chosen = list(ens.indices)
            emit(
                {
                    "kind": "ensemble",
                    "name": f"{pool}:{method}",
                    "combines": "simulated positions (emps-ensemble eq. 16)",
                    "test_rmse_mm": round(ens.ensemble.score(test, q_test[chosen]), 4),
                    "train_rmse_mm": round(ens.ensemble.score(train, q_train[chosen]), 4),
                    "fit_s": round(fit_s, 3),
                    "members": [keys[i] for i in chosen],
                    "weights": rounded(ens.ensemble.weights, 4),
                    "intercept_mm": round(1000 * float(ens.ensemble.intercept), 4),
                }
            )

    # closed loop (PD controller), relative errors [%] as the published model is scored
    for label, plant in {"reference (Janot et al. 2019)": REFERENCE, **everything}.items():
        on_train = fj.emps.emps_closed_loop_errors(plant, train)
        on_test = fj.emps.emps_closed_loop_errors(plant, test)
        emit(
            {
                "kind": "closed_loop",
                "name": label,
                **{f"train_{k}": round(v, 5) for k, v in on_train.items()},
                **{f"test_{k}": round(v, 5) for k, v in on_test.items()},
                "published_reference_position_pct": [0.013752, 0.0080248],
            }
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--laws", nargs="+", default=list(LAWS), choices=list(LAWS))
    parser.add_argument("--steps", type=int, default=150, help="Levenberg-Marquardt steps (over 3 stages)")
    parser.add_argument("--quick", action="store_true", help="60 steps per fit")
    parser.add_argument("--study", action="store_true", help="run the sensitivity study instead (~15 min)")
    parser.add_argument("--hybrid", action="store_true", help="grey + black-box hybrids, ensembles, closed loop")
    parser.add_argument("--bgbm", action="store_true", help="only the laws and their BGBM error models (~6 min)")
    parser.add_argument(
        "--crossfile", action="store_true", help="plateau forces of both records; each law fitted on each (~2 min)"
    )
    parser.add_argument("--hybrid-steps", type=int, default=200, help="Adam steps of each hybrid fit")
    parser.add_argument(
        "--variants", nargs="+", default=["mlp(v,q)/free", "mlp(v,q)/frozen"], choices=list(HYBRID_VARIANTS)
    )
    parser.add_argument("--width", type=int, default=16, help="hidden units of the residual network")
    parser.add_argument("--smoke", action="store_true", help="CI size of --hybrid: one law, short fits (< 90 s)")
    args = parser.parse_args()
    folder = data_dir() / "emps"
    train, test = fj.load_emps(folder / "DATA_EMPS.mat"), fj.load_emps(folder / "DATA_EMPS_PULSES.mat")
    t0 = time.perf_counter()
    if args.study:
        run_study(train, test)
    elif args.hybrid:
        if args.smoke:
            smoke_bgbm = [(("force",), 1), (("force", "qd"), 1)]
            run_hybrid(train, test, ["CoulombViscous"], 20, 20, ["mlp(v,q)/free", "mlp(v,q)/frozen"], 8, smoke_bgbm)
        else:
            run_hybrid(train, test, args.laws, args.steps, args.hybrid_steps, args.variants, args.width)
    elif args.crossfile:
        run_crossfile(train, test, args.laws, args.steps)
    elif args.bgbm:
        run_bgbm(train, test, fit_members(train, test, args.laws, args.steps), BGBM_CONFIGS)
    else:
        run_laws(train, test, args.laws, 60 if args.quick else args.steps)
    emit({"kind": "total", "wall_s": round(time.perf_counter() - t0, 1)})


if __name__ == "__main__":
    main()
