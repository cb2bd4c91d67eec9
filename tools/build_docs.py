"""Build the API reference of lbc_core from its docstrings, with pdoc: one HTML page of the names lbc_core exports.

    .venv/bin/python tools/build_docs.py                 # into out/docs (make docs)
    .venv/bin/python tools/build_docs.py --output DIR

The docstrings are NumPy style with Sphinx roles (:func:`bind`). The build fails, with exit status 1, on any warning
pdoc gives and on any broken cross-reference: a role whose target does not exist in lbc_core. A role may name
something outside the reference (a constant of lbc_core.binding.options, say): it is then shown as code, not as a link.
tests/test_docs_build.py runs this build.
"""

import argparse
import html
import importlib
import os
import re
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = ROOT / "out" / "docs"
MODULE = "lbc_core"
ROLE = re.compile(r"(?::py)?:(?:mod|func|data|const|class|meth|attr|exc|obj):`~?\.?([^`]+)`")


def _documented(doc):
    """The documentation object and everything below it that the page shows."""
    yield doc
    for member in getattr(doc, "members", {}).values():
        if member.taken_from[0].startswith(MODULE) and not member.name.startswith("_"):
            yield from _documented(member)


def _exists(dotted):
    """Whether ``a.b.c`` names a module, or an object or attribute inside one (dataclass fields included)."""
    import pdoc.doc

    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            module = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        rest = parts[cut:]
        if not rest:
            return True
        if pdoc.doc.Module(module).get(".".join(rest)) is not None:
            return True
        target = module
        for name in rest:
            if not hasattr(target, name):
                return False
            target = getattr(target, name)
        return True
    return False


def broken_references(module_doc):
    """The roles of the documented docstrings whose targets do not exist: [(where, target)]."""
    broken = []
    for doc in _documented(module_doc):
        origin, qualname = doc.taken_from
        scopes = [origin, MODULE]
        # A role inside a class (or one of its members) may name a sibling member.
        owner = qualname.split(".")[0] if doc.kind != "module" else ""
        if owner:
            scopes.insert(0, f"{origin}.{owner}")
        for target in ROLE.findall(doc.docstring):
            name = target.removesuffix("()")
            if not any(_exists(candidate) for candidate in [name, *(f"{scope}.{name}" for scope in scopes)]):
                broken.append((doc.fullname, target))
    return broken


def broken_anchors(directory):
    """Links within the built pages to anchors that no page defines: [(page, link)]."""
    broken = []
    pages = {path.name: path.read_text(encoding="utf-8") for path in directory.glob("*.html")}
    ids = {name: set(re.findall(r'\bid="([^"]+)"', text)) for name, text in pages.items()}
    for name, text in pages.items():
        for link in re.findall(r'\bhref="([^"]*#[^"]*)"', text):
            page, _, anchor = html.unescape(link).partition("#")
            if page.startswith(("http:", "https:")):
                continue
            if anchor and anchor not in ids.get(page or name, ()):
                broken.append((name, link))
    return broken


def build(output=OUTPUT):
    """Write the reference into ``output``; returns the problems found (warnings and broken references), as text."""
    # numpy probes the CPU with lscpu when scipy imports it; pdoc would suppress that and warn.
    os.environ.setdefault("PDOC_ALLOW_EXEC", "1")
    import pdoc
    import pdoc.doc
    import pdoc.render

    output = Path(output)
    problems = []
    pdoc.render.configure(docformat="numpy", show_source=False, search=True,
                          footer_text=f"lbc {importlib.import_module(MODULE).__version__}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pdoc.pdoc(MODULE, output_directory=output)
        module_doc = pdoc.doc.Module(importlib.import_module(MODULE))
        problems += [f"broken reference in {where}: {target}" for where, target in broken_references(module_doc)]
    # pdoc gives some warnings once per place that asks; each is reported once.
    problems = list(dict.fromkeys(f"pdoc warns: {warning.message}" for warning in caught)) + problems
    problems += [f"broken link in {page}: {link}" for page, link in broken_anchors(output)]
    return problems


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", type=Path, default=OUTPUT, help="where the HTML goes (default: out/docs)")
    args = parser.parse_args(argv)
    problems = build(args.output)
    for problem in problems:
        print(problem, file=sys.stderr)
    if problems:
        return 1
    page = args.output / f"{MODULE}.html"
    print(f"{page.relative_to(ROOT) if page.is_relative_to(ROOT) else page}: the API reference of {MODULE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
