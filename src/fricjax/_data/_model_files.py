"""Model files: `save_model` / `load_model`, arrays by equinox serialisation plus a JSON description of the tree.

A model file holds, in this order:

1. the magic line `fricjax-model\\n` (14 bytes);
2. the length N of the header, an unsigned 64-bit little-endian integer (8 bytes);
3. the header, N bytes of UTF-8 JSON: `{"format": "fricjax-model", "format_version": 2, "fricjax": <version>,
   "checksum": "sha256", "smoothing": <smoothing>, "tree": <node>}`, where `<smoothing>` says whether the saved
   model is exact or smooth: `{"kind": "exact" | "smooth" | "mixed" | "none"}` (every smoothing strategy in it
   `Exact()`, every one `Smooth(eps)`, some of each, none at all), with `"eps": [...]` (the distinct widths) where
   any is smooth (files saved before fricjax recorded it lack the key), and a node is one of
   - `{"kind": "module", "module": ..., "qualname": ..., "static": {name: value}, "fields": {name: node}}` for
     an equinox Module (static values: numbers, strings, bools, None, and lists / `{"tuple": [...]}` of those),
   - `{"kind": "tuple" | "list", "items": [node, ...]}`, `{"kind": "dict", "items": [[key, node], ...]}`,
   - `{"kind": "none"}`, `{"kind": "array", "shape": [...], "dtype": "float64"}`,
   - `{"kind": "value", "value": ...}` for a Python bool / int / float / str leaf;
4. the arrays, as `equinox.tree_serialise_leaves` writes them (one `.npy` record per array, in the order of
   `jax.tree_util.tree_leaves`);
5. the SHA-256 digest (32 bytes) of everything before it: header and arrays. Files of format version 1 (before
   the checksum) end with the arrays, and still load.

Loading rebuilds the skeleton from the header (instances made by `object.__new__` and `object.__setattr__`,
as equinox's own unflattening does: no `__init__`, no `__check_init__`) and fills it with
`equinox.tree_deserialise_leaves`, reading the `.npy` records with `allow_pickle=False`. Nothing from the file
is executed or unpickled, and only allowed classes are instantiated: fricjax's own (their module starts with
`fricjax.`) and those the caller passes in `classes=`. The checksum is verified before anything is read, and
the loaded model is checked against its classes' invariants (`_model_checks`: shapes, dtypes, finite and
positive values, transform names), as its constructors would have checked them.

Why not pickle: unpickling runs code named by the file. Why not equinox serialisation alone: it loads into a
skeleton of the model, which the caller would have to rebuild with the right hyperparameters; the JSON header
is that skeleton.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import pathlib
import struct
import uuid
from collections.abc import Callable, Iterable
from typing import IO, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._smoothing import AbstractSmoothing, Exact, Smooth
from .._smoothing import exact as exact_model
from .._version import fricjax_version
from ._model_checks import check_loaded, warn_unloadable

MAGIC = b"fricjax-model\n"
FORMAT = "fricjax-model"
FORMAT_VERSION = 2  # 2: a SHA-256 checksum at the end
_DIGEST_SIZE = 32
_LENGTH = struct.Struct("<Q")

# dtypes an array in a model file may have (no object, string or structured dtypes)
_DTYPES = frozenset(
    {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64"}
    | {"float16", "bfloat16", "float32", "float64", "complex64", "complex128"}
)
_SCALARS = (bool, int, float, str)


def save_model(path: str | pathlib.Path, model: Any) -> None:
    """Save a model (or a tuple / list / dict of models) to one file, without pickle.

    Format (`.eqx` is the usual extension): the line `fricjax-model`, the length of the header (8 bytes,
    unsigned little-endian), the header, then the arrays as `equinox.tree_serialise_leaves` writes them (one
    `.npy` record per array, in `jax.tree_util.tree_leaves` order). The header is UTF-8 JSON with the format
    name and version, the fricjax version, whether the model is exact or smooth (`"smoothing"`: `{"kind": "exact"}`,
    `{"kind": "smooth", "eps": [...]}`, ...) and the tree: for each equinox Module its class (module and qualname),
    its static fields and its children; tuples, lists, dicts and None as such; arrays by shape and dtype; Python
    numbers and strings by value. The file ends with the SHA-256 digest of all that precedes it.

    The file is written to a temporary file in the same folder and then renamed over `path`, so a save that
    fails leaves an existing file at `path` untouched.

    **Arguments:**

    - `path`: the file to write (replaced if it exists).
    - `model`: any fricjax model, or any tree of equinox Modules, tuples, lists, dicts (string or integer
      keys), None, arrays and Python numbers / strings. Static fields must hold numbers, strings, bools, None,
      or tuples / lists of those.

    **Returns:** nothing. Raises `ValueError` naming the part of `model` that cannot be described (a function,
    a NamedTuple, a NumPy object array, ...) or the path that cannot be written.

    ```python
    >>> import pathlib, tempfile, fricjax as fj
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "coulomb.eqx"
    >>> fj.save_model(path, fj.Coulomb(Fc=2.0, smoothing=fj.Smooth(1e-3)))
    >>> round(float(fj.load_model(path)(-0.1)), 6)
    -2.0
    ```
    """
    path = pathlib.Path(path)
    tree = _describe(model)  # first: it names what a model file cannot hold
    warn_unloadable(model)  # what load_model would refuse
    header = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "fricjax": fricjax_version(), "checksum": "sha256",
        "smoothing": _smoothing(model), "tree": tree,
    }  # fmt: skip
    try:
        header_bytes = json.dumps(header, separators=(",", ":")).encode("utf-8")
    except ValueError as err:  # e.g. a string with a lone surrogate
        raise ValueError(f"save_model: the model cannot be described as JSON ({err}).") from err

    def write(handle: IO[bytes]) -> None:
        hashing = _HashingWriter(handle)
        hashing.write(MAGIC)
        hashing.write(_LENGTH.pack(len(header_bytes)))
        hashing.write(header_bytes)
        eqx.tree_serialise_leaves(hashing, model, filter_spec=_save_leaf)
        handle.write(hashing.digest.digest())

    _write_atomically(path, write)


def load_model(path: str | pathlib.Path, *, classes: Iterable[type] = (), exact: bool = False) -> Any:
    """Load a model written by `save_model`; never executes code from the file and never unpickles.

    The header is read first: a file that does not start with the fricjax magic line (a pickle, say) is
    refused before anything else is read. The tree is rebuilt from the JSON description without calling any
    constructor, for allowed classes only: every equinox Module defined in fricjax, plus `classes`. Arrays
    (JAX or NumPy when saved) come back as JAX arrays of the saved dtype, read without pickle; a weakly typed
    leaf such as `jnp.asarray(0.1)` comes back strongly typed, as with `equinox.tree_deserialise_leaves`.

    **Arguments:**

    - `path`: a file written by `save_model`.
    - `classes`: your own equinox Module classes that the file holds (a model you wrote, or `eqx.nn` layers),
      e.g. `classes=(MyModel,)`. Only pass classes whose files you trust to hold sensible field values.
    - `exact`: return `fj.exact(model)`: every smoothing strategy replaced by `Exact()` (a fit saves the smooth
      model it trained; `fricjax compare` scores, and reports the parameters of, the exact one). The file's header
      says which the saved model is (`"smoothing"`), and so does `print(model)`.

    **Returns:** the saved model (or tree of models), with the same classes, static fields and array values
    (smoothing replaced by `Exact()` with `exact=True`).

    Raises `ValueError` naming the file when it is missing, is not a fricjax model file, is damaged (its SHA-256
    checksum does not match; files saved before checksums have none and still load), names a class that is
    neither fricjax's nor in `classes`, or holds values its classes' constructors refuse (a shape, a dtype, a
    non-finite or negative value, an unknown positivity transform: the message names the field).

    ```python
    >>> import pathlib, tempfile, fricjax as fj
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "dahl.eqx"
    >>> fj.save_model(path, fj.Dahl(sigma0=1e5, Fc=1.0))
    >>> type(fj.load_model(path)).__name__
    'Dahl'
    >>> fj.save_model(path, fj.Coulomb(Fc=2.0, smoothing=fj.Smooth(1e-3)))
    >>> type(fj.load_model(path, exact=True).smoothing).__name__
    'Exact'
    ```
    """
    path = pathlib.Path(path)
    allowed = _allowed_classes(classes)
    if not path.is_file():
        raise ValueError(f"load_model: no file at {path}.")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ValueError(f"load_model: cannot read {path}: {err.strerror}.") from err
    verified = len(data) > _DIGEST_SIZE and hashlib.sha256(data[:-_DIGEST_SIZE]).digest() == data[-_DIGEST_SIZE:]
    header, start = _read_header(data, path)
    _check_header(header, path, verified)
    if header["format_version"] >= 2:
        data = data[:-_DIGEST_SIZE]
    try:
        like = _build(header["tree"], allowed, "model", path)
    except RecursionError:
        raise ValueError(f"load_model: {path} is damaged (its model description is nested too deeply).") from None
    handle = io.BytesIO(data)
    handle.seek(start)
    try:
        model = eqx.tree_deserialise_leaves(handle, like, filter_spec=_load_leaf)
    except (ValueError, TypeError, RuntimeError, OSError, EOFError) as err:
        cause: BaseException = err
        while cause.__cause__ is not None:  # equinox wraps the error in one naming the leaf's path
            cause = cause.__cause__
        detail = str(err) if cause is err else f"{err}: {cause}"
        raise ValueError(f"load_model: {path} is damaged (reading its arrays: {detail}).") from err
    if handle.read(1):
        raise ValueError(f"load_model: {path} is damaged (unexpected data after the arrays).")
    check_loaded(model, path)
    return exact_model(model) if exact else model


# ----------------------------------------------------------------------------------------------------------------
# saving
# ----------------------------------------------------------------------------------------------------------------


def _smoothing(model: Any) -> dict[str, Any]:
    """The header's `"smoothing"` entry: whether the smoothing strategies in `model` are exact or smooth."""
    strategies = [
        leaf
        for leaf in jax.tree_util.tree_leaves(model, is_leaf=lambda x: isinstance(x, AbstractSmoothing))
        if isinstance(leaf, AbstractSmoothing)
    ]
    smooth = [s for s in strategies if isinstance(s, Smooth)]
    if not strategies:
        return {"kind": "none"}
    if all(isinstance(s, Exact) for s in strategies):
        return {"kind": "exact"}
    kind = "mixed" if any(isinstance(s, Exact) for s in strategies) else "smooth"
    if any(not eqx.is_array(s.eps) or isinstance(s.eps, jax.core.Tracer) for s in smooth):
        return {"kind": kind}  # a traced model: _describe refuses it with its own message
    # str() of a NumPy scalar: the shortest decimal of its own dtype (a float32 0.001 is 0.001, not 0.0010000000474)
    widths = {float(str(w)) for s in smooth for w in np.asarray(s.eps).reshape(-1)}
    return {"kind": kind, "eps": sorted(widths)}


