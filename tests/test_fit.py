"""The fitting engine `fj.fit`: losses, solver paths, freezing, separable least squares, multi-start,
continuation, early stopping, the divergence guard, bad input, `FitResult` and saving / loading models.

Every problem is small (records of 300 samples; 1200 for the standard-deviation scaling check) and most use
the smooth Coulomb + viscous law, whose simulation compiles fast: `fit` compiles its own closures on every
call, so fits are shared through module-scoped fixtures where several tests read the same result.
"""

from __future__ import annotations

import pickle
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
import pytest

import fricjax as fj

# ----------------------------------------------------------------------------------------------------------------
# shared problems
# ----------------------------------------------------------------------------------------------------------------

DT = 1e-3
N = 300
EPS = 1e-4  # smoothing width [m/s]; the peak velocity of the motions below is ~3e-2 m/s


def sine_motion(n: int = N, growing: bool = False) -> fj.Motion:
    """A 5 Hz sine of 1 mm; `growing` ramps the amplitude from 0.2 mm (pre-sliding for LuGre) to 1.2 mm."""
    t = np.arange(n) * DT
    envelope = 0.2 + t / t[-1] if growing else 1.0
    return fj.Motion.from_position(1e-3 * envelope * np.sin(2 * np.pi * 5.0 * t), dt=DT)


def coulomb_viscous(Fc: float, Fv: float, offset: float) -> fj.CoulombViscous:
    return fj.CoulombViscous(Fc=Fc, Fv=Fv, offset=offset, smoothing=fj.Smooth(EPS))


def lugre(sigma2: float = 40.0, offset: float = 0.05) -> fj.LuGre:
    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0)
    return fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=sigma2, offset=offset, smoothing=fj.Smooth(EPS))


MOTION = sine_motion()
TRUTH = coulomb_viscous(1.0, 30.0, 0.2)
START = coulomb_viscous(0.6, 18.0, 0.1)  # 40 % / 40 % / 50 % off
DATA = fj.FrictionData(MOTION, fj.simulate(TRUTH, MOTION))


def physical(model: Any) -> dict[str, float]:
    p = fj.unwrap(model)
    return {"Fc": float(p.Fc), "Fv": float(p.Fv), "offset": float(p.offset)}


def assert_recovers(model: Any, rtol: float) -> None:
    got, want = physical(model), physical(TRUTH)
    for name in want:
        np.testing.assert_allclose(got[name], want[name], rtol=rtol, err_msg=name)


def noisy_data(n: int, seed: int = 0, sigma: float = 0.05) -> fj.FrictionData:
    motion = sine_motion(n)
    noise = sigma * np.random.default_rng(seed).standard_normal(n)
    return fj.FrictionData(motion, np.asarray(fj.simulate(TRUTH, motion)) + noise)


def tree_finite(tree: Any) -> bool:
    return all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(tree) if eqx.is_inexact_array(x))


def state_trajectory(model: Any, motion: fj.Motion) -> Any:
    """The state after every sample, from a scan of `model.step` written here (independent of the losses)."""
    model = fj.unwrap(model)

    samples = motion.samples(model.requires)

    def body(state: Any, k: Any) -> Any:
        state, _ = model.step(state, samples.at(k))
        return state, state

    _, states = jax.lax.scan(body, model.init_state(), jnp.arange(motion.length))
    return states


def least_squares_values(model: Any, paths: list[str], data: fj.FrictionData) -> np.ndarray:
    """The least-squares values of the real scalar / array fields `paths` (which enter the force linearly) with
    every other parameter as in `model`: columns from simulating unit vectors, solved by NumPy's lstsq."""

    def get(m: Any, path: str) -> Any:
        for part in path.split("."):
            m = getattr(m, part)
        return m

    shapes = [jnp.shape(get(model, p)) for p in paths]
    sizes = [int(np.prod(s)) for s in shapes]

    def with_values(flat: np.ndarray) -> Any:
        pieces, i = [], 0
        for shape, size in zip(shapes, sizes, strict=True):
            pieces.append(jnp.asarray(flat[i : i + size].reshape(shape)))
            i += size
        return eqx.tree_at(lambda m: [get(m, p) for p in paths], model, pieces)

    total = sum(sizes)
    f0 = np.asarray(fj.simulate(with_values(np.zeros(total)), data.motion))
    columns = [np.asarray(fj.simulate(with_values(np.eye(total)[j]), data.motion)) - f0 for j in range(total)]
    theta, *_ = np.linalg.lstsq(np.stack(columns, axis=1), np.asarray(data.force) - f0, rcond=None)
    return theta


class ARX(fj.AbstractFrictionModel):
    """A toy first-order ARX friction model, `F_k = a F_{k-1} + b v_k`, feeding back its output."""

    a: jax.Array
    b: Any  # positive, stored through fj.Positive

    requires: ClassVar[frozenset[str]] = frozenset({"v"})

    def __init__(self, a: float, b: float):
        self.a = jnp.asarray(a)
        self.b = fj.Positive(b, name="b")

    def init_state(self) -> jax.Array:
        return jnp.zeros_like(self.a)

    def step(self, state: jax.Array, sample: fj.MotionSample) -> tuple[jax.Array, jax.Array]:
        p = fj.unwrap(self)
        force = p.a * state + p.b * sample.v
        return force, force

    def feedback(self, state: jax.Array, y_measured: jax.Array) -> jax.Array:
        return y_measured  # the state is the past output: teacher forcing replaces it by the measurement


