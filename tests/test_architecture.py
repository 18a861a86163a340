"""The architecture holds: dependencies point one way (no import cycles), one scan over time, public-only tests."""

from __future__ import annotations

import ast
import pathlib
import re

import fricjax as fj

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "fricjax"

# the layers of DESIGN.md, lowest first: a module may import only from its own layer or lower ones
LAYERS = [
    {"_xla_flags", "_lapack_threads", "_smoothing", "_constraints", "_inputs", "_metrics"},
    {"_models"},
    {"_simulate"},
    {"_systems", "_data"},
    {"_estimation"},
    {"_protocols", "_plot"},
    {"_cli", "compare", "__init__", "__main__"},
]


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: pathlib.Path, deferred: bool = False) -> set[str]:
    """Modules of fricjax imported at module level (with `deferred`, also those imported inside functions)."""
    name = _module_name(path)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree) if deferred else tree.body:
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = package[: len(package) - node.level + 1]
            target = ".".join([*base, *([node.module] if node.module else [])])
            if node.module is None:  # from . import x
                found.update(f"{target}.{alias.name}" for alias in node.names)
            else:
                found.add(target)
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("fricjax"):
            found.add(node.module)
    return found


def _graph(deferred: bool = False) -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        graph[name] = {m for m in _imports(path, deferred) if m in modules and m != name}
    return graph


# deferred imports against the layering, each a public convenience method of a model class
ALLOWED_DEFERRED = {
    "fricjax._models.combine._ensemble -> fricjax._simulate",  # AbstractEnsemble.predict / member_predictions
    "fricjax._models.combine._ensemble -> fricjax._estimation._ensemble_fit",  # WeightedEnsemble.fit
    "fricjax._models.combine._ensemble -> fricjax._data._record",  # FrictionData, under TYPE_CHECKING only
}


def _layer(module: str) -> int:
    top = module.split(".")[1] if "." in module else "__init__"
    for index, layer in enumerate(LAYERS):
        if top in layer:
            return index
    raise AssertionError(f"{module} is in no layer of the design; add it to LAYERS")


def test_no_import_cycles():
    graph = _graph()
    state: dict[str, int] = {}

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                raise AssertionError("import cycle: " + " -> ".join([*trail, node, nxt]))
            if nxt not in state:
                visit(nxt, [*trail, node])
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [])


def test_dependencies_point_one_way():
    wrong = [
        f"{module} -> {target}"
        for module, targets in _graph().items()
        for target in targets
        if _layer(target) > _layer(module)
    ]
    assert not wrong, "imports against the layering of DESIGN.md:\n" + "\n".join(sorted(wrong))


def test_deferred_imports_against_the_layering_are_the_documented_ones():
    upward = {
        f"{module} -> {target}"
        for module, targets in _graph(deferred=True).items()
        for target in targets
        if _layer(target) > _layer(module)
    }
    assert upward == ALLOWED_DEFERRED, sorted(upward ^ ALLOWED_DEFERRED)


def test_one_scan_over_time():
    """`lax.scan` appears in `_simulate.py` (time), in the sweep driver (optimiser steps; the fit driver loops
    over them with `lax.fori_loop`, its step count traced), in the NARX
    regressors' play operators (their states along a record for teacher-forced rows: a recursion of the
    displacement alone, no model) and in the BGBM's linear error filter (`B / A` of recorded signals, as
    `scipy.signal.lfilter`, no model), nowhere else."""
    users = sorted(
        str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if re.search(r"lax\.scan\(", p.read_text())
    )
    assert users == [
        "_estimation/_sweep.py",
        "_models/blackbox/_regressors.py",
        "_protocols/_emps_bgbm.py",
        "_simulate.py",
    ], users


def test_tests_and_notebooks_import_public_names_only():
    offenders = []
    for path in [*ROOT.glob("tests/*.py"), *ROOT.glob("notebooks/*.ipynb")]:
        if re.search(r"fricjax\._|fj\._", path.read_text()) and path.name != "test_architecture.py":
            offenders.append(path.name)
    assert not offenders, offenders


def test_public_names_have_docstrings():
    missing = [
        name
        for name in dir(fj)
        if not name.startswith("_") and callable(getattr(fj, name)) and not (getattr(fj, name).__doc__ or "").strip()
    ]
    assert not missing, missing
