"""The elements of multi-element models read off records: Maxwell-slip thresholds and stiffnesses by a dense
linear regression merged to a count (`maxwell_slip_elements`), the count a record supports (`element_count`), GMS's
sliding law screened on a small grid (`screen_gms_sliding_law`), and the edits of an element set (small elements
replaced, the largest split).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import numpy as np

from ..._constraints import unwrap
from ..._data._record import FrictionData
from ..._models.physics._gms import GMS
from ..._models.physics._maxwell_slip import MaxwellSlip, SpringForces
from ..._models.physics._stribeck import ExponentialStribeck
from ..._simulate import simulate
from ..._validation import nonnegative_float, positive_int
from .._sweep import stack_models
from ..problem._records import padded_record
from ._record_scales import (
    RecordScales,
    as_records,
    host_signals,
    mean_offset,
    record_indicator,
    record_of_each_sample,
    with_viscous_slope,
)

_SIMULATE_EACH = eqx.filter_jit(eqx.filter_vmap(simulate, in_axes=(0, None)))  # a batch of models, one record

GRID_ELEMENTS = 48  # the dense LR model of `maxwell_slip_elements`


def maxwell_slip_elements(
    data: FrictionData | Sequence[FrictionData], scales: RecordScales, elements: int, *, viscous: bool = False
) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The `elements` Maxwell-slip elements that best reproduce the record: thresholds [m], stiffnesses [N/m], the
    force offset [N] and, with `viscous`, a viscous slope [N s/m] (>= 0) fitted with them (else 0); None for a
    record without motion. GMS starts take their element stiffnesses and force shares from them. Several records
    (a list): one regression of all, each record's elements starting from rest and each record its own offset (the
    offset returned is their mean weighted by length).

    Two steps, both without a descent through the non-smooth threshold clip (parlitz2004 §III-C fits NLR models by a
    genetic algorithm and Nelder-Mead for that reason): (1) an LR model (parlitz2004 §III-A) of `GRID_ELEMENTS`
    elements, thresholds spread geometrically from the small steps near reversals to 20x the slip distance, its
    element forces `k_i Delta_i >= 0` and offset by non-negative least squares on the exact element deflections
    (`_dense_elements`); (2) adjacent elements of that model merged, the pair whose merge changes the initial
    loading curve `sum_i k_i min(delta, Delta_i)` least first (a merged element keeps the pair's force capacity, at
    the stiffness-weighted threshold or at either member's), until `elements` are left (the curve fixes the model's
    response to any displacement history: Masing's rule). On the NLR records of benchmarks/global_search.py the start
    alone is within 1.008x of the true model's held-out error."""
    dense = _dense_elements(as_records(data, "maxwell_slip_elements"), scales, viscous=viscous, elements=elements)
    if dense is None:
        return None
    grid, stiffness, offset, Fv = dense
    thresholds, k = _merge_elements(grid, stiffness, elements)
    return thresholds, k, offset, Fv


def _elements_by_nnls(
    deflections: np.ndarray, velocity: np.ndarray | None, force: Any, group: np.ndarray | None = None
) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Non-negative least squares of `force ~ deflections @ c + Fv v + offset[group]` (the normalised element
    deflections, shape (N, M); no viscous column when `velocity` is None; `group` each sample's record, default one
    record; the offsets of either sign): the element forces `c` [N], `Fv` [N s/m], the offset of each record [N] and
    the mean squared residual [N^2]. The design is first reduced to its triangular factor (small; the same
    minimiser, and the residual of the part it cannot reach added back)."""
    import scipy.optimize

    force = np.asarray(force, np.float64)
    group = np.zeros(len(force), int) if group is None else np.asarray(group)
    records = int(group.max()) + 1
    indicator = record_indicator(group, records)
    v = np.zeros((len(force), 0)) if velocity is None else np.asarray(velocity, np.float64)[:, None]
    design = np.concatenate([deflections, v, indicator, -indicator], axis=1)
    triangle = np.asarray(np.linalg.qr(np.concatenate([design, force[:, None]], axis=1), mode="r"))
    n = design.shape[1]
    # fewer samples than columns (a short record, a fine grid): the factor has fewer rows; its missing rows are zeros
    triangle = np.pad(triangle, ((0, max(0, n + 1 - triangle.shape[0])), (0, 0)))
    solution, reduced = scipy.optimize.nnls(triangle[:n, :n], triangle[:n, n], maxiter=50 * n)
    m = deflections.shape[1]
    Fv = float(solution[m]) if velocity is not None else 0.0
    residual = (float(reduced) ** 2 + float(triangle[n, n]) ** 2) / len(force)
    offsets = solution[n - 2 * records : n - records] - solution[n - records :]
    return solution[:m], Fv, offsets, residual


def _dense_elements(
    records: Sequence[FrictionData], scales: RecordScales, *, viscous: bool, elements: int = 2
) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The dense LR model of `maxwell_slip_elements` (step 1): the thresholds [m] and stiffnesses [N/m] of its
    elements with a non-zero force, its offset [N] (several records: their offsets' mean weighted by length) and
    viscous slope [N s/m]; None for records without motion (or shorter than `3 * elements` samples)."""
    signals = [host_signals(r) for r in records]
    steps = np.abs(np.concatenate([np.diff(x) for x, _, _ in signals]))
    steps = steps[steps > 0]
    lengths = [r.length for r in records]
    if steps.size < 2 or sum(lengths) < 3 * elements:
        return None
    top = 20.0 * max(scales.slip, scales.breakaway)
    low = min(max(float(np.percentile(steps, 2)), 5e-5 * top), 1e-2 * top)  # the small steps near reversals
    grid = np.geomspace(low, top, GRID_ELEMENTS)
    velocity = np.concatenate([v for _, v, _ in signals]) if viscous else None
    force = np.concatenate([f for _, _, f in signals])
    group = record_of_each_sample(lengths)
    capacity, Fv, offsets, _ = _elements_by_nnls(element_deflections(records, grid), velocity, force, group)
    keep = capacity > 1e-9 * max(float(capacity.max()), 1e-300)
    if not keep.any():
        return None
    offset = mean_offset(offsets, lengths)
    return grid[keep], capacity[keep] / grid[keep], offset, Fv