# ----------------------------------------------------------------------------------------------------------------
# losses
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("burn_in", [0, 37])
def test_simulation_loss_residuals(burn_in):
    loss = fj.SimulationLoss(burn_in=burn_in)
    r_true = np.asarray(loss.residuals(TRUTH, None, DATA))
    assert r_true.shape == (N - burn_in,)
    assert np.max(np.abs(r_true)) < 1e-12 and float(loss(TRUTH, None, DATA)) < 1e-24
    # a wrong model: the scaled simulation error after the burn-in, and the loss is its mean square
    r = np.asarray(loss.residuals(START, None, DATA))
    expected = (np.asarray(fj.simulate(START, MOTION)) - np.asarray(DATA.force)) / np.std(np.asarray(DATA.force))
    np.testing.assert_allclose(r, expected[burn_in:], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(float(loss(START, None, DATA)), np.mean(expected[burn_in:] ** 2), rtol=1e-12)
    raw = fj.SimulationLoss(burn_in=burn_in, normalise=False).residuals(START, None, DATA)
    np.testing.assert_allclose(raw, expected[burn_in:] * np.std(np.asarray(DATA.force)), rtol=1e-12, atol=1e-14)


def test_simulation_loss_rejects_negative_burn_in():
    with pytest.raises(ValueError, match="burn_in"):
        fj.SimulationLoss(burn_in=-1)


@pytest.fixture(scope="module")
def lugre_problem():
    model = lugre()
    motion = sine_motion(growing=True)
    return model, fj.FrictionData(motion, fj.simulate(model, motion))


@pytest.mark.slow  # moved from the fast tier (under 5 minutes cold on 2 cores; 2026-11-27: 291 s, clean clone)
def test_multiple_shooting_loss_at_true_model(lugre_problem):
    model, data = lugre_problem
    length = 64  # 300 samples hold 4 whole segments; the last 44 samples are not scored
    loss = fj.MultipleShootingLoss(length)
    extra = loss.init_extra(model, data)
    # the initial states of segments 2..4 are the states a full simulation passes through
    z = np.asarray(state_trajectory(model, data.motion).z)
    np.testing.assert_allclose(np.asarray(extra.z), z[[length - 1, 2 * length - 1, 3 * length - 1]], rtol=1e-12)
    r = np.asarray(loss.residuals(model, extra, data))
    assert r.shape == (4 * length + 3,)  # force errors of every segment + one scalar state gap per junction
    assert np.max(np.abs(r)) < 1e-10 and float(loss(model, extra, data)) < 1e-20
    # a wrong model, or wrong initial states, is scored
    assert float(loss(lugre(sigma2=20.0), extra, data)) > 1e-3
    wrong = jax.tree_util.tree_map(lambda z: 2.0 * z, extra)
    r_wrong = np.asarray(loss.residuals(model, wrong, data))
    assert np.max(np.abs(r_wrong[:length])) < 1e-10  # the first segment starts from the model's own state
    assert np.max(np.abs(r_wrong[4 * length :])) > 0.1  # the continuity gaps show the wrong states


def _gms_truth_and_start():
    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3)
    truth = fj.GMS(stribeck, k=[2e4, 1e4, 5e3], alpha=[0.5, 0.3, 0.2], C=20.0)
    start = fj.GMS(fj.ExponentialStribeck(Fc=0.8, Fs=1.2, vs=2e-3), k=[3e4, 5e3, 5e3], alpha=[0.4, 0.4, 0.2], C=30.0)
    return truth, start


def _lugre_truth_and_start():
    start = fj.LuGre(fj.ExponentialStribeck(Fc=0.7, Fs=1.2, vs=2e-3), sigma0=5e4, sigma1=200.0, sigma2=20.0)
    return lugre(offset=0.0), start


@pytest.mark.parametrize(
    "models",
    [
        pytest.param(_lugre_truth_and_start, id="lugre", marks=pytest.mark.slow),  # the loss is checked fast
        pytest.param(_gms_truth_and_start, id="gms", marks=pytest.mark.slow),  # the same check, two state leaves
    ],
)
def test_multiple_shooting_jacobian_shares_tangents_and_takes_the_dense_steps(models):
    """A segment's start moves only that segment and the two continuity gaps beside it, so fricjax's
    Levenberg-Marquardt shares one tangent among every other segment's start (2 per state component instead of one
    per segment); optimistix's differentiates every column. Both take the same iterates: LuGre (one state) and GMS
    (two state leaves of three elements each)."""
    truth, start = models()
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 1.3 * np.arange(900) * 1e-3), dt=1e-3)
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    start = fj.with_smoothing(start, fj.Smooth(1e-7))
    kwargs = dict(loss=fj.MultipleShootingLoss(100), steps=3, scaling=fj.ParameterScaling())
    ours = fj.fit(start, data, solver=fj.levenberg_marquardt(), **kwargs)
    theirs = fj.fit(start, data, solver=optx.LevenbergMarquardt(1e-10, 1e-12), **kwargs)
    for a, b in zip(jax.tree_util.tree_leaves(ours.model), jax.tree_util.tree_leaves(theirs.model), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-7, atol=1e-12)


def test_multiple_shooting_loss_rejects_bad_segments(lugre_problem):
    model, data = lugre_problem
    for bad in (1, 0):
        with pytest.raises(ValueError, match="segment_length"):
            fj.MultipleShootingLoss(bad)
    with pytest.raises(ValueError, match="continuity_weight"):
        fj.MultipleShootingLoss(10, continuity_weight=-1.0)
    loss = fj.MultipleShootingLoss(151)  # one whole segment in 300 samples
    with pytest.raises(ValueError, match="fewer than 2 segments"):
        loss.init_extra(model, data)
    with pytest.raises(ValueError, match="fewer than 2 segments"):
        loss.residuals(model, None, data)


def test_one_step_loss_needs_feedback():
    with pytest.raises(TypeError, match="feeds back no outputs"):
        fj.OneStepLoss().residuals(TRUTH, None, DATA)
    with pytest.raises(TypeError, match="CoulombViscous feeds back no outputs"):
        fj.fit(START, DATA, loss=fj.OneStepLoss(), steps=1)


@pytest.fixture(scope="module")
def arx_data():
    return fj.FrictionData(MOTION, fj.simulate(ARX(0.5, 20.0), MOTION))


def test_one_step_loss_residuals_of_a_toy_model(arx_data):
    force = np.asarray(arx_data.force)
    model = ARX(0.3, 10.0)
    for burn_in in (0, 5):
        loss = fj.OneStepLoss(burn_in=burn_in)
        past = np.r_[0.0, force[:-1]]
        expected = (0.3 * past + 10.0 * np.asarray(arx_data.motion.v) - force) / np.std(force)
        np.testing.assert_allclose(loss.residuals(model, None, arx_data), expected[burn_in:], rtol=1e-10, atol=1e-13)
        assert float(loss(ARX(0.5, 20.0), None, arx_data)) < 1e-24


