"""Friction models: one module per family; `_base` holds the abstract interfaces."""
