"""The one optimisation loop and its parts: solvers (fricjax's Levenberg-Marquardt, optax / optimistix adapters),
strategies, stopping words, `Solution` and `RESULTS`, signals, devices, and `least_squares` on it."""
