"""Where a fit runs: the accelerator for batched work and long records with a time-parallel form, the host CPU for
one sequential run.

On a GPU every step of a sequential scan is a kernel launch of several microseconds, so a single free run of a
model without a time-parallel form (GMS, DNLRX, NARX networks) is 100-500x slower than on the CPU, while batched
work (multi-start, sweeps) and the parallel form of long records are many times faster there
(benchmarks/README.md, "Accelerators"). `fj.fit(..., device="auto")` (and `fricjax compare --device auto`)
therefore chooses per fit; `device="cpu"` / `"accelerator"` / a `jax.Device` force the choice.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from typing import Any

import equinox as eqx
import jax

from ..._constraints import unwrap
from ..._data._record import FrictionData
from ..._models._base import AbstractModel
from ..._simulate import on_accelerator
from ..._simulate._parallel import has_parallel_form

DEVICES = ("auto", "cpu", "gpu", "accelerator")  # "gpu": the accelerator, by its usual name
# `device="auto"` keeps a single fit on the accelerator from this many samples on when the model has a
# time-parallel form (below it, compiling for the GPU costs more than the CPU's whole fit; benchmarks/README.md)
ACCELERATOR_MIN_LENGTH = 200_000


# a device every `device="auto"` fit inside `forced_device(...)` takes (`fricjax compare --device gpu|cpu`)
_FORCED: contextvars.ContextVar[Any] = contextvars.ContextVar("fricjax_forced_device", default=None)


@contextlib.contextmanager
def forced_device(device: Any) -> Iterator[None]:
    """Within the block, JAX's default device is `device` (a `jax.Device`; None: unchanged) and every
    `fj.fit(..., device="auto")` stays on it."""
    if device is None:
        yield
        return
    token = _FORCED.set(device)
    try:
        with jax.default_device(device):
            yield
    finally:
        _FORCED.reset(token)


def resolve_device(device: Any) -> Any:
    """`"cpu"` / `"gpu"` / `"accelerator"` as a `jax.Device` (None: keep the default device, for `"auto"`)."""
    check_device(device)
    if device == "cpu":
        return jax.devices("cpu")[0]
    if device in ("gpu", "accelerator"):
        return jax.devices()[0] if on_accelerator() else _accelerators()[0]
    return device if isinstance(device, jax.Device) else None


def check_device(device: Any, where: str = "fit") -> None:
    """Validate a `device=` argument: one of `DEVICES`, a `jax.Device`, or None (JAX's default device)."""
    if device is None or isinstance(device, jax.Device):
        return
    if device not in DEVICES:
        raise ValueError(
            f"{where}: `device` must be one of {DEVICES}, a jax.Device or None, got {device!r} "
            "(e.g. device='cpu' to run on the host, or jax.devices('gpu')[0])."
        )
    if device in ("gpu", "accelerator") and not on_accelerator() and not _accelerators():
        raise ValueError(
            f"{where}: device={device!r} but JAX sees only CPU devices ({jax.devices()}); use device='cpu' or 'auto'."
        )


def _accelerators() -> list[Any]:
    return [d for d in jax.devices() if d.platform != "cpu"]


def choose_device(model: Any, data: Any, device: Any, batched: bool) -> tuple[Any, str]:
    """The device a fit of `model` on `data` runs on, and why: `(None, reason)` keeps JAX's default device.

    `device="auto"`: on a CPU default device, stay; on an accelerator, stay for batched work (`batched`: several
    starts) and for a model with a time-parallel form on a record of at least `ACCELERATOR_MIN_LENGTH` samples,
    else the host CPU. `"cpu"`, `"accelerator"`, a `jax.Device`: that device."""
    check_device(device)
    if device == "auto" and _FORCED.get() is not None:
        return None, "the device of the enclosing run"
    if device is None:
        return None, "JAX's default device"
    if isinstance(device, jax.Device):
        return device, f"asked for ({device.platform})"
    if device == "cpu":
        return (jax.devices("cpu")[0], "asked for") if on_accelerator() else (None, "asked for")
    if device in ("gpu", "accelerator"):
        return (None, "asked for") if on_accelerator() else (_accelerators()[0], "asked for")
    if not on_accelerator():
        return None, "no accelerator is the default device"
    if batched:
        return None, "batched work (several starts) runs on the accelerator"
    if isinstance(model, AbstractModel) and isinstance(data, FrictionData):
        friction = unwrap(model)
        parallel = has_parallel_form(friction, friction.samples(data.motion))
        if parallel and data.length >= ACCELERATOR_MIN_LENGTH:
            return None, f"time-parallel form on {data.length} samples"
        why = "a short record" if parallel else "no time-parallel form: one launch per step on the accelerator"
        return jax.devices("cpu")[0], f"sequential work on the host CPU ({why})"
    return jax.devices("cpu")[0], "sequential work on the host CPU"


def to_device(tree: Any, device: Any) -> Any:
    """The arrays of `tree` placed on `device` (other leaves unchanged)."""
    arrays, rest = eqx.partition(tree, eqx.is_array)
    return eqx.combine(jax.device_put(arrays, device), rest)
