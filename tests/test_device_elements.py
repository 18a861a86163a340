"""Real-device elements (issue 29 item 3): backlash, asymmetric dynamic friction, normal-load scaling.

- asymmetric LuGre / GMS / Dahl: steady sliding gives the positive branch for v > 0 and the negative one for v < 0;
  symmetric pairs equal scalar coefficients; GMS sticks inside [-alpha s-, alpha s+];
- backlash: no force change inside the gap, hysteresis loops widened by exactly the gap, the sliding force of the
  wrapped model once engaged;
- normal load: force levels proportional to the load; a constant load equals the model with every force
  parameter scaled;
- smooth -> exact as eps -> 0, gradients against finite differences, saved and loaded;
- oracles: independent NumPy loops (the play operator in absolute positions y = clamp(y, x - g/2, x + g/2), the
  Dahl law in closed form per direction, LuGre by fine RK4 sub-steps with the branch picked by the sign of v).
"""

import jax

jax.config.update("jax_enable_x64", True)

import math  # noqa: E402

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import fricjax as fj  # noqa: E402

DT = 1e-3


def zoh_position(v, dt):
    return np.concatenate([[0.0], np.cumsum(v[1:] * dt)])


def sine_motion(amplitude, periods=3, n_per=1000, dt=DT):
    t = np.arange(periods * n_per + 1) * dt
    return fj.Motion.from_position(amplitude * np.sin(2 * np.pi * t / (n_per * dt)), dt=dt)


def s_exp(v, Fc, Fs, vs, delta):
    return Fc + (Fs - Fc) * math.exp(-((abs(v) / vs) ** delta))


# ----------------------------------------------------------------------------------------------------------------
# asymmetric dynamic friction
# ----------------------------------------------------------------------------------------------------------------

PLUS, MINUS = (1.0, 1.5, 1e-3, 2.0), (0.7, 1.2, 2e-3, 1.0)  # (Fc, Fs, vs, delta) of each branch


def asym_stribeck():
    return fj.ExponentialStribeck(*(tuple(pair) for pair in zip(PLUS, MINUS, strict=True)))


def test_stribeck_pairs_select_the_branch_and_equal_pairs_are_the_scalar_curve():
    curve = asym_stribeck()
    assert curve.asymmetric and not fj.ExponentialStribeck(1.0, 1.5, 1e-3).asymmetric
    for v in (1e-4, 1e-3, 5e-3):
        assert float(curve(v)) == pytest.approx(s_exp(v, *PLUS), rel=1e-12)
        assert float(curve(-v)) == pytest.approx(s_exp(v, *MINUS), rel=1e-12)
    assert float(curve(-2e-3, up=1.0)) == pytest.approx(s_exp(2e-3, *PLUS), rel=1e-12)  # a model's smooth step
    v = np.linspace(-5e-3, 5e-3, 11)
    for cls, shape in ((fj.ExponentialStribeck, 2.0), (fj.RationalStribeck, 1.5)):
        pairs = cls(Fc=(1.0, 1.0), Fs=(1.5, 1.5), vs=(1e-3, 1e-3), **{"delta" if shape == 2.0 else "mu": shape})
        scalar = cls(1.0, 1.5, 1e-3, shape)
        np.testing.assert_allclose(np.asarray(pairs(v)), np.asarray(scalar(v)), rtol=1e-14)
    with pytest.raises(ValueError, match="Fc"):
        fj.ExponentialStribeck(Fc=[1.0, 1.0, 1.0], Fs=1.5, vs=1e-3)


