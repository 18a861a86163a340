"""Former home of `FitResult` (now `fj.Solution`, in `_solution.py`): the names, for the modules not yet moved."""

from ._solution import RESULT_CODES as RESULT_CODES
from ._solution import FitResult as FitResult
