"""Build the Blender extension zips: one per platform and Python ABI, each with exactly the wheels it needs.

    .venv/bin/python tools/build_extension.py                                   # every zip, into dist/
    .venv/bin/python tools/build_extension.py --platform linux-x64 --python 3.13  # just one
    .venv/bin/python tools/build_extension.py --write-manifest                  # after changing a pin

Blender 4.2 to 5.0 run Python 3.11, 5.1 and newer Python 3.13. Blender 4.2.0's installer does not sort wheels by
Python version (it puts cp313 wheels into Python 3.11), so each zip carries one ABI's wheels and the Blender range of
that ABI as its ``blender_version_min``/``blender_version_max``; Blender refuses a zip outside its range.

Steps:

1. Download the wheels of lbc_core's dependencies (pyproject.toml's ``dependencies`` less numpy, which Blender ships)
   at the versions pinned by pyproject.toml's ``extension`` extra, for every platform and both Pythons, with
   ``pip download --only-binary=:all:``, into ``wheels/`` (git-ignored: wheels are never committed). Check that each
   wheel's own requirements are bundled too (or are numpy).
2. Check that ``blender_manifest.toml`` lists exactly these wheels (or rewrite the list with ``--write-manifest``).
3. For each Python ABI and platform, stage the extension (the manifest with that ABI's Blender range and that
   platform's wheels alone, ``lbc_addon``'s modules at the package root, ``lbc_core`` as a sub-package: bundled wheels
   must be PyPI's own) and build it with Blender's own builder; then validate the zip with it.
4. Write a static extension repository beside the zips: Blender's ``index.json`` (and an ``index.html`` listing the
   zips) for every zip in the output folder, as ``blender --command extension server-generate`` makes it. A studio
   hosts the folder on any file server; artists add the URL of its ``index.json`` once, in Blender's Preferences >
   Get Extensions > Repositories, and Blender picks the zip for its version and platform.
5. Print which zip is for which Blender versions and platform.

Blender's builder is ``blender --command extension`` when a Blender binary is on the PATH, else the same script
(``blender_ext.py``, standard library only) from the ``bpy`` module when it is installed, else from the ``bpy`` wheel
pinned by pyproject.toml's ``dev`` extra: downloaded once with ``pip download``, the script kept in ``wheels/builder/``.
So the build needs only Python 3.11 or newer and pip (``make extension`` makes such an environment, ``.venv-build``).

Shewchuk's Triangle is never bundled (its licence is not GPL-compatible); the add-on uses lbc_core's own mesher.
"""

import argparse
import importlib.util
import json
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WHEELS = ROOT / "wheels"
MANIFEST = ROOT / "blender_manifest.toml"

SHIPPED_BY_BLENDER = {"numpy"}
# Each Python ABI: the Blender versions that run it, as the manifest's blender_version_min and blender_version_max
# (the first version not served: 5.3.0 is the first untested one, `make test` runs 4.2.0, 4.5.4, 5.0.1, 5.1.2 and
# 5.2.3), and the part of the zip's name that tells users which zip is theirs.
PYTHON_LINES = {
    "3.11": ("4.2.0", "5.1.0", "blender4.2-5.0"),
    "3.13": ("5.1.0", "5.3.0", "blender5.1-5.2"),
}
# pip platform tags per Blender platform (pip takes older macOS tags of the same architecture too). Linux: Blender
# needs glibc 2.28. macOS: the oldest the pinned wheels allow (scipy 1.17.1: macOS 12 on arm64, 10.14 on x86_64; its
# macOS 14 wheels use Accelerate instead of OpenBLAS).
PLATFORM_TAGS = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),
    "windows-x64": ("win_amd64",),
    "macos-arm64": ("macosx_12_0_arm64",),
    "macos-x64": ("macosx_10_14_x86_64",),
}


def normalise(name):
    """A distribution name as wheel file names spell it."""
    return re.sub(r"[-_.]+", "_", name).lower()


