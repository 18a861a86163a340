"""The linear-algebra kernel: `fj.lstsq` (column-scaled SVD, ridge, nonnegative bounds, derivatives),
`fj.covariance` / `fj.parameter_std`, and `fj.select_terms` (FROLS with ERR and PRESS, worden2007 §7,
Billings 2013 ch. 3), each against an independent oracle."""

from __future__ import annotations

import functools
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

import fricjax as fj

BACKENDS = [np.asarray, jnp.asarray]


def exact_lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The exact least-squares solution of the float data (full column rank), in rational arithmetic."""
    n, p = A.shape
    Af = [[Fraction(float(v)) for v in row] for row in A]
    bf = [Fraction(float(v)) for v in b]
    M = [[sum(Af[k][i] * Af[k][j] for k in range(n)) for j in range(p)] + [sum(Af[k][i] * bf[k] for k in range(n))]
         for i in range(p)]  # fmt: skip
    for c in range(p):  # Gauss-Jordan on the normal equations, exactly
        pivot = next(r for r in range(c, p) if M[r][c] != 0)
        M[c], M[pivot] = M[pivot], M[c]
        for r in range(p):
            if r != c and M[r][c] != 0:
                f = M[r][c] / M[c][c]
                M[r] = [x - f * y for x, y in zip(M[r], M[c], strict=True)]
    return np.array([float(M[i][p] / M[i][i]) for i in range(p)])


def relative(x, reference) -> float:
    return float(np.linalg.norm(np.asarray(x) - reference) / np.linalg.norm(reference))


# ----------------------------------------------------------------------------------------------------------------
# lstsq
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS, ids=["numpy", "jax"])
def test_lstsq_matches_numpy_on_well_conditioned_problems(backend):
    rng = np.random.default_rng(0)
    shapes = [(40, 5)] * 3 + ([(300, 12)] if backend is np.asarray else [])  # one compilation for JAX
    for n, p in shapes:
        A, b = rng.standard_normal((n, p)) * rng.uniform(0.1, 10.0, p), rng.standard_normal(n)
        result = fj.lstsq(backend(A), backend(b))
        reference, *_ = np.linalg.lstsq(A, b, rcond=None)
        assert relative(result.x, reference) < 1e-10
        np.testing.assert_allclose(result.residual, b - A @ reference, rtol=1e-10, atol=1e-12)
        assert int(result.rank) == p
        scaled = A / np.linalg.norm(A, axis=0)
        assert float(result.cond) == pytest.approx(np.linalg.cond(scaled), rel=1e-10)
        assert type(result.x) is type(backend(A))  # NumPy in, NumPy out; JAX in, JAX out
    # several right-hand sides at once
    A, B = rng.standard_normal((40, 5)), rng.standard_normal((40, 3))
    X = fj.lstsq(backend(A), backend(B)).x
    assert X.shape == (5, 3) and relative(X, np.linalg.lstsq(A, B, rcond=None)[0]) < 1e-10


@pytest.mark.parametrize("backend", BACKENDS, ids=["numpy", "jax"])
def test_lstsq_ill_conditioned_problems(backend):
    rng = np.random.default_rng(1)
    # columns in units 12 decades apart (cond(A) ~ 1e12): column scaling makes it a cond-1.5 problem
    A = rng.standard_normal((40, 5)) * np.logspace(-6, 6, 5)
    b = rng.standard_normal(40)
    assert np.linalg.cond(A) > 1e11
    exact = exact_lstsq(A, b)
    assert relative(fj.lstsq(backend(A), backend(b)).x, exact) < 1e-10
    assert np.max(np.abs(fj.lstsq(backend(A), backend(b)).x - exact) / np.abs(exact)) < 1e-10  # every component
    # intrinsically ill-conditioned: two nearly collinear columns (cond of the scaled matrix ~ 1e5)
    A = rng.standard_normal((40, 5))
    A[:, 4] = A[:, 3] + 1e-5 * A[:, 4]
    b = A @ rng.standard_normal(5) + 1e-6 * rng.standard_normal(40)
    result = fj.lstsq(backend(A), backend(b))
    assert 1e4 < float(result.cond) < 1e6
    assert relative(result.x, exact_lstsq(A, b)) < 1e-10
    assert relative(result.x, np.linalg.lstsq(A, b, rcond=None)[0]) < 1e-10


@pytest.mark.parametrize("backend", BACKENDS, ids=["numpy", "jax"])
def test_lstsq_rank_deficient_and_underdetermined(backend):
    rng = np.random.default_rng(2)
    A = rng.standard_normal((40, 5))
    A[:, 3] = A[:, 1]  # a copy
    A[:, 4] = 0.0  # a zero column
    b = rng.standard_normal(40)
    result = fj.lstsq(backend(A), backend(b))
    assert int(result.rank) == 3 and float(result.cond) == np.inf
    reference, *_ = np.linalg.lstsq(A, b, rcond=None)
    np.testing.assert_allclose(A @ np.asarray(result.x), A @ reference, rtol=1e-10)  # same fit
    np.testing.assert_allclose(result.x[1], result.x[3], rtol=1e-10)  # the copies share the weight
    assert float(result.x[4]) == 0.0
    # more parameters than samples: the exact fit of minimum norm in the scaled coordinates
    A, b = rng.standard_normal((6, 9)) * np.logspace(-2, 2, 9), rng.standard_normal(6)
    result = fj.lstsq(backend(A), backend(b))
    norms = np.linalg.norm(A, axis=0)
    np.testing.assert_allclose(A @ np.asarray(result.x), b, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(result.x, np.linalg.pinv(A / norms) @ b / norms, rtol=1e-10)


@pytest.mark.parametrize("backend", BACKENDS, ids=["numpy", "jax"])
def test_lstsq_ridge_is_scale_free_tikhonov(backend):
    rng = np.random.default_rng(3)
    A, b = rng.standard_normal((40, 5)) * [1e-3, 1.0, 1e2, 1e4, 0.1], rng.standard_normal(40)
    norms = np.linalg.norm(A, axis=0)
    As = A / norms
    for ridge in (1e-12, 1e-2, 3.0):
        expected = np.linalg.solve(As.T @ As + ridge * np.eye(5), As.T @ b) / norms
        np.testing.assert_allclose(fj.lstsq(backend(A), backend(b), ridge=ridge).x, expected, rtol=1e-10)


@pytest.mark.parametrize("backend", BACKENDS, ids=["numpy", "jax"])
def test_lstsq_nonnegative_matches_scipy(backend):
    rng = np.random.default_rng(4)
    active = 0
    for _ in range(6):
        A = rng.standard_normal((40, 5)) * np.logspace(-2, 2, 5)
        b = rng.standard_normal(40)
        norms = np.linalg.norm(A, axis=0)
        result = fj.lstsq(backend(A), backend(b), nonnegative=True)
        reference, rnorm = scipy.optimize.nnls(A, b)
        assert np.all(np.asarray(result.x) >= 0)
        np.testing.assert_allclose(np.asarray(result.x) * norms, reference * norms, atol=1e-10 * np.linalg.norm(b))
        assert np.linalg.norm(result.residual) == pytest.approx(rnorm, rel=1e-10)
        active += int(np.sum(reference == 0))
        # a mask: only some parameters bounded (scipy's bounded least squares as the oracle)
        mask = np.array([True, False, True, False, True])
        bounds = (np.where(mask, 0.0, -np.inf), np.full(5, np.inf))
        reference = scipy.optimize.lsq_linear(A, b, bounds=bounds, method="bvls", tol=1e-14).x
        x = np.asarray(fj.lstsq(backend(A), backend(b), nonnegative=mask).x)
        assert np.all(x[mask] >= 0)
        np.testing.assert_allclose(x * norms, reference * norms, atol=1e-9 * np.linalg.norm(b))
    assert active >= 6  # the bounds were active in these draws
    # with a ridge: the damped problem with bounds, i.e. NNLS of [A_s; sqrt(ridge) I]
    As = A / norms
    augmented = np.vstack([As, np.sqrt(0.1) * np.eye(5)])
    reference = scipy.optimize.nnls(augmented, np.concatenate([b, np.zeros(5)]))[0] / norms
    x = fj.lstsq(backend(A), backend(b), nonnegative=True, ridge=0.1).x
    np.testing.assert_allclose(np.asarray(x) * norms, reference * norms, atol=1e-10)


def test_lstsq_nonnegative_under_jit_and_vmap():
    rng = np.random.default_rng(5)
    A = jnp.asarray(rng.standard_normal((8, 40, 5)))
    b = jnp.asarray(rng.standard_normal((8, 40)))
    solve = jax.jit(jax.vmap(lambda A, b: fj.lstsq(A, b, nonnegative=True).x))
    for x, Ai, bi in zip(solve(A, b), A, b, strict=True):
        np.testing.assert_allclose(x, scipy.optimize.nnls(np.asarray(Ai), np.asarray(bi))[0], atol=1e-10)


@functools.partial(jax.jit, static_argnames="mask")
def _directional_derivatives(A, b, ridge, w, dA, db, dridge, mask=None):
    """d/dh of w . lstsq(A + h dA, b + h db, ridge + h dridge).x at h = 0: by autodiff and by central differences."""
    nonnegative = None if mask is None else np.asarray(mask)

    def f(A, b, ridge):
        return jnp.dot(w, fj.lstsq(A, b, ridge=ridge, nonnegative=nonnegative).x)

    gA, gb, gr = jax.grad(f, argnums=(0, 1, 2))(A, b, ridge)
    h = 1e-6
    fd = (f(A + h * dA, b + h * db, ridge + h * dridge) - f(A - h * dA, b - h * db, ridge - h * dridge)) / (2 * h)
    return jnp.sum(gA * dA) + jnp.sum(gb * db) + gr * dridge, fd


def test_lstsq_gradients_match_finite_differences():
    rng = np.random.default_rng(6)
    Q, _ = np.linalg.qr(rng.standard_normal((40, 5)))
    scales = np.array([1e-3, 1.0, 1e3, 10.0, 1.0])
    cases = [
        # badly scaled columns (perturbed along their own scales), a ridge (and its derivative), and orthonormal
        # columns (all singular values equal: differentiating through the SVD goes wrong there)
        (rng.standard_normal((40, 5)) * scales, 0.0, 0.0, scales, None),
        (rng.standard_normal((40, 5)), 1e-2, 1.0, 1.0, None),
        (Q, 0.0, 0.0, 1.0, None),
        # bounds: the derivative of the solution on the free set (strict complementarity holds for this draw)
        (rng.standard_normal((40, 5)), 0.0, 0.0, 1.0, (True, True, False, True, True)),
        # more parameters than samples: the minimum-norm solution
        (rng.standard_normal((6, 9)), 0.0, 0.0, 1.0, None),
    ]
    for A, ridge, dridge, scale, mask in cases:
        n, p = A.shape
        w = rng.standard_normal(p) * scale  # weights in the parameters' units
        dA, db = rng.standard_normal((n, p)) * scale, rng.standard_normal(n)
        analytic, fd = _directional_derivatives(A, rng.standard_normal(n), ridge, w, dA, db, dridge, mask=mask)
        assert float(analytic) == pytest.approx(float(fd), rel=1e-7), (A.shape, ridge, mask)


def test_lstsq_follows_float32():
    rng = np.random.default_rng(7)
    A, b = rng.standard_normal((40, 5)).astype(np.float32), rng.standard_normal(40).astype(np.float32)
    result = fj.lstsq(jnp.asarray(A), jnp.asarray(b))
    assert result.x.dtype == jnp.float32 and result.residual.dtype == jnp.float32
    np.testing.assert_allclose(result.x, np.linalg.lstsq(A.astype(np.float64), b, rcond=None)[0], rtol=1e-4)


def test_lstsq_errors():
    A, b = np.ones((5, 2)), np.ones(5)
    with pytest.raises(ValueError, match="`A` must be a non-empty 2-D array"):
        fj.lstsq(np.ones(5), b)
    with pytest.raises(ValueError, match=r"`b` must have shape \(5,\)"):
        fj.lstsq(A, np.ones(4))
    with pytest.raises(ValueError, match="`A` contains NaN or inf"):
        fj.lstsq(np.where(np.eye(5, 2) > 0, np.nan, 1.0), b)
    with pytest.raises(ValueError, match="`ridge` must be a finite scalar >= 0"):
        fj.lstsq(A, b, ridge=-1.0)
    with pytest.raises(ValueError, match=r"boolean mask of shape \(2,\)"):
        fj.lstsq(A, b, nonnegative=[True, False, True])
    with pytest.raises(ValueError, match=r"single right-hand side"):
        fj.lstsq(A, np.ones((5, 2)), nonnegative=True)


# ----------------------------------------------------------------------------------------------------------------
# covariance
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS, ids=["numpy", "jax"])
def test_covariance_matches_the_direct_formula(backend):
    rng = np.random.default_rng(8)
    n = 300
    A = np.column_stack([np.ones(n), rng.standard_normal(n) * 1e-3, rng.standard_normal(n) * 1e4])
    b = A @ [1.0, 2e3, 3e-4] + 0.1 * rng.standard_normal(n)
    r = np.asarray(fj.lstsq(backend(A), backend(b)).residual)
    direct = (r @ r / (n - 3)) * np.linalg.inv(A.T @ A)
    np.testing.assert_allclose(fj.covariance(backend(A), backend(r)), direct, rtol=1e-9)
    np.testing.assert_allclose(fj.parameter_std(backend(A), backend(r)), np.sqrt(np.diag(direct)), rtol=1e-9)
    # dof for q further (nonlinear) parameters fitted to the same residuals
    np.testing.assert_allclose(fj.covariance(backend(A), backend(r), n - 5), direct * (n - 3) / (n - 5), rtol=1e-9)


def test_covariance_is_the_gauss_newton_std_of_fit():
    """The form `fit` uses for its standard deviations: J (R, P) the residual Jacobian, r the residuals,
    s^2 pinv(J_s^T J_s) / (norms norms^T), J_s = J / norms (`_std_from_jacobian`)."""
    rng = np.random.default_rng(9)
    J = rng.standard_normal((40, 5)) * [1e8, 1.0, 1e-3, 30.0, 1.0]
    r = 0.05 * rng.standard_normal(40)
    dof = max(r.size - J.shape[1], 1)
    norms = np.sqrt(np.sum(J**2, axis=0))
    Js = J / norms
    expected = np.sum(r**2) / dof * np.linalg.pinv(Js.T @ Js) / np.outer(norms, norms)
    std = jax.jit(lambda J, r: fj.parameter_std(J, r, dof))(jnp.asarray(J), jnp.asarray(r))  # inside a jitted fit
    np.testing.assert_allclose(std, np.sqrt(np.diag(expected)), rtol=1e-9)
    np.testing.assert_allclose(fj.covariance(jnp.asarray(J), jnp.asarray(r), dof), expected, rtol=1e-9)


def test_covariance_errors():
    with pytest.raises(ValueError, match="`dof` must be positive"):
        fj.covariance(np.ones((3, 3)), np.ones(3))
    with pytest.raises(ValueError, match=r"`residuals` must have shape \(4,\)"):
        fj.covariance(np.ones((4, 2)), np.ones(3))


# ----------------------------------------------------------------------------------------------------------------
# select_terms (FROLS / PRESS)
# ----------------------------------------------------------------------------------------------------------------


def _sparse_problem(noise: float, n: int = 400, m: int = 20):
    rng = np.random.default_rng(10)
    Z = rng.standard_normal((n, m))
    X = Z + 0.6 * np.roll(Z, 1, axis=1)  # correlated candidates (neighbours share a component)
    true = (4, 11, 17)
    y = 0.5 + X[:, true] @ [2.0, -1.5, 0.8] + noise * rng.standard_normal(n)
    return X, y, true


def test_select_terms_recovers_a_sparse_regression():
    # exact: 3 of 20 correlated candidates; PRESS reaches round-off at the true size and stops there
    X, y, true = _sparse_problem(noise=0.0)
    selection = fj.select_terms(X, y)
    assert sorted(selection.indices) == sorted(true)
    coefficients = dict(zip(selection.indices, selection.coefficients, strict=True))
    np.testing.assert_allclose([coefficients[i] for i in true], [2.0, -1.5, 0.8], rtol=1e-10)
    assert selection.intercept == pytest.approx(0.5, rel=1e-10)
    assert np.argmin(selection.press) == 3 and selection.press[3] < 1e-20 * selection.press[0]
    # ERR: shares of y^T y, summing to at most 1; the intercept's share is the rest of the first drop
    yy = y @ y
    assert np.all(selection.err > 0) and selection.err.sum() <= 1.0
    assert selection.err.sum() == pytest.approx((selection.rss[0] - selection.rss[-1]) / yy, rel=1e-10)
    assert selection.err.sum() + (1 - selection.rss[0] / yy) == pytest.approx(1.0, rel=1e-12)
    # the ERR ranking stops at round-off too
    assert fj.select_terms(X, y, criterion="err").indices == selection.indices

    # with noise: ERR ranks the true terms first and PRESS drops by orders of magnitude through them; after them it
    # is flat at the noise level. (Each further term lowers the residual sum of squares by sigma^2 chi^2_1 of the
    # best of the remaining candidates and raises PRESS by about 2 sigma^2: with 17 candidates left, the best
    # usually explains more than 2 sigma^2 of the noise, so greedy PRESS goes on by a few terms of no weight.)
    X, y, true = _sparse_problem(noise=0.1)
    ranked = fj.select_terms(X, y, criterion="err", max_terms=8)
    assert sorted(ranked.indices[:3]) == sorted(true)
    assert len(ranked.indices) == 8 and np.all(np.diff(ranked.rss) <= 0) and ranked.err.sum() <= 1.0
    assert np.all(np.diff(ranked.press[:4]) < 0) and ranked.press[3] < 2e-2 * ranked.press[2]
    assert ranked.press[3] <= 1.05 * ranked.press.min()
    selection = fj.select_terms(X, y)
    assert sorted(selection.indices[:3]) == sorted(true) and np.all(np.diff(selection.press) < 0)
    np.testing.assert_allclose(selection.press[:4], ranked.press[:4], rtol=1e-10)
    assert np.all(np.abs(selection.coefficients[3:]) < 0.02)  # the extra terms carry (almost) no weight
    # the refitted coefficients are the least-squares ones of the selected columns with intercept
    design = np.column_stack([np.ones(len(y)), X[:, list(selection.indices)]])
    reference, *_ = np.linalg.lstsq(design, y, rcond=None)
    np.testing.assert_allclose([selection.intercept, *selection.coefficients], reference, rtol=1e-10)


def test_select_terms_without_intercept_and_press_is_leave_one_out():
    rng = np.random.default_rng(11)
    n = 60
    X = rng.standard_normal((n, 6))
    X[:, 2] = 1.0  # the constant competes as a candidate
    y = 3.0 + 0.7 * X[:, 4] + 0.05 * rng.standard_normal(n)
    selection = fj.select_terms(X, y, intercept=False)
    assert set(selection.indices[:2]) == {2, 4} and selection.intercept == 0.0
    assert selection.press[0] == pytest.approx(y @ y) and selection.rss[0] == pytest.approx(y @ y)
    for size in range(1, len(selection.indices) + 1):
        design = X[:, list(selection.indices[:size])]
        loo = []
        for k in range(n):  # PRESS by its definition: refit without sample k, predict it
            keep = np.arange(n) != k
            theta, *_ = np.linalg.lstsq(design[keep], y[keep], rcond=None)
            loo.append(y[k] - design[k] @ theta)
        assert selection.press[size] == pytest.approx(np.sum(np.square(loo)), rel=1e-9)


def test_select_terms_with_fixed_columns():
    """Fixed columns (a drift) are in every model: the selection equals a selection on the candidates with the
    fixed columns projected out, PRESS is leave-one-out with them in the design, and the coefficients are the
    joint least-squares ones."""
    rng = np.random.default_rng(12)
    n = 80
    X = rng.standard_normal((n, 7))
    drift = np.linspace(0.0, 1.0, n)
    y = 0.3 + 1.2 * drift + 0.9 * X[:, 1] - 0.4 * X[:, 5] + 0.05 * rng.standard_normal(n)
    selection = fj.select_terms(X, y, fixed=drift)
    assert set(selection.indices[:2]) == {1, 5}
    design = np.column_stack([np.ones(n), X[:, list(selection.indices)], drift])
    reference, *_ = np.linalg.lstsq(design, y, rcond=None)
    np.testing.assert_allclose(
        [selection.intercept, *selection.coefficients, *selection.fixed_coefficients], reference, rtol=1e-10
    )
    for size in range(len(selection.indices) + 1):
        design = np.column_stack([np.ones(n), drift, X[:, list(selection.indices[:size])]])
        loo = []
        for k in range(n):
            keep = np.arange(n) != k
            theta, *_ = np.linalg.lstsq(design[keep], y[keep], rcond=None)
            loo.append(y[k] - design[k] @ theta)
        assert selection.press[size] == pytest.approx(np.sum(np.square(loo)), rel=1e-9)
    assert fj.select_terms(X, y).fixed_coefficients.shape == (0,)
    with pytest.raises(ValueError, match="fixed"):
        fj.select_terms(X, y, fixed=np.ones(n))  # spanned by the intercept
    with pytest.raises(ValueError, match="fixed"):
        fj.select_terms(X, y, fixed=np.ones(n - 1))


def _old_orthogonal_forward(forces: np.ndarray, target: np.ndarray, max_members: int, criterion: str):
    """The ensemble's selection before `select_terms` replaced it (verbatim, members as rows): the oracle."""

    def value(residual, leverage):
        if criterion == "rss":
            return float(residual @ residual)
        denominator = 1.0 - leverage
        if np.any(denominator <= 1e-12):
            return float("inf")
        return float(np.sum((residual / denominator) ** 2))

    n_members, n_samples = forces.shape
    eps = np.finfo(np.float64).eps
    residual = target - target.mean()
    leverage = np.full(n_samples, 1.0 / n_samples)
    remainders = forces - forces.mean(axis=1, keepdims=True)
    sizes = np.linalg.norm(forces, axis=1)
    basis = [np.full(n_samples, 1.0 / np.sqrt(n_samples))]
    history = [value(residual, leverage)]
    floor = 100.0 * eps * history[0]
    chosen: list[int] = []
    while len(chosen) < max_members:
        best, best_value, best_q = -1, np.inf, None
        for i in range(n_members):
            if i in chosen:
                continue
            w = remainders[i]
            for q in basis:
                w = w - q * (q @ w)
            norm = np.linalg.norm(w)
            if sizes[i] == 0 or norm <= np.sqrt(eps) * sizes[i]:
                continue
            q = w / norm
            candidate = value(residual - q * (q @ residual), leverage + q**2)
            if candidate < best_value:
                best, best_value, best_q = i, candidate, q
        if best_q is None or not best_value < history[-1] - floor:
            break
        chosen.append(best)
        basis.append(best_q)
        residual = residual - best_q * (best_q @ residual)
        leverage = leverage + best_q**2
        remainders = remainders - np.outer(remainders @ best_q, best_q)
        history.append(best_value)
    return chosen, history


