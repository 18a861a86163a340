"""`data_folder`: where fricjax finds the benchmark data (EMPS, Bouc-Wen, the damper records) when no path is given.

Never relative to the current working directory: a script gives the same answer from any folder.
"""

from __future__ import annotations

import os
import pathlib

ENVIRONMENT_VARIABLE = "FRICJAX_DATA"


def checkout_data_folder() -> pathlib.Path | None:
    """`shared/data` beside the fricjax checkout this package runs from (`<checkout>/../shared/data`), or `None` when
    fricjax is not run from a checkout (an installed wheel) or that folder does not exist."""
    root = pathlib.Path(__file__).resolve().parents[3]  # <checkout>/src/fricjax/_data/_folder.py
    if not (root / "pyproject.toml").is_file() or not (root / "src" / "fricjax").is_dir():
        return None
    folder = root.parent / "shared" / "data"
    return folder if folder.is_dir() else None


def data_folder(subfolder: str | None = None) -> pathlib.Path:
    """The data folder fricjax reads benchmark files from when you give no path: `$FRICJAX_DATA` when that is set,
    else `shared/data` beside the fricjax checkout (`<checkout>/../shared/data`, for an editable install). Neither
    depends on the current working directory.

    **Arguments:**

    - `subfolder`: a folder inside it (`"emps"`, `"boucwen"`, `"damper"`); `None` for the data folder itself.

    **Returns:** the absolute path of the folder (it exists).

    **Raises:** `FileNotFoundError` when `FRICJAX_DATA` names no folder, when it is not set and there is no
    `shared/data` beside the checkout (the message names both places), or when `subfolder` is not in it.

    ```python
    >>> import fricjax as fj
    >>> (fj.data_folder("emps") / "DATA_EMPS.mat").is_file()  # doctest: +SKIP
    True
    ```
    """
    setting = os.environ.get(ENVIRONMENT_VARIABLE)
    if setting:
        folder = pathlib.Path(setting).expanduser()
        if not folder.is_dir():
            raise FileNotFoundError(f"{ENVIRONMENT_VARIABLE}={setting!r} names no folder; set it to the data folder.")
    else:
        found = checkout_data_folder()
        if found is None:
            beside = pathlib.Path(__file__).resolve().parents[3].parent / "shared" / "data"
            raise FileNotFoundError(
                f"fricjax's data folder: {ENVIRONMENT_VARIABLE} is not set and there is no folder {beside} "
                f"(shared/data beside the fricjax checkout); set {ENVIRONMENT_VARIABLE} to the folder that holds the "
                "benchmark data (export FRICJAX_DATA=/path/to/data) or pass the file's path."
            )
        folder = found
    folder = folder.resolve()
    if subfolder is None:
        return folder
    inside = folder / subfolder
    if not inside.is_dir():
        source = f"${ENVIRONMENT_VARIABLE}" if setting else "the checkout's shared/data"
        raise FileNotFoundError(f"the data folder {folder} ({source}) has no folder {subfolder!r}.")
    return inside
