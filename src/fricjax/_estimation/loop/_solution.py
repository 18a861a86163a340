"""`Solution`: what every fit returns, and `RESULTS`, the one enumeration of why a fit stopped.

In the optimistix style (`optx.Solution`, `optx.RESULTS`): one result type, one `eqx.Enumeration` whose entries carry
the sentence that explains them, and `throw=True` on the driver to raise instead of returning a failure.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import numpy as np

from ..._constraints import PARAMETER_UNITS as PARAMETER_UNITS
from ..._constraints import parameter_arrays, parameter_line, parameter_units, unwrap
from ..._smoothing import exact
from ._plausibility import implausible


class RESULTS(eqx.Enumeration):
    """Why a fit stopped. `successful`, `max_steps` and `early_stopped` return a usable model (`Solution.success`);
    `diverged` and `solver_failed` return the best model seen before the failure (never worse than the start)."""

    successful = (
        "a convergence test held (the solver's own, or the loss fell by less than `tolerance` over one "
        "check), or the parameters are linear and were solved by least squares"
    )
    max_steps = (
        "the step budget ran out before a convergence test held: the best model seen is returned, but it may not be "
        "converged (the message says whether the loss was still falling)"
    )
    early_stopped = "the validation loss stopped improving (patience exhausted); the best model was kept"
    diverged = "a loss or parameter became non-finite; the last good model was kept"
    solver_failed = "the solver (an optimistix one) reported a failure; the best model seen was kept"


RESULT_NAMES = ("successful", "max_steps", "early_stopped", "diverged", "solver_failed")
#: `{name: sentence}` of every result code (the command line's legend; `RESULTS` is the enumeration).
RESULT_CODES = {name: RESULTS[getattr(RESULTS, name)] for name in RESULT_NAMES}  # type: ignore[misc]
_USABLE = ("successful", "max_steps", "early_stopped")


def result_name(result: Any) -> str:
    """The name of a (concrete, unbatched) `RESULTS` item: `"successful"`, `"max_steps"`, ..."""
    for name in RESULT_NAMES:
        if bool(result == getattr(RESULTS, name)):
            return name
    raise ValueError(f"not a fricjax result code: {result!r}")


def as_result(code: Any) -> Any:
    """A `RESULTS` item from an item or its name (`"successful"`, or a legacy `"solver_failed:<detail>"`)."""
    if isinstance(code, RESULTS):
        return code
    if isinstance(code, str) and code.split(":")[0] in RESULT_NAMES:
        return getattr(RESULTS, code.split(":")[0])
    raise ValueError(f"result must be a fj.RESULTS item or one of {', '.join(RESULT_NAMES)}; got {code!r}.")


class FitFailed(RuntimeError):
    """Raised by a fit with `throw=True` that diverged or whose solver failed; `.solution` holds what it found."""

    def __init__(self, solution: Solution):
        super().__init__(f"fit: {solution.code}: {solution.message}")
        self.solution = solution


@dataclasses.dataclass(frozen=True)
class Solution:
    """What a fit returns (`fj.fit`, `fj.least_squares`; `FitResult` is the same class under its former name), and
    the base of what every identification of the estimation layer returns (`fj.identify_kernel_narx`, ...: their
    results are `Solution`s with the family's own fields added).

    - `model`: the fitted model (smoothing as at the end of the fit); `exact_model` is `fj.exact(model)`.
    - `result`: a `fj.RESULTS` item (`code` is its name: `successful`, `max_steps`, `early_stopped`, `diverged`,
      `solver_failed`); `message`: one sentence saying why the fit stopped and which stage produced the model.
    - `history`: dict of NumPy arrays `step`, `train_loss`, `val_loss` (NaN without validation), `eps` (the
      smoothing width in force at each check: the continuation stage's, else the model's own; NaN for an exact
      model or differing widths), and `time` (seconds since the call started, compilation included).
    - `train_loss`, `val_loss`: final losses of the returned model (validation in free-run simulation);
      `exact_val_loss`: the same with the exact model (NaN without validation data).
    - `evaluations`: solver steps per start; `wall_time` [s]; `num_starts`; `best_start`.
    - `std`: pytree shaped like `fj.unwrap(model)`, the Gauss-Newton standard deviations of the trained
      physical parameters (residual variance x (J^T J)^-1), NaN for frozen ones; `None` if not computed.
    - `extra`: the loss's extra decision variables (multiple-shooting states; a fit to several records: the
      per-record nuisances in units of each record's force spread).
    - `records`: a fit to several records: `fj.RecordNuisances` (each record's offset [N], drift [N/s], initial
      state and training NMSE); `None` otherwise.
    - `start_kept`: no step improved on the model the fit was given (by validation where there is validation
      data), so that model is returned unchanged (`message` says so).
    """

    model: Any
    result: Any = "successful"
    message: str = ""
    history: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    train_loss: float = float("nan")
    val_loss: float = float("nan")
    exact_val_loss: float = float("nan")
    evaluations: int = 0
    wall_time: float = 0.0
    num_starts: int = 1
    best_start: int = 0
    std: Any = None
    extra: Any = None
    records: Any = None
    start_kept: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "result", as_result(self.result))  # a name is accepted (thin compatibility)

    @property
    def code(self) -> str:
        """The result code's name: `"successful"`, `"max_steps"`, `"early_stopped"`, `"diverged"`, ..."""
        return result_name(self.result)

    @property
    def success(self) -> bool:
        """True unless the fit diverged or the solver failed."""
        return self.code in _USABLE

    @property
    def exact_model(self) -> Any:
        return exact(self.model)

    def parameters(self) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
        """`{path: (value, std)}` of the physical parameters of the fitted model (std `None` if unknown)."""
        values = parameter_arrays(unwrap(exact(self.model)))  # exact(): smoothing widths are settings, not parameters
        stds = parameter_arrays(exact(self.std)) if self.std is not None else {}
        return {path: (value, stds.get(path)) for path, value in values.items()}

    def parameter_table(self) -> list[dict[str, Any]]:
        """One row per physical parameter: `path`, `value`, `std` (NaN where unknown) and `unit` (SI; `""` where the
        name is not a literature symbol fricjax knows)."""
        rows = []
        units = parameter_units(unwrap(exact(self.model)))
        for path, (value, std) in self.parameters().items():
            value = np.asarray(value)
            std = np.full(value.shape, np.nan) if std is None else np.asarray(std)
            rows.append({"path": path, "value": value, "std": std, "unit": units[path]})
        return rows

    def _validation_text(self) -> str:
        """The validation part of the summary's loss line; never a bare "nan": without validation data (the losses
        and their history all NaN) it says so."""
        if np.isfinite(self.val_loss) or np.isfinite(self.exact_val_loss):
            if not np.isfinite(self.exact_val_loss):  # a model without a smooth mode (kernel, local): one loss
                return f"validation loss {self.val_loss:.4g}"
            return f"validation loss {self.val_loss:.4g} (exact {self.exact_val_loss:.4g})"
        history = np.asarray(self.history.get("val_loss", []), dtype=float)
        if np.any(np.isfinite(history)):
            return "validation loss not finite"
        if self.code == "diverged":
            return "no finite validation loss (no validation data, or the fit diverged before one was computed)"
        return "no validation data"

    def summary(self, max_parameters: int = 20) -> str:
        """A short human-readable report: result, losses, and at most `max_parameters` parameter lines (arrays of
        more than 8 entries are summarised by shape and range)."""
        effort = f" after {self.evaluations} steps in {self.wall_time:.2f} s" if self.evaluations else ""
        losses = f"train loss {self.train_loss:.4g}, " + self._validation_text()
        lines = [f"{type(self).__name__}: {self.code}{effort}: {self.message}", losses]
        rows = self.parameter_table()
        # with per-record offsets the model's own `offset` fields were held at their start (fj.Nuisances): the
        # force on record i is the model's, its own offset included, plus record i's offset
        per_record_offsets = self.records is not None and self.records.offset is not None
        for row in rows[:max_parameters]:
            line = "  " + parameter_line(row["path"], row["value"], row["std"], row["unit"])
            if per_record_offsets and row["path"].split(".")[-1] == "offset":
                line += " (held; each record's offset below is added to it)"
            lines.append(line)
        if len(rows) > max_parameters:
            lines.append(f"  ... and {len(rows) - max_parameters} more parameter arrays (Solution.parameters())")
        # what a model of its class should not have (compare's table notes; the bound notes need to know what was
        # trained, which compare does and a Solution does not)
        notes = implausible(self.model, bounds=False)
        if notes:
            lines.append("  implausible: " + "; ".join(notes))
        if self.records is not None:
            lines.append(f"  per record ({len(self.records.names)}):")
            lines += ["    " + line for line in self.records.lines()]
        return "\n".join(lines)


FitResult = Solution
