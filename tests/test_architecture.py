"""The real import graph against docs/ARCHITECTURE.md ("Layers and imports"): the doc is the code.

Every module of lbc_core and lbc_addon is parsed with ``ast`` (module-level and function-level imports, relative and
absolute, ``from . import x``), never imported. A failure names the offending arrow and what to do about it.
Runs in the fast tier (no marker): the whole file takes a second or two.
"""

import ast
import functools
import re
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "ARCHITECTURE.md"
CORE, ADDON = "lbc_core", "lbc_addon"
BLENDER_MODULES = {"bpy", "bmesh", "mathutils", "gpu", "blf", "bgl", "idprop", "freestyle", "aud"}


# ------------------------------------------------------------------------------------------------------ the doc


def doc_block(text, kind):
    """The lines of the doc's fenced block ```kind, comments (#) and blank lines dropped; an indented line is joined
    to the line before it."""
    found = re.findall(rf"^```{re.escape(kind)}\n(.*?)^```", text, flags=re.S | re.M)
    assert len(found) == 1, f"docs/ARCHITECTURE.md needs exactly one ```{kind} block, found {len(found)}"
    lines = []
    for line in found[0].splitlines():
        line = line.split("#")[0].rstrip()
        if line and line[0].isspace() and lines:
            lines[-1] += " " + line.strip()
        elif line:
            lines.append(line.strip())
    return lines


def allowed_imports(text):
    """({module: set of modules it may import}, {module: layer number}) from the ```imports block.

    A line ``[N name]`` opens layer N; a line ``module: a b c`` (commas optional) lists what the module may import.
    """
    allowed, layers, layer = {}, {}, None
    for line in doc_block(text, "imports"):
        header = re.fullmatch(r"\[(\d+)\s[^\]]*\]", line)
        if header:
            layer = int(header.group(1))
            continue
        module, colon, targets = line.partition(":")
        module = module.strip()
        assert layer is not None and colon and module not in allowed, f"bad line in the doc's imports block: {line!r}"
        allowed[module] = set(targets.replace(",", " ").split())
        layers[module] = layer
    return allowed, layers


def private_allowances(text):
    """{(module, module it takes a private name from, name)} from the ```private-imports block
    (``module: target._name ...``)."""
    allowed = set()
    for line in doc_block(text, "private-imports"):
        module, _, names = line.partition(":")
        for dotted in names.replace(",", " ").split():
            target, _, name = dotted.rpartition(".")
            allowed.add((module.strip(), target, name))
    return allowed


def addon_api_names(text):
    """The lbc_core names the add-on may use, from the ```addon-api block."""
    return {name for line in doc_block(text, "addon-api") for name in line.replace(",", " ").split()}


# ----------------------------------------------------------------------------------------------- the real graph


def parsed(path):
    """The imports, attribute reads and calls of a source file, anywhere in it (one walk per version of the file)."""
    stat = path.stat()
    return _parsed(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=None)
def _parsed(path, mtime, size):
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    kinds = (ast.Import, ast.ImportFrom, ast.Attribute, ast.Call, ast.Assign)
    return tuple(node for node in ast.walk(tree) if isinstance(node, kinds))


def modules_of(root, package):
    """{short name: path} of every module of ``package`` under ``root``: "__init__" for the package itself,
    "meshing" for meshing/__init__.py, "meshing.common" for meshing/common.py."""
    found = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root / package).with_suffix("").parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts.pop()
        found[".".join(parts)] = path
    return found


def _resolve(source, level, module, package, known):
    """The short name of the module an import of ``module`` (relative at ``level``) in module ``source`` reads; None
    for a module outside ``package``."""
    if level == 0:
        if not module or module.split(".")[0] != package:
            return None
        dotted = module.split(".")[1:]
    else:
        here = source.split(".") if source in known and known[source].name == "__init__.py" else source.split(".")[:-1]
        here = [] if here == ["__init__"] else here
        dotted = here[:len(here) - (level - 1)] + (module.split(".") if module else [])
    return ".".join(dotted) or "__init__"


def imports_of(root, package):
    """Every import of a module of ``package`` by one of its modules: [(source, target, name, line)].

    ``name`` is the name taken (None for ``import x``); ``from .a import b`` where ``a.b`` is a module counts as an
    import of ``a.b``. Imports inside functions count the same as module-level ones.
    """
    known = modules_of(root, package)
    found = []
    for source, path in known.items():
        for node in parsed(path):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    target = _resolve(source, 0, alias.name, package, known)
                    if target is not None:
                        found.append((source, target, None, node.lineno))
            elif isinstance(node, ast.ImportFrom):
                target = _resolve(source, node.level, node.module, package, known)
                if target is None:
                    continue
                for alias in node.names:
                    submodule = alias.name if target == "__init__" else f"{target}.{alias.name}"
                    if submodule in known:
                        found.append((source, submodule, None, node.lineno))
                    else:
                        found.append((source, target, alias.name, node.lineno))
    return found


