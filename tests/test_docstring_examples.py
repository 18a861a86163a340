"""Every `>>>` example in a public docstring (the API reference's examples) runs and prints what it shows.

The examples sit in Markdown fences (```python ... ```) for the documentation site; a fence line ends an example's
expected output here, as a blank line does for doctest."""

import doctest
import inspect
import re

import pytest

import fricjax as fj


def _docstrings():
    """(label, docstring) of every public name of `fj` and of the public methods and properties its classes define."""
    out = {}
    for name in sorted(dir(fj)):
        if name.startswith("_"):
            continue
        obj = getattr(fj, name)
        if inspect.getdoc(obj) and ">>>" in (obj.__doc__ or ""):
            out[f"fj.{name}"] = obj.__doc__
        if inspect.isclass(obj):
            for attribute, member in vars(obj).items():
                doc = getattr(member, "__doc__", None) or ""
                if not attribute.startswith("_") and ">>>" in doc:
                    out[f"fj.{name}.{attribute}"] = doc
    return sorted(out.items())


EXAMPLES = _docstrings()


def test_the_public_docstrings_hold_examples():
    assert len(EXAMPLES) >= 40, [label for label, _ in EXAMPLES]


@pytest.mark.slow  # about 25 s for all of them on 2 cores (each compiles its own small programs)
@pytest.mark.parametrize("label, docstring", EXAMPLES, ids=[label for label, _ in EXAMPLES])
def test_docstring_example_runs(label, docstring):
    source = re.sub(r"^\s*```.*$", "", inspect.cleandoc(docstring), flags=re.MULTILINE)
    test = doctest.DocTestParser().get_doctest(source, {}, label, label, 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    report = []
    runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)
