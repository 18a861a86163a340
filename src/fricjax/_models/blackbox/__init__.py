"""Black-box models (NARX, kernel, neural, local): the contract they share lives in `_models/_base.py`."""
