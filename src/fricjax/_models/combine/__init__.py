"""Models built from other models: ensembles (and grey-box + black-box hybrids)."""