@pytest.mark.slow  # fast tier trimmed (2026-11-27): a regression check against an older code path
def test_select_terms_equals_the_old_ensemble_selection():
    rng = np.random.default_rng(12)
    n = 150
    t = np.linspace(0.0, 1.0, n)
    forces = np.stack(
        [
            np.sin(7 * t),
            np.sign(np.sin(7 * t)) + 0.1 * t,
            np.sin(7 * t) + 0.3 * np.cos(3 * t),
            np.full(n, 2.0),  # spanned by the intercept
            rng.standard_normal(n),
            np.cos(3 * t),  # spanned by members 0 and 2
            t**2,
        ]
    )
    target = 0.2 + forces[1] - 0.4 * forces[2] + 0.2 * forces[6] + 0.05 * rng.standard_normal(n)
    motion = fj.Motion.from_position(1e-3 * np.sin(7 * t), dt=1.0 / n)
    members = [fj.Coulomb(Fc=1.0)] * len(forces)  # stand-ins: the predictions are given
    data = fj.FrictionData(motion, target)
    for criterion, max_members in [("press", 7), ("rss", 7), ("press", 2)]:
        old_indices, old_history = _old_orthogonal_forward(forces, target, max_members, criterion)
        new = fj.select_terms(
            forces.T, target, criterion="press" if criterion == "press" else "err", max_terms=max_members
        )
        assert list(new.indices) == old_indices, criterion
        np.testing.assert_allclose(new.press if criterion == "press" else new.rss, old_history, rtol=1e-12)
        if criterion == "rss":  # and through the public ensemble entry point
            public = fj.select_forward(members, data, max_members, criterion, predictions=forces)
            assert list(public.indices) == old_indices
            np.testing.assert_allclose(public.press, old_history, rtol=1e-12)
    assert 3 not in new.indices and 5 not in _old_orthogonal_forward(forces, target, 7, "rss")[0]


def test_select_terms_errors():
    X, y = np.ones((10, 3)), np.ones(10)
    with pytest.raises(ValueError, match="`criterion` must be 'press' or 'err'"):
        fj.select_terms(X, y, criterion="aic")
    with pytest.raises(ValueError, match="`max_terms` must be a positive integer"):
        fj.select_terms(X, y, max_terms=0)
    with pytest.raises(ValueError, match=r"`target` must have shape \(10,\)"):
        fj.select_terms(X, np.ones(9))
    with pytest.raises(ValueError, match="`candidates` must be a non-empty 2-D array"):
        fj.select_terms(np.ones(10), y)
    with pytest.raises(ValueError, match="greedy loop on values"):
        jax.jit(lambda X: fj.select_terms(X, y).coefficients)(jnp.asarray(X))
