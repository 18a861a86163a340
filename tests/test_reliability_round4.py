"""Reliability, round 4 (issue 52): values no model can compute with, records named twice or weighted silently,
checks too strict or too loose, plausible records that raised tracebacks. The cache: tests/test_compilation_cache.py."""

import equinox as eqx
import jax.numpy as jnp
import pytest

import fricjax as fj


@pytest.mark.parametrize(
    "build",
    [
        lambda value: fj.Backlash(fj.Coulomb(Fc=1.0), gap=value),
        lambda value: fj.NormalLoad(fj.Coulomb(Fc=1.0), reference=value),
    ],
    ids=["Backlash.gap", "NormalLoad.reference"],
)
def test_subnormal_divisors_are_refused_by_the_constructors(build):
    with pytest.raises(ValueError, match="too small to compute with"):
        build(1e-320)
    build(1e-6)  # small, normal: fine


@pytest.mark.parametrize("bad", [0.0, -5.0, 1e-320])
def test_load_model_refuses_a_reference_load_the_constructor_refuses(tmp_path, bad):
    model = fj.NormalLoad(fj.Coulomb(Fc=1.0), reference=100.0)
    edited = eqx.tree_at(lambda m: m.reference.value, model, jnp.asarray(bad))
    path = tmp_path / "normal_load.eqx"
    with pytest.warns(UserWarning, match="load_model will refuse"):
        fj.save_model(path, edited)
    with pytest.raises(ValueError, match="NormalLoad.*reference"):
        fj.load_model(path)
    fj.save_model(path, model)
    assert float(fj.load_model(path).reference.value) == 100.0


def test_load_model_refuses_a_subnormal_gap(tmp_path):
    model = fj.Backlash(fj.Coulomb(Fc=1.0), gap=1e-3)
    edited = eqx.tree_at(lambda m: m.gap.raw, model, jnp.asarray(-736.8))  # log(1e-320): a subnormal gap
    path = tmp_path / "backlash.eqx"
    with pytest.warns(UserWarning):
        fj.save_model(path, edited)
    with pytest.raises(ValueError, match="invalid Positive at `model.gap`"):
        fj.load_model(path)
