"""What a user reads: `print(model)` lists the physical parameter values with their units, and a fit's summary
never prints a bare "nan" for a validation loss it does not have."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import fricjax as fj


def _lugre(**kwargs) -> fj.LuGre:
    stribeck = fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3)
    return fj.LuGre(stribeck, sigma0=1e5, sigma1=300.0, sigma2=0.4, **kwargs)


def test_print_lists_physical_values_with_units():
    text = str(_lugre(z0=2e-6, smoothing=fj.Smooth(1e-3)))
    assert text.splitlines() == [
        "LuGre (smooth, eps 0.001)",
        "  stribeck.Fc = 1 [N]",
        "  stribeck.Fs = 1.5 [N]",
        "  stribeck.vs = 0.001 [m/s]",  # a positive parameter: the physical value, not its logarithm
        "  stribeck.delta = 1 [-]",
        "  sigma0 = 100000 [N/m]",
        "  sigma1 = 300 [N s/m]",
        "  sigma2 = 0.4 [N s/m]",
        "  offset = 0 [N]",
        "  z0 = 2e-06 [m]",
    ]
    assert repr(fj.exact(_lugre())).startswith("LuGre (exact)\n")


def test_print_marks_fixed_parameters_and_summarises_long_arrays():
    text = str(fj.CoulombViscous(Fc=fj.Fixed(1.0), Fv=20.0))
    assert "  Fc = 1 [N] (fixed)" in text.splitlines() and "  Fv = 20 [N s/m]" in text.splitlines()
    k = np.linspace(1e4, 2e4, 12)
    text = str(fj.MaxwellSlip.nlr(k=k, thresholds=np.linspace(1e-6, 1.2e-5, 12)))
    assert "  force_map.k: shape (12,), range [1e+04, 2e+04] [N/m]" in text.splitlines()
    assert len(text.splitlines()) == 4  # the class line, thresholds, offset, k


def test_print_falls_back_to_equinox_where_values_are_not_concrete():
    model = _lugre()
    seen = []

    def record(m):
        seen.append(repr(m))
        return fj.unwrap(m).sigma0

    jax.jit(record)(model)  # traced leaves: equinox's formatting, no error
    eqx.filter_vmap(record)(fj.stack_models([model, model]))
    eqx.filter_eval_shape(record, model)
    assert len(seen) == 3 and all(text.startswith("LuGre(\n") and "sigma0=" in text for text in seen)

    @jax.jit
    def closure(x):  # a concrete model printed while a jit is traced (an error message, say): values
        seen.append(repr(model))
        return x

    closure(jnp.ones(()))
    assert "  sigma0 = 100000 [N/m]" in seen[-1].splitlines()


def test_tree_pformat_keeps_the_structural_view():
    text = eqx.tree_pformat(_lugre())
    assert text.startswith("LuGre(\n") and "Positive(" in text and "[N/m]" not in text


def test_summary_without_validation_data_prints_no_nan():
    model = fj.Coulomb(Fc=1.0)
    for result in ("successful", "max_steps", "diverged"):
        lines = fj.Solution(model, result=result, train_loss=0.25).summary().splitlines()
        assert lines[1].startswith("train loss 0.25, ") and "nan" not in lines[1].lower(), lines[1]
    assert "no validation data" in fj.Solution(model, train_loss=0.25).summary()
    with_validation = fj.Solution(model, train_loss=0.25, val_loss=0.5, exact_val_loss=0.75).summary()
    assert "validation loss 0.5 (exact 0.75)" in with_validation
    # a model without a smooth mode (kernel NARX, local models) has one validation loss: no "(exact nan)"
    one_loss = fj.Solution(model, train_loss=0.25, val_loss=0.5).summary()
    assert "validation loss 0.5" in one_loss and "nan" not in one_loss.lower()
    assert "  Fc = 1 [N]" in with_validation.splitlines()
