"""Physics tests: the behaviour the papers describe for each friction model.

- steady sliding gives the Stribeck curve plus the viscous term (LuGre: worden2007 §3.2; GMS: §3.3);
- pre-sliding: a small displacement gives the rest stiffness (sigma0 x for LuGre, sum k_i x for Maxwell slip
  and GMS);
- hysteresis with non-local memory (parlitz2004 §II-A, Fig. 1): an inner loop closes and is wiped out, and a
  reversal follows the Masing rule y(x_m) - 2 y((x_m - x) / 2);
- a single Maxwell-slip element is a spring-slider (hand-computed);
- smooth -> exact as eps -> 0 for every model with stick/slip or sign switching;
- float32 motion and parameters give finite forces, also for stiff bristles.
"""

import jax

jax.config.update("jax_enable_x64", True)

import math  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import fricjax as fj  # noqa: E402


def stribeck_exp(v, Fc, Fs, vs, delta=1.0):
    return Fc + (Fs - Fc) * np.exp(-((np.abs(v) / vs) ** delta))


def stribeck_rational(v, Fc, Fs, vs, mu):
    return Fc + (Fs - Fc) / (1.0 + (np.abs(v) / vs) ** mu)


def zoh_position(v, dt):
    """x_0 = 0, x_k = x_{k-1} + v_k dt (the zero-order hold of v that `Motion.from_velocity` documents)."""
    return np.concatenate([[0.0], np.cumsum(v[1:] * dt)])


def cosine_path(points, dt, vmax):
    """Displacement through `points` [m], each leg a half-cosine (velocity zero at the reversals, peak `vmax`).

    Returns the samples and the index of the last sample of each leg (so legs can be compared across paths).
    """
    pieces, ends = [np.array([float(points[0])])], [0]
    for a, b in zip(points[:-1], points[1:], strict=True):
        n = max(int(math.ceil(math.pi * abs(b - a) / (2 * vmax) / dt)), 4)
        s = np.arange(1, n + 1) / n
        pieces.append(a + (b - a) * (1 - np.cos(np.pi * s)) / 2)
        ends.append(ends[-1] + n)
    return np.concatenate(pieces), ends


# ----------------------------------------------------------------------------------------------------------------
# steady sliding: the Stribeck curve plus the viscous term
# ----------------------------------------------------------------------------------------------------------------

SLIDING_VELOCITIES = [v * s for v in (1e-4, 5e-4, 2e-3, 1e-2, 0.1) for s in (1.0, -1.0)]


@pytest.mark.parametrize("curve", ["exponential", "rational"])
def test_lugre_steady_sliding_is_stribeck_curve_plus_viscous(curve):
    Fc, Fs, vs = 1.0, 1.5, 1e-3
    sigma0, sigma1, sigma2, offset = 1e5, 300.0, 2.0, 0.05
    if curve == "exponential":
        stribeck, s = fj.ExponentialStribeck(Fc=Fc, Fs=Fs, vs=vs, delta=1.5), lambda v: stribeck_exp(v, Fc, Fs, vs, 1.5)
    else:
        stribeck, s = fj.RationalStribeck(Fc=Fc, Fs=Fs, vs=vs, mu=2.0), lambda v: stribeck_rational(v, Fc, Fs, vs, 2.0)
    model = fj.LuGre(stribeck, sigma0=sigma0, sigma1=sigma1, sigma2=sigma2, offset=offset)
    dt, T = 1e-2, 400  # slowest bristle rate sigma0 |v| / s(v) ~ 7 /s: T dt ~ 27 time constants
    for v in SLIDING_VELOCITIES:
        force = np.asarray(fj.simulate(model, fj.Motion(v=np.full(T, v), dt=dt)))
        expected = s(v) * np.sign(v) + sigma2 * v + offset
        assert abs(force[-1] - expected) < 1e-9 * abs(expected), (v, force[-1], expected)
    # the curve itself shows the Stribeck dip: friction falls from Fs towards Fc, then rises viscously
    steady = [
        float(fj.simulate(model, fj.Motion(v=np.full(T, v), dt=dt))[-1]) - offset for v in (1e-4, 2e-3, 1e-2, 0.1)
    ]
    assert steady[0] > steady[1] > steady[2] and steady[3] > steady[2]


