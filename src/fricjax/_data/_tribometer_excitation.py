"""The synthetic tribometer's excitation: the three friction regimes (pre-sliding, mixed, gross sliding) and the
displacement that visits them, an amplitude-modulated multi-sine from rest with its analytic velocity.

The amplitudes are given in units of the true model's breakaway displacement (`_tribometer_model`), so one regime
means the same for any model; `make_tribometer` (`_tribometer`) draws the excitation from its seed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# ---------------------------------------------------------------------------------------------------------------
# Regimes and the excitation


class _Regime(NamedTuple):
    low: float  # smallest displacement amplitude, in units of the breakaway displacement
    high: float  # largest displacement amplitude, same units
    minor: float  # amplitude of the fast component relative to the slow one (minor loops when > 1 / 3.7)
    description: str


REGIMES: dict[str, _Regime] = {
    "presliding": _Regime(
        0.02,
        0.6,
        0.35,
        "pre-sliding: displacement amplitude 0.02-0.6 x the breakaway displacement; the weakest element never "
        "slips, so there is no gross sliding and the peak force stays below the breakaway force",
    ),
    "mixed": _Regime(
        0.1,
        4.0,
        0.3,
        "mixed: displacement amplitude 0.1-4 x the breakaway displacement; pre-sliding stretches with "
        "excursions into gross sliding",
    ),
    "sliding": _Regime(
        15.0,
        30.0,
        0.12,
        "gross sliding: displacement amplitude 15-30 x the breakaway displacement; sticking only shortly "
        "after the velocity reversals",
    ),
}

# the carrier: a slow component, a fast one (minor loops) and a weak faster one (frequencies in Hz, x jitter)
_CARRIER_HZ = 4.0
_CARRIER_RATIOS = (1.0, 3.7, 8.3)
# the amplitude modulation: two slow sines with incommensurate frequencies [Hz]
_ENVELOPE_HZ = (0.45, 1.15)
_FADE_IN_S = 0.1


class _Excitation(NamedTuple):
    x: np.ndarray
    v: np.ndarray
    frequencies_hz: list[float]
    amplitudes: list[float]
    envelope_hz: list[float]
    envelope_m: tuple[float, float]


def _excitation(rng: np.random.Generator, t: np.ndarray, scale: float, regime: _Regime) -> _Excitation:
    """An amplitude-modulated multi-sine displacement [m] and its analytic velocity [m/s], from rest at t = 0.

    `x(t) = fade(t) * env(t) * m(t) / max|m|`, with `m` the sum of three sines (the slow carrier, a component
    3.7 x faster whose velocity exceeds the carrier's when `minor > 0.27`, so the velocity reverses inside a
    half-cycle and minor loops appear, and a weak one 8.3 x faster), `env` an amplitude modulation between
    `low` and `high` breakaway displacements built from two slow sines (so loops grow and shrink, with nested
    reversals: non-local memory), and `fade` a raised cosine over the first 0.1 s (the rig starts at rest).
    """
    jitter = rng.uniform(0.9, 1.1)
    freqs = [_CARRIER_HZ * jitter * r * (rng.uniform(0.97, 1.03) if i else 1.0) for i, r in enumerate(_CARRIER_RATIOS)]
    amps = [1.0, regime.minor, regime.minor / 4.0]
    phases = rng.uniform(0.0, 2.0 * np.pi, size=len(freqs))
    env_freqs = [f * rng.uniform(0.9, 1.1) for f in _ENVELOPE_HZ]
    env_phases = rng.uniform(0.0, 2.0 * np.pi, size=2)

    m = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in zip(amps, freqs, phases, strict=True))
    dm = sum(a * 2 * np.pi * f * np.cos(2 * np.pi * f * t + p) for a, f, p in zip(amps, freqs, phases, strict=True))
    peak = np.max(np.abs(m))
    m, dm = m / peak, dm / peak

    # e in [0, 1]: mean of two slow sines; squared so that small loops take more of the time
    u = 0.5 + 0.25 * sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(env_freqs, env_phases, strict=True))
    du = 0.25 * sum(2 * np.pi * f * np.cos(2 * np.pi * f * t + p) for f, p in zip(env_freqs, env_phases, strict=True))
    low, high = regime.low * scale, regime.high * scale
    env = low + (high - low) * u**2
    denv = (high - low) * 2.0 * u * du

    ramp = np.clip(t / _FADE_IN_S, 0.0, 1.0)
    fade = 0.5 * (1.0 - np.cos(np.pi * ramp))
    dfade = np.where(t < _FADE_IN_S, 0.5 * np.pi / _FADE_IN_S * np.sin(np.pi * ramp), 0.0)

    x = fade * env * m
    v = dfade * env * m + fade * denv * m + fade * env * dm
    return _Excitation(x, v, freqs, amps, env_freqs, (low, high))