@pytest.mark.parametrize("curve", ["exponential", "rational"])
def test_lugre_asymmetric_steady_sliding_follows_each_branch(curve):
    sigma2, offset = 2.0, 0.05
    if curve == "exponential":
        stribeck, branch = asym_stribeck(), {1: lambda v: s_exp(v, *PLUS), -1: lambda v: s_exp(v, *MINUS)}
    else:
        stribeck = fj.RationalStribeck(Fc=(1.0, 0.7), Fs=(1.5, 1.2), vs=(1e-3, 2e-3), mu=(2.0, 1.0))
        branch = {
            1: lambda v: 1.0 + 0.5 / (1 + (abs(v) / 1e-3) ** 2),
            -1: lambda v: 0.7 + 0.5 / (1 + abs(v) / 2e-3),
        }
    model = fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=sigma2, offset=offset)
    for v in (1e-4, 2e-3, 1e-2, -1e-4, -2e-3, -1e-2):
        force = float(fj.simulate(model, fj.Motion(v=np.full(400, v), dt=1e-2))[-1])
        sign = 1 if v > 0 else -1
        expected = sign * branch[sign](v) + sigma2 * v + offset
        assert force == pytest.approx(expected, rel=1e-9), (v, force, expected)


@pytest.mark.parametrize("C", [30.0, 3e3])
def test_gms_asymmetric_steady_sliding_follows_each_branch(C):
    model = fj.GMS(asym_stribeck(), k=[2e4, 1e4, 5e3], alpha=[0.5, 0.3, 0.2], C=C, sigma2=2.0, offset=-0.1)
    T, ramp = 1600, 200
    for v in (1e-4, 2e-3, -1e-4, -2e-3):
        vel = v * np.minimum(np.arange(T) / ramp, 1.0)
        force = float(fj.simulate(model, fj.Motion(x=zoh_position(vel, DT), v=vel, dt=DT))[-1])
        s = s_exp(v, *PLUS) if v > 0 else -s_exp(v, *MINUS)
        assert force == pytest.approx(s + 2.0 * v - 0.1, rel=1e-9), (v, force)


def test_gms_asymmetric_elements_stick_inside_the_two_bounds_at_rest():
    """After sliding either way and stopping, each element holds its slip force: alpha_i s+(0) above (Fs+),
    alpha_i s-(0) below (Fs-), not a bound of the other side."""
    model = fj.GMS(asym_stribeck(), k=[2e4, 1e4], alpha=[0.6, 0.4], C=3e3)
    for v, level in ((1e-4, s_exp(1e-4, *PLUS)), (-1e-4, -s_exp(1e-4, *MINUS))):
        vel = np.concatenate([np.full(1500, v), np.zeros(100)])
        force = np.asarray(fj.simulate(model, fj.Motion(x=zoh_position(vel, DT), v=vel, dt=DT)))
        assert force[1499] == pytest.approx(level, rel=1e-9)
        assert force[-1] == pytest.approx(level, rel=1e-9)  # held at rest: inside [-alpha Fs-, alpha Fs+]


def test_dahl_asymmetric_tends_to_each_coulomb_level():
    model = fj.Dahl(sigma0=1e4, Fc=(1.0, 0.6))
    up = fj.Motion(v=np.full(2000, 1e-2), dt=DT)  # 20 mm: 200 force lengths Fc / sigma0
    assert float(fj.simulate(model, up)[-1]) == pytest.approx(1.0, rel=1e-12)
    assert float(fj.simulate(model, fj.Motion(v=-up.v, dt=DT))[-1]) == pytest.approx(-0.6, rel=1e-12)
    with pytest.raises(ValueError, match="Fc"):
        fj.Dahl(sigma0=1e4, Fc=(1.0, -0.6))


# ----------------------------------------------------------------------------------------------------------------
# backlash
# ----------------------------------------------------------------------------------------------------------------


def test_backlash_force_stays_zero_inside_the_gap():
    motion = sine_motion(0.9e-3)  # +-0.9 mm around the centre of a 2 mm gap (+-1 mm)
    for inner in (fj.Coulomb(Fc=1.0), fj.LuGre(asym_stribeck(), 1e5, 300.0, 40.0), fj.Dahl(1e4, 1.0)):
        assert np.all(np.asarray(fj.simulate(fj.Backlash(inner, gap=2e-3), motion)) == 0.0)


