"""No batched LAPACK call where fricjax vmaps its linear algebra (src/fricjax/_lapack_threads.py, "Batched calls
deadlock"): jaxlib 0.10.2 splits a batch of matrices over XLA's CPU thread pool and blocks a pool thread until the
chunks are done, which deadlocks when as many such calls run at once as the pool has threads (notebook 06's local
models: both `tf_XLAEigen` threads in `lapack_dgesdd_ffi -> ParallelBatchMap -> BlockingCounter::Wait`). A call
on one matrix runs inline, so the programs JAX compiles are read (`jax_dump_ir_to`) for LAPACK custom calls with
batch dimensions; the intermittent hang itself is not tested (it needs a busy machine and minutes).

1. The local models' truncated principal component regression (`fj.LocalModel(kind="linear")`, all points
   neighbours) against a NumPy oracle built on `numpy.linalg.svd` / `lstsq`, on random problems (tall and wide,
   rank- and rcond-truncated, a zero column), queries batched as `identify_local_model` batches them.
2. The programs of `identify_local_model` (grid predictions and free runs), the kernel NARX solvers and a
   multi-start fit with separable parameters: every SVD, Cholesky, QR and eigendecomposition on one matrix (the
   fit's Levenberg-Marquardt QR solve, optimistix's, stays batched: one dependent chain per step).
"""

from __future__ import annotations

import glob
import re

import jax
import numpy as np
import pytest

import fricjax as fj

LAPACK_CALL = re.compile(r"custom_call @(lapack_\w+)\(.*?num_batch_dims = \"(\d+)\"")


def lapack_calls(run, tmp_path) -> list[tuple[str, int]]:
    """`(target, number of batch dimensions)` of every LAPACK call in the programs `run()` compiles."""
    jax.clear_caches()  # compile afresh, so that every program is dumped
    jax.config.update("jax_dump_ir_to", str(tmp_path))
    try:
        run()
    finally:
        jax.config.update("jax_dump_ir_to", "")
    calls = []
    for path in glob.glob(str(tmp_path / "*.mlir")):
        with open(path) as file:
            calls += [(m.group(1), int(m.group(2))) for m in LAPACK_CALL.finditer(file.read())]
    return calls


def assert_one_matrix_per_call(calls, expected: set[str], allowed_batched: frozenset[str] = frozenset()) -> None:
    assert {target for target, _ in calls} >= expected, calls
    batched = sorted({target for target, dims in calls if dims and target not in allowed_batched})
    assert not batched, f"batched LAPACK calls (can deadlock XLA's CPU thread pool): {batched}"


# ----------------------------------------------------------------------------------------------------------------
# 1. truncated principal component regression against NumPy
# ----------------------------------------------------------------------------------------------------------------


def tpcr_numpy(points, forces, query, rank, rcond):
    """The local linear prediction with every point a neighbour: centred TPCR by NumPy (the principal components
    from `numpy.linalg.svd`, the least-squares fit on the kept ones by `numpy.linalg.lstsq`)."""
    zbar, fbar = points.mean(axis=0), forces.mean()
    centred = points - zbar
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    floor = max(rcond, np.finfo(float).eps * max(centred.shape)) * s[0]
    basis = vt[(s > floor) & (np.arange(s.size) < rank)].T  # (D, r)
    slope = basis @ np.linalg.lstsq(centred @ basis, forces - fbar, rcond=None)[0]
    return fbar + (query - zbar) @ slope


CASES = {
    "tall, full rank": dict(shape=(40, 6), rank=None, rcond=0.0),
    "tall, rank 3": dict(shape=(40, 6), rank=3, rcond=0.0),
    "tall, rcond": dict(shape=(40, 6), rank=None, rcond=0.3),
    "zero column": dict(shape=(30, 8), rank=None, rcond=1e-3, zero=(1, 5)),
    "wide": dict(shape=(5, 9), rank=None, rcond=1e-3),
}


