"""The time-parallel free run (`fj.simulate(..., scan="parallel")`) equals the sequential scan: values to 1e-12
relative, gradients to 1e-10, under jit, vmap and grad; models without the form say so."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

jax.config.update("jax_enable_x64", True)


def _motion(length: int = 1500, seed: int = 0) -> fj.Motion:
    """A random walk on a growing sine: pre-sliding reversals, stick and gross sliding in one record."""
    rng = np.random.default_rng(seed)
    t = np.arange(length) * 1e-3
    x = 2e-4 * (t / t[-1]) ** 2 * np.sin(2 * np.pi * 3 * t) + np.cumsum(rng.normal(size=length)) * 2e-7
    return fj.Motion.from_position(x, dt=1e-3)


def _lugre(smoothing: fj.AbstractSmoothing | None = None) -> fj.LuGre:
    smoothing = fj.Exact() if smoothing is None else smoothing
    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0)
    return fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=0.4, offset=0.1, z0=2e-6, smoothing=smoothing)


MODELS = {
    "lugre": _lugre(),
    "lugre_smooth": _lugre(fj.Smooth(1e-4)),
    "nlr": fj.MaxwellSlip.nlr(k=[1e5, 5e4, 2e4], thresholds=[1e-6, 3e-6, 1e-5], offset=-0.05),
    "lr": fj.MaxwellSlip.lr(k=[4e4, 2e4, 1e4, 5e3], max_deflection=2e-5),
    "tustin": fj.Tustin(Fc=1.0, Fs=1.5, vs=1e-3, Fv=0.3),
    "drift_lugre": fj.SensorDrift(_lugre(), rate=0.3),
    "leaky_drift_nlr": fj.SensorDrift(fj.MaxwellSlip.nlr(k=[1e5, 5e4], thresholds=[1e-6, 3e-6]), 0.3, tau=0.5),
    # the classical Dahl model (exponent fixed at 1), asymmetric Coulomb levels, from a loaded initial force
    "dahl": fj.Dahl(1e5, [1.0, 0.7], alpha=fj.Fixed(1.0), offset=0.1, F0=0.2),
    "dahl_smooth": fj.Dahl(1e5, 1.0, alpha=fj.Fixed(1.0), F0=-0.3, smoothing=fj.Smooth(1e-4)),
}


def _relative(a: object, b: object) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


FAST = ("lugre", "nlr", "tustin", "drift_lugre", "dahl")  # the fast tier; the others in the slow one (compilation time)


def _tiers(names: list[str], fast: tuple[str, ...]) -> list[object]:
    return [name if name in fast else pytest.param(name, marks=pytest.mark.slow) for name in names]


@pytest.mark.parametrize("name", _tiers(sorted(MODELS), FAST))
def test_parallel_equals_sequential(name):
    model, motion = MODELS[name], _motion()
    sequential = fj.simulate(model, motion, scan="sequential")
    parallel = fj.simulate(model, motion, scan="parallel")
    assert parallel.shape == sequential.shape
    assert _relative(parallel, sequential) < 1e-12


@pytest.mark.parametrize(
    "name", _tiers(["lugre", "lugre_smooth", "nlr", "drift_lugre", "dahl", "dahl_smooth"], ("lugre", "nlr", "dahl"))
)
def test_parallel_gradients_equal_sequential(name):
    model, motion = MODELS[name], _motion(400, seed=1)
    target = fj.simulate(model, motion) * 1.02 + 0.01

    def loss(m: object, scan: str) -> jax.Array:
        return jnp.mean((fj.simulate(m, motion, scan=scan) - target) ** 2)

    sequential = eqx.filter_grad(loss)(model, "sequential")
    parallel = eqx.filter_grad(loss)(model, "parallel")
    for a, b in zip(jax.tree_util.tree_leaves(parallel), jax.tree_util.tree_leaves(sequential), strict=True):
        assert np.all(np.isfinite(np.asarray(a)))
        assert _relative(a, b) < 1e-10


@pytest.mark.slow  # 5-6 s: the fast tier stays within 5 minutes
def test_parallel_on_records_of_every_length_and_in_forward_mode():
    """Records shorter than two blocks, one sample past them, and a length no block divides; then a jvp."""
    model = MODELS["nlr"]
    for length in (2, 17, 1031):
        motion = _motion(length, seed=length)
        parallel = fj.simulate(model, motion, scan="parallel")
        assert _relative(parallel, fj.simulate(model, motion, scan="sequential")) < 1e-12
    lugre, motion = MODELS["lugre"], _motion(300, seed=6)

    def force(sigma0: jax.Array, scan: str) -> jax.Array:
        return fj.simulate(eqx.tree_at(lambda m: m.sigma0, lugre, sigma0), motion, scan=scan)

    sigma0 = fj.unwrap(lugre).sigma0
    _, parallel = jax.jvp(lambda s: force(s, "parallel"), (sigma0,), (jnp.asarray(1e3),))
    _, sequential = jax.jvp(lambda s: force(s, "sequential"), (sigma0,), (jnp.asarray(1e3),))
    assert _relative(parallel, sequential) < 1e-10


@pytest.mark.slow  # fast tier trimmed (2026-11-27): a dtype edge; gradients equal the sequential ones fast
def test_parallel_gradients_of_a_float32_model_from_a_python_float_state():
    """A weakly typed initial state (a Python float) takes the float32 model's dtype: so must its tangent."""
    motion = fj.Motion.from_position(np.asarray(_motion(300, seed=7).x, np.float32), dt=1e-3)
    model = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32) if eqx.is_inexact_array(x) else x, _lugre())
    state = eqx.tree_at(lambda s: s.z, fj.unwrap(model).init_state(), 0.0)

    def loss(m: object, scan: str) -> jax.Array:
        return jnp.mean(fj.simulate(m, motion, state, scan=scan) ** 2)

    parallel = eqx.filter_grad(loss)(model, "parallel")
    sequential = eqx.filter_grad(loss)(model, "sequential")
    for a, b in zip(jax.tree_util.tree_leaves(parallel), jax.tree_util.tree_leaves(sequential), strict=True):
        assert a.dtype == jnp.float32
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-3, atol=1e-6)


