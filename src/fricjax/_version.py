"""The installed fricjax's version, for `fj.__version__`, model files and reports (a primitive: imports nothing of
fricjax, so every layer may ask for it)."""

from __future__ import annotations

import functools


@functools.cache
def fricjax_version() -> str:
    """The installed fricjax's version (`"0.0.0"` in a source tree that is not installed)."""
    from importlib.metadata import PackageNotFoundError, version  # 30 ms: imported on first use

    try:
        return version("fricjax")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "0.0.0"
