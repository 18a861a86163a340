"""Datasets, loaders and preprocessing."""