MOST_ELEMENTS = 8  # the largest element count `element_count` considers
ELEMENT_TOLERANCE = 0.02  # the relative excess of the mean squared residual that `element_count` accepts


def element_count(
    data: FrictionData | Sequence[FrictionData],
    *,
    most: int = MOST_ELEMENTS,
    tolerance: float = ELEMENT_TOLERANCE,
    fewest: int = 2,
) -> int:
    """How many elements a multi-element model (GMS, Maxwell-slip) of the record needs, read off it before any
    fit: the fewest (`fewest` ... `most`) whose Maxwell-slip model (the thresholds of the dense regression of
    `maxwell_slip_elements` merged down to that count; the element forces, viscous slope and offset refitted by
    non-negative least squares) leaves a mean squared residual within `1 + tolerance` of the best count's. The
    merged models' deflections come from one vmap-ed simulation. Several records (a list): the most that any one
    of them needs (a record with little pre-sliding cannot tell small elements apart, and one regression of records
    of different regimes fits neither well). Returns 4 (the former default, within `fewest`-`most`) for a record
    without motion.

    The residuals of neighbouring counts can differ by several per cent from the merging alone, so a count above
    the true one is read off some records: on the synthetic tribometer (3 seeds, 60 % and 80 % training parts) 4
    off 4 of 6 mixed records of the default 4-element GMS (5 off the others) and 6 off the mixed records of a
    6-element GMS that benchmarks/held_out_compare.py uses (there GMS(4) scores 2.8-16x the true model's error on
    held-out records, GMS(5) 1.5-10x, GMS(6) 1.0-1.7x). `fricjax compare` therefore keeps more than 4 GMS elements only
    where the validation part prefers them significantly. Counts below the truth are read too, where the record does
    not load every element apart (a user's trial, 2026-11-28: a GMS(4) truth on a pre-sliding record read 3; GMS(2)
    and GMS(3) truths read 3-6): the count is a start for a model choice, not an estimate of the truth.
    """
    fewest, most = positive_int(fewest, "fewest", "element_count"), positive_int(most, "most", "element_count")
    tolerance = nonnegative_float(tolerance, "tolerance", "element_count")
    if fewest > most:
        raise ValueError(f"element_count: `fewest` ({fewest}) must be at most `most` ({most}).")
    if not isinstance(data, FrictionData):
        try:
            records = list(data)
        except TypeError:
            records = []
        if not records or not all(isinstance(r, FrictionData) for r in records):
            raise TypeError("element_count: `data` must be an fj.FrictionData or a non-empty list of them.")
        return max(element_count(r, most=most, tolerance=tolerance, fewest=fewest) for r in records)
    dense = _dense_elements([data], RecordScales.from_data(data), viscous=True, elements=most)
    if dense is None:  # nothing to read: the former default, within the asked range
        return min(max(4, fewest), most)
    grid, stiffness, _, _ = dense
    counts = list(range(fewest, most + 1))
    merged = [_merge_elements(grid, stiffness, m)[0] for m in counts]
    deflections = element_deflections([data], np.concatenate(merged))  # normalised, (N, all counts' elements)
    v = np.asarray(data.motion.samples().v, np.float64)
    edges = np.cumsum([0, *(len(t) for t in merged)])
    residuals = [
        _elements_by_nnls(deflections[:, a:b], v, data.force)[3] for a, b in zip(edges[:-1], edges[1:], strict=True)
    ]
    best = min(residuals)
    return next((m for m, r in zip(counts, residuals, strict=True) if r <= (1.0 + tolerance) * best), most)