def _describe(node: Any, where: str = "model") -> dict[str, Any]:
    """The JSON description of `node` (see the module docstring); `where` names it in errors."""
    if node is None:
        return {"kind": "none"}
    if eqx.is_array(node):
        if isinstance(node, jax.core.Tracer):
            raise ValueError(f"save_model: `{where}` is a traced value; save models outside jit / vmap / grad.")
        try:
            dtype = np.dtype(node.dtype).name
        except TypeError:  # extended dtypes (PRNG keys) are not NumPy dtypes
            dtype = str(node.dtype)
        if dtype not in _DTYPES:
            raise ValueError(f"save_model: `{where}` is an array of dtype {dtype}, which a model file cannot hold.")
        return {"kind": "array", "shape": list(np.shape(node)), "dtype": dtype}
    if type(node) in _SCALARS:
        return {"kind": "value", "value": node}
    if type(node) is tuple or type(node) is list:
        kind = type(node).__name__
        return {"kind": kind, "items": [_describe(item, f"{where}[{i}]") for i, item in enumerate(node)]}
    if type(node) is dict:
        if not (all(type(key) is str for key in node) or all(type(key) is int for key in node)):
            raise ValueError(f"save_model: the keys of `{where}` must be all strings or all integers: {list(node)}.")
        items = []
        for key, value in node.items():
            items.append([key, _describe(value, f"{where}[{key!r}]")])
        return {"kind": "dict", "items": items}
    if isinstance(node, eqx.Module):
        return _describe_module(node, where)
    raise ValueError(
        f"save_model: cannot describe `{where}` (a {type(node).__module__}.{type(node).__qualname__}); a model file "
        "holds equinox Modules, tuples, lists, dicts, None, arrays and Python numbers / strings."
    )


