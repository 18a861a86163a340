"""The batch-minor free run under `jax.vmap` (models whose `batch_minor()` is true: LuGre, Maxwell-slip LR / NLR), a
performance path: the batch runs as the last axis of the loop's arrays and the outputs are written in `(batch,
time)` order. Its values must be the per-trajectory runs', however the arguments are batched (parameters, part of
them, motions, `dt`, nested vmaps), and its derivatives the plain scan's (a custom JVP: the path is never
differentiated)."""

from __future__ import annotations

import functools
from typing import ClassVar

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.extend  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import fricjax as fj  # noqa: E402

T = 300
ATOL = 1e-13  # forces of ~1 N: the batched loop may contract multiply-adds differently


def motion(scale: float = 1.0, dt: float = 1e-3) -> fj.Motion:
    t = np.arange(T) * dt
    return fj.Motion.from_position(scale * 2e-5 * np.sin(2 * np.pi * 4 * t) * (0.3 + t / t[-1]), dt=dt)


def nlr(k_scale=1.0, threshold_scale=1.0, offset=0.1, smoothing=None) -> fj.MaxwellSlip:
    kwargs = {} if smoothing is None else {"smoothing": smoothing}
    return fj.MaxwellSlip.nlr(
        k=k_scale * jnp.array([3e5, 1.5e5, 8e4, 2e4]),
        thresholds=threshold_scale * jnp.array([0.7e-6, 1.9e-6, 3.6e-6, 6.5e-6]),
        offset=offset,
        **kwargs,
    )


def stack(trees):
    return jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *trees)


def simulate_each(models, motions):
    return np.stack([np.asarray(fj.simulate(m, mo)) for m, mo in zip(models, motions, strict=True)])


def transposed_shapes(jaxpr) -> list[tuple[int, ...]]:
    """The operand shapes of every `transpose` in a jaxpr, sub-jaxprs included."""
    shapes = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "transpose":
            shapes.append(tuple(eqn.invars[0].aval.shape))
        for sub in jax.extend.core.jaxprs_in_params(eqn.params):
            shapes.extend(transposed_shapes(sub))
    return shapes


@pytest.mark.parametrize("smoothing", [None, fj.Smooth(1e-3)], ids=["exact", "smooth"])
def test_batch_of_models_equals_each_model_and_writes_rows_directly(smoothing):
    """A batch of NLR models (every parameter batched): the batched forces are each model's, and the program
    moves no `(time, batch)` array: the rows are written in the loop (no transposition of the output)."""
    models = [nlr(1.0 + 0.2 * i, 1.0 - 0.1 * i, 0.1 * i, smoothing) for i in range(5)]
    mo = motion()
    batched = eqx.filter_vmap(lambda m: fj.simulate(m, mo))(stack(models))
    assert batched.shape == (5, T)
    np.testing.assert_allclose(batched, simulate_each(models, [mo] * 5), rtol=0, atol=ATOL)
    jaxpr = jax.make_jaxpr(lambda ms: eqx.filter_vmap(lambda m: fj.simulate(m, mo))(ms))(stack(models))
    assert all(T not in shape for shape in transposed_shapes(jaxpr.jaxpr)), transposed_shapes(jaxpr.jaxpr)


