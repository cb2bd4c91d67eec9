"""The Python examples of the documentation run as they are written.

Each ```python block of a page is run in order, in one namespace per page (a later block may use what an earlier
one made), in a temporary folder (the examples write files). A page without Python blocks fails, so that an example
dropped by mistake from a page that should have some is noticed.
"""

import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # binds end to end: left out of the fast tier

ROOT = Path(__file__).resolve().parent.parent
PAGES = ("README.md", "docs/python.md")
BLOCK = re.compile(r"^```python\n(.*?)^```", re.DOTALL | re.MULTILINE)


def python_blocks(page):
    """The ```python blocks of ``page`` (a path under the project's root), as (line number, code) pairs."""
    text = (ROOT / page).read_text(encoding="utf-8")
    return [(text.count("\n", 0, match.start()) + 1, match.group(1)) for match in BLOCK.finditer(text)]


def test_the_pattern_finds_blocks_and_their_lines():
    assert BLOCK.findall("text\n```python\nx = 1\n```\n```sh\nls\n```\n") == ["x = 1\n"]


@pytest.mark.parametrize("page", PAGES)
def test_every_python_example_runs(page, tmp_path, monkeypatch):
    blocks = python_blocks(page)
    assert blocks, f"{page} has no ```python example"
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"example of {page}"}
    for line, code in blocks:
        try:
            exec(compile(code, f"{page}, the example at line {line}", "exec"), namespace)
        except Exception as error:
            pytest.fail(f"{page}: the example at line {line} fails: {type(error).__name__}: {error}")
