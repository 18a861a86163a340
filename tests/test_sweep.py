"""`fj.sweep` and `fj.stack_models`: a vmap-ed sweep over orders, widths, seeds and learning rates equals
training each configuration alone; a masked configuration trains exactly like the smaller model it stands for."""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
import optax
import pytest

import fricjax as fj

from helpers import neural_record

STEPS = 12
SAMPLES = 120  # short records: the sweep's logic, not its training, is under test


def alone(model, data, loss, rate, steps=STEPS):
    """A plain optax loop over one model (the reference the sweep must reproduce)."""
    params, static = eqx.partition(model, fj.trainable_filter(model))
    optimiser = optax.adam(rate)
    state = optimiser.init(params)

    @jax.jit
    def update(p, s):
        grads = jax.grad(lambda q: loss(eqx.combine(q, static), None, data))(p)
        updates, s = optimiser.update(grads, s, p)
        return optax.apply_updates(p, updates), s

    for _ in range(steps):
        params, state = update(params, state)
    return eqx.combine(params, static)


def regressors(data, input_mask=None, output_mask=None):
    base = fj.NARXRegressors.from_data(data, ("x", "v"), 1, 3)
    return fj.NARXRegressors(
        ("x", "v"),
        1,
        3,
        input_mean=base.input_mean,
        input_scale=base.input_scale,
        output_mean=base.output_mean,
        output_scale=base.output_scale,
        input_mask=input_mask,
        output_mask=output_mask,
    )


@pytest.mark.slow  # ~5 s; the fast tier stays well under 5 minutes
def test_sweep_equals_each_configuration_alone():
    data = neural_record(SAMPLES)
    loss = fj.OneStepLoss()
    configs = [
        (regressors(data), 0, 1e-2),
        (regressors(data, output_mask=[1.0, 0.0, 0.0]), 1, 3e-2),
        (regressors(data, input_mask=[1.0, 0.0]), 2, 1e-3),
    ]
    models = [fj.MLPNARX.init(reg, 4, key=jax.random.PRNGKey(seed)) for reg, seed, _ in configs]
    result = fj.sweep(models, data, loss=loss, learning_rate=[rate for *_, rate in configs], steps=STEPS, checks=4)
    assert result.train_loss.shape == (3,) and "diverged" not in result.codes
    assert result.history["train_loss"].shape == (4, 3)
    for i, (model, (*_, rate)) in enumerate(zip(models, configs, strict=True)):
        reference = alone(model, data, loss, rate)
        np.testing.assert_allclose(result[i].model.W, reference.W, rtol=1e-9, atol=1e-12)
        assert result.train_loss[i] == pytest.approx(float(loss(reference, None, data)), rel=1e-9)
        assert result.train_loss[i] < float(loss(model, None, data))


@pytest.mark.slow  # about 4 s
def test_masked_configuration_trains_like_the_smaller_model():
    """Masked lags and units get zero gradients, so the sweep's masked model is the smaller model, trained."""
    data = neural_record(SAMPLES)
    loss = fj.SimulationLoss()
    full = fj.MLPNARX.init(regressors(data), 6, key=jax.random.PRNGKey(4))
    masked = fj.MLPNARX(
        regressors(data, input_mask=[1.0, 0.0], output_mask=[1.0, 1.0, 0.0]),
        full.W,
        full.b,
        full.d,
        full.d0,
        unit_mask=[1, 1, 1, 0, 0, 0],
    )
    keep = [0, 1, 4, 5]  # lag 0 of (x, v), output lags 1 and 2
    small = fj.MLPNARX(
        fj.NARXRegressors(
            ("x", "v"),
            0,
            2,
            input_mean=full.regressors.input_mean,
            input_scale=full.regressors.input_scale,
            output_mean=full.regressors.output_mean,
            output_scale=full.regressors.output_scale,
        ),
        np.asarray(full.W)[:3][:, keep],
        full.b[:3],
        full.d[:3],
        full.d0,
    )
    result = fj.sweep([full, masked], data, loss=loss, learning_rate=1e-2, steps=STEPS)
    trained_small = alone(small, data, loss, 1e-2)
    np.testing.assert_allclose(
        fj.simulate(result[1].model, data.motion), fj.simulate(trained_small, data.motion), rtol=1e-8, atol=1e-10
    )
    np.testing.assert_allclose(np.asarray(result[1].model.W)[:3][:, keep], trained_small.W, rtol=1e-8, atol=1e-10)
    np.testing.assert_array_equal(np.asarray(result[1].model.W)[3:], np.asarray(full.W)[3:])  # masked units untouched


@pytest.mark.slow  # about 3 s
def test_sweep_keeps_finite_parameters_when_a_configuration_diverges():
    data = neural_record(SAMPLES)
    models = [fj.GSNN.init(regressors(data), 2, key=jax.random.PRNGKey(s)) for s in (0, 1)]
    result = fj.sweep(models, data, learning_rate=[1e-2, 1e6], steps=4, validation=data, validation_burn_in=10)
    for i in range(2):
        leaves = jax.tree_util.tree_leaves(eqx.filter(result[i].model, eqx.is_inexact_array))
        assert all(np.all(np.isfinite(np.asarray(leaf))) for leaf in leaves)
    assert np.isfinite(result.train_loss[0]) and np.isfinite(result.val_loss[0])
    assert result.best_configuration == 0 and result.codes == ("max_steps", "diverged"), result.codes


@pytest.mark.slow  # fast tier trimmed (2026-11-27): an error message
def test_stack_models_names_the_difference():
    data = neural_record(SAMPLES)
    a = fj.MLPNARX.init(regressors(data), 4, key=jax.random.PRNGKey(0))
    b = fj.MLPNARX.init(regressors(data), 5, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="maximal shape"):
        fj.stack_models([a, b])
    c = fj.MLPNARX.init(fj.NARXRegressors.from_data(data, ("x", "v"), 0, 3), 4, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="structure"):
        fj.stack_models([a, c])
    with pytest.raises(ValueError, match="learning_rate"):
        fj.sweep([a, a], data, learning_rate=[1e-2, -1.0], steps=2)


@pytest.mark.slow  # fast tier trimmed (2026-11-27): a compile-count property
def test_a_second_sweep_of_the_same_shapes_does_not_recompile():
    """Issue 12: the sweep's jitted pieces take the loss, the data and the optimiser as arguments, so a second
    sweep with new weights, learning rates and data of the same shapes compiles nothing."""
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: compiles.append(event) if "backend_compile" in event else None
    )
    counts = []
    for seed in range(2):
        record = neural_record(SAMPLES)
        data = fj.FrictionData(record.motion, np.asarray(record.force) * (1.0 + 0.1 * seed))  # new values
        models = [fj.MLPNARX.init(regressors(data), 4, key=jax.random.PRNGKey(seed + k)) for k in range(2)]
        before = len(compiles)
        fj.sweep(models, data, loss=fj.OneStepLoss(), learning_rate=[1e-2 * (seed + 1), 3e-3], steps=4, checks=2)
        counts.append(len(compiles) - before)
    assert counts[0] > 0 and counts[1] == 0, counts