def test_lugre_batch_equals_each_model_and_writes_rows_directly():
    """LuGre (a scalar state; batch-minor too): a batch over the Stribeck curve and the damping, in pre-sliding
    and sliding, equals each model's run, without a transposition of the output."""

    def lugre(s):
        stribeck = fj.ExponentialStribeck(Fc=1.0 * s, Fs=1.5, vs=1e-3, delta=2.0)
        return fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0 * s, sigma2=0.4)

    scales = (0.6, 1.0, 1.3)
    mo = motion(scale=100.0)  # 2 mm: sliding between pre-sliding reversals
    batched = jax.vmap(lambda s: fj.simulate(lugre(s), mo))(jnp.array(scales))
    np.testing.assert_allclose(batched, simulate_each([lugre(s) for s in scales], [mo] * 3), rtol=0, atol=ATOL)
    jaxpr = jax.make_jaxpr(lambda ss: jax.vmap(lambda s: fj.simulate(lugre(s), mo))(ss))(jnp.array(scales))
    assert all(T not in shape for shape in transposed_shapes(jaxpr.jaxpr))


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the batch-minor rule is checked fast
def test_partly_batched_parameters_motions_and_dt():
    """Only the offset, or only the stiffnesses, batched (the other parameters shared); one model over a batch
    of motions with different sampling times; both batched at once."""
    model, mo = nlr(), motion()
    scales = jnp.array([0.5, 1.0, 2.0])

    def with_offset(s):
        return eqx.tree_at(lambda m: m.force_map.offset, model, 0.1 * s)

    # the offset alone batched (a scalar parameter), then k through the constructor (a reparametrised field)
    out = jax.vmap(lambda s: fj.simulate(with_offset(s), mo))(scales)
    np.testing.assert_allclose(out, simulate_each([with_offset(s) for s in scales], [mo] * 3), rtol=0, atol=ATOL)
    out = jax.vmap(lambda s: fj.simulate(nlr(k_scale=s), mo))(scales)
    np.testing.assert_allclose(out, simulate_each([nlr(k_scale=s) for s in scales], [mo] * 3), rtol=0, atol=ATOL)

    motions = [motion(s, dt) for s, dt in ((0.5, 1e-3), (1.0, 2e-3), (3.0, 5e-4))]
    out = eqx.filter_vmap(lambda m_: fj.simulate(model, m_))(stack(motions))
    np.testing.assert_allclose(out, simulate_each([model] * 3, motions), rtol=0, atol=ATOL)

    models = [nlr(s) for s in (0.5, 1.0, 2.0)]
    out = eqx.filter_vmap(lambda m, m_: fj.simulate(m, m_))(stack(models), stack(motions))
    np.testing.assert_allclose(out, simulate_each(models, motions), rtol=0, atol=ATOL)


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the batch-minor rule is checked fast
def test_nested_vmap_and_fir_force_maps_with_history():
    """A 2 x 3 grid (models x motions) by nested vmaps; DNLRX (FIR bands on the deflections and the
    displacement: a history in the state), which keeps vmap's own batching, batched over its coefficients."""
    models = [nlr(1.0), nlr(1.7, 0.8)]
    motions = [motion(s) for s in (0.5, 1.0, 2.5)]
    grid = eqx.filter_vmap(lambda m: eqx.filter_vmap(lambda m_: fj.simulate(m, m_))(stack(motions)))(stack(models))
    assert grid.shape == (2, 3, T)
    for i, m in enumerate(models):
        np.testing.assert_allclose(grid[i], simulate_each([m] * 3, motions), rtol=0, atol=ATOL)

    def dnlrx(s):
        theta = jnp.array([[0.4, 0.3, 0.2], [0.1, -0.05, 0.02], [0.03, 0.0, -0.01]]) * s
        return fj.MaxwellSlip.dnlrx([1e-6, 3e-6, 7e-6], theta, c=jnp.array([100.0, -40.0]) * s, offset=0.05)

    assert nlr().batch_minor() and not dnlrx(1.0).batch_minor()
    scales = jnp.array([0.5, 1.0, 1.5, 3.0])
    mo = motion()
    out = jax.vmap(lambda s: fj.simulate(dnlrx(s), mo))(scales)
    np.testing.assert_allclose(out, simulate_each([dnlrx(s) for s in scales], [mo] * 4), rtol=0, atol=ATOL)


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 319 s)
def test_derivatives_are_the_plain_scans():
    """Forward derivatives of a batch (first: a jitted program batched before it is differentiated, the case
    where the derivative rule's batch axes must match the vmap rule's), gradients of a loss summed over a batch
    and per-model gradients under vmap equal those of the one-model runs (the custom JVP: the batch-minor loop
    is never differentiated)."""
    mo, target = motion(), jnp.asarray(np.random.default_rng(0).normal(0.0, 0.1, T))
    scales = jnp.array([0.6, 1.0, 1.8])

    def forces(s):
        return fj.simulate(nlr(k_scale=s, threshold_scale=1.0 / s), mo)

    _, tangent = jax.jvp(jax.vmap(forces), (scales,), (jnp.ones(3),))
    expected = np.stack([np.asarray(jax.jvp(forces, (s,), (1.0,))[1]) for s in scales])
    assert tangent.shape == (3, T)
    np.testing.assert_allclose(tangent, expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())

    def loss(s):
        return jnp.mean((forces(s) - target) ** 2)

    each = np.array([jax.grad(loss)(s) for s in scales])
    np.testing.assert_allclose(jax.grad(lambda ss: jnp.sum(jax.vmap(loss)(ss)))(scales), each, rtol=1e-10)
    np.testing.assert_allclose(jax.vmap(jax.grad(loss))(scales), each, rtol=1e-10)


