"""Estimation: the fit driver, losses, strategies, least squares / selection / covariance, results, model files."""
