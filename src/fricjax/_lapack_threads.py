"""The LAPACK setting fricjax makes: the OpenBLAS behind JAX's CPU linear algebra runs on one thread.

On CPU, `jnp.linalg` (QR, SVD, eigh, Cholesky, solves) calls LAPACK through `scipy.linalg.cython_lapack`, which in
SciPy's wheels is SciPy's own OpenBLAS (`scipy.libs/libscipy_openblas*`; NumPy carries a separate copy). XLA makes
those calls from the worker threads of its intra-op pool, one per core, and OpenBLAS then starts its own threads,
one per core, which spin while they wait for work. When XLA runs two thunks at once (independent operations of one
program), or any other process needs a core, the spinning threads take the cores from the threads they wait for.
Measured on the 2-core CPU of benchmarks/README.md (jaxlib 0.10.2, SciPy 1.17.1, `benchmarks/lapack_threads.py`,
`results/lapack-threads.jsonl`): a scan of 50 steps, each a QR, an eigh and an SVD of 200 x 200 matrices, takes
0.196 s quiet (0.209 s with two threads), but 0.77 s beside one busy process and 1.91 s (worst 3.3 s) beside another
JAX program with OpenBLAS's default threads, against 0.204 s and 0.254 s on one thread; beside a notebook running
fits it took 0.35-33 s (an unrecorded run). A notebook's linear-in-parameters fits once stalled in CI far past their
usual time (cause not established), and the kernel NARX solver already avoids two LAPACK calls at once because they
deadlocked (`_estimation/families/_kernel_narx.py`). The price: a large factorisation alone on a quiet machine loses
OpenBLAS's second core (the direct kernel solve of 4 000 samples 1.04 -> 1.22 s,
`results/kernel-blas-threads.jsonl`).

fricjax therefore sets that OpenBLAS to one thread (`scipy_openblas_set_num_threads(1)`) when its public names load
(at the first use of one of them after `import fricjax`, before any computation of fricjax's) and when the command
line starts, which keeps the parallelism with XLA's pool, where it belongs. It affects `scipy.linalg` in the same
process too, not NumPy's linear algebra. It does nothing when the library is not SciPy's bundled OpenBLAS (a SciPy
built on MKL or a system BLAS), when the user chose a thread count (`OPENBLAS_NUM_THREADS`, `GOTO_NUM_THREADS` or
`OMP_NUM_THREADS`, which OpenBLAS reads), or when `FRICJAX_KEEP_BLAS_THREADS` is set to a non-empty value.

**Batched calls deadlock.** jaxlib 0.10.2's LAPACK kernels (`jaxlib/cpu/lapack_kernels.cc`, `ParallelBatchMap`)
split a *batch* of matrices (a call under `vmap`, or on stacked matrices) whose work exceeds about 2e5 flops into
chunks, schedule them on XLA's intra-op pool (the threads named `tf_XLAEigen`, one per core) and block on an
`absl::BlockingCounter` until they are done. A call made from a pool thread waits there while holding that thread;
when as many batched calls run at once as the pool has threads (two independent thunks on 2 cores, e.g. the full
batches and the remainder of a `lax.map(..., batch_size=)`), every thread waits for chunks no thread is left to run:
a native deadlock, intermittent, likelier on a busy machine (notebook 06's local models hung in CI with both pool
threads in `lapack_dgesdd_ffi -> ParallelBatchMap -> BlockingCounter::Wait`). A call on one matrix (batch 1) runs
inline on its own thread and never waits (`chunk_size >= batch_count`); jax's sources after 0.11.0 compile the
pool path out of open-source builds (jax commit 859992407d). `thin_svd` is an SVD that stays one matrix per LAPACK
call under any `vmap`, for code that is vmapped (`LocalModel`'s local fits); the kernel NARX solvers loop their
factorisations with `lax.map` (no `batch_size`) for the same reason (`_estimation/families/_kernel_solvers.py`).
"""

from __future__ import annotations

import ctypes
import os
import pathlib
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp

# the user's own choice of BLAS threads: OpenBLAS reads these at load, in this order of precedence
USER_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")
_SETTERS = ("scipy_openblas_set_num_threads", "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads", "openblas_get_num_threads")


def scipy_openblas_libraries() -> list[pathlib.Path]:
    """The OpenBLAS shared libraries bundled with the installed SciPy wheel (none for other builds)."""
    try:
        import scipy
    except ImportError:  # pragma: no cover - SciPy is a dependency of JAX
        return []
    package = pathlib.Path(scipy.__file__).resolve().parent
    folders = (package.parent / "scipy.libs", package / ".dylibs", package.parent / "scipy.libs" / "bin")
    return sorted(path for folder in folders if folder.is_dir() for path in folder.glob("*openblas*"))


