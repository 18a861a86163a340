"""The API reference, generated at build time from the public namespaces (`dir(fricjax)` and its sub-namespaces
`fricjax.compare`, `fricjax.emps`, `fricjax.boucwen`).

Every public name is placed on the page of the private module it is defined in (found by griffe, which resolves
`from ._models.physics._lugre import LuGre as LuGre` to its target), in the order of `SECTIONS`; a name from a
module no section claims lands on the page "Other names", so a name added to `fricjax/__init__.py` is never
left out. Each name is rendered by mkdocstrings (`::: fricjax.NAME`): its signature, its docstring and its public
methods. tests/test_docs_site.py checks the built pages hold every public name.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import types


@dataclasses.dataclass(frozen=True)
class Section:
    page: str  # file name under api/
    title: str
    prefixes: tuple[str, ...]  # private modules (dotted, without "fricjax.") whose names go on this page
    intro: str


# the public sub-namespaces (modules of `fricjax`): their names are listed one by one as `fricjax.NAMESPACE.NAME`
NAMESPACES = ("compare", "emps", "boucwen")

SECTIONS = (
    Section(
        "simulate.md",
        "Simulation and inputs",
        ("_simulate", "_inputs"),
        "`fj.simulate` is the one loop over time for every model; `Motion` and `InputRecord` are what it runs on.",
    ),
    Section(
        "smoothing.md",
        "Smooth and exact, parameters",
        ("_smoothing", "_constraints"),
        "Smoothing strategies (`Exact`, `Smooth(eps)`) and the parameter wrappers (`Positive`, `Simplex`, "
        "`Fixed`) resolved once per call by `unwrap`.",
    ),
    Section(
        "physics.md",
        "Physics models",
        ("_models._base", "_models.physics"),
        "The model contract (`AbstractModel`: `init_state`, `step`, `feedback`) and the physics (grey-box) "
        "families: static curves, Stribeck curves, Dahl, LuGre, GMS, Maxwell-slip.",
    ),
    Section(
        "blackbox.md",
        "Black-box models",
        ("_models.blackbox",),
        "NARX regressors and the networks and polynomial models built on them.",
    ),
    Section(
        "combine.md",
        "Ensembles and sensor models",
        ("_models.combine",),
        "Models made of models: averaged and weighted ensembles, a sensor drift added to any model.",
    ),
    Section(
        "fitting.md",
        "Fitting",
        (
            "_estimation._fit",
            "_estimation._sweep",
            "_estimation.loop",
            "_estimation.problem",
            "_data._model_files",
        ),
        "`fj.fit` and `fj.least_squares` over the one optimisation loop: `Solution` and `RESULTS`, solvers "
        "(`AbstractSolver`, fricjax's Levenberg-Marquardt and the optax / optimistix adapters), losses and "
        "strategies, sweeps of many configurations in one program, model files.",
    ),
    Section(
        "linear.md",
        "Least squares and term selection",
        ("_estimation.linear", "_estimation.families", "_estimation"),
        "One linear-algebra kernel: least squares, covariance, forward orthogonal term selection (ERR / PRESS), "
        "and the identification functions built on it.",
    ),
    Section(
        "data.md",
        "Data",
        ("_data",),
        "Records, file I/O with units, the EMPS loader, the synthetic tribometer, preprocessing, differentiators.",
    ),
    Section(
        "systems.md",
        "EMPS: systems and protocols",
        (
            "_systems",
            "_protocols._emps_idm",
            "_protocols._emps_idm_data",
            "_protocols._emps_plateaus",
            "_protocols._emps_open_loop",
            "_protocols._emps_hybrid",
            "_protocols._emps_bgbm",
        ),
        "The EMPS axis as a model under `fj.simulate` (open and closed loop), its identification protocols and its "
        "grey + black-box models (hybrids, BGBM, ensembles): the protocols in the namespace `fj.emps`.",
    ),
    Section(
        "metrics.md",
        "Metrics",
        ("_metrics",),
        "Error measures as the papers report them.",
    ),
    Section(
        "boucwen.md",
        "Bouc-Wen: the benchmark's protocol",
        ("_protocols._boucwen",),
        "The scoring and the loss of the Bouc-Wen hysteresis benchmark, in the namespace `fj.boucwen`; the system "
        "(`fj.BoucWen`) and its records (`fj.load_boucwen`) are with the systems and the data.",
    ),
    Section(
        "compare.md",
        "fj.compare and the command line",
        ("_protocols", "_plot", "_cli", "compare"),
        "The identification exercise behind `fricjax compare`, as the public namespace `fj.compare`, and the "
        "command line itself (`fj.main`).",
    ),
)
OTHER = Section("other.md", "Other names", ("",), "Public names defined in modules no other page lists.")


@dataclasses.dataclass(frozen=True)
class Entry:
    identifier: str  # the dotted public path rendered by mkdocstrings: "fricjax.LuGre", "fricjax.compare.score"
    target: str  # where griffe finds it: "fricjax._models.physics._lugre.LuGre"


def public_names(namespace: types.ModuleType) -> list[str]:
    """The public names of a namespace: not underscored, and not a module (except the sub-namespaces)."""
    return [
        name
        for name in dir(namespace)
        if not name.startswith("_")
        and (not isinstance(getattr(namespace, name), types.ModuleType) or name in NAMESPACES)
    ]


@functools.cache
def _griffe_package(search_path: str):
    import griffe

    return griffe.load("fricjax", search_paths=[search_path], resolve_aliases=False)


def entries(search_path: str) -> list[Entry]:
    """Every public name of `fricjax` and of its sub-namespaces, with where its definition lives."""
    fricjax = importlib.import_module("fricjax")
    package = _griffe_package(search_path)
    found = []
    namespaces = [("fricjax", fricjax, package)]
    namespaces += [(f"fricjax.{name}", getattr(fricjax, name), package[name]) for name in NAMESPACES]
    for prefix, namespace, griffe_namespace in namespaces:
        for name in public_names(namespace):
            if prefix == "fricjax" and name in NAMESPACES:
                continue  # a sub-namespace: its names are listed one by one
            try:
                member = griffe_namespace[name]
                target = member.target_path if member.is_alias else member.path
                if target.startswith("fricjax._public."):  # the lazy namespace's one hop: to the definition
                    inner = package["_public"][target.rsplit(".", 1)[1]]
                    target = inner.target_path if inner.is_alias else inner.path
            except KeyError:  # not visible to static analysis: place it by its runtime module
                target = f"{getattr(getattr(namespace, name), '__module__', prefix)}.{name}"
            found.append(Entry(f"{prefix}.{name}", target))
    return found


def section_of(entry: Entry) -> Section:
    if entry.identifier.startswith("fricjax.compare."):
        return SECTIONS[-1]
    module = entry.target.rsplit(".", 1)[0].removeprefix("fricjax").removeprefix(".")
    best, length = OTHER, -1
    for section in SECTIONS:
        for prefix in section.prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > length:
                best, length = section, len(prefix)
    return best


def _source_order(search_path: str, entry: Entry) -> tuple[str, int]:
    package = _griffe_package(search_path)
    try:
        obj = package[entry.target.removeprefix("fricjax.")]
        return entry.target.rsplit(".", 1)[0], obj.lineno or 0
    except (KeyError, Exception):
        return entry.target, 0


def pages(search_path: str) -> dict[Section, list[Entry]]:
    """The API pages in order, each with its entries (grouped by defining module, in source order)."""
    grouped: dict[Section, list[Entry]] = {}
    for entry in entries(search_path):
        grouped.setdefault(section_of(entry), []).append(entry)
    ordered = {}
    for section in (*SECTIONS, OTHER):
        if section in grouped:
            ordered[section] = sorted(grouped[section], key=lambda e: _source_order(search_path, e))
    return ordered


def _module_summary(search_path: str, module: str) -> str:
    package = _griffe_package(search_path)
    try:
        docstring = package[module.removeprefix("fricjax.")].docstring
    except KeyError:
        return ""
    if docstring is None:
        return ""
    return inspect.cleandoc(docstring.value).split("\n\n")[0].replace("\n", " ")


def _namespace_page(namespace: str) -> str:
    """The page that renders a sub-namespace's docstring (and so its anchor, `fricjax.NAMESPACE`)."""
    return {"compare": "compare.md", "emps": "systems.md", "boucwen": "boucwen.md"}[namespace]


