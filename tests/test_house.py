"""Three house rules for lbc_core and lbc_addon, checked: no module holding more than one job, no function longer
than a reviewer can hold in mind, and no constant buried under a lab notebook.

- A module is at most MAX_MODULE_LINES lines: a longer one holds more than one job; move one into a module of its own.
- A function's body (its docstring left out) is at most MAX_BODY_LINES lines: split a longer one into well-named
  helpers.
- A module-level UPPER_CASE constant has at most MAX_COMMENT_LINES comment lines right above it: what it is, its unit,
  and the bench/RESULTS.md section that measured it; the measurements themselves live in RESULTS.md.

Exceptions a reviewer accepted are in ALLOWED, each with its reason; an entry the code no longer needs fails too, so
the list only shrinks. Every module is parsed with ``ast``, never imported. Runs in the fast tier (no marker).
"""

import ast
import re
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MAX_BODY_LINES = 60
MAX_COMMENT_LINES = 3
MAX_MODULE_LINES = 600
CONSTANT = re.compile(r"_?[A-Z][A-Z0-9_]*")

# "path:name" (a function's qualified name, Class.method, or a constant's) → the reason a reviewer accepted.
ALLOWED = {
}


def modules():
    """Every module of lbc_core (sub-packages included) and lbc_addon, as paths relative to the repository."""
    paths = sorted(ROOT.glob("lbc_core/**/*.py")) + sorted(ROOT.glob("lbc_addon/*.py"))
    return [path.relative_to(ROOT).as_posix() for path in paths if "__pycache__" not in path.parts]


def long_functions(source):
    """[(line, qualified name, body lines)] of the functions whose body, docstring left out, exceeds MAX_BODY_LINES."""
    found = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                body = child.body[1:] if _docstring_first(child) and len(child.body) > 1 else child.body
                lines = child.end_lineno - body[0].lineno + 1
                if lines > MAX_BODY_LINES:
                    found.append((child.lineno, name, lines))
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return found


def _docstring_first(function):
    first = function.body[0]
    return isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str)


def buried_constants(source):
    """[(line, names, comment lines)] of the module-level assignments to UPPER_CASE names (in module-level if, try
    and with blocks too) with more than MAX_COMMENT_LINES contiguous comment lines right above them."""
    lines = source.splitlines()
    found = []
    for node in _module_statements(ast.parse(source).body):
        targets = node.targets if isinstance(node, ast.Assign) else [node.target]
        names = [name.id for target in targets for name in (target.elts if isinstance(target, ast.Tuple) else [target])
                 if isinstance(name, ast.Name) and CONSTANT.fullmatch(name.id)]
        if not names:
            continue
        above = node.lineno - 2
        while above >= 0 and lines[above].lstrip().startswith("#"):
            above -= 1
        comments = node.lineno - 2 - above
        if comments > MAX_COMMENT_LINES:
            found.append((node.lineno, names, comments))
    return found


def _module_statements(body):
    """The assignments among ``body``'s statements and those of its if / try / with blocks, never inside a function
    or class."""
    for node in body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            yield node
        elif isinstance(node, (ast.If, ast.Try, ast.With)):
            for block in (node.body, getattr(node, "orelse", []), getattr(node, "finalbody", []),
                          *(handler.body for handler in getattr(node, "handlers", []))):
                yield from _module_statements(block)


def violations():
    """{"path:name": message} of every function and constant that breaks a rule, allowed or not."""
    found = {}
    for path in modules():
        source = (ROOT / path).read_text(encoding="utf-8")
        for line, name, lines in long_functions(source):
            found[f"{path}:{name}"] = (
                f"{path}:{line}: function {name} has a body of {lines} lines (over {MAX_BODY_LINES}): split it into "
                f"well-named helpers, or add '{path}:{name}' to ALLOWED in tests/test_house.py with the reason a "
                "reviewer accepted")
        if source.count("\n") > MAX_MODULE_LINES:
            found[path] = (f"{path} has {source.count(chr(10))} lines (over {MAX_MODULE_LINES}): it holds more than one "
                           "job; move one into a module of its own in the same folder")
        for line, names, comments in buried_constants(source):
            for name in names:
                found[f"{path}:{name}"] = (
                    f"{path}:{line}: constant {name} has {comments} comment lines above it (over "
                    f"{MAX_COMMENT_LINES}): say in a line or two what it is and its unit, and point to the "
                    "bench/RESULTS.md section that measured it (bench/RESULTS.md, \"Section title\"); move the "
                    "measurements there")
    return found


# ------------------------------------------------------------------------------------------------------ the rules


def test_no_module_function_or_constant_breaks_a_rule():
    broken = [message for key, message in sorted(violations().items()) if key not in ALLOWED]
    assert not broken, "\n".join(broken)


def test_every_allowance_is_still_needed():
    found = violations()
    stale = [key for key in ALLOWED if key not in found]
    assert not stale, ("these entries of ALLOWED in tests/test_house.py break no rule any more: remove them\n"
                       + "\n".join(stale))


def test_every_allowance_says_why():
    assert all(isinstance(reason, str) and reason.strip() for reason in ALLOWED.values())


# ------------------------------------------------------------------------------------------------------ the checker


def test_the_checker_flags_a_long_function_and_a_buried_constant():
    body = "".join(f"        x{k} = {k}\n" for k in range(MAX_BODY_LINES + 1))
    source = textwrap.dedent('''\
        """A module."""

        # One.
        # Two.
        # Three.
        # Four.
        NOTEBOOK, _HIDDEN = 1, 2
        # One.
        # Two.
        # Three.
        SHORT = 3
        lower_case = 4


        class Holder:
            def method(self):
                """A docstring is not counted."""
        ''') + body + textwrap.dedent('''

        def fits():
            """Exactly the limit."""
        ''') + "".join(f"    y{k} = {k}\n" for k in range(MAX_BODY_LINES))
    assert long_functions(source) == [(16, "Holder.method", MAX_BODY_LINES + 1)]
    assert buried_constants(source) == [(7, ["NOTEBOOK", "_HIDDEN"], 4)]


def test_the_checker_looks_into_module_level_blocks_and_nested_functions():
    source = textwrap.dedent('''\
        try:
            # 1
            # 2
            # 3
            # 4
            LIMIT = 1
        except ImportError:
            LIMIT = 2


        def outer():
            def inner():
        ''') + "".join(f"        z{k} = {k}\n" for k in range(MAX_BODY_LINES + 1))
    assert buried_constants(source) == [(6, ["LIMIT"], 4)]
    assert [name for _, name, _ in long_functions(source)] == ["outer", "outer.inner"]


def test_no_merge_conflict_markers_are_left_in_the_tree():
    """A merge once committed its conflict markers into the changelog unseen: no tracked text file may hold one."""
    import subprocess

    listed = subprocess.run(["git", "ls-files", "*.py", "*.md", "*.toml", "*.cfg", "Makefile"], cwd=ROOT,
                            capture_output=True, text=True).stdout.split()
    marked = [f"{path}:{number}" for path in listed if (ROOT / path).is_file()
              for number, line in enumerate((ROOT / path).read_text(encoding="utf-8").splitlines(), 1)
              if re.match(r"(<{7}|>{7}) |={7}$", line)]
    assert not marked, f"merge conflict markers left in: {', '.join(marked)}"
