"""Batches across devices: the leading axis of a sweep's configurations or a fit's starts, sharded.

`fj.sweep` and the multi-start of `fj.fit` train a batch of independent problems in one vmap-ed, jit-compiled
program. With several local devices (GPUs, TPU cores, or CPU "devices": `XLA_FLAGS=
--xla_force_host_platform_device_count=N`), `shard_batch` places the batch's arrays along a one-axis mesh
(`jax.sharding.NamedSharding` with `PartitionSpec("batch")`), so XLA's partitioner runs each device's share of
the batch there; the rest (the data, the static parts of the models) is replicated. The programs do not
change: the same jitted functions, the same results (the problems never interact), one compilation per
sharding. For machines beyond one host see `benchmarks/multihost_sweep.py` (`jax.distributed.initialize`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

# With the default devices, a batch is spread only where each device gets at least this many rows
# (`FRICJAX_SHARD_MIN_ROWS` to change): below that the partitioned program's overhead outweighs the second core (the
# default `fricjax compare` on 2 host devices with every batch sharded, its 4-start fits included: 44.6 s, against
# 40.6 s on one device and 38.1 s with this threshold; benchmarks/README.md)
MIN_ROWS_PER_DEVICE = 16


def min_rows_per_device() -> int:
    """`MIN_ROWS_PER_DEVICE`, or `FRICJAX_SHARD_MIN_ROWS` when set."""
    chosen = os.environ.get("FRICJAX_SHARD_MIN_ROWS", "").strip()
    if not chosen:
        return MIN_ROWS_PER_DEVICE
    try:
        return int(chosen)
    except ValueError:
        raise ValueError(f"FRICJAX_SHARD_MIN_ROWS={chosen!r}: expected a whole number of rows per device") from None


def batch_devices(batch: int, devices: Sequence[Any] | None = None) -> list[Any]:
    """The devices a batch of `batch` problems is spread over: of `devices` the largest count that divides the
    batch (1 device: no sharding); with the default `devices` (every local device) on a CPU only counts that leave
    each host device at least `min_rows_per_device()` rows."""
    pool = list(jax.local_devices() if devices is None else devices)
    if not pool:
        raise ValueError("shard_batch: `devices` is empty; pass None (every local device) or a list of devices.")
    count = math.gcd(int(batch), len(pool)) if batch > 0 else 1
    if devices is None and pool[0].platform == "cpu":  # measured on host devices; accelerators take any batch
        while count > 1 and batch < count * min_rows_per_device():
            count = max(d for d in range(1, count) if count % d == 0)  # the next divisor down
    return pool[:count]


def shard_batch(tree: Any, devices: Sequence[Any] | None = None) -> Any:
    """Place every array leaf of `tree` with a leading batch axis of one common size `B` along the devices
    (`batch_devices(B, devices)`: by default every local device, as many as divide `B`); other leaves (scalars,
    non-arrays) are left as they are. With one device this is the identity.

    ```python
    >>> import jax.numpy as jnp, fricjax as fj
    >>> batch = {"k": jnp.ones((8, 3)), "c": jnp.ones(8)}
    >>> sharded = fj.shard_batch(batch)        # on a 4-device machine, 2 rows of each leaf per device
    >>> sharded["k"].shape
    (8, 3)
    ```
    """
    leaves = [leaf for leaf in jax.tree_util.tree_leaves(tree) if eqx.is_array(leaf) and np.ndim(leaf) >= 1]
    if not leaves:
        return tree
    sizes = {int(np.shape(leaf)[0]) for leaf in leaves}
    if len(sizes) != 1:
        raise ValueError(
            f"shard_batch: the array leaves must share one leading batch axis, got sizes {sorted(sizes)}; stack the "
            "problems first (fj.stack_models)."
        )
    pool = batch_devices(sizes.pop(), devices)
    if len(pool) == 1 and devices is None:
        return tree
    sharding = NamedSharding(Mesh(np.asarray(pool), ("batch",)), PartitionSpec("batch"))

    def place(leaf: Any) -> Any:
        if eqx.is_array(leaf) and np.ndim(leaf) >= 1:
            return jax.device_put(leaf, sharding)
        return leaf

    return jax.tree_util.tree_map(place, tree)
