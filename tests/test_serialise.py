"""Model files (`fj.save_model` / `fj.load_model`): every family and wrapper round-trips with equal leaves and
equal simulations; pickles, unknown classes and damaged files are refused without running anything from the
file; a failing save leaves the existing file untouched.

Motions are 100 samples and the one fit runs 10 steps: the time goes into compiling the simulations.
"""

from __future__ import annotations

import hashlib
import io
import json
import pathlib
import pickle
import struct
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

from helpers import presliding_to_sliding, stribeck

MOTION = presliding_to_sliding(100)


def assert_same_tree(loaded: Any, original: Any) -> None:
    """Same classes and static fields (the tree structure), and leaves of equal dtype, shape and value."""
    assert jax.tree_util.tree_structure(loaded) == jax.tree_util.tree_structure(original)
    for new, old in zip(jax.tree_util.tree_leaves(loaded), jax.tree_util.tree_leaves(original), strict=True):
        if eqx.is_array(old):
            assert isinstance(new, jax.Array) and new.dtype == old.dtype and new.shape == old.shape
            np.testing.assert_array_equal(np.asarray(new), np.asarray(old))
        else:  # a Python number or string
            assert type(new) is type(old) and new == old


def round_trip(tmp_path: pathlib.Path, model: Any) -> Any:
    path = tmp_path / "model.eqx"
    fj.save_model(path, model)
    loaded = fj.load_model(path)
    assert_same_tree(loaded, model)
    return loaded


def lugre(**kwargs: Any) -> fj.LuGre:
    return fj.LuGre(stribeck(), sigma0=1e5, sigma1=300.0, sigma2=40.0, offset=0.05, z0=1e-6, **kwargs)


THETA = [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]
MODELS = {
    "lugre_exact": lambda: lugre(),
    "lugre_smooth": lambda: fj.LuGre(
        fj.RationalStribeck(Fc=1.0, Fs=1.5, vs=1e-3, mu=2.0), 1e5, 300.0, 40.0, smoothing=fj.Smooth(1e-4)
    ),
    "gms": lambda: fj.GMS(stribeck(), k=[4e4, 2e4, 1e4], alpha=[0.5, 0.3, 0.2], C=20.0, smoothing=fj.Smooth(1e-7)),
    "maxwell_nlr": lambda: fj.MaxwellSlip.nlr(k=[2e5, 1e5, 5e4], thresholds=[2e-6, 6e-6, 2e-5], offset=0.1),
    "maxwell_dnlrx": lambda: fj.MaxwellSlip.dnlrx(
        thresholds=[2e-6, 6e-6, 2e-5], theta=THETA, c=[1e3, -5e2], smoothing=fj.Smooth(1e-2)
    ),
    "maxwell_lr": lambda: fj.MaxwellSlip.lr(k=[2e5, 1e5, 5e4], max_deflection=2e-5),
    "dahl": lambda: fj.Dahl(sigma0=1e5, Fc=1.0, alpha=1.7, F0=0.1, smoothing=fj.Smooth(1e-4)),
    "coulomb": lambda: fj.Coulomb(Fc=1.0, offset=0.1),
    "coulomb_asym": lambda: fj.Coulomb(Fc=(1.0, 1.2), smoothing=fj.Smooth(1e-4)),
    "coulomb_viscous": lambda: fj.CoulombViscous(Fc=1.0, Fv=50.0),
    "coulomb_viscous_asym": lambda: fj.CoulombViscous(Fc=(1.0, 1.2), Fv=(50.0, 80.0)),
    "threlfall": lambda: fj.Threlfall(Fc=1.0, Fv=50.0, v0=2e-3),
    "threlfall_asym": lambda: fj.Threlfall(Fc=(1.0, 0.9), Fv=50.0, v0=(2e-3, 3e-3)),
    "tustin": lambda: fj.Tustin(Fc=1.0, Fs=1.5, vs=1e-3, Fv=50.0),
    "tustin_asym": lambda: fj.Tustin(Fc=(1.0, 1.1), Fs=1.5, vs=(1e-3, 2e-3), smoothing=fj.Smooth(1e-4)),
    "bo_pavelescu": lambda: fj.BoPavelescu(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0, Fv=50.0),
    "bo_pavelescu_asym": lambda: fj.BoPavelescu(Fc=(1.0, 1.1), Fs=(1.5, 1.4), vs=1e-3, delta=(2.0, 1.5), Fv=50.0),
    "average_ensemble": lambda: fj.AverageEnsemble(
        [lugre(), fj.MaxwellSlip.nlr(k=[2e5, 1e5], thresholds=[2e-6, 2e-5]), fj.Coulomb(Fc=1.0)]
    ),
    "weighted_ensemble": lambda: fj.WeightedEnsemble(
        [
            fj.MaxwellSlip.dnlrx(thresholds=[2e-6, 6e-6, 2e-5], theta=THETA, c=[1e3]),
            lugre(smoothing=fj.Smooth(1e-4)),
            fj.BoPavelescu(Fc=(1.0, 1.1), Fs=1.5, vs=1e-3, smoothing=fj.Smooth(1e-4)),
        ],
        weights=[0.5, 0.3, 0.2],
        intercept=0.1,
    ),
    # wrappers placed by hand: a softplus Positive (a non-default static field) and a Fixed viscous term
    "wrapped": lambda: eqx.tree_at(
        lambda m: (m.stribeck.Fc, m.sigma2),
        lugre(),
        (fj.Positive(1.0, transform="softplus"), fj.Fixed(jnp.asarray(40.0))),
    ),
}


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_family_round_trips(name, tmp_path):
    model = MODELS[name]()
    assert type(round_trip(tmp_path, model)) is type(model)


