"""The solvers of kernel ridge regression, `(K + rho I) alpha = y` on the teacher-forced rows of a record, for
`identify_kernel_narx` (`_kernel_narx`, whose docstring describes the methods):

- `"direct"`: the N x N kernel matrix and one Cholesky factor per ridge value (`_direct`).
- `"cg"`: conjugate gradients (`lineax.CG`) with the matrix-free, blocked kernel matvec (`_gram_times`),
  preconditioned by a Nyström approximation of K from m landmark rows (`_cg`, `_nystrom_factors`).
- `"nystrom"`: m landmark rows as the centres, the reduced ridge problem solved through a QR factor of the
  Nyström features (`_nystrom`).

`_Rows` holds the normalised rows and target a solver works on; `_solve` runs the chosen solver for every width and
ridge of one kernel at once. Widths are looped (`lax.map`), not vmapped: batched LAPACK calls on XLA's CPU thread
pool deadlock when two run at once, as a QR's orthogonal factor and the eigendecomposition that needs only its R
can (jaxlib 0.10.2 on 2 cores); one width at a time also bounds the memory to one kernel matrix.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np

from ..._constraints import unwrap
from ..._data._record import FrictionData
from ..._models.blackbox._kernel import AbstractKernel, ExponentialKernel, KernelNARX, PolynomialKernel
from ..._models.blackbox._regressors import NARXRegressors
from ..._validation import nonnegative_int
from ..linear._regressor_rows import teacher_forced_rows

# the memory [bytes] of one block of kernel rows in the matrix-free products
_BLOCK_BYTES = 2**25
# the largest N x N Cholesky factor the direct solver attempts on CPU: jaxlib 0.10.2's LAPACK (32-bit integers,
# through SciPy's OpenBLAS) segfaults between N = 15 500 (works) and 15 900 (measured on this project's machine)
_DIRECT_CPU_MAX = 15_500
# eigenvalues of the landmark kernel matrix below this many machine epsilons x the largest are dropped (float64:
# 2e-12; the polynomial kernel's matrices are rank-deficient): the Nyström features `K_nm V L^(-1/2)` then carry
# relative errors of about eps / sqrt(that fraction)
_RCOND_EPS = 1e4


# ----------------------------------------------------------------------------------------------------------------
# rows, kernels, blocks
# ----------------------------------------------------------------------------------------------------------------


class _Rows(NamedTuple):
    rows: np.ndarray  # (N, P) normalised regressor rows
    target: np.ndarray  # (N,) normalised force
    offset: float  # the constant b: the target's mean

    @classmethod
    def build(
        cls, data: FrictionData, regs: NARXRegressors, burn_in: int | None, where: str, burn_default: bool = True
    ) -> _Rows:
        lag = max(regs.input_lags, regs.output_lags)
        start = (lag if burn_default else 0) if burn_in is None else burn_in
        start = nonnegative_int(start, "burn_in", where, hint="(samples)")
        if data.length - start < 2:
            raise ValueError(
                f"{where}: too few samples: {data.length} in the record, {data.length - start} after the burn-in of "
                f"{start}; pass a longer record or lower the lags / `burn_in`."
            )
        template = KernelNARX(regs, PolynomialKernel(1), np.zeros((1, regs.size)), np.zeros(1))
        template.check_inputs(data.motion)
        rows = np.asarray(teacher_forced_rows(regs, data.motion.samples(regs.requires), data.force), np.float64)
        rows = rows[start:]
        scales = unwrap(regs)
        force = np.asarray(data.force, np.float64)[start:]
        target = (force - float(scales.output_mean)) / float(scales.output_scale)
        return cls(rows, target, float(np.mean(target)))


def _kernel(kind: str, degree: Any, width: Any) -> AbstractKernel:
    return PolynomialKernel(degree) if kind == "polynomial" else ExponentialKernel(width)


def _block(rows: int, columns: int, block_size: int | None) -> int:
    if block_size is not None:
        return int(min(block_size, rows))
    return int(max(1, min(rows, _BLOCK_BYTES // (8 * max(columns, 1)))))


# ----------------------------------------------------------------------------------------------------------------
# solvers
# ----------------------------------------------------------------------------------------------------------------


class _Solved(NamedTuple):
    alphas: np.ndarray  # (W, R, m)
    centres: np.ndarray  # (m, P)
    steps: np.ndarray | None  # (W, R) CG iterations


def _solve(
    kind: str,
    degree: Any,
    widths: np.ndarray,
    fit: _Rows,
    ridges: np.ndarray,
    solver: str,
    landmarks: np.ndarray | None,
    tolerance: float,
    max_steps: int,
    block_size: int | None,
) -> _Solved:
    rows, target = jnp.asarray(fit.rows), jnp.asarray(fit.target - fit.offset)
    n = rows.shape[0]
    widths_j, ridges_j = jnp.asarray(widths, rows.dtype), jnp.asarray(ridges, rows.dtype)
    if solver == "direct":
        if n > _DIRECT_CPU_MAX and jax.default_backend() == "cpu":
            raise ValueError(
                f"identify_kernel_narx: solver='direct' on {n} rows: the {n} x {n} Cholesky factor crashes jaxlib's "
                f"CPU LAPACK above {_DIRECT_CPU_MAX} rows (32-bit integers); use solver='cg' (matrix-free, the same "
                "solution) or solver='nystrom' (m landmarks)."
            )
        alphas = _direct(kind, degree, widths_j, rows, target, ridges_j)
        return _Solved(np.asarray(alphas), fit.rows, None)
    assert landmarks is not None or solver == "cg"
    m = 0 if landmarks is None else len(landmarks)
    if solver == "nystrom":
        assert landmarks is not None
        block = _block(n, m, block_size)
        alphas = _nystrom(kind, degree, widths_j, rows, target, ridges_j, jnp.asarray(landmarks), block)
        return _Solved(np.asarray(alphas), fit.rows[landmarks], None)
    block = _block(n, n, block_size)
    index = jnp.asarray(np.arange(0) if landmarks is None else landmarks)
    alphas, steps = _cg(kind, degree, widths_j, rows, target, ridges_j, index, tolerance, max_steps, block)
    return _Solved(np.asarray(alphas), fit.rows, np.asarray(steps))


@functools.partial(jax.jit, static_argnames=("kind", "degree", "block"))
def _gram_times_jit(kind: str, degree: Any, width: Any, rows: Any, centres: Any, matrix: Any, block: int) -> Any:
    return _gram_times(_kernel(kind, degree, width), rows, centres, matrix, block)


def _gram_times(kernel: AbstractKernel, rows: Any, centres: Any, matrix: Any, block: int) -> Any:
    """`gram(rows, centres) @ matrix`, the kernel matrix made and used one block of `block` rows at a time, so
    that it is never held whole (memory `block x len(centres)`)."""
    n = rows.shape[0]
    blocks = -(-n // block)
    padded = jnp.concatenate([rows, jnp.zeros((blocks * block - n, rows.shape[1]), rows.dtype)])
    out = jax.lax.map(lambda r: kernel.gram(r, centres) @ matrix, padded.reshape(blocks, block, rows.shape[1]))
    return out.reshape((blocks * block, *out.shape[2:]))[:n]


@functools.partial(jax.jit, static_argnames=("kind", "degree"))
def _direct(kind: str, degree: Any, widths: Any, rows: Any, target: Any, ridges: Any) -> Any:
    """`(K + rho I)^-1 y` for every width and ridge (one kernel matrix, then one Cholesky factor each, in turn)."""
    eye = jnp.eye(rows.shape[0], dtype=rows.dtype)

    def per_width(width: Any) -> Any:
        gram = _kernel(kind, degree, width).gram(rows, rows)

        def per_ridge(ridge: Any) -> Any:
            factor = jax.scipy.linalg.cho_factor(gram + ridge * eye, lower=True)
            return jax.scipy.linalg.cho_solve(factor, target)

        # one factor at a time: the eigendecomposition that would serve every ridge at once costs about ten
        # Cholesky factors on CPU (measured, n = 4800), more than a grid of ridges usually holds
        return jax.lax.map(per_ridge, ridges)

    return jax.lax.map(per_width, widths)


class _Nystrom(NamedTuple):
    """The Nyström approximation `K ~ K_nm K_mm^+ K_mn = Phi Phi^T` of the kernel matrix from m landmark rows, in
    factors that never form `Phi^T Phi` (its round-off would square the condition number): `Phi = K_nm T = Q R`
    (QR; `T = V L^(-1/2)` from `K_mm = V L V^T`, eigenvalues below `_RCOND_EPS` machine epsilons x the largest
    dropped as zero columns) and `R R^T = U S U^T`, so that `Phi Phi^T = basis diag(values) basis^T` with
    `basis = Q U` orthonormal to round-off."""

    basis: Any  # (n, m) Q U
    values: Any  # (m,) S, the eigenvalues of the approximation
    upper: Any  # (m, m) R
    rotation: Any  # (m, m) U
    transform: Any  # (m, m) T


def _nystrom_factors(kernel: AbstractKernel, rows: Any, landmarks: Any, block: int) -> _Nystrom:
    values, vectors = jnp.linalg.eigh(kernel.gram(landmarks, landmarks))
    keep = values > _RCOND_EPS * jnp.finfo(values.dtype).eps * values[-1]
    transform = vectors * jnp.where(keep, 1 / jnp.sqrt(jnp.where(keep, values, 1.0)), 0.0)
    orthonormal, upper = jnp.linalg.qr(_gram_times(kernel, rows, landmarks, transform, block))
    # the eigendecomposition below needs only R: without this barrier XLA may run it beside the LAPACK call that
    # forms Q, and two LAPACK calls at once can deadlock XLA's CPU thread pool (see the module docstring)
    orthonormal, upper = jax.lax.optimization_barrier((orthonormal, upper))
    # eigh of R R^T rather than the SVD of R: the same left vectors and values at a third of the cost on CPU
    values, rotation = jnp.linalg.eigh(upper @ upper.T)
    return _Nystrom(orthonormal @ rotation, jnp.maximum(values, 0.0), upper, rotation, transform)


@functools.partial(jax.jit, static_argnames=("kind", "degree", "block"))
def _nystrom(kind: str, degree: Any, widths: Any, rows: Any, target: Any, ridges: Any, index: Any, block: int) -> Any:
    """Nyström kernel ridge regression on the landmark rows `index`: `min ||Phi beta - y||^2 + rho ||beta||^2`,
    `alpha = T beta`. One factorisation serves every ridge: `beta = (R^T R + rho)^-1 R^T Q^T y =
    R^T U (S + rho)^-1 U^T Q^T y`."""
    landmarks = rows[index]

    def per_width(width: Any) -> Any:
        f = _nystrom_factors(_kernel(kind, degree, width), rows, landmarks, block)
        projected = f.basis.T @ target  # U^T Q^T y
        betas = (projected / (f.values + ridges[:, None])) @ (f.upper.T @ f.rotation).T  # (R, m)
        return betas @ f.transform.T

    return jax.lax.map(per_width, widths)


@functools.partial(jax.jit, static_argnames=("kind", "degree", "max_steps", "block"))
def _cg(
    kind: str,
    degree: Any,
    widths: Any,
    rows: Any,
    target: Any,
    ridges: Any,
    index: Any,
    tolerance: float,
    max_steps: int,
    block: int,
) -> tuple[Any, Any]:
    """`(K + rho I) alpha = y` by conjugate gradients (lineax) with the blocked, matrix-free matvec, every ridge
    in one vmapped solve (the kernel blocks do not depend on the ridge, so they are made once per iteration),
    preconditioned by the Nyström approximation from the landmark rows `index` (none when empty)."""
    n = rows.shape[0]
    structure = jax.ShapeDtypeStruct((n,), rows.dtype)
    psd = lx.positive_semidefinite_tag
    # no residual replacement (`stabilise_every=None`): the true residual `b - (K + rho) alpha` of large
    # coefficients carries round-off of order eps ||K|| ||alpha||, which, fed back every few steps, stalls the
    # iteration at an error of that size / rho; the recursive residual keeps converging (measured: rho = 1e-5,
    # 46 steps to 5e-9 without, no convergence in 500 steps with)
    atol = tolerance * jnp.max(jnp.abs(target))
    solver = lx.CG(rtol=tolerance, atol=atol, max_steps=max_steps, stabilise_every=None)

    def per_width(width: Any) -> tuple[Any, Any]:
        kernel = _kernel(kind, degree, width)
        if index.shape[0]:  # the approximation's eigenpairs: K ~ basis diag(values) basis^T
            factors = _nystrom_factors(kernel, rows, rows[index], block)
            basis, values = factors.basis, factors.values

        def per_ridge(ridge: Any) -> tuple[Any, Any]:
            operator = lx.FunctionLinearOperator(
                lambda v: _gram_times(kernel, rows, rows, v, block) + ridge * v, structure, tags=psd
            )
            options = {}
            if index.shape[0]:
                # only directions with eigenvalues above rho: the others are conditioned by the ridge already
                keep = values > ridge
                smallest = jnp.min(jnp.where(keep, values, jnp.inf))
                scale = jnp.where(keep, (smallest + ridge) / (values + ridge) - 1.0, 0.0)
                options["preconditioner"] = lx.FunctionLinearOperator(
                    lambda v: v + basis @ (scale * (basis.T @ v)), structure, tags=psd
                )
            solution = lx.linear_solve(operator, target, solver, options=options, throw=False)
            return solution.value, solution.stats["num_steps"]

        return jax.vmap(per_ridge)(ridges)

    return jax.lax.map(per_width, widths)