@pytest.mark.parametrize("C", [30.0, 3e3])
def test_gms_steady_sliding_is_stribeck_curve_plus_viscous(C):
    Fc, Fs, vs = 1.0, 1.5, 1e-3
    sigma2, offset = 2.0, -0.1
    model = fj.GMS(
        fj.ExponentialStribeck(Fc=Fc, Fs=Fs, vs=vs, delta=2.0),
        k=[2e4, 1e4, 5e3],
        alpha=[0.5, 0.3, 0.2],
        C=C,
        sigma2=sigma2,
        offset=offset,
    )
    dt, T, ramp = 1e-3, 1600, 200  # slowest slip rate C / s(v) >= 20 /s: > 28 time constants after the ramp
    for v in SLIDING_VELOCITIES:
        # accelerate from rest: the elements stick, break away at alpha_i s(v(t)) and then slip while s(v)
        # changes, so the end value is reached through the slip dynamics, not set by the clip
        vel = v * np.minimum(np.arange(T) / ramp, 1.0)
        force = np.asarray(fj.simulate(model, fj.Motion(x=zoh_position(vel, dt), v=vel, dt=dt)))
        expected = stribeck_exp(v, Fc, Fs, vs, 2.0) * np.sign(v) + sigma2 * v + offset
        assert abs(force[-1] - expected) < 1e-9 * abs(expected), (v, force[-1], expected)


# ----------------------------------------------------------------------------------------------------------------
# pre-sliding: rest stiffness
# ----------------------------------------------------------------------------------------------------------------


def test_lugre_presliding_force_is_sigma0_x():
    """Monotone micro-displacement from rest: F = sigma0 x + (sigma1 + sigma2) v - O(sigma0^2 x^2 / Fc).

    From dz/dx = 1 - sigma0 z / s(v) with 0 <= z <= x and s >= Fc: 0 <= x - z <= sigma0 x^2 / (2 Fc), and
    sigma1 dz/dt = sigma1 v (1 - sigma0 z / s) deviates from sigma1 v by at most sigma1 v sigma0 x / Fc.
    """
    Fc, Fs, vs = 1.0, 1.5, 1e-3
    sigma0, sigma1, sigma2 = 1e5, 5.0, 0.4
    A, duration, dt = 1e-7, 0.1, 1e-4  # sigma0 A = 0.01 N << Fc: deep in pre-sliding
    t = np.arange(int(duration / dt) + 1) * dt
    v = A * np.pi / (2 * duration) * np.sin(np.pi * t / duration)  # x = A (1 - cos(pi t / duration)) / 2
    v[0] = 0.0
    x = zoh_position(v, dt)
    model = fj.LuGre(fj.ExponentialStribeck(Fc=Fc, Fs=Fs, vs=vs), sigma0=sigma0, sigma1=sigma1, sigma2=sigma2)
    force = np.asarray(fj.simulate(model, fj.Motion(x=x, v=v, dt=dt)))
    linear = sigma0 * x + (sigma1 + sigma2) * v
    bound = sigma0**2 * x**2 / (2 * Fc) + sigma1 * v * sigma0 * x / Fc
    assert np.all(np.abs(force - linear) <= bound + 1e-12 * sigma0 * A)
    assert np.all(force <= linear + 1e-15)  # the bristle law only softens
    assert abs(force[-1] / (sigma0 * x[-1]) - 1.0) < 1e-2  # stiffness at the end of the ramp (v = 0)
    # and the tangent stiffness at the start is sigma0 to second order
    assert abs(force[10] / (sigma0 * x[10] + (sigma1 + sigma2) * v[10]) - 1.0) < 1e-4


