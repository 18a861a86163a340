#!/usr/bin/env python
"""Success rate of physics fits over seeded random records: how often a fit gets within 1.2x of the true model.

For each family (LuGre, GMS(4), Maxwell-slip NLR(5), the Tustin static law) and seed: true parameters drawn
log-uniformly (a factor 2 either way) around a nominal model (the static level Fs 25-100 % above Fc). Two GMS
families: `gms`, whose element stiffnesses are proportional to their force shares (all four break away at one
displacement: the hysteresis of a single element), and `gms-spread`, whose elements break away at 0.25, 0.5, 1 and 2
times a nominal displacement (four distinct pre-sliding branches); a training record and a held-out test record of
different amplitude and frequency (both from pre-sliding into sliding), the forces with noise (1 % of the force
range) and the displacement quantised (2 nm) as a sensor gives them. Each fit starts from `fj.initial_guess` (the
true element count; GMS also from its start with the small elements replaced, where that differs, the lower training
loss kept, as `fricjax compare` does with its validation part; each GMS fit then polished by LM through a two-stage
smoothing continuation, 10x the width then 1x, kept where its training loss is lower (compare: its validation
loss); `--no-polish` leaves it out) and runs Levenberg-Marquardt (smooth model, separable linear parameters) with
`--starts` starts (`--screen 0`: screened by their loss at the start, the best `--keep` fitted); a fit succeeds
when its exact free run's NMSE on the test record is within `--tolerance` (1.2) times the true model's NMSE on the
same measured input. Prints one JSON line per family and start count (success rate, median ratio, wall time per fit,
the start's time included, how many fits stopped at their step budget: not converged) and one per fit with
`--verbose`.

Run: `python benchmarks/global_search.py [--seeds 10] [--starts 1 8] [--screen 0 --keep 4] [--families gms nlr]`.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fricjax as fj  # noqa: E402
from _environment import environment  # noqa: E402

DT = 1e-3
NOISE = 0.01  # of the force range
QUANTUM = 2e-9  # m


def excitation(seed: int, amplitude: float, frequency: float, samples: int = 6000) -> fj.Motion:
    """A sine whose amplitude rises from 1 % to 100 % of `amplitude` [m], plus a slow random walk, quantised."""
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * DT
    envelope = amplitude * (0.01 + 0.99 * (t / t[-1]) ** 2)
    x = envelope * np.sin(2 * np.pi * frequency * t) + np.cumsum(rng.normal(size=samples)) * amplitude * 1e-3
    return fj.Motion.from_position(np.round(x / QUANTUM) * QUANTUM, dt=DT)


def truth(family: str, rng: np.random.Generator) -> tuple[Any, tuple[str, ...]]:
    """A random true model of `family` and its linear (separable) parameters."""

    def f(value: float) -> float:  # log-uniform, a factor 2 either way
        return float(value * np.exp(rng.uniform(-np.log(2), np.log(2))))

    Fc = f(1.0)  # a static level 25-100 % above the Coulomb level (Fs > Fc: a plausible true model)
    stribeck = fj.ExponentialStribeck(Fc=Fc, Fs=Fc * (1.0 + f(0.5)), vs=f(2e-3), delta=2.0)
    if family == "lugre":
        return fj.LuGre(stribeck, f(1e5), f(300.0), f(40.0), offset=0.1), ("sigma1", "sigma2", "offset")
    if family == "gms":  # k proportional to the force shares: every element breaks away at one displacement
        k = f(1e5) * np.array([0.4, 0.3, 0.2, 0.1])
        return fj.GMS(stribeck, k, [0.4, 0.3, 0.2, 0.1], f(50.0), f(40.0), offset=0.1), ("sigma2", "offset")
    if family == "gms-spread":  # the elements break away at 0.25, 0.5, 1 and 2 times a nominal displacement
        alpha = np.array([0.4, 0.3, 0.2, 0.1])
        breakaway = 1.5 * Fc / f(1e5) * np.array([0.25, 0.5, 1.0, 2.0])  # m: the nominal static level / stiffness
        k = alpha * 1.5 * Fc / breakaway
        return fj.GMS(stribeck, k, alpha, f(50.0), f(40.0), offset=0.1), ("sigma2", "offset")
    if family == "nlr":
        thresholds = f(2e-5) * np.geomspace(0.05, 1.0, 5)
        return fj.MaxwellSlip.nlr(k=f(1.0) / 5 / thresholds, thresholds=thresholds, offset=0.1), ("force_map.offset",)
    if family == "tustin":
        law = fj.unwrap(stribeck)
        return fj.Tustin(Fc=law.Fc, Fs=law.Fs, vs=law.vs, Fv=f(40.0), offset=0.1), ("Fv", "offset")
    raise ValueError(family)


def smoothing(family: str, data: fj.FrictionData) -> fj.AbstractSmoothing:
    scales = fj.RecordScales.from_data(data)
    if family == "nlr":
        return fj.Smooth(1e-3)
    if family.startswith("gms"):
        return fj.Smooth(max(1e-3 * scales.dx, 1e-12))
    return fj.Smooth(max(1e-3 * scales.vs, 1e-9))


def _train_loss(result: fj.FitResult) -> float:
    return float(result.train_loss) if np.isfinite(result.train_loss) else np.inf


def one(
    family: str, seed: int, starts: int, steps: int, screen: float = 0.25, keep: int = 2, polish: bool = True
) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    model, linear = truth(family, rng)
    records = []
    for part, (amplitude, frequency) in enumerate(((2e-3, 1.0), (8e-4, 2.3))):
        motion = excitation(1000 * seed + part, amplitude, frequency)
        force = np.asarray(fj.simulate(model, motion))
        force = force + NOISE * np.ptp(force) * rng.normal(size=force.shape)
        records.append(fj.FrictionData(motion, force))
    train, test = records
    began = time.perf_counter()  # the data-driven start is part of the fit's time
    elements = {"gms": 4, "gms-spread": 4, "nlr": 5}.get(
        family
    )  # the true model's structure (initial_guess's default is 4)
    start = fj.initial_guess(type(model), train, elements=elements, smoothing=smoothing(family, train))
    multistart = (
        None
        if starts == 1
        else fj.MultiStart(starts, 1.0, distribution="log-uniform", keep=keep if keep < starts else None, screen=screen)
    )
    begins = [start]
    if isinstance(start, fj.GMS):  # as compare: also from the start with its small elements replaced, where it differs
        replaced = fj.initial_guess(start, train, without_small_elements=True)
        if not np.array_equal(np.asarray(fj.unwrap(replaced).k), np.asarray(fj.unwrap(start).k)):
            begins.append(replaced)
    fits = [
        fj.fit(
            begin,
            train,
            solver=fj.levenberg_marquardt(),
            steps=steps,
            scaling=fj.ParameterScaling(),
            separable=linear,
            multistart=multistart,
            tolerance=1e-4,
            seed=seed,
        )
        for begin in begins
    ]
    if polish and isinstance(start, fj.GMS):  # as compare: each fit polished by a smoothing continuation back to eps
        eps = float(smoothing(family, train).eps)
        polished = [
            fj.fit(
                result.model,
                train,
                solver=fj.levenberg_marquardt(),
                steps=steps,
                scaling=fj.ParameterScaling(),
                separable=linear,
                continuation=fj.Continuation(10.0 * eps, eps, stages=2),
                tolerance=1e-4,
            )
            for result in fits
        ]
        fits = [min(pair, key=_train_loss) for pair in zip(fits, polished, strict=True)]
    result = min(fits, key=_train_loss)  # no validation part
    wall = time.perf_counter() - began
    fitted = float(fj.nmse(test.force, fj.simulate(fj.exact(result.model), test.motion)))
    reference = float(fj.nmse(test.force, fj.simulate(model, test.motion)))
    return {
        "family": family,
        "seed": seed,
        "starts": starts,
        "ratio": fitted / reference,
        "fitted_nmse": fitted,
        "true_nmse": reference,
        "wall_s": wall,
        "result": result.code,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", nargs="+", default=["lugre", "gms", "gms-spread", "nlr", "tustin"])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--starts", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--tolerance", type=float, default=1.2)
    parser.add_argument("--screen", type=float, default=0.25, help="share of the steps screening (0: forward)")
    parser.add_argument("--keep", type=int, default=2, help="starts polished after screening")
    parser.add_argument(
        "--no-polish", action="store_true", help="GMS: leave out the smoothing-continuation polish of each fit"
    )
    parser.add_argument("--verbose", action="store_true")
    cfg = parser.parse_args()
    env = environment()
    for family in cfg.families:
        for starts in cfg.starts:
            runs = [
                one(family, seed, starts, cfg.steps, cfg.screen, cfg.keep, not cfg.no_polish)
                for seed in range(cfg.seeds)
            ]
            if cfg.verbose:
                for run in runs:
                    print(json.dumps({**run, **env}), flush=True)
            ratios = [run["ratio"] for run in runs]
            print(
                json.dumps(
                    {
                        "bench": "global_search",
                        "family": family,
                        "starts": starts,
                        "screen": cfg.screen,
                        "keep": cfg.keep,
                        "steps": cfg.steps,
                        "polish": not cfg.no_polish,
                        "seeds": cfg.seeds,
                        "success_rate": float(np.mean([r <= cfg.tolerance for r in ratios])),
                        "median_ratio": statistics.median(ratios),
                        "worst_ratio": max(ratios),
                        "stopped_at_budget": sum(run["result"] == "max_steps" for run in runs),  # not converged
                        "median_wall_s": statistics.median(run["wall_s"] for run in runs),
                        **env,
                    }
                ),
                flush=True,
            )


if __name__ == "__main__":
    main()
