"""fricjax: friction models as jit-compiled scan simulators, with smooth and exact stick/slip.

One flat public namespace: `import fricjax as fj`.
"""

import importlib as _importlib

# first, before any JAX computation: sets XLA_FLAGS so that XLA:CPU compiles each scan as one function
from . import _xla_flags as _xla_flags  # isort: skip
from ._version import fricjax_version as _fricjax_version

TYPE_CHECKING = False  # `typing` is not imported (10 ms of the `fricjax` program's start-up); type checkers read True

if TYPE_CHECKING:  # type checkers and IDEs see every public name; at run time they load on first use
    from typing import Any as _Any

    from ._public import *  # noqa: F403
del TYPE_CHECKING


def __getattr__(name: str) -> "_Any":  # quoted: no `from __future__ import annotations` (a public name here)
    """The public names load on first use, all at once (PEP 562): `import fricjax` itself imports no JAX (and
    `__version__` reads the installed metadata on first use: 30 ms that `fricjax`'s start-up does not wait for)."""
    if name == "__version__":
        return _fricjax_version()
    if name.startswith("__"):
        raise AttributeError(name)
    public = _importlib.import_module("._public", __name__)
    names = {key: value for key, value in vars(public).items() if not key.startswith("_")}
    globals().update(names)
    if name not in names:
        raise AttributeError(f"module 'fricjax' has no attribute {name!r}")
    return names[name]


def __dir__() -> list[str]:
    public = _importlib.import_module("._public", __name__)
    return sorted(set(globals()) | {key for key in vars(public) if not key.startswith("_")})
