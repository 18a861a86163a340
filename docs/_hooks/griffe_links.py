"""A griffe extension: paper keys and `fj.NAME` in docstrings become links (see links.py), before rendering."""

from __future__ import annotations

import pathlib
import sys

import griffe

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from links import link_markdown, public_identifiers  # noqa: E402


class DocstringLinks(griffe.Extension):
    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        if pkg.name != "fricjax":
            return
        public = public_identifiers()
        seen: set[int] = set()

        def visit(obj: griffe.Object) -> None:
            if id(obj) in seen:
                return
            seen.add(id(obj))
            if obj.docstring is not None:
                obj.docstring.value = link_markdown(obj.docstring.value, public)
            for member in obj.members.values():
                if not member.is_alias:
                    visit(member)

        visit(pkg)
