"""Bounds and regularisation in `fj.fit` (issue 55, item 5; `idnlgrey`'s Minimum / Maximum and Regularization):
`fj.Bounded` parameters that never leave their interval, `fj.Bounds` to bound a fit's parameters by path, and
`fj.Regularisation` (L2 / L1 on the change from the start)."""

from __future__ import annotations

import warnings

import equinox as eqx
import numpy as np
import optax
import pytest

import fricjax as fj

MOTION = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 12, 600)), dt=1e-3)
TRUTH = fj.CoulombViscous(Fc=1.0, Fv=30.0, smoothing=fj.Smooth(1e-4))
DATA = fj.FrictionData(MOTION, fj.simulate(TRUTH, MOTION))
START = fj.CoulombViscous(Fc=0.5, Fv=10.0, smoothing=fj.Smooth(1e-4))


def test_a_bounded_parameter_maps_its_raw_leaf_into_the_interval_and_survives_a_model_file(tmp_path):
    bounded = fj.Bounded(0.3, 0.2, 0.8)
    assert float(fj.unwrap(bounded)) == pytest.approx(0.3, rel=1e-12)
    far = eqx.tree_at(lambda b: b.raw, bounded, bounded.raw + 1e3)  # any raw value stays inside
    assert 0.2 < float(fj.unwrap(far)) <= 0.8
    for value, low, high in [(0.9, 0.2, 0.8), (0.2, 0.2, 0.8), (0.5, 0.8, 0.2), (0.5, 0.0, np.inf)]:
        with pytest.raises(ValueError, match="bounds|inside"):
            fj.Bounded(value, low, high, name="Fc")
    model = eqx.tree_at(lambda m: m.Fc, START, fj.Bounded(0.5, 0.2, 0.8, name="Fc"))
    assert "Fc = 0.5 [N] (bounded 0.2 .. 0.8)" in str(model)
    fj.save_model(tmp_path / "m.eqx", model)
    loaded = fj.load_model(tmp_path / "m.eqx")
    assert float(fj.unwrap(loaded).Fc) == pytest.approx(0.5) and "(bounded 0.2 .. 0.8)" in str(loaded)


@pytest.mark.parametrize("solver", ["lm", "adam"])
def test_a_bounded_fit_ends_inside_its_bounds(solver):
    chosen = fj.levenberg_marquardt() if solver == "lm" else optax.adam(5e-2)
    result = fj.fit(START, DATA, solver=chosen, steps=60, strategies=[fj.Bounds({"Fc": (0.2, 0.8)})])
    fitted = fj.unwrap(result.model)
    assert 0.2 < float(fitted.Fc) < 0.8 and result.success
    assert "(bounded 0.2 .. 0.8)" in result.summary()
    if solver == "lm":  # the truth (Fc = 1) is outside: the fit presses against the upper bound
        assert float(fitted.Fc) > 0.79


def test_a_start_outside_its_bounds_is_moved_inside_with_a_warning_and_conflicts_are_refused():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = fj.fit(
            START, DATA, solver=fj.levenberg_marquardt(), steps=5, strategies=[fj.Bounds({"Fc": (0.7, 1.5)})]
        )
    assert any("not inside (0.7, 1.5)" in str(w.message) for w in caught)
    assert 0.7 < float(fj.unwrap(result.model).Fc) < 1.5
    with pytest.raises(ValueError, match="also separable"):
        fj.fit(START, DATA, steps=2, separable=("Fv",), strategies=[fj.Bounds({"Fv": (1.0, 50.0)})])
    fixed = eqx.tree_at(lambda m: m.Fv, START, fj.Fixed(10.0))
    with pytest.raises(ValueError, match="fixed"):
        fj.fit(fixed, DATA, steps=2, strategies=[fj.Bounds({"Fv": (1.0, 50.0)})])
    with pytest.raises(ValueError, match="not a field path"):
        fj.fit(START, DATA, steps=2, strategies=[fj.Bounds({"sigma0": (1.0, 2.0)})])
    with pytest.raises(ValueError, match="low < high"):
        fj.Bounds({"Fc": (2.0, 1.0)})


def test_regularisation_holds_parameters_near_the_start_in_proportion_to_its_weight():
    def fitted(strength):
        strategy = fj.Regularisation(l2=strength)
        result = fj.fit(START, DATA, solver=fj.levenberg_marquardt(), steps=60, strategies=[strategy])
        return fj.unwrap(result.model), result

    weak, weak_result = fitted(1e-9)
    strong, strong_result = fitted(1.0)
    assert float(weak.Fc) == pytest.approx(1.0, rel=1e-3) and float(weak.Fv) == pytest.approx(30.0, rel=1e-3)
    # a relative change of Fv (stored as a log) costs l2 log(Fv / 10)^2: the strong penalty keeps it near 10
    assert abs(np.log(float(strong.Fv) / 10.0)) < 0.05 < abs(np.log(float(weak.Fv) / 10.0))
    # train_loss is the data's loss, without the penalty
    data_loss = float(fj.SimulationLoss()(strong_result.model, None, DATA))
    assert strong_result.train_loss == pytest.approx(data_loss, rel=1e-9)
    with pytest.raises(ValueError, match="l2 > 0"):
        fj.Regularisation()


def test_an_l1_penalty_has_finite_gradients_at_the_start():
    """|d| is rounded at 0, where every fit starts: LM's Jacobian and Adam's gradient stay finite."""
    for solver in (fj.levenberg_marquardt(), optax.adam(1e-2)):
        result = fj.fit(START, DATA, solver=solver, steps=20, strategies=[fj.Regularisation(l1=1e-3)])
        assert result.code != "diverged" and np.isfinite(result.train_loss), result.message
