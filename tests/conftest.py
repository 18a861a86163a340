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