@pytest.mark.slow  # fast tier trimmed (2026-11-27): an edge of the gradients checked fast
def test_parallel_gradients_with_respect_to_the_initial_state_batched():
    """Reverse mode through the parallel form's custom derivative (the tangent scan, transposed): with respect to
    the initial state alone (the maps constant), and a batch of gradients under vmap."""
    model, motion = MODELS["nlr"], _motion(300, seed=8)
    state = fj.unwrap(model).init_state()
    target = fj.simulate(model, motion) * 1.02

    def loss(delta: jax.Array, scan: str) -> jax.Array:
        start = eqx.tree_at(lambda s: s.delta, state, delta)
        return jnp.mean((fj.simulate(model, motion, start, scan=scan) - target) ** 2)

    deltas = jnp.asarray([[5e-7, -2e-6, 4e-6], [-1e-6, 1e-6, 0.0]])
    parallel = jax.vmap(jax.grad(lambda d: loss(d, "parallel")))(deltas)
    sequential = jnp.stack([jax.grad(lambda d: loss(d, "sequential"))(d) for d in deltas])
    assert np.all(np.asarray(parallel) != 0.0)
    assert _relative(parallel, sequential) < 1e-10


@pytest.mark.slow
def test_parallel_play_operators_and_forward_mode():
    motion = _motion(600, seed=2)
    plays = fj.PlayOperators([1e-6, 4e-6, 2e-5])
    assert _relative(fj.simulate(plays, motion, scan="parallel"), fj.simulate(plays, motion, scan="sequential")) < 1e-12
    model = MODELS["nlr"]

    def force(k: jax.Array, scan: str) -> jax.Array:
        return fj.simulate(eqx.tree_at(lambda m: m.force_map.k, model, k), motion, scan=scan)

    k = fj.unwrap(model).force_map.k
    direction = jnp.asarray([1e3, -2e3, 5e2])
    _, forward_parallel = jax.jvp(lambda k_: force(k_, "parallel"), (k,), (direction,))
    _, forward_sequential = jax.jvp(lambda k_: force(k_, "sequential"), (k,), (direction,))
    assert _relative(forward_parallel, forward_sequential) < 1e-10


def test_parallel_under_vmap_and_jit():
    motion = _motion(500, seed=3)
    sigma0 = jnp.asarray([5e4, 1e5, 2e5])

    def run(s0: jax.Array, scan: str) -> jax.Array:
        return fj.simulate(eqx.tree_at(lambda m: m.sigma0, _lugre(), s0), motion, scan=scan)

    batched = jax.jit(jax.vmap(lambda s0: run(s0, "parallel")))(sigma0)
    looped = np.stack([np.asarray(run(s0, "sequential")) for s0 in sigma0])
    assert batched.shape == (3, 500)
    assert _relative(batched, looped) < 1e-12


def test_parallel_from_a_given_state():
    model, motion = MODELS["nlr"], _motion(300, seed=4)
    state = fj.unwrap(model).init_state()
    state = eqx.tree_at(lambda s: s.delta, state, jnp.asarray([5e-7, -2e-6, 4e-6]))
    a = fj.simulate(model, motion, state, scan="parallel")
    b = fj.simulate(model, motion, state, scan="sequential")
    assert _relative(a, b) < 1e-12