def _loaded_functions(names: tuple[str, ...]) -> dict[str, Any]:
    """The first of `names` found in each bundled OpenBLAS that is already loaded, by library file name (a file
    not loaded is not opened: loading a second OpenBLAS would start its own threads)."""
    mode = getattr(os, "RTLD_NOLOAD", 0)
    found = {}
    for path in scipy_openblas_libraries():
        try:
            library = ctypes.CDLL(str(path), mode=mode)  # the handle of the copy in use
        except OSError:  # not loaded, or not a loadable library
            continue
        for name in names:
            function = getattr(library, name, None)
            if function is not None:
                found[path.name] = function
                break
    return found


def blas_threads() -> dict[str, int]:
    """Threads of each loaded SciPy OpenBLAS, by library file name (for benchmarks and bug reports)."""
    counts = {}
    for name, getter in _loaded_functions(_GETTERS).items():
        getter.restype = ctypes.c_int
        counts[name] = int(getter())
    return counts


def limit_blas_threads(environ: Mapping[str, str], threads: int = 1) -> list[str]:
    """Set SciPy's bundled OpenBLAS to `threads` threads unless `environ` opts out (`FRICJAX_KEEP_BLAS_THREADS`,
    or a thread count of the user's: `USER_THREAD_VARIABLES`); returns the libraries set."""
    if environ.get("FRICJAX_KEEP_BLAS_THREADS") or any(environ.get(key) for key in USER_THREAD_VARIABLES):
        return []
    try:
        import scipy.linalg.cython_lapack  # noqa: F401  (loads the library JAX's LAPACK calls go to)
    except ImportError:  # pragma: no cover - SciPy is a dependency of JAX
        return []
    done = []
    for name, setter in _loaded_functions(_SETTERS).items():
        setter.argtypes = [ctypes.c_int]
        setter(threads)
        done.append(name)
    return done


@jax.custom_batching.sequential_vmap
def _svd_one_at_a_time(matrix: Any) -> Any:
    """LAPACK's thin SVD; under `vmap`, a `lax.map` over the batch: one matrix per call (see the module docstring)."""
    u, s, vh = jnp.linalg.svd(matrix, full_matrices=False)
    return u, s, vh  # a tuple, not jnp's named result: the derivative rule returns the same structure


@jax.custom_jvp
def thin_svd(matrix: Any) -> tuple[Any, Any, Any]:
    """`jnp.linalg.svd(matrix, full_matrices=False)` (`(u, s, vh)`, the same LAPACK routine and results) for a real
    `(m, n)` matrix, made one matrix per LAPACK call however it is vmapped, so that it never enters jaxlib's
    batch-parallel path, which can deadlock XLA's CPU thread pool (module docstring). As fast as the batched
    call (a batch of 768 matrices 300 x 28: 0.18-0.20 s either way on 2 cores, OpenBLAS on one thread).
    Differentiable (`jax.custom_batching` rules are not, so the derivative is written out: JAX's SVD rule, with
    zero singular values given zero weight in the division by `s`)."""
    return _svd_one_at_a_time(matrix)


@thin_svd.defjvp
def _thin_svd_jvp(primals: Any, tangents: Any) -> Any:
    (a,), (da,) = primals, tangents
    u, s, vh = _svd_one_at_a_time(a)  # on primals only: the tangents below are linear, so `grad` can transpose them
    v = vh.T
    ds_full = u.T @ da @ v
    ds = jnp.diagonal(ds_full)
    gaps = (s[None, :] + s[:, None]) * (s[None, :] - s[:, None])  # s_j^2 - s_i^2
    f = jnp.where(gaps == 0, 0.0, 1.0 / jnp.where(gaps == 0, 1.0, gaps))
    inverse = jnp.where(s == 0, 0.0, 1.0 / jnp.where(s == 0, 1.0, s))
    du = u @ (f * (ds_full * s[None, :] + (ds_full * s[None, :]).T))
    dv = v @ (f * (s[:, None] * ds_full + (s[:, None] * ds_full).T))
    m, n = a.shape[-2:]
    if m > n:  # the part of da v outside the span of u
        dav = da @ v
        du = du + (dav - u @ (u.T @ dav)) * inverse[None, :]
    if n > m:
        dau = da.T @ u
        dv = dv + (dau - v @ (v.T @ dau)) * inverse[None, :]
    return (u, s, vh), (du, ds, dv.T)


def configure() -> None:
    """Called once by `import fricjax`."""
    limit_blas_threads(os.environ)


configure()
