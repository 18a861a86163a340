"""The Bouc-Wen hysteretic benchmark records and their loader (`load_boucwen`).

Noël & Schoukens 2016, *Hysteretic benchmark with a dynamic nonlinearity* (Workshop on Nonlinear System
Identification Benchmarks): a simulated mass-spring-damper with a Bouc-Wen hysteretic restoring force, input
force u [N], output displacement y [m], sampled at 750 Hz. The official test signals are noise-free
(`uval/yval_multisine.mat`: one steady-state period of 8192 samples; `uval/yval_sinesweep.mat`: 153 000
samples from rest); the training realisation `generated_train_forgione/train.h5` (M. Forgione, made with the
official p-code: 5 periods x 8192 samples of a 5-150 Hz multisine, output noise of RMS 8e-6 m) comes from
the dynoNet repository. See `$FRICJAX_DATA/README.md`, section 2.
"""

from __future__ import annotations

import os
from typing import NamedTuple

import equinox as eqx
import numpy as np
import scipy.io

from ._folder import data_folder

BOUCWEN_DT = 1.0 / 750.0
"""Sample time of the benchmark records [s] (fs = 750 Hz)."""

BOUCWEN_PERIOD = 8192
"""Samples in one period of the benchmark's multisines."""

_FILES = {
    "multisine": ("uval_multisine.mat", "yval_multisine.mat"),
    "sinesweep": ("uval_sinesweep.mat", "yval_sinesweep.mat"),
}
_TRAIN = os.path.join("generated_train_forgione", "train.h5")


class BoucWenRecord(eqx.Module):
    """One Bouc-Wen benchmark record.

    **Fields:** `u` the input force [N], shape `(T,)`; `y` the output displacement [m], shape `(T,)`; `dt` the
    sample time [s] (1/750); `name` (`"train"`, `"multisine"`, `"sinesweep"`); `source` the file(s) read.
    """

    u: np.ndarray
    y: np.ndarray
    dt: float = eqx.field(static=True)
    name: str = eqx.field(static=True)
    source: str = eqx.field(static=True)

    @property
    def length(self) -> int:
        """Number of samples T."""
        return int(self.u.shape[0])


class BoucWenData(NamedTuple):
    """The benchmark's three records: `train` (40 960 samples, noisy; fit and select on it only), `multisine`
    (the test: one steady-state period, 8192 samples) and `sinesweep` (the second test, from rest)."""

    train: BoucWenRecord
    multisine: BoucWenRecord
    sinesweep: BoucWenRecord


def _folder(path: str | os.PathLike[str] | None) -> str:
    if path is not None:
        return os.fspath(path)
    try:
        root = data_folder()
    except FileNotFoundError as err:
        raise FileNotFoundError(
            f"load_boucwen: no `path` given, and no data folder: {err} The folder must hold boucwen/; or pass "
            "path='/path/to/data/boucwen'."
        ) from None
    return os.path.join(root, "boucwen")


def _vector(path: str, key: str) -> np.ndarray:
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"load_boucwen: no file at {path!r}; the Bouc-Wen benchmark files (BoucWenFiles.zip, "
            "nonlinearbenchmark.org) "
            "belong in $FRICJAX_DATA/boucwen/: set FRICJAX_DATA or pass `path=` the folder holding them."
        )
    try:
        contents = scipy.io.loadmat(path)
    except Exception as error:
        raise ValueError(f"load_boucwen: {path!r} could not be read as a MATLAB .mat file ({error}).") from error
    if key not in contents:
        raise ValueError(f"load_boucwen: {path!r} lacks the variable `{key}`; is it the official benchmark file?")
    return _finite(np.asarray(contents[key], dtype=np.float64).reshape(-1), path)


def _finite(value: np.ndarray, path: str) -> np.ndarray:
    if not np.all(np.isfinite(value)):
        raise ValueError(f"load_boucwen: {path!r} holds NaN or inf.")
    return value


def _train(folder: str) -> BoucWenRecord:
    path = os.path.join(folder, _TRAIN)
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"load_boucwen: no file at {path!r}; the training realisation train.h5 (forgi86/dynonet, "
            "examples/BW/data/Test signals/train.h5) belongs in $FRICJAX_DATA/boucwen/generated_train_forgione/: "
            "set FRICJAX_DATA or pass `path=`."
        )
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            group = handle["multisine"]
            u = np.asarray(group["u"], dtype=np.float64).reshape(-1)
            y = np.asarray(group["y"], dtype=np.float64).reshape(-1)
            fs = float(np.asarray(group["fs"]).reshape(-1)[0]) if "fs" in group else 750.0
    except (OSError, KeyError) as error:
        raise ValueError(
            f"load_boucwen: {path!r} is not the expected HDF5 file (group `multisine` with `u`, `y`, `fs`): {error}."
        ) from error
    if u.shape != y.shape or abs(fs - 750.0) > 1e-9:
        raise ValueError(f"load_boucwen: {path!r}: u {u.shape} and y {y.shape} must match and fs be 750 Hz, got {fs}.")
    return BoucWenRecord(_finite(u, path), _finite(y, path), BOUCWEN_DT, "train", path)


def load_boucwen(path: str | os.PathLike[str] | None = None) -> BoucWenData:
    """Read the Bouc-Wen benchmark (Noël & Schoukens 2016): the training realisation and the two test records.

    **Arguments:** `path` the folder holding `uval_multisine.mat`, `yval_multisine.mat`, `uval_sinesweep.mat`,
    `yval_sinesweep.mat` and `generated_train_forgione/train.h5`; default `boucwen/` in `fj.data_folder()`
    (`$FRICJAX_DATA`, else `shared/data` beside the fricjax checkout).

    **Returns:** a `BoucWenData(train, multisine, sinesweep)` of `BoucWenRecord`s (u [N], y [m], dt = 1/750 s).
    The protocol: fit and select on `train` only; score the free-run simulation RMSE [m] on `multisine` (one
    steady-state period: simulate a few repeated periods first, score the last) and on `sinesweep` (from rest).

    **Raises:** `FileNotFoundError` naming the missing file and the fix (FRICJAX_DATA or `path=`); `ValueError`
    for a file of the wrong content.

    ```python
    >>> import fricjax as fj
    >>> data = fj.load_boucwen()  # doctest: +SKIP
    >>> data.train.length, data.multisine.length, data.sinesweep.length  # doctest: +SKIP
    (40960, 8192, 153000)
    ```
    """
    folder = _folder(path)
    if not os.path.isdir(folder):
        raise FileNotFoundError(
            f"load_boucwen: no folder {folder!r}; pass `path=` the folder holding the Bouc-Wen benchmark files or set "
            "FRICJAX_DATA to the data folder that holds boucwen/."
        )
    tests = {}
    for name, (ufile, yfile) in _FILES.items():
        upath, ypath = os.path.join(folder, ufile), os.path.join(folder, yfile)
        u, y = _vector(upath, f"uval_{name}"), _vector(ypath, f"yval_{name}")
        if u.shape != y.shape:
            raise ValueError(f"load_boucwen: {upath!r} and {ypath!r} have different lengths {u.shape}, {y.shape}.")
        tests[name] = BoucWenRecord(u, y, BOUCWEN_DT, name, f"{upath}, {ypath}")
    return BoucWenData(_train(folder), tests["multisine"], tests["sinesweep"])
