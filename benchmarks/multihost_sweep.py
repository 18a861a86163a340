"""A sweep across several machines (hosts) with `jax.distributed`: the runnable multi-host example.

`fj.sweep` shards its batch of configurations over the devices of one process (`fj.shard_batch`). For more
configurations than one machine holds, start this script once per host: every process calls
`jax.distributed.initialize`, takes its share of the configuration grid (by `jax.process_index()`), trains it with
`fj.sweep` (sharded over its own local devices), and the processes gather the validation losses with
`jax.experimental.multihost_utils.process_allgather`, so that every host knows the best configuration. The
configurations never interact, so no parameter crosses the network during training.

On a cluster (one line per host; SLURM and Cloud TPU fill these in for `jax.distributed.initialize()` by
themselves):

```bash
python benchmarks/multihost_sweep.py --coordinator host0:12345 --num-processes 2 --process-id 0   # on host 0
python benchmarks/multihost_sweep.py --coordinator host0:12345 --num-processes 2 --process-id 1   # on host 1
```

On one machine, as a check (two CPU processes, two forced host devices each):

```bash
python benchmarks/multihost_sweep.py --local 2
```

It prints one JSON line per process: its configurations, its devices, the gathered validation losses of the
whole grid, the best configuration and the wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time


def run_process(coordinator: str, num_processes: int, process_id: int, configurations: int, steps: int) -> None:
    import jax

    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes, process_id=process_id)
    jax.config.update("jax_enable_x64", True)
    import equinox as eqx
    import numpy as np
    from jax.experimental import multihost_utils

    import fricjax as fj

    start = time.perf_counter()
    record = fj.make_tribometer("sliding", seed=0, duration=0.6)
    train, validation = record.train, record.validation
    # the grid: MLP NARX networks over output orders (masks of one maximal shape) and seeds
    orders = [1, 2, 3, 4]
    grid = [(order, seed) for seed in range(configurations // len(orders) + 1) for order in orders][:configurations]
    mine = [i for i in range(len(grid)) if i % jax.process_count() == jax.process_index()]

    base = fj.NARXRegressors.from_data(train, ("v",), 0, max(orders))

    def model(order: int, seed: int) -> fj.MLPNARX:
        mask = np.asarray([1.0] * order + [0.0] * (max(orders) - order))
        regressors = eqx.tree_at(lambda r: r.output_mask, base, fj.Fixed(mask))
        return fj.MLPNARX.init(regressors, 6, key=jax.random.PRNGKey(seed))

    result = fj.sweep(
        [model(*grid[i]) for i in mine],
        train,
        loss=fj.OneStepLoss(),
        learning_rate=3e-3,
        steps=steps,
        validation=validation,
    )
    losses = np.full(len(grid), np.nan)
    losses[mine] = result.val_loss
    # every process contributes its row (NaN where another process trained the configuration)
    gathered = np.asarray(multihost_utils.process_allgather(losses))
    everything = np.nanmin(gathered.reshape(-1, len(grid)), axis=0)
    best = int(np.argmin(everything))
    print(
        json.dumps(
            {
                "kind": "multihost_sweep",
                "process": jax.process_index(),
                "processes": jax.process_count(),
                "local_devices": len(jax.local_devices()),
                "global_devices": len(jax.devices()),
                "configurations": mine,
                "val_loss": [float(v) for v in everything],
                "best": {"order": grid[best][0], "seed": grid[best][1], "val_loss": float(everything[best])},
                "wall_s": round(time.perf_counter() - start, 2),
            }
        ),
        flush=True,
    )
    jax.distributed.shutdown()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--coordinator", default=None, help="host:port of process 0 (--local: a free local port)")
    parser.add_argument("--num-processes", type=int, default=1)
    parser.add_argument("--process-id", type=int, default=0)
    parser.add_argument("--local", type=int, default=0, help="start this many processes on this machine and wait")
    parser.add_argument("--configurations", type=int, default=8)
    parser.add_argument("--steps", type=int, default=100)
    args = parser.parse_args()
    if args.local:
        if args.coordinator is None:
            with socket.socket() as probe:  # a port nobody listens on
                probe.bind(("localhost", 0))
                args.coordinator = f"localhost:{probe.getsockname()[1]}"
        env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS="--xla_force_host_platform_device_count=2")
        base = [sys.executable, __file__, "--coordinator", args.coordinator, "--num-processes", str(args.local)]
        extra = ["--configurations", str(args.configurations), "--steps", str(args.steps)]
        children = [
            subprocess.Popen([*base, "--process-id", str(i), *extra], env=env, stdout=subprocess.PIPE, text=True)
            for i in range(args.local)
        ]
        # each child writes into its own pipe; relay them whole, one after another (a shared pipe interleaves)
        for child in children:
            output, _ = child.communicate()
            sys.stdout.write(output)
        sys.stdout.flush()
        return max(child.returncode for child in children)
    if args.coordinator is None:
        parser.error("--coordinator HOST:PORT is needed (the address of process 0), or --local N")
    run_process(args.coordinator, args.num_processes, args.process_id, args.configurations, args.steps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