STATIC_RATIOS = (1.1, 1.5, 2.2, 3.2, 4.5)  # Fs / Fc screened by `screen_gms_sliding_law`
STRIBECK_VELOCITY_FACTORS = (0.3, 1.0, 3.0)  # times the record's slow velocity
ATTRACTION_FACTORS = (1.0, 4.0)  # times 10 Fs per second


def screen_gms_sliding_law(guess: GMS, records: Sequence[FrictionData]) -> GMS:
    """`guess` with the Stribeck curve and attraction rate of the best of a small grid (`STATIC_RATIOS` x
    `STRIBECK_VELOCITY_FACTORS` x `ATTRACTION_FACTORS`, and `guess`'s own), each run free on the record in one
    vmap-ed program, with the viscous slope (>= 0) and offset of each solved by least squares: the peak of |F| on a
    record underestimates `Fs` when the elements reach their bound only once the velocity has passed `vs`, and a
    gradient fit from too low an `Fs` stays in a flat Stribeck curve (benchmarks/global_search.py: 8-17x the true
    model's error on 4 of 10 seeds). Several records: each run from rest, each its own offset, the cost pooled."""
    p = unwrap(guess)
    Fc, vs, C = float(p.stribeck.Fc), float(p.stribeck.vs), float(p.C) / float(p.stribeck.Fs)
    candidates = [guess]
    for ratio in STATIC_RATIOS:
        for factor in STRIBECK_VELOCITY_FACTORS:
            for rate in ATTRACTION_FACTORS:
                stribeck = ExponentialStribeck(Fc=Fc, Fs=ratio * Fc, vs=factor * vs, delta=float(p.stribeck.delta))
                candidates.append(
                    GMS(stribeck, k=p.k, alpha=p.alpha, C=rate * C * ratio * Fc, sigma2=p.sigma2, offset=p.offset,
                        smoothing=guess.smoothing)
                )  # fmt: skip
    forces = simulate_each(candidates, records)
    signals = [host_signals(r) for r in records]
    v = np.concatenate([v for _, v, _ in signals])
    elastic = forces - np.asarray(p.sigma2) * v - np.asarray(p.offset)  # each candidate without its linear terms
    residual = np.concatenate([f for _, _, f in signals])[None, :] - elastic
    best, best_cost, best_linear = 0, np.inf, (float(p.sigma2), float(p.offset))
    lengths = [r.length for r in records]
    group = record_of_each_sample(lengths)
    indicator = record_indicator(group, len(records))
    for i, r in enumerate(residual):
        *offsets, Fv = with_viscous_slope(indicator, v, r)
        cost = float(np.mean((r - Fv * v - np.asarray(offsets)[group]) ** 2))
        if np.isfinite(cost) and cost < best_cost:
            best, best_cost = i, cost
            best_linear = (float(Fv), mean_offset(offsets, lengths))
    chosen = unwrap(candidates[best])
    law = chosen.stribeck
    stribeck = ExponentialStribeck(Fc=float(law.Fc), Fs=float(law.Fs), vs=float(law.vs), delta=float(law.delta))
    return GMS(
        stribeck, k=chosen.k, alpha=chosen.alpha, C=chosen.C, sigma2=best_linear[0], offset=best_linear[1],
        smoothing=guess.smoothing,
    )  # fmt: skip


def element_deflections(records: Sequence[FrictionData], thresholds: np.ndarray) -> np.ndarray:
    """The exact Maxwell-slip element deflections over thresholds, normalised (`delta_i / Delta_i`), shape (N, M)
    (N the records' samples one after another), each record from rest (parlitz2004 eq. 3): one single-element model
    per threshold (`k = 1 / Delta`: its force is the normalised deflection), run side by side in one vmap-ed
    program."""
    return simulate_each([MaxwellSlip.nlr(k=[1.0 / t], thresholds=[t]) for t in thresholds], records).T


