"""What a release is made of: one version everywhere, `make extension` needing no test environment, and the extension
repository it writes, from which Blender 4.2 and 5.2 each install the zip for their own Python through a file:// URL.

The repository test builds this platform's two zips (one per Python) into a temporary folder and runs a background
session in the environments of Blender 4.2 and 5.2 (.venv-blender-4.2, .venv-blender-5.2: `make test` makes them); a
line whose environment is missing is skipped. These are marked slow (the build and two Blender sessions).
"""

import json
import platform
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import lbc_core

pytestmark = pytest.mark.slow  # builds and installs: left out of the fast tier

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
import build_extension  # noqa: E402

BLENDER_PLATFORM = {("Linux", "x86_64"): "linux-x64", ("Windows", "AMD64"): "windows-x64",
                    ("Darwin", "arm64"): "macos-arm64", ("Darwin", "x86_64"): "macos-x64"}.get(
    (platform.system(), platform.machine()))


def project_version():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def test_one_version_in_pyproject_manifest_library_and_changelog():
    version = project_version()
    assert re.fullmatch(r"\d+\.\d+\.\d+", version)
    assert tomllib.loads((ROOT / "blender_manifest.toml").read_text())["version"] == version
    assert lbc_core.__version__ == version
    # The changelog has a section for the version, dated, and it is the newest released one.
    released = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert released and released[0] == version


@pytest.mark.parametrize("page", ["README.md", "docs/blender.md"])
def test_the_docs_name_the_zips_of_this_version(page):
    names = re.findall(r"lbc-(\d+\.\d+\.\d+)-blender", (ROOT / page).read_text())
    assert names and set(names) == {project_version()}


@pytest.mark.parametrize("page", ["README.md", "docs/blender.md"])
def test_the_docs_version_tables_give_each_zip_the_blender_range_it_is_built_for(page):
    """Each row of the install table names the Blender versions of its zip's range: "5.1 and newer" under a manifest
    that stops before 5.3 promised what no test ran."""
    rows = re.findall(r"^\| ([^|]+?) \| (3\.\d+) \| `lbc-[\d.]+-(blender[\d.]+-[\d.]+)-", (ROOT / page).read_text(), re.M)
    assert len(rows) == len(build_extension.PYTHON_LINES)
    for versions, python, range_name in rows:
        first, stop, name = build_extension.PYTHON_LINES[python]
        assert name == range_name
        low, high = name.removeprefix("blender").split("-")
        assert re.fullmatch(rf"{re.escape(low)}( LTS)? to {re.escape(high)}", versions), (versions, name)


