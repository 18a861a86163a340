"""Cross-references in Markdown: paper keys to the References page, `fj.NAME` to the API reference.

The docstrings cite papers by local keys ("worden2007 §3.2") and name the API as `fj.simulate`. On the site
each key becomes a link to its full reference (an anchor `ref-KEY` on references.md) and each `fj.NAME` in a code
span a link to NAME's entry in the API reference. Both go through mkdocs-autorefs, so in a strict build a key
without a reference, or a link to no entry, fails the build. Fenced code blocks and other code spans are left
alone.
"""

from __future__ import annotations

import re

# the papers' keys as the code cites them (the full references: docs/references.md, anchors "ref-KEY")
PAPER_KEYS = ("worden2007", "parlitz2004", "emps-ensemble", "kernel-method", "amthor")

_FENCE = re.compile(r"^( {0,8})(```|~~~)")
_CODE_SPAN = re.compile(r"(`+)(.+?)\1", re.S)
_KEY = re.compile(r"(?<![\w\-\[/#.])(" + "|".join(re.escape(k) for k in PAPER_KEYS) + r")(?![\w\-\]])")
_API = re.compile(r"fj\.((?:compare|emps|boucwen)\.)?([A-Za-z_][A-Za-z0-9_]*)((?:\.[A-Za-z_][A-Za-z0-9_]*)*)(\(\))?")


def _link_text(text: str, public: frozenset[str]) -> str:
    out, last = [], 0
    for match in _CODE_SPAN.finditer(text):
        out.append(_KEY.sub(r"[\1][ref-\1]", text[last : match.start()]))
        out.append(_link_code(match, text, public))
        last = match.end()
    out.append(_KEY.sub(r"[\1][ref-\1]", text[last:]))
    return "".join(out)


def _link_code(match: re.Match, text: str, public: frozenset[str]) -> str:
    span = match.group(0)
    api = _API.fullmatch(match.group(2).strip())
    already_linked = match.start() > 0 and text[match.start() - 1] == "[" and text[match.end() : match.end() + 1] == "]"
    if api is None or already_linked or len(match.group(1)) > 1:
        return span
    identifier = "fricjax." + (api.group(1) or "") + api.group(2)
    if identifier not in public:
        return span
    return f"[{span}][{identifier}]"


def link_markdown(markdown: str, public: frozenset[str]) -> str:
    """`markdown` with paper keys and `fj.NAME` code spans turned into autorefs links (code blocks untouched)."""
    lines = markdown.split("\n")
    blocks: list[tuple[bool, list[str]]] = []  # (is code, lines)
    fence = None
    for line in lines:
        match = _FENCE.match(line)
        if fence is None and match:
            fence = match.group(2)
            blocks.append((True, [line]))
        elif fence is not None:
            blocks[-1][1].append(line)
            if line.strip().startswith(fence):
                fence = None
        elif line.lstrip().startswith("#"):  # a heading: left as it is (no link inside a heading)
            blocks.append((True, [line]))
        elif blocks and not blocks[-1][0]:
            blocks[-1][1].append(line)
        else:
            blocks.append((False, [line]))
    return "\n".join("\n".join(block) if code else _link_text("\n".join(block), public) for code, block in blocks)


def public_identifiers() -> frozenset[str]:
    """Every public identifier the API reference renders: "fricjax.NAME" and "fricjax.NAMESPACE.NAME"."""
    from api import NAMESPACES, public_names

    import fricjax

    names = {f"fricjax.{n}" for n in public_names(fricjax)}
    for namespace in NAMESPACES:
        names |= {f"fricjax.{namespace}.{n}" for n in public_names(getattr(fricjax, namespace))}
    return frozenset(names)