def _describe_module(module: eqx.Module, where: str) -> dict[str, Any]:
    cls = type(module)
    fields = dataclasses.fields(module)
    names = {f.name for f in fields}
    extra = set(vars(module)) - names
    if extra:
        raise ValueError(
            f"save_model: cannot describe `{where}` (a {cls.__qualname__}): it holds attributes that are not "
            f"fields ({', '.join(sorted(extra))})."
        )
    static, children = {}, {}
    for f in fields:
        if f.name not in vars(module):
            raise ValueError(f"save_model: cannot describe `{where}` (a {cls.__qualname__}): `{f.name}` is not set.")
        value = vars(module)[f.name]
        if f.metadata.get("static", False):
            static[f.name] = _encode_static(value, f"{where}.{f.name}")
        else:
            children[f.name] = _describe(value, f"{where}.{f.name}")
    return {
        "kind": "module",
        "module": cls.__module__,
        "qualname": cls.__qualname__,
        "static": static,
        "fields": children,
    }


def _encode_static(value: Any, where: str) -> Any:
    if value is None or type(value) in _SCALARS:
        return value
    if type(value) is list:
        return [_encode_static(item, f"{where}[{i}]") for i, item in enumerate(value)]
    if type(value) is tuple:
        return {"tuple": [_encode_static(item, f"{where}[{i}]") for i, item in enumerate(value)]}
    raise ValueError(
        f"save_model: cannot describe the static field `{where}` (a {type(value).__qualname__}); static fields "
        "must hold numbers, strings, bools, None, or tuples / lists of those."
    )


