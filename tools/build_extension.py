"""Build the Blender extension zips: one per platform, each with the wheels that platform needs.

    .venv/bin/python tools/build_extension.py                      # all four platforms, into dist/
    .venv/bin/python tools/build_extension.py --platform linux-x64 # just one
    .venv/bin/python tools/build_extension.py --write-manifest     # after changing a pin: rewrite the wheel list

Steps:

1. Download the wheels of lbc_core's dependencies (pyproject.toml's ``dependencies`` less numpy, which Blender ships)
   at the versions pinned in ``PINS``, for every platform and for Python 3.11 (Blender 4.2 to 5.0) and 3.13 (5.1 and
   newer), with ``pip download --only-binary=:all:``, into ``wheels/`` (git-ignored: wheels are never committed).
   Check that each wheel's own requirements are bundled too (or are numpy).
2. Build ``lbc_core`` itself as a pure-Python wheel, so the add-on imports it exactly as in the project's .venv.
3. Check that ``blender_manifest.toml`` lists exactly these wheels (or rewrite the list with ``--write-manifest``).
4. Stage the extension (manifest, ``lbc_addon``'s modules at the package root, the wheels) and build it with
   Blender's own builder: ``blender --command extension build --split-platforms`` when a Blender binary is on the
   PATH, else the same builder script shipped in the ``bpy`` module; then validate every zip with it.

Shewchuk's Triangle is never bundled (its licence is not GPL-compatible); the add-on uses lbc_core's own mesher.
"""

import argparse
import base64
import hashlib
import importlib.util
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WHEELS = ROOT / "wheels"
MANIFEST = ROOT / "blender_manifest.toml"

# Versions with wheels for Python 3.11 and 3.13 on all four platforms that work with numpy 1.26 to 2.x (Blender 4.2
# to 4.5 ship numpy 1.26): scipy 1.17.1 needs numpy >= 1.26.4, < 2.7 (scipy 1.18 needs numpy 2).
PINS = {"scipy": "1.17.1", "potpourri3d": "1.4.0", "cholespy": "2.2.0"}
SHIPPED_BY_BLENDER = {"numpy"}
PYTHON_VERSIONS = ("3.11", "3.13")
# pip platform tags per Blender platform. Linux: Blender needs glibc 2.28. macOS: scipy 1.17's wheels need macOS 14.
PLATFORM_TAGS = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),
    "windows-x64": ("win_amd64",),
    "macos-arm64": ("macosx_14_0_arm64",),
    "macos-x64": ("macosx_14_0_x86_64",),
}
# Fixed zip timestamps make the lbc_core wheel byte-identical from one build to the next.
_EPOCH = (1980, 1, 1, 0, 0, 0)


def normalise(name):
    """A distribution name as wheel file names spell it."""
    return re.sub(r"[-_.]+", "_", name).lower()


def dependencies():
    """lbc_core's runtime dependencies from pyproject.toml, less those Blender ships; each must have a pin."""
    with open(ROOT / "pyproject.toml", "rb") as handle:
        requirements = tomllib.load(handle)["project"]["dependencies"]
    names = [normalise(re.split(r"[<>=!~ \[;]", requirement, maxsplit=1)[0]) for requirement in requirements]
    bundled = [name for name in names if name not in SHIPPED_BY_BLENDER]
    unpinned = [name for name in bundled if name not in PINS]
    if unpinned:
        sys.exit(f"pyproject.toml needs {unpinned} but PINS in {Path(__file__).name} has no version for them")
    return bundled


def download(platforms):
    """pip-download the pinned wheels for these platforms and both Python versions; returns their paths.

    Each (platform, Python) pair gets its own folder, so the folder's content is exactly what pip chose for it.
    """
    WHEELS.mkdir(exist_ok=True)
    # Keep wheels out of git without touching the repository's .gitignore.
    (WHEELS / ".gitignore").write_text("*\n")
    paths = {}
    for platform in platforms:
        for python in PYTHON_VERSIONS:
            folder = WHEELS / platform / f"py{python}"
            command = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
                       "--implementation", "cp", "--python-version", python, "--dest", str(folder)]
            for tag in PLATFORM_TAGS[platform]:
                command += ["--platform", tag]
            command += [f"{name}=={PINS[name]}" for name in dependencies()]
            subprocess.run(command, check=True)
            for path in folder.glob("*.whl"):
                if PINS.get(_wheel_tags(path.name)[0]) == _wheel_tags(path.name)[1]:  # not a stale pin
                    paths[path.name] = path
    return [paths[name] for name in sorted(paths)]


def _wheel_tags(filename):
    parts = filename[: -len(".whl")].split("-")
    return normalise(parts[0]), parts[1], parts[-3], parts[-2], parts[-1]


def check_requirements(paths):
    """Every requirement of every bundled wheel must be bundled too, or shipped by Blender."""
    bundled = {_wheel_tags(path.name)[0] for path in paths}
    for path in paths:
        with zipfile.ZipFile(path) as archive:
            metadata = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
            text = archive.read(metadata).decode()
        for line in text.splitlines():
            if not line.startswith("Requires-Dist:") or "extra ==" in line:
                continue
            required = normalise(re.split(r"[<>=!~ \[;(]", line.split(":", 1)[1].strip(), maxsplit=1)[0])
            if required not in bundled | SHIPPED_BY_BLENDER:
                sys.exit(f"{path.name} requires {required}, which is neither bundled nor shipped with Blender")


