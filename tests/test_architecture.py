"""The architecture holds: dependencies point one way (no import cycles), one scan over time, public-only tests."""

from __future__ import annotations

import ast
import pathlib
import re

import pytest

import fricjax as fj

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "fricjax"

# the layers of DESIGN.md, lowest first: a module may import only from its own layer or lower ones
LAYERS = [
    {
        "_xla_flags",
        "_lapack_threads",
        "_version",
        "_compilation_cache",
        "_smoothing",
        "_constraints",
        "_inputs",
        "_metrics",
        "_residuals",
        "_validation",
    },
    {"_models"},
    {"_simulate"},
    {"_systems", "_data"},
    {"_estimation"},
    {"_protocols", "_plot"},
    {"_cli", "compare", "emps", "boucwen", "_public", "__init__", "__main__"},
]


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: pathlib.Path, deferred: bool = False) -> set[str]:
    """Modules of fricjax imported at module level (with `deferred`, also those imported anywhere else: inside
    functions, and under `if TYPE_CHECKING:`, which counts as an import too)."""
    name = _module_name(path)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree) if deferred else tree.body:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.split(".")[0] == "fricjax")
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            base = package[: len(package) - node.level + 1]
            target = ".".join([*base, *([node.module] if node.module else [])])
            if node.module is None:  # from . import x: the module x, or an attribute of the package itself
                for alias in node.names:
                    found.add(f"{target}.{alias.name}")
                    if not _is_module(f"{target}.{alias.name}"):
                        found.add(target)
            else:
                found.add(target)
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("fricjax"):
            found.add(node.module)
    return found


def _is_module(name: str) -> bool:
    """Whether the dotted `name` is a module or package of the source tree."""
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _graph(deferred: bool = False) -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        graph[name] = {m for m in _imports(path, deferred) if m in modules and m != name}
    return graph


def _layer(module: str) -> int:
    top = module.split(".")[1] if "." in module else "__init__"
    for index, layer in enumerate(LAYERS):
        if top in layer:
            return index
    raise AssertionError(f"{module} is in no layer of the design; add it to LAYERS")


def test_no_import_cycles():
    """No cycle among the imports, those inside functions included."""
    graph = _graph(deferred=True)
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
    """No import runs upward in the layers of DESIGN.md, not even inside a function or under `TYPE_CHECKING`."""
    wrong = [
        f"{module} -> {target}"
        for module, targets in _graph(deferred=True).items()
        for target in targets
        if _layer(target) > _layer(module)
    ]
    assert not wrong, "imports against the layering of DESIGN.md:\n" + "\n".join(sorted(wrong))


# the estimation layer's rooms, lowest first (src/fricjax/_estimation/__init__.py): the loop and the linear algebra,
# then what a fit minimises, then the drivers, then what runs before a fit and the families' own fitters
ESTIMATION_ROOMS = [{"linear", "loop"}, {"problem"}, {"_fit", "_fit_arguments", "_sweep"}, {"initial", "families"}]


def test_the_estimation_rooms_import_one_way():
    """Inside `_estimation/`, a sub-package imports only from its own room or lower ones, never across a room of its
    own rank (`linear` and `loop` know nothing of each other), so the folder tree is the architecture."""

    def room(module: str) -> int | None:
        parts = module.split(".")
        if parts[:2] != ["fricjax", "_estimation"] or len(parts) < 3:
            return None
        for index, rooms in enumerate(ESTIMATION_ROOMS):
            if parts[2] in rooms:
                return index
        raise AssertionError(f"{module} is in no room of the estimation layer; add it to ESTIMATION_ROOMS")

    wrong = []
    for module, targets in _graph(deferred=True).items():
        mine = room(module)
        for target in targets:
            theirs = room(target)
            if mine is None or theirs is None or target.split(".")[2] == module.split(".")[2]:
                continue
            if theirs > mine or (theirs == mine and mine != 2):
                wrong.append(f"{module} -> {target}")
    assert not wrong, "imports against the rooms of _estimation:\n" + "\n".join(sorted(wrong))


def test_one_scan_over_time():
    """`lax.scan` and `lax.associative_scan` appear in the package `_simulate/` (time: every recursion along a
    record runs there, the NARX play operators and the BGBM's error filter included) and in the estimation loop
    over optimiser steps (`_estimation/loop/_loop.py`; the sweep driver's own until it moves there), nowhere else."""
    users = sorted(
        str(p.relative_to(PACKAGE))
        for p in PACKAGE.rglob("*.py")
        if re.search(r"lax\.(associative_)?scan\(", p.read_text())
    )
    in_simulate = {user for user in users if user.startswith("_simulate/")}
    assert in_simulate, users
    assert set(users) - in_simulate <= {"_estimation/loop/_loop.py", "_estimation/_sweep.py"}, users


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


def test_public_namespace_is_the_public_module():
    """`dir(fj)` is exactly the public names of `fricjax._public` (loaded on first use): nothing of the package's own
    machinery leaks in (a `from __future__ import annotations` in `__init__` made `fj.annotations` public)."""
    import importlib

    public = {name for name in vars(importlib.import_module("fricjax._public")) if not name.startswith("_")}
    assert {name for name in dir(fj) if not name.startswith("_")} == public


