"""The Bouc-Wen benchmark (Noël & Schoukens 2016): loader, ground-truth system, loss and protocol.

The real-data tests read `$FRICJAX_DATA/boucwen` (see `shared/data/README.md`, section 2) and skip when the data
folder is missing.
"""

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate

from fricjax import (
    BOUCWEN_DT,
    BOUCWEN_PERIOD,
    BoucWen,
    BoucWenRecord,
    boucwen_inputs,
    fit,
    levenberg_marquardt,
    load_boucwen,
    load_model,
    save_model,
    simulate,
)
from fricjax.boucwen import (
    BoucWenLoss,
    boucwen_rmse,
    score_boucwen,
)

PUBLISHED = {"m": 2.0, "c": 10.0, "k": 5e4, "alpha": 5e4, "beta": 1e3, "gamma": 0.8, "delta": -1.1, "nu": 1.0}


@pytest.fixture(scope="module")
def data(data_dir):
    return load_boucwen(data_dir / "boucwen")


# --- loading ------------------------------------------------------------------------------------------------------


def test_load_boucwen_shapes(data):
    assert (data.train.length, data.multisine.length, data.sinesweep.length) == (40960, 8192, 153000)
    for record in data:
        assert record.dt == BOUCWEN_DT == 1 / 750
        assert record.u.shape == record.y.shape and record.u.dtype == np.float64
        assert os.path.exists(record.source.split(",")[0])
    assert np.isclose(np.std(data.multisine.u), 50.0, rtol=1e-3)
    assert np.isclose(np.sqrt(np.mean(data.multisine.y**2)), 6.67e-4, rtol=1e-2)
    assert data.train.length == 5 * BOUCWEN_PERIOD


