"""bench/RESULTS.md's table of contents lists every ## section, by the anchor GitHub gives it."""

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench import results_toc  # noqa: E402


def test_slugs_are_githubs():
    assert results_toc.slug("2D (woody unless said otherwise)") == "2d-woody-unless-said-otherwise"
    assert results_toc.slug("The starting penalty c_d / √n (3D)") == "the-starting-penalty-c_d--n-3d"
    assert results_toc.slug(results_toc.plain("Where `bench/floors.py` goes")) == "where-benchfloorspy-goes"
    assert [anchor for _, _, anchor in results_toc.headings("## A\n\n## A\n\n```\n## not one\n```\n### A\n")] \
        == ["a", "a-1", "a-2"]


def test_every_section_is_in_the_contents():
    text = results_toc.RESULTS.read_text()
    assert results_toc.START in text and results_toc.END in text
    listed = text.split(results_toc.START, 1)[1].split(results_toc.END, 1)[0]
    links = re.findall(r"^ *- \[.*\]\(#([^)]*)\)$", listed, flags=re.M)
    sections = [line for line in text.splitlines() if line.startswith("## ")]
    assert len(sections) > 10
    for line in sections:
        anchor = results_toc.slug(results_toc.plain(line[3:]))
        assert any(link == anchor or re.fullmatch(re.escape(anchor) + r"-\d+", link) for link in links), \
            f"{line!r} is not in bench/RESULTS.md's contents: run bench/results_toc.py"
    assert results_toc.main(["--check"]) == 0, "the contents are out of date: run bench/results_toc.py"
