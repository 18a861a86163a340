"""Batches across devices (`fj.shard_batch`): a sweep's configurations and a fit's starts, sharded over every local
device, give the results of one device. The multi-device runs use four forced host (CPU) devices in a
subprocess (`XLA_FLAGS=--xla_force_host_platform_device_count=4` must be set before JAX starts)."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

SCRIPT = pathlib.Path(__file__).parent / "scripts" / "sharded_batches.py"


def test_one_device_is_the_identity_and_errors_name_the_fix():
    batch = {"k": jnp.arange(6.0).reshape(3, 2), "c": jnp.ones(3), "name": "x"}
    assert fj.shard_batch(batch) is batch if len(jax.local_devices()) == 1 else True
    assert len(fj.batch_devices(6, jax.local_devices()[:1])) == 1
    with pytest.raises(ValueError, match="leading batch axis"):
        fj.shard_batch({"a": jnp.ones(3), "b": jnp.ones(4)})
    with pytest.raises(ValueError, match="`devices` is empty"):
        fj.batch_devices(4, [])


def _run(tmp_path: pathlib.Path, devices: int) -> dict[str, np.ndarray]:
    out = tmp_path / f"devices{devices}.npz"
    env = dict(os.environ, JAX_PLATFORMS="cpu", FRICJAX_SHARD_MIN_ROWS="1")  # the small test batches sharded too
    flags = [f for f in env.get("XLA_FLAGS", "").split() if "device_count" not in f]
    env["XLA_FLAGS"] = " ".join([*flags, f"--xla_force_host_platform_device_count={devices}"])
    completed = subprocess.run(
        [sys.executable, str(SCRIPT), str(out)], env=env, capture_output=True, text=True, timeout=600
    )
    assert completed.returncode == 0, completed.stderr[-3000:]
    with np.load(out) as loaded:
        return {key: loaded[key] for key in loaded.files}


@pytest.mark.slow
def test_sharded_sweep_and_multistart_equal_one_device(tmp_path):
    """Issue 12: a 4-configuration sweep (one configuration per device), a 6-configuration sweep (spread over
    the 2 devices that divide it), 4-start fits with Adam and Levenberg-Marquardt and the free runs of 4
    Maxwell-slip models (the batch-minor loop), on 4 forced host devices, equal the same runs on one device (to
    round-off: the partitioned program may order sums differently)."""
    single, sharded = _run(tmp_path, 1), _run(tmp_path, 4)
    assert int(single["devices"]) == 1 and int(sharded["devices"]) == 4
    assert int(sharded["sweep_devices"]) == 4 and int(sharded["six_devices"]) == 2  # really sharded
    assert int(sharded["maxwell_devices"]) == 4
    assert set(single) == set(sharded)
    for key in single:
        if key.endswith("devices"):
            continue
        scale = max(float(np.max(np.abs(single[key]), initial=0.0)), 1e-300)
        np.testing.assert_allclose(sharded[key], single[key], rtol=1e-10, atol=1e-12 * scale, err_msg=key)


@pytest.mark.slow
def test_multihost_example_runs_on_two_local_processes():
    """The documented multi-host example (`benchmarks/multihost_sweep.py --local 2`): two processes joined by
    `jax.distributed.initialize`, each training half of the grid on its two local devices, gather one table."""
    script = pathlib.Path(__file__).parents[1] / "benchmarks" / "multihost_sweep.py"
    completed = subprocess.run(
        [sys.executable, str(script), "--local", "2", "--configurations", "4", "--steps", "5"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert completed.returncode == 0, completed.stderr[-3000:]
    lines = [json.loads(line) for line in completed.stdout.splitlines() if line.startswith("{")]
    assert sorted(line["process"] for line in lines) == [0, 1]
    assert all(line["processes"] == 2 and line["global_devices"] == 4 for line in lines)
    assert sorted(c for line in lines for c in line["configurations"]) == [0, 1, 2, 3]
    assert lines[0]["val_loss"] == lines[1]["val_loss"] and np.all(np.isfinite(lines[0]["val_loss"]))