def _zero_crossings(x, force):
    """The displacements where `force` changes sign, linearly interpolated, by direction of the change."""
    out = {1: [], -1: []}
    for k in np.flatnonzero(np.sign(force[1:]) != np.sign(force[:-1])):
        if force[k] == 0.0 or force[k + 1] == 0.0:
            continue
        w = force[k] / (force[k] - force[k + 1])
        out[int(np.sign(force[k + 1]))].append(x[k] + w * (x[k + 1] - x[k]))
    return out


def test_backlash_widens_the_hysteresis_loop_by_the_gap_and_holds_a_plateau():
    """Dahl is rate independent: with a play each branch of the loop crosses zero `gap` further from its
    reversal (the lost motion), so the zero crossings move apart by exactly 2 gap, and after each reversal the
    force stays constant while the displacement crosses the gap."""
    gap, dahl = 0.6e-3, fj.Dahl(sigma0=1e4, Fc=1.0)
    motion = sine_motion(3e-3, n_per=4000)
    x = np.asarray(motion.x)
    plain = _zero_crossings(x, np.asarray(fj.simulate(dahl, motion)))
    played = _zero_crossings(x, np.asarray(fj.simulate(fj.Backlash(dahl, gap), motion)))
    width_plain = plain[1][-1] - plain[-1][-1]
    width_played = played[1][-1] - played[-1][-1]
    assert width_played - width_plain == pytest.approx(2 * gap, rel=2e-3)
    # the plateau: from the top reversal, the force is unchanged until x has come down by the gap
    force = np.asarray(fj.simulate(fj.Backlash(dahl, gap), motion))
    top = int(np.argmax(x[4000:8000])) + 4000
    inside = (x <= x[top]) & (x > x[top] - gap) & (np.arange(x.size) >= top) & (np.arange(x.size) < top + 2000)
    assert np.ptp(force[inside]) < 1e-12 and inside.sum() > 50
    assert force[top + 2000] < force[top] - 0.5


def test_backlash_engaged_sliding_equals_the_wrapped_model():
    """Once the slack is taken up, the element sees the measured velocity: LuGre's steady sliding is unchanged."""
    model = fj.LuGre(asym_stribeck(), sigma0=1e5, sigma1=300.0, sigma2=2.0)
    for v in (2e-3, -2e-3):
        motion = fj.Motion(v=np.full(400, v), dt=1e-2)
        np.testing.assert_allclose(
            float(fj.simulate(fj.Backlash(model, 1e-3), motion)[-1]), float(fj.simulate(model, motion)[-1]), rtol=1e-9
        )


def _play_positions(x, gap, y0=None):
    """The play operator in absolute positions (independent of fricjax's normalised slack)."""
    y = np.empty_like(x)
    previous = x[0] if y0 is None else y0
    for k, xk in enumerate(x):
        previous = min(max(previous, xk - gap / 2), xk + gap / 2)
        y[k] = previous
    return y


def _dahl_closed_form(y, sigma0, Fc_plus, Fc_minus, F0=0.0):
    """Dahl, alpha = 1, per displacement increment: F -> d Fc_d exponentially in the distance, rate sigma0 / Fc_d."""
    F, out = F0, np.empty_like(y)
    for k in range(y.size):
        dy = 0.0 if k == 0 else y[k] - y[k - 1]
        if dy > 0:
            F = Fc_plus + (F - Fc_plus) * math.exp(-sigma0 * dy / Fc_plus)
        elif dy < 0:
            F = -Fc_minus + (F + Fc_minus) * math.exp(sigma0 * dy / Fc_minus)
        out[k] = F
    return out


