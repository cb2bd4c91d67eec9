"""The add-on takes lbc_core from one place, its API for the add-on: the bundled sub-package's in the extension, the
top-level package's here."""

import ast
from pathlib import Path

import pytest

import lbc_core
import lbc_core.addon_api
from lbc_addon import api, core, jobs

pytestmark = pytest.mark.blender

ADDON = Path(core.__file__).parent


def test_in_the_project_tree_the_add_on_uses_the_top_level_lbc_core():
    assert core._api is lbc_core.addon_api
    assert jobs.bind is lbc_core.bind and api.CageError is lbc_core.CageError


def test_the_add_on_takes_every_name_of_its_api_and_nothing_else():
    taken = {name for name in vars(core) if not name.startswith("_") and name not in ("Path",)}
    assert taken | {"__version__"} == set(lbc_core.addon_api.__all__)
    for name in lbc_core.addon_api.__all__:
        assert getattr(core, name) is getattr(lbc_core.addon_api, name), name


def test_no_other_add_on_module_imports_lbc_core_itself():
    # An absolute import would fail in the extension, where lbc_core is a sub-package of the add-on.
    for path in sorted(ADDON.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [alias.name for alias in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module]
            assert not any(name.split(".")[0] == "lbc_core" for name in names) or path.name == "core.py", path.name