def test_one_step_loss_fit_recovers_toy_model(arx_data):
    result = fj.fit(
        ARX(0.3, 10.0), arx_data, loss=fj.OneStepLoss(), solver=fj.levenberg_marquardt(), steps=30, compute_std=False
    )
    assert result.success, result.message
    p = fj.unwrap(result.model)
    np.testing.assert_allclose([float(p.a), float(p.b)], [0.5, 20.0], rtol=1e-8)
    assert result.train_loss < 1e-20


# ----------------------------------------------------------------------------------------------------------------
# solver paths
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "solver, steps, eval_every, codes",
    [
        pytest.param(optax.adam(3e-2), 1000, 1000, {"max_steps"}, id="optax-adam"),
        pytest.param(optax.lbfgs(), 60, 60, {"max_steps"}, id="optax-lbfgs", marks=pytest.mark.slow),
        pytest.param(fj.levenberg_marquardt(), 50, None, {"successful"}, id="optimistix-lm"),
        pytest.param(
            optx.BFGS(rtol=1e-10, atol=1e-12), 200, None, {"successful"}, id="optimistix-bfgs", marks=pytest.mark.slow
        ),
    ],
)
def test_solvers_recover_parameters(solver, steps, eval_every, codes):
    start_loss = float(fj.SimulationLoss()(START, None, DATA))
    result = fj.fit(
        START, DATA, solver=solver, steps=steps, eval_every=eval_every, scaling=fj.ParameterScaling(), compute_std=False
    )
    assert result.code in codes, (result.code, result.message)
    assert result.success and result.message
    assert_recovers(result.model, rtol=1e-6)
    assert result.train_loss < 1e-12 * start_loss
    assert 1 <= result.evaluations <= steps
    assert result.num_starts == 1 and result.best_start == 0
    assert np.isnan(result.val_loss) and np.isnan(result.exact_val_loss)  # no validation data
    # the smoothing is kept (a setting, not a parameter)
    assert float(result.model.smoothing.eps) == EPS
    assert result.std is None and all(std is None for _, std in result.parameters().values())  # compute_std=False


# ----------------------------------------------------------------------------------------------------------------
# noisy fits shared by freeze / FitResult / standard deviations / save-load
# ----------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def noisy_fits():
    """LM fits of noisy records of N and 4N samples (same motion pattern), offset frozen at its true value."""
    start = coulomb_viscous(0.6, 18.0, 0.2)
    fits = {}
    for n in (N, 4 * N):
        data = noisy_data(n)
        fit = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=50, freeze=("offset",), compute_std=True)
        fits[n] = (data, fit)
    return start, fits


def test_freeze_keeps_the_start_value(noisy_fits):
    start, fits = noisy_fits
    for _, result in fits.values():
        assert result.success, result.message
        assert float(fj.unwrap(result.model).offset) == float(start.offset)  # exactly
        assert abs(physical(result.model)["Fc"] - 1.0) < 0.03  # the others trained (start 0.6)
        assert abs(physical(result.model)["Fv"] - 30.0) < 1.5  # start 18


def test_freeze_of_a_positive_field():
    result = fj.fit(START, DATA, solver=fj.levenberg_marquardt(), steps=50, freeze=("Fc",), compute_std=False)
    assert float(fj.unwrap(result.model).Fc) == float(fj.unwrap(START).Fc)
    assert float(fj.unwrap(result.model).Fv) != 18.0


def test_freeze_unknown_field_names_it():
    with pytest.raises(ValueError, match="'sigma9'"):
        fj.fit(START, DATA, freeze=("sigma9",), steps=1)
    with pytest.raises(ValueError, match=r"'stribeck\.Fx'"):
        fj.fit(lugre(), DATA, freeze=("stribeck.Fx",), steps=1)


def test_freeze_everything_is_an_error():
    with pytest.raises(ValueError, match="every parameter is frozen"):
        fj.fit(START, DATA, freeze=("Fc", "Fv", "offset"), steps=1)


def test_fit_result_history_parameters_and_summary(noisy_fits):
    _, fits = noisy_fits
    for _, result in fits.values():
        lengths = {key: len(value) for key, value in result.history.items()}
        assert set(lengths) == {"step", "train_loss", "val_loss", "eps", "time"}
        assert len(set(lengths.values())) == 1 and lengths["step"] >= 1, lengths
        assert np.all(np.diff(result.history["step"]) > 0)
        params = result.parameters()
        assert set(params) == {"Fc", "Fv", "offset"}
        unwrapped = fj.unwrap(result.model)
        for name, (value, _) in params.items():
            np.testing.assert_array_equal(value, np.asarray(getattr(unwrapped, name)))
        text = result.summary()
        assert isinstance(text, str)
        for name in ("Fc", "Fv", "offset", result.code):
            assert name in text
        np.testing.assert_allclose(result.train_loss, result.history["train_loss"][-1], rtol=1e-6)


def test_gauss_newton_standard_deviations(noisy_fits):
    _, fits = noisy_fits
    stds = {}
    for n, (data, result) in fits.items():
        params = result.parameters()
        for name in ("Fc", "Fv"):
            std = params[name][1]
            assert std is not None and np.isfinite(std) and std > 0, (n, name, std)
            # the estimate is consistent with its error (noise-free truth: Fc = 1, Fv = 30)
            assert abs(float(params[name][0]) - {"Fc": 1.0, "Fv": 30.0}[name]) < 5 * float(std)
        assert np.isnan(params["offset"][1])  # frozen
        assert np.isnan(float(fj.unwrap(result.std).offset))
        # an independent computation: analytic Jacobian columns tanh(v / eps), v; s^2 = |r|^2 / (n - 2)
        v = np.asarray(data.motion.v)
        p = physical(result.model)
        r = p["Fc"] * np.tanh(v / EPS) + p["Fv"] * v + p["offset"] - np.asarray(data.force)
        J = np.stack([np.tanh(v / EPS), v], axis=1)
        cov = np.sum(r**2) / (n - 2) * np.linalg.inv(J.T @ J)
        np.testing.assert_allclose([params["Fc"][1], params["Fv"][1]], np.sqrt(np.diag(cov)), rtol=1e-6)
        stds[n] = params
    for name in ("Fc", "Fv"):
        ratio = float(stds[4 * N][name][1]) / float(stds[N][name][1])
        assert 0.3 < ratio < 0.7, (name, ratio)  # ~ 1 / sqrt(4)