def test_oracle_backlash_dahl_and_coulomb_viscous_against_numpy_loops():
    gap = 0.8e-3
    t = np.arange(3000) * DT
    x = 2e-3 * np.sin(2 * np.pi * 1.3 * t) * np.cos(2 * np.pi * 0.4 * t) + 0.3e-3 * np.sin(2 * np.pi * 7.0 * t)
    motion = fj.Motion.from_position(x, dt=DT)
    y = _play_positions(x, gap)
    expected = _dahl_closed_form(y, 1e4, 1.0, 0.6)
    actual = np.asarray(fj.simulate(fj.Backlash(fj.Dahl(sigma0=1e4, Fc=(1.0, 0.6)), gap), motion))
    np.testing.assert_allclose(actual, expected, rtol=1e-9, atol=1e-12)
    # a static law sees the measured velocity times the transmitted fraction of each step
    v = np.asarray(motion.v)
    dx, dy = np.diff(x, prepend=x[0]), np.diff(y, prepend=y[0])
    vy = np.where(dx != 0, v * dy / np.where(dx != 0, dx, 1.0), 0.0)
    law = np.where(vy > 0, 1.0 + 30.0 * vy, np.where(vy < 0, -0.7 + 50.0 * vy, 0.0))
    actual = fj.simulate(fj.Backlash(fj.CoulombViscous(Fc=(1.0, 0.7), Fv=(30.0, 50.0)), gap), motion)
    np.testing.assert_allclose(np.asarray(actual), law, rtol=1e-9, atol=1e-12)


# ----------------------------------------------------------------------------------------------------------------
# normal load
# ----------------------------------------------------------------------------------------------------------------


def _lugre_rk4(v, dt, load, reference, sigma0, sigma1, sigma2, offset, substeps=200):
    """LuGre (worden2007 eqs. 3-5), branch by sign(v), v held over each step; force scaled by |N| / N_ref."""
    z, out = 0.0, np.empty(v.size)
    for k, vk in enumerate(v):
        s = s_exp(vk, *PLUS) if vk > 0 else s_exp(vk, *MINUS)

        def f(zz, vk=vk, s=s):
            return vk - sigma0 * abs(vk) * zz / s

        if k > 0:
            h = dt / substeps
            for _ in range(substeps):
                k1 = f(z)
                k2 = f(z + 0.5 * h * k1)
                k3 = f(z + 0.5 * h * k2)
                k4 = f(z + h * k3)
                z = z + h * (k1 + 2 * k2 + 2 * k3 + k4) / 6
        friction = sigma0 * z + sigma1 * f(z) + sigma2 * vk
        out[k] = abs(load[k]) / reference * friction + offset
    return out


def test_oracle_normal_load_lugre_against_numpy_rk4():
    t = np.arange(1500) * DT
    v = 2e-3 * np.sin(2 * np.pi * 2.0 * t) + 4e-4 * np.sin(2 * np.pi * 11.0 * t)
    v[0] = 0.0
    load = 150.0 + 60.0 * np.sin(2 * np.pi * 0.7 * t)
    motion = fj.Motion(x=zoh_position(v, DT), v=v, dt=DT, normal_force=load)
    model = fj.NormalLoad(fj.LuGre(asym_stribeck(), 2e4, 100.0, 3.0, offset=0.2), reference=120.0)
    expected = _lugre_rk4(v, DT, load, 120.0, 2e4, 100.0, 3.0, 0.2)
    actual = np.asarray(fj.simulate(model, motion))
    np.testing.assert_allclose(actual, expected, rtol=0, atol=1e-7 * np.ptp(expected))


