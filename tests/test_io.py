"""Reading records: column aliases, units in the header / NPZ / arguments (SI inside), extra NPZ keys, `dt=`."""

from __future__ import annotations

import numpy as np
import pytest

import fricjax as fj
from fricjax.compare import load_split

N = 150
DT = 1e-3
T = np.arange(N) * DT
X = np.sin(np.arange(N) / 20)  # in the file's displacement unit
F = np.cos(np.arange(N) / 20)  # in the file's force unit


def _csv(path, header, *columns, encoding="utf-8"):
    rows = "\n".join(",".join(f"{value:.12g}" for value in row) for row in np.column_stack(columns))
    path.write_text(header + "\n" + rows + "\n", encoding=encoding)
    return path


@pytest.mark.parametrize(
    "header",
    [
        "t,x,F",
        "t,x,Friction",
        "t,x,friction_force",
        "t,Position,force",
        "t,displacement,force",
        "t, pos ,force",
        "time,x,force",
        "Time,x,force",
    ],
)
def test_every_alias_of_time_displacement_and_force(tmp_path, header):
    data = fj.load_record(_csv(tmp_path / "r.csv", header, T, X, F))
    assert data.length == N and float(data.motion.dt) == pytest.approx(DT)
    np.testing.assert_allclose(data.motion.x, X)
    np.testing.assert_allclose(data.force, F)


@pytest.mark.parametrize("name", ["velocity", "Vel"])
def test_velocity_aliases(tmp_path, name):
    data = fj.load_record(_csv(tmp_path / "r.csv", f"t,{name},force", T, X, F))
    np.testing.assert_allclose(data.motion.v, X)


def test_units_in_csv_header_brackets_give_si(tmp_path):
    data = fj.load_record(_csv(tmp_path / "r.csv", "t [s],x [um],force (kN)", T, X, F))
    np.testing.assert_allclose(data.motion.x, 1e-6 * X)
    np.testing.assert_allclose(data.force, 1e3 * F)
    # time in ms, velocity in mm/s (which sets the displacement unit), a commented header as np.savetxt writes it
    path = tmp_path / "v.csv"
    np.savetxt(path, np.c_[np.arange(N), X, F], delimiter=",", header="time (ms), v [mm/s], F [mN]")
    data = fj.load_record(path)
    assert float(data.motion.dt) == pytest.approx(1e-3)
    np.testing.assert_allclose(data.motion.v, 1e-3 * X)
    np.testing.assert_allclose(data.force, 1e-3 * F)


@pytest.mark.parametrize(
    "x_unit, factor", [("m", 1.0), ("mm", 1e-3), ("um", 1e-6), ("µm", 1e-6), ("nm", 1e-9), ("in", 0.0254)]
)
def test_x_unit_argument(tmp_path, x_unit, factor):
    data = fj.load_record(_csv(tmp_path / "r.csv", "t,x,force", T, X, F), x_unit=x_unit)
    np.testing.assert_allclose(data.motion.x, factor * X)


@pytest.mark.parametrize(
    "force_unit, factor",
    [("N", 1.0), ("kN", 1e3), ("mN", 1e-3), ("lbf", 4.4482216152605), ("kip", 4448.2216152605)],
)
def test_force_unit_argument(tmp_path, force_unit, factor):
    data = fj.load_record(_csv(tmp_path / "r.csv", "t,x,force", T, X, F), force_unit=force_unit)
    np.testing.assert_allclose(data.force, factor * F)


def test_unit_arguments_win_over_the_file(tmp_path):
    path = _csv(tmp_path / "r.csv", "t,x [um],v [mm/s],force [kN]", T, X, X, F)
    with pytest.warns(UserWarning) as warned:  # v is not dx/dt: keep it unchecked
        data = fj.load_record(path, x_unit="mm", force_unit="N", velocity="file")
    assert [str(w.message).split(": ", 1)[1] for w in warned] == [
        "x_unit='mm' (--x-unit) overrides the displacement unit 'um' that 'x [um]' gives; the data are read in 'mm'",
        "force_unit='N' (--force-unit) overrides the force unit 'kN' that 'force [kN]' gives; the data are read in 'N'",
    ]
    np.testing.assert_allclose(data.motion.x, 1e-3 * X)
    np.testing.assert_allclose(data.motion.v, 1e-3 * X)
    np.testing.assert_allclose(data.force, F)
    with pytest.raises(fj.RecordError, match="um .* and mm .*make them agree"):
        fj.load_record(path)  # without the argument, the file disagrees with itself


