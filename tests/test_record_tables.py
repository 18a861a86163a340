"""Records as NPZ tables (`data` + `columns`) with units as name suffixes, the normal load, and the velocity check:
the friction-damper records of `$FRICJAX_DATA/damper` (see `shared/data/README.md`, section 3; skipped when the
folder is missing) and synthetic tables for each error."""

from __future__ import annotations

import numpy as np
import pytest

import fricjax as fj
from fricjax.compare import load_split

INCH = 0.0254  # m
KIP = 4448.2216152605  # N
LBF = 4.4482216152605  # N
DAMPER_DT = 1 / 1024
ACTUATORS = ("actuator_force1_lb", "actuator_force2_lb")

N = 400
DT = 1e-3
K = np.arange(N)
X = np.sin(2 * np.pi * K / 200)  # two periods, in the file's displacement unit
V = np.gradient(X, DT)  # its rate of change, in the displacement unit per second
F = np.cos(2 * np.pi * K / 200)


def _damper_files(data_dir, folder):
    path = data_dir / "damper" / folder
    files = sorted(path.glob("*.npz"))
    if not files:
        pytest.skip(f"damper records not found in {path}")
    return files


def _raw(path):
    with np.load(path) as archive:
        return dict(zip(archive["columns"].tolist(), archive["data"].T, strict=True))


def _table(path, **columns):
    np.savez(path, data=np.column_stack(list(columns.values())), columns=np.array(list(columns)), meta_json="{}")
    return path


def _rms(signal):
    return float(np.sqrt(np.mean(np.square(signal))))


def _card(path):
    """The columns used and ignored and the units `read_record` reports (through the compare data card)."""
    card = load_split(str(path))[1]
    return card["columns"], tuple(card["ignored"]), card["units"]


# --- the damper records --------------------------------------------------------------------------------------------


def test_damper_characterization_records_in_si(data_dir):
    files = _damper_files(data_dir, "dataset-3/characterization_tests")
    assert len(files) == 10
    for path in files:
        raw = _raw(path)
        data = fj.load_record(path, normal_force_column=ACTUATORS)  # the file's velocity agrees with x
        motion = data.motion
        assert float(motion.dt) == DAMPER_DT and data.length == raw["time_s"].size, path.name
        np.testing.assert_allclose(motion.x, raw["displacement_in"] * INCH, rtol=1e-12)
        np.testing.assert_allclose(data.force, raw["friction_force_kip"] * KIP, rtol=1e-12)
        np.testing.assert_allclose(motion.v, raw["velocity_in_per_s"] * INCH, rtol=1e-12)
        derived = np.gradient(np.asarray(motion.x), DAMPER_DT)
        assert 0.98 < _rms(motion.v) / _rms(derived) < 1.02, path.name
        normal = (raw["actuator_force1_lb"] + raw["actuator_force2_lb"]) * LBF
        np.testing.assert_allclose(motion.normal_force, normal, rtol=1e-12)
        assert 2000 < float(np.mean(normal)) < 6000, path.name  # two actuators of a few hundred lb each
    columns, ignored, units = _card(files[0])
    assert columns == {"t": "time_s", "x": "displacement_in", "force": "friction_force_kip", "v": "velocity_in_per_s"}
    assert ignored == ("actuator_force1_lb", "actuator_force2_lb", "meta_json") and units == {"x": "in", "force": "kip"}


def test_damper_semi_active_records_need_the_velocity_derived(data_dir):
    files = _damper_files(data_dir, "dataset-4")
    assert len(files) == 12
    for path in files:
        with pytest.raises(fj.RecordError, match=r"'velocity_in_per_s' disagrees with .*'displacement_in': it is "):
            fj.load_record(path)
        raw = _raw(path)
        data = fj.load_record(path, velocity="derive", normal_force_column=list(ACTUATORS))
        x = raw["displacement_in"] * INCH
        np.testing.assert_allclose(data.motion.x, x, rtol=1e-12)
        np.testing.assert_allclose(data.motion.v, np.gradient(x, DAMPER_DT), rtol=1e-9, atol=1e-12)
        ratio = _rms(raw["velocity_in_per_s"] * INCH) / _rms(data.motion.v)
        assert ratio == pytest.approx(1 / 125.4, rel=0.01), path.name  # the README's caveat
        normal = (raw["actuator_force1_lb"] + raw["actuator_force2_lb"]) * LBF
        np.testing.assert_allclose(data.motion.normal_force, normal, rtol=1e-12)
    data = fj.load_record(files[0], velocity="file")  # taken as written, unchecked
    np.testing.assert_allclose(data.motion.v, _raw(files[0])["velocity_in_per_s"] * INCH, rtol=1e-12)
    assert data.motion.normal_force is None  # no column named for it, none found by its name


