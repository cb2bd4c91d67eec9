"""The extension as users get it: the manifest lists the pinned wheels and the tested Blender range; this machine's
zips build and validate with this Blender's builder; the other Python's zip is refused, and the one for this Python
installs into a fresh user directory through Blender's installer, in a Python holding only what Blender ships, and
works there end to end (see helpers/extension_session.py); the session, a background script, then exits."""

import importlib.metadata
import json
import platform
import subprocess
import sys
import sysconfig
import time
import tomllib
from pathlib import Path

import pytest

from helpers.blender_scenes import ROOT

pytestmark = pytest.mark.blender

sys.path.insert(0, str(ROOT / "tools"))
import build_extension  # noqa: E402

BLENDER_PLATFORM = {("Linux", "x86_64"): "linux-x64", ("Windows", "AMD64"): "windows-x64",
                    ("Darwin", "arm64"): "macos-arm64", ("Darwin", "x86_64"): "macos-x64"}.get(
    (platform.system(), platform.machine()))
PYTHON = f"{sys.version_info.major}.{sys.version_info.minor}"


def test_manifest_lists_each_pinned_wheel_and_the_tested_blender_range():
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    ranges = [build_extension.PYTHON_LINES[python][:2] for python in sorted(build_extension.PYTHON_LINES)]
    assert (manifest["blender_version_min"], manifest["blender_version_max"]) == (ranges[0][0], ranges[-1][1])
    assert all(earlier[1] == later[0] for earlier, later in zip(ranges, ranges[1:]))  # no gap, no overlap
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert set(manifest["platforms"]) == set(build_extension.PLATFORM_TAGS)
    wheels = [path.removeprefix("./wheels/") for path in manifest["wheels"]]
    assert wheels == sorted(wheels) and len(set(wheels)) == len(wheels)
    names = [build_extension.normalise(name.split("-")[0]) for name in wheels]
    # Only PyPI's own wheels: numpy is Blender's, Triangle never bundled, lbc_core a sub-package, not a wheel.
    assert set(names) == set(build_extension.dependencies())
    for dependency, version in build_extension.pins().items():
        pure = any(name.startswith(f"{dependency}-") and name.endswith("-py3-none-any.whl") for name in wheels)
        # One wheel per platform and Python, or one pure-Python wheel for them all.
        assert names.count(dependency) == 1 if pure else len(build_extension.PLATFORM_TAGS) * len(
            build_extension.PYTHON_LINES)
        assert all(name.split("-")[1] == version for name in wheels if name.startswith(f"{dependency}-"))


def _blender_like_site(directory):
    """A site-packages with this environment's bpy, numpy and the rest, less lbc and the libraries the extension
    bundles: what a Blender without the extension has. Returns its path."""
    hidden = {file.parts[0] for name in [*build_extension.pins(), "lbc"]
              for file in importlib.metadata.distribution(name).files}
    directory.mkdir()
    for entry in sorted(Path(sysconfig.get_paths()["purelib"]).iterdir()):
        if entry.name not in hidden:
            (directory / entry.name).symlink_to(entry)
    return directory


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Build this platform's zips and run extension_session.py with the one for this Python; returns (result, exit).

    ``exit`` is the session's exit status, or "hung" when it had not exited 30 s after writing its result.
    """
    if BLENDER_PLATFORM is None:
        pytest.skip("not one of the extension's four platforms")
    directory = tmp_path_factory.mktemp("install")
    archives = build_extension.main(["--platform", BLENDER_PLATFORM, "--output", str(directory / "dist")])
    (archive,) = [path for path in archives if build_extension.PYTHON_LINES[PYTHON][2] in path.name]
    (other,) = [path for path in archives if path != archive]
    result = directory / "result.json"
    environment = {"BLENDER_USER_RESOURCES": str(directory / "user"), "PATH": "/usr/bin:/bin",
                   "PYTHONPATH": str(_blender_like_site(directory / "site-packages"))}
    # -S: no site-packages but the Blender-like one, no .pth files (the project's editable install).
    command = [sys.executable, "-S", str(ROOT / "tests" / "helpers" / "extension_session.py"), str(archive), str(other),
               str(result), str(directory / "session.blend")]
    log = (directory / "session.log").open("w")
    process = subprocess.Popen(command, cwd=directory, env=environment, stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 600
    while process.poll() is None and not result.exists() and time.monotonic() < deadline:
        time.sleep(0.5)
    try:
        status = process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        status = "hung"
    log.close()
    output = (directory / "session.log").read_text()[-3000:]
    assert result.exists(), f"the session ended without a result (exit {status}):\n{output}"
    return json.loads(result.read_text()), status, output, directory


def test_built_zip_installs_in_a_fresh_blender_and_works_end_to_end(session):
    result, _, _, directory = session
    assert result["importable_before"] == []  # nothing of lbc's came from this environment
    assert not result["other_installed"]  # the other Python's zip says it is not for this Blender
    assert result["install"] == ["FINISHED"] and result["enabled"]
    extension = str(directory / "user" / "extensions")
    assert result["lbc_core"].startswith(str(directory / "user" / "extensions" / "user_default" / "lbc" / "lbc_core"))
    assert all(path.startswith(extension) for path in result["bundled"].values())
    # Only this Python's wheels were installed: Blender 4.2.0 puts every wheel of the zip into site-packages.
    assert result["other_abi"] == []
    assert {"scipy", "potpourri3d", "cholespy"} <= set(result["site_packages"])
    assert not {"numpy", "triangle", "lbc_core"} & set(result["site_packages"])

    assert result["bind_operator"] == ["FINISHED"] and result["bind_api"] == 8
    assert result["moved"][0] == pytest.approx([0.5, 0.5], abs=1e-5)
    assert result["moved"][1] == pytest.approx([0.5, 0.5], abs=1e-5)
    assert "not closed" in result["bad_cage"] and result["bad_cage_untouched"]
    assert "not closed" in result["bad_cage_operator"] and result["bad_cage_operator_untouched"]
    # The saved file deforms without the extension, and with it the binding is live again.
    enabled, moved = result["reopened_without"]
    assert not enabled and moved == pytest.approx([0.5, 0.5], abs=1e-5)
    (ok, message), moved = result["reopened_with"]
    assert ok and moved == pytest.approx([0.5, 0.5], abs=1e-5), message
    assert result["rebind"] == ["FINISHED"]
    assert result["rest_after_rebind"] == pytest.approx([0.0, 0.0], abs=1e-5)
    assert result["moved_after_rebind"] == pytest.approx([0.25, 0.25], abs=1e-5)
    assert result["unbind"] == ["FINISHED"] and result["unbound_exactly"]
    assert result["modifiers_after_api_unbind"] == [] and result["node_groups_left"] == []


# Measured: the bpy module of Blender 4.2.0 crashes (SIGSEGV) at interpreter exit in a script that registers an
# operator class of its own, but this session with the installed extension exits cleanly there (7 runs of 7 on the
# add-on split into what reads, solves and writes, its Blender modules imported in register(); it crashed in every
# earlier run, cause not isolated); 4.5.4 hung at exit with the add-on registered from the project's tree, not with
# the installed extension; 5.0.1 to 5.2.3 exit cleanly.
def test_background_script_exits_cleanly(session):
    _, status, output, _ = session
    assert status == 0, output