def external_imports(root, package):
    """Every import of a top-level module outside ``package``: [(source, top-level name, line)]."""
    found = []
    for source, path in modules_of(root, package).items():
        for node in parsed(path):
            if isinstance(node, ast.Import):
                found += [(source, alias.name.split(".")[0], node.lineno) for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                found.append((source, node.module.split(".")[0], node.lineno))
    return found


def private_uses(root, package):
    """Private names a module takes from another of the package: [(source, target, name, line)], by ``from x import
    _name`` or by ``x._name`` on a module bound by ``from . import x``."""
    known = modules_of(root, package)
    found = [(s, t, n, line) for s, t, n, line in imports_of(root, package)
             if n is not None and n.startswith("_") and not n.startswith("__")]
    for source, path in known.items():
        nodes = parsed(path)
        bound = {}
        for node in nodes:
            if isinstance(node, ast.ImportFrom) and node.level:
                target = _resolve(source, node.level, node.module, package, known)
                for alias in node.names:
                    submodule = alias.name if target == "__init__" else f"{target}.{alias.name}"
                    if submodule in known:
                        bound[alias.asname or alias.name] = submodule
        for node in nodes:
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound
                    and node.attr.startswith("_") and not node.attr.startswith("__")):
                found.append((source, bound[node.value.id], node.attr, node.lineno))
    return found


def arrows(imports):
    """{source: {target: first line}} of the imports between different modules."""
    graph = {}
    for source, target, _, line in imports:
        if source != target:
            graph.setdefault(source, {}).setdefault(target, line)
    return graph


# --------------------------------------------------------------------------------------------------- the checks


def arrow_violations(root, allowed, layers):
    """Messages for each import of lbc_core the doc does not allow."""
    found = []
    for source, targets in sorted(arrows(imports_of(root, CORE)).items()):
        for target, line in sorted(targets.items()):
            if target in allowed.get(source, set()):
                continue
            where = f"{where_in(root, CORE, source)}:{line}: {source} → {target} is not allowed by docs/ARCHITECTURE.md"
            if layers.get(target, 0) > layers.get(source, 0):
                found.append(f"{where}: it points up a layer ({source} is in layer {layers[source]}, {target} in "
                             f"{layers[target]}). Take what you need from a lower layer, or move the code.")
            else:
                found.append(f"{where}. If the architecture should have this arrow, add {target} to {source}'s line "
                             "in the doc's imports block, in the same commit; else import from another module.")
    return found


def where_in(root, package, module):
    """The path of a module from the repository's root, for messages."""
    return modules_of(root, package)[module].relative_to(root).as_posix()


def stale_allowances(root, allowed):
    """Messages for each arrow the doc allows that no import makes any more."""
    real = arrows(imports_of(root, CORE))
    return [f"docs/ARCHITECTURE.md allows {source} → {target}, but {source} no longer imports {target}: remove "
            f"{target} from its line in the imports block, so the doc stays the real graph."
            for source, targets in sorted(allowed.items()) for target in sorted(targets)
            if target not in real.get(source, {})]


def layer_violations(allowed, layers):
    """Messages for each arrow the doc itself allows towards a higher layer, or to a module it does not list."""
    found = []
    for source, targets in sorted(allowed.items()):
        for target in sorted(targets):
            if target not in layers:
                found.append(f"docs/ARCHITECTURE.md: {source} → {target}, but {target} has no line of its own")
            elif layers[target] > layers[source]:
                found.append(f"docs/ARCHITECTURE.md: {source} (layer {layers[source]}) → {target} (layer "
                             f"{layers[target]}) points up a layer: move one of them, or split the module")
    return found


def loops(graph):
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def loop_violations(root):
    """Messages for each import loop that is not inside one sub-package (meshing's __init__ and its backends)."""
    found = []
    for component in loops(arrows(imports_of(root, CORE))):
        if len({name.split(".")[0] for name in component}) > 1:
            found.append(f"lbc_core has an import loop through {', '.join(sorted(component))}: break it by moving "
                         "what the lower module needs down a layer")
    return found