def core_wheel():
    """Build lbc_core as a pure-Python wheel in wheels/; returns its path."""
    version = re.search(r'__version__ = "([^"]+)"', (ROOT / "lbc_core" / "__init__.py").read_text()).group(1)
    dist_info = f"lbc_core-{version}.dist-info"
    files = {  # subpackages included (lbc_core.meshing)
        path.relative_to(ROOT).as_posix(): path.read_bytes() for path in sorted((ROOT / "lbc_core").rglob("*.py"))
    }
    requires = "".join(f"Requires-Dist: {name}\n" for name in ["numpy", *dependencies()])
    files[f"{dist_info}/METADATA"] = (
        f"Metadata-Version: 2.1\nName: lbc_core\nVersion: {version}\nSummary: Local Barycentric Coordinates\n"
        f"License-Expression: GPL-3.0-or-later\nRequires-Python: >=3.11\n{requires}"
    ).encode()
    files[f"{dist_info}/WHEEL"] = b"Wheel-Version: 1.0\nGenerator: lbc tools/build_extension.py\nRoot-Is-Purelib: " \
                                  b"true\nTag: py3-none-any\n"
    record = "".join(f"{name},sha256={_digest(data)},{len(data)}\n" for name, data in files.items())
    files[f"{dist_info}/RECORD"] = (record + f"{dist_info}/RECORD,,\n").encode()
    WHEELS.mkdir(exist_ok=True)
    path = WHEELS / f"lbc_core-{version}-py3-none-any.whl"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            archive.writestr(zipfile.ZipInfo(name, _EPOCH), data)
    return path


def _digest(data):
    return base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def manifest_wheels(text):
    """The ``wheels`` list of a manifest's text."""
    return tomllib.loads(text).get("wheels", [])


def with_lists(text, platforms, wheels):
    """The manifest text with its ``platforms`` and ``wheels`` arrays replaced (everything else kept)."""
    wheel_lines = "".join(f'  "./wheels/{name}",\n' for name in wheels)
    platform_list = ", ".join(f'"{platform}"' for platform in platforms)
    text = re.sub(r"(?ms)^platforms = \[.*?\]\n", f"platforms = [{platform_list}]\n", text)
    return re.sub(r"(?ms)^wheels = \[.*?\]\n", f"wheels = [\n{wheel_lines}]\n", text)


def blender_builder():
    """The command that runs Blender's extension builder: a Blender binary, else the script in the bpy module."""
    blender = shutil.which("blender")
    if blender:
        return [blender, "--factory-startup", "--command", "extension"]
    spec = importlib.util.find_spec("bpy")
    if spec is not None:
        for script in Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"):
            return [sys.executable, str(script)]
    sys.exit("Blender's extension builder was not found: put blender on the PATH or install the bpy module")


def stage(directory, manifest_text, wheels):
    """Lay out the extension's source: manifest, the add-on's modules at the root, the wheels."""
    if directory.exists():
        shutil.rmtree(directory)
    (directory / "wheels").mkdir(parents=True)
    (directory / "blender_manifest.toml").write_text(manifest_text)
    for path in sorted((ROOT / "lbc_addon").glob("*.py")):
        shutil.copy2(path, directory / path.name)
    for path in wheels:
        shutil.copy2(path, directory / "wheels" / path.name)


def build(platforms, output, write_manifest):
    """Download, check, stage and build; returns the zips made."""
    wheels = download(platforms)
    check_requirements(wheels)
    wheels = sorted({*wheels, core_wheel()}, key=lambda path: path.name)
    text = MANIFEST.read_text()
    listed = manifest_wheels(text)
    expected = [f"./wheels/{path.name}" for path in wheels]
    if set(platforms) == set(PLATFORM_TAGS) and listed != expected:
        if not write_manifest:
            missing = sorted(set(expected) - set(listed))
            extra = sorted(set(listed) - set(expected))
            sys.exit(f"blender_manifest.toml's wheels differ from the pinned ones: missing {missing}, not bundled "
                     f"{extra}; run with --write-manifest")
        text = with_lists(text, tomllib.loads(text)["platforms"], [path.name for path in wheels])
        MANIFEST.write_text(text)
        print(f"rewrote the wheel list of {MANIFEST.name}")
    else:
        unlisted = sorted(set(expected) - set(listed))
        if unlisted:
            sys.exit(f"blender_manifest.toml does not list {unlisted}: build all platforms with --write-manifest")
    staging = ROOT / "dist" / "staging"
    stage(staging, with_lists(text, platforms, [path.name for path in wheels]), wheels)
    output.mkdir(parents=True, exist_ok=True)
    builder = blender_builder()
    subprocess.run([*builder, "build", "--source-dir", str(staging), "--output-dir", str(output), "--split-platforms"],
                   check=True)
    version = tomllib.loads(text)["version"]
    zips = [output / f"lbc-{version}-{platform.replace('-', '_')}.zip" for platform in platforms]
    for path in zips:
        subprocess.run([*builder, "validate", str(path)], check=True)
    return zips


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORM_TAGS),
                        help="build only this platform (repeatable; default: all)")
    parser.add_argument("--output", type=Path, default=ROOT / "dist", help="where the zips go (default: dist/)")
    parser.add_argument("--write-manifest", action="store_true",
                        help="rewrite blender_manifest.toml's wheel list from the pinned versions")
    args = parser.parse_args(argv)
    for path in build(args.platform or list(PLATFORM_TAGS), args.output, args.write_manifest):
        print(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}: {path.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