def test_unknown_unit_names_the_known_ones(tmp_path):
    path = _csv(tmp_path / "r.csv", "t,x [furlong],force", T, X, F)
    with pytest.raises(fj.RecordError, match=r"unknown displacement unit 'furlong' \(known: m, .*um.*--x-unit"):
        fj.load_record(path)
    with pytest.raises(fj.RecordError, match=r"unknown force unit 'MN' \(known: N, kN, mN"):
        fj.load_record(path, x_unit="mm", force_unit="MN")


def test_npz_with_extra_keys_and_a_units_entry(tmp_path):
    path = tmp_path / "r.npz"
    np.savez(
        path,
        time=T,
        position=X,
        F=F,
        units="x=um,force=kN",
        operator="bench 3",
        image=np.ones((4, 5)),
        temperature=np.full(N, 21.0),
        meta=np.array({"a": 1}, dtype=object),
    )
    data = fj.load_record(path)
    np.testing.assert_allclose(data.motion.x, 1e-6 * X)
    np.testing.assert_allclose(data.force, 1e3 * F)
    # units in the key names, a scalar dt, the units entry as a 1-D array of strings
    path = tmp_path / "k.npz"
    np.savez(path, **{"x [mm]": X, "force": F, "dt": np.array(2e-3), "units": np.array(["force=mN"])})
    data = fj.load_record(path)
    assert float(data.motion.dt) == pytest.approx(2e-3)
    np.testing.assert_allclose(data.motion.x, 1e-3 * X)
    np.testing.assert_allclose(data.force, 1e-3 * F)


def test_dt_argument_for_a_rounded_or_missing_time_column(tmp_path):
    rounded = np.round(np.arange(N) * 0.0007, 3)
    path = _csv(tmp_path / "rounded.csv", "t,x,force", rounded, X, F)
    with pytest.raises(fj.RecordError, match=r"uniformly sampled.*dt=.*--dt"):
        fj.load_record(path)
    assert float(fj.load_record(path, dt=7e-4).motion.dt) == pytest.approx(7e-4)
    path = _csv(tmp_path / "no_time.csv", "x,force", X, F)
    with pytest.raises(fj.RecordError, match=r"need a time column 't'.*dt="):
        fj.load_record(path)
    assert float(fj.load_record(path, dt=5e-4).motion.dt) == pytest.approx(5e-4)
    for bad in (0.0, -1e-3, float("nan"), float("inf"), "fast"):
        with pytest.raises(fj.RecordError, match="positive finite"):
            fj.load_record(path, dt=bad)


@pytest.mark.parametrize("header", ["t,x,position,force", "t,x,force,F"])
def test_two_columns_for_one_role_is_an_error(tmp_path, header):
    path = _csv(tmp_path / "r.csv", header, T, X, X, F)
    first, second = header.split(",")[1:3] if "position" in header else header.split(",")[2:4]
    with pytest.raises(fj.RecordError, match=f"columns '{first}' and '{second}' both give"):
        fj.load_record(path)


def test_byte_order_mark_header_with_units(tmp_path):
    path = _csv(tmp_path / "excel.csv", '"time [ms]","x [mm]","force [N]"', np.arange(N), X, F, encoding="utf-8-sig")
    data = fj.load_record(path)
    assert float(data.motion.dt) == pytest.approx(1e-3)
    np.testing.assert_allclose(data.motion.x, 1e-3 * X)


