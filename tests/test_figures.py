"""Every figure quoted in the README and the docs equals the cell of the benchmark table it comes from
(tools/figures.py: `python tools/figures.py` rewrites them; `make bench` does so after measuring)."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
import figures  # noqa: E402


@pytest.fixture(scope="module")
def found():
    return figures.tables(figures.BENCHMARKS.read_text(encoding="utf-8"))


@pytest.mark.parametrize("page", figures.PAGES, ids=lambda page: page.name)
def test_every_quoted_figure_equals_its_table(page, found):
    text = page.read_text(encoding="utf-8")
    wrong = [f"{key} | {row} | {column}: the page says {value!r}, the table {figures.cell(found, key, row, column)!r}"
             for key, row, column, value in figures.figures(text)
             if value != figures.cell(found, key, row, column)]
    assert not wrong, f"{page.name}: run python tools/figures.py\n" + "\n".join(wrong)


def test_the_readme_quotes_its_headline_figures_from_the_tables():
    assert len(figures.figures((ROOT / "README.md").read_text(encoding="utf-8"))) >= 4


def test_a_figure_that_drifted_is_caught_and_rewritten(found):
    text = "binds in <!-- figure: mesh-deform | bind | LBC -->1.0 s<!-- /figure --> here"
    right = figures.cell(found, "mesh-deform", "bind", "LBC")
    assert right != "1.0 s"
    assert figures.synced(text, found) == f"binds in <!-- figure: mesh-deform | bind | LBC -->{right}<!-- /figure --> here"