@pytest.mark.slow  # a few seconds (a subprocess or a fit): the fast tier stays under 5 minutes
def test_outputs_independent_of_the_batched_argument():
    """A batch over `dt` alone, which Maxwell-slip's forces do not read: the forces are one row repeated, and
    gradients and forward derivatives through the batch are those of the rows (the vmap rule batches every
    output; the derivative rule must batch them alike, or JAX combines the two wrongly: once a third of the
    gradient)."""
    x = 2e-5 * np.sin(np.linspace(0.0, 20.0, T))
    dts = jnp.array([1e-3, 2e-3, 5e-4])

    def batch(s):
        return jax.vmap(lambda dt: fj.simulate(nlr(k_scale=s), fj.Motion(x=x, dt=dt)))(dts)

    def row(s):
        return fj.simulate(nlr(k_scale=s), fj.Motion(x=x, dt=1e-3))

    np.testing.assert_allclose(batch(1.0), np.stack([row(1.0)] * 3), rtol=0, atol=ATOL)
    expected = 3 * jax.grad(lambda s: jnp.sum(row(s) ** 2))(1.0)
    np.testing.assert_allclose(jax.grad(lambda s: jnp.sum(batch(s) ** 2))(1.0), expected, rtol=1e-10)
    tangent = jax.jvp(batch, (1.0,), (1.0,))[1]
    assert tangent.shape == (3, T)
    np.testing.assert_allclose(tangent, np.stack([jax.jvp(row, (1.0,), (1.0,))[1]] * 3), rtol=1e-10, atol=1e-12)
    assert jax.jacfwd(batch)(1.0).shape == (3, T)

    # nested: an outer vmap over `dt` alone around an inner one over the stiffnesses (the outer batches the inner
    # rule's own operations), and the other nesting
    ks = jnp.array([0.7, 1.4])

    def grid(s, outer_dt=True):
        def one(dt, k):
            return fj.simulate(nlr(k_scale=s * k), fj.Motion(x=x, dt=dt))

        if outer_dt:
            return jax.vmap(lambda dt: jax.vmap(lambda k: one(dt, k))(ks))(dts)
        return jax.vmap(lambda k: jax.vmap(lambda dt: one(dt, k))(dts))(ks)

    rows = [lambda s, k=k: fj.simulate(nlr(k_scale=s * k), fj.Motion(x=x, dt=1e-3)) for k in ks]
    expected = 3 * sum(jax.grad(lambda s, r=r: jnp.sum(r(s) ** 2))(1.0) for r in rows)
    for outer_dt, shape in ((True, (3, 2, T)), (False, (2, 3, T))):
        nested = functools.partial(grid, outer_dt=outer_dt)
        gradient = jax.grad(lambda s, f=nested: jnp.sum(f(s) ** 2))(1.0)
        np.testing.assert_allclose(gradient, expected, rtol=1e-10, err_msg=f"outer vmap over dt: {outer_dt}")
        assert jax.jvp(nested, (1.0,), (1.0,))[1].shape == shape