def test_load_boucwen_default_path_and_errors(data_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("FRICJAX_DATA", str(data_dir))
    assert load_boucwen().multisine.length == 8192
    monkeypatch.setenv("FRICJAX_DATA", str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError, match="FRICJAX_DATA"):
        load_boucwen()
    with pytest.raises(FileNotFoundError, match="FRICJAX_DATA"):
        load_boucwen(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match="uval_multisine.mat"):
        load_boucwen(tmp_path)
    (tmp_path / "uval_multisine.mat").write_text("not a mat file")
    with pytest.raises(ValueError, match="MATLAB"):
        load_boucwen(tmp_path)


# --- the ground-truth system --------------------------------------------------------------------------------------


def scipy_reference(u: np.ndarray, dt: float) -> np.ndarray:
    """An independent solution: DOP853 at tight tolerance, the force linear between samples, nu = 1."""
    p = PUBLISHED
    t_samples = np.arange(len(u)) * dt

    def rhs(t, x):
        y, v, z = x
        force = np.interp(t, t_samples, u)
        dz = p["alpha"] * v - p["beta"] * (p["gamma"] * abs(v) * z + p["delta"] * v * abs(z))
        return [v, (force - p["c"] * v - p["k"] * y - z) / p["m"], dz]

    sol = scipy.integrate.solve_ivp(
        rhs, (0, t_samples[-1]), [0, 0, 0], method="DOP853", t_eval=t_samples, rtol=1e-11, atol=1e-14, max_step=dt / 4
    )
    return sol.y[0]


def test_boucwen_matches_independent_integrator():
    rng = np.random.default_rng(0)
    u = 60 * np.convolve(rng.standard_normal(160), np.ones(4) / 4, mode="same")
    y = np.asarray(simulate(BoucWen(**PUBLISHED, substeps=20), boucwen_inputs(u)))
    reference = scipy_reference(u, BOUCWEN_DT)
    assert np.max(np.abs(y - reference)) < 1e-4 * np.max(np.abs(reference))


def test_boucwen_reproduces_official_test_outputs(data):
    """The data are noise-free: the published system reproduces them (to 7.3e-6 m; the anchors are 1.87e-5 m)."""
    model = BoucWen.benchmark()
    multisine, prediction = boucwen_rmse(model, data.multisine, periods=3)
    assert multisine < 8e-6 and prediction.shape == (8192,)
    head = BoucWenRecord(data.sinesweep.u[:15000], data.sinesweep.y[:15000], BOUCWEN_DT, "head", "")
    assert boucwen_rmse(model, head)[0] < 8e-6


def test_boucwen_errors_and_serialise(tmp_path):
    with pytest.raises(ValueError, match="substeps"):
        BoucWen(**PUBLISHED, substeps=0)
    with pytest.raises(ValueError, match="`m`"):
        BoucWen(**{**PUBLISHED, "m": -1.0})
    with pytest.raises(ValueError, match="u"):
        boucwen_inputs(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="burn_in"):
        BoucWenLoss(burn_in=-1)
    model = BoucWen(**PUBLISHED, substeps=3)
    save_model(tmp_path / "bw.eqx", model)
    again = load_model(tmp_path / "bw.eqx")
    u = np.sin(np.linspace(0, 20, 100)) * 30
    np.testing.assert_allclose(simulate(again, boucwen_inputs(u)), simulate(model, boucwen_inputs(u)))


@pytest.mark.slow  # fast tier trimmed (2026-11-27): jit and vmap of every model run fast in test_battery.py
def test_boucwen_jit_and_vmap():
    u = jnp.asarray(np.sin(np.linspace(0, 20, 80)) * 30)
    model = BoucWen(**PUBLISHED, substeps=2)
    eager = simulate(model, boucwen_inputs(u))
    jitted = jax.jit(lambda m: simulate(m, boucwen_inputs(u)))(model)
    np.testing.assert_allclose(jitted, eager, rtol=1e-12, atol=1e-15)
    alphas = jnp.array([4e4, 5e4])
    batched = jax.vmap(lambda a: simulate(BoucWen(**{**PUBLISHED, "alpha": a}, substeps=2), boucwen_inputs(u)))(alphas)
    np.testing.assert_allclose(batched[1], eager, rtol=1e-12, atol=1e-15)


@pytest.mark.slow
def test_grey_box_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    u = 50 * rng.standard_normal(60)
    y = np.asarray(simulate(BoucWen(**PUBLISHED, substeps=2), boucwen_inputs(u)))
    record = BoucWenRecord(u, y, BOUCWEN_DT, "synthetic", "")
    names = list(PUBLISHED)
    start = np.array([2.2, 12.0, 5.5e4, 4.5e4, 1.2e3, 0.7, -1.0, 1.1])

    @jax.jit
    def loss(theta):
        model = BoucWen(**dict(zip(names, theta, strict=True)), substeps=2)
        return BoucWenLoss()(model, None, record)

    grad = np.asarray(jax.grad(loss)(jnp.asarray(start)))
    for i in range(len(names)):
        h = 1e-6 * abs(start[i])
        up, down = start.copy(), start.copy()
        up[i] += h
        down[i] -= h
        fd = (float(loss(jnp.asarray(up))) - float(loss(jnp.asarray(down)))) / (2 * h)
        assert np.isclose(grad[i], fd, rtol=1e-4, atol=1e-9 * np.max(np.abs(grad * start)) / abs(start[i])), names[i]


@pytest.mark.slow
def test_grey_box_fit_recovers_parameters():
    """Output-error fit through fj.fit on a noise-free synthetic record, from a start 10-20 % off."""
    rng = np.random.default_rng(2)
    u = 50 * np.convolve(rng.standard_normal(600), np.ones(3) / 3, mode="same")
    y = np.asarray(simulate(BoucWen(**PUBLISHED, substeps=2), boucwen_inputs(u)))
    record = BoucWenRecord(u, y, BOUCWEN_DT, "synthetic", "")
    start = BoucWen(m=2.2, c=12.0, k=5.5e4, alpha=4.5e4, beta=1.2e3, gamma=0.7, delta=-1.0, nu=1.0, substeps=2)
    result = fit(start, record, loss=BoucWenLoss(), solver=levenberg_marquardt(), steps=40, freeze=("nu",))
    assert float(result.train_loss) < 1e-8


# --- the benchmark ------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_score_boucwen_true_model(data):
    scores = score_boucwen(BoucWen.benchmark(), data.multisine, data.sinesweep)
    assert scores.multisine < 8e-6 and scores.sinesweep < 6e-6


@pytest.mark.slow
def test_benchmark_smoke(data_dir):
    root = pathlib.Path(__file__).resolve().parents[1]
    env = {**os.environ, "FRICJAX_DATA": str(data_dir), "PYTHONPATH": str(root / "src")}
    out = subprocess.run(
        [sys.executable, str(root / "benchmarks" / "boucwen.py"), "--smoke"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=True,
    )
    lines = [line for line in out.stdout.splitlines() if line.startswith("{")]
    assert len(lines) == 9 and all('"kind": "boucwen"' in line for line in lines)
    names = [json.loads(line)["name"] for line in lines]
    assert any(name.startswith("MLP NARX") for name in names) and any(name.startswith("GSNN") for name in names)
    assert sum(name.startswith("oscillator + ") for name in names) == 3
    assert all(np.isfinite(json.loads(line)["test_rmse_m"]) for line in lines)