@pytest.mark.parametrize(
    "name",  # the two other tall cases compile their own programs: slow tier (fast tier trimmed, 2026-11-27)
    [
        n if n in ("tall, full rank", "zero column", "wide") else pytest.param(n, marks=pytest.mark.slow)
        for n in sorted(CASES)
    ],
)
def test_local_linear_fit_is_truncated_principal_component_regression(name):
    case = CASES[name]
    rng = np.random.default_rng(2)
    count, dims = case["shape"]
    points = rng.normal(size=(count, dims)) * np.geomspace(1.0, 1e-2, dims)  # the truncation picks some
    points[:, list(case.get("zero", ()))] = 0.0
    forces, queries = rng.normal(size=count), rng.normal(size=(300, dims))  # 256 + a remainder of 44
    model = fj.LocalModel(
        fj.NARXRegressors(("x",), dims - 1, 0),
        points,
        forces,
        neighbours=count,
        kind="linear",
        rank=case["rank"],
        rcond=case["rcond"],
    )
    rank = dims if case["rank"] is None else case["rank"]
    expected = [tpcr_numpy(points, forces, q, rank, case["rcond"]) for q in queries]
    np.testing.assert_allclose(model.predict(queries), expected, rtol=1e-9, atol=1e-10)
    # reverse mode through the one-at-a-time SVD: the derivative in the query is the TPCR slope
    slope = jax.grad(lambda q: model.predict(q[None])[0])(jax.numpy.asarray(queries[0]))
    zero = np.zeros(dims)
    expected_slope = [
        tpcr_numpy(points, forces, e, rank, case["rcond"]) - tpcr_numpy(points, forces, zero, rank, case["rcond"])
        for e in np.eye(dims)
    ]
    np.testing.assert_allclose(slope, expected_slope, rtol=1e-8, atol=1e-9)


# ----------------------------------------------------------------------------------------------------------------
# 2. compiled programs
# ----------------------------------------------------------------------------------------------------------------


def tribometer_split():
    t = np.arange(420) * 1e-3
    x = 1e-5 * np.sin(40 * t) * (0.5 + t)
    data = fj.FrictionData(fj.Motion.from_position(x, dt=1e-3), np.tanh(2e5 * x))
    return data, data.slice(0, 300)


@pytest.mark.parametrize("output_embedding", [0, pytest.param(1, marks=pytest.mark.slow)])
@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 319 s)
def test_local_model_grid_runs_one_neighbourhood_per_lapack_call(output_embedding, tmp_path):
    """`identify_local_model` as the knn recipe runs it: configurations looped, neighbour masks vmapped, queries
    `batch_size` at a time (before: the full batches and the remainder, two independent batched SVDs, which hung
    notebook 06); with fed-back forces, the free runs (a vmapped scan)."""
    data, train = tribometer_split()

    def run():
        fj.identify_local_model(
            train,
            validation=data,
            validation_burn_in=300,
            embedding=(1, 2),
            delay=1,
            neighbours=(6, 12),
            kind="linear",
            output_embedding=output_embedding,
        )

    assert_one_matrix_per_call(lapack_calls(run, tmp_path), {"lapack_dgesdd_ffi"})


@pytest.mark.slow  # moved from the fast tier (2-core Xeon, 2026-11-27): an HLO structure check
@pytest.mark.parametrize("solver", ["direct", "nystrom", "cg"])
def test_kernel_solvers_run_one_matrix_per_lapack_call(solver, tmp_path):
    data, train = tribometer_split()

    def run():
        fj.identify_kernel_narx(
            train,
            signals=("x",),
            input_lags=2,
            output_lags=0,
            kernel="exponential",
            width=[10.0, 30.0],
            ridge=[1e-4, 1e-2],
            solver=solver,
            landmarks=None if solver == "direct" else 40,
            validation=data,
            validation_burn_in=300,
        )

    expected = {"lapack_dpotrf_ffi"} if solver == "direct" else {"lapack_dsyevd_ffi", "lapack_dgeqrf_ffi"}
    assert_one_matrix_per_call(lapack_calls(run, tmp_path), expected)


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 345 s)
def test_multistart_fit_with_separable_parameters_runs_one_svd_per_lapack_call(tmp_path):
    """The separable solve (`fj.lstsq`'s SVD) is vmapped over the starts; optimistix's QR solve of the
    Levenberg-Marquardt step stays batched (geqrf -> ormqr -> trsm, each waiting for the one before)."""
    data, train = tribometer_split()
    start = fj.CoulombViscous(Fc=0.5, Fv=1.0, offset=0.1, smoothing=fj.Smooth(1e-4))

    def run():
        fj.fit(
            start,
            train,
            solver=fj.levenberg_marquardt(),
            steps=2,
            multistart=fj.MultiStart(count=3, spread=0.3),
            separable=("offset",),
            compute_std=False,
        )

    qr_solve = frozenset({"lapack_dgeqrf_ffi", "lapack_dormqr_ffi", "lapack_dtrsm_ffi"})
    assert_one_matrix_per_call(lapack_calls(run, tmp_path), {"lapack_dgesdd_ffi"}, allowed_batched=qr_solve)
