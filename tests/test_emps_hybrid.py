"""EMPS grey + black-box hybrids (`HybridFriction` in an `EMPSPlant`), their fit, ensembles and closed loop.

Synthetic records (the open-loop response of a known plant) keep the fast tier cheap; the benchmark's smoke
run on the real files is in the slow tier.
"""

import json
import os
import pathlib
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj
from fricjax import (
    CoulombViscous,
    EMPSPlant,
    EMPSRecord,
    HybridFriction,
    Smooth,
    Tustin,
    simulate_closed_loop,
    simulate_open_loop,
)
from fricjax.emps import (
    EMPSEnsemble,
    emps_hybrid_start,
    fit_emps_ensemble,
    fit_emps_hybrid,
)

ROOT = pathlib.Path(__file__).resolve().parents[1]
GTAU, DT = 35.1507, 1e-3
TRUTH = EMPSPlant(95.0, CoulombViscous(Fc=20.0, Fv=200.0, offset=-3.0, smoothing=Smooth(1e-3)))


def synthetic_record(plant: EMPSPlant = TRUTH, n: int = 600) -> EMPSRecord:
    t = np.arange(n) * DT
    vir = 1.0 + 2.0 * np.sin(2 * np.pi * 2.1 * t) + 0.8 * np.sin(2 * np.pi * 5.3 * t + 0.4)
    q = np.asarray(simulate_open_loop(plant, vir, GTAU, DT, q0=0.01, qd0=0.02).q)
    return EMPSRecord(
        t=t, qm=q, qg=q, vir=vir, force=GTAU * vir, pulses=None, gtau=GTAU, kp=160.18, kv=243.45, dt=DT, name="syn"
    )


@pytest.fixture(scope="module")
def record() -> EMPSRecord:
    return synthetic_record()


def hybrid_plant(record, inputs=("v", "q", "u"), seed=0, scale_d=0.0) -> EMPSPlant:
    plant = emps_hybrid_start(TRUTH, record, inputs, 6, key=jax.random.PRNGKey(seed))
    if scale_d:
        d = scale_d * jax.random.normal(jax.random.PRNGKey(seed + 1), (6,))
        plant = eqx.tree_at(lambda p: p.friction.d, plant, d)
    return plant


# --- the hybrid law -----------------------------------------------------------------------------------------------


def test_zero_residual_is_the_physics_plant_exactly(record):
    plant = hybrid_plant(record)
    assert isinstance(plant.friction, HybridFriction) and plant.friction.inputs == ("v", "q", "u")
    a = simulate_open_loop(TRUTH, record.vir, GTAU, DT, q0=0.01, qd0=0.02)
    b = simulate_open_loop(plant, record.vir, GTAU, DT, q0=0.01, qd0=0.02)
    # two programs, one plus an exact zero: equal to the last bit but where XLA fused them differently (one sample
    # of 600 differed by 1 ulp once XLA:CPU's concurrency-optimized scheduler was turned off, src/fricjax/_xla_flags.py)
    np.testing.assert_allclose(np.asarray(a.q), np.asarray(b.q), rtol=1e-15, atol=0)
    np.testing.assert_allclose(np.asarray(a.qd), np.asarray(b.qd), rtol=1e-15, atol=0)


