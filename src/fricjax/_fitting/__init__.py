"""Fitting: losses, the `fit` driver, separable least squares, multi-start, continuation, results."""