@pytest.mark.slow  # the fast tier stays under 5 minutes
def test_loaded_models_simulate_as_saved(tmp_path):
    names = sorted(MODELS)
    models = [MODELS[name]() for name in names]
    loaded = round_trip(tmp_path, models)  # a list of models is a model file too
    # every simulation in one compilation (faster than one per model); the loaded list compiles again, since
    # weakly typed leaves (the width of Smooth(1e-4)) come back strongly typed
    simulate_all = eqx.filter_jit(lambda models: [fj.simulate(model, MOTION) for model in models])
    for name, new, old in zip(names, simulate_all(loaded), simulate_all(models), strict=True):
        np.testing.assert_array_equal(np.asarray(new), np.asarray(old), err_msg=name)


def test_constraint_wrappers_round_trip(tmp_path):
    wrappers = {
        "log": fj.Positive([1.0, 2.0]),
        "softplus": fj.Positive(3.0, transform="softplus"),
        "fixed": fj.Fixed(fj.Positive(2.0)),
        "simplex": fj.Simplex([0.2, 0.3, 0.5]),
    }
    loaded = round_trip(tmp_path, wrappers)
    assert loaded["softplus"].transform == "softplus"
    for key in wrappers:
        np.testing.assert_array_equal(fj.unwrap(loaded[key]), fj.unwrap(wrappers[key]))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float32_and_float64_models_keep_their_dtype(dtype, tmp_path):
    model = fj.LuGre(
        fj.ExponentialStribeck(Fc=dtype(1.0), Fs=dtype(1.5), vs=dtype(1e-3)),
        sigma0=dtype(1e5),
        sigma1=dtype(300.0),
        sigma2=dtype(40.0),
        smoothing=fj.Smooth(dtype(1e-4)),
    )
    loaded = round_trip(tmp_path, model)
    assert {leaf.dtype for leaf in jax.tree_util.tree_leaves(loaded)} == {np.dtype(dtype)}
    motion = fj.Motion.from_position(np.asarray(MOTION.x, dtype), dt=dtype(1e-3))
    np.testing.assert_array_equal(np.asarray(fj.simulate(loaded, motion)), np.asarray(fj.simulate(model, motion)))


def test_emps_plant_and_system_round_trip(tmp_path):
    friction = fj.CoulombViscous(Fc=(20.0, 21.0), Fv=200.0, offset=-3.0, smoothing=fj.Smooth(1e-3))
    plant = fj.EMPSPlant(95.1, friction, offset=0.5)
    loaded = round_trip(tmp_path, plant)
    vir = np.r_[np.full(50, 2.0), np.full(50, -2.0)]
    new, old = (fj.simulate_open_loop(p, vir, gtau=35.15, dt=1e-3) for p in (loaded, plant))
    np.testing.assert_array_equal(np.asarray(new.q), np.asarray(old.q))
    # the open-loop system model: a static field (substeps) around the plant
    system = fj.EMPSOpenLoop(plant, jnp.asarray(35.15), substeps=2)
    loaded = round_trip(tmp_path, system)
    assert loaded.substeps == 2
    inputs = fj.InputRecord(dt=1e-3, vir=vir)
    for new, old in zip(fj.simulate(loaded, inputs), fj.simulate(system, inputs), strict=True):
        np.testing.assert_array_equal(np.asarray(new), np.asarray(old))