# --- synthetic tables ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "names, x_factor, force_factor, time_factor",
    [
        (("time_s", "displacement_in", "friction_force_kip", "velocity_in_per_s"), INCH, KIP, 1.0),
        (("t_ms", "x_um", "F_kN", "v_um_per_s"), 1e-6, 1e3, 1e-3),
        (("time", "position_mm", "force_lb", "vel_mm/s"), 1e-3, LBF, 1.0),
        (("t [us]", "x [nm]", "force (mN)", "v [nm/s]"), 1e-9, 1e-3, 1e-6),  # brackets in table columns
    ],
)
def test_unit_suffixes_and_brackets_give_si(tmp_path, names, x_factor, force_factor, time_factor):
    scale = 1 / time_factor  # the time column counts in its own unit; the velocity is per second
    path = _table(tmp_path / "r.npz", **dict(zip(names, (K * DT * scale, X, F, V), strict=True)))
    data = fj.load_record(path)
    assert float(data.motion.dt) == pytest.approx(DT)
    np.testing.assert_allclose(data.motion.x, x_factor * X, rtol=1e-12)
    np.testing.assert_allclose(data.motion.v, x_factor * V, rtol=1e-12)
    np.testing.assert_allclose(data.force, force_factor * F, rtol=1e-12)
    columns, ignored, _ = _card(path)
    assert columns == dict(zip(("t", "x", "force", "v"), names, strict=True)) and ignored == ("meta_json",)


def test_unknown_unit_suffix_is_part_of_the_name(tmp_path):
    path = _table(tmp_path / "r.npz", t=K * DT, x_furlong=X, x_mm=X, force_filtered=F, F_N=F, F_MN=F)
    data = fj.load_record(path)  # `MN` is not a unit (case-sensitive); `furlong` is none
    np.testing.assert_allclose(data.motion.x, 1e-3 * X)
    columns, ignored, _ = _card(path)
    assert columns == {"t": "t", "x": "x_mm", "force": "F_N"}
    assert ignored == ("x_furlong", "force_filtered", "F_MN", "meta_json")
    only_unknown = _table(tmp_path / "u.npz", t=K * DT, displacement_furlong=X, force=F)
    with pytest.raises(fj.RecordError, match=r"need a displacement column 'x'"):
        fj.load_record(only_unknown)


def test_inconsistent_velocity_is_named_and_fixed_by_the_keyword(tmp_path):
    path = _table(tmp_path / "r.npz", time_s=K * DT, displacement_in=X, velocity_in_per_s=V / 125.4, force=F)
    with pytest.raises(fj.RecordError) as caught:
        fj.load_record(path)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(str(path))
    assert "'velocity_in_per_s' disagrees with displacement column 'displacement_in'" in message
    assert "it is 0.00797 times" in message and "velocity='derive'" in message and "drop the velocity" in message
    derived = fj.load_record(path, velocity="derive")
    np.testing.assert_allclose(derived.motion.v, INCH * V, rtol=1e-12)
    np.testing.assert_allclose(fj.load_record(path, velocity="file").motion.v, INCH * V / 125.4, rtol=1e-12)
    flipped = _table(tmp_path / "f.npz", t=K * DT, x=X, v=-V, force=F)
    with pytest.raises(fj.RecordError, match=r"it is -1 times"):
        fj.load_record(flipped)
    noisy = _table(tmp_path / "n.npz", t=K * DT, x=X + 1e-3 * np.random.default_rng(0).standard_normal(N), v=V, force=F)
    np.testing.assert_allclose(fj.load_record(noisy).motion.v, V)  # noise on x does not hide an agreeing v
    only_v = _table(tmp_path / "v.npz", t=K * DT, v=V, force=F)
    with pytest.raises(
        fj.RecordError, match=r"velocity='derive' \(--velocity derive\) needs a displacement column .* only 'v'"
    ):
        fj.load_record(only_v, velocity="derive")
    with pytest.raises(fj.RecordError, match=r"velocity must be 'auto', 'file' or 'derive', got 'measured'"):
        fj.load_record(path, velocity="measured")


