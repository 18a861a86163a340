"""Every fenced Python block of README.md and docs/**/*.md runs, in reading order.

The blocks of one Markdown file share one namespace, as a reader pasting them in order into one interpreter would;
each file runs in its own subprocess (working directory a fresh temporary folder, ``FRICJAX_DATA`` and
``MPLBACKEND=Agg`` set) under a timeout. A ``--8<-- "path"`` line (pymdownx.snippets, as the site build uses) is
replaced by the file it names. A block whose first line starts with ``>>>`` is run as a doctest (its printed output
is checked) in the same namespace.

**Convention for blocks that are not meant to run** (output samples, fragments of a larger program): an HTML comment
``<!-- no-run -->`` on the line right before the opening fence. It is invisible on GitHub and on the site. Use it
sparingly: a block that takes long should be made short (fewer steps, a shorter record), not excluded. Only
```` ```python ```` fences are run; ```` ```bash ```` and other languages never are.

Files whose blocks take more than a few seconds are in ``SLOW`` (the slow tier); the rest run in the fast tier.

The README is also checked for development history that does not belong in a user's guide (commit hashes, issue
references, figures with their old values), and its first two commands for agreement with what ``.ci/run`` runs.
"""

import doctest
import json
import os
import pathlib
import re
import subprocess
import sys
import textwrap

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA_DIR = os.environ.get("FRICJAX_DATA", str(ROOT.parent / "shared" / "data"))
NO_RUN = "<!-- no-run -->"
_FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
_SNIPPET = re.compile(r'^--8<--\s+"([^"]+)"\s*$', re.MULTILINE)

# seconds each file takes on a quiet 2-core machine (compilation included), when more than a few
SLOW = {
    "README.md": 45,
    "docs/concepts.md": 40,
    "docs/exercises/boucwen.md": 70,
    "docs/exercises/compare.md": 90,
    "docs/exercises/emps.md": 40,
    "docs/models/gms.md": 20,
    "docs/models/kernel.md": 30,
    "docs/models/lugre.md": 20,
    "docs/models/neural-narx.md": 25,
    "docs/models/polynomial-narx.md": 10,
    "docs/write-your-own-model.md": 12,
    # fast tier under 5 minutes cold on 2 cores (2026-11-27): these run in the slow tier
    "docs/models/static.md": 20,
    "docs/models/dahl.md": 20,
    "docs/models/maxwell-slip.md": 20,
}


def python_blocks(path: pathlib.Path) -> list[tuple[int, str]]:
    """The ``(line, source)`` of every runnable ```` ```python ```` block of a Markdown file, in order."""
    text = path.read_text()
    blocks = []
    for match in _FENCE.finditer(text):
        before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1].strip()
        if before == NO_RUN:
            continue
        source = _SNIPPET.sub(lambda m: (ROOT / m.group(1)).read_text(), match.group(1))
        blocks.append((text[: match.start()].count("\n") + 2, source))
    return blocks


def markdown_files() -> list[str]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return [str(f.relative_to(ROOT)) for f in files if python_blocks(f)]


_RUNNER = textwrap.dedent(
    """
    import doctest, json, sys
    blocks = json.loads(sys.stdin.read())
    namespace = {"__name__": "__main__"}
    for name, line, source in blocks:
        label = f"{name}:{line}"
        print(f"--- {label}", flush=True)
        if source.lstrip().startswith(">>>"):
            test = doctest.DocTestParser().get_doctest(source, namespace, label, name, line)
            runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
            runner.run(test, clear_globs=False)
            if runner.failures:
                sys.exit(f"doctest block {label} failed")
        else:
            exec(compile(source, label, "exec"), namespace)
    """
)


def run_markdown(name: str, tmp_path: pathlib.Path, timeout: float) -> None:
    blocks = [(name, line, source) for line, source in python_blocks(ROOT / name)]
    env = {**os.environ, "FRICJAX_DATA": DATA_DIR, "MPLBACKEND": "Agg", "PYTHONPATH": str(ROOT / "src")}
    env["FRICJAX_CACHE_DIR"] = str(tmp_path / "jax-cache")  # fj.enable_compilation_cache() in a block: not ~/.cache
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _RUNNER],
            input=json.dumps(blocks),
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired as error:
        out = error.stdout.decode() if isinstance(error.stdout, bytes) else (error.stdout or "")
        pytest.fail(f"{name}: blocks ran past {timeout:.0f} s; last started: {out.strip().splitlines()[-1:]}")
    assert proc.returncode == 0, f"{name}: a block failed\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"


@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in markdown_files()],
)
def test_markdown_python_blocks_run_in_order(name, tmp_path):
    run_markdown(name, tmp_path, timeout=max(60.0, 4.0 * SLOW.get(name, 10)))


def test_every_slow_entry_names_a_markdown_file_with_blocks():
    assert set(SLOW) <= set(markdown_files())


def test_block_parser_honours_no_run_and_snippets(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "text\n\n```python\nx = 1\n```\n\n<!-- no-run -->\n```python\nraise SystemExit\n```\n\n```bash\nls\n```\n"
        '\n```python\n--8<-- "docs/examples/spring_slider.py"\n```\n\n```python\n>>> 1 + 1\n2\n```\n'
    )
    blocks = python_blocks(page)
    assert [line for line, _ in blocks] == [4, 17, 21]
    assert blocks[0][1] == "x = 1\n"
    assert "class" in blocks[1][1] and "--8<--" not in blocks[1][1]
    assert doctest.DocTestParser().get_examples(blocks[2][1])[0].want == "2\n"


# a commit hash: 7-40 hex digits with at least one letter and one digit (plain numbers and words are not hashes)
_HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
# issue references and the phrases of a development log: "before this", figures that moved ("0.0998 -> 0.104 %")
_HISTORY = re.compile(
    r"\bissues? #?\d+|\bbefore this\b|\bpreviously\b|\bused to be\b|\bit was \d|\d\s*(?:->|→)\s*\d", re.IGNORECASE
)


def test_readme_has_no_development_history():
    text = (ROOT / "README.md").read_text()
    found = sorted(set(_HASH.findall(text)) | {m.group(0) for m in _HISTORY.finditer(text)})
    assert not found, f"README.md holds development history (commit hashes, issue references, old figures): {found}"
    assert not _HASH.search("a 1000000-sample record, 40 000 steps, decade") and _HASH.search("see 7f339c2")


def test_readme_first_commands_are_those_ci_runs():
    """.ci/run runs the README's first two commands (install + main job, then the fast tier): they must agree."""
    commands = re.findall(r"^```bash\n(.*?)\n```", (ROOT / "README.md").read_text(), re.MULTILINE | re.DOTALL)
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[0] == 'python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && fricjax compare'
    assert commands[0] in ci
    assert commands[1] == ". .venv/bin/activate && python -m pytest"
    assert "python -m pytest" in ci