def test_auto_is_sequential_on_cpu_and_agrees():
    model, motion = MODELS["lugre"], _motion(3000, seed=5)
    assert _relative(fj.simulate(model, motion), fj.simulate(model, motion, scan="sequential")) == 0.0


@pytest.mark.parametrize(
    "model",
    [
        fj.MaxwellSlip.nlr(k=[1e5], thresholds=[1e-6], smoothing=fj.Smooth(0.01)),
        fj.MaxwellSlip.dlr(np.ones((3, 2)), max_deflection=1e-5),
        fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=[1e4, 5e3], alpha=[0.5, 0.5], C=20.0),
        fj.Dahl(1e5, 1.0),  # the exponent is trained: the update is affine only at alpha = 1
        fj.Dahl(1e5, 1.0, alpha=fj.Fixed(0.8)),
    ],
)
def test_parallel_refused_without_the_form(model):
    with pytest.raises(ValueError, match="scan='parallel' needs a model with a time-parallel form"):
        fj.simulate(model, _motion(50), scan="parallel")


def test_a_classical_dahl_whose_exponent_was_replaced_is_refused():
    """The parallel form is read off how the model was built; replacing `alpha` afterwards is refused at the call
    instead of running one exponent in `step` and another in the form."""
    model = eqx.tree_at(lambda m: m.alpha, MODELS["dahl"], fj.Fixed(fj.Positive(0.5)))
    with pytest.raises(ValueError, match="no longer matches how the model was built"):
        fj.simulate(model, _motion(50))


def test_bad_scan_option():
    with pytest.raises(ValueError, match="`scan` must be one of"):
        fj.simulate(MODELS["lugre"], _motion(50), scan="fast")


def test_fit_device_choice_on_cpu():
    motion = _motion(400, seed=6)
    truth = fj.CoulombViscous(Fc=1.0, Fv=30.0, smoothing=fj.Smooth(1e-4))
    data = fj.FrictionData(motion, fj.simulate(truth, motion))
    start = fj.CoulombViscous(Fc=0.5, Fv=10.0, smoothing=fj.Smooth(1e-4))
    on_host = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=30, device=jax.devices("cpu")[0])
    assert "on cpu" in on_host.message
    assert abs(float(fj.unwrap(on_host.model).Fc) - 1.0) < 1e-6
    with pytest.raises(ValueError, match="`device` must be one of"):
        fj.fit(start, data, device="fastest")
    if not [d for d in jax.devices() if d.platform != "cpu"]:
        with pytest.raises(ValueError, match="sees only CPU devices"):
            fj.fit(start, data, device="gpu")


def _has_loop(fun, *args) -> bool:
    """Whether the program of `fun(*args)` holds a sequential loop (a scan or while primitive, at any depth)."""
    text = str(jax.make_jaxpr(fun)(*args))
    return " scan[" in text or " while[" in text


@pytest.mark.slow  # ~8 s of compilations: the fast tier stays under 5 minutes
def test_auto_choices_when_the_default_device_is_an_accelerator(monkeypatch):
    """What `scan="auto"` and `fj.fit(device="auto")` choose on a GPU / TPU, run here with JAX's default backend
    reported as "gpu": the parallel form (no loop: an accelerator unrolls its rounds) from 256 samples on for a
    model that has one, the sequential scan below that and for a model without one; a single fit of a model
    without the form moves to the host CPU and says so, a multi-start one stays. Lengths not used elsewhere in
    this file, so that no program traced for the CPU is reused."""
    lugre = MODELS["lugre"]
    gms = fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=[1e4, 5e3], alpha=[0.5, 0.5], C=20.0)
    long, short = _motion(2999, seed=11), _motion(211, seed=12)
    sequential = fj.simulate(lugre, long, scan="sequential")
    assert _has_loop(lambda m: fj.simulate(m, long, scan="sequential"), lugre)  # the probe sees a scan
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert not _has_loop(lambda m: fj.simulate(m, long), lugre)
    assert _relative(fj.simulate(lugre, long), sequential) < 1e-12
    assert _has_loop(lambda m: fj.simulate(m, short), lugre)  # below PARALLEL_MIN_LENGTH
    assert _has_loop(lambda m: fj.simulate(m, long), gms)  # no parallel form

    dahl = fj.Dahl(1e5, 1.0)  # its exponent trained: no parallel form
    data = fj.FrictionData(short, fj.simulate(dahl, short))
    single = fj.fit(dahl, data, solver=fj.levenberg_marquardt(), steps=2)
    assert "on cpu: sequential work on the host CPU (no time-parallel form" in single.message
    several = fj.fit(dahl, data, solver=fj.levenberg_marquardt(), steps=2, multistart=2)
    assert "on cpu" not in several.message