def test_fitted_model_round_trips(tmp_path):
    truth = fj.CoulombViscous(Fc=1.0, Fv=50.0, smoothing=fj.Smooth(1e-4))
    data = fj.FrictionData(MOTION, fj.simulate(truth, MOTION))
    start = fj.CoulombViscous(Fc=0.8, Fv=40.0, smoothing=fj.Smooth(1e-4))
    model = fj.fit(start, data, steps=10, compute_std=False).model
    loaded = round_trip(tmp_path, model)
    np.testing.assert_array_equal(np.asarray(fj.simulate(loaded, MOTION)), np.asarray(fj.simulate(model, MOTION)))


def test_trees_of_models_and_python_values_round_trip(tmp_path):
    tree = {"models": (fj.Coulomb(Fc=1.0), None, [fj.Dahl(sigma0=1e5, Fc=1.0)]), "meta": [3, 2.5, "text", True]}
    loaded = round_trip(tmp_path, tree)
    assert loaded["meta"] == [3, 2.5, "text", True] and type(loaded["models"]) is tuple


class ViscousWithMemory(fj.AbstractFrictionModel):
    """A user-written model (not a fricjax class) with static fields, a ClassVar, a property and a
    `__check_init__` that would fail if it ran on the array-free skeleton that loading builds."""

    c: Any
    decay: jax.Array
    label: str = eqx.field(static=True)
    lags: tuple[int, ...] = eqx.field(static=True)

    requires: ClassVar[frozenset[str]] = frozenset({"v"})

    def __check_init__(self) -> None:
        if not bool(np.all(np.asarray(fj.unwrap(self.c)) > 0)):
            raise ValueError("c must be positive")

    @property
    def time_constant(self) -> jax.Array:
        return -1.0 / jnp.log(self.decay)

    def init_state(self) -> jax.Array:
        return jnp.zeros((), self.decay.dtype)

    def step(self, state: jax.Array, sample: fj.MotionSample) -> tuple[jax.Array, jax.Array]:
        state = self.decay * state + sample.v
        return state, fj.unwrap(self.c) * state


def test_user_model_needs_its_class_passed(tmp_path):
    model = fj.AverageEnsemble([ViscousWithMemory(fj.Positive(50.0), jnp.asarray(0.5), "mine", (1, 2)), lugre()])
    path = tmp_path / "user.eqx"
    fj.save_model(path, model)
    with pytest.raises(ValueError, match=r"ViscousWithMemory.*classes="):
        fj.load_model(path)
    loaded = fj.load_model(path, classes=(ViscousWithMemory,))
    assert_same_tree(loaded, model)
    user = loaded.members[0]
    assert (user.label, user.lags, user.requires) == ("mine", (1, 2), frozenset({"v"}))
    np.testing.assert_allclose(user.time_constant, 1.0 / np.log(2.0))
    np.testing.assert_array_equal(np.asarray(fj.simulate(loaded, MOTION)), np.asarray(fj.simulate(model, MOTION)))


class _CreatesMarker:
    """Unpickling this object creates the file `marker`: what a malicious pickle could do."""

    def __init__(self, marker: pathlib.Path):
        self.marker = marker

    def __reduce__(self) -> Any:
        return pathlib.Path.touch, (self.marker,)


def write_model_file(path: pathlib.Path, tree: dict, arrays: bytes = b"", **header: Any) -> None:
    """A model file by hand, in the layout the docstring of `fj.save_model` gives: the magic line, the header's
    length (8 bytes, little-endian), the JSON header, the arrays."""
    header = {"format": "fricjax-model", "format_version": 1, "fricjax": "0.1.0", "tree": tree} | header
    text = json.dumps(header).encode()
    path.write_bytes(b"fricjax-model\n" + struct.pack("<Q", len(text)) + text + arrays)