def test_import_and_help_answer_before_jax_loads():
    """`import fricjax` and `fricjax --help` import no JAX (the public names load on first use), so the command
    line's help and argument errors answer at once; the first public name loads everything."""
    import subprocess
    import sys

    probe = (
        "import sys, fricjax\n"
        "assert 'jax' not in sys.modules, 'import fricjax imported jax'\n"
        "import runpy\n"
        "sys.argv = ['fricjax', 'compare', '--help']\n"
        "try:\n"
        "    runpy.run_module('fricjax', run_name='__main__')\n"
        "except SystemExit:\n"
        "    pass\n"
        "assert 'jax' not in sys.modules, 'fricjax compare --help imported jax'\n"
        "fricjax.LuGre\n"
        "assert 'jax' in sys.modules and 'fricjax._estimation._fit' in sys.modules\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "--device" in done.stdout


def _concrete_model_classes() -> set[str]:
    """The names of the concrete model classes (subclasses of `AbstractModel`, not `Abstract*`) under `_models` and
    `_systems`, read from their class definitions."""
    bases: dict[str, list[str]] = {}
    for folder in ("_models", "_systems"):
        for path in (PACKAGE / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef):
                    bases[node.name] = [ast.unparse(b).split(".")[-1].split("[")[0] for b in node.bases]

    def is_model(name: str, seen: frozenset[str] = frozenset()) -> bool:
        return name == "AbstractModel" or any(
            b not in seen and is_model(b, seen | {name})
            for b in bases.get(name, [])
            if b in bases or b == "AbstractModel"
        )

    return {name for name in bases if not name.startswith("Abstract") and is_model(name)}


def test_no_code_outside_the_models_switches_on_a_model_class():
    """DESIGN.md v4: what only a model family knows is a method of its class (`breakaway_displacement`,
    `implausible`, `slipping`, `smoothing_scale`, `without_drift`, wrappers' `model` walk), so that a new friction model
    is one file. Flags `isinstance` / `issubclass` on a concrete model class (or on a name bound to a tuple of them),
    `cls is C` / `cls in (C, D)`, and dicts keyed by model classes, outside `_models`."""
    models = _concrete_model_classes()
    found = set()
    for path in PACKAGE.rglob("*.py"):
        relative = str(path.relative_to(PACKAGE))
        if relative.startswith("_models"):
            continue
        tree = ast.parse(path.read_text())
        tuples = {  # names bound to a class or a tuple of classes (GUESSABLE = (Coulomb, ...))
            target.id: {ast.unparse(e).split(".")[-1] for e in getattr(node.value, "elts", [node.value])}
            for node in ast.walk(tree)
            if isinstance(node, ast.Assign)
            for target in node.targets
            if isinstance(target, ast.Name)
        }

        def names(expr: ast.AST, tuples: dict[str, set[str]] = tuples) -> set[str]:
            out = set()
            for e in getattr(expr, "elts", [expr]):
                name = ast.unparse(e).split(".")[-1]
                out |= {name} | tuples.get(name, set())
            return out & models

        def scopes(node: ast.AST, where: str):
            for child in ast.iter_child_nodes(node):
                inner = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else where
                yield child, inner
                yield from scopes(child, inner)

        for node, where in scopes(tree, "<module>"):
            hit = set()
            if isinstance(node, ast.Call) and ast.unparse(node.func) in ("isinstance", "issubclass") and node.args[1:]:
                hit = names(node.args[1])
            elif isinstance(node, ast.Compare) and any(
                isinstance(o, (ast.Is, ast.IsNot, ast.In, ast.NotIn)) for o in node.ops
            ):
                hit = set().union(*(names(c) for c in node.comparators))
            elif isinstance(node, ast.Dict):
                hit = set().union(set(), *(names(k) for k in node.keys if k is not None))
            if hit:
                found.add((relative, where))
    assert not found, f"switches on model classes outside _models (make it a method of the class): {sorted(found)}"


def test_protocol_names_live_in_their_namespaces():
    """DESIGN.md v4: `fj.*` keeps models, data, simulate, fit and metrics; a benchmark's protocols are in its
    namespace (`fj.emps`, `fj.boucwen`, as `fj.compare`). The former flat names still read, with a warning."""
    for namespace in (fj.emps, fj.boucwen):
        names = [name for name in dir(namespace) if not name.startswith("_")]
        assert names and not set(names) & set(dir(fj)), namespace.__name__
    with pytest.warns(DeprecationWarning, match=r"fj\.fit_emps_idm moved to fj\.emps\.fit_emps_idm"):
        assert fj.fit_emps_idm is fj.emps.fit_emps_idm
    with pytest.warns(DeprecationWarning, match=r"fj\.boucwen\.score_boucwen"):
        assert fj.score_boucwen is fj.boucwen.score_boucwen
    with pytest.warns(DeprecationWarning, match=r"fj\.SweepResult is gone: the fit returns a batched fj\.Solution"):
        assert fj.SweepResult is fj.Solution
