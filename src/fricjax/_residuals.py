"""Residual analysis of a prediction, as system identification judges a model (MATLAB's `resid`; Ljung, System
Identification, 2nd ed. 1999, §16.6): the autocorrelation of the residual `e = F - F_hat` and its cross-correlation
with the input, each with the band a white residual independent of the input stays inside with the given confidence.

An output-error (free-run) model has no noise model, so its residual need not be white (it carries the sensor's
coloured noise and whatever the model lacks, as a slow error); what it must not be is correlated with past inputs:
a cross-correlation outside the band at positive lags says the model misses a dynamic of the input, at negative
lags that the input depends on past residuals (feedback in the data).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from jaxtyping import ArrayLike

__all__ = ["ResidualAnalysis", "residual_analysis"]

_Z = {0.9: 1.6449, 0.95: 1.9600, 0.99: 2.5758, 0.999: 3.2905}  # two-sided normal quantiles


@dataclasses.dataclass(frozen=True)
class ResidualAnalysis:
    """The residual's autocorrelation `autocorrelation[k]` at lags `k = 0..max_lag` (1 at lag 0) and its
    cross-correlation with the input, `cross_correlation[j]` = corr(u(t), e(t + tau)) at `cross_lags[j] = tau` from
    `-max_lag` to `max_lag`; `band` the half-width of the autocorrelation's confidence band (`z / sqrt(samples)`, that
    of a white residual); `cross_band` the cross-correlation's, `z sqrt(P / samples)` with `P = sum_k r_e(k) r_u(k)`
    over `|k| <= max_lag` (Ljung 1999, eq. 16.60: a residual that is not white but independent of the input stays
    inside it; 1 when either is white); `confidence`; `samples` the residual's length; `input_name` the input's name;
    `rms` the residual's RMS [N]."""

    autocorrelation: np.ndarray
    cross_lags: np.ndarray
    cross_correlation: np.ndarray
    band: float
    cross_band: float
    confidence: float
    samples: int
    input_name: str
    rms: float

    @property
    def lags(self) -> np.ndarray:
        """The autocorrelation's lags, `0..max_lag` (samples)."""
        return np.arange(self.autocorrelation.size)

    def _passes(self, correlations: np.ndarray, band: float) -> bool:
        """Whether `correlations` leave the band no more than chance lets a white, independent residual: at most the
        expected count of lags plus two standard deviations of it, and none by more than half the band again (a
        lag at 1.5 times the band, 3.9 sigma for 99 %, is no chance excursion)."""
        expected = (1.0 - self.confidence) * correlations.size
        allowed = int(math.ceil(expected + 2.0 * math.sqrt(max(expected, 1e-12))))
        magnitude = np.abs(correlations)
        return int(np.sum(magnitude > band)) <= allowed and float(magnitude.max(initial=0.0)) <= 1.5 * band

    @property
    def outside_autocorrelation(self) -> int:
        """Lags `1..max_lag` at which the autocorrelation leaves the band."""
        return int(np.sum(np.abs(self.autocorrelation[1:]) > self.band))

    @property
    def outside_cross_correlation(self) -> int:
        """Lags at which the cross-correlation with the input leaves the band."""
        return int(np.sum(np.abs(self.cross_correlation) > self.cross_band))

    @property
    def white(self) -> bool:
        """Whether the residual passes as white: no more lags outside the band than chance allows."""
        return self._passes(self.autocorrelation[1:], self.band)

    @property
    def independent(self) -> bool:
        """Whether the residual passes as uncorrelated with the input (all lags, negative ones included)."""
        return self._passes(self.cross_correlation, self.cross_band)

    def verdict(self) -> str:
        """One line: whiteness and independence from the input, with the largest correlations."""
        pct = f"{100 * self.confidence:g} %"
        auto = np.abs(self.autocorrelation[1:]).max(initial=0.0)
        cross = np.abs(self.cross_correlation).max(initial=0.0)
        worst = int(self.cross_lags[int(np.argmax(np.abs(self.cross_correlation)))])
        white = "white" if self.white else "not white"
        independent = "independent of" if self.independent else "correlated with"
        return (
            f"residual {white} ({self.outside_autocorrelation} of {self.autocorrelation.size - 1} lags outside the "
            f"{pct} band, largest |r| {auto:.2f}); {independent} {self.input_name} "
            f"({self.outside_cross_correlation} of {self.cross_correlation.size} lags outside, largest |r| {cross:.2f} "
            f"at lag {worst}); RMS {self.rms:.4g} N"
        )


