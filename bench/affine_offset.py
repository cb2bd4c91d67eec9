"""How closely a binding follows an affine map of its cage, against the cage's distance from the origin.

An L polygon (2D, meshed by the bundled Delaunay mesher, as in Blender) and a unit cube (3D), moved to each
offset, bind 300 inside points; the cage is then mapped by a
fixed shear-and-scale plus a shift, and the points' deformation compared with the same map applied to them. Printed:
the largest error over the cage's diagonal, the same in ulps of the largest coordinate (float64 cannot do better
than about one), the largest |Σ w - 1|, and the bind time. Each bind runs in a child process with a time limit.

    .venv/bin/python bench/affine_offset.py [--against OLD_TREE] [--limit SECONDS]

``--against`` runs the same binds with the lbc_core of another checkout (e.g. ``git worktree add /tmp/lbc-old
62f1484``) in the same run, side by side.
"""

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OFFSETS = [0.0, 1e4, 1e5, 1e6, 1e8]

CHILD = """
import json, sys, time, numpy as np, lbc_core
dim, offset = int(sys.argv[1]), float(sys.argv[2])
if dim == 2:
    cage, faces = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float), None
    points = np.random.default_rng(0).uniform(0.02, 1.98, (1200, 2))
    points = points[(points[:, 0] < 0.98) | (points[:, 1] < 0.98)][:300]
    linear = np.array([[1.1, 0.3], [-0.2, 0.8]])
else:
    cage = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    points = np.random.default_rng(0).uniform(0.02, 0.98, (300, 3))
    linear = np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.3], [0.05, 0.0, 1.2]])
cage, points = cage + offset, points + offset
shift = np.full(dim, 0.25)
start = time.perf_counter()
binding = lbc_core.bind(cage, faces, points, cells=2000 if dim == 3 else 1000,
                       method="auto" if dim == 3 else "delaunay")
seconds = time.perf_counter() - start
posed, expected = cage @ linear.T + shift, points @ linear.T + shift
error = float(np.abs(binding.deform(posed) - expected).max())
largest = max(np.abs(a).max() for a in (cage, posed, points, expected))
print(json.dumps({"error": error / binding.cage.bbox_diagonal, "ulps": error / float(np.spacing(largest)),
                  "unity": float(np.abs(np.asarray(binding.weights.sum(axis=1)).ravel() - 1).max()),
                  "seconds": seconds}))
"""


def measure(tree, dim, offset, limit):
    """One bind in a child process importing lbc_core from ``tree``; None when it takes longer than ``limit``."""
    try:
        run = subprocess.run([sys.executable, "-c", CHILD, str(dim), repr(offset)], capture_output=True, text=True,
                             timeout=limit, cwd=tree, env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"},
                             check=True)
    except subprocess.TimeoutExpired:
        return None
    return json.loads(run.stdout.strip().splitlines()[-1])


def cell(result, limit):
    if result is None:
        return f"no result in {limit:.0f} s"
    return (f"{result['error']:.1e} ({result['ulps']:.1f} ulp), |Σw-1| {result['unity']:.0e}, "
            f"{result['seconds']:.2f} s")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--against", type=Path, help="another checkout whose lbc_core runs side by side")
    parser.add_argument("--limit", type=float, default=60.0, help="seconds allowed per bind")
    args = parser.parse_args()
    trees = {"this tree": ROOT}
    if args.against:
        trees[str(args.against)] = args.against.resolve()
    print("affine map error / diagonal (in ulps of the largest coordinate), largest |Σ w - 1|, bind time")
    print("| cage | offset | " + " | ".join(trees) + " |")
    print("| --- | --- |" + " --- |" * len(trees))
    for dim in (2, 3):
        for offset in OFFSETS:
            results = [measure(tree, dim, offset, args.limit) for tree in trees.values()]
            name = "L polygon" if dim == 2 else "unit cube"
            print(f"| {name} | {offset:g} | " + " | ".join(cell(r, args.limit) for r in results) + " |", flush=True)


if __name__ == "__main__":
    main()
