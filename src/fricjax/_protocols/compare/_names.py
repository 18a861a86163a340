"""The names of the models `compare` can fit (no imports: the command line reads them before it loads JAX)."""

PHYSICS_MODELS = ("stribeck", "lugre", "lugre-backlash", "gms", "nlr", "dnlrx")
NEURAL_MODELS = ("mlp", "gsnn", "rnn", "avd")
LINEAR_MODELS = ("narx", "kernel", "knn", "wavelet")
MODEL_NAMES = PHYSICS_MODELS + NEURAL_MODELS + LINEAR_MODELS
"""Every model `compare` can fit; the command line fits `PHYSICS_MODELS` unless told otherwise."""