def private_violations(root, allowed):
    """Messages for each private name a module takes from another that the doc does not list; and for each listing
    no module uses any more."""
    used = {(source, target, name): line for source, target, name, line in private_uses(root, CORE)}
    found = [f"{where_in(root, CORE, source)}:{line} takes {target}.{name}, a private name of another module: make it "
             "public in its module (drop the underscore) if it is meant to be shared, or move it"
             for (source, target, name), line in sorted(used.items()) if (source, target, name) not in allowed]
    found += [f"docs/ARCHITECTURE.md lists {source}: {target}.{name} among the private imports, but no module takes it: "
              "remove it from the private-imports block" for source, target, name in sorted(allowed - set(used))]
    return found


def blender_in_core_violations(root):
    """Messages for each import of Blender's modules or of the add-on in lbc_core."""
    return [f"{where_in(root, CORE, source)}:{line} imports {name}: lbc_core never imports Blender or the add-on (the add-on "
            "calls lbc_core, never the other way); pass the data in as numpy arrays"
            for source, name, line in external_imports(root, CORE) if name in BLENDER_MODULES | {ADDON}]


def addon_violations(root, api_names):
    """Messages for each way lbc_addon reaches lbc_core other than core.py's names of lbc_core.addon_api listed in
    the doc, and for each difference between that list and addon_api's ``__all__``."""
    found = []
    modules = modules_of(root, ADDON)
    for source, path in modules.items():
        nodes = parsed(path)
        for node in nodes:
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level in (0, 1):  # lbc_core, or the bundled .lbc_core
                names = [node.module or ""]
            if any(name.split(".")[0] == CORE for name in names) and source != "core":
                found.append(f"lbc_addon/{path.name}:{node.lineno} imports lbc_core itself: take the name from "
                             "lbc_addon.core (an absolute import would fail in the extension, where lbc_core is a "
                             "sub-package of the add-on)")
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module == "core":
                found += [f"lbc_addon/{path.name}:{node.lineno} takes {alias.name} from lbc_addon.core, which is not "
                          "in the add-on's API (docs/ARCHITECTURE.md, addon-api block): use a name of that API, or "
                          "add it to lbc_core/addon_api.py, the doc and lbc_addon/core.py together"
                          for alias in node.names if alias.name not in api_names]
    found += _core_py_violations(modules["core"], api_names)
    exported = _all_of(root / CORE / "addon_api.py")
    if exported != api_names:
        found.append(f"lbc_core/addon_api.py's __all__ and the doc's addon-api block differ: only in __all__ "
                     f"{sorted(exported - api_names)}, only in the doc {sorted(api_names - exported)}")
    return found


def _core_py_violations(path, api_names):
    """lbc_addon/core.py imports only lbc_core.addon_api (``from lbc_core import addon_api``, or the bundled
    ``from .lbc_core import addon_api``) and takes only the listed names from it."""
    found = []
    for node in parsed(path):
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == CORE and node.level in (0, 1):
            taken = [alias.name for alias in node.names]
            if node.module != CORE or taken != ["addon_api"]:
                found.append(f"lbc_addon/core.py:{node.lineno} imports {', '.join(taken)} from {node.module}: the "
                             "add-on takes lbc_core only through lbc_core.addon_api")
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "_api"
                and node.attr not in api_names):
            found.append(f"lbc_addon/core.py:{node.lineno} takes {node.attr} from lbc_core.addon_api, which is not in "
                         "the doc's addon-api block: add it there and to addon_api's __all__, or do without")
    return found


def dynamic_import_violations(root):
    """Messages for each import by name at run time (importlib.import_module, __import__) in lbc_core or lbc_addon:
    it hides an arrow from this test and from an editor's go-to-definition."""
    found = []
    for package in (CORE, ADDON):
        for source, path in modules_of(root, package).items():
            for node in parsed(path):
                called = getattr(node, "func", None) if isinstance(node, ast.Call) else None
                name = getattr(called, "attr", None) or getattr(called, "id", None)
                if name in ("import_module", "__import__"):
                    found.append(f"{path.relative_to(root).as_posix()}:{node.lineno} imports by name at run time "
                                 f"({name}): import the module plainly, so the import graph shows the arrow")
    return found


def _all_of(path):
    """The names of a module's ``__all__`` list, read without importing it."""
    for node in parsed(path):
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return set(ast.literal_eval(node.value))
    return set()


def folder_violations(layers):
    """Messages for each sub-package whose modules the doc puts in more than one layer: the folders are the layers."""
    folders = {module.split(".")[0] for module in layers if "." in module}
    by_folder = {}
    for module, layer in layers.items():
        if module.split(".")[0] in folders:
            by_folder.setdefault(module.split(".")[0], set()).add(layer)
    return [f"docs/ARCHITECTURE.md puts the modules of lbc_core/{folder}/ in layers {sorted(found)}: a folder is one "
            "layer; move the module that does not belong into the folder of its layer"
            for folder, found in sorted(by_folder.items()) if len(found) > 1]