def independent_std(model: Any, paths: list[str], data: fj.FrictionData) -> np.ndarray:
    """Gauss-Newton standard deviations of the physical parameters `paths`, from a Jacobian with respect to
    relative changes (theta_i (1 + u_i)), so that parameters of any magnitude are resolved alike."""
    unwrapped = fj.unwrap(model)

    def get(m: Any, path: str) -> Any:
        for part in path.split("."):
            m = getattr(m, part)
        return m

    theta = jnp.stack([jnp.asarray(get(unwrapped, p)) for p in paths])

    def residuals(u: jax.Array) -> jax.Array:
        values = [theta[i] * u[i] for i in range(len(paths))]
        return (
            fj.simulate(eqx.tree_at(lambda m: [get(m, p) for p in paths], unwrapped, values), data.motion) - data.force
        )

    ones = jnp.ones(len(paths))
    r, J = np.asarray(residuals(ones)), np.asarray(jax.jacfwd(residuals)(ones))
    cov = np.sum(r**2) / (r.size - len(paths)) * np.linalg.inv(J.T @ J)
    return np.sqrt(np.diag(cov)) * np.abs(np.asarray(theta))


@pytest.mark.slow
def test_gauss_newton_std_of_badly_scaled_parameters(lugre_problem):
    """LuGre with noise: sigma0 (1e5 N/m) and vs (1e-3 m/s) in one covariance."""
    model, clean = lugre_problem
    noise = 0.01 * np.random.default_rng(3).standard_normal(clean.length)
    data = fj.FrictionData(clean.motion, np.asarray(clean.force) + noise)
    result = fj.fit(model, data, solver=optax.adam(1e-6), steps=1, freeze=("z0",), compute_std=True)
    paths = ["stribeck.Fc", "stribeck.Fs", "stribeck.vs", "stribeck.delta", "sigma0", "sigma1", "sigma2", "offset"]
    want = independent_std(result.model, paths, data)
    params = result.parameters()
    got = np.array([float(params[p][1]) for p in paths])
    assert np.isnan(params["z0"][1])
    np.testing.assert_allclose(got, want, rtol=0.02)


def test_summary_keeps_significant_digits():
    model = fj.CoulombViscous(Fc=1.0002e-3, Fv=30.0, offset=0.2)
    std = fj.unwrap(fj.CoulombViscous(Fc=1.76e-4, Fv=0.3, offset=2.5e-4))
    result = fj.FitResult(
        model=model, result="successful", message="test", history={}, train_loss=0.0, val_loss=float("nan"),
        exact_val_loss=float("nan"), evaluations=1, wall_time=0.0, num_starts=1, best_start=0, std=std,
    )  # fmt: skip
    lines = {line.split("=")[0].strip(): line.split("=")[1] for line in result.summary().splitlines() if " = " in line}
    for name, value, sd in (("Fc", 1.0002e-3, 1.76e-4), ("Fv", 30.0, 0.3), ("offset", 0.2, 2.5e-4)):
        shown_value, shown_std = (float(part.split("[")[0]) for part in lines[name].split("±"))
        np.testing.assert_allclose(shown_value, value, rtol=1e-3, err_msg=name)
        np.testing.assert_allclose(shown_std, sd, rtol=1e-2, err_msg=name)


# ----------------------------------------------------------------------------------------------------------------
# separable least squares
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.slow  # about 10 s: the fast tier stays under 5 minutes
def test_separable_offset_and_viscous_coefficient(noisy_fits):
    """Fv and offset solved inside the fit from a wrong start; their fitted values are the least-squares values
    for the fitted Fc (noisy data, so these are not simply the true values)."""
    data, _ = noisy_fits[1][N]
    start = coulomb_viscous(0.6, 3.0, -1.0)
    result = fj.fit(
        start, data, solver=fj.levenberg_marquardt(), steps=50, separable=("Fv", "offset"), compute_std=True
    )
    assert result.success, result.message
    fitted = physical(result.model)
    ls = least_squares_values(result.model, ["Fv", "offset"], data)
    np.testing.assert_allclose([fitted["Fv"], fitted["offset"]], ls, rtol=1e-8)
    assert abs(fitted["Fc"] - 1.0) < 0.03 and abs(fitted["Fv"] - 30.0) < 1.5 and abs(fitted["offset"] - 0.2) < 0.02
    # the same optimum as the joint fit: the gradient of the full loss vanishes there
    full = fj.SimulationLoss()
    grads = jax.grad(lambda m: full(m, None, data))(result.model)
    for name in ("Fv", "offset"):
        assert abs(float(getattr(grads, name))) < 1e-8, (name, getattr(grads, name))
    # standard deviations cover the separable fields as well
    for name in ("Fc", "Fv", "offset"):
        std = result.parameters()[name][1]
        assert np.isfinite(std) and std > 0, (name, std)


@pytest.mark.slow  # about 7 s
def test_separable_lugre_sigma2_and_offset(lugre_problem):
    model, data = lugre_problem
    start = eqx.tree_at(lambda m: (m.sigma2, m.offset), model, (jnp.asarray(5.0), jnp.asarray(-1.0)))
    result = fj.fit(start, data, solver=optax.adam(1e-6), steps=1, separable=("sigma2", "offset"), compute_std=False)
    fitted = fj.unwrap(result.model)
    np.testing.assert_allclose(float(fitted.sigma2), 40.0, rtol=1e-6)
    np.testing.assert_allclose(float(fitted.offset), 0.05, atol=1e-6)
    ls = least_squares_values(result.model, ["sigma2", "offset"], data)
    np.testing.assert_allclose([float(fitted.sigma2), float(fitted.offset)], ls, rtol=1e-6, atol=1e-8)
    assert result.train_loss < 1e-10


