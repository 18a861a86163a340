"""Estimation, one folder per job; the drivers at the top.

- `_fit.py` (`fj.fit`), `_fit_arguments.py` (its checked arguments), `_sweep.py` (`fj.sweep`): the drivers.
- `loop/`: the one optimisation loop, its solvers and strategies, `Solution` / `RESULTS`, signals and devices.
- `problem/`: what a fit minimises: losses, several records with their nuisances, the trained / separable parameters.
- `initial/`: before a fit: record scales, data-driven starts, multi-element models' elements, `fj.initialise`.
- `linear/`: least squares, covariance, term selection, teacher-forced regressor rows.
- `families/`: the closed-form and selection fitters of model families (kernel, local, wavelet, polynomial NARX,
  recursive least squares, ensemble weights).

Imports within run one way: `linear` and `loop` <- `problem` <- the drivers <- `initial`, `families`.
"""
