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


# protocol names that moved to their namespaces (DESIGN.md v4): the flat name still reads them, with a warning
_MOVED = {
    "EMPSBGBMFit": "emps",
    "EMPSErrorModel": "emps",
    "fit_emps_bgbm": "emps",
    "EMPSEnsemble": "emps",
    "EMPSEnsembleFit": "emps",
    "EMPSHybridFit": "emps",
    "emps_closed_loop_errors": "emps",
    "emps_hybrid_start": "emps",
    "fit_emps_ensemble": "emps",
    "fit_emps_hybrid": "emps",
    "EMPSIDMResult": "emps",
    "fit_emps_idm": "emps",
    "EMPSIDMData": "emps",
    "emps_idm_data": "emps",
    "EMPSOpenLoopFit": "emps",
    "EMPSOpenLoopLoss": "emps",
    "fit_emps_open_loop": "emps",
    "predict_emps_open_loop": "emps",
    "score_emps_open_loop": "emps",
    "split_emps_record": "emps",
    "EMPS_PLATEAU_VELOCITIES": "emps",
    "EMPSPlateau": "emps",
    "emps_plateau_forces": "emps",
    "BOUCWEN_STEADY_PERIODS": "boucwen",
    "BoucWenLoss": "boucwen",
    "BoucWenScores": "boucwen",
    "boucwen_rmse": "boucwen",
    "score_boucwen": "boucwen",
}


# result types that one `fj.Solution` replaced (DESIGN.md v4): the old name reads `Solution`, with a warning naming
# the family's typed `aux`
_REPLACED = {
    "SweepResult": "a batched fj.Solution (solution[i], codes, best_configuration)",
    "KernelNARXResult": "fj.Solution with aux fj.KernelNARXSearch",
    "LocalModelResult": "fj.Solution with aux fj.LocalModelSearch",
    "PolynomialNARXResult": "fj.Solution with aux fj.PolynomialNARXSelection",
    "WaveletNARXResult": "fj.Solution with aux fj.WaveletNARXSelection",
    "RecursiveFitResult": "fj.Solution with aux fj.RecursiveFitTrace",
}


def __getattr__(name: str) -> "_Any":  # quoted: no `from __future__ import annotations` (a public name here)
    """The public names load on first use, all at once (PEP 562): `import fricjax` itself imports no JAX (and
    `__version__` reads the installed metadata on first use: 30 ms that `fricjax`'s start-up does not wait for)."""
    if name == "__version__":
        return _fricjax_version()
    if name.startswith("__"):
        raise AttributeError(name)
    if name in _REPLACED:
        import warnings

        warnings.warn(
            f"fj.{name} is gone: the fit returns {_REPLACED[name]}; fj.{name} reads fj.Solution and goes in a later "
            "release",
            DeprecationWarning,
            stacklevel=2,
        )
        return __getattr__("Solution")
    if name in _MOVED:
        import warnings

        namespace = _importlib.import_module(f".{_MOVED[name]}", __name__)
        warnings.warn(
            f"fj.{name} moved to fj.{_MOVED[name]}.{name} (the protocols' names live in their namespaces); "
            "the old name goes in a later release",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(namespace, name)
    public = _importlib.import_module("._public", __name__)
    names = {key: value for key, value in vars(public).items() if not key.startswith("_")}
    globals().update(names)
    if name not in names:
        raise AttributeError(f"module 'fricjax' has no attribute {name!r}")
    return names[name]


def __dir__() -> list[str]:
    public = _importlib.import_module("._public", __name__)
    return sorted(set(globals()) | {key for key in vars(public) if not key.startswith("_")})