@pytest.mark.slow
def test_separable_maxwell_slip_dnlrx_fir():
    motion = sine_motion(growing=True)
    thresholds = [2e-6, 2e-5]
    theta = np.array([[0.3, 0.5], [0.2, -0.1]])
    truth = fj.MaxwellSlip.dnlrx(thresholds, theta, c=[1e3, -5e2], offset=0.1, smoothing=fj.Smooth(1e-2))
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    start = fj.MaxwellSlip.dnlrx(thresholds, np.zeros((2, 2)), c=[0.0, 0.0], offset=0.0, smoothing=fj.Smooth(1e-2))
    separable = ("force_map.theta", "force_map.c", "force_map.offset")
    result = fj.fit(start, data, solver=optax.adam(1e-6), steps=1, separable=separable, compute_std=False)
    fm = result.model.force_map
    np.testing.assert_allclose(np.asarray(fm.theta), theta, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(np.asarray(fm.c), [1e3, -5e2], rtol=1e-6)
    np.testing.assert_allclose(float(fm.offset), 0.1, rtol=1e-6)
    ls = least_squares_values(result.model, list(separable), data)
    got = np.r_[np.asarray(fm.theta).ravel(), np.asarray(fm.c), float(fm.offset)]
    np.testing.assert_allclose(got, ls, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize(
    "solver",
    [
        pytest.param(optax.adam(1e-3), marks=pytest.mark.slow),
        pytest.param(fj.levenberg_marquardt(), marks=pytest.mark.slow),
    ],
    ids=["optax", "optimistix"],
)
def test_separable_only_linear_parameters_left(solver):
    motion = sine_motion(growing=True)
    thresholds = fj.Fixed(jnp.array([2e-6, 2e-5]))
    truth = fj.MaxwellSlip(thresholds, fj.FIRForces(np.array([[0.3, 0.5]]), None, 0.1), smoothing=fj.Smooth(1e-2))
    start = fj.MaxwellSlip(thresholds, fj.FIRForces(np.zeros((1, 2)), None, 0.0), smoothing=fj.Smooth(1e-2))
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    separable = ("force_map.theta", "force_map.offset")
    result = fj.fit(start, data, solver=solver, steps=1, separable=separable, compute_std=False)
    np.testing.assert_allclose(np.asarray(result.model.force_map.theta), [[0.3, 0.5]], rtol=1e-6)
    np.testing.assert_allclose(float(result.model.force_map.offset), 0.1, rtol=1e-6)


def test_separable_rejects_reparametrised_and_nonlinear_fields(lugre_problem):
    model, data = lugre_problem
    with pytest.raises(ValueError, match="'sigma0' is reparametrised"):
        fj.fit(model, data, separable=("sigma0",), steps=1)
    with pytest.raises(ValueError, match="'Fc' is reparametrised"):
        fj.fit(START, DATA, separable=("Fc",), steps=1)
    with pytest.raises(ValueError, match="SimulationLoss"):
        fj.fit(model, data, loss=fj.MultipleShootingLoss(50), separable=("offset",), steps=1)
    with pytest.raises(ValueError, match="'nope'"):
        fj.fit(START, DATA, separable=("nope",), steps=1)
    # the Dahl initial force F0 is a real field that does not enter the force linearly (alpha != 1)
    dahl = fj.Dahl(sigma0=1e5, Fc=1.0, alpha=1.7, F0=0.1)
    dahl_data = fj.FrictionData(MOTION, fj.simulate(fj.Dahl(sigma0=1e5, Fc=1.0, alpha=1.7), MOTION))
    with pytest.raises(ValueError, match=r"do not enter the simulated force linearly"):
        fj.fit(dahl, dahl_data, separable=("F0",), steps=1)


# ----------------------------------------------------------------------------------------------------------------
# multi-start
# ----------------------------------------------------------------------------------------------------------------

# Gauss-Newton is invariant to the per-parameter scaling `fit` applies, so one start fitted alone follows the
# same path as inside the vmap-ed batch; one step leaves the starts at different losses.
MS_SOLVER: Any = optx.GaussNewton(rtol=1e-12, atol=1e-14)


@pytest.fixture(scope="module")
def split_data():
    return DATA.split(0.5)


@pytest.fixture(scope="module")
def multistart_fits(split_data):
    train, val = split_data

    def run(seed: int) -> fj.FitResult:
        return fj.fit(
            START,
            train,
            validation=val,
            solver=MS_SOLVER,
            steps=1,
            multistart=fj.MultiStart(count=4, spread=0.5),
            seed=seed,
            compute_std=False,
        )

    return run(0), run(0), run(1)


def test_multistart_is_deterministic(multistart_fits):
    first, again, other_seed = multistart_fits
    for result in multistart_fits:
        assert result.num_starts == 4 and 0 <= result.best_start < 4
        assert np.isfinite(result.val_loss)
    assert first.best_start == again.best_start
    for a, b in zip(jax.tree_util.tree_leaves(first.model), jax.tree_util.tree_leaves(again.model), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    if first.best_start == 0 and other_seed.best_start == 0:  # start 0 is the initial model for every seed
        assert physical(first.model) == physical(other_seed.model)
    else:
        assert physical(first.model) != physical(other_seed.model)


def test_multistart_chooses_lowest_validation_loss(multistart_fits, split_data):
    train, val = split_data
    first = multistart_fits[0]
    params, static = eqx.partition(START, fj.trainable_filter(START))
    starts = fj.MultiStart(4, 0.5).draw(params, seed=0)
    val_losses = []
    for i in range(4):
        model = eqx.combine(jax.tree_util.tree_map(lambda a, i=i: a[i], starts), static)
        alone = fj.fit(model, train, validation=val, solver=MS_SOLVER, steps=1, compute_std=False)
        val_losses.append(alone.val_loss)
    assert len(set(np.round(val_losses, 12))) == 4, val_losses  # the starts really differ
    assert first.best_start == int(np.argmin(val_losses)), (first.best_start, val_losses)
    np.testing.assert_allclose(first.val_loss, min(val_losses), rtol=1e-6)


def test_multistart_and_continuation_arguments_are_checked():
    with pytest.raises(ValueError, match="count"):
        fj.MultiStart(count=0)
    with pytest.raises(ValueError, match="spread"):
        fj.MultiStart(count=2, spread=-1.0)
    with pytest.raises(ValueError, match="eps_start"):
        fj.Continuation(0.0, 1e-4)
    with pytest.raises(ValueError, match="stages"):
        fj.Continuation(1e-2, 1e-4, stages=0)


# ----------------------------------------------------------------------------------------------------------------
# continuation, early stopping, divergence
# ----------------------------------------------------------------------------------------------------------------


def test_continuation_schedule(split_data):
    train, val = split_data
    continuation = fj.Continuation(1e-2, 1e-4, stages=3)
    np.testing.assert_allclose(continuation.schedule(), [1e-2, 1e-3, 1e-4], rtol=1e-12)
    result = fj.fit(
        START, train, validation=val, solver=optax.adam(3e-2), steps=300, eval_every=50,
        continuation=continuation, scaling=fj.ParameterScaling(),
    )  # fmt: skip
    # two checks per stage of 100 steps, at the stage's eps
    np.testing.assert_allclose(result.history["eps"], np.repeat([1e-2, 1e-3, 1e-4], 2), rtol=1e-12)
    np.testing.assert_array_equal(result.history["step"], [50, 100, 150, 200, 250, 300])
    assert float(result.model.smoothing.eps) == pytest.approx(1e-4, rel=1e-12)
    assert np.isfinite(result.exact_val_loss) and np.isfinite(result.val_loss)
    exact_val = float(fj.SimulationLoss()(fj.exact(result.model), None, val))
    np.testing.assert_allclose(result.exact_val_loss, exact_val, rtol=1e-10)
    assert result.exact_val_loss < 1e-3  # close to the exact model
    assert f"{result.exact_val_loss:.4g}" in result.summary()


def test_continuation_returns_best_model_at_final_eps(split_data):
    smooth_truth = fj.CoulombViscous(Fc=1.0, Fv=30.0, offset=0.2, smoothing=fj.Smooth(1e-2))
    data = fj.FrictionData(MOTION, fj.simulate(smooth_truth, MOTION))
    train, val = data.split(0.5)
    result = fj.fit(
        START, train, validation=val, solver=optax.adam(3e-2), steps=300, eval_every=100,
        continuation=fj.Continuation(1e-2, 1e-4, stages=3), compute_std=False,
    )  # fmt: skip
    history = result.history
    final_stage = history["eps"] == history["eps"][-1]
    assert float(result.model.smoothing.eps) == pytest.approx(1e-4, rel=1e-12)
    # the returned model (at eps_end) is at least as good as the best point seen in the final stage
    assert result.val_loss <= np.min(history["val_loss"][final_stage]) * (1 + 1e-9), (
        result.val_loss,
        history["val_loss"],
    )


def test_validation_early_stopping_keeps_best_model():
    """Trained towards model A, validated on data of model B, starting at B: the validation loss only worsens."""
    model_b = coulomb_viscous(0.5, 15.0, 0.0)
    val = fj.FrictionData(MOTION, fj.simulate(model_b, MOTION))
    patience = 3
    result = fj.fit(
        model_b, DATA, validation=val, solver=optax.adam(1e-2), steps=400, eval_every=10, patience=patience,
        compute_std=False, progress=True,
    )  # fmt: skip
    assert result.code == "early_stopped" and result.success, result.message
    history = result.history
    assert len(history["step"]) == patience + 1 and history["step"][-1] == 10 * (patience + 1)
    assert np.all(np.diff(history["val_loss"]) > 0)  # it really stopped improving
    # no step improved on the start (model B, which the validation data come from): the start is returned
    assert result.val_loss < 1e-20 and "the input model is returned unchanged" in result.message
    np.testing.assert_allclose(result.train_loss, float(fj.SimulationLoss()(model_b, None, DATA)), rtol=1e-10)
    assert result.train_loss > history["train_loss"][-1]


def test_divergence_guard():
    start_loss = float(fj.SimulationLoss()(START, None, DATA))
    result = fj.fit(START, DATA, solver=optax.sgd(1e6), steps=20, eval_every=5, compute_std=False)
    assert result.code == "diverged"
    assert result.success is False
    assert isinstance(result.message, str) and result.message
    assert tree_finite(result.model)
    assert np.all(np.isfinite(np.asarray(fj.simulate(result.model, MOTION))))
    assert np.isfinite(result.train_loss) and result.train_loss <= start_loss * (1 + 1e-12)


# ----------------------------------------------------------------------------------------------------------------
# bad input
# ----------------------------------------------------------------------------------------------------------------


def test_bad_fit_arguments():
    with pytest.raises(TypeError, match="`data`"):
        fj.fit(START, MOTION, steps=1)
    with pytest.raises(TypeError, match="`data`"):
        fj.fit(START, (np.asarray(MOTION.x), np.asarray(DATA.force)), steps=1)
    with pytest.raises(TypeError, match="`validation`"):
        fj.fit(START, DATA, validation=np.asarray(DATA.force), steps=1)
    with pytest.raises(TypeError, match="`model`"):
        fj.fit({"Fc": 1.0}, DATA, steps=1)
    for steps in (0, -3, 2.5):
        with pytest.raises(ValueError, match="`steps`"):
            fj.fit(START, DATA, steps=steps)
    for solver in ("adam", optax.adam, optx.least_squares):
        with pytest.raises(TypeError, match="`solver`"):
            fj.fit(START, DATA, solver=solver, steps=1)
    with pytest.raises(TypeError, match="`loss`"):
        fj.fit(START, DATA, loss=lambda m, e, d: 0.0, steps=1)


def test_bad_friction_data():
    with pytest.raises(ValueError, match="samples"):
        fj.FrictionData(MOTION, np.zeros(N - 1))
    with pytest.raises(ValueError, match="NaN or inf"):
        fj.FrictionData(MOTION, np.r_[np.zeros(N - 1), np.nan])
    with pytest.raises(TypeError, match="motion"):
        fj.FrictionData(np.asarray(MOTION.x), np.zeros(N))
    for points in [(0,), (0.0,), (N,), (1.0,), (0.6, 0.6), (0.8, 0.6)]:
        with pytest.raises(ValueError, match="empty"):
            DATA.split(*points)
    with pytest.raises(ValueError, match="empty"):
        DATA.slice(10, 10)
    with pytest.raises(ValueError, match="split point"):
        DATA.split()


# ----------------------------------------------------------------------------------------------------------------
# saving and loading
# ----------------------------------------------------------------------------------------------------------------


def test_save_load_round_trip(noisy_fits, tmp_path):
    _, fits = noisy_fits
    model = fits[N][1].model
    path = tmp_path / "m.eqx"
    fj.save_model(path, model)
    loaded = fj.load_model(path)
    assert type(loaded) is type(model)
    np.testing.assert_array_equal(np.asarray(fj.simulate(loaded, MOTION)), np.asarray(fj.simulate(model, MOTION)))
    np.testing.assert_array_equal(
        np.asarray(fj.simulate(fj.exact(loaded), MOTION)), np.asarray(fj.simulate(fj.exact(model), MOTION))
    )
    # a model with a state-holding family and nested wrappers round-trips too
    lugre_model = lugre()
    fj.save_model(str(tmp_path / "lugre.eqx"), lugre_model)
    np.testing.assert_array_equal(
        np.asarray(fj.simulate(fj.load_model(str(tmp_path / "lugre.eqx")), MOTION)),
        np.asarray(fj.simulate(lugre_model, MOTION)),
    )


def test_load_rejects_non_model_files(tmp_path):
    text = tmp_path / "notes.txt"
    text.write_text("not a model")
    with pytest.raises(ValueError, match="not a fricjax model file"):
        fj.load_model(text)
    foreign = tmp_path / "foreign.pkl"
    foreign.write_bytes(pickle.dumps({"weights": [1.0, 2.0]}))
    with pytest.raises(ValueError, match="not a fricjax model file"):
        fj.load_model(foreign)
    with pytest.raises(ValueError, match="no file"):
        fj.load_model(tmp_path / "missing.eqx")


def test_save_to_unwritable_path(tmp_path):
    with pytest.raises(ValueError, match="cannot write"):
        fj.save_model(tmp_path / "no_such_dir" / "m.eqx", TRUTH)
    with pytest.raises(ValueError, match="cannot write"):
        fj.save_model(tmp_path, TRUTH)  # a directory


# ----------------------------------------------------------------------------------------------------------------
# never worse than the start, no silent success
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.slow  # the fast tier stays under 5 minutes
def test_fit_never_returns_a_model_worse_than_its_start():
    """Default Adam moves LuGre's zero-initialised z0 [m] by ~1e-2 per step: every step is worse than the start."""
    truth = lugre()
    data = fj.FrictionData(MOTION, fj.simulate(truth, MOTION))
    start = eqx.tree_at(lambda m: m.stribeck.Fc, truth, fj.Positive(1.05))  # a start close to the truth
    start_loss = float(fj.SimulationLoss()(start, None, data))
    result = fj.fit(start, data, steps=20)
    assert result.train_loss <= start_loss * (1 + 1e-12), (result.train_loss, start_loss)
    assert result.success


def test_parameter_scaling_uses_physical_ranges_for_zero_parameters():
    """Issue 8 item 5: a zero-initialised z0 [m] is scaled by the pre-sliding range Fc / sigma0, not by 1."""
    start = lugre(offset=0.0)
    params = eqx.filter(start, eqx.is_inexact_array)
    scales = fj.ParameterScaling().scales(params, start)
    assert np.isclose(float(scales.z0), 1.0 / 1e5) and np.isclose(float(scales.offset), 1.0)
    assert np.isclose(float(scales.sigma2), 40.0)  # non-zero fields: their own magnitude
    members = fj.AverageEnsemble([start, start])
    nested = fj.ParameterScaling().scales(eqx.filter(members, eqx.is_inexact_array), members)
    assert np.isclose(float(nested.members[1].z0), 1e-5)
    # a user's override still wins
    assert float(fj.ParameterScaling({"z0": 3e-6}).scales(params, start).z0) == pytest.approx(3e-6)


@pytest.mark.slow  # the fast tier stays under 5 minutes
def test_scaled_adam_fits_a_zero_initialised_bristle_deflection():
    """With physical ranges one learning rate moves z0 by a fraction of Fc / sigma0 per step: the fit improves
    (without them it moved z0 by ~1e-2 m per step and every step was worse than the start)."""
    truth = eqx.tree_at(lambda m: m.z0, lugre(), jnp.asarray(6e-6))
    data = fj.FrictionData(MOTION, fj.simulate(truth, MOTION))
    start = eqx.tree_at(lambda m: m.z0, truth, jnp.asarray(0.0))
    start_loss = float(fj.SimulationLoss()(start, None, data))
    result = fj.fit(start, data, steps=60, train="z0", scaling=fj.ParameterScaling())
    assert result.train_loss < 0.1 * start_loss, (result.train_loss, start_loss)
    assert abs(float(fj.unwrap(result.model).z0) - 6e-6) < 2e-6
    unscaled = fj.fit(start, data, steps=20, train="z0")  # steps of ~1e-2 m: every one is worse
    assert float(fj.unwrap(unscaled.model).z0) == 0.0 and "scaling=fj.ParameterScaling()" in unscaled.message


@pytest.mark.parametrize("solver", [optax.adam(3e-2), optx.LevenbergMarquardt(rtol=0.0, atol=0.0)], ids=["adam", "lm"])
def test_tolerance_ends_a_fit_as_converged_before_its_budget(solver):
    """A stopping rule for every solver: optimistix LM with tolerances it never meets, and Adam, stop as converged once
    the loss stops falling, well before the budget; without the rule they run it out."""
    noisy = fj.FrictionData(MOTION, np.asarray(DATA.force) + 0.05 * np.random.default_rng(0).normal(size=DATA.length))
    result = fj.fit(
        START, noisy, solver=solver, steps=400, eval_every=20, tolerance=1e-3, scaling=fj.ParameterScaling()
    )
    assert result.code == "successful" and "converged" in result.message, result.message
    assert result.history["step"][-1] < 400
    budget = fj.fit(START, noisy, solver=solver, steps=60, eval_every=20, scaling=fj.ParameterScaling())
    assert budget.code == "max_steps"


def test_validation_burn_in_covering_the_record_is_refused():
    train, val = DATA.split(0.5)
    with pytest.raises(ValueError, match="validation burn-in"):
        fj.fit(START, train, validation=val, validation_burn_in=val.length, steps=1)


@pytest.mark.slow  # the fast tier stays under 5 minutes
def test_separable_least_squares_keeps_damping_nonnegative():
    """Data with a falling force-velocity slope: unconstrained least squares would give Fv ~ -5 N s/m."""
    v = np.asarray(MOTION.v)
    force = 1.0 * np.tanh(v / EPS) - 5.0 * v + 0.2
    data = fj.FrictionData(MOTION, force)
    result = fj.fit(START, data, solver=fj.levenberg_marquardt(), steps=30, separable=("Fv", "offset"))
    p = fj.unwrap(result.model)
    assert float(p.Fv) == 0.0  # the bound is active, not violated
    assert abs(float(p.offset) - 0.2) < 0.05 and np.isfinite(result.train_loss)
    free = fj.lstsq(np.column_stack([v, np.ones_like(v)]), force - np.tanh(v / EPS)).x
    assert free[0] < -4.0  # what the unconstrained solve would have returned


@pytest.mark.parametrize("solver", [optax.adam(3e-2), fj.levenberg_marquardt()], ids=["adam", "lm"])
def test_gradient_fits_keep_damping_nonnegative(solver):
    v = np.asarray(MOTION.v)
    data = fj.FrictionData(MOTION, 1.0 * np.tanh(v / EPS) - 5.0 * v + 0.2)  # a falling force-velocity slope
    result = fj.fit(START, data, solver=solver, steps=60, scaling=fj.ParameterScaling())
    assert float(fj.unwrap(result.model).Fv) >= 0.0


@pytest.mark.slow  # moved from the fast tier (2-core Xeon, 2026-11-27): a compile-count property
@pytest.mark.parametrize("solver", ["adam", "lm"])
def test_a_second_fit_of_the_same_shapes_does_not_recompile(solver):
    """Issue 12: `fit`'s drivers are module-level jitted functions taking the problem as an argument, so a second
    fit with a new start, new data and new validation data of the same shapes compiles nothing (the optax solver
    object is the same; a new `optax.adam(...)` object is a new static argument)."""
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: compiles.append(event) if "backend_compile" in event else None
    )
    adam = optax.adam(1e-2)
    counts = []
    for i in range(2):
        motion = fj.Motion.from_position(1e-3 * (1 + 0.1 * i) * np.sin(np.linspace(0, 12, N)), dt=DT)
        truth = fj.CoulombViscous(Fc=1.0 + 0.1 * i, Fv=20.0, smoothing=fj.Smooth(EPS))
        data = fj.FrictionData(motion, fj.simulate(truth, motion))
        start = fj.CoulombViscous(Fc=0.5 + 0.1 * i, Fv=10.0, smoothing=fj.Smooth(EPS))
        options = {"solver": adam, "steps": 6} if solver == "adam" else {"steps": 3}
        before = len(compiles)
        fj.fit(start, data, validation=data, multistart=2, progress=False, **options)
        counts.append(len(compiles) - before)
    assert counts[0] > 0 and counts[1] == 0, counts


def test_optax_chunks_of_any_length_share_one_compilation():
    """Issue 12: the number of optax steps between checks is a traced argument, so a fit whose chunks have other
    lengths (7 steps checked every 2: chunks of 2, 2, 2, 1) compiles nothing after one with chunks of 3."""
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: compiles.append(event) if "backend_compile" in event else None
    )
    adam = optax.adam(1e-2)
    motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 12, N)), dt=DT)
    data = fj.FrictionData(motion, fj.simulate(fj.CoulombViscous(Fc=1.0, Fv=20.0, smoothing=fj.Smooth(EPS)), motion))
    start = fj.CoulombViscous(Fc=0.5, Fv=10.0, smoothing=fj.Smooth(EPS))
    first = fj.fit(start, data, solver=adam, steps=6, eval_every=3, progress=False)
    before = len(compiles)
    second = fj.fit(start, data, solver=adam, steps=7, eval_every=2, progress=False)
    assert len(compiles) == before, compiles[before:]
    assert first.history["step"][-1] == 6 and second.history["step"][-1] == 7, (first.history, second.history)
    assert second.train_loss < first.train_loss  # the seventh step went on from the sixth's state


