"""mkdocs hooks of the documentation site (mkdocs.yml `hooks:`): generated pages, notebooks, links, equations.

- The API reference pages are generated from `dir(fricjax)` and its sub-namespaces (api.py) and put in the
  navigation under "API reference".
- The notebooks are executed (notebooks.py: smoke size, cached by their inputs; a cell that raises fails the
  build) and converted to Markdown pages with their figures as PNG files, under "Notebooks"; the original `.ipynb`
  is offered for download beside each.
- Paper keys and `fj.NAME` code spans become links (links.py; the docstrings get the same by griffe_links.py).
- Equations written `$...$` / `$$...$$` (pymdownx.arithmatex, generic mode) are converted to MathML at build
  time (latex2mathml): the pages need no script and no network to show them; a formula latex2mathml cannot
  convert fails the build.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import pathlib
import re
import sys
import time

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

HOOKS = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HOOKS))

import api  # noqa: E402
import links  # noqa: E402
import notebooks  # noqa: E402

ROOT = HOOKS.parents[1]
SRC = str(ROOT / "src")
log = logging.getLogger("mkdocs.hooks.fricjax")
API_TITLE = "API reference"
NOTEBOOKS_TITLE = "Notebooks"

_state: dict = {}


def _notebook_title(path: pathlib.Path) -> str:
    cells = json.loads(path.read_text())["cells"]
    for cell in cells:
        if cell["cell_type"] == "markdown":
            for line in "".join(cell["source"]).splitlines():
                if line.startswith("# "):
                    return line[2:].strip()
    return path.stem


def on_config(config):
    grouped = api.pages(SRC)
    _state["api"] = grouped
    _state["public"] = links.public_identifiers()
    api_nav = [{"Overview": "api/index.md"}] + [{s.title: f"api/{s.page}"} for s in grouped]
    paths = sorted(notebooks.NOTEBOOKS.glob("*.ipynb"))
    notebook_nav = [{_notebook_title(p): f"notebooks/{p.stem}.md"} for p in paths]
    placed = set()
    for item in config["nav"]:
        if isinstance(item, dict) and API_TITLE in item:
            item[API_TITLE] = api_nav
            placed.add(API_TITLE)
        if isinstance(item, dict) and NOTEBOOKS_TITLE in item:
            item[NOTEBOOKS_TITLE] = notebook_nav
            placed.add(NOTEBOOKS_TITLE)
    missing = {API_TITLE, NOTEBOOKS_TITLE} - placed
    if missing:
        raise ValueError(f"mkdocs.yml: the nav needs the entries {sorted(missing)} (filled by docs/_hooks/build.py)")
    return config


@event_priority(50)  # before the search plugin and mkdocstrings see the files
def on_files(files: Files, config) -> Files:
    grouped = _state["api"]
    files.append(File.generated(config, "api/index.md", content=api.index_markdown(SRC, grouped)))
    for section, items in grouped.items():
        files.append(File.generated(config, f"api/{section.page}", content=api.page_markdown(SRC, section, items)))

    start = time.perf_counter()
    executed = notebooks.execute_all(log=log.info)
    for name, path in executed.items():
        stem = pathlib.Path(name).stem
        if isinstance(path, str):  # it could not run here (no data folder): its page says why, its source is offered
            title = _notebook_title(notebooks.NOTEBOOKS / name)
            note = (
                f'# {title}\n\n!!! note "Not executed in this build"\n    {path}.\n\n[Download the notebook]({name})\n'
            )
            files.append(File.generated(config, f"notebooks/{stem}.md", content=note))
            files.append(File.generated(config, f"notebooks/{name}", abs_src_path=str(notebooks.NOTEBOOKS / name)))
            continue
        markdown, images = notebook_markdown(path, stem)
        files.append(File.generated(config, f"notebooks/{stem}.md", content=markdown))
        for image_name, data in images.items():
            files.append(File.generated(config, f"notebooks/{stem}_files/{image_name}", content=data))
        source = notebooks.NOTEBOOKS / name
        files.append(File.generated(config, f"notebooks/{name}", abs_src_path=str(source)))
    log.info(f"notebooks ready in {time.perf_counter() - start:.0f} s")
    return files


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def _text(value) -> str:
    return "".join(value) if isinstance(value, list) else value


def _fenced(text: str, language: str) -> list[str]:
    text = _ANSI.sub("", text).rstrip("\n")
    fence = "````" if "```" in text else "```"
    return [f"{fence}{language}", text, fence, ""]


def notebook_markdown(path: pathlib.Path, stem: str) -> tuple[str, dict[str, bytes]]:
    """A Markdown page of an executed notebook: its cells, its outputs, its figures as PNG files."""
    import nbformat

    notebook = nbformat.read(path, as_version=4)
    lines: list[str] = []
    images: dict[str, bytes] = {}
    first_heading = True
    for index, cell in enumerate(notebook.cells):
        if cell.cell_type == "markdown":
            lines += [cell.source, ""]
            if first_heading and cell.source.lstrip().startswith("# "):
                first_heading = False
                lines += [
                    '!!! info "Executed during the documentation build"',
                    "",
                    "    This page is the notebook "
                    f"[`notebooks/{stem}.ipynb`]({stem}.ipynb) run at its smoke size (`FRICJAX_SMOKE=1`: shorter "
                    "records, fewer models and steps than the figures quoted in its text, which are measured at "
                    'full size). Run it yourself: `pip install -e ".[notebooks]"`, then `jupyter lab notebooks/` '
                    "(unset `FRICJAX_SMOKE` for the full size).",
                    "",
                ]
            continue
        if cell.cell_type != "code":
            continue
        lines += _fenced(cell.source, "python")
        for number, output in enumerate(cell.get("outputs", [])):
            kind = output.get("output_type")
            if kind == "stream":
                lines += _fenced(_text(output["text"]), "text")
            elif kind in ("execute_result", "display_data"):
                data = output.get("data", {})
                if "image/png" in data:
                    image_name = f"cell{index:02d}_{number}.png"
                    images[image_name] = base64.b64decode(_text(data["image/png"]))
                    lines += [f"![figure of cell {index}]({stem}_files/{image_name}){{ .notebook-figure }}", ""]
                elif "text/html" in data:
                    lines += ['<div class="notebook-html" markdown="0">', _text(data["text/html"]), "</div>", ""]
                elif "text/markdown" in data:
                    lines += [_text(data["text/markdown"]), ""]
                elif "text/plain" in data:
                    lines += _fenced(_text(data["text/plain"]), "text")
            elif kind == "error":  # cannot happen: execution raises first; kept so a stored error is never hidden
                raise RuntimeError(f"{path.name}: cell {index} holds an error output: {output.get('ename')}")
    return "\n".join(lines), images


def on_page_markdown(markdown: str, page, config, files) -> str:
    return links.link_markdown(markdown, _state["public"])


_INLINE = re.compile(r'<span class="arithmatex">\\\((.*?)\\\)</span>', re.S)
_BLOCK = re.compile(r'<div class="arithmatex">\\\[(.*?)\\\]</div>', re.S)


def _mathml(latex: str, display: str, page) -> str:
    from latex2mathml.converter import convert

    source = html.unescape(latex).strip()
    try:
        return convert(source, display=display)
    except Exception as error:  # noqa: BLE001 - any failure of the converter fails the build, naming the formula
        raise ValueError(f"{page.file.src_uri}: cannot convert the formula {source!r} to MathML: {error}") from error


def on_page_content(content: str, page, config, files) -> str:
    content = _BLOCK.sub(lambda m: _mathml(m.group(1), "block", page), content)
    return _INLINE.sub(lambda m: _mathml(m.group(1), "inline", page), content)