class TwoOutputSpringSliders(fj.AbstractFrictionModel):
    """A batch-minor test model with a tuple state, an integer field and a vector output: two spring-sliders
    (stiffness `k` [N/m], slip force `fs` [N]) driven by `sign * dx`, and their forces scaled by `dt` (a record
    constant) plus a count of the steps taken (the second state leaf)."""

    k: jax.Array
    fs: jax.Array
    sign: jax.Array  # integer: an array field that is not a differentiable parameter

    requires: ClassVar[frozenset[str]] = frozenset({"x", "dt"})

    def batch_minor(self):
        return True

    def init_state(self):
        return jnp.zeros(2), jnp.zeros(())

    def step(self, state, sample):
        force, steps = state
        force = jnp.clip(force + self.k * self.sign * sample.dx, -self.fs, self.fs)
        return (force, steps + 1.0), jnp.stack([force[0], force[1] * sample.dt * 1e3 + 1e-3 * steps])


def sliders(s, sign=1):
    return TwoOutputSpringSliders(jnp.array([1e4, 3e4]) * s, jnp.array([0.2, 0.5]) * s, jnp.asarray(sign))


def test_the_rule_for_any_model_tuple_state_integer_field_vector_output():
    """The batching rule is generic: a tuple state, a batched integer field and a vector output per step come
    back as `(B, T, 2)`; a batch over one state leaf alone, and its gradient."""
    models = [sliders(s, sign) for s, sign in ((0.5, 1), (1.0, -1), (2.0, 1))]
    motions = [motion(s, dt) for s, dt in ((1.0, 1e-3), (2.0, 2e-3), (0.7, 1e-3))]
    out = eqx.filter_vmap(lambda m, m_: fj.simulate(m, m_))(stack(models), stack(motions))
    assert out.shape == (3, T, 2)
    np.testing.assert_allclose(out, simulate_each(models, motions), rtol=0, atol=1e-15)

    mo, counts = motion(), jnp.array([0.0, 10.0, 20.0])

    def loss(s, count):
        return jnp.sum(fj.simulate(sliders(s), mo, state0=(jnp.zeros(2), count)) ** 2)

    out = jax.vmap(lambda c: fj.simulate(sliders(1.0), mo, state0=(jnp.zeros(2), c)))(counts)
    expected = [fj.simulate(sliders(1.0), mo, state0=(jnp.zeros(2), c)) for c in counts]
    np.testing.assert_allclose(out, np.stack(expected), rtol=0, atol=1e-15)
    grad = jax.grad(lambda s: jnp.sum(jax.vmap(lambda c: loss(s, c))(counts)))(1.0)
    np.testing.assert_allclose(grad, sum(jax.grad(loss)(1.0, c) for c in counts), rtol=1e-10)


def test_batching_is_an_option_of_simulate():
    """`batching="vmap"` switches the layout off on the driver (the same forces, a transposed output);
    `"batch_minor"` for a model that does not declare it, or an unknown value, is one clear error."""
    models = [nlr(1.0 + 0.2 * i, 1.0 - 0.1 * i, 0.1 * i) for i in range(3)]
    mo = motion()
    minor = eqx.filter_vmap(lambda m: fj.simulate(m, mo, batching="batch_minor"))(stack(models))
    own = eqx.filter_vmap(lambda m: fj.simulate(m, mo, batching="vmap"))(stack(models))
    np.testing.assert_allclose(own, minor, rtol=0, atol=ATOL)
    jaxpr = jax.make_jaxpr(lambda ms: eqx.filter_vmap(lambda m: fj.simulate(m, mo, batching="vmap"))(ms))
    assert any(T in shape for shape in transposed_shapes(jaxpr(stack(models)).jaxpr))  # vmap's own: (T, B) moved
    gms = fj.GMS(fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3), k=[1e4, 5e3], alpha=[0.5, 0.5], C=20.0)
    with pytest.raises(ValueError, match="batching=.batch_minor.*GMS does not"):
        fj.simulate(gms, mo, batching="batch_minor")
    with pytest.raises(ValueError, match="`batching` must be one of"):
        fj.simulate(models[0], mo, batching="minor")
    with pytest.raises(ValueError, match="`batching` must be one of"):
        fj.SimulationLoss(batching="rows")
