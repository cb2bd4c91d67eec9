"""The extension as users get it: the manifest lists the pinned wheels, the zip for this machine builds with
Blender's builder, installs into a fresh Blender session through the Extensions system, enables, and binds with
the lbc_core it bundles."""

import json
import platform
import subprocess
import sys
import textwrap
import tomllib

import pytest

from blender_scenes import ROOT

sys.path.insert(0, str(ROOT / "tools"))
import build_extension  # noqa: E402

BLENDER_PLATFORM = {("Linux", "x86_64"): "linux-x64", ("Windows", "AMD64"): "windows-x64",
                    ("Darwin", "arm64"): "macos-arm64", ("Darwin", "x86_64"): "macos-x64"}.get(
    (platform.system(), platform.machine()))


def test_manifest_lists_each_pinned_wheel_for_every_platform_and_python():
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["blender_version_min"] == "4.2.0" and manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert set(manifest["platforms"]) == set(build_extension.PLATFORM_TAGS)
    wheels = [path.removeprefix("./wheels/") for path in manifest["wheels"]]
    assert wheels == sorted(wheels) and len(set(wheels)) == len(wheels)
    assert not any(name.startswith(("numpy-", "triangle-")) for name in wheels)
    names = [build_extension.normalise(name.split("-")[0]) for name in wheels]
    for dependency in build_extension.dependencies():
        assert names.count(dependency) == len(build_extension.PLATFORM_TAGS) * len(build_extension.PYTHON_VERSIONS)
        assert all(name.split("-")[1] == build_extension.PINS[dependency]
                   for name in wheels if build_extension.normalise(name.split("-")[0]) == dependency)
    import lbc_core

    assert f"lbc_core-{lbc_core.__version__}-py3-none-any.whl" in wheels


INSTALL_AND_BIND = textwrap.dedent("""
    import json, os, sys
    # Only the extension may provide lbc_core and the add-on: hide the project's editable install.
    sys.meta_path[:] = [f for f in sys.meta_path
                        if not (f.__module__ if isinstance(f, type) else type(f).__module__).startswith("__editable__")]
    sys.path[:] = [p for p in sys.path if p not in ("", os.getcwd(), {root!r})]
    import bpy
    result = {{}}
    try:
        import lbc_core
        result["before"] = lbc_core.__file__
    except ImportError:
        result["before"] = None
    result["install"] = sorted(bpy.ops.extensions.package_install_files(
        filepath={zip!r}, repo="user_default", enable_on_install=True))
    result["enabled"] = "bl_ext.user_default.lbc" in bpy.context.preferences.addons
    import lbc_core
    result["lbc_core"] = lbc_core.__file__
    result["site_packages"] = sorted(os.listdir(os.path.dirname(os.path.dirname(lbc_core.__file__))))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.7)
    mesh = bpy.context.active_object
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    cage = bpy.context.active_object
    with bpy.context.temp_override(active_object=cage, object=cage, selected_objects=[mesh, cage]):
        result["bind"] = sorted(bpy.ops.object.lbc_bind(resolution=1000))
    cage.location.x += 0.5
    evaluated = mesh.evaluated_get(bpy.context.evaluated_depsgraph_get())
    moved = [v.co.x - w.co.x for v, w in zip(evaluated.to_mesh().vertices, mesh.data.vertices)]
    result["moved"] = [min(moved), max(moved)]
    with open({out!r}, "w") as handle:
        json.dump(result, handle)
    sys.stdout.flush()
    os._exit(0)  # bpy 4.5.4 can deadlock in its teardown at exit (see tests/conftest.py)
""")


@pytest.mark.skipif(BLENDER_PLATFORM is None, reason="not one of the extension's four platforms")
def test_built_zip_installs_into_a_fresh_blender_and_binds(tmp_path):
    build_extension.main(["--platform", BLENDER_PLATFORM, "--output", str(tmp_path / "dist")])
    archive = tmp_path / "dist" / f"lbc-0.1.0-{BLENDER_PLATFORM.replace('-', '_')}.zip"
    out = tmp_path / "result.json"
    script = INSTALL_AND_BIND.format(root=str(ROOT), zip=str(archive), out=str(out))
    environment = {"BLENDER_USER_RESOURCES": str(tmp_path / "user"), "PATH": "/usr/bin:/bin"}
    process = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=environment, timeout=600,
                             capture_output=True, text=True)
    assert process.returncode == 0, process.stdout[-2000:] + process.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result["before"] is None
    assert result["install"] == ["FINISHED"] and result["enabled"]
    assert result["lbc_core"].startswith(str(tmp_path / "user" / "extensions"))
    # The bundled wheels were installed beside it (numpy is Blender's own, Triangle is never bundled).
    assert {"scipy", "potpourri3d", "cholespy"} <= set(result["site_packages"])
    assert not {"numpy", "triangle"} & set(result["site_packages"])
    assert result["bind"] == ["FINISHED"]
    assert result["moved"] == pytest.approx([0.5, 0.5], abs=1e-5)