def test_make_extension_needs_no_test_environment():
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    # -B: every step, as on a fresh clone; -n: only print them.
    steps = subprocess.run(["make", "-n", "-B", "extension"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout
    assert "tools/build_extension.py" in steps
    assert ".venv/" not in steps and ".venv-blender" not in steps
    assert not re.search(r"pip install .*(bpy|-e|\.\[)", steps)  # no bpy, no project install, no extras


SESSION = r'''
import json, os, sys
import bpy

url, module, result_path = sys.argv[1:4]
result = {}
# Installing from a repository needs online access, off in the bpy module (Blender asks the user once).
bpy.context.preferences.system.use_online_access = True
repos = bpy.context.preferences.extensions.repos
repo = repos.new(name="Studio", module=module, remote_url=url)
index = list(repos).index(repo)
result["sync"] = sorted(bpy.ops.extensions.repo_sync(repo_index=index))
result["install"] = sorted(bpy.ops.extensions.package_install(repo_index=index, pkg_id="lbc", enable_on_install=True))
name = f"bl_ext.{module}.lbc"
result["enabled"] = name in bpy.context.preferences.addons
result["directory"] = repo.directory
with open(os.path.join(repo.directory, "lbc", "blender_manifest.toml"), "rb") as handle:
    import tomllib
    result["manifest"] = tomllib.load(handle)
import importlib
api = importlib.import_module(f"{name}.api")
result["lbc_core"] = sys.modules[f"{name}.lbc_core"].__file__

bpy.ops.wm.read_homefile(use_empty=True)
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.7)
sphere = bpy.context.active_object
bpy.ops.mesh.primitive_cube_add(size=2.0)
cage = bpy.context.active_object
result["control_points"] = api.bind(sphere, cage, cells=1000).control_points
cage.location.x += 0.5
evaluated = sphere.evaluated_get(bpy.context.evaluated_depsgraph_get())
result["moved"] = evaluated.to_mesh().vertices[0].co.x - sphere.data.vertices[0].co.x
with open(result_path, "w") as handle:
    json.dump(result, handle)
sys.stdout.flush()
os._exit(0)  # the bpy module of 4.2.0 can crash at interpreter exit once an add-on is registered
'''


@pytest.fixture(scope="module")
def repository(tmp_path_factory):
    """This platform's zips for both Pythons and their index.json, built as `make extension` does; the folder."""
    if BLENDER_PLATFORM is None:
        pytest.skip("not one of the extension's four platforms")
    folder = tmp_path_factory.mktemp("repository")
    zips = build_extension.main(["--platform", BLENDER_PLATFORM, "--output", str(folder)])
    assert len(zips) == len(build_extension.PYTHON_LINES)
    return folder


@pytest.mark.slow
def test_repository_lists_each_zip_with_its_blender_range(repository):
    index = json.loads((repository / "index.json").read_text())
    assert index["version"] == "v1"
    entries = {entry["archive_url"]: entry for entry in index["data"]}
    for python, (low, high, _) in build_extension.PYTHON_LINES.items():
        entry = entries[f"./{build_extension.zip_name(project_version(), python, BLENDER_PLATFORM)}"]
        assert (entry["id"], entry["version"]) == ("lbc", project_version())
        assert (entry["blender_version_min"], entry["blender_version_max"]) == (low, high)
        assert entry["platforms"] == [BLENDER_PLATFORM]
        assert (repository / entry["archive_url"]).stat().st_size == entry["archive_size"]
    assert (repository / "index.html").exists()


@pytest.mark.slow
@pytest.mark.parametrize("line, python", [("4.2", "3.11"), ("5.2", "3.13")])
def test_blender_installs_its_own_zip_from_the_repository_by_url(repository, tmp_path, line, python):
    interpreter = ROOT / f".venv-blender-{line}" / "bin" / "python"
    if not interpreter.exists():
        pytest.skip(f"no .venv-blender-{line} (make test makes it)")
    script, result = tmp_path / "session.py", tmp_path / "result.json"
    script.write_text(SESSION)
    environment = {"BLENDER_USER_RESOURCES": str(tmp_path / "user"), "PATH": "/usr/bin:/bin",
                   "HOME": str(tmp_path)}
    process = subprocess.run([str(interpreter), str(script), (repository / "index.json").as_uri(), "studio",
                              str(result)], cwd=tmp_path, env=environment, capture_output=True, text=True,
                             timeout=600)
    assert result.exists(), f"the session ended without a result (exit {process.returncode}):\n" + \
        (process.stdout + process.stderr)[-3000:]
    found = json.loads(result.read_text())
    assert found["sync"] == ["FINISHED"] and found["install"] == ["FINISHED"] and found["enabled"]
    # Blender chose the zip of its own Python from the two of this platform.
    low, high, _ = build_extension.PYTHON_LINES[python]
    assert (found["manifest"]["blender_version_min"], found["manifest"]["blender_version_max"]) == (low, high)
    assert found["manifest"]["version"] == project_version()
    assert found["lbc_core"].startswith(str(Path(found["directory"]) / "lbc" / "lbc_core"))
    assert found["control_points"] == 8 and found["moved"] == pytest.approx(0.5, abs=1e-4)
