"""Run the tests on every supported Blender line, each in its own environment, and say how each line did.

    python tools/test_lines.py .venv .venv-blender-4.2 .venv-blender-5.0 ...   # what `make test` runs

The first environment runs the whole suite, each other one the tests marked ``blender`` (the add-on's, the install
of the built extension zip included, and the shared Blender scenes' own tests). Every line runs even when one fails;
the summary at the end gives each line's Blender version, Python and pytest's closing line, and the exit status is
the first failed line's pytest status (0 when all pass). Extra pytest arguments go after ``--``.
"""

import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BLENDER_TESTS = ["-m", "blender"]  # pyproject.toml's marker of the add-on's tests
COUNTED = ("passed", "failed", "skipped", "errors", "error")


def describe(python):
    """'Blender 4.2.0, Python 3.11.7' for the environment whose interpreter is ``python`` (bpy is not imported)."""
    query = "import importlib.metadata, platform; print(importlib.metadata.version('bpy'), platform.python_version())"
    bpy_version, python_version = subprocess.run([python, "-c", query], check=True, capture_output=True,
                                                 text=True).stdout.split()
    return f"Blender {bpy_version}, Python {python_version}"


def run(python, tests, extra):
    """Run pytest, echoing its output; returns (exit status, its closing line, seconds)."""
    start = time.perf_counter()
    process = subprocess.Popen([python, "-m", "pytest", "-q", *tests, *extra], cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    closing = ""
    for line in process.stdout:
        sys.stdout.write(line)
        sys.stdout.flush()
        if re.search(r"\b(passed|failed|error|errors|no tests ran)\b.* in [\d.]+s", line):
            closing = line.strip(" =\n")
    return process.wait(), closing, time.perf_counter() - start


def counts(closing):
    """{'passed': 54, 'skipped': 1, ...} from pytest's closing line."""
    found = {word: 0 for word in COUNTED}
    for number, word in re.findall(r"(\d+) (\w+)", closing):
        if word in found:
            found[word] += int(number)
    return found


def main(argv):
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    environments = argv[: argv.index("--")] if "--" in argv else argv
    if not environments:
        sys.exit(__doc__)
    results = []
    for index, environment in enumerate(environments):
        python = str(Path(environment) / "bin" / "python")
        label = describe(python)
        scope = "whole suite" if index == 0 else "add-on tests"
        print(f"\n===== {label}: {scope} ({environment}) =====", flush=True)
        status, closing, seconds = run(python, [] if index == 0 else BLENDER_TESTS, extra)
        results.append((label, scope, status, closing, seconds))
    print("\n===== every supported Blender line =====")
    total = {word: 0 for word in COUNTED}
    for label, scope, status, closing, seconds in results:
        verdict = "ok" if status == 0 else f"FAILED (pytest exit status {status})"
        print(f"{label:<30} {scope:<13} {verdict:<30} {closing or 'no closing line'} ({seconds:.0f} s in all)")
        for word, number in counts(closing).items():
            total[word] += number
    failures = total["failed"] + total["errors"] + total["error"]
    print(f"total: {total['passed']} passed, {failures} failed, {total['skipped']} skipped")
    return next((status for _, _, status, _, _ in results if status != 0), 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
