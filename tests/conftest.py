"""Shared test set-up: float64 everywhere, data location, and the model table every battery test crosses."""

import os
import pathlib

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import pytest  # noqa: E402

DATA_DIR = os.environ.get("FRICJAX_DATA", str(pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"))


@pytest.fixture(scope="session")
def data_dir() -> pathlib.Path:
    path = pathlib.Path(DATA_DIR)
    if not path.is_dir():
        pytest.skip(f"real data not found at {path}; set FRICJAX_DATA to the shared/data folder")
    return path


@pytest.fixture(scope="session")
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def train(data_dir):
    """The EMPS estimation record (DATA_EMPS.mat)."""
    from fricjax import load_emps

    return load_emps(data_dir / "emps" / "DATA_EMPS.mat")


@pytest.fixture(scope="session")
def test_record(data_dir):
    """The EMPS test record (DATA_EMPS_PULSES.mat)."""
    from fricjax import load_emps

    return load_emps(data_dir / "emps" / "DATA_EMPS_PULSES.mat")