@pytest.mark.slow  # about 4 s (compilations)
def test_zero_residual_is_the_physics_plant_in_closed_loop_and_score(record):
    plant = hybrid_plant(record)
    c = simulate_closed_loop(TRUTH, record.qg, GTAU, 160.18, 243.45, DT, q0=0.01)
    d = simulate_closed_loop(plant, record.qg, GTAU, 160.18, 243.45, DT, q0=0.01)
    # equal to round-off, as in open loop (two programs fused differently); the loop keeps the differences bounded
    np.testing.assert_allclose(np.asarray(c.q), np.asarray(d.q), rtol=1e-13, atol=0)
    assert fj.emps.score_emps_open_loop(plant, record) == pytest.approx(
        fj.emps.score_emps_open_loop(TRUTH, record), rel=1e-12
    )


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the hybrid law is checked fast
def test_residual_reads_its_inputs(record):
    plant = hybrid_plant(record, scale_d=1.0)
    h = plant.friction
    v, q, u = 0.05, 0.1, 30.0
    x = (np.array([v, q, u]) - np.asarray(h.center.value)) / np.asarray(h.scale.value)
    expected = float(np.tanh(np.asarray(h.W) @ x + np.asarray(h.b)) @ np.asarray(h.d))  # force_scale 1 N
    assert float(h.residual(v, q, u)) == pytest.approx(expected, rel=1e-12)
    assert float(h(v, q, u)) == pytest.approx(float(TRUTH.friction(v)) + expected, rel=1e-12)
    assert float(plant.resisting_force(v, q, u)) == pytest.approx(float(h(v, q, u)), rel=1e-12)
    with pytest.raises(ValueError, match="q=...") as info:
        h(v)
    assert "u=..." in str(info.value)
    # a residual on v alone needs nothing more, and runs under fj.simulate on a Motion
    only_v = hybrid_plant(record, ("v",), scale_d=1.0).friction
    motion = fj.Motion.from_position(1e-3 * np.sin(np.linspace(0, 6, 100)), dt=DT)
    np.testing.assert_allclose(fj.simulate(only_v, motion), only_v(motion.v), rtol=1e-12)


def test_construction_errors():
    law = CoulombViscous(Fc=20.0, Fv=200.0)
    with pytest.raises(ValueError, match="inputs"):
        HybridFriction.init(law, ("v", "x"), 4, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="width"):
        HybridFriction.init(law, ("v",), 0, key=jax.random.PRNGKey(0))
    with pytest.raises(TypeError, match="static friction law"):
        HybridFriction(object(), np.zeros((2, 1)), np.zeros(2), np.zeros(2))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="shapes"):
        HybridFriction(law, np.zeros((2, 2)), np.zeros(2), np.zeros(2), inputs=("v",))
    with pytest.raises(ValueError, match="scale"):
        HybridFriction(law, np.zeros((2, 1)), np.zeros(2), np.zeros(2), scale=[0.0])


@pytest.mark.slow  # about 2 s (compilations)
def test_asymmetric_law_and_model_file(record, tmp_path):
    law = Tustin(Fc=(20.0, 22.0), Fs=(25.0, 27.0), vs=0.01, Fv=(180.0, 220.0), smoothing=Smooth(1e-3))
    hybrid = HybridFriction.init(law, ("v", "q"), 4, key=jax.random.PRNGKey(0), scale=[0.1, 0.1])
    hybrid = eqx.tree_at(lambda h: h.d, hybrid, jnp.array([0.5, -1.0, 2.0, 0.1]))
    assert hybrid.asymmetric and hybrid.width == 4
    plant = EMPSPlant(95.0, hybrid)
    fj.save_model(tmp_path / "hybrid.eqx", plant)
    loaded = fj.load_model(tmp_path / "hybrid.eqx")
    assert loaded.friction.inputs == ("v", "q")
    a = simulate_open_loop(plant, record.vir, GTAU, DT, q0=0.01)
    b = simulate_open_loop(loaded, record.vir, GTAU, DT, q0=0.01)
    np.testing.assert_array_equal(np.asarray(a.q), np.asarray(b.q))


def _position_loss(d, W, plant, record):
    plant = eqx.tree_at(lambda p: (p.friction.d, p.friction.W), plant, (d, W))
    sim = simulate_open_loop(plant, record.vir[:200], GTAU, DT, q0=0.01, qd0=0.02)
    return jnp.sum(sim.q**2) * 1e4


def test_gradients_match_finite_differences(record):
    plant = hybrid_plant(record, scale_d=2.0)
    d, W = plant.friction.d, plant.friction.W
    loss = jax.jit(_position_loss)
    gd, gW = jax.jit(jax.grad(_position_loss, argnums=(0, 1)))(d, W, plant, record)
    h = 1e-6
    for i in (0, 3):
        e = jnp.zeros_like(d).at[i].set(h)
        fd = (float(loss(d + e, W, plant, record)) - float(loss(d - e, W, plant, record))) / (2 * h)
        assert float(gd[i]) == pytest.approx(fd, rel=1e-4, abs=1e-9)
    e = jnp.zeros_like(W).at[1, 1].set(h)
    fd = (float(loss(d, W + e, plant, record)) - float(loss(d, W - e, plant, record))) / (2 * h)
    assert float(gW[1, 1]) == pytest.approx(fd, rel=1e-4, abs=1e-9)


