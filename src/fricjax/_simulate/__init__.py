"""`fj.simulate` and the loops over time behind it: the one place in the package where a record is run step by step
(`_scan`: the sequential scan; `_primal`: faster free runs outside derivatives; `_tangent`: the tangent-linear
derivative; `_parallel`: the time-parallel form) and where `run` chooses among them (`_driver`)."""

from ._driver import BATCHING, DERIVATIVES, check_force_shape, check_options, run, simulate
from ._parallel import PARALLEL_MIN_LENGTH, SCANS, on_accelerator
from ._scan import BATCH_MINOR_UNROLL, DEFAULT_UNROLL, split_time_signals

__all__ = [
    "BATCHING",
    "BATCH_MINOR_UNROLL",
    "DEFAULT_UNROLL",
    "DERIVATIVES",
    "PARALLEL_MIN_LENGTH",
    "SCANS",
    "check_force_shape",
    "check_options",
    "on_accelerator",
    "run",
    "simulate",
    "split_time_signals",
]
