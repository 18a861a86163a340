"""Issue 55, item 3: an input that is a copy of the output. A normal-load column that follows the friction force
itself (the damper's actuator forces: its drive, |correlation| 0.98-0.998 with |F|) is refused by compare before
any fit, with the reason and the option that overrides it; `fj.load_record` warns; the command line never suggests
such a column as the normal load."""

from __future__ import annotations

import re

import numpy as np
import pytest

import fricjax as fj

DAMPER = "damper/dataset-2/characterization_tests/0.25Hz36lbtension1amplitude.npz"
ACTUATORS = ["actuator_force1_lb", "actuator_force2_lb"]


def _record(path, leaky: bool):
    """A CSV record with a legitimate normal load (a slow, independent swing) and a drive force that follows the
    friction force (the friction plus an inertia term and noise)."""
    rng = np.random.default_rng(0)
    t = np.arange(3000) * 1e-3
    x = 1e-3 * np.sin(2 * np.pi * 2 * t)
    v = np.gradient(x, t)
    force = np.tanh(v / 1e-3) + 0.05 * rng.standard_normal(t.size)
    load = 10 + 2 * np.sin(2 * np.pi * 0.3 * t + 1.0)
    drive = force + 0.02 * np.gradient(v, t) + 0.02 * rng.standard_normal(t.size)
    columns = [t, x, force, drive if leaky else load, load]
    np.savetxt(path, np.c_[tuple(columns)], delimiter=",", header="t,x,force,drive_force,clamp_load", comments="")
    return path


def test_a_load_that_follows_the_force_is_refused_before_any_fit(tmp_path, capsys):
    path = _record(tmp_path / "leaky.csv", leaky=True)
    with pytest.warns(
        UserWarning, match=r"'drive_force' follows the friction force itself \(\|correlation\| (0\.9|1\.0)"
    ):
        data = fj.load_record(path, normal_force_column="drive_force")
    assert data.motion.normal_force is not None  # a warning, not an error: the library's user decides
    out = tmp_path / "out"
    code = fj.main(["compare", "--data", str(path), "--normal-force-column", "drive_force", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists(), err
    assert "its normal load follows the friction force itself" in err and "--accept-correlated-load" in err
    assert "Traceback" not in err and "warning" not in err.lower().split("error")[0], err
    # a load that does not follow the force is taken as it is
    fj.load_record(_record(tmp_path / "fine.csv", leaky=False), normal_force_column="drive_force")


@pytest.mark.slow  # two short compare runs (~40 s)
def test_the_command_line_suggests_only_a_checked_load_column(tmp_path, capsys):
    path = _record(tmp_path / "leaky.csv", leaky=True)
    common = ["compare", "--data", str(path), "--models", "stribeck", "--steps", "2", "--no-progress"]
    assert fj.main([*common, "--out", str(tmp_path / "a")]) == 0
    printed = capsys.readouterr().out
    suggested = [line for line in printed.splitlines() if "name them with --normal-force-column" in line]
    assert suggested and "'clamp_load'" in suggested[0] and "drive_force" not in suggested[0], printed
    assert re.search(r"'drive_force' \((0\.9|1\.0)", printed) and "follow the friction force" in printed, printed
    # the override: the user says the correlated column truly is the load
    code = fj.main(
        [*common, "--normal-force-column", "drive_force", "--accept-correlated-load", "--out", str(tmp_path / "b")]
    )
    assert code == 0, capsys.readouterr().err


def test_the_dampers_actuator_forces_follow_its_friction_force(data_dir):
    """On the damper's records the actuator forces (the drive) follow the friction force: named as the normal load
    they are warned about (compare refuses them the same way)."""
    path = data_dir / DAMPER
    if not path.exists():
        pytest.skip(f"{path}: not in this data folder")
    with pytest.warns(UserWarning, match=r"follows the friction force itself \(\|correlation\| 0\.9[5-9]"):
        fj.load_record(path, normal_force_column=ACTUATORS)