def _requirement_name(requirement):
    return normalise(re.split(r"[<>=!~ \[;(]", requirement.strip(), maxsplit=1)[0])


def _pyproject():
    with open(ROOT / "pyproject.toml", "rb") as handle:
        return tomllib.load(handle)["project"]


def pins():
    """The bundled libraries' versions, from pyproject.toml's ``extension`` extra: {normalised name: version}."""
    found = {}
    for requirement in _pyproject()["optional-dependencies"]["extension"]:
        name, _, version = requirement.partition("==")
        if not version:
            sys.exit(f"pyproject.toml's extension extra must pin each library with ==, not {requirement!r}")
        found[normalise(name)] = version.strip()
    return found


def dependencies():
    """lbc_core's runtime dependencies from pyproject.toml, less those Blender ships; each must have a pin."""
    bundled = [name for name in map(_requirement_name, _pyproject()["dependencies"]) if name not in SHIPPED_BY_BLENDER]
    unpinned = [name for name in bundled if name not in pins()]
    if unpinned:
        sys.exit(f"pyproject.toml needs {unpinned} but its extension extra pins no version for them")
    return bundled


def download(platforms, pythons):
    """pip-download the pinned wheels; returns {python: {platform: [paths of its wheels]}}.

    Each (platform, Python) pair gets its own folder, emptied first, so that it holds exactly what pip chose (pip's
    cache makes a second download quick).
    """
    WHEELS.mkdir(exist_ok=True)
    # Keep wheels out of git without touching the repository's .gitignore.
    (WHEELS / ".gitignore").write_text("*\n")
    pinned = pins()
    found = {}
    for python in pythons:
        found[python] = {}
        for platform in platforms:
            folder = WHEELS / platform / f"py{python}"
            shutil.rmtree(folder, ignore_errors=True)
            command = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
                       "--implementation", "cp", "--python-version", python, "--dest", str(folder)]
            for tag in PLATFORM_TAGS[platform]:
                command += ["--platform", tag]
            command += [f"{name}=={pinned[name]}" for name in dependencies()]
            subprocess.run(command, check=True)
            found[python][platform] = sorted(folder.glob("*.whl"), key=lambda path: path.name)
    return found


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
            required = _requirement_name(line.split(":", 1)[1])
            if required not in bundled | SHIPPED_BY_BLENDER:
                sys.exit(f"{path.name} requires {required}, which is neither bundled nor shipped with Blender")


def manifest_wheels(text):
    """The ``wheels`` list of a manifest's text."""
    return tomllib.loads(text).get("wheels", [])


def with_lists(text, platforms, wheels, blender_range=None):
    """The manifest text with its ``platforms`` and ``wheels`` arrays (and, if given, its Blender version range)
    replaced; everything else kept."""
    wheel_lines = "".join(f'  "./wheels/{name}",\n' for name in wheels)
    platform_list = ", ".join(f'"{platform}"' for platform in platforms)
    text = re.sub(r"(?ms)^platforms = \[.*?\]\n", f"platforms = [{platform_list}]\n", text)
    text = re.sub(r"(?ms)^wheels = \[.*?\]\n", f"wheels = [\n{wheel_lines}]\n", text)
    if blender_range is not None:
        for key, version in zip(("blender_version_min", "blender_version_max"), blender_range):
            text = re.sub(rf'(?m)^{key} = ".*"$', f'{key} = "{version}"', text)
    return text


BUILDER_SCRIPT = "scripts/addons_core/bl_pkg/cli/blender_ext.py"


def builder_bpy_version():
    """The bpy version whose builder script is downloaded when there is no Blender: the one the dev extra pins."""
    for requirement in _pyproject()["optional-dependencies"]["dev"]:
        name, _, version = requirement.partition("==")
        if normalise(name) == "bpy" and version:
            return version.strip()
    sys.exit("pyproject.toml's dev extra must pin bpy with ==: its builder script builds the extension")