def test_normal_load_scales_force_levels_and_a_constant_load_scales_every_force_parameter():
    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3)
    lugre = fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=2.0)
    motion = sine_motion(1e-3)
    loaded = fj.Motion(x=motion.x, v=motion.v, dt=DT, normal_force=np.full(motion.length, -2.5 * 80.0))
    scaled = fj.LuGre(fj.ExponentialStribeck(2.5, 3.75, 1e-3), sigma0=2.5e5, sigma1=750.0, sigma2=5.0)
    np.testing.assert_allclose(
        np.asarray(fj.simulate(fj.NormalLoad(lugre, 80.0), loaded)),
        np.asarray(fj.simulate(scaled, motion)),
        rtol=1e-9,
        atol=1e-12,
    )
    # a sensor offset is not friction: it is not scaled
    with_offset = fj.NormalLoad(fj.Coulomb(Fc=1.0, offset=0.3), 80.0)
    steps = fj.Motion(v=np.full(3, 0.1), dt=DT, normal_force=np.array([40.0, 80.0, 160.0]))
    np.testing.assert_allclose(np.asarray(fj.simulate(with_offset, steps)), [0.8, 1.3, 2.3], rtol=1e-12)
    with pytest.raises(ValueError, match="normal load"):
        fj.simulate(with_offset, fj.Motion(v=np.full(3, 0.1), dt=DT))
    with pytest.raises(ValueError, match="reference"):
        fj.NormalLoad(lugre, 0.0)
    with pytest.raises(TypeError, match="NormalLoad"):
        fj.NormalLoad("lugre", 1.0)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="Backlash"):
        fj.Backlash("lugre", 1e-3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="gap"):
        fj.Backlash(lugre, -1e-3)


# ----------------------------------------------------------------------------------------------------------------
# smooth -> exact, gradients, files
# ----------------------------------------------------------------------------------------------------------------


def _sliding_motion(T=1000):
    t = np.arange(T) * DT
    v = 1.3e-3 * np.sin(2 * np.pi * 2.0 * t) * (1.0 + 0.6 * np.cos(2 * np.pi * 0.7 * t))
    v = np.where(np.abs(v) < 1e-5, np.where(v < 0, -1e-5, 1e-5), v)  # away from v = 0, as in test_physics
    v[0] = 0.0
    return fj.Motion(x=zoh_position(v, DT), v=v, dt=DT)


SMOOTH_CASES = {
    "lugre-asym": (lambda: fj.LuGre(asym_stribeck(), 1e5, 300.0, 0.4), [1e-3, 1e-4, 1e-5, 1e-6, 1e-7], 1e-4),
    "gms-asym": (lambda: fj.GMS(asym_stribeck(), [2e4, 1e4], [0.6, 0.4], 40.0), [1e-6, 1e-7, 1e-8, 1e-9], 1e-3),
    "dahl-asym": (lambda: fj.Dahl(1e5, (1.0, 0.6)), [1e-4, 1e-5, 1e-6, 1e-7, 1e-8], 1e-3),
    # the play only (dimensionless eps, a fraction of gap / 2), around an exact model; the motion (3e-4 m peak to
    # peak) crosses the 5e-5 m gap at every reversal
    "backlash": (lambda: fj.Backlash(fj.Dahl(1e4, 1.0), 5e-5), [1e-1, 3e-2, 1e-2, 3e-3, 1e-3], 2e-4),
    # LuGre behind a gap of 5e-5 m (the motion crosses it at every reversal); eps on |v| as LuGre's
    "lugre-backlash-asym": (
        lambda: fj.LuGreBacklash(asym_stribeck(), 1e5, 300.0, 0.4, gap=5e-5),
        [1e-3, 1e-4, 1e-5, 1e-6, 1e-7],
        1e-4,
    ),
}


@pytest.mark.parametrize("name", list(SMOOTH_CASES))
def test_smooth_converges_to_exact(name):
    make, eps_values, bound = SMOOTH_CASES[name]
    model, motion = make(), _sliding_motion()
    exact = np.asarray(fj.simulate(fj.exact(model), motion))
    errors = []
    for eps in eps_values:
        if name == "backlash":
            smooth = eqx.tree_at(lambda m: m.smoothing, model, fj.Smooth(eps))
        else:
            smooth = fj.with_smoothing(model, fj.Smooth(eps))
        errors.append(np.max(np.abs(np.asarray(fj.simulate(smooth, motion)) - exact)) / np.ptp(exact))
    assert errors[0] > 1e-3, errors
    for coarse, fine in zip(errors[:-1], errors[1:], strict=True):
        assert fine < coarse or fine < 1e-13, errors
    assert errors[-1] < bound, errors