def test_normal_force_by_name_and_by_column_names(tmp_path):
    path = _table(tmp_path / "r.npz", t=K * DT, x=X, force_kN=F, normal_force_lb=np.full(N, 10.0))
    np.testing.assert_allclose(fj.load_record(path).motion.normal_force, np.full(N, 10 * LBF))
    assert _card(path)[0]["normal_force"] == "normal_force_lb"
    for name in ("N", "normal", "Normal_Load"):  # the aliases; without a unit, the friction force's unit
        data = fj.load_record(_table(tmp_path / "a.npz", t=K * DT, x=X, force_kN=F, **{name: np.full(N, 2.0)}))
        np.testing.assert_allclose(data.motion.normal_force, np.full(N, 2e3))
    path = _table(tmp_path / "n.npz", t=K * DT, x=X, force=F, n=K)  # `n`: a sample index
    assert fj.load_record(path).motion.normal_force is None and _card(path)[1] == ("n", "meta_json")
    # named columns are summed, each in its own unit, the name matched case-insensitively; they win over an alias
    path = _table(tmp_path / "s.npz", t=K * DT, x=X, F=F, press_a_lb=np.full(N, 1.0), press_b=np.full(N, 3.0), N=K)
    data = fj.load_record(path, normal_force_column=["PRESS_A_lb", "press_b"], force_unit="kN")
    np.testing.assert_allclose(data.motion.normal_force, np.full(N, LBF + 3e3))
    # a CSV file, one name as a string
    csv = tmp_path / "r.csv"
    np.savetxt(csv, np.c_[K * DT, X, F, np.full(N, 5.0)], delimiter=",", header="t,x_mm,F,clamp [kN]", comments="")
    data = fj.load_record(csv, normal_force_column="clamp [kN]")
    np.testing.assert_allclose(data.motion.normal_force, np.full(N, 5e3))
    np.testing.assert_allclose(data.motion.x, 1e-3 * X)


def test_normal_force_errors_name_the_file_the_column_and_the_columns_found(tmp_path):
    path = _table(tmp_path / "r.npz", time_s=K * DT, x=X, force=F, actuator_force1_lb=np.ones(N))
    with pytest.raises(fj.RecordError) as caught:
        fj.load_record(path, normal_force_column=("actuator_force1_lb", "actuator_force2_lb"))
    message = str(caught.value)
    assert message == (
        f"{path}: no column 'actuator_force2_lb' for the normal force (normal_force_column, --normal-force-column); "
        "found: 'time_s', 'x', 'force', 'actuator_force1_lb', 'meta_json'"
    )
    with pytest.raises(fj.RecordError, match=r"column 'force' gives 'force'; it cannot also be the normal force"):
        fj.load_record(path, normal_force_column="force")
    with pytest.raises(fj.RecordError, match=r"names 'x1' twice"):
        fj.load_record(path, normal_force_column=("x1", "X1"))
    with pytest.raises(fj.RecordError, match=r"normal_force_column must be a column name"):
        fj.load_record(path, normal_force_column=())
    bad = _table(tmp_path / "b.npz", t=K * DT, x=X, force=F, **{"normal [furlong]": np.ones(N)})
    with pytest.raises(fj.RecordError, match=r"unknown normal force unit 'furlong'"):
        fj.load_record(bad)


def test_table_shape_errors_and_plain_keys_beside_a_table(tmp_path):
    path = tmp_path / "r.npz"
    np.savez(path, data=np.c_[K * DT, X, F], columns=np.array(["t", "x"]))
    with pytest.raises(fj.RecordError, match=r"'data' has 3 columns but 'columns' names 2; give one name per column"):
        fj.load_record(path)
    np.savez(path, data=np.c_[K * DT, X], columns=np.array(["t", "x"]), force=F)  # a key beside the table
    np.testing.assert_allclose(fj.load_record(path).force, F)
    np.savez(path, data=np.c_[K * DT, X, F], columns=np.array(["t", "x", "x_m"]))
    with pytest.raises(fj.RecordError, match=r"columns 'x' and 'x_m' both give 'x'"):
        fj.load_record(path)


def test_splits_and_joins_keep_the_normal_force(tmp_path):
    normal = 1.0 + K / N
    data = fj.load_record(_table(tmp_path / "r.npz", t=K * DT, x=X, force=F, normal_force=normal))
    first, second = data.split(0.5)
    np.testing.assert_allclose(second.motion.normal_force, normal[N // 2 :])
    np.testing.assert_allclose(fj.concatenate([first, second]).motion.normal_force, normal)