def _version_tuple(text):
    return tuple(int(part) for part in text.split("."))


def downloaded_builder():
    """Blender's builder script from the pinned bpy wheel, downloaded once and kept in wheels/builder/; its path."""
    version = builder_bpy_version()
    script = WHEELS / "builder" / f"bpy-{version}" / "blender_ext.py"
    if script.exists():
        return script
    # The script is the same on every platform: take it from the Linux wheel, for the Python of that Blender.
    (python,) = [python for python, (low, high, _) in PYTHON_LINES.items()
                 if _version_tuple(low) <= _version_tuple(version) < _version_tuple(high)]
    print(f"downloading the bpy {version} wheel once, for Blender's extension builder (about 400 MB)")
    WHEELS.mkdir(exist_ok=True)
    (WHEELS / ".gitignore").write_text("*\n")
    with tempfile.TemporaryDirectory() as scratch:
        subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
                        "--implementation", "cp", "--python-version", python, "--platform", "manylinux_2_28_x86_64",
                        "--dest", scratch, f"bpy=={version}"], check=True)
        (wheel,) = Path(scratch).glob("bpy-*.whl")
        with zipfile.ZipFile(wheel) as archive:
            (member,) = [name for name in archive.namelist() if name.endswith(f"/{BUILDER_SCRIPT}")]
            script.parent.mkdir(parents=True, exist_ok=True)
            partial = script.with_suffix(".part")
            partial.write_bytes(archive.read(member))
            partial.replace(script)
    return script


def blender_builder():
    """The command that runs Blender's extension builder: a Blender binary, else the script of the bpy module, else
    the script downloaded from the pinned bpy wheel."""
    blender = shutil.which("blender")
    if blender:
        return [blender, "--factory-startup", "--command", "extension"]
    spec = importlib.util.find_spec("bpy")
    if spec is not None:
        for script in Path(spec.origin).parent.glob(f"*/{BUILDER_SCRIPT}"):
            return [sys.executable, str(script)]
    return [sys.executable, str(downloaded_builder())]


def stage(directory, manifest_text, wheels):
    """Lay out the extension's source: manifest, the add-on's modules at the root, lbc_core beside them (with its
    sub-packages), the wheels."""
    (directory / "wheels").mkdir(parents=True)
    (directory / "blender_manifest.toml").write_text(manifest_text)
    for path in sorted((ROOT / "lbc_addon").glob("*.py")):
        shutil.copy2(path, directory / path.name)
    for path in sorted((ROOT / "lbc_core").rglob("*.py")):
        target = directory / path.relative_to(ROOT)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, target)
    for path in wheels:
        shutil.copy2(path, directory / "wheels" / path.name)


def zip_name(version, python, platform):
    """The file name of one zip, e.g. ``lbc-0.2.0-blender4.2-5.0-linux_x64.zip``."""
    return f"lbc-{version}-{PYTHON_LINES[python][2]}-{platform.replace('-', '_')}.zip"


