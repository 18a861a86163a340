"""fricjax (its public names, at first use) runs the OpenBLAS behind JAX's CPU LAPACK calls (SciPy's bundled copy) on
one thread, leaves it alone when the user chose (`OPENBLAS_NUM_THREADS`, `OMP_NUM_THREADS`) or opts out, and LAPACK
results stay right (src/fricjax/_lapack_threads.py). Each case runs in a fresh interpreter, reading the thread count
through the library's own C function."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

import pytest
import scipy

_SCIPY = pathlib.Path(scipy.__file__).resolve().parent
LIBRARIES = sorted(
    path
    for folder in (_SCIPY.parent / "scipy.libs", _SCIPY / ".dylibs")
    if folder.is_dir()
    for path in folder.glob("*openblas*")
)
pytestmark = pytest.mark.skipif(not LIBRARIES, reason="SciPy without its bundled OpenBLAS (not a PyPI wheel)")
USER_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS", "FRICJAX_KEEP_BLAS_THREADS")
ALLOWED_CPUS = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)

PROBE = """
import ctypes, json, sys
if sys.argv[1] == "fricjax":
    import fricjax
    fricjax.simulate  # the public names load on first use (fricjax/__init__.py), and set the threads then
else:
    import scipy.linalg.cython_lapack
library = ctypes.CDLL(sys.argv[2])
get = getattr(library, "scipy_openblas_get_num_threads", None) or library.openblas_get_num_threads
print(json.dumps(get()))
"""

# two independent SVDs per step (XLA may run them at once on its pool), checked against NumPy in a fresh
# interpreter with a time limit: two LAPACK calls at once have deadlocked XLA's pool before (_kernel_narx.py)
SIDE_BY_SIDE = """
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import fricjax
a = np.random.default_rng(0).standard_normal((4, 120, 40))
def step(carry, k):
    x = jnp.asarray(a)[k]
    return carry, (jnp.linalg.svd(x, compute_uv=False), jnp.linalg.svd(x.T @ x, compute_uv=False))
_, (s1, s2) = jax.jit(lambda: jax.lax.scan(step, 0.0, jnp.arange(4)))()
for k in range(4):
    np.testing.assert_allclose(s1[k], np.linalg.svd(a[k], compute_uv=False), rtol=1e-12)
    np.testing.assert_allclose(s2[k], np.linalg.svd(a[k].T @ a[k], compute_uv=False), rtol=1e-10)
print("ok")
"""


def _run(source: str, *args: str, **env: str) -> str:
    environ = {k: v for k, v in os.environ.items() if k not in USER_VARIABLES}
    environ.update(JAX_PLATFORMS="cpu", **env)
    result = subprocess.run(
        [sys.executable, "-c", source, *args], env=environ, capture_output=True, text=True, timeout=180, check=False
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return result.stdout.strip().splitlines()[-1]


def _threads(*, import_fricjax: bool = True, **env: str) -> int:
    return json.loads(_run(PROBE, "fricjax" if import_fricjax else "scipy", str(LIBRARIES[0]), **env))


@pytest.mark.slow  # a few seconds (a subprocess or a fit): the fast tier stays under 5 minutes
def test_import_sets_scipys_openblas_to_one_thread_and_respects_the_users_choice():
    assert _threads() == 1
    untouched = _threads(import_fricjax=False)
    assert _threads(FRICJAX_KEEP_BLAS_THREADS="1") == untouched
    if ALLOWED_CPUS >= 2:
        assert untouched >= 2  # OpenBLAS's own default: one thread per CPU the process may use
        for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
            assert _threads(**{variable: "2"}) == 2, variable


@pytest.mark.slow  # a subprocess (~2 s): the fast tier stays well under 5 minutes
def test_lapack_calls_running_side_by_side_in_a_scan_are_right():
    assert _run(SIDE_BY_SIDE) == "ok"