def all_violations(root, text):
    """Every message of every check, for the tree at ``root`` and the doc ``text``."""
    allowed, layers = allowed_imports(text)
    missing = sorted(set(modules_of(root, CORE)) - set(allowed))
    unknown = sorted(set(allowed) - set(modules_of(root, CORE)))
    return ([f"lbc_core's module {name} has no line in the doc's imports block: add one, in its layer"
             for name in missing]
            + [f"the doc's imports block names {name}, which is no module of lbc_core: remove its line"
               for name in unknown]
            + arrow_violations(root, allowed, layers) + stale_allowances(root, allowed) + layer_violations(allowed, layers)
            + folder_violations(layers) + loop_violations(root) + private_violations(root, private_allowances(text))
            + blender_in_core_violations(root) + addon_violations(root, addon_api_names(text))
            + dynamic_import_violations(root))


# -------------------------------------------------------------------------------------------------------- tests


@pytest.fixture(scope="module")
def doc():
    return DOC.read_text(encoding="utf-8")


def test_every_lbc_core_module_has_a_line_in_the_doc(doc):
    allowed, _ = allowed_imports(doc)
    assert sorted(set(modules_of(ROOT, CORE)) - set(allowed)) == [], "add a line for each, in its layer"
    assert sorted(set(allowed) - set(modules_of(ROOT, CORE))) == [], "remove the lines of modules that are gone"


def test_lbc_core_imports_only_the_arrows_the_doc_allows(doc):
    message = "\n".join(arrow_violations(ROOT, *allowed_imports(doc)))
    assert not message, message


def test_the_doc_allows_no_arrow_the_code_does_not_make(doc):
    message = "\n".join(stale_allowances(ROOT, allowed_imports(doc)[0]))
    assert not message, message


def test_the_doc_arrows_never_point_up_a_layer(doc):
    message = "\n".join(layer_violations(*allowed_imports(doc)))
    assert not message, message


def test_each_folder_of_lbc_core_is_one_layer(doc):
    message = "\n".join(folder_violations(allowed_imports(doc)[1]))
    assert not message, message


def test_the_only_import_loop_is_inside_meshing():
    message = "\n".join(loop_violations(ROOT))
    assert not message, message


def test_private_names_stay_in_their_module(doc):
    message = "\n".join(private_violations(ROOT, private_allowances(doc)))
    assert not message, message


def test_lbc_core_never_imports_blender_or_the_add_on():
    message = "\n".join(blender_in_core_violations(ROOT))
    assert not message, message


def test_no_module_imports_by_name_at_run_time():
    message = "\n".join(dynamic_import_violations(ROOT))
    assert not message, message


def test_the_add_on_uses_only_its_api_of_lbc_core(doc):
    message = "\n".join(addon_violations(ROOT, addon_api_names(doc)))
    assert not message, message


# --------------------------------------------------------------------------- the checker catches what it should


SYNTHETIC_DOC = """
```imports
[1 foundations]
errors:
geometry:
[2 stages]
meshing: errors
meshing.common: meshing geometry
cage: geometry
[3 face]
__init__: cage
addon_api: errors
```

```private-imports
```

```addon-api
CageError
```
"""


def synthetic_tree(tmp_path, files):
    """A fake lbc_core and lbc_addon under ``tmp_path`` that keep the synthetic doc, with ``files`` ({relative path:
    source}) written over them."""
    base = {
        "lbc_core/__init__.py": "from .cage import Cage\n",
        "lbc_core/errors.py": "class CageError(ValueError):\n    pass\n",
        "lbc_core/geometry.py": "def unit(x):\n    return x\n",
        "lbc_core/cage.py": "from .geometry import unit\n",
        "lbc_core/meshing/__init__.py": "from ..errors import CageError\n",
        "lbc_core/meshing/common.py": "from . import DomainMesh\nfrom ..geometry import unit\n",
        "lbc_core/addon_api.py": "from .errors import CageError\n__all__ = ['CageError']\n",
        "lbc_addon/__init__.py": "",
        "lbc_addon/core.py": "from lbc_core import addon_api as _api\nCageError = _api.CageError\n",
        "lbc_addon/jobs.py": "from .core import CageError\n",
    }
    for relative, source in {**base, **files}.items():
        path = tmp_path / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(source))
    return tmp_path