def test_a_levenberg_marquardt_fit_compiles_one_program():
    """Issue 33 (first-call latency): a single-start Levenberg-Marquardt fit without validation data compiles one
    program of the loop, the residuals and Jacobian at a trial point, and scores itself with it (no separate loss
    program, no compiled solver loop)."""
    import logging

    names = []

    class Names(logging.Handler):
        def emit(self, record):
            message = record.getMessage()
            if message.startswith("Finished XLA compilation of jit("):
                names.append(message.split("jit(")[1].split(")")[0])

    handler, logger = Names(), logging.getLogger("jax")
    logger.addHandler(handler)
    try:
        with jax.log_compiles():
            motion = fj.Motion.from_position(2e-3 * np.sin(np.linspace(0, 9, 333)), dt=DT)  # a shape of its own
            data = fj.FrictionData(motion, fj.simulate(TRUTH, motion))
            names.clear()
            result = fj.fit(START, data, solver=fj.levenberg_marquardt(), steps=30, scaling=fj.ParameterScaling())
    finally:
        logger.removeHandler(handler)
    assert result.code == "successful" and result.train_loss < 1e-12, result.message
    loop_programs = [n for n in names if n in ("evaluate_starts", "batched_losses", "run_steps", "init_states")]
    assert loop_programs == ["evaluate_starts"], names
    assert "evaluate" not in names, names  # the returned model's loss came from the same program