def test_maxwell_slip_presliding_force_is_sum_k_x_and_virgin_curve():
    k = np.array([3e5, 1.5e5, 8e4, 2e4])
    thresholds = np.array([0.7e-6, 1.9e-6, 3.6e-6, 6.5e-6])
    model = fj.MaxwellSlip.nlr(k=k, thresholds=thresholds)
    dt = 1e-3
    # below the smallest threshold, back and forth: linear spring sum k_i
    x_small = 0.6e-6 * np.sin(np.linspace(0, 5 * np.pi, 400))
    force = np.asarray(fj.simulate(model, fj.Motion(x=x_small, dt=dt)))
    np.testing.assert_allclose(force, k.sum() * x_small, rtol=1e-12, atol=1e-12 * k.sum() * 0.6e-6)
    # monotone loading from rest past every threshold: the virgin curve sum_i k_i min(x, Delta_i)
    for sign in (1.0, -1.0):
        x = sign * np.linspace(0.0, 8e-6, 500)
        force = np.asarray(fj.simulate(model, fj.Motion(x=x, dt=dt)))
        virgin = sign * (k * np.minimum(np.abs(x)[:, None], thresholds)).sum(axis=1)
        np.testing.assert_allclose(force, virgin, rtol=1e-12, atol=1e-12 * np.abs(virgin).max())


def test_gms_presliding_force_is_sum_k_x():
    k = np.array([2e4, 1e4, 5e3])
    alpha = np.array([0.5, 0.3, 0.2])
    sigma2 = 0.3
    # break-away displacements alpha_i Fc / k_i = 25, 30, 40 um: stay below 10 um, even at a fast pace
    model = fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=k, alpha=alpha, C=50.0, sigma2=sigma2)
    dt = 1e-3
    t = np.arange(600) * dt
    v = 2 * np.pi * 3.0 * 1e-5 * np.cos(2 * np.pi * 3.0 * t) * np.exp(-t)
    v[0] = 0.0
    x = zoh_position(v, dt)
    assert np.abs(x).max() < 1e-5
    force = np.asarray(fj.simulate(model, fj.Motion(x=x, v=v, dt=dt)))
    expected = k.sum() * x + sigma2 * v
    np.testing.assert_allclose(force, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


# ----------------------------------------------------------------------------------------------------------------
# hysteresis with non-local memory
# ----------------------------------------------------------------------------------------------------------------

# parlitz2004 Fig. 1(a): 0 -> A (virgin) -> B (reversal) -> C (inner reversal) -> B (loop closes) -> D
A_, B_, C_, D_ = 8e-6, -4.4e-6, 0.9e-6, -8e-6


def _loop_paths(dt, vmax):
    with_loop, ends1 = cosine_path([0.0, A_, B_, C_, B_, D_], dt, vmax)
    without, ends2 = cosine_path([0.0, A_, B_, D_], dt, vmax)
    # the last leg B -> D is the same samples in both paths
    np.testing.assert_array_equal(with_loop[ends1[4] :], without[ends2[2] :])
    return with_loop, ends1, without, ends2


def _hysteresis_checks(force_loop, ends1, force_plain, ends2, x_loop, tolerance):
    scale = np.ptp(force_plain)
    # the inner loop is a genuine hysteresis loop: ascending and descending branches differ
    up = force_loop[ends1[2] : ends1[3] + 1]
    down = force_loop[ends1[3] : ends1[4] + 1][::-1]
    x_up = x_loop[ends1[2] : ends1[3] + 1]
    x_down = x_loop[ends1[3] : ends1[4] + 1][::-1]
    mid = 0.5 * (B_ + C_)
    gap = np.interp(mid, x_up, up) - np.interp(mid, x_down, down)
    assert abs(gap) > 0.05 * scale
    # it closes: back at B the force is the one before the inner loop
    assert abs(force_loop[ends1[4]] - force_loop[ends1[2]]) <= tolerance * scale
    # and it is wiped out: the rest of the path follows the outer curve as if it had never happened
    np.testing.assert_allclose(force_loop[ends1[4] :], force_plain[ends2[2] :], rtol=0, atol=tolerance * scale)


def test_maxwell_slip_inner_loop_closes_and_is_wiped_out():
    k = np.array([3e5, 1.5e5, 8e4, 2e4, 1e4])
    thresholds = np.array([0.7e-6, 1.9e-6, 3.6e-6, 6.5e-6, 9.5e-6])
    model = fj.MaxwellSlip.nlr(k=k, thresholds=thresholds, offset=0.2)
    dt = 1e-3
    x_loop, ends1, x_plain, ends2 = _loop_paths(dt, vmax=2e-4)
    force_loop = np.asarray(fj.simulate(model, fj.Motion(x=x_loop, dt=dt)))
    force_plain = np.asarray(fj.simulate(model, fj.Motion(x=x_plain, dt=dt)))
    _hysteresis_checks(force_loop, ends1, force_plain, ends2, x_loop, tolerance=1e-12)


def test_maxwell_slip_reversal_follows_masing_rule():
    """parlitz2004 Fig. 1(a): after a reversal at x_m the force follows y(x_m) - 2 y((x_m - x) / 2)."""
    k = np.array([3e5, 1.5e5, 8e4, 2e4])
    thresholds = np.array([0.7e-6, 1.9e-6, 3.6e-6, 6.5e-6])
    model = fj.MaxwellSlip.nlr(k=k, thresholds=thresholds)

    def virgin(u):
        return np.sign(u) * (k * np.minimum(np.abs(np.asarray(u))[..., None], thresholds)).sum(axis=-1)

    x_m = 5e-6
    x = np.concatenate([np.linspace(0.0, x_m, 300), np.linspace(x_m, -x_m, 600)[1:]])
    force = np.asarray(fj.simulate(model, fj.Motion(x=x, dt=1e-3)))
    descending = x[299:]
    masing = virgin(x_m) - 2 * virgin((x_m - descending) / 2)
    np.testing.assert_allclose(force[299:], masing, rtol=0, atol=1e-12 * np.abs(masing).max())
    # the loop is symmetric: at -x_m the force is -y(x_m)
    assert abs(force[-1] + virgin(x_m)) < 1e-12 * abs(virgin(x_m))


def test_gms_inner_loop_closes_and_is_wiped_out_in_rate_independent_limit():
    """Slow motion (v <= vs / 100) and fast slip dynamics: GMS ~ Maxwell slip, so the wipe-out holds closely.

    The residual comes from s(v) varying with the speed along the path (about 3e-6 of the force range here; it
    grows with v / vs, to ~1e-4 at vs / 10 and ~2e-3 at vs / 2), hence the 1e-4 tolerance.
    """
    k = np.array([6e5, 2e5, 6e4])
    alpha = np.array([0.5, 0.3, 0.2])
    model = fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=k, alpha=alpha, C=1e4)
    dt = 1e-3
    x_loop, ends1, x_plain, ends2 = _loop_paths(dt, vmax=1e-5)
    # break-away displacements alpha_i Fs / k_i = 1.25, 2.25, 5 um: the outer loop makes every element slip,
    # the inner loop (5.3 um) the first two only
    force_loop = np.asarray(fj.simulate(model, fj.Motion.from_position(x_loop, dt)))
    force_plain = np.asarray(fj.simulate(model, fj.Motion.from_position(x_plain, dt)))
    _hysteresis_checks(force_loop, ends1, force_plain, ends2, x_loop, tolerance=1e-4)