def read_model_file(data: bytes) -> tuple[dict, bytes]:
    """The JSON header and the array bytes of a model file's contents."""
    assert data.startswith(b"fricjax-model\n")
    (length,) = struct.unpack("<Q", data[14:22])
    return json.loads(data[22 : 22 + length]), data[22 + length :]


def test_pickles_are_refused_before_anything_is_deserialised(tmp_path):
    live = tmp_path / "live-marker"
    pickle.loads(pickle.dumps(_CreatesMarker(live)))
    assert live.exists()  # the payload works: unpickling it creates its marker
    marker = tmp_path / "marker"
    path = tmp_path / "model.eqx"
    path.write_bytes(pickle.dumps({"model": _CreatesMarker(marker)}))
    with pytest.raises(ValueError, match="not a fricjax model file"):
        fj.load_model(path)
    # a pickle hidden in an object array behind a valid header is not loaded either
    buffer = io.BytesIO()
    np.save(buffer, np.array([_CreatesMarker(marker)], dtype=object), allow_pickle=True)
    write_model_file(path, {"kind": "array", "shape": [1], "dtype": "float64"}, buffer.getvalue())
    with pytest.raises(ValueError, match="damaged"):
        fj.load_model(path)
    assert not marker.exists()


def test_classes_outside_fricjax_are_refused(tmp_path):
    path = tmp_path / "model.eqx"
    tree = {"kind": "module", "module": "os", "qualname": "system", "static": {}, "fields": {}}
    write_model_file(path, tree)
    with pytest.raises(ValueError, match=r"os\.system.*classes="):
        fj.load_model(path)
    with pytest.raises(TypeError, match="classes"):
        fj.load_model(path, classes=(print,))


def test_damaged_files_are_refused(tmp_path):
    path = tmp_path / "model.eqx"
    fj.save_model(path, fj.Coulomb(Fc=1.0))
    good = path.read_bytes()
    for damaged, match in [(good[:-3], "damaged"), (good + b"x", "checksum"), (good[:20], "damaged")]:
        path.write_bytes(damaged)
        with pytest.raises(ValueError, match=match):
            fj.load_model(path)

    for edit, match in [  # edits of the description of the Positive wrapper around Fc
        (lambda fc: fc["fields"]["raw"].update(shape=[2]), "shape"),  # the header disagrees with the arrays
        (lambda fc: fc["static"].update(extra=1), "does not match Positive"),  # fields of another version
        (lambda fc: fc.update(module="builtins", qualname="object"), r"builtins\.object.*classes="),
        (lambda fc: fc.update(kind="code"), "unknown kind"),
    ]:
        header, arrays = read_model_file(good)
        edit(header["tree"]["fields"]["Fc"])
        write_model_file(path, header["tree"], arrays)
        with pytest.raises(ValueError, match=match):
            fj.load_model(path)
    write_model_file(path, {"kind": "none"}, format_version=99)
    with pytest.raises(ValueError, match="upgrade fricjax"):
        fj.load_model(path)
    with pytest.raises(ValueError, match="no file"):
        fj.load_model(tmp_path / "missing.eqx")


def test_failing_save_leaves_the_existing_file_untouched(tmp_path):
    path = tmp_path / "model.eqx"
    model = lugre()
    fj.save_model(path, model)
    before = path.read_bytes()
    with pytest.raises(ValueError, match=r"model\[1\].*function"):
        fj.save_model(path, (model, lambda v: v))  # cannot be described: fails before writing
    deleted = jnp.ones(3)
    deleted.delete()
    with pytest.raises(RuntimeError):
        fj.save_model(path, (model, deleted))  # fails while writing the arrays
    assert path.read_bytes() == before
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind
    loaded = fj.load_model(path)
    np.testing.assert_array_equal(np.asarray(fj.simulate(loaded, MOTION)), np.asarray(fj.simulate(model, MOTION)))


