"""`fj.TangentGradients`: `fj.simulate` differentiates the wrapped model's free run through the tangent-linear
recurrence (a custom JVP of the scan). The derivatives must be those of the scan itself: reverse mode, forward
mode, with respect to parameters and to the input record, under vmap, through SensorDrift."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

from helpers import model_table, presliding_to_sliding, smooth

MODELS = model_table()
TANGENT = ["lugre", "lugre_rational", "gms", "dahl", "bo_pavelescu_asym", "tustin", "maxwell_nlr", "maxwell_dnlrx"]


def _flat(tree: Any) -> np.ndarray:
    leaves = jax.tree_util.tree_leaves(eqx.filter(tree, eqx.is_inexact_array))
    return np.concatenate([np.ravel(np.asarray(leaf)) for leaf in leaves])


def _derivatives(model: Any, motion: fj.Motion, target: jax.Array) -> tuple[np.ndarray, ...]:
    params, static = eqx.partition(model, eqx.is_inexact_array)

    def loss(p: Any, x: jax.Array) -> jax.Array:
        moved = fj.Motion.from_position(x, dt=motion.dt)
        return jnp.mean((fj.simulate(eqx.combine(p, static), moved) - target) ** 2)

    x = jnp.asarray(motion.x)
    value, (grad_p, grad_x) = jax.value_and_grad(loss, argnums=(0, 1))(params, x)
    forward = jax.jacfwd(loss)(params, x)
    return np.asarray(value), _flat(grad_p), np.asarray(grad_x), _flat(forward)


# the fast tier checks one model in exact mode here (LuGre's tangent gradients: the driver-option test below); the
# rest (compilation-bound: ~7 s each) run in the slow tier
FAST = {("bo_pavelescu_asym", "exact")}
CASES = [
    pytest.param(name, mode, marks=() if (name, mode) in FAST else pytest.mark.slow)
    for name in TANGENT
    for mode in ("exact", "smooth")
]


@pytest.mark.parametrize(("name", "mode"), CASES)
def test_tangent_derivatives_equal_the_scans(name, mode):
    model = MODELS[name] if mode == "exact" else smooth(name, MODELS[name])
    assert fj.TangentGradients(model).tangent_gradients() and not model.tangent_gradients()
    motion = presliding_to_sliding(200)
    target = 1.05 * fj.simulate(model, motion) + 0.01
    ours = _derivatives(fj.TangentGradients(model), motion, target)
    reference = _derivatives(model, motion, target)
    for label, a, b in zip(("value", "grad params", "grad x", "jacfwd params"), ours, reference, strict=True):
        scale = max(float(np.max(np.abs(b))), 1e-300)
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * scale, err_msg=f"{name} {mode}: {label}")
        assert np.all(np.isfinite(a))


@pytest.mark.slow
def test_tangent_derivatives_through_a_wrapper_and_under_vmap():
    """SensorDrift(LuGre) takes the tangent path too; per-model gradients under vmap equal the loop's."""
    base = fj.SensorDrift(fj.TangentGradients(MODELS["lugre"]), 0.3, 2.0)
    assert base.tangent_gradients()
    motion = presliding_to_sliding(150)
    target = fj.simulate(base, motion) * 0.97
    params, static = eqx.partition(base, eqx.is_inexact_array)
    batched = jax.tree_util.tree_map(lambda p: jnp.stack([p, 1.01 * p, 0.98 * p]), params)

    def loss(p: Any) -> jax.Array:
        return jnp.mean((fj.simulate(eqx.combine(p, static), motion) - target) ** 2)

    grads = jax.vmap(jax.grad(loss))(batched)
    for i in range(3):
        single = jax.tree_util.tree_map(lambda p, i=i: p[i], batched)
        expected = _flat(jax.grad(lambda p: _scan_loss(p, static, motion, target))(single))
        got = _flat(jax.tree_util.tree_map(lambda g, i=i: g[i], grads))
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12 * np.max(np.abs(expected)))


def _scan_loss(p: Any, static: Any, motion: fj.Motion, target: jax.Array) -> jax.Array:
    model = eqx.combine(p, static)
    reference = eqx.tree_at(lambda m: m.model, model, model.model.model)  # unwrapped: the scan's own derivative
    assert not reference.tangent_gradients()
    return jnp.mean((fj.simulate(reference, motion) - target) ** 2)


def test_tangent_gradients_refuses_a_model_that_feeds_back():
    narx = fj.MLPNARX.init(fj.NARXRegressors(("v",), 1, 2), 3, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="feeds back"):
        fj.TangentGradients(narx)


@pytest.mark.slow  # moved from the fast tier, which must run cold in under 5 minutes on 2 cores (2026-11-27: 345 s)
def test_derivatives_are_an_option_of_the_driver():
    """`fj.simulate(..., derivatives="tangent")` and `fj.SimulationLoss(derivatives="tangent")` give the scan's
    derivatives (the choice on the driver, not on the model) and the wrapper's values, through a SensorDrift too
    (it overrides `feedback`; its free run still takes the tangent path); unknown values are refused."""
    model = MODELS["lugre"]
    motion = presliding_to_sliding(200)
    target = 1.05 * fj.simulate(model, motion) + 0.01
    data = fj.FrictionData(motion, target)
    tangent = _flat(jax.grad(lambda m: fj.SimulationLoss(derivatives="tangent")(m, None, data))(model))
    scan = _flat(jax.grad(lambda m: fj.SimulationLoss(derivatives="scan")(m, None, data))(model))
    np.testing.assert_allclose(tangent, scan, rtol=1e-10, atol=1e-10 * np.max(np.abs(scan)))
    drifting = fj.SensorDrift(model, 0.1, 1.0)
    wrapped_drift = fj.SensorDrift(fj.TangentGradients(model), 0.1, 1.0)
    a = fj.simulate(drifting, motion, derivatives="tangent")
    np.testing.assert_array_equal(a, fj.simulate(wrapped_drift, motion))  # the same path: equal to the bit
    with pytest.raises(ValueError, match="`derivatives` must be one of"):
        fj.SimulationLoss(derivatives="adjoint")
    with pytest.raises(ValueError, match="`derivatives` must be one of"):
        fj.simulate(model, motion, derivatives="reverse")
