"""Signal preprocessing for identification: zero-phase filtering, differentiation, decimation, detrending and
normalisation.

These run once, on concrete data, before any model is fitted, so they are NumPy / SciPy functions (not jitted)
that return NumPy arrays. Their defaults follow the MATLAB conventions of the EMPS reference scripts (Janot,
Gautier & Brunot 2019, *Data Set and Reference Models of EMPS*, §3.1-3.4): `butter_filtfilt` pads like MATLAB's
`filtfilt`, and `decimate` is MATLAB's `decimate` (Chebyshev type I anti-alias filter run forwards and backwards,
the kept samples aligned on the *last* sample), which reproduces the published IDIM-LS figures to every printed
digit. `scipy.signal.decimate` differs in both respects (it pads more and keeps the *first* sample); see
`decimate` for the size of the difference on EMPS.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any, Literal

import equinox as eqx
import numpy as np
import scipy.signal as ss
from jaxtyping import ArrayLike

from .._metrics import numpy_std
from .._validation import is_integer, nonnegative_int, positive_int


def _as_signal(signal: ArrayLike, name: str, *, axis: int = -1, min_length: int = 1) -> np.ndarray:
    """`signal` as a floating NumPy array, checked finite and long enough along `axis`."""
    try:
        array = np.asarray(signal)
    except Exception as error:  # pragma: no cover - exotic inputs
        raise TypeError(f"`{name}` must be an array of numbers, got {type(signal).__name__}.") from error
    if array.dtype == object or not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise TypeError(f"`{name}` must be an array of numbers, got dtype {array.dtype}.")
    if not np.issubdtype(array.dtype, np.floating):
        array = array.astype(np.float64)
    if array.ndim == 0:
        raise ValueError(f"`{name}` must be a signal with a time axis, got a scalar.")
    try:
        length = array.shape[axis]
    except IndexError:
        raise ValueError(f"`axis={axis}` is out of range for `{name}` of shape {array.shape}.") from None
    if length < min_length:
        raise ValueError(
            f"`{name}` has {length} samples along axis {axis} but at least {min_length} are needed; "
            "give a longer record (or lower the filter order / decimation factor)."
        )
    if not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array.reshape(-1)))[0])
        raise ValueError(
            f"`{name}` contains NaN or inf (first at flat index {bad}); clean or interpolate the record first."
        )
    return array


def _positive_scalar(value: Any, name: str, unit: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"`{name}` must be a number in {unit}, got {value!r}.") from None
    if not (np.isfinite(number) and number > 0):
        raise ValueError(f"`{name}` must be a positive, finite number in {unit}, got {value!r}.")
    return number


def _positive_int(value: Any, name: str, where: str = "") -> int:
    """`positive_int`, except that a value that is no integer at all is a TypeError here, as for the signals of
    these NumPy functions. (`where` is left out by the EMPS IDM protocol.)"""
    try:
        return positive_int(value, name, where)
    except ValueError as error:
        if is_integer(value):
            raise
        raise TypeError(str(error)) from None


def butter_filtfilt(
    signal: ArrayLike,
    dt: float,
    cutoff_hz: float,
    order: int = 4,
    *,
    axis: int = -1,
    padlen: int | None = None,
) -> np.ndarray:
    """Zero-phase low-pass Butterworth filtering: the filter is run forwards and then backwards.

    `scipy.signal.butter(order, cutoff_hz / f_nyquist)` applied with `scipy.signal.filtfilt`. The two passes
    cancel the phase, so the output has no lag (the EMPS description §3.1: "applied in both forward and reverse
    directions to avoid lag introduction"); the magnitude response is the Butterworth one squared (-6 dB at
    `cutoff_hz`). The EMPS reference filters the motor position with `order=4`, `cutoff_hz=100` at 1 kHz.

    **Arguments:**

    - `signal`: the signal, time along `axis` (any units; the output has the same units).
    - `dt`: sample time [s] (> 0).
    - `cutoff_hz`: cut-off frequency [Hz], `0 < cutoff_hz < 1 / (2 dt)` (the Nyquist frequency).
    - `order`: filter order (>= 1).
    - `axis`: the time axis.
    - `padlen`: samples of odd reflection added at each end before filtering. Default `3 * order`, the
      padding of MATLAB's `filtfilt` (SciPy's own default, `3 * (order + 1)`, changes the few samples
      nearest each end). The signal must be longer than `padlen`.

    **Returns:** the filtered signal, same shape, as a NumPy array.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> t = np.arange(2000) * 1e-3
    >>> y = fj.butter_filtfilt(np.sin(2 * np.pi * 5 * t) + 0.1 * np.sin(2 * np.pi * 300 * t), 1e-3, 100.0)
    >>> bool(np.max(np.abs(y - np.sin(2 * np.pi * 5 * t))[100:-100]) < 1e-3)
    True
    ```
    """
    dt = _positive_scalar(dt, "dt", "seconds")
    cutoff_hz = _positive_scalar(cutoff_hz, "cutoff_hz", "Hz")
    order = _positive_int(order, "order", "butter_filtfilt")
    nyquist = 0.5 / dt
    if cutoff_hz >= nyquist:
        raise ValueError(
            f"`cutoff_hz` = {cutoff_hz} Hz is at or above the Nyquist frequency 1/(2 dt) = {nyquist} Hz; "
            "choose a lower cut-off."
        )
    padlen = 3 * order if padlen is None else nonnegative_int(padlen, "padlen", "butter_filtfilt")
    x = _as_signal(signal, "signal", axis=axis, min_length=padlen + 1)
    b, a = ss.butter(order, cutoff_hz / nyquist)
    return ss.filtfilt(b, a, x, axis=axis, padtype="odd", padlen=padlen)


def central_difference(signal: ArrayLike, dt: float, *, axis: int = -1) -> np.ndarray:
    """Derivative by central differences, one-sided at the two ends.

    `y'_k = (y_{k+1} - y_{k-1}) / (2 dt)` inside, `(y_1 - y_0) / dt` and `(y_{T-1} - y_{T-2}) / dt` at the ends:
    `np.gradient(signal, axis=axis) / dt`, the same as the EMPS reference's `diffcent`. Exact for quadratics
    inside the record (second order), first order at the ends.

    **Arguments:** `signal` (time along `axis`, at least 2 samples); `dt` sample time [s] (> 0); `axis`.

    **Returns:** the derivative, same shape, in units of `signal` per second.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> fj.central_difference(np.array([0.0, 1.0, 4.0, 9.0]), 1.0)
    array([1., 2., 4., 5.])
    ```
    """
    dt = _positive_scalar(dt, "dt", "seconds")
    x = _as_signal(signal, "signal", axis=axis, min_length=2)
    return np.gradient(x, axis=axis) / dt


@functools.lru_cache(maxsize=32)
def _decimation_filter(factor: int, order: int, ripple_db: float) -> tuple[np.ndarray, np.ndarray]:
    """MATLAB `decimate`'s anti-alias filter: Chebyshev I, `ripple_db` ripple, cut-off 0.8 / factor of Nyquist.

    As MATLAB does, the order is lowered until the transfer-function design is numerically sound (its gain at
    the cut-off is -ripple_db within 1e-6 dB).
    """
    edge = 0.8 / factor
    for n in range(order, 0, -1):
        b, a = ss.cheby1(n, ripple_db, edge)
        _, response = ss.freqz(b, a, worN=[np.pi * edge])
        if np.any(b != 0) and abs(20 * np.log10(abs(response[0])) + ripple_db) <= 1e-6:
            return b, a
    raise ValueError(  # pragma: no cover - only for absurd factors
        f"decimate: no stable Chebyshev anti-alias filter for `factor={factor}`; decimate in several stages."
    )


def decimate(
    signal_or_arrays: Any,
    factor: int,
    *,
    order: int = 8,
    ripple_db: float = 0.05,
    axis: int = -1,
    align: Literal["end", "start"] = "end",
) -> Any:
    """Down-sample by an integer `factor` after a zero-phase anti-alias filter (MATLAB's `decimate`).

    Each signal is filtered with a Chebyshev type I low-pass of order `order` (8), passband ripple
    `ripple_db` (0.05 dB) and edge `0.8 / factor` of the Nyquist frequency, run forwards and backwards
    (`filtfilt`, MATLAB padding `3 * order`), and one sample in `factor` is kept. This is the "parallel
    filtering and re-sampling" of the EMPS description §3.2 (there `factor = 10`, applied to every column of the
    observation matrix and to the force).

    `align="end"` (default) keeps the samples that end on the last one, as MATLAB does (its first kept index
    is `factor - (factor * ceil(T / factor) - T)`, 1-based); `align="start"` keeps samples `0, factor, ...`
    as `scipy.signal.decimate` does. Both keep `ceil(T / factor)` samples. On EMPS the choice matters more than
    one would guess: with `align="start"` and SciPy's longer padding the IDIM-LS relative error comes out
    4.12 % instead of the published 4.0834 % (the independent re-run quoted in the data README); with the
    defaults here every published figure is reproduced to all printed digits.

    **Arguments:**

    - `signal_or_arrays`: one array, or a tuple / list / dict of arrays (each decimated separately; the same
      container type is returned).
    - `factor`: the decimation factor (integer >= 1; 1 returns the input unchanged, as a copy).
    - `order`, `ripple_db`: the anti-alias filter (lowered automatically if the design is numerically
      unsound, as in MATLAB).
    - `axis`: the time axis.
    - `align`: `"end"` (MATLAB) or `"start"` (SciPy), see above.

    **Returns:** the decimated array(s), `ceil(T / factor)` samples along `axis`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> fj.decimate(np.ones(1000), 10).shape
    (100,)
    ```
    """
    factor = _positive_int(factor, "factor", "decimate")
    order = _positive_int(order, "order", "decimate")
    ripple_db = _positive_scalar(ripple_db, "ripple_db", "dB")
    if align not in ("end", "start"):
        raise ValueError(f"`align` must be 'end' (MATLAB) or 'start' (SciPy), got {align!r}.")

    if isinstance(signal_or_arrays, Mapping):
        return {
            key: decimate(value, factor, order=order, ripple_db=ripple_db, axis=axis, align=align)
            for key, value in signal_or_arrays.items()
        }
    if isinstance(signal_or_arrays, (tuple, list)) and not _is_numeric_sequence(signal_or_arrays):
        out = [decimate(v, factor, order=order, ripple_db=ripple_db, axis=axis, align=align) for v in signal_or_arrays]
        return type(signal_or_arrays)(out) if isinstance(signal_or_arrays, list) else tuple(out)

    if factor == 1:
        return _as_signal(signal_or_arrays, "signal", axis=axis).copy()
    b, a = _decimation_filter(factor, order, ripple_db)
    padlen = 3 * (max(len(a), len(b)) - 1)
    x = _as_signal(signal_or_arrays, "signal", axis=axis, min_length=padlen + 1)
    filtered = ss.filtfilt(b, a, x, axis=axis, padtype="odd", padlen=padlen)
    length = x.shape[axis]
    start = (length - 1) % factor if align == "end" else 0
    index = [slice(None)] * x.ndim
    index[axis] = slice(start, None, factor)
    return filtered[tuple(index)]


def _is_numeric_sequence(value: Any) -> bool:
    """A flat list / tuple of numbers is one signal, not a container of signals."""
    return len(value) > 0 and all(isinstance(item, (int, float, np.number)) for item in value)


def detrend_linear(signal: ArrayLike, *, axis: int = -1, return_trend: bool = False) -> Any:
    """Remove the least-squares straight line (offset and drift) from a signal.

    `scipy.signal.detrend(signal, type="linear")`; used to remove sensor drift from force records.

    **Arguments:** `signal` (time along `axis`, at least 2 samples); `axis`; `return_trend` to also return the
    removed line.

    **Returns:** the detrended signal (and the trend, with `return_trend=True`; `signal = detrended + trend`).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> bool(np.allclose(fj.detrend_linear(3.0 + 2.0 * np.arange(10.0)), 0.0))
    True
    ```
    """
    x = _as_signal(signal, "signal", axis=axis, min_length=2)
    detrended = ss.detrend(x, axis=axis, type="linear")
    return (detrended, x - detrended) if return_trend else detrended


class Normaliser(eqx.Module):
    """An affine normalisation `z = (x - mean) / scale` and its inverse `x = z * scale + mean`.

    Works on NumPy and JAX arrays alike (plain arithmetic), so a model trained on normalised signals can be
    mapped back to physical units inside `jit`.

    **Fields:** `mean` and `scale` (> 0), NumPy arrays that broadcast against the data (kept dims).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> z, norm = fj.normalise(np.array([1.0, 2.0, 3.0]))
    >>> norm.inverse(z)
    array([1., 2., 3.])
    ```
    """

    mean: np.ndarray
    scale: np.ndarray

    def __call__(self, x: Any) -> Any:
        """Normalise `x` (physical units -> dimensionless)."""
        return (x - self.mean) / self.scale

    def inverse(self, z: Any) -> Any:
        """Undo the normalisation (dimensionless -> physical units)."""
        return z * self.scale + self.mean


def normalise(data: ArrayLike, *, axis: int | tuple[int, ...] | None = -1) -> tuple[np.ndarray, Normaliser]:
    """Scale a signal to zero mean and unit standard deviation along `axis`.

    **Arguments:**

    - `data`: the data (at least 2 samples along `axis`, finite, not constant).
    - `axis`: the axis (or axes) the statistics are taken over; `-1` (default) normalises each channel of a
      `(..., T)` array over time; `None` uses one mean and scale for everything.

    **Returns:** `(normalised, normaliser)`, with `normaliser.inverse(normalised)` equal to `data`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> z, norm = fj.normalise(np.array([2.0, 4.0, 6.0]))
    >>> round(float(z.mean()), 12), round(float(z.std()), 12)
    (0.0, 1.0)
    ```
    """
    x = _as_signal(data, "data")
    axes = tuple(range(x.ndim)) if axis is None else (axis,) if isinstance(axis, int) else tuple(axis)
    try:
        count = int(np.prod([x.shape[a] for a in axes]))
    except IndexError:
        raise ValueError(f"`axis={axis}` is out of range for `data` of shape {x.shape}.") from None
    if count < 2:
        raise ValueError(f"`data` needs at least 2 values along `axis={axis}` to compute a standard deviation.")
    mean = np.mean(x, axis=axis, keepdims=True)
    scale = np.reshape(numpy_std(x, axis=axis), mean.shape).astype(mean.dtype)  # scaled before squaring
    if np.any(scale <= np.finfo(x.dtype).tiny) or np.any(scale <= 1e-12 * np.abs(mean)):
        raise ValueError(
            "`data` is constant along the normalisation axis (zero standard deviation); drop the constant "
            "channel or normalise over another `axis`."
        )
    normaliser = Normaliser(mean=mean, scale=scale)
    return normaliser(x), normaliser