def write_repository(builder, output):
    """Write Blender's index.json (and index.html) of every zip in ``output``; returns the index's entries."""
    generated = subprocess.run([*builder, "server-generate", "--repo-dir", str(output), "--html"], text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    # It reports a zip it cannot read, or two zips for the same Blender and platform, and goes on: show all but its
    # count of packages.
    for line in generated.stdout.splitlines():
        if not re.fullmatch(r"found \d+ packages\.", line.strip()):
            print(line)
    if generated.returncode:
        sys.exit(f"Blender's builder could not write the extension repository of {output}")
    return json.loads((output / "index.json").read_text(encoding="utf-8"))["data"]


def describe(entry):
    """One line saying which Blender versions and platforms a zip of the repository is for."""
    high = entry.get("blender_version_max")
    blenders = f"Blender {entry['blender_version_min']} or newer" if high is None else \
        f"Blender {entry['blender_version_min']} up to {high} (excluded)"
    platforms = ", ".join(entry.get("platforms", ["every platform"]))
    pythons = ", ".join(entry.get("python_versions", []))
    return (f"{entry['archive_url'].removeprefix('./')}: {blenders}, {platforms}"
            f"{f', Python {pythons}' if pythons else ''}; {entry['archive_size'] / 1e6:.1f} MB")


def build(platforms, pythons, output, write_manifest):
    """Download, check, stage and build; returns the zips made."""
    wheels = download(platforms, pythons)
    every_wheel = [path for by_platform in wheels.values() for paths in by_platform.values() for path in paths]
    check_requirements(every_wheel)
    text = MANIFEST.read_text()
    listed = manifest_wheels(text)
    expected = sorted({f"./wheels/{path.name}" for path in every_wheel})  # a pure-Python wheel serves every zip
    if set(platforms) == set(PLATFORM_TAGS) and set(pythons) == set(PYTHON_LINES) and listed != expected:
        if not write_manifest:
            missing = sorted(set(expected) - set(listed))
            extra = sorted(set(listed) - set(expected))
            sys.exit(f"blender_manifest.toml's wheels differ from the pinned ones: missing {missing}, not bundled "
                     f"{extra}; run with --write-manifest")
        text = with_lists(text, tomllib.loads(text)["platforms"], [name.removeprefix("./wheels/") for name in expected])
        MANIFEST.write_text(text)
        print(f"rewrote the wheel list of {MANIFEST.name}")
    else:
        unlisted = sorted(set(expected) - set(listed))
        if unlisted:
            sys.exit(f"blender_manifest.toml does not list {unlisted}: build everything with --write-manifest")
    builder = blender_builder()
    version = tomllib.loads(text)["version"]
    output.mkdir(parents=True, exist_ok=True)
    zips = []
    for python in pythons:
        for platform in platforms:
            # One platform a build, its manifest listing that platform's wheels only: Blender 4.2.0's installer reads
            # the top-level list (not the one --split-platforms adds) and says it skips every other platform's wheel.
            with tempfile.TemporaryDirectory() as scratch:
                staging, built = Path(scratch) / "source", Path(scratch) / "built"
                built.mkdir()
                platform_wheels = wheels[python][platform]
                stage(staging, with_lists(text, [platform], [path.name for path in platform_wheels],
                                          PYTHON_LINES[python][:2]), platform_wheels)
                subprocess.run([*builder, "build", "--source-dir", str(staging), "--output-dir", str(built),
                                "--split-platforms"], check=True)
                target = output / zip_name(version, python, platform)
                shutil.move(built / f"lbc-{version}-{platform.replace('-', '_')}.zip", target)
                subprocess.run([*builder, "validate", str(target)], check=True)
                zips.append(target)
    return zips, write_repository(builder, output)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORM_TAGS),
                        help="build only this platform (repeatable; default: all)")
    parser.add_argument("--python", action="append", choices=sorted(PYTHON_LINES),
                        help="build only for this Python ABI (repeatable; default: all)")
    parser.add_argument("--output", type=Path, default=ROOT / "dist", help="where the zips go (default: dist/)")
    parser.add_argument("--write-manifest", action="store_true",
                        help="rewrite blender_manifest.toml's wheel list from the pinned versions")
    args = parser.parse_args(argv)
    zips, entries = build(args.platform or list(PLATFORM_TAGS), args.python or list(PYTHON_LINES), args.output,
                          args.write_manifest)
    output = args.output.resolve()
    shown = output.relative_to(ROOT) if output.is_relative_to(ROOT) else output
    print(f"\n{shown}/ holds {len(entries)} zip(s) and an extension repository, index.json:")
    for entry in sorted(entries, key=lambda entry: entry["archive_url"]):
        print(f"  {describe(entry)}")
    print(f"Install one zip from disk, or host {shown}/ on a file server and add the URL of its index.json in "
          f"Blender's Preferences > Get Extensions > Repositories.")
    return zips


if __name__ == "__main__":
    main()