def page_markdown(search_path: str, section: Section, items: list[Entry]) -> str:
    lines = [f"# {section.title}", "", section.intro, ""]
    for namespace in NAMESPACES:
        if _namespace_page(namespace) == section.page:
            lines += [
                f"The public namespace `fj.{namespace}` (`import fricjax as fj`):",
                "",
                f"::: fricjax.{namespace}",
            ]
            lines += ["", "    options:", "      members: false", "      show_root_heading: false", ""]
    lines += ["Names on this page: " + ", ".join(f"[`{_short(e)}`][{e.identifier}]" for e in items) + ".", ""]
    module = None
    for entry in items:
        here = entry.target.rsplit(".", 1)[0]
        if here != module:
            module = here
            summary = _module_summary(search_path, module)
            if summary:
                lines += ["---", "", f"*{summary}*", ""]
        lines += [f"::: {entry.identifier}", ""]
    return "\n".join(lines)


def _short(entry: Entry) -> str:
    return "fj." + entry.identifier.removeprefix("fricjax.")


def index_markdown(search_path: str, grouped: dict[Section, list[Entry]]) -> str:
    lines = [
        "# API reference",
        "",
        "Generated at build time from the public namespaces, `dir(fricjax)` and `dir(fricjax.compare)`, "
        "`dir(fricjax.emps)`, `dir(fricjax.boucwen)`: every "
        "public name, with its signature and docstring, on the page of the module it is defined in. Import as "
        "`import fricjax as fj`.",
        "",
        "| page | names |",
        "|---|---|",
    ]
    for section, items in grouped.items():
        names = ", ".join(f"[`{_short(e)}`][{e.identifier}]" for e in items)
        lines.append(f"| [{section.title}]({section.page}) | {names} |")
    return "\n".join(lines) + "\n"
