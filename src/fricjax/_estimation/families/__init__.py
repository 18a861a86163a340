"""Closed-form and selection fitters of model families: kernel, local, wavelet and polynomial NARX, recursive least
squares, ensemble weights."""
