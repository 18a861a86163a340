"""Shared test set-up: float64 everywhere, data location, and the model table every battery test crosses."""

import os
import pathlib

# The command line's persistent compilation cache stays off in the test process and its subprocesses: one in-process
# `fj.main(["compare", ...])` would turn it on for the rest of the session, writing every program the session compiles
# into the user's ~/.cache/fricjax (a cold cache's writes cost the fast tier 70-90 s). The tests of the cache itself
# drop this variable for their subprocesses.
os.environ.setdefault("FRICJAX_NO_CACHE", "1")
# One host device: the tests compile thousands of small programs, and with one device per core (fricjax's default,
# src/fricjax/_xla_flags.py) the batches of 32 and more rows compile as partitioned programs, which takes longer (fast
# tier 369 s against 340 s, cold, 2 cores). tests/test_xla_flags.py runs the default
# in subprocesses, tests/test_sharding.py several forced devices.
os.environ.setdefault("FRICJAX_HOST_DEVICES", "1")

import jax  # noqa: E402

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


# Linux refuses a process more than vm.max_map_count (65,530 by default) memory mappings, and XLA:CPU maps every
# compiled executable's code separately: the slow tier compiles thousands of programs, and once the count neared
# the limit the compiler died with SIGSEGV inside backend_compile. Compiled code is therefore released after each
# module that leaves the process above 40 % of the limit, and after any test that leaves it above half. (At a quarter
# the whole fast tier released once, after test_parallel_scan.py at 17 400 mappings: 5 s of clearing, and the later
# modules compiled again what they shared with the earlier ones.)
_MAP_LIMIT_SHARE = 0.5
_MAP_LIMIT_SHARE_AFTER_MODULE = 0.4


def _map_limit() -> int:
    try:
        return int(pathlib.Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 65530


def _mapping_count() -> int:
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:  # not Linux: no such limit to keep clear of
        return 0


def _release_compiled_code() -> None:
    import gc

    jax.clear_caches()
    gc.collect()


@pytest.fixture(autouse=True)
def _keep_clear_of_the_mapping_limit():
    yield
    if _mapping_count() > _MAP_LIMIT_SHARE * _map_limit():
        _release_compiled_code()


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_code_after_each_module():
    """Drop JAX's compilation caches after a test module that leaves many mappings (see `_MAP_LIMIT_SHARE`)."""
    yield
    if _mapping_count() > _MAP_LIMIT_SHARE_AFTER_MODULE * _map_limit():
        _release_compiled_code()