def residual_analysis(
    measured: ArrayLike,
    predicted: ArrayLike,
    input: ArrayLike,
    *,
    max_lag: int = 25,
    confidence: float = 0.99,
    input_name: str = "the input",
) -> ResidualAnalysis:
    """Correlation analysis of the residual `e = measured - predicted` [N]: its autocorrelation at lags `0..max_lag`
    and its cross-correlation with `input` (the velocity or displacement the model was driven by, one value per
    sample) at lags `-max_lag..max_lag`, with the `confidence` bands (0.9, 0.95, 0.99 or 0.999) of a white residual,
    `z / sqrt(N)`, and of a residual independent of the input, widened by the two signals' own correlations
    (`ResidualAnalysis.cross_band`; Ljung 1999, §16.6; MATLAB's `resid`).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> rng = np.random.default_rng(0)
    >>> v = rng.standard_normal(5000)
    >>> white = fj.residual_analysis(np.tanh(v) + 0.1 * rng.standard_normal(5000), np.tanh(v), v)
    >>> white.white, white.independent
    (True, True)
    >>> missed = fj.residual_analysis(np.tanh(v) + 0.2 * np.roll(v, 1), np.tanh(v), v)  # a delayed input term missed
    >>> missed.independent, int(missed.cross_lags[np.argmax(np.abs(missed.cross_correlation))])
    (False, 1)
    ```
    """
    measured = np.asarray(measured, np.float64).reshape(-1)
    predicted = np.asarray(predicted, np.float64).reshape(-1)
    u = np.asarray(input, np.float64).reshape(-1)
    if not (measured.size == predicted.size == u.size):
        raise ValueError(
            f"residual_analysis: measured, predicted and input need one value per sample each; got {measured.size}, "
            f"{predicted.size} and {u.size}."
        )
    if confidence not in _Z:
        raise ValueError(f"residual_analysis: confidence must be one of {sorted(_Z)}, got {confidence!r}.")
    if isinstance(max_lag, bool) or not isinstance(max_lag, (int, np.integer)) or not 1 <= max_lag < measured.size // 2:
        raise ValueError(
            f"residual_analysis: max_lag must be a whole number from 1 to half the record ({measured.size // 2 - 1}), "
            f"got {max_lag!r}."
        )
    if not (np.all(np.isfinite(measured)) and np.all(np.isfinite(predicted)) and np.all(np.isfinite(u))):
        raise ValueError("residual_analysis: the measured force, the prediction and the input must be finite.")
    e = measured - predicted
    n = e.size
    e_c, u_c = e - e.mean(), u - u.mean()
    e_scale, u_scale = float(np.sqrt(np.mean(e_c**2))), float(np.sqrt(np.mean(u_c**2)))
    if not e_scale > 0 or not u_scale > 0:
        raise ValueError("residual_analysis: the residual and the input must vary (a constant has no correlation).")
    e_n, u_n = e_c / e_scale, u_c / u_scale
    auto = np.array([np.dot(e_n[: n - k], e_n[k:]) / n for k in range(max_lag + 1)])
    input_auto = np.array([np.dot(u_n[: n - k], u_n[k:]) / n for k in range(max_lag + 1)])
    spread = max(float(auto[0] * input_auto[0] + 2.0 * np.dot(auto[1:], input_auto[1:])), 1.0)
    lags = np.arange(-max_lag, max_lag + 1)
    cross = np.array(
        [np.dot(u_n[: n - t], e_n[t:]) / n if t >= 0 else np.dot(u_n[-t:], e_n[: n + t]) / n for t in lags]
    )
    return ResidualAnalysis(
        autocorrelation=auto,
        cross_lags=lags,
        cross_correlation=cross,
        band=_Z[confidence] / math.sqrt(n),
        cross_band=_Z[confidence] * math.sqrt(spread / n),
        confidence=confidence,
        samples=n,
        input_name=input_name,
        rms=float(np.sqrt(np.mean(e**2))),
    )
