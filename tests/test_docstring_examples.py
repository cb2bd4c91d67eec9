"""Every ``>>>`` example in lbc_core's docstrings runs and prints what it says (doctest), in the fast tier: an example
that drifts from the code fails here, not in a reader's hands. The examples of docs/python.md run in
test_docs_examples.py."""

import doctest
import importlib
from pathlib import Path

import numpy as np
import pytest

import lbc_core

ROOT = Path(lbc_core.__file__).parent


def modules_with_examples():
    """The dotted names of lbc_core's modules whose source holds a doctest prompt."""
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        if ">>> " in path.read_text(encoding="utf-8"):
            parts = path.relative_to(ROOT.parent).with_suffix("").parts
            found.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return found


def test_the_examples_are_found():
    assert len(modules_with_examples()) >= 7


@pytest.mark.parametrize("name", modules_with_examples())
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = [test for test in finder.find(module, name, extraglobs={"np": np}) if test.examples]
    assert tests, f"{name} has a '>>> ' that is no doctest"
    for test in tests:
        runner.run(test)
    assert runner.failures == 0, f"{runner.failures} example(s) of {name} failed: run python -m doctest -v on it"
