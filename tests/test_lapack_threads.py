"""`import fricjax` runs the OpenBLAS behind JAX's CPU LAPACK calls (SciPy's bundled copy) on one thread, leaves it
alone when the user chose (`OPENBLAS_NUM_THREADS`) or opts out, and LAPACK results stay right
(src/fricjax/_lapack_threads.py). Each case runs in a fresh interpreter, reading the thread count through the
library's own C function."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy

import fricjax  # noqa: F401

LIBRARIES = sorted((pathlib.Path(scipy.__file__).resolve().parents[1] / "scipy.libs").glob("*openblas*"))
pytestmark = pytest.mark.skipif(not LIBRARIES, reason="SciPy without its bundled OpenBLAS (not a PyPI wheel)")

PROBE = """
import ctypes, json, sys
if sys.argv[1] == "fricjax":
    import fricjax
else:
    import scipy.linalg.cython_lapack
library = ctypes.CDLL(sys.argv[2])
get = getattr(library, "scipy_openblas_get_num_threads", None) or library.openblas_get_num_threads
print(json.dumps(get()))
"""


def _threads(*, import_fricjax: bool = True, **env: str) -> int:
    environ = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "FRICJAX_KEEP_BLAS_THREADS")}
    environ.update(JAX_PLATFORMS="cpu", **env)
    result = subprocess.run(
        [sys.executable, "-c", PROBE, "fricjax" if import_fricjax else "scipy", str(LIBRARIES[0])],
        env=environ,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_import_sets_scipys_openblas_to_one_thread_and_respects_the_users_choice():
    assert _threads() == 1
    assert _threads(OPENBLAS_NUM_THREADS="2") == 2
    untouched = _threads(import_fricjax=False)
    assert _threads(FRICJAX_KEEP_BLAS_THREADS="1") == untouched
    if (os.cpu_count() or 1) > 1:
        assert untouched > 1  # OpenBLAS's own default: one thread per core


def test_lapack_calls_running_side_by_side_in_a_scan_are_right():
    """Two independent SVDs per step (XLA may run them at once on its pool), checked against NumPy."""
    a = np.random.default_rng(0).standard_normal((4, 120, 40))

    def step(carry, k):
        s1 = jnp.linalg.svd(jnp.asarray(a)[k], compute_uv=False)
        s2 = jnp.linalg.svd(jnp.asarray(a)[k].T @ jnp.asarray(a)[k], compute_uv=False)
        return carry, (s1, s2)

    _, (s1, s2) = jax.jit(lambda: jax.lax.scan(step, 0.0, jnp.arange(4)))()
    for k in range(4):
        np.testing.assert_allclose(s1[k], np.linalg.svd(a[k], compute_uv=False), rtol=1e-12)
        np.testing.assert_allclose(s2[k], np.linalg.svd(a[k].T @ a[k], compute_uv=False), rtol=1e-10)