# --- the fit ------------------------------------------------------------------------------------------------------


WRONG = EMPSPlant(97.0, CoulombViscous(Fc=21.0, Fv=190.0, offset=-2.5, smoothing=Smooth(1e-3)))


@pytest.mark.slow  # a few seconds (a subprocess or a fit): the fast tier stays under 5 minutes
def test_frozen_physics_stays_frozen(record):
    short = fj.emps.split_emps_record(record, 0, 150)
    fitted = fit_emps_hybrid(short, WRONG, inputs=("v",), width=4, freeze_physics=True, steps=4, validation=None)
    p, s = fj.unwrap(fitted.plant), fj.unwrap(WRONG)
    assert float(p.mass) == float(s.mass) and float(p.offset) == float(s.offset)
    for name in ("Fc", "Fv", "offset"):
        assert float(getattr(p.friction.law, name)) == float(getattr(s.friction, name))
    assert float(jnp.max(jnp.abs(p.friction.d))) > 0  # the network trained
    assert np.isnan(fitted.val_rmse_mm) and fitted.refined is None


@pytest.mark.slow  # about 15 s
def test_free_physics_trains_and_the_tail_is_scored(record):
    free = fit_emps_hybrid(record, WRONG, inputs=("v",), width=4, steps=6, validation=0.3, lm_steps=2)
    assert float(fj.unwrap(free.plant).mass) != float(fj.unwrap(WRONG).mass) and np.isfinite(free.val_rmse_mm)
    head = fj.emps.split_emps_record(record, 0, 420)
    assert float(np.sqrt(free.result.train_loss)) < fj.emps.score_emps_open_loop(WRONG, head)
    assert free.refined is not None


def test_fit_argument_errors(record):
    with pytest.raises(ValueError, match="validation"):
        fit_emps_hybrid(record, TRUTH, validation=1.5)
    with pytest.raises(ValueError, match="steps"):
        fit_emps_hybrid(record, TRUTH, steps=-1)
    with pytest.raises(TypeError, match="EMPSPlant"):
        fit_emps_hybrid(record, TRUTH.friction)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="`patience`.*early_stopping=True"):
        fit_emps_hybrid(record, TRUTH, patience=5)  # watched only with early stopping


# --- ensembles ----------------------------------------------------------------------------------------------------


@pytest.mark.slow  # fast tier trimmed (2026-11-27): the hybrid's gradients are checked fast
def test_ensembles_of_positions_fit_on_training_data_only(record):
    plants = [
        EMPSPlant(95.0, CoulombViscous(Fc=21.0, Fv=200.0, offset=-3.0)),
        EMPSPlant(95.0, CoulombViscous(Fc=19.0, Fv=205.0, offset=-3.0)),
        EMPSPlant(96.0, CoulombViscous(Fc=20.0, Fv=195.0, offset=-3.2)),
    ]
    train, other = fj.emps.split_emps_record(record, 0, 400), fj.emps.split_emps_record(record, 400)
    positions = EMPSEnsemble(plants).member_positions(train)
    average = fit_emps_ensemble(plants, train, "average").ensemble
    np.testing.assert_allclose(average.weights, [1 / 3] * 3)
    np.testing.assert_allclose(average.predict(train, positions), positions.mean(axis=0), rtol=1e-12)
    weighted = fit_emps_ensemble(plants, train, "lstsq")
    # the weights are the least-squares solution on the training record's scored samples, nothing else
    A = np.column_stack([np.ones(380), np.asarray(positions).T[20:]])
    coef = np.linalg.lstsq(A, train.qm[20:], rcond=None)[0]
    np.testing.assert_allclose(weighted.ensemble.weights, coef[1:], rtol=1e-6)
    assert float(weighted.ensemble.intercept) == pytest.approx(coef[0], abs=1e-9)
    # never worse than any member on the training record; the held-out part is only scored
    assert weighted.ensemble.score(train) <= min(fj.emps.score_emps_open_loop(p, train) for p in plants) + 1e-9
    assert np.isfinite(weighted.ensemble.score(other))
    nonnegative = fit_emps_ensemble(plants, train, "nonnegative", positions=positions).ensemble
    assert np.all(np.asarray(nonnegative.weights) >= 0)
    assert nonnegative.score(train) <= min(fj.emps.score_emps_open_loop(p, train) for p in plants) + 1e-9
    selected = fit_emps_ensemble(plants, train, "press", positions=positions)
    assert set(selected.indices) <= {0, 1, 2} and len(selected.press) == len(selected.indices) + 1
    with pytest.raises(ValueError, match="method"):
        fit_emps_ensemble(plants, train, "median")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="positions"):
        fit_emps_ensemble(plants, train, "lstsq", positions=np.zeros((2, 400)))