# ----------------------------------------------------------------------------------------------------------------
# a single Maxwell-slip element: a spring-slider, by hand
# ----------------------------------------------------------------------------------------------------------------


def test_single_maxwell_slip_element_is_hand_computed_spring_slider():
    # k = 1000 N/m, Delta = 1 mm: the spring holds at most 1 N, then the slider moves.
    #   x [mm]     0    0.5   1.5   2.5   2.0   0.8   -0.4   0.1
    #   delta [mm] 0    0.5   1.0   1.0   0.5  -0.7   -1.0  -0.5   (clipped at +-1 mm: the slider slips)
    #   F [N]      0    0.5   1.0   1.0   0.5  -0.7   -1.0  -0.5
    x = 1e-3 * np.array([0.0, 0.5, 1.5, 2.5, 2.0, 0.8, -0.4, 0.1])
    expected = np.array([0.0, 0.5, 1.0, 1.0, 0.5, -0.7, -1.0, -0.5])
    model = fj.MaxwellSlip.nlr(k=[1e3], thresholds=[1e-3])
    force = np.asarray(fj.simulate(model, fj.Motion(x=x, dt=1e-3)))
    np.testing.assert_allclose(force, expected, rtol=0, atol=1e-12)
    # with an offset b the force shifts by b; starting elsewhere (element relaxed at x(0)) changes nothing
    shifted = np.asarray(
        fj.simulate(fj.MaxwellSlip.nlr(k=[1e3], thresholds=[1e-3], offset=0.25), fj.Motion(x=x + 3e-3, dt=1e-3))
    )
    np.testing.assert_allclose(shifted, expected + 0.25, rtol=0, atol=1e-12)
    # the same element as LR(1) (Delta_1 = max_deflection) and as DLR(1, 0) (theta_0 = k Delta)
    lr = np.asarray(fj.simulate(fj.MaxwellSlip.lr(k=[1e3], max_deflection=1e-3), fj.Motion(x=x, dt=1e-3)))
    dlr = np.asarray(fj.simulate(fj.MaxwellSlip.dlr(theta=[[1.0]], max_deflection=1e-3), fj.Motion(x=x, dt=1e-3)))
    np.testing.assert_allclose(lr, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dlr, expected, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------------------------------------
# smooth -> exact as eps -> 0
# ----------------------------------------------------------------------------------------------------------------


def _sliding_motion(T=1000, dt=1e-3, rest=True):
    t = np.arange(T) * dt
    v = 1.3e-3 * np.sin(2 * np.pi * 2.0 * t) * (1.0 + 0.6 * np.cos(2 * np.pi * 0.7 * t)) + 2e-4 * np.sin(
        2 * np.pi * 9.0 * t
    )
    # no speed inside (0, 1e-5): a discontinuous law can only converge pointwise away from v = 0
    v = np.where(np.abs(v) < 1e-5, np.where(v < 0, -1e-5, 1e-5), v)
    v[0] = 0.0
    if rest:
        v[T // 3 : T // 3 + 40] = 0.0  # a rest (dx = 0 exactly), as in quantised encoder data
    return fj.Motion(x=zoh_position(v, dt), v=v, dt=dt)


def _presliding_motion(T=1000, dt=1e-3):
    t = np.linspace(0.0, 1.0, T)
    x = 6e-6 * np.sin(2 * np.pi * 2.0 * t) * (0.4 + 0.6 * np.abs(np.sin(2 * np.pi * 0.8 * t)))
    return fj.Motion.from_position(x + 1.5e-6 * np.sin(2 * np.pi * 13.0 * t), dt)


SMOOTH_CASES = {
    # name: (model, motion, eps values over four decades (units stated by each model), smallest-error bound)
    "lugre": (
        lambda: fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.4),
        _sliding_motion,
        [1e-3, 1e-4, 1e-5, 1e-6, 1e-7],  # m/s, on |v|; |v| up to 2e-3
        1e-4,
    ),
    "gms": (
        lambda: fj.GMS(
            fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=[2e4, 1e4, 5e3], alpha=[0.5, 0.3, 0.2], C=40.0
        ),
        lambda: _sliding_motion(rest=False),  # see test_gms_smooth_converges_to_exact_through_a_rest
        [1e-6, 1e-7, 1e-8, 1e-9, 1e-10],  # m, on dx (~ 1e-6) and the element lengths (~ 1e-5)
        1e-3,
    ),
    "maxwell-slip": (
        lambda: fj.MaxwellSlip.nlr(k=[3e5, 1.5e5, 8e4, 2e4], thresholds=[0.7e-6, 1.9e-6, 3.6e-6, 6.5e-6]),
        _presliding_motion,
        [3e-1, 3e-2, 3e-3, 3e-4, 3e-5],  # dimensionless, on dbar
        1e-6,
    ),
    "dahl": (
        lambda: fj.Dahl(sigma0=1e5, Fc=1.0, alpha=1.0),
        _sliding_motion,
        [1e-5, 1e-6, 1e-7, 1e-8, 1e-9],  # m/s, per the docstring
        1e-3,
    ),
    "bo-pavelescu-asym": (
        lambda: fj.BoPavelescu(Fc=(1.0, 0.8), Fs=(1.5, 1.3), vs=(1e-3, 2e-3), delta=(2.0, 1.0), Fv=(0.3, 0.5)),
        _sliding_motion,
        [1e-4, 1e-5, 1e-6, 1e-7, 1e-8],  # m/s
        1e-6,
    ),
    "coulomb-viscous-asym": (
        lambda: fj.CoulombViscous(Fc=(1.0, 0.7), Fv=(0.3, 0.6)),
        _sliding_motion,
        [1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
        1e-6,
    ),
    "coulomb": (lambda: fj.Coulomb(Fc=1.0), _sliding_motion, [1e-4, 1e-5, 1e-6, 1e-7, 1e-8], 1e-6),
    "tustin": (
        lambda: fj.Tustin(Fc=1.0, Fs=1.5, vs=1e-3, Fv=0.3),
        _sliding_motion,
        [1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
        1e-6,
    ),
    # Threlfall's law is continuous at v = 0 and smoothing only blends its two sides: the sides must differ (an
    # asymmetric law) for the smoothing to show at all
    "threlfall-asym": (
        lambda: fj.Threlfall(Fc=(1.0, 0.7), Fv=(0.3, 0.5), v0=(2e-4, 3e-4)),
        _sliding_motion,
        [1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
        1e-6,
    ),
}


@pytest.mark.parametrize("name", list(SMOOTH_CASES))
def test_smooth_converges_to_exact(name):
    make, make_motion, eps_values, smallest_bound = SMOOTH_CASES[name]
    model, motion = make(), make_motion()
    exact = np.asarray(fj.simulate(fj.exact(model), motion))
    scale = np.ptp(exact)
    errors = []
    for eps in eps_values:
        smooth = np.asarray(fj.simulate(fj.with_smoothing(model, fj.Smooth(eps)), motion))
        assert np.all(np.isfinite(smooth))
        errors.append(np.max(np.abs(smooth - exact)) / scale)
    assert errors[0] > 1e-3, errors  # the smoothing is visible at the widest eps (the test is not vacuous)
    for coarse, fine in zip(errors[:-1], errors[1:], strict=True):
        assert fine < coarse or fine < 1e-13, errors
    assert errors[-1] < smallest_bound, errors


def test_gms_smooth_converges_to_exact_through_a_rest():
    model = fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=[2e4, 1e4, 5e3], alpha=[0.5, 0.3, 0.2], C=40.0)
    motion = _sliding_motion(rest=True)
    exact = np.asarray(fj.simulate(fj.exact(model), motion))
    errors = [
        np.max(np.abs(np.asarray(fj.simulate(fj.with_smoothing(model, fj.Smooth(eps)), motion)) - exact))
        / np.ptp(exact)
        for eps in (1e-8, 1e-10, 1e-12)
    ]
    assert errors[-1] < 1e-3, errors


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_dahl_smoothing_width_is_a_velocity(dt):
    """At constant sliding speed |v| = 1e-3 m/s, Smooth(eps = 1e-5 m/s) (1 % of |v|) must be near exact."""
    v = np.full(200, 1e-3)
    v[0] = 0.0
    motion = fj.Motion(x=zoh_position(v, dt), v=v, dt=dt)
    model = fj.Dahl(sigma0=1e4, Fc=1.0)
    exact = np.asarray(fj.simulate(model, motion))
    smooth = np.asarray(fj.simulate(fj.with_smoothing(model, fj.Smooth(1e-5)), motion))
    # tanh(|v| / eps) = tanh(100) = 1 to machine precision: no smoothing error is expected at all
    np.testing.assert_allclose(smooth, exact, rtol=1e-6, atol=1e-9)


# ----------------------------------------------------------------------------------------------------------------
# float32
# ----------------------------------------------------------------------------------------------------------------

f32 = np.float32


def _f32_motion_sliding(T=400, dt=1e-3, amplitude=1e-2):
    t = np.arange(T) * dt
    v = (amplitude * np.sin(2 * np.pi * 5.0 * t)).astype(f32)
    return fj.Motion.from_velocity(v, f32(dt))


def _f32_motion_presliding(T=400, dt=1e-3):
    t = np.arange(T) * dt
    return fj.Motion.from_position((8e-6 * np.sin(2 * np.pi * 3.0 * t)).astype(f32), f32(dt))


def _stribeck32():
    return fj.ExponentialStribeck(Fc=f32(1.0), Fs=f32(1.5), vs=f32(1e-3), delta=f32(1.0))


# every argument float32, including the optional ones (offset, z0, F0, sigma2)
FLOAT32_MODELS = {
    "lugre-stiff": (
        lambda: fj.LuGre(_stribeck32(), f32(1e8), f32(1e4), f32(0.4), offset=f32(0.0), z0=f32(0.0)),
        _f32_motion_sliding,
    ),
    "lugre-stiff-rational": (
        lambda: fj.LuGre(
            fj.RationalStribeck(f32(1.0), f32(1.5), f32(1e-3), f32(2.0)),
            f32(1e8),
            f32(1e4),
            f32(0.4),
            offset=f32(0.0),
            z0=f32(0.0),
        ),
        _f32_motion_sliding,
    ),
    "gms-stiff": (
        lambda: fj.GMS(
            _stribeck32(),
            k=np.array([1e8, 5e7], f32),
            alpha=np.array([0.6, 0.4], f32),
            C=f32(1e5),
            sigma2=f32(0.3),
            offset=f32(0.0),
        ),
        _f32_motion_sliding,
    ),
    "maxwell-slip-nlr": (
        lambda: fj.MaxwellSlip.nlr(
            k=np.array([3e5, 1e5, 2e4], f32), thresholds=np.array([1e-6, 3e-6, 6e-6], f32), offset=f32(0.0)
        ),
        _f32_motion_presliding,
    ),
    "maxwell-slip-dnlrx": (
        lambda: fj.MaxwellSlip.dnlrx(
            thresholds=np.array([1e-6, 3e-6], f32),
            theta=np.ones((3, 2), f32),
            c=np.array([1e5, -5e4], f32),
            offset=f32(0.0),
        ),
        _f32_motion_presliding,
    ),
    "dahl": (lambda: fj.Dahl(f32(1e8), f32(1.0), f32(0.5), offset=f32(0.0), F0=f32(0.0)), _f32_motion_sliding),
    "bo-pavelescu": (
        lambda: fj.BoPavelescu(f32(1.0), f32(1.5), f32(1e-3), f32(2.0), f32(0.3), offset=f32(0.0)),
        _f32_motion_sliding,
    ),
    "threlfall-asym": (
        lambda: fj.Threlfall(np.array([1.0, 1.2], f32), f32(0.3), f32(1e-3), offset=f32(0.0)),
        _f32_motion_sliding,
    ),
    "tustin": (
        lambda: fj.Tustin(f32(1.0), f32(1.5), f32(1e-3), f32(0.3), offset=f32(0.0)),
        _f32_motion_sliding,
    ),
}


@pytest.mark.parametrize("name", sorted(FLOAT32_MODELS))
def test_float32_gives_finite_float32_force(name):
    make, make_motion = FLOAT32_MODELS[name]
    model, motion = make(), make_motion()
    force = fj.simulate(model, motion)
    assert force.dtype == np.float32
    force = np.asarray(force)
    assert np.all(np.isfinite(force))
    # and it agrees with the float64 simulation of the same (float32-representable) data
    model64 = jax.tree_util.tree_map(
        lambda a: a.astype(np.float64) if hasattr(a, "dtype") and a.dtype == np.float32 else a, model
    )
    motion64 = fj.Motion(x=np.asarray(motion.x, np.float64), v=np.asarray(motion.v, np.float64), dt=float(motion.dt))
    force64 = np.asarray(fj.simulate(model64, motion64))
    assert np.max(np.abs(force - force64)) <= 1e-3 * np.max(np.abs(force64)), name


def test_float32_stiff_lugre_stays_bounded():
    """sigma0 = 1e8 N/m at 1 kHz in float32: bounded by the Stribeck curve plus the damping terms."""
    model, motion = FLOAT32_MODELS["lugre-stiff"]
    force = np.asarray(fj.simulate(model(), motion()))
    v_max = float(np.max(np.abs(motion().v)))
    assert np.all(np.isfinite(force))
    assert np.max(np.abs(force)) <= 1.5 + 0.4 * v_max + 1e4 * v_max + 1e-3


@pytest.mark.parametrize("name", ["lugre", "gms", "maxwell-slip", "dahl", "bo-pavelescu"])
def test_float32_with_default_arguments_keeps_float32(name):
    makers = {
        "lugre": lambda: fj.LuGre(fj.ExponentialStribeck(f32(1.0), f32(1.5), f32(1e-3)), f32(1e8), f32(1e4), f32(0.4)),
        "gms": lambda: fj.GMS(
            fj.ExponentialStribeck(f32(1.0), f32(1.5), f32(1e-3)),
            k=np.array([2e4, 1e4], f32),
            alpha=np.array([0.6, 0.4], f32),
            C=f32(50.0),
        ),
        "maxwell-slip": lambda: fj.MaxwellSlip.nlr(k=np.array([3e5, 1e5], f32), thresholds=np.array([1e-6, 3e-6], f32)),
        "dahl": lambda: fj.Dahl(f32(1e5), f32(1.0)),
        "bo-pavelescu": lambda: fj.BoPavelescu(f32(1.0), f32(1.5), f32(1e-3)),
    }
    motion = _f32_motion_presliding() if name == "maxwell-slip" else _f32_motion_sliding()
    force = fj.simulate(makers[name](), motion)
    assert force.dtype == np.float32
    assert np.all(np.isfinite(np.asarray(force)))


@pytest.mark.parametrize("name", ["lugre-stiff", "gms-stiff", "maxwell-slip-nlr", "dahl", "bo-pavelescu"])
def test_float32_smooth_mode_keeps_float32(name):
    make, make_motion = FLOAT32_MODELS[name]
    model = fj.with_smoothing(make(), fj.Smooth(f32(1e-4)))
    force = fj.simulate(model, make_motion())
    assert force.dtype == np.float32
    assert np.all(np.isfinite(np.asarray(force)))


# ----------------------------------------------------------------------------------------------------------------
# GMS's packed free run (`packed_unroll`): a performance path whose values and derivatives are the plain scan's
# ----------------------------------------------------------------------------------------------------------------


def _gms_packed_case():
    t = np.arange(600) * 1e-3
    motion = fj.Motion.from_position(2e-4 * np.sin(2 * np.pi * 3 * t) * (0.2 + t), dt=1e-3)
    model = fj.GMS(
        fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3),
        k=[4e4, 2e4, 1e4],
        alpha=[0.5, 0.3, 0.2],
        C=20.0,
        sigma2=0.4,
        smoothing=fj.Smooth(1e-6),
    )
    dummy = np.zeros(600)

    def free(m, unroll=None):
        return fj.simulate(m, motion, unroll=unroll)

    def plain(m):
        return fj.simulate(m, motion, measured=dummy)

    return model, free, plain


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 319 s)
def test_gms_packed_free_run_equals_plain_scan_values_and_gradients():
    """The free run of GMS packs its parameters (a custom JVP whose rule is the plain scan's JVP); the one-step
    mode (`measured=`, equal to the free run for a model without fed-back outputs) runs the plain scan."""
    import equinox as eqx

    model, free, plain = _gms_packed_case()
    np.testing.assert_allclose(free(model), plain(model), rtol=0, atol=1e-13)
    np.testing.assert_allclose(free(model, unroll=3), plain(model), rtol=0, atol=1e-13)

    def loss(run):
        return lambda m: jax.numpy.mean((run(m) - 0.5) ** 2)

    g_free = eqx.filter_grad(loss(free))(model)
    g_plain = eqx.filter_grad(loss(plain))(model)
    for a, b in zip(jax.tree_util.tree_leaves(g_free), jax.tree_util.tree_leaves(g_plain), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14 * float(np.max(np.abs(b))))


@pytest.mark.slow  # the nested derivative compiles for ~6 s
def test_gms_packed_free_run_equals_plain_scan_nested_derivatives_and_vmap():
    """A derivative of a derivative (the separable fits' forward Jacobian under reverse mode) and vmap of GMS's
    packed free run equal the plain scan's."""
    import equinox as eqx

    model, free, plain = _gms_packed_case()

    def nested(run):
        def f(Fc):
            m = eqx.tree_at(lambda g: g.stribeck.Fc, model, Fc)
            return jax.numpy.sum(jax.jacfwd(lambda s: run(eqx.tree_at(lambda g: g.sigma2, m, s)))(0.4) ** 2)

        return jax.grad(f)(1.0)

    np.testing.assert_allclose(nested(free), nested(plain), rtol=1e-10)
    batch = eqx.filter_vmap(lambda s: free(eqx.tree_at(lambda g: g.sigma2, model, s)))(jax.numpy.array([0.1, 0.4]))
    np.testing.assert_allclose(batch[1], plain(model), rtol=0, atol=1e-13)
