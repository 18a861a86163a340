"""`Solution`: what every fit returns, and `RESULTS`, the one enumeration of why a fit stopped.

In the optimistix style (`optx.Solution`, `optx.RESULTS`): one result type, an `eqx.Module`, for every estimation
entry point (what only one family's fitter returns is its typed `aux`); one `eqx.Enumeration` that extends
optimistix's own with the entries of fricjax's loop, whose items carry the sentence that explains them; and
`throw=True` on the drivers to raise instead of returning a failure. A sweep returns one batched `Solution`.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import numpy as np
import optimistix as optx

from ..._constraints import PARAMETER_UNITS as PARAMETER_UNITS
from ..._constraints import parameter_arrays, parameter_line, parameter_units, sided_paths, unwrap
from ..._models._display import bounded_paths
from ..._smoothing import exact
from ._plausibility import implausible, poorly_determined


class RESULTS(optx.RESULTS):  # type: ignore[misc]
    """Why a fit stopped: optimistix's `RESULTS` (its `successful` and its solvers' failures) and the outcomes of
    fricjax's loop. `successful`, `max_steps` and `early_stopped` return a usable model (`Solution.success`);
    `diverged` and `solver_failed` return the best model seen before the failure (never worse than the start)."""

    max_steps = (
        "the step budget ran out before a convergence test held: the best model seen is returned, but it may not be "
        "converged (the message says whether the loss was still falling)"
    )
    early_stopped = "the validation loss stopped improving (patience exhausted); the best model was kept"
    diverged = "a loss or parameter became non-finite; the last good model was kept"
    solver_failed = "the solver (an optimistix one) reported a failure; the best model seen was kept"


RESULT_NAMES = ("successful", "max_steps", "early_stopped", "diverged", "solver_failed")
#: `{name: sentence}` of every result code of a fit (the command line's legend; `RESULTS` is the enumeration, whose
#: `successful` is optimistix's, without a sentence).
RESULT_CODES = {
    "successful": (
        "a convergence test held (the solver's own, or the loss fell by less than `tolerance` over one "
        "check), or the parameters are linear and were solved by least squares"
    ),
    **{name: RESULTS[getattr(RESULTS, name)] for name in RESULT_NAMES[1:]},  # type: ignore[misc]
}
_USABLE = ("successful", "max_steps", "early_stopped")


def result_name(result: Any) -> str:
    """The name of a (concrete, unbatched) `RESULTS` item: `"successful"`, `"max_steps"`, ..."""
    for name in RESULT_NAMES:
        if bool(result == getattr(RESULTS, name)):
            return name
    raise ValueError(f"not a fricjax result code: {result!r}")


def as_result(code: Any) -> Any:
    """A `RESULTS` item from an item (fricjax's, or optimistix's own: promoted) or its name (`"successful"`, or a
    legacy `"solver_failed:<detail>"`)."""
    if isinstance(code, RESULTS):
        return code
    if isinstance(code, optx.RESULTS):
        return RESULTS.promote(code)
    if isinstance(code, str) and code.split(":")[0] in RESULT_NAMES:
        return getattr(RESULTS, code.split(":")[0])
    raise ValueError(f"result must be a fj.RESULTS item or one of {', '.join(RESULT_NAMES)}; got {code!r}.")


class FitFailed(RuntimeError):
    """Raised by a fit with `throw=True` that diverged or whose solver failed; `.solution` holds what it found."""

    def __init__(self, solution: Solution):
        super().__init__(f"fit: {solution.code}: {solution.message}")
        self.solution = solution


class Solution(eqx.Module):
    """What every fit and identification returns (`fj.fit`, `fj.least_squares`, `fj.sweep`, the `identify_*` functions,
    `fj.recursive_fit`; `FitResult` is the same class under its former name): one `eqx.Module`.

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
    - `aux`: what only the entry point that made it returns, typed (`fj.KernelNARXSearch`, `fj.LocalModelSearch`,
      `fj.PolynomialNARXSelection`, `fj.WaveletNARXSelection`, `fj.RecursiveFitTrace`); `None` for a fit. Its fields
      read through as the solution's own attributes (`solution.ridge` is `solution.aux.ridge`).

    A sweep's `Solution` is batched along its configurations: `model` is the stacked batch, `result`, `train_loss`
    and `val_loss` have shape `(B,)`, `history` arrays `(checks, B)`; `solution[i]` is configuration `i`'s own
    (unbatched) `Solution`, `codes` names each one's result and `best_configuration` is the index with the lowest
    validation loss (training loss without validation data).
    """

    model: Any
    result: Any = "successful"
    message: str = ""
    history: dict[str, np.ndarray] = eqx.field(default_factory=dict)
    train_loss: float | np.ndarray = float("nan")  # (B,) in a sweep's batched solution
    val_loss: float | np.ndarray = float("nan")
    exact_val_loss: float | np.ndarray = float("nan")
    evaluations: int = 0
    wall_time: float = 0.0
    num_starts: int = 1
    best_start: int = 0
    std: Any = None
    extra: Any = None
    records: Any = None
    start_kept: bool = False
    aux: Any = None

    def __check_init__(self) -> None:
        if not isinstance(self.result, RESULTS):
            object.__setattr__(self, "result", as_result(self.result))  # a name is accepted (thin compatibility)

    def __getattr__(self, name: str) -> Any:
        """The typed `aux`'s fields read through (`solution.candidates` is `solution.aux.candidates`)."""
        aux = self.__dict__.get("aux")
        if not name.startswith("_") and aux is not None and name in getattr(aux, "__dataclass_fields__", {}):
            return getattr(aux, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def batched(self) -> bool:
        """Whether this is a sweep's batch of solutions (one per configuration) rather than one fit's."""
        return np.ndim(self.train_loss) > 0

    @property
    def code(self) -> str:
        """The result code's name: `"successful"`, `"max_steps"`, `"early_stopped"`, `"diverged"`, ... (a batched
        solution: `codes`)."""
        if self.batched:
            raise TypeError(
                "a sweep's Solution holds one result per configuration: read `codes`, or `solution[i].code`"
            )
        return result_name(self.result)

    @property
    def codes(self) -> tuple[str, ...]:
        """Each configuration's result code (a single fit: its one code)."""
        if not self.batched:
            return (self.code,)
        return tuple(self[i].code for i in range(np.size(self.train_loss)))

    def __getitem__(self, i: int) -> Solution:
        """Configuration `i` of a sweep's batched `Solution`, as one fit's `Solution` (its model unbatched)."""
        if not self.batched:
            raise TypeError("one fit's Solution has no configurations to index; a sweep's Solution has")
        count = np.size(self.train_loss)
        if not -count <= int(i) < count:
            raise IndexError(f"configuration {i} of a sweep of {count}")

        def pick(leaf: Any) -> Any:
            return leaf[i] if eqx.is_array(leaf) else leaf

        history = {
            key: np.asarray(value)[:, i] if np.ndim(value) == 2 else value for key, value in self.history.items()
        }
        return Solution(
            model=jax.tree_util.tree_map(pick, self.model),
            result=jax.tree_util.tree_map(pick, self.result),
            message=self.message,
            history=history,
            train_loss=float(np.asarray(self.train_loss)[i]),
            val_loss=float(np.asarray(self.val_loss)[i]),
            exact_val_loss=float(np.asarray(self.exact_val_loss).reshape(-1)[i])
            if np.ndim(self.exact_val_loss)
            else float("nan"),
            evaluations=self.evaluations,
            wall_time=self.wall_time,
        )

    @property
    def best_configuration(self) -> int:
        """A sweep's index with the lowest validation loss (training loss when no validation data was given)."""
        if not self.batched:
            raise TypeError("one fit's Solution has no configurations; `best_start` is the start it kept")
        scores = self.val_loss if np.isfinite(self.val_loss).any() else self.train_loss
        if not np.isfinite(scores).any():
            raise ValueError("no configuration of this sweep has a finite loss: every one diverged")
        return int(np.nanargmin(np.where(np.isfinite(scores), scores, np.nan)))

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
        name is not a literature symbol fricjax knows), `sided`: a (+, -) pair (value and std: v > 0, then v < 0)."""
        rows = []
        units = parameter_units(unwrap(exact(self.model)))
        sided = sided_paths(unwrap(exact(self.model)))
        for path, (value, std) in self.parameters().items():
            value = np.asarray(value)
            std = np.full(value.shape, np.nan) if std is None else np.asarray(std)
            rows.append({"path": path, "value": value, "std": std, "unit": units[path], "sided": path in sided})
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
        if self.batched:
            counts = {code: self.codes.count(code) for code in dict.fromkeys(self.codes)}
            outcome = ", ".join(f"{number} {code}" for code, number in counts.items())
            finite = np.isfinite(self.val_loss).any() or np.isfinite(self.train_loss).any()
            best = f"the best is {self.best_configuration}" if finite else "no finite loss"
            return (
                f"Solution of a sweep of {np.size(self.train_loss)} configurations{effort}: {outcome}; {best} "
                "(`solution[i]` is configuration i's)"
            )
        losses = f"train loss {self.train_loss:.4g}, " + self._validation_text()
        title = "Solution" if self.aux is None else f"Solution ({type(self.aux).__name__})"
        lines = [f"{title}: {self.code}{effort}: {self.message}", losses]
        rows = self.parameter_table()
        # with per-record offsets the model's own `offset` fields were held at their start (fj.Nuisances): the
        # force on record i is the model's, its own offset included, plus record i's offset
        per_record_offsets = self.records is not None and self.records.offset is not None
        bounded = bounded_paths(self.model)
        for row in rows[:max_parameters]:
            line = "  " + parameter_line(row["path"], row["value"], row["std"], row["unit"], sided=row["sided"])
            if per_record_offsets and row["path"].split(".")[-1] == "offset":
                line += " (held; each record's offset below is added to it)"
            if row["path"] in bounded:
                line += " (bounded {:g} .. {:g})".format(*bounded[row["path"]])
            lines.append(line)
        if len(rows) > max_parameters:
            lines.append(f"  ... and {len(rows) - max_parameters} more parameter arrays (Solution.parameters())")
        # what a model of its class should not have (compare's table notes; the bound notes need to know what was
        # trained, which compare does and a Solution does not)
        notes = implausible(self.model, bounds=False)
        if notes:
            lines.append("  implausible: " + "; ".join(notes))
        uncertain = poorly_determined(self.model, self.std)
        if uncertain:
            lines.append("  uncertain: " + "; ".join(uncertain))
        if self.records is not None:
            lines.append(f"  per record ({len(self.records.names)}):")
            lines += ["    " + line for line in self.records.lines()]
        return "\n".join(lines)


FitResult = Solution