GRADIENT_CASES = {
    "backlash-gap": lambda g: fj.Backlash(
        fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 1e-3), 2e4, 100.0, 3.0, smoothing=fj.Smooth(1e-4)),
        g * 1e-3,
        smoothing=fj.Smooth(1e-2),
    ),
    "lugre-asym-Fc-": lambda g: fj.LuGre(
        fj.ExponentialStribeck(Fc=jnp.array([1.0, g]), Fs=(1.5, 1.2), vs=1e-3),
        2e4,
        100.0,
        3.0,
        smoothing=fj.Smooth(1e-4),
    ),
    "gms-asym-Fs-": lambda g: fj.GMS(
        fj.ExponentialStribeck(Fc=(1.0, 0.7), Fs=jnp.array([1.5, g]), vs=1e-3),
        [2e4, 1e4],
        [0.6, 0.4],
        40.0,
        smoothing=fj.Smooth(1e-7),
    ),  # fmt: skip
    "dahl-asym-Fc-": lambda g: fj.Dahl(1e4, jnp.array([1.0, g]), smoothing=fj.Smooth(1e-4)),
    "normal-load-sigma0": lambda g: fj.NormalLoad(
        fj.LuGre(fj.ExponentialStribeck(1.0, 1.5, 1e-3), g * 2e4, 100.0, 3.0, smoothing=fj.Smooth(1e-4)), 100.0
    ),
}


FAST_GRADIENTS = ("backlash-gap",)  # the others compile for 3-5 s each: slow tier


@pytest.mark.parametrize(
    "name", [n if n in FAST_GRADIENTS else pytest.param(n, marks=pytest.mark.slow) for n in GRADIENT_CASES]
)
def test_gradient_matches_finite_differences(name):
    t = np.arange(600) * DT
    x = 1.5e-3 * np.sin(2 * np.pi * 2.0 * t) + 2e-4 * np.sin(2 * np.pi * 9.0 * t)
    motion = fj.Motion.from_position(x, dt=DT)
    motion = fj.Motion(x=motion.x, v=motion.v, dt=DT, normal_force=100.0 + 30.0 * np.cos(2 * np.pi * t))
    make, value = GRADIENT_CASES[name], 0.8

    def loss(g):
        return jnp.sum(fj.simulate(make(g), motion) ** 2)

    grad = float(jax.grad(loss)(value))
    h = 1e-6
    finite = (float(loss(value + h)) - float(loss(value - h))) / (2 * h)
    assert np.isfinite(grad) and grad == pytest.approx(finite, rel=1e-5, abs=1e-8 * abs(float(loss(value))))


@pytest.mark.slow  # about 4 s of compilation
def test_saved_and_loaded_and_time_parallel_form(tmp_path):
    t = np.arange(500) * DT
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * 2.0 * t), dt=DT)
    motion = fj.Motion(x=motion.x, v=motion.v, dt=DT, normal_force=100.0 + 30.0 * np.cos(2 * np.pi * t))
    lugre = fj.LuGre(asym_stribeck(), 1e5, 300.0, 0.4, offset=0.1)
    model = fj.NormalLoad(fj.Backlash(lugre, 2e-4, smoothing=fj.Smooth(1e-2)), 90.0)
    fj.save_model(tmp_path / "m.eqx", model)
    back = fj.load_model(tmp_path / "m.eqx")
    np.testing.assert_allclose(np.asarray(fj.simulate(back, motion)), np.asarray(fj.simulate(model, motion)))
    # NormalLoad keeps the wrapped model's time-parallel form (LuGre's affine bristle update)
    np.testing.assert_allclose(
        np.asarray(fj.simulate(fj.NormalLoad(lugre, 90.0), motion, scan="parallel")),
        np.asarray(fj.simulate(fj.NormalLoad(lugre, 90.0), motion, scan="sequential")),
        rtol=1e-9,
        atol=1e-12,
    )