def simulate_each(models: list[Any], records: Sequence[FrictionData]) -> np.ndarray:
    """The free-run forces of models of one structure on each record's motion from rest, shape (models, N), the
    records one after another: one vmap-ed program (compiled once per structure and record shape; several records
    are padded at rest to the longest, so one program serves them all, and the padding is cut off)."""
    stacked = stack_models(models)
    if len(records) == 1:
        return np.asarray(_SIMULATE_EACH(stacked, records[0].motion), np.float64)
    total = max(r.length for r in records)
    return np.concatenate(
        [
            np.asarray(_SIMULATE_EACH(stacked, padded_record(r, total, frozenset(), False).motion), np.float64)[
                :, : r.length
            ]
            for r in records
        ],
        axis=1,
    )


def _merge_elements(grid: np.ndarray, stiffness: np.ndarray, elements: int) -> tuple[np.ndarray, np.ndarray]:
    """`elements` elements whose initial loading curve `sum k_i min(delta, Delta_i)` is closest to that of the given
    ones: adjacent pairs merged greedily (force capacity kept, at the stiffness-weighted threshold or at either
    member's); where there are fewer, the one of
    the largest capacity split in two around its threshold."""
    thresholds, k = [float(t) for t in grid], [float(s) for s in stiffness]
    delta = np.geomspace(thresholds[0] / 3.0, thresholds[-1] * 3.0, 256)

    def curve(t: list[float], s: list[float]) -> np.ndarray:
        return np.sum(np.asarray(s)[:, None] * np.minimum(delta[None, :], np.asarray(t)[:, None]), axis=0)

    target = curve(thresholds, k)
    while len(thresholds) > elements:
        best: tuple[float, list[float], list[float]] | None = None
        for i in range(len(thresholds) - 1):
            capacity = k[i] * thresholds[i] + k[i + 1] * thresholds[i + 1]
            # the merged threshold: the stiffness-weighted mean (the stiffness added) or either member's own (the
            # other's capacity moved there): an element of a small force share is absorbed by its neighbour
            # instead of dragging the merged threshold towards it
            for merged in (capacity / (k[i] + k[i + 1]), thresholds[i], thresholds[i + 1]):
                t = [*thresholds[:i], merged, *thresholds[i + 2 :]]
                s = [*k[:i], capacity / merged, *k[i + 2 :]]
                cost = float(np.sum((curve(t, s) - target) ** 2))
                if best is None or cost < best[0]:
                    best = (cost, t, s)
        assert best is not None
        _, thresholds, k = best
    return _split_largest(thresholds, k, elements)


MIN_ELEMENT_SHARE = 0.02  # the force share below which `without_small_elements` replaces an element


def replace_small_elements(thresholds: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The elements with each one of less than `MIN_ELEMENT_SHARE` of the force capacity dropped and the largest
    split instead (as many elements). The non-negative least squares of the dense model leave such elements at the
    small steps near reversals, where a GMS start kept them dead through the fit; on other records they are a true
    element seen faintly (a 5 % element at 0.25 um read as 0.7 %), so both starts are fitted where they differ
    (`initial_guess(..., without_small_elements=True)`; benchmarks/README.md, "Global search, round 6")."""
    t, s = [float(v) for v in thresholds], [float(v) for v in k]
    for _ in range(len(t)):
        capacity = np.asarray(s) * np.asarray(t)
        if len(t) < 2 or capacity.min() >= MIN_ELEMENT_SHARE * capacity.sum():
            break
        i = int(np.argmin(capacity))
        dropped_t, dropped_s = [*t[:i], *t[i + 1 :]], [*s[:i], *s[i + 1 :]]
        split = _split_largest(dropped_t, dropped_s, len(t))
        t, s = [float(v) for v in split[0]], [float(v) for v in split[1]]
    return np.asarray(t), np.asarray(s)


def _split_largest(thresholds: list[float], k: list[float], elements: int) -> tuple[np.ndarray, np.ndarray]:
    """The element of the largest force capacity split in two around its threshold until there are `elements`."""
    while len(thresholds) < elements:
        i = int(np.argmax(np.asarray(k) * np.asarray(thresholds)))
        thresholds = [*thresholds[:i], thresholds[i] / 1.5, thresholds[i] * 1.2, *thresholds[i + 1 :]]
        k = [*k[:i], k[i] / 2.0, k[i] / 2.0, *k[i + 1 :]]
    return np.asarray(thresholds), np.asarray(k)


def element_count_of(model: Any) -> int:
    """The element count of a multi-element model instance (`num_elements`; 4 for a model without elements). A
    Maxwell-slip start must hold spring elements (NLR), whose count and shares the regression reads."""
    force_map = getattr(model, "force_map", None)
    if force_map is not None and not isinstance(force_map, SpringForces):
        raise TypeError("initial_guess: Maxwell-slip starts are NLR models (SpringForces), not DLR / DNLRX.")
    count = getattr(model, "num_elements", None)
    return 4 if count is None else int(count)