# --- the benchmark part (real data) -------------------------------------------------------------------------------


def run_emps_benchmark(data_dir, *args: str) -> list[dict]:
    """`benchmarks/emps.py ARGS` in a subprocess on the real data: its JSON lines."""
    env = {**os.environ, "FRICJAX_DATA": str(data_dir), "PYTHONPATH": str(ROOT / "src")}
    out = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "emps.py"), *args],
        capture_output=True,
        text=True,
        env=env,
        check=True,
        timeout=600,
    )
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


@pytest.mark.slow  # about 75 s
def test_benchmark_hybrid_smoke(data_dir):
    lines = run_emps_benchmark(data_dir, "--hybrid", "--smoke")
    kinds = {line["kind"] for line in lines}
    assert {"member", "bgbm", "bgbm_choice", "hybrid", "ensemble", "closed_loop", "total"} <= kinds
    for line in lines:
        if line["kind"] in ("hybrid", "ensemble", "bgbm", "bgbm_choice") and "error" not in line:
            assert {"name", "test_rmse_mm", "train_rmse_mm", "fit_s", "jax", "device"} <= set(line)
            assert np.isfinite(line["test_rmse_mm"]) and line["test_rmse_mm"] < 50.0
    closed = [line for line in lines if line["kind"] == "closed_loop"]
    assert all(line["test_position_pct"] < 0.01 for line in closed)


@pytest.mark.slow  # about 25 s
def test_benchmark_crossfile_diagnosis(data_dir):
    """`emps.py --crossfile`: the test file's plateau forces are higher in magnitude than the training file's in
    both directions (the change of friction that keeps training-file fits from 3 mm), a law fitted on either file scores
    better on it than on the other, and moving the training fit's Coulomb force by the plateau change helps on
    the test file."""
    lines = run_emps_benchmark(data_dir, "--crossfile", "--laws", "CoulombViscous")
    plateaus = [line for line in lines if line["kind"] == "plateau_force"]
    assert len(plateaus) == 4
    for line in plateaus:
        assert line["test_minus_train_N"] * np.sign(line["velocity_m_s"]) > 0.5  # more friction, both directions
        assert min(line["samples"]) > 1000
        assert line["test_pulse_off_minus_train_N"] * np.sign(line["velocity_m_s"]) > 0.5  # not the pulses'
        # the pulse is on half the time, and 300 ms after it count as on: far fewer samples than the whole plateau
        assert 300 < line["test_pulse_off_samples"] < 0.4 * line["samples"][1]
    (shift,) = [line for line in lines if line["kind"] == "plateau_shift"]
    assert 1.0 < shift["delta_Fc_N"] < 1.6
    assert shift["test_rmse_mm"] < 0.6 * shift["unshifted_test_rmse_mm"]
    assert shift["train_rmse_mm"] > shift["unshifted_train_rmse_mm"]
    crossfile = {(line["name"], line["fitted_on"]): line for line in lines if line["kind"] == "crossfile"}
    assert len(crossfile) == 4 and not any(line["used_for_choice"] for line in crossfile.values())
    for name in ("CoulombViscous", "CoulombViscous-asym"):
        on_train, on_test = crossfile[(name, "DATA_EMPS")], crossfile[(name, "DATA_EMPS_PULSES")]
        assert on_train["train_rmse_mm"] < on_test["train_rmse_mm"]
        assert on_test["test_rmse_mm"] < on_train["test_rmse_mm"]
