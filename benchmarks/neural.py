"""NOE training of the neural NARX models, and full vs truncated output-error gradients.

worden2007 §6.2 trained the GSNN by "NOE" with a Jacobian truncated to a window of past errors (eq. 33),
because the full gradient through the feedback was impractical. Here the full gradient is one reverse pass
through `fj.simulate`. This script prints JSON lines:

- `{"kind": "noe_fit", "model": "gsnn5", ...}`: the papers' GSNN NARX (5 neurons; dx, v, a with lags 0-2; 4 past
  outputs) trained on `--samples` samples of the mixed tribometer regime: teacher forcing (`fj.OneStepLoss`,
  Adam) then NOE (`fj.SimulationLoss`, Adam), each through `fj.fit`; fit times (compilation included), the
  free-run NMSE [%] on the training record and on the held-out rest of the record.
- `{"kind": "noe_fit", "model": "gsnn5_plays", ...}`: the `gsnn` of `fricjax compare` (5 neurons and a linear
  part on the velocity and 20 play operators) with its recipe (output layer by least squares, then 600 NOE
  steps), same records and fields.
- `{"kind": "gradient", "window": W, ...}`: from the same teacher-forced start, `--noe-steps` Adam steps with
  the full NOE gradient (`window: null`) and with gradients truncated to windows of W samples (the state
  entering each window is a constant for differentiation; the forward pass is the same free run): time per
  gradient, cosine between the truncated and the full gradient at the start, the training loss reached and the
  held-out free-run NMSE.

Run: `python benchmarks/neural.py [--samples 10000] [--noe-steps 1500] [--windows 20 200]`.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402
from fricjax._constraints import unwrap  # noqa: E402
from fricjax._simulate import run as scan_run  # noqa: E402
from fricjax._simulate import split_time_signals  # noqa: E402


def records(samples: int) -> tuple[fj.FrictionData, fj.FrictionData]:
    """`samples` training samples of the mixed regime (2 kHz) and the whole record (25 % more) for testing."""
    full = fj.make_tribometer("mixed", seed=0, duration=1.25 * samples / 2000.0).full
    return full.slice(0, samples), full


def gsnn(train: fj.FrictionData) -> Any:
    regressors = fj.NARXRegressors.from_data(train, ("dx", "v", "a"), input_lags=2, output_lags=4)
    return fj.GSNN.init(regressors, 5, key=jax.random.PRNGKey(0))


def held_out_nmse(model: Any, full: fj.FrictionData, start: int) -> float:
    prediction = np.asarray(fj.simulate(model, full.motion))
    return float(fj.nmse(np.asarray(full.force)[start:], prediction[start:]))


def truncated_loss(window: int | None, data: fj.FrictionData) -> Any:
    """The simulation loss (mean squared error / variance) whose gradient sees `window` samples back at most
    (None: the full gradient). Same forward pass in both cases."""
    force = jnp.asarray(data.force)
    variance = jnp.var(force)

    def loss(params: Any, static: Any) -> Any:
        model = unwrap(eqx.combine(params, static))
        samples = model.samples(data.motion)
        state = model.init_state()
        if window is None:
            _, prediction = scan_run(model, samples, state)
        else:
            steps, rebuild = split_time_signals(samples)
            chunks = data.length // window
            usable = chunks * window
            cut = [None if s is None else s[:usable].reshape((chunks, window) + s.shape[1:]) for s in steps]

            def chunk(carry: Any, signals: Any) -> Any:
                carry = jax.lax.stop_gradient(carry)  # the truncation: no gradient into earlier windows
                return scan_run(model, rebuild(signals), carry)

            _, prediction = jax.lax.scan(chunk, state, cut)
            prediction = prediction.reshape(-1)
            force_used = force[:usable]
            return jnp.mean((prediction - force_used) ** 2) / variance
        return jnp.mean((prediction - force) ** 2) / variance

    return loss


def train_noe(start: Any, data: fj.FrictionData, window: int | None, steps: int, rate: float) -> dict[str, Any]:
    params, static = eqx.partition(start, fj.trainable_filter(start))
    loss = truncated_loss(window, data)
    full_loss = truncated_loss(None, data)
    optimiser = optax.adam(rate)

    @jax.jit
    def update(p: Any, s: Any) -> Any:
        value, grads = jax.value_and_grad(loss)(p, static)
        updates, s = optimiser.update(grads, s, p)
        return optax.apply_updates(p, updates), s, value

    grad = jax.jit(jax.grad(loss))
    full_grad = jax.jit(jax.grad(full_loss))
    g, g_full = (jax.flatten_util.ravel_pytree(f(params, static))[0] for f in (grad, full_grad))
    cosine = float(jnp.dot(g, g_full) / (jnp.linalg.norm(g) * jnp.linalg.norm(g_full)))
    state = optimiser.init(params)
    jax.block_until_ready(update(params, state))  # compile
    tic = time.perf_counter()
    for _ in range(steps):
        params, state, _ = update(params, state)
    jax.block_until_ready(params)
    elapsed = time.perf_counter() - tic
    return {
        "ms_per_step": 1e3 * elapsed / steps,
        "cosine_to_full": cosine,
        "train_nmse_percent": 100 * float(jax.jit(full_loss)(params, static)),
        "model": eqx.combine(params, static),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--teacher-steps", type=int, default=750)
    parser.add_argument("--noe-steps", type=int, default=1500)
    parser.add_argument("--windows", type=int, nargs="*", default=[20, 200])
    args = parser.parse_args()
    env = environment(optax=optax.__version__, fricjax=fj.__version__)
    train, full = records(args.samples)
    start = gsnn(train)

    tic = time.perf_counter()
    teacher = fj.fit(start, train, loss=fj.OneStepLoss(), solver=optax.adam(1e-2), steps=args.teacher_steps)
    teacher_s = time.perf_counter() - tic
    tic = time.perf_counter()
    noe = fj.fit(teacher.model, train, solver=optax.adam(1e-3), steps=args.noe_steps)
    noe_s = time.perf_counter() - tic
    line = {
        "kind": "noe_fit",
        "model": "gsnn5",
        "samples": args.samples,
        "teacher_steps": args.teacher_steps,
        "noe_steps": args.noe_steps,
        "teacher_s": round(teacher_s, 2),
        "noe_s": round(noe_s, 2),
        "fit_s": round(teacher_s + noe_s, 2),
        "ms_per_noe_step": round(1e3 * noe_s / args.noe_steps, 3),
        "train_nmse_percent_teacher": round(held_out_nmse(teacher.model, train, 0), 4),
        "train_nmse_percent": round(held_out_nmse(noe.model, train, 0), 4),
        "held_out_nmse_percent": round(held_out_nmse(noe.model, full, args.samples), 4),
        "result": noe.code,
        **env,
    }
    print(json.dumps(line), flush=True)

    from fricjax import compare as C

    spec = C.default_models(C.FitSettings())["gsnn"]
    split = C.Split(full, int(0.8 * args.samples), args.samples)  # validation: the last 20 % of the training part
    tic = time.perf_counter()
    result = spec.fit(spec.build(C.DataScales.from_data(split.train)), split, 0, False)
    fit_s = time.perf_counter() - tic
    line = {
        "kind": "noe_fit",
        "model": "gsnn5_plays",
        "samples": args.samples,
        "noe_steps": C.FitSettings().neural_steps,
        "fit_s": round(fit_s, 2),
        "train_nmse_percent": round(held_out_nmse(fj.exact(result.model), train, 0), 4),
        "held_out_nmse_percent": round(held_out_nmse(fj.exact(result.model), full, args.samples), 4),
        "result": result.code,
        **env,
    }
    print(json.dumps(line), flush=True)

    for window in [None, *args.windows]:
        out = train_noe(teacher.model, train, window, args.noe_steps, 1e-3)
        line = {
            "kind": "gradient",
            "model": "gsnn5",
            "samples": args.samples,
            "window": window,
            "steps": args.noe_steps,
            "ms_per_step": round(out["ms_per_step"], 3),
            "cosine_to_full": round(out["cosine_to_full"], 4),
            "train_nmse_percent": round(out["train_nmse_percent"], 4),
            "held_out_nmse_percent": round(held_out_nmse(out["model"], full, args.samples), 4),
            **env,
        }
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
