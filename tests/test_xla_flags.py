"""`import fricjax` makes XLA:CPU compile small scans as one function (the small-while-loop threshold in XLA_FLAGS),
keeps the user's own XLA flags, and can be turned off (src/fricjax/_xla_flags.py; benchmarks/README.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import pytest

import fricjax  # noqa: F401  (imported before any computation, as conftest does: the setting applies here)

KEY = "xla_cpu_small_while_loop_byte_threshold"
SCHEDULER = "xla_cpu_enable_concurrency_optimized_scheduler"

# run in a fresh interpreter: XLA reads XLA_FLAGS once, when JAX starts its backends. The scan carries 64 values:
# a loop body touching more than 1 024 bytes, which XLA by default runs op by op
SCAN = "lambda x: jax.lax.scan(lambda s, u: (jnp.sin(s) + u, (s.sum(), s)), jnp.zeros(64), x)"
PROBE = f"""
import json, os, sys, warnings
warnings.simplefilter("always")
import jax, jax.numpy as jnp
if sys.argv[1] == "started":
    jnp.ones(2).block_until_ready()  # JAX's backends start before fricjax is imported
with warnings.catch_warnings(record=True) as caught:
    import fricjax
hlo = jax.jit({SCAN}).lower(jnp.ones(4000)).compile().as_text()
print(json.dumps({{"flags": os.environ.get("XLA_FLAGS", ""), "one_function": "xla_cpu_small_call" in hlo,
                  "devices": jax.device_count(), "warnings": [str(w.message) for w in caught]}}))
"""


def _probe(
    xla_flags: str,
    *,
    started: bool = False,
    keep: bool = False,
    host_devices: str | None = None,
    cgroup_root: str | None = None,
) -> dict:
    unset = ("XLA_FLAGS", "FRICJAX_KEEP_XLA_FLAGS", "FRICJAX_HOST_DEVICES", "FRICJAX_CGROUP_ROOT")
    env = {k: v for k, v in os.environ.items() if k not in unset}
    env.update(JAX_PLATFORMS="cpu", XLA_FLAGS=xla_flags)
    if cgroup_root is not None:
        env["FRICJAX_CGROUP_ROOT"] = cgroup_root
    if keep:
        env["FRICJAX_KEEP_XLA_FLAGS"] = "1"
    if host_devices is not None:
        env["FRICJAX_HOST_DEVICES"] = host_devices
    result = subprocess.run(
        [sys.executable, "-c", PROBE, "started" if started else "fresh"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return json.loads(result.stdout.strip().splitlines()[-1])


def _hlo_of_a_scan_stacking_its_states() -> str:
    return jax.jit(eval(SCAN)).lower(jnp.ones(4000)).compile().as_text()


def test_this_process_compiles_a_scan_with_stacked_states_into_one_function():
    assert KEY in os.environ["XLA_FLAGS"]
    assert f"--{SCHEDULER}=false" in os.environ["XLA_FLAGS"].split()  # tests/test_solvers.py: one answer per call
    assert "xla_cpu_small_call" in _hlo_of_a_scan_stacking_its_states()


@pytest.mark.slow  # a few seconds (a subprocess or a fit): the fast tier stays under 5 minutes
def test_the_users_flags_are_kept_and_extra_options_merged():
    out = _probe("--xla_backend_extra_options=xla_cpu_disable_loop_unrolling --xla_force_host_platform_device_count=2")
    assert f"--xla_backend_extra_options=xla_cpu_disable_loop_unrolling,{KEY}=" in out["flags"]
    assert out["flags"].split().count(f"--{SCHEDULER}=false") == 1
    assert out["flags"].count("--xla_backend_extra_options") == 1
    assert out["devices"] == 2 and out["one_function"] and out["warnings"] == []


@pytest.mark.slow  # a few seconds (a subprocess or a fit): the fast tier stays under 5 minutes
def test_opting_out_leaves_xla_flags_alone_and_xla_its_default():
    out = _probe("--xla_force_host_platform_device_count=2", keep=True)
    assert out["flags"] == "--xla_force_host_platform_device_count=2"
    assert not out["one_function"]  # XLA's own default threshold: the scan runs op by op
    own = _probe(f"--xla_backend_extra_options={KEY}=1024 --{SCHEDULER}=true", host_devices="1")  # the user's own
    assert own["flags"] == f"--xla_backend_extra_options={KEY}=1024 --{SCHEDULER}=true" and not own["one_function"]


@pytest.mark.slow  # three subprocesses (~2 s each)
def test_every_core_is_a_host_device_unless_the_user_says_otherwise(tmp_path):
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    default = _probe("", cgroup_root=str(tmp_path))  # no cgroup files there: no quota
    assert default["devices"] == max(1, min(cores, 8)) and default["one_function"]
    assert _probe("", host_devices="3")["devices"] == 3
    assert _probe("--xla_force_host_platform_device_count=5", host_devices="3")["devices"] == 5  # the user's flag
    assert _probe("", host_devices="1")["devices"] == 1
    with pytest.raises(subprocess.CalledProcessError) as error:
        _probe("", host_devices="many")
    assert "FRICJAX_HOST_DEVICES='many': expected a whole number" in error.value.stderr


@pytest.mark.slow  # subprocesses (~2 s each): the fast tier stays well under 5 minutes
def test_a_cgroup_cpu_quota_caps_the_host_devices(tmp_path):
    """A container limited to fewer CPUs than its affinity shows (`docker --cpus`) gets one device per allowed CPU:
    cgroup v2's `cpu.max`, cgroup v1's `cfs_quota_us` / `cfs_period_us`; "max" or -1 is no quota."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    every = max(1, min(cores, 8))
    v2, v1 = tmp_path / "v2", tmp_path / "v1" / "cpu"
    v2.mkdir()
    v1.mkdir(parents=True)
    (v1 / "cpu.cfs_period_us").write_text("100000\n")
    for text, expected in (("100000 100000\n", 1), ("max 100000\n", every), ("150000 100000\n", min(2, every))):
        (v2 / "cpu.max").write_text(text)
        assert _probe("", cgroup_root=str(v2))["devices"] == expected, text
    for quota, expected in (("100000", 1), ("-1", every)):
        (v1 / "cpu.cfs_quota_us").write_text(quota + "\n")
        assert _probe("", cgroup_root=str(tmp_path / "v1"))["devices"] == expected, quota


@pytest.mark.slow  # a subprocess (~2 s): the fast tier stays well under 5 minutes
def test_importing_fricjax_after_jax_started_warns_how_to_fix_it():
    out = _probe("", started=True)
    assert not out["one_function"]
    assert len(out["warnings"]) == 1 and "Import fricjax before the first JAX computation" in out["warnings"][0]