def test_compare_data_card_lists_columns_ignored_and_units(tmp_path):
    path = _csv(tmp_path / "r.csv", "time,x [um],F [kN],temperature", T, X, F, np.zeros(N))
    _, card, _ = load_split(str(path))
    assert card["columns"] == {"t": "time", "x": "x [um]", "force": "F [kN]"}
    assert card["ignored"] == ["temperature"]
    assert card["units"] == {"x": "um", "force": "kN"}


def test_a_time_column_in_milliseconds_is_warned_about_and_t_unit_reads_it(tmp_path):
    """Issue 55: a record at 1 kHz whose `t` is in ms (no unit written) became dt = 1 s, and every rate parameter
    1000x wrong, without a word. A time column without a unit that gives a sample time above 50 ms (below 20 Hz)
    is warned about, naming `t_unit` / `--t-unit`; `t_unit` reads it (and wins over the file's unit)."""
    path = _csv(tmp_path / "ms.csv", "t,x,F", T * 1e3, X, F)
    with pytest.warns(UserWarning, match=r"'t' has no unit and gives a sample time of 1 s \(1 Hz\).*--t-unit ms"):
        assert float(fj.load_record(path).motion.dt) == 1.0
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert float(fj.load_record(path, t_unit="ms").motion.dt) == pytest.approx(DT)
        # a unit in the name, or a fast record, is not warned about
        fj.load_record(_csv(tmp_path / "s.csv", "t [s],x,F", T * 1e3, X, F))
        fj.load_record(_csv(tmp_path / "fast.csv", "t,x,F", T, X, F))
    with pytest.warns(UserWarning, match=r"t_unit='us' .*overrides the time unit 'ms'"):
        named = fj.load_record(_csv(tmp_path / "named.csv", "t [ms],x,F", T * 1e6, X, F), t_unit="us")
    assert float(named.motion.dt) == pytest.approx(DT)
    with pytest.raises(ValueError, match="time unit"):
        fj.load_record(path, t_unit="min")
    code = fj.main(["compare", "--t-unit", "ms", "--out", str(tmp_path / "out")])  # built-in records: no file
    assert code == 2


def test_columns_named_by_the_caller_take_their_roles_with_their_units(tmp_path):
    """Issue 55, item 5: a file whose columns are named by the rig (`clock`, `lvdt_mm`, `F_meas [kN]`) is read
    without editing it: `columns={role: name}` (`--t-column`, `--x-column`, `--v-column`, `--force-column`); a unit
    in brackets or as the name's suffix counts, and a column an alias would give the same role is not used."""
    path = _csv(tmp_path / "rig.csv", "clock,lvdt_mm,F_meas [kN],force", T, X, F, 5 + F)
    data = fj.load_record(path, columns={"t": "clock", "x": "lvdt_mm", "force": "F_meas"})
    assert float(data.motion.dt) == pytest.approx(DT)
    np.testing.assert_allclose(data.motion.x, 1e-3 * X)
    np.testing.assert_allclose(data.force, 1e3 * F)  # F_meas, not the column called force
    loaded = fj.compare.load_record_spec(str(path), columns={"t": "clock", "x": "lvdt_mm", "force": "F_meas"})
    assert loaded.card["columns"]["force"] == "F_meas [kN]" and "force" in loaded.card["ignored"]
    with pytest.raises(ValueError, match=r"no column 'nothere' for 'x' \(columns=, --x-column\); found: 'clock'"):
        fj.load_record(path, columns={"t": "clock", "x": "nothere"})
    with pytest.raises(ValueError, match="unknown role 'time'; the roles are t, dt, x, v, force"):
        fj.load_record(path, columns={"time": "clock"})
    with pytest.raises(ValueError, match="both 'x' and 'v'"):
        fj.load_record(path, columns={"x": "lvdt_mm", "v": "LVDT_mm"})
    speed = fj.load_record(
        _csv(tmp_path / "v.csv", "clock,speed_mm/s,F", T, X, F), columns={"t": "clock", "v": "speed_mm/s"}
    )
    np.testing.assert_allclose(speed.motion.v, 1e-3 * X)  # the mapped column's unit, mm/s
    code = fj.main(["compare", "--force-column", "F_meas", "--out", str(tmp_path / "out")])  # built-in: no file
    assert code == 2