def _save_leaf(handle: IO[bytes], leaf: Any) -> None:
    """Write an array leaf as a `.npy` record; Python scalar leaves are in the JSON header already."""
    if eqx.is_array(leaf):
        array = np.asarray(leaf)
        if not array.dtype.isnative:
            array = array.astype(array.dtype.newbyteorder("="))
        np.save(handle, array, allow_pickle=False)


class _HashingWriter:
    """A binary file-like object that writes through to `handle` and hashes what it writes (SHA-256)."""

    def __init__(self, handle: IO[bytes]):
        self.handle = handle
        self.digest = hashlib.sha256()

    def write(self, data: Any) -> int:
        self.digest.update(data)
        return self.handle.write(data)


def _write_atomically(path: pathlib.Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write through a temporary file in the target's folder, then rename it over the target (`os.replace`)."""
    if path.is_dir():
        raise ValueError(f"save_model: cannot write {path}: it is a folder; give a file name, e.g. {path / 'm.eqx'}.")
    # a short name of its own (not the target's name plus a suffix, which would exceed the file system's limit of
    # 255 bytes for a long but legal target name)
    temporary = path.with_name(f".fj-{uuid.uuid4().hex[:12]}.tmp")
    try:
        # mode 0o666 less the umask, as for an ordinary new file (tempfile would make it 0o600)
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as err:
        raise ValueError(f"save_model: cannot write {path}: {err.strerror}; choose a writable path.") from err
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException as err:
        temporary.unlink(missing_ok=True)
        if isinstance(err, OSError):
            raise ValueError(f"save_model: cannot write {path}: {err.strerror}; choose a writable path.") from err
        raise


# ----------------------------------------------------------------------------------------------------------------
# loading
# ----------------------------------------------------------------------------------------------------------------


def _read_header(data: bytes, path: pathlib.Path) -> tuple[Any, int]:
    """The parsed JSON header of a model file's contents, and the offset where its arrays start."""
    if data[: len(MAGIC)] != MAGIC:
        raise ValueError(
            f"load_model: {path} is not a fricjax model file (it does not start with the line "
            f"{MAGIC.decode().strip()!r}); pickle files are never loaded."
        )
    start = len(MAGIC) + _LENGTH.size
    if len(data) < start:
        raise ValueError(f"load_model: {path} is damaged (the header is cut short).")
    (length,) = _LENGTH.unpack(data[len(MAGIC) : start])
    if length > len(data) - start:
        raise ValueError(f"load_model: {path} is damaged (header length {length} exceeds the file size).")
    try:
        return json.loads(data[start : start + length].decode("utf-8")), start + length
    except (ValueError, RecursionError) as err:
        raise ValueError(f"load_model: {path} is damaged (its header is not valid JSON: {err}).") from err


def _check_header(header: Any, path: pathlib.Path, verified: bool) -> None:
    """The format name and version; files of version 2 and later must match their checksum (`verified`)."""
    if not isinstance(header, dict) or header.get("format") != FORMAT or "tree" not in header:
        raise ValueError(f"load_model: {path} is damaged (its header lacks the format name or the model tree).")
    version = header.get("format_version")
    if type(version) is not int or version < 1:
        raise ValueError(f"load_model: {path} is damaged (format version {version!r}).")
    if version > FORMAT_VERSION:
        raise ValueError(
            f"load_model: {path} has format version {version}, newer than this fricjax reads ({FORMAT_VERSION}); "
            f"it was written by fricjax {header.get('fricjax')}: upgrade fricjax to load it."
        )
    if version >= 2 and (header.get("checksum") != "sha256" or not verified):
        raise ValueError(
            f"load_model: {path} is damaged: its contents do not match its SHA-256 checksum (the file was changed, "
            "cut short or extended after it was saved); save the model again or restore the file from a copy."
        )


def _allowed_classes(classes: Iterable[type]) -> dict[tuple[str, str], type]:
    """`{(module, qualname): class}` of the equinox Modules a file may instantiate."""
    if isinstance(classes, type):
        classes = (classes,)
    allowed: dict[tuple[str, str], type] = {}
    seen: set[type] = set()
    stack: list[type] = [eqx.Module]
    while stack:  # every equinox Module subclass defined in fricjax
        subclasses: list[type] = stack.pop().__subclasses__()
        for sub in subclasses:
            if sub not in seen:
                seen.add(sub)
                stack.append(sub)
                if sub.__module__.startswith("fricjax."):
                    allowed[(sub.__module__, sub.__qualname__)] = sub
    for cls in classes:
        if not (isinstance(cls, type) and issubclass(cls, eqx.Module)):
            raise TypeError(f"load_model: `classes` must hold equinox Module classes, got {cls!r}.")
        allowed[(cls.__module__, cls.__qualname__)] = cls
    return allowed


def _field(node: Any, key: str, kind: type, where: str, path: pathlib.Path) -> Any:
    if not isinstance(node, dict) or not isinstance(node.get(key), kind):
        raise ValueError(f"load_model: {path} is damaged (the description of `{where}` lacks a valid {key!r}).")
    return node[key]


def _build(node: Any, allowed: dict[tuple[str, str], type], where: str, path: pathlib.Path) -> Any:
    """The skeleton described by `node`: arrays as `jax.ShapeDtypeStruct`s, to be filled by equinox."""
    kind = _field(node, "kind", str, where, path)
    if kind == "none":
        return None
    if kind == "array":
        shape = _field(node, "shape", list, where, path)
        dtype = _field(node, "dtype", str, where, path)
        if not all(type(n) is int and n >= 0 for n in shape) or dtype not in _DTYPES:
            raise ValueError(f"load_model: {path} is damaged (`{where}`: shape {shape}, dtype {dtype!r}).")
        return jax.ShapeDtypeStruct(tuple(shape), jax.dtypes.canonicalize_dtype(jnp.dtype(dtype)))
    if kind == "value":
        value = node.get("value")
        if type(value) not in _SCALARS:
            raise ValueError(f"load_model: {path} is damaged (`{where}` holds {value!r}).")
        return value
    if kind in ("tuple", "list"):
        items = [
            _build(item, allowed, f"{where}[{i}]", path)
            for i, item in enumerate(_field(node, "items", list, where, path))
        ]
        return tuple(items) if kind == "tuple" else items
    if kind == "dict":
        out = {}
        for pair in _field(node, "items", list, where, path):
            if not (isinstance(pair, list) and len(pair) == 2 and type(pair[0]) in (str, int)):
                raise ValueError(f"load_model: {path} is damaged (an entry of `{where}`).")
            out[pair[0]] = _build(pair[1], allowed, f"{where}[{pair[0]!r}]", path)
        return out
    if kind == "module":
        return _build_module(node, allowed, where, path)
    raise ValueError(f"load_model: {path} is damaged (`{where}` has unknown kind {kind!r}).")


def _build_module(node: dict, allowed: dict[tuple[str, str], type], where: str, path: pathlib.Path) -> Any:
    module_name = _field(node, "module", str, where, path)
    qualname = _field(node, "qualname", str, where, path)
    static = _field(node, "static", dict, where, path)
    children = _field(node, "fields", dict, where, path)
    cls = allowed.get((module_name, qualname))
    if cls is None:
        moved = [c for (m, q), c in allowed.items() if q == qualname and m.split(".")[0] != "fricjax"]
        if len(moved) == 1:  # a class passed in `classes` that has moved (a notebook's __main__ -> a module)
            raise ValueError(
                f"load_model: {path} holds a {module_name}.{qualname} (at `{where}`); `classes` has "
                f"{moved[0].__module__}.{qualname}, from another module. The file names its class by module: "
                f"pass the class from {module_name!r}, or load it there and save it again from "
                f"{moved[0].__module__!r}."
            )
        raise ValueError(
            f"load_model: {path} holds a {module_name}.{qualname} (at `{where}`), which is neither a fricjax Module "
            f"nor in `classes`; if you trust the file, pass the class: "
            f"fj.load_model(path, classes=({qualname.split('.')[-1]},))."
        )
    if getattr(cls, "__abstractmethods__", None) or getattr(cls, "__abstractvars__", None):
        raise ValueError(f"load_model: {path} is damaged (`{where}` is of the abstract class {qualname}).")
    fields = dataclasses.fields(cls)
    expected_static = {f.name for f in fields if f.metadata.get("static", False)}
    expected_children = {f.name for f in fields} - expected_static
    # a static field added to a class since the file was written, with a default, takes it (older files still load)
    defaults = {f.name: f.default for f in fields if f.name in expected_static and f.default is not dataclasses.MISSING}
    static = {name: defaults[name] for name in expected_static - set(static) if name in defaults} | static
    if set(static) != expected_static or set(children) != expected_children:
        raise ValueError(
            f"load_model: the description of `{where}` in {path} does not match {qualname} (fields "
            f"{sorted(set(static) | set(children))} in the file, {sorted(expected_static | expected_children)} "
            "in the class); it was probably written by another version."
        )
    instance: Any = object.__new__(cls)  # as equinox's unflattening: no __init__, no __check_init__
    for f in fields:
        if f.name in expected_static:
            value = _decode_static(static[f.name], f"{where}.{f.name}", path)
        else:
            value = _build(children[f.name], allowed, f"{where}.{f.name}", path)
        object.__setattr__(instance, f.name, value)
    return instance


def _decode_static(value: Any, where: str, path: pathlib.Path) -> Any:
    if value is None or type(value) in _SCALARS:
        return value
    if type(value) is list:
        return [_decode_static(item, where, path) for item in value]
    if type(value) is dict and set(value) == {"tuple"} and type(value["tuple"]) is list:
        return tuple(_decode_static(item, where, path) for item in value["tuple"])
    raise ValueError(f"load_model: {path} is damaged (the static field `{where}` holds {value!r}).")


def _load_leaf(handle: IO[bytes], like: Any) -> Any:
    """Read the `.npy` record of an array leaf (no pickle) and check it against the header."""
    if not isinstance(like, jax.ShapeDtypeStruct):
        return like  # a Python scalar from the header
    array = np.lib.format.read_array(handle, allow_pickle=False)
    if array.dtype.kind == "V" and like.dtype.kind == "V" and array.dtype.itemsize == like.dtype.itemsize:
        array = array.view(like.dtype)  # bfloat16 and other ml_dtypes are written as raw bytes
    if array.shape != like.shape or jax.dtypes.canonicalize_dtype(array.dtype) != like.dtype:
        raise ValueError(
            f"the file holds an array of shape {array.shape} and dtype {array.dtype} where its header says "
            f"shape {like.shape} and dtype {like.dtype}"
        )
    return jnp.asarray(array)
