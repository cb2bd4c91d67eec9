"""The API reference (make docs) builds from the docstrings with no pdoc warning and no broken reference, documents
every name lbc_core exports, and a broken reference or a bad export fails the build."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import lbc_core

pytestmark = pytest.mark.slow  # builds and installs: left out of the fast tier

ROOT = Path(__file__).resolve().parent.parent
BUILD = ROOT / "tools" / "build_docs.py"

pytest.importorskip("pdoc", reason="the API reference needs pdoc (pyproject.toml's dev extra)")


def run(code_or_args, tmp_path):
    """Run the build in a fresh interpreter (pdoc caches what it read); returns the finished process."""
    command = [sys.executable, *code_or_args] if isinstance(code_or_args, list) else [sys.executable, "-c", code_or_args]
    return subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300)


def test_reference_builds_cleanly_and_documents_every_exported_name(tmp_path):
    process = run([str(BUILD), "--output", str(tmp_path / "docs")], tmp_path)
    assert process.returncode == 0, process.stderr
    assert process.stderr == ""
    page = (tmp_path / "docs" / "lbc_core.html").read_text(encoding="utf-8")
    for name in lbc_core.__all__:
        assert f'<section id="{name}">' in page, name
    # The Sphinx roles became links: bind's docstring points at Cancelled, load_binding's at Binding.save.
    assert '<a href="#Cancelled">' in page and '<a href="#Binding.save">' in page
    assert (tmp_path / "docs" / "index.html").exists() and (tmp_path / "docs" / "search.js").exists()


def test_a_broken_reference_or_a_bad_export_fails_the_build(tmp_path):
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(BUILD.parent)!r})
        import inspect
        import lbc_core, build_docs
        inspect.unwrap(lbc_core.bind).__doc__ += "\\n\\nSee :func:`no_such_function` and :class:`Binding`.\\n"
        lbc_core.__all__ = [*lbc_core.__all__, "no_such_name"]
        sys.exit(build_docs.main(["--output", {str(tmp_path / "docs")!r}]))
    """)
    process = run(code, tmp_path)
    assert process.returncode == 1
    problems = process.stderr.splitlines()
    assert "broken reference in lbc_core.bind: no_such_function" in problems
    assert not any("Binding" in line for line in problems)  # an existing target is fine
    assert [line for line in problems if line.startswith("pdoc warns: Found 'no_such_name' in lbc_core.__all__")]
