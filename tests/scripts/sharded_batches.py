"""Run a sweep and multi-start fits and save their results: run by tests/test_sharding.py once on one device and
once with four forced host devices (XLA_FLAGS=--xla_force_host_platform_device_count=4); the results must agree.

Usage: python sharded_batches.py OUT.npz
"""

from __future__ import annotations

import sys

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

import fricjax as fj  # noqa: E402


def leaves(tree):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(eqx.filter(tree, eqx.is_inexact_array))]


def main(out: str) -> None:
    devices = len(jax.devices())
    data = fj.make_tribometer("sliding", seed=0, duration=0.4).train
    results = {}

    # a sweep of 4 configurations (output-lag masks x seeds): one per device on four devices
    regressors = lambda mask: fj.NARXRegressors(("v",), 0, 2, output_mask=mask)  # noqa: E731
    masks = ([1, 0], [1, 1], [1, 1], [0, 1])
    models = [fj.MLPNARX.init(regressors(m), 4, key=jax.random.PRNGKey(i)) for i, m in enumerate(masks)]
    sweep = fj.sweep(models, data, loss=fj.OneStepLoss(), learning_rate=[1e-2, 1e-2, 3e-3, 1e-2], steps=25)
    sharded = jax.tree_util.tree_leaves(eqx.filter(sweep.model, eqx.is_inexact_array))[0]
    results["sweep_devices"] = np.asarray(len(sharded.sharding.device_set))
    results["sweep_train_loss"] = sweep.train_loss
    for i, leaf in enumerate(leaves(sweep.model)):
        results[f"sweep_leaf_{i}"] = leaf
    # 6 configurations: spread over the 2 devices that divide the batch
    six = fj.sweep(models + models[:2], data, loss=fj.OneStepLoss(), steps=10)
    results["six_devices"] = np.asarray(fj.batch_devices(6).__len__())
    results["six_train_loss"] = six.train_loss

    # multi-start fits (optax and Levenberg-Marquardt): the starts are the batch
    start = fj.LuGre(
        fj.ExponentialStribeck(Fc=1.0, Fs=1.4, vs=2e-3), sigma0=1e5, sigma1=0.0, sigma2=0.0, smoothing=fj.Smooth(1e-5)
    )
    adam = fj.fit(
        start,
        data,
        solver=optax.adam(1e-2),
        steps=30,
        multistart=fj.MultiStart(4, spread=0.3),
        scaling=fj.ParameterScaling(),
        seed=1,
        progress=False,
    )
    lm = fj.fit(
        start,
        data,
        steps=6,
        multistart=fj.MultiStart(4, spread=0.3),
        scaling=fj.ParameterScaling(),
        seed=1,
        progress=False,
    )
    for name, result in (("adam", adam), ("lm", lm)):
        results[f"{name}_best_start"] = np.asarray(result.best_start)
        results[f"{name}_train_loss"] = np.asarray(result.train_loss)
        for i, leaf in enumerate(leaves(result.model)):
            results[f"{name}_leaf_{i}"] = leaf
    # a batch of Maxwell-slip models (the batch-minor free run under vmap), sharded over the devices
    scales = np.linspace(0.5, 2.0, 4)
    maxwell = eqx.filter_vmap(
        lambda s: fj.MaxwellSlip.nlr(k=s * np.array([3e5, 1e5, 2e4]), thresholds=np.array([1e-6, 3e-6, 9e-6]) / s)
    )(scales)
    placed = fj.shard_batch(maxwell)
    forces = eqx.filter_vmap(lambda m: fj.simulate(m, data.motion))(placed)
    results["maxwell_devices"] = np.asarray(len(forces.sharding.device_set))
    results["maxwell_forces"] = np.asarray(forces)
    results["devices"] = np.asarray(devices)
    np.savez(out, **results)


if __name__ == "__main__":
    main(sys.argv[1])
