"""The table of contents at the top of bench/RESULTS.md: write it again, or check that it is up to date.

    .venv/bin/python bench/results_toc.py           # rewrite the contents between the markers
    .venv/bin/python bench/results_toc.py --check   # exit 1 if a section is missing or a link is stale

The contents link every ``##`` section, and the ``###`` sections under the ones named in NESTED, by GitHub's anchors
(the heading's text lower-cased, punctuation dropped, spaces as hyphens, "-1", "-2" after repeats). They sit between
the two marker comments below, right after the title; a file without them gets them there. Only the contents change.
"""

import argparse
import re
import sys
import unicodedata
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
START = "<!-- contents: written by bench/results_toc.py -->"
END = "<!-- end of contents -->"
# The ## sections whose ### sections are listed too (by the start of their heading's text).
NESTED = ("The locality solver",)


def plain(heading):
    """A heading's text as GitHub renders it: no code ticks, emphasis or link syntax."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    return re.sub(r"[`*]|(?<!\w)_|_(?!\w)", "", text).strip()


def slug(text):
    """GitHub's anchor for a heading's plain text (before repeats are numbered)."""
    kept = "".join(c for c in text.lower() if c in " -_" or unicodedata.category(c)[0] in "LNM")
    return kept.replace(" ", "-")


def headings(text):
    """[(level, markdown text, anchor)] of every ## and ### heading outside code fences, in order."""
    found, seen, fenced = [], {}, False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
            continue
        match = None if fenced else re.match(r"(#{1,6}) +(.*?)\s*#*\s*$", line)
        if not match:
            continue
        title = plain(match.group(2))
        anchor = slug(title)
        repeat = seen.get(anchor, 0)
        seen[anchor] = repeat + 1
        if repeat:
            anchor = f"{anchor}-{repeat}"
        if len(match.group(1)) in (2, 3):
            found.append((len(match.group(1)), match.group(2), anchor))
    return found


def contents(text):
    """The contents block (markers included) for ``text``."""
    lines, nested = [START, "", "**Contents**", ""], False
    for level, title, anchor in headings(text):
        if level == 2:
            nested = plain(title).startswith(NESTED)
            lines.append(f"- [{title}](#{anchor})")
        elif nested:
            lines.append(f"  - [{title}](#{anchor})")
    return "\n".join(lines + ["", END])


def with_contents(text):
    """``text`` with its contents block written again (inserted after the title if there is none)."""
    if START in text:
        before, rest = text.split(START, 1)
        after = rest.split(END, 1)[1]
        body = before + after  # headings counted without the old contents
        return before + contents(body) + after
    title, _, rest = text.partition("\n")
    return f"{title}\n\n{contents(text)}\n{rest}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check; exit 1 if the contents are not up to date")
    parser.add_argument("path", nargs="?", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    text = args.path.read_text()
    new = with_contents(text)
    if args.check:
        if new != text:
            print(f"{args.path}: the contents are out of date; run bench/results_toc.py", file=sys.stderr)
            return 1
        return 0
    if new != text:
        args.path.write_text(new)
        print(f"wrote the contents of {args.path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