def test_the_synthetic_tree_keeps_its_doc(tmp_path):
    assert all_violations(synthetic_tree(tmp_path, {}), SYNTHETIC_DOC) == []


@pytest.mark.parametrize("relative, source, expected", [
    # A new arrow up the layers, in each form an import can take.
    ("lbc_core/geometry.py", "from .cage import make_cage\n", "geometry → cage is not allowed"),
    ("lbc_core/geometry.py", "def f():\n    from . import cage\n", "geometry → cage is not allowed"),
    ("lbc_core/geometry.py", "import lbc_core.cage\n", "geometry → cage is not allowed"),
    ("lbc_core/geometry.py", "from lbc_core import cage\n", "geometry → cage is not allowed"),
    ("lbc_core/meshing/common.py", "from .. import cage\n", "meshing.common → cage is not allowed"),
    ("lbc_core/cage.py", "from .errors import CageError\n", "cage → errors is not allowed"),
    ("lbc_core/errors.py", "from . import geometry\n", "errors → geometry is not allowed"),
    ("lbc_core/cage.py", "from . import __version__\n", "cage → __init__ is not allowed"),
    # An arrow the doc allows that is gone.
    ("lbc_core/cage.py", "import numpy\n", "no longer imports geometry"),
    # A loop across modules (meshing → meshing.common → meshing is inside one package, and allowed).
    ("lbc_core/errors.py", "def f():\n    from .meshing import x\n", "import loop through errors, meshing"),
    # Private names.
    ("lbc_core/cage.py", "from .geometry import _unit\n", "takes geometry._unit, a private name"),
    ("lbc_core/cage.py", "from . import geometry\ngeometry._unit(1)\n", "takes geometry._unit, a private name"),
    # Blender in lbc_core.
    ("lbc_core/geometry.py", "def f():\n    import bpy\n", "imports bpy: lbc_core never imports Blender"),
    ("lbc_core/geometry.py", "from lbc_addon import jobs\n", "imports lbc_addon"),
    # The add-on past its API.
    ("lbc_addon/jobs.py", "from .core import CageError, Cancelled\n", "takes Cancelled from lbc_addon.core"),
    ("lbc_addon/jobs.py", "import lbc_core\n", "imports lbc_core itself"),
    ("lbc_addon/jobs.py", "from .lbc_core import addon_api\n", "imports lbc_core itself"),
    ("lbc_addon/core.py", "from lbc_core import addon_api as _api\nX = _api.bind\n", "takes bind from lbc_core.addon_api"),
    ("lbc_addon/core.py", "from lbc_core.solve import solver\n", "the add-on takes lbc_core only through lbc_core.addon_api"),
    ("lbc_addon/core.py", "from .lbc_core import binding\n", "the add-on takes lbc_core only through lbc_core.addon_api"),
    # Imports by name at run time hide their arrows.
    ("lbc_addon/core.py", "import importlib\n_api = importlib.import_module('lbc_core.addon_api')\n",
     "imports by name at run time (import_module)"),
    ("lbc_core/cage.py", "def f():\n    return __import__('lbc_core.errors')\n", "imports by name at run time (__import__)"),
    ("lbc_core/addon_api.py", "__all__ = ['CageError', 'bind']\n", "only in __all__ ['bind']"),
])
def test_the_checker_catches(tmp_path, relative, source, expected):
    messages = all_violations(synthetic_tree(tmp_path, {relative: source}), SYNTHETIC_DOC)
    assert any(expected in message for message in messages), messages


def test_the_checker_catches_an_arrow_up_a_layer_in_the_doc(tmp_path):
    doc = SYNTHETIC_DOC.replace("errors:\n", "errors: cage\n")
    root = synthetic_tree(tmp_path, {"lbc_core/errors.py": "def f():\n    from .cage import x\n"})
    messages = all_violations(root, doc)
    assert any("errors (layer 1) → cage (layer 2) points up a layer" in message for message in messages), messages


def test_the_checker_catches_a_folder_split_across_layers(tmp_path):
    doc = SYNTHETIC_DOC.replace("meshing.common: meshing geometry\n", "").replace(
        "addon_api: errors\n", "addon_api: errors\nmeshing.common: meshing geometry\n")
    messages = all_violations(synthetic_tree(tmp_path, {}), doc)
    assert any("lbc_core/meshing/ in layers [2, 3]" in message for message in messages), messages


def test_the_checker_catches_a_module_missing_from_the_doc(tmp_path):
    messages = all_violations(synthetic_tree(tmp_path, {"lbc_core/stray.py": ""}), SYNTHETIC_DOC)
    assert "lbc_core's module stray has no line in the doc's imports block: add one, in its layer" in messages
