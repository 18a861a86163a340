"""A synthetic tribometer: friction data in the pre-sliding, mixed and gross-sliding regimes, with sensor effects.

It imitates the KU Leuven tribometer of parlitz2004 §II-B and worden2007 §2: a Lorentz actuator imposes a
displacement on the moving block, a laser interferometer measures it (quantised, noisy), and a piezoelectric
force cell measures the friction force (noisy, with a slow trend from charge leakage). The friction force is
simulated by a known ("true") fricjax model from the *true* displacement, so a fitted model can be scored
against the noise-free force and its parameters against the true ones.

This module is the sensor model and the record: `make_tribometer` adds the sensor effects to the true force and
displacement and assembles `TribometerData` (splits, truth, data card). The excitation and the regimes are in
`_tribometer_excitation`, the true model and its scales in `_tribometer_model`.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._inputs import Motion
from .._models._base import AbstractFrictionModel
from .._simulate import simulate
from .._validation import nonnegative_int
from ._differentiators import al_alaoui_derivative
from ._memory import memory_problem
from ._record import FrictionData
from ._tribometer_excitation import REGIMES, _excitation
from ._tribometer_model import (
    _breakaway_displacement,
    _breakaway_force,
    _offset,
    default_tribometer_model,
    model_parameters,
    slipping_elements,
)

# default sensor effects
_FORCE_NOISE_REL = 0.0075  # of the clean force's peak-to-peak range
_DRIFT_REL = -0.03  # total drift at the end of the record, of the clean force's peak-to-peak range
_POSITION_QUANTISATION = 1e-9  # m: a laser interferometer's resolution (Renishaw, parlitz2004 §II-B)
_POSITION_NOISE_STD = 1e-9  # m: vibration and air-path noise of the interferometer
# memory per sample while a record is generated (the signals, the simulation, the splits): 190-300 bytes measured
# (peak resident memory, 1e5-1e6 samples, the default model); a request that cannot fit is refused before allocating
_BYTES_PER_SAMPLE = 400


# ---------------------------------------------------------------------------------------------------------------
# The data set


class TribometerData(eqx.Module):
    """A synthetic tribometer record, its train / validation / test splits, the truth and a data card.

    **Fields:**

    - `train`, `validation`, `test`: consecutive parts of `full` (`FrictionData`).
    - `full`: the whole measured record: the measured (quantised, noisy) displacement, the velocity derived
      from it, and the measured (noisy, drifting) force.
    - `true_model`: the model that made the force (as passed, or the default exact GMS).
    - `true_motion`: the true displacement and its analytic velocity (what the force was simulated from).
    - `clean_force`: the noise- and drift-free force [N], shape `(T,)`.
    - `sensor_force`: what the force cell reads without its white noise: the clean force plus drift and
      offset [N]. Its error against `full.force` is the noise floor no fitted model can beat.
    - `card`: the data card, a JSON-serialisable dict (regime, seed, sizes, sample rate, excitation, sensor
      effects, the true parameters, the fraction of samples with every element sticking, peak / breakaway
      force, ...). `card_text()` prints it; `save_card(path)` writes it as JSON.
    """

    train: FrictionData
    validation: FrictionData
    test: FrictionData
    full: FrictionData
    true_model: AbstractFrictionModel
    true_motion: Motion
    clean_force: Float[Array, "T"]
    sensor_force: Float[Array, "T"]
    card: dict[str, Any]

    def card_text(self) -> str:
        """The data card as indented `key: value` lines."""
        return "\n".join(_card_lines(self.card, 0))

    def save_card(self, path: str | os.PathLike[str]) -> pathlib.Path:
        """Write the data card as JSON to `path`; returns the path."""
        path = pathlib.Path(path)
        path.write_text(json.dumps(self.card, indent=2) + "\n")
        return path


def _card_lines(card: dict[str, Any], indent: int) -> list[str]:
    lines = []
    for key, value in card.items():
        if isinstance(value, dict):
            lines.append(" " * indent + f"{key}:")
            lines.extend(_card_lines(value, indent + 2))
        else:
            lines.append(" " * indent + f"{key}: {_fmt(value)}")
    return lines


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def make_tribometer(
    regime: str,
    *,
    seed: int = 0,
    model: AbstractFrictionModel | None = None,
    duration: float = 4.0,
    sample_rate: float = 2000.0,
    noise: bool = True,
    force_noise_std: float | None = None,
    drift: float | None = None,
    drift_time_constant: float | None = None,
    force_offset: float = 0.0,
    position_quantisation: float | None = None,
    position_noise_std: float | None = None,
    velocity: str = "central",
    breakaway_displacement: float | None = None,
    splits: Sequence[float] = (0.6, 0.8),
) -> TribometerData:
    """Synthetic tribometer data in a chosen friction regime, with the sensor effects of a real rig.

    The rig (parlitz2004 §II-B, Figs. 2-5; worden2007 §2): an actuator imposes a displacement `x(t)` on the
    moving block; the friction force is simulated by the true `model` from the **true** displacement (and its
    analytic velocity), then measured by a piezoelectric force cell, while `x` is measured by a laser
    interferometer. The record carries what the sensors give:

    - **measured displacement** = the true one plus white position noise (`position_noise_std`, default 1 nm,
      vibration and air-path noise), quantised to the interferometer resolution (`position_quantisation`,
      default 1 nm, the resolution of the Renishaw interferometer of the Leuven rig); worden2007 §2 reports
      quantisation noise "substantial" at pre-sliding amplitudes.
    - **velocity** derived from the measured displacement: `velocity="central"` (default) by central
      differences (`fj.Motion.from_position`), `"al-alaoui"` by the zero-phase Al-Alaoui differentiator
      (`fj.al_alaoui_derivative`, worden2007 §6).
    - **measured force** = clean force + white noise (`force_noise_std`, default 0.75 % of the clean force's
      peak-to-peak range) + a slow drift from charge leakage of the piezo force cell (parlitz2004 §II-B, the
      "slow trend" of Fig. 5, removed there by linear detrending): `drift * (1 - exp(-t / tau)) /
      (1 - exp(-T / tau))`, reaching `drift` [N] (default -3 % of the peak-to-peak range) at the end of the
      record, with `tau = drift_time_constant` (default: the record's duration, a curved trend between a linear
      and a saturating one).
    - **force-cell offset** `force_offset` [N] (default 0): the cell is not zeroed between records, so a
      record may start at a non-zero reading at rest.

    The excitation is an amplitude-modulated multi-sine (the periodic trajectories the rig can always impose,
    parlitz2004 §II-B): a slow carrier (about 4 Hz) with a faster component that reverses the velocity inside
    a half-cycle (minor loops) and a slow modulation of the amplitude, so loops of many sizes, nested
    reversals and wiped-out inner loops (non-local memory) appear, as in the profiles of parlitz2004 Figs. 4-5.
    The phases and frequencies (±10 %) are drawn from `seed`. The amplitude is set relative to the true model's
    breakaway displacement `x_b` (GMS: `max_i alpha_i Fs / k_i`, 10 um for the default model):

    - `"presliding"`: 0.02-0.6 `x_b`: no gross sliding; most samples have every element sticking; the peak
      force stays well below the breakaway force `Fs`.
    - `"mixed"`: 0.1-4 `x_b`: pre-sliding stretches and excursions into gross sliding.
    - `"sliding"`: 15-30 `x_b`: gross sliding, sticking only just after the velocity reversals.

    The default true model is `default_tribometer_model()`: an exact GMS with N = 4 elements and an exponential
    Stribeck curve (`Fc = 1 N`, `Fs = 1.4 N`, `vs = 1 mm/s`, `k = 1.4e5 ... 5.6e4 N/m`, `sigma2 = 10 N·s/m`).

    The default size, 4 s at 2 kHz (8000 samples; 4800 for training), keeps a fit of a handful of models on the
    training split within minutes on a laptop CPU. The data are deterministic for a seed (NumPy `Generator`s
    spawned from `seed`: the excitation, the force noise and the position noise each have their own stream, so
    switching one effect off leaves the others unchanged).

    **Arguments:**

    - `regime`: `"presliding"`, `"mixed"` or `"sliding"`.
    - `seed`: non-negative integer seed.
    - `model`: the true friction model (any fricjax model; default `default_tribometer_model()`). It is used as
      given: pass `fj.exact(model)` for the exact equations.
    - `duration`: record length [s]; `sample_rate`: [Hz] (the record has `round(duration * sample_rate)`
      samples, at least 100).
    - `noise`: `False` switches every sensor effect off (the measured force is the clean force, the measured
      displacement the true one); the effect arguments must then be left at `None` or 0.
    - `force_noise_std` [N], `drift` [N, signed], `drift_time_constant` [s], `force_offset` [N, signed],
      `position_quantisation` [m],
      `position_noise_std` [m]: the sensor effects (`None`: the defaults above; 0 switches one off).
    - `velocity`: `"central"` or `"al-alaoui"`, how the velocity is derived from the measured displacement.
    - `breakaway_displacement`: the displacement scale `x_b` [m] of the regimes; default from the model (GMS,
      Maxwell-slip, LuGre, Dahl; required for other models).
    - `splits`: the train / validation / test boundaries as two increasing fractions (default 60 / 20 / 20 %).

    **Returns:** a `TribometerData` (`train`, `validation`, `test`, `full`, `true_model`, `true_motion`,
    `clean_force`, `card`).

    ```python
    >>> import fricjax as fj
    >>> data = fj.make_tribometer("presliding", seed=0)
    >>> data.train.length, data.validation.length, data.test.length
    (4800, 1600, 1600)
    >>> data.card["sticking"]["all_sticking_fraction"] > 0.5
    True
    ```
    """
    if not isinstance(regime, str) or regime not in REGIMES:
        raise ValueError(
            f"make_tribometer: unknown `regime` {regime!r}; choose one of {', '.join(map(repr, REGIMES))}."
        )
    spec = REGIMES[regime]
    seed = nonnegative_int(seed, "seed", "make_tribometer")
    if model is None:
        model = default_tribometer_model()
    elif not isinstance(model, AbstractFrictionModel):
        raise TypeError(f"make_tribometer: `model` must be a fricjax friction model, got {type(model).__name__}.")
    duration = _positive("duration", duration, "s")
    sample_rate = _positive("sample_rate", sample_rate, "Hz")
    length = int(round(duration * sample_rate))
    if length < 100:
        raise ValueError(
            f"make_tribometer: `duration * sample_rate` gives {length} samples; at least 100 are needed "
            "(lengthen `duration` or raise `sample_rate`)."
        )
    problem = memory_problem(length * _BYTES_PER_SAMPLE)
    if problem:
        raise ValueError(
            f"make_tribometer: `duration` {duration:g} s at `sample_rate` {sample_rate:g} Hz gives {length} samples, "
            f"which need {problem}; shorten `duration` or lower `sample_rate`."
        )
    if not isinstance(noise, bool):
        raise TypeError(f"make_tribometer: `noise` must be True or False, got {noise!r}.")
    effects = {
        "force_noise_std": force_noise_std,
        "drift": drift,
        "drift_time_constant": drift_time_constant,
        "position_quantisation": position_quantisation,
        "position_noise_std": position_noise_std,
        "force_offset": force_offset,
    }
    for name, value in effects.items():
        if value is None:
            continue
        number = _finite(name, value)
        if name not in ("drift", "force_offset") and (number < 0 or (name == "drift_time_constant" and number == 0)):
            bound = "> 0" if name == "drift_time_constant" else ">= 0"
            raise ValueError(f"make_tribometer: `{name}` must be {bound}, got {value!r}.")
        if not noise and number != 0 and name != "drift_time_constant":
            raise ValueError(
                f"make_tribometer: `noise=False` switches every sensor effect off, but `{name}={value!r}` was "
                "given; pass noise=True to use it, or drop the argument."
            )
    if velocity not in ("central", "al-alaoui"):
        raise ValueError(f"make_tribometer: `velocity` must be 'central' or 'al-alaoui', got {velocity!r}.")
    splits = _check_splits(splits, length)
    if breakaway_displacement is None:
        x_b = _breakaway_displacement(model)
    else:
        x_b = _positive("breakaway_displacement", breakaway_displacement, "m")

    dt = 1.0 / sample_rate
    t = np.arange(length) * dt
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(3)]
    excitation = _excitation(streams[0], t, x_b, spec)

    # the truth: force from the true displacement and its analytic velocity
    true_motion = Motion(x=excitation.x, v=excitation.v, dt=dt)
    clean = np.asarray(simulate(model, true_motion))
    if not np.all(np.isfinite(clean)):
        raise ValueError(
            f"make_tribometer: the simulated force of {type(model).__name__} is not finite; check the model's "
            "parameters."
        )
    force_range = float(np.ptp(clean))

    # sensor effects
    if noise:
        force_std = _FORCE_NOISE_REL * force_range if force_noise_std is None else float(force_noise_std)
        drift_n = _DRIFT_REL * force_range if drift is None else float(drift)
        tau = duration if drift_time_constant is None else float(drift_time_constant)
        quantum = _POSITION_QUANTISATION if position_quantisation is None else float(position_quantisation)
        x_std = _POSITION_NOISE_STD if position_noise_std is None else float(position_noise_std)
    else:
        force_std = drift_n = quantum = x_std = 0.0
        tau = duration if drift_time_constant is None else float(drift_time_constant)
    t_end = t[-1] if t[-1] > 0 else dt
    drift_signal = drift_n * (-np.expm1(-t / tau)) / (-math.expm1(-t_end / tau))
    offset_n = float(force_offset) if noise else 0.0
    sensor = clean + drift_signal + offset_n  # what the cell reads without noise: the noise floor's reference
    force = sensor + force_std * streams[1].standard_normal(length)
    x_meas = excitation.x + x_std * streams[2].standard_normal(length)
    if quantum > 0:
        x_meas = quantum * np.round(x_meas / quantum)
    if not noise:
        force, x_meas, sensor = clean.copy(), excitation.x.copy(), clean.copy()
    if velocity == "central":
        motion = Motion.from_position(x_meas, dt)
    else:
        motion = Motion(x=x_meas, v=al_alaoui_derivative(x_meas, dt, zero_phase=True), dt=dt)
    full = FrictionData(motion, force)
    train, validation, test = full.split(*splits)

    # regime statistics from the true model's state
    edges = [0, *[int(round(s * length)) for s in splits], length]
    slipping = slipping_elements(model, true_motion)
    sticking: dict[str, Any]
    if slipping is None:
        sticking = {
            "all_sticking_fraction": None,
            "gross_sliding_fraction": None,
            "note": f"{type(model).__name__} has no stick/slip elements",
        }
    else:
        all_stick = ~np.any(slipping, axis=1)
        all_slip = np.all(slipping, axis=1)
        sticking = {
            "all_sticking_fraction": float(np.mean(all_stick)),
            "gross_sliding_fraction": float(np.mean(all_slip)),
            "per_element_slipping_fraction": [float(f) for f in np.mean(slipping, axis=0)],
            "all_sticking_fraction_by_split": {
                name: float(np.mean(all_stick[a:b]))
                for name, a, b in zip(("train", "validation", "test"), edges[:-1], edges[1:], strict=True)
            },
        }
    f_break = _breakaway_force(model)
    peak = float(np.max(np.abs(clean - _offset(model))))
    card: dict[str, Any] = {
        "regime": regime,
        "description": spec.description,
        "seed": int(seed),
        "model": type(model).__name__,
        "samples": {"full": length, "train": train.length, "validation": validation.length, "test": test.length},
        "split_edges": edges,
        "sample_rate_hz": sample_rate,
        "dt_s": dt,
        "duration_s": length * dt,
        "excitation": {
            "kind": "amplitude-modulated multi-sine from rest (raised-cosine fade-in over 0.1 s)",
            "frequencies_hz": [round(f, 6) for f in excitation.frequencies_hz],
            "relative_amplitudes": excitation.amplitudes,
            "envelope_frequencies_hz": [round(f, 6) for f in excitation.envelope_hz],
            "amplitude_range_m": list(excitation.envelope_m),
            "amplitude_range_over_breakaway_displacement": [spec.low, spec.high],
            "peak_displacement_m": float(np.max(np.abs(excitation.x))),
            "peak_velocity_m_per_s": float(np.max(np.abs(excitation.v))),
        },
        "breakaway_displacement_m": x_b,
        "breakaway_force_N": f_break,
        "peak_force_N": peak,
        "peak_over_breakaway_force": None if f_break is None else peak / f_break,
        "force_range_N": force_range,
        "sticking": sticking,
        "sensor": {
            "noise": noise,
            "force_noise_std_N": force_std,
            "force_noise_over_range": force_std / force_range if force_range > 0 else None,
            "drift_N": drift_n,
            "drift_time_constant_s": tau,
            "force_offset_N": offset_n,
            "drift_model": "drift * (1 - exp(-t/tau)) / (1 - exp(-T/tau)) (charge leakage of the piezo force cell)",
            "position_quantisation_m": quantum,
            "position_noise_std_m": x_std,
            "velocity": "central differences of the measured displacement (fj.Motion.from_position)"
            if velocity == "central"
            else "zero-phase Al-Alaoui differentiator of the measured displacement (fj.al_alaoui_derivative)",
        },
        "model_parameters": model_parameters(model),
    }
    json.dumps(card)  # the card must stay JSON-serialisable
    return TribometerData(
        train=train,
        validation=validation,
        test=test,
        full=full,
        true_model=model,
        true_motion=true_motion,
        clean_force=jnp.asarray(clean),
        sensor_force=jnp.asarray(sensor),
        card=card,
    )


def _positive(name: str, value: Any, unit: str) -> float:
    number = _finite(name, value)
    if number <= 0:
        raise ValueError(f"make_tribometer: `{name}` must be a positive number in {unit}, got {value!r}.")
    return number


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise TypeError(f"make_tribometer: `{name}` must be a number, got {value!r}.")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"make_tribometer: `{name}` must be a number, got {value!r}.") from None
    if not math.isfinite(number):
        raise ValueError(f"make_tribometer: `{name}` must be finite, got {value!r}.")
    return number


def _check_splits(splits: Any, length: int) -> tuple[float, float]:
    try:
        points = tuple(float(s) for s in splits)
    except (TypeError, ValueError):
        raise TypeError(
            f"make_tribometer: `splits` must be two increasing fractions, e.g. (0.6, 0.8), got {splits!r}."
        ) from None
    if len(points) != 2 or not 0 < points[0] < points[1] < 1:
        raise ValueError(
            f"make_tribometer: `splits` must be two increasing fractions in (0, 1) (train / validation / test "
            f"boundaries), e.g. (0.6, 0.8), got {splits!r}."
        )
    edges = [0, *[int(round(p * length)) for p in points], length]
    if any(b <= a for a, b in zip(edges[:-1], edges[1:], strict=True)):
        raise ValueError(
            f"make_tribometer: `splits` {splits!r} leave an empty part of the {length}-sample record; move them apart."
        )
    return points