def test_save_refuses_what_it_cannot_describe(tmp_path):
    path = tmp_path / "model.eqx"
    for tree, match in [
        ({"a": fj.MotionSample(1.0, 2.0, 3.0, 4.0)}, r"model\['a'\].*MotionSample"),
        ([jax.random.key(0)], r"model\[0\].*dtype key"),
        ({1: 1.0, "b": 2.0}, "all strings or all integers"),
        (fj.Continuation(1e-3, 1e-5, 3), "Continuation"),
    ]:
        with pytest.raises(ValueError, match=match):
            fj.save_model(path, tree)
    with pytest.raises(ValueError, match="cannot write"):
        fj.save_model(tmp_path / "no_such_dir" / "m.eqx", fj.Coulomb(Fc=1.0))
    with pytest.raises(ValueError, match="cannot write"):
        fj.save_model(tmp_path, fj.Coulomb(Fc=1.0))
    assert not path.exists()


def _header(path: pathlib.Path) -> dict:
    """The JSON header of a model file, read as the format says (magic line, 8-byte length, JSON)."""
    data = path.read_bytes()
    (length,) = struct.unpack("<Q", data[14:22])
    return json.loads(data[22 : 22 + length])


def test_files_say_whether_the_model_is_exact_or_smooth(tmp_path):
    path = tmp_path / "model.eqx"
    smooth = fj.LuGre(stribeck(), sigma0=1e5, sigma1=300.0, sigma2=40.0, smoothing=fj.Smooth(jnp.float32(1e-3)))
    cases = [
        (smooth, {"kind": "smooth", "eps": [0.001]}),  # the float32 width's own shortest decimal
        (fj.exact(smooth), {"kind": "exact"}),
        ((fj.exact(smooth), fj.with_smoothing(smooth, fj.Smooth(0.3))), {"kind": "mixed", "eps": [0.3]}),
        ({"k": jnp.ones(2)}, {"kind": "none"}),  # a tree without a smoothing strategy
    ]
    for model, expected in cases:
        fj.save_model(path, model)
        assert _header(path)["smoothing"] == expected, model


def test_load_model_exact_applies_fj_exact(tmp_path):
    path = tmp_path / "model.eqx"
    model = fj.Dahl(sigma0=1e5, Fc=1.0, alpha=1.7, smoothing=fj.Smooth(1e-4))
    fj.save_model(path, model)
    loaded = fj.load_model(path)
    assert isinstance(loaded.smoothing, fj.Smooth)  # as saved, unless asked
    exact = fj.load_model(path, exact=True)
    assert_same_tree(exact, fj.exact(model))
    assert isinstance(exact.smoothing, fj.Exact) and str(exact).startswith("Dahl (exact)")
    np.testing.assert_array_equal(fj.simulate(exact, MOTION), fj.simulate(fj.exact(model), MOTION))
    # a file written before the header said so (no "smoothing" key) still loads, exact on request too
    data = path.read_bytes()
    header = _header(path)
    del header["smoothing"]
    old = json.dumps(header, separators=(",", ":")).encode()
    (length,) = struct.unpack("<Q", data[14:22])
    body = data[:14] + struct.pack("<Q", len(old)) + old + data[22 + length : -32]
    (tmp_path / "old.eqx").write_bytes(body + hashlib.sha256(body).digest())
    assert isinstance(fj.load_model(tmp_path / "old.eqx", exact=True).smoothing, fj.Exact)


def test_a_static_field_added_since_a_file_was_written_takes_its_default(tmp_path):
    """Dahl's `classical` flag came after files of Dahl models were written: such a file (no `classical` in the
    header) loads as a model built with a trained exponent; a classical model round-trips with its flag."""
    path = tmp_path / "model.eqx"
    classical = fj.Dahl(sigma0=1e5, Fc=[1.0, 0.7], alpha=fj.Fixed(1.0), F0=0.1)
    fj.save_model(path, classical)
    loaded = fj.load_model(path)
    assert loaded.classical
    parallel, sequential = fj.simulate(loaded, MOTION, scan="parallel"), fj.simulate(classical, MOTION)
    np.testing.assert_allclose(parallel, sequential, rtol=0, atol=1e-12)
    model = fj.Dahl(sigma0=1e5, Fc=1.0, alpha=1.7)
    fj.save_model(path, model)
    header, arrays = read_model_file(path.read_bytes()[:-32])  # format 2 ends with the checksum
    assert header["tree"]["static"].pop("classical") is False
    write_model_file(tmp_path / "old.eqx", header["tree"], arrays)
    old = fj.load_model(tmp_path / "old.eqx")
    assert not old.classical
    np.testing.assert_array_equal(fj.simulate(old, MOTION), fj.simulate(model, MOTION))
