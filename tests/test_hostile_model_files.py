"""Hostile model files: a SHA-256 checksum over header and arrays catches any changed bit, and a loaded model is
checked against its classes' invariants (shapes, dtypes, finite and positive values, transform names) as its
constructors check them, whether the file has a checksum (format 2) or not (format 1, still loaded)."""

from __future__ import annotations

import hashlib
import json
import pathlib
import struct
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

from helpers import stribeck


def lugre(**kwargs: Any) -> fj.LuGre:
    return fj.LuGre(stribeck(), sigma0=1e5, sigma1=300.0, sigma2=40.0, offset=0.05, z0=1e-6, **kwargs)


def split(data: bytes) -> tuple[dict, bytes]:
    """The JSON header and the arrays (without the checksum) of a format-2 file's contents."""
    (length,) = struct.unpack("<Q", data[14:22])
    return json.loads(data[22 : 22 + length]), data[22 + length : -32]


def write(path: pathlib.Path, header: dict, arrays: bytes, *, checksum: bool = True) -> None:
    """A model file by hand, with a valid checksum (format 2) or none (format 1, as written before checksums)."""
    header = dict(header, format_version=2, checksum="sha256") if checksum else dict(header, format_version=1)
    if not checksum:
        header.pop("checksum", None)
    text = json.dumps(header).encode()
    body = b"fricjax-model\n" + struct.pack("<Q", len(text)) + text + arrays
    path.write_bytes(body + (hashlib.sha256(body).digest() if checksum else b""))


def test_every_changed_bit_is_refused_naming_the_file(tmp_path):
    """Single-bit flips of a LuGre file (one bit in 41, all over the file): none loads; each error names the file.
    Without the checksum about 2 % of them loaded and simulated different forces."""
    path = tmp_path / "lugre.eqx"
    fj.save_model(path, lugre())
    good = path.read_bytes()
    loaded = []
    for bit in range(0, 8 * len(good), 41):
        damaged = bytearray(good)
        damaged[bit // 8] ^= 1 << (bit % 8)
        path.write_bytes(bytes(damaged))
        try:
            fj.load_model(path)
            loaded.append(bit)
        except ValueError as err:
            assert str(path) in str(err)
    assert loaded == []
    path.write_bytes(good)
    with pytest.raises(ValueError, match=r"lugre\.eqx is damaged: .*SHA-256 checksum"):
        path.write_bytes(good[:-40] + good[-39:])  # one byte fewer
        fj.load_model(path)


def test_old_files_without_checksum_load_and_are_checked(tmp_path):
    path = tmp_path / "old.eqx"
    model = lugre()
    fj.save_model(path, model)
    header, arrays = split(path.read_bytes())
    write(path, header, arrays, checksum=False)
    loaded = fj.load_model(path)
    np.testing.assert_array_equal(fj.unwrap(loaded).sigma1, fj.unwrap(model).sigma1)
    fj.save_model(path, eqx.tree_at(lambda m: m.sigma1, model, jnp.asarray(np.nan)))
    header, arrays = split(path.read_bytes())
    write(path, header, arrays, checksum=False)
    with pytest.raises(ValueError, match=r"old\.eqx holds an invalid LuGre at `model`: `sigma1` .*non-finite"):
        fj.load_model(path)


@pytest.mark.parametrize(
    "replace, match",
    [
        (lambda m: (m.sigma1, jnp.ones((2, 2))), r"`model`: `sigma1` is an array of shape \(2, 2\)"),
        (lambda m: (m.sigma1, jnp.asarray(np.nan)), r"`model`: `sigma1` holds a non-finite value"),
        (lambda m: (m.sigma1, jnp.asarray(-1e9)), r"`model`: `sigma1` must be >= 0, got -1000000000\.0"),
        (lambda m: (m.offset, jnp.asarray(np.inf)), r"`model`: `offset` holds a non-finite value"),
        (lambda m: (m.sigma0.raw, jnp.asarray(-1e9)), r"Positive at `model.sigma0`: .*finite and positive, got 0"),
        (lambda m: (m.sigma0.raw, jnp.asarray(1e9)), r"Positive at `model.sigma0`: .*finite and positive, got inf"),
        (lambda m: (m.stribeck.Fc.raw, jnp.asarray(np.nan)), r"Positive at `model.stribeck.Fc`"),
        (lambda m: (m.sigma0, fj.Positive([1e5, 2e5])), r"`model`: `sigma0` is an array of shape \(2,\)"),
        (lambda m: (m.z0, jnp.asarray(0, dtype=jnp.int32)), r"`z0` is an array of shape \(\) and dtype int32"),
        (lambda m: (m.z0, "0.0"), r"`z0` is str '0.0'"),
    ],
)
def test_values_the_constructor_refuses_are_refused(tmp_path, replace, match):
    """Files that hold what `fj.LuGre(...)` refuses (written by another tool, or edited and checksummed again)."""
    path = tmp_path / "bad.eqx"
    model = lugre()
    fj.save_model(path, eqx.tree_at(lambda m: replace(m)[0], model, replace(model)[1]))
    with pytest.raises(ValueError, match=r"bad\.eqx holds an invalid .*" + match):
        fj.load_model(path)


def test_unknown_transform_names_are_refused(tmp_path):
    """A positivity transform named "mog" was read as softplus."""
    path = tmp_path / "mog.eqx"
    fj.save_model(path, lugre())
    header, arrays = split(path.read_bytes())
    assert header["tree"]["fields"]["sigma0"]["static"]["transform"] == "log"
    header["tree"]["fields"]["sigma0"]["static"]["transform"] = "mog"
    for checksum in (True, False):
        write(path, header, arrays, checksum=checksum)
        with pytest.raises(ValueError, match=r"Positive at `model.sigma0`: `transform` is str 'mog'.*'log'"):
            fj.load_model(path)


def test_element_counts_must_agree(tmp_path):
    """GMS `k` and `alpha` are one number per element (the annotations' `N`): 3 stiffnesses and 2 fractions do
    not make a GMS model."""
    path = tmp_path / "gms.eqx"
    gms = fj.GMS(stribeck(), k=[4e4, 2e4, 1e4], alpha=[0.5, 0.3, 0.2], C=20.0)
    fj.save_model(path, eqx.tree_at(lambda m: m.alpha, gms, fj.Simplex([0.5, 0.5])))
    with pytest.raises(ValueError, match=r"gms\.eqx holds an invalid GMS at `model`: `alpha` is an array of shape"):
        fj.load_model(path)
    fj.save_model(path, [gms, fj.GMS(stribeck(), k=[1e4, 2e4], alpha=[0.5, 0.5], C=1.0)])  # per model: fine
    assert len(fj.load_model(path)) == 2


def test_long_legal_file_names_are_saved(tmp_path):
    """The temporary file's name no longer adds 18 characters to the target's (255 is the usual limit)."""
    for length in (238, 255):
        path = tmp_path / ("m" * (length - 4) + ".eqx")
        fj.save_model(path, fj.Coulomb(Fc=1.0))
        assert type(fj.load_model(path)) is fj.Coulomb
        assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]
        path.unlink()
