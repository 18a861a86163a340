"""`FitResult`: what `fit` returns, with its parameter table and summary."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._constraints import parameter_arrays, unwrap

RESULT_CODES = {
    "successful": "the solver's convergence test held (optimistix solvers), or the parameters are linear and were "
    "solved by least squares",
    "max_steps": "the step budget ran out before a convergence test held: the best model seen is returned, but it "
    "may not be converged (the message says whether the loss was still falling)",
    "early_stopped": "the validation loss stopped improving (patience exhausted); the best model was kept",
    "diverged": "a loss or parameter became non-finite; the last good model was kept",
    "solver_failed": "the optimistix solver reported a failure; the best model seen was kept",
}


@dataclasses.dataclass(frozen=True)
class FitResult:
    """What `fit` returns.

    - `model`: the fitted model (smoothing as at the end of the fit); `exact_model` is `fj.exact(model)`.
    - `result`: a result code (`successful`, `max_steps`, `early_stopped`, `diverged`, `solver_failed`; see
      `RESULT_CODES`) and `message`, a sentence saying why the fit stopped.
    - `history`: dict of NumPy arrays `step`, `train_loss`, `val_loss` (NaN without validation), `eps`, and
      `time` (seconds since the call started, compilation included).
    - `train_loss`, `val_loss`: final losses of the returned model (validation in free-run simulation);
      `exact_val_loss`: the same with the exact model (NaN without validation data).
    - `evaluations`: loss (+ gradient) evaluations per start; `wall_time` [s]; `num_starts`; `best_start`.
    - `std`: pytree shaped like `fj.unwrap(model)`, the Gauss-Newton standard deviations of the trained
      physical parameters (residual variance x (J^T J)^-1), NaN for frozen ones; `None` if not computed.
    - `extra`: the loss's extra decision variables (multiple-shooting states).
    """

    model: Any
    result: str
    message: str
    history: dict[str, np.ndarray]
    train_loss: float
    val_loss: float
    exact_val_loss: float
    evaluations: int
    wall_time: float
    num_starts: int
    best_start: int
    std: Any = None
    extra: Any = None

    @property
    def success(self) -> bool:
        """True unless the fit diverged or the solver failed."""
        return self.result in ("successful", "max_steps", "early_stopped")

    @property
    def exact_model(self) -> Any:
        from .._smoothing import exact

        return exact(self.model)

    def parameters(self) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
        """`{path: (value, std)}` of the physical parameters of the fitted model (std `None` if unknown)."""
        from .._smoothing import exact

        values = parameter_arrays(unwrap(exact(self.model)))  # exact(): smoothing widths are settings, not parameters
        stds = parameter_arrays(exact(self.std)) if self.std is not None else {}
        return {path: (value, stds.get(path)) for path, value in values.items()}

    def summary(self, max_parameters: int = 20) -> str:
        """A short human-readable report: result, losses, and at most `max_parameters` parameter lines (arrays of
        more than 8 entries are summarised by shape and range)."""
        lines = [
            f"fit: {self.result} after {self.evaluations} evaluations in {self.wall_time:.2f} s: {self.message}",
            f"train loss {self.train_loss:.4g}, validation loss {self.val_loss:.4g} (exact {self.exact_val_loss:.4g})",
        ]
        parameters = list(self.parameters().items())
        for path, (value, std) in parameters[:max_parameters]:
            value = np.asarray(value)
            if value.size > 8:
                lines.append(f"  {path}: shape {value.shape}, range [{value.min():.4g}, {value.max():.4g}]")
                continue
            text = np.array2string(value, formatter={"float_kind": lambda x: f"{x:.6g}"})
            if std is not None and np.all(np.isfinite(std)):
                text += " ± " + np.array2string(np.asarray(std), formatter={"float_kind": lambda x: f"{x:.3g}"})
            lines.append(f"  {path} = {text}")
        if len(parameters) > max_parameters:
            lines.append(f"  ... and {len(parameters) - max_parameters} more parameter arrays (FitResult.parameters())")
        return "\n".join(lines)
