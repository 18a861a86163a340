"""The EMPS benchmark record and its loader (`DATA_EMPS.mat`, `DATA_EMPS_PULSES.mat`).

The Electro-Mechanical Positioning System (Janot, Gautier & Brunot 2019, *Data Set and Reference Models of
EMPS*, nonlinearbenchmark.org) is a ball-screw axis under a PD position controller, logged at 1 kHz. The
identification exercises on it live in `fricjax._protocols` (`_emps_idm`, `_emps_open_loop`).
"""

from __future__ import annotations

import os

import equinox as eqx
import numpy as np
import scipy.io

_VECTORS = ("t", "qm", "qg", "vir")
_SCALARS = ("gtau", "kp", "kv")


# ---------------------------------------------------------------------------------------------------------------
# Loading


class EMPSRecord(eqx.Module):
    """One EMPS experiment as recorded (raw, unfiltered, 1 kHz).

    **Fields:**

    - `t`: time [s], shape `(T,)`; `dt` the mean sample time [s] (1 ms).
    - `qm`: measured motor position, on the load side [m]; `qg`: reference position [m].
    - `vir`: controller output, the drive command [V]; `force = gtau * vir` the drive force [N].
    - `gtau`: drive gain [N/V]; `kp`: position gain [1/s]; `kv`: velocity gain [V/(m/s)].
    - `pulses`: the pulse disturbance [V] added to the command (`pulses_N`, PULSES file only), else `None`.
      `vir` already contains it.
    - `name`: the file name without extension (`"DATA_EMPS"`, `"DATA_EMPS_PULSES"`).
    """

    t: np.ndarray
    qm: np.ndarray
    qg: np.ndarray
    vir: np.ndarray
    force: np.ndarray
    pulses: np.ndarray | None
    gtau: float
    kp: float
    kv: float
    dt: float
    name: str = eqx.field(static=True)

    @property
    def length(self) -> int:
        """Number of samples T."""
        return int(self.t.shape[0])


def load_emps(path: str | os.PathLike[str]) -> EMPSRecord:
    """Read `DATA_EMPS.mat` or `DATA_EMPS_PULSES.mat` of the EMPS benchmark.

    Variables read: `t`, `qm`, `qg`, `vir` (vectors), `gtau`, `kp`, `kv` (scalars) and, when present, `pulses_N`.
    The drive force is `force = gtau * vir` [N] (the official scripts' `Force1`).

    **Arguments:** `path` to the `.mat` file.

    **Returns:** an `EMPSRecord`.

    **Raises:** `FileNotFoundError` for a missing file; `ValueError` for a file that is not a MATLAB file, lacks
    a variable, or holds inconsistent values.

    ```python
    >>> import fricjax as fj
    >>> rec = fj.load_emps(fj.data_folder("emps") / "DATA_EMPS.mat")  # doctest: +SKIP
    >>> rec.length, rec.dt, rec.pulses is None  # doctest: +SKIP
    (24841, 0.001, True)
    ```
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(
            f"load_emps: {path!r} is a folder; pass the file itself, e.g. {os.path.join(path, 'DATA_EMPS.mat')!r} "
            "or DATA_EMPS_PULSES.mat."
        )
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"load_emps: no file at {path!r}; pass the path of DATA_EMPS.mat or DATA_EMPS_PULSES.mat "
            "(the EMPS benchmark files from nonlinearbenchmark.org)."
        )
    try:
        contents = scipy.io.loadmat(path)
    except Exception as error:
        raise ValueError(f"load_emps: {path!r} could not be read as a MATLAB .mat file ({error}).") from error
    missing = [name for name in (*_VECTORS, *_SCALARS) if name not in contents]
    if missing:
        raise ValueError(
            f"load_emps: {path!r} lacks the variable(s) {', '.join(missing)}; an EMPS file holds t, qm, qg, vir, "
            "gtau, kp and kv. Is this DATA_EMPS.mat or DATA_EMPS_PULSES.mat?"
        )

    def vector(name: str) -> np.ndarray:
        value = np.asarray(contents[name], dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(value)):
            raise ValueError(f"load_emps: variable `{name}` in {path!r} contains NaN or inf.")
        return value

    def scalar(name: str) -> float:
        value = np.asarray(contents[name], dtype=np.float64).reshape(-1)
        if value.size != 1 or not np.isfinite(value[0]) or value[0] <= 0:
            raise ValueError(f"load_emps: variable `{name}` in {path!r} must be one positive number, got {value!r}.")
        return float(value[0])

    t, qm, qg, vir = (vector(name) for name in _VECTORS)
    pulses = vector("pulses_N") if "pulses_N" in contents else None
    lengths = {
        name: v.shape[0]
        for name, v in zip((*_VECTORS, "pulses_N"), (t, qm, qg, vir, pulses), strict=True)
        if v is not None
    }
    if len(set(lengths.values())) != 1:
        raise ValueError(f"load_emps: the signals in {path!r} have different lengths {lengths}.")
    if t.shape[0] < 3 or not np.all(np.diff(t) > 0):
        raise ValueError(f"load_emps: `t` in {path!r} must hold at least 3 strictly increasing times.")
    gtau, kp, kv = (scalar(name) for name in _SCALARS)
    return EMPSRecord(
        t=t,
        qm=qm,
        qg=qg,
        vir=vir,
        force=gtau * vir,
        pulses=pulses,
        gtau=gtau,
        kp=kp,
        kv=kv,
        dt=float((t[-1] - t[0]) / (t.shape[0] - 1)),
        name=os.path.splitext(os.path.basename(path))[0],
    )
