"""Meshing on the cage corpus: cells, meshing time and whole-bind time per cage family, at the default resolution.

Run from the repository root:  python bench/bench_mesher.py [cells] [--quick]
Prints a markdown table (the README's mesher table) and the tetrahedra's radius ratios. Each cage binds 1000 points
spread over its middle (points outside a non-convex cage are bound to its closest point, as always). A small cage is
meshed once first, so that no row pays the process's one-time costs (imports, first calls); binds shorter than
SHORT seconds are repeated, REPEATS times in all, and the median of each figure is printed (on a shared machine one
short bind can take twice as long as the next).
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from helpers import cage_corpus  # noqa: E402
import lbc_core  # noqa: E402
from lbc_core import meshing  # noqa: E402
from lbc_core.kernel.geometry import radius_ratios  # noqa: E402
from lbc_core.io import read_cage  # noqa: E402

FAMILIES = [
    ("cube (6 quads)", "cube", "as-made"),
    ("cylinder, 32 sides, n-gon caps (Blender's default)", "cylinder-32-ngon", "as-made"),
    ("cylinder, 64 sides, triangle-fan caps", "cylinder-64-fan", "as-made"),
    ("cone, 32 sides, n-gon cap", "cone-32-ngon", "as-made"),
    ("prism, 16 sides, 3 rings, n-gon caps", "prism-16-rings-3", "as-made"),
    ("UV sphere (16 × 8)", "uv-sphere", "as-made"),
    ("torus (24 × 8)", "torus", "as-made"),
    ("Suzanne's hull", "monkey-hull", "as-made"),
    ("box with extruded limbs", "limbs", "as-made"),
    ("bent tube, 12-gon caps", "bent-tube", "as-made"),
    ("thin plate (aspect 0.02)", "thin-plate", "as-made"),
    ("subdivided box, top nudged by 1e-4", "near-coplanar-quads", "as-made"),
    ("cube scaled by 1e-6", "cube", "scaled-1e-6"),
    ("cube dented by 1e-5", "cube", "dented-1e-5"),
    ("cylinder moved to 1e6", "cylinder-32-ngon", "moved-1e6"),
    ("cylinder squashed to aspect 1e-3", "cylinder-32-ngon", "squashed-1e-3"),
    ("cylinder dented by 1e-8", "cylinder-32-ngon", "dented-1e-8"),
    ("cylinder dented by 1e-2", "cylinder-32-ngon", "dented-1e-2"),
    ("gargoyle cage_L12", ROOT / "tests/data/cages-3d/gargoyle/cage_L12.obj", None),
    ("hand, finger boxes 0.11 % of the diagonal apart", ROOT / "tests/data/cages-3d/hand/cage.obj", None),
]


SHORT = 5.0
REPEATS = 3
QUICK = FAMILIES[:2]  # --quick: a smoke run


def middle_points(vertices, rng, count=1000):
    """(count, 3) points spread uniformly over the middle half of the cage's bounding box, in each direction."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    return 0.5 * (low + high) + 0.25 * (high - low) * rng.uniform(-1.0, 1.0, (count, 3))


def measure(cells, families=FAMILIES, repeats=REPEATS):
    """Yield one row per cage family: its label, control points, tetrahedra, the medians of meshing and bind seconds
    and of the meshing's share of the bind, and the tetrahedra's radius ratios (mean and 1st percentile)."""
    rng = np.random.default_rng(0)
    meshing.mesh_domain(lbc_core.make_cage(*cage_corpus.load("cube")), cells=500)  # warm up
    for label, name, kind in families:
        if kind is None:
            vertices, faces = read_cage(name)
        else:
            vertices, faces = cage_corpus.variant(*cage_corpus.load(name), kind)
        points = middle_points(vertices, rng)
        cage = lbc_core.make_cage(vertices, faces)
        alone, total, share = [], [], []
        while len(total) < (repeats if not total or total[0] < SHORT else 1):
            clock = time.perf_counter()
            mesh = meshing.mesh_domain(cage, cells=cells)
            alone.append(time.perf_counter() - clock)
            clock = time.perf_counter()
            binding = lbc_core.bind(vertices, faces, points, cells=cells)
            total.append(time.perf_counter() - clock)
            share.append(binding.timings["meshing"] / total[-1])
        ratio = radius_ratios(mesh.vertices, mesh.cells)
        yield dict(label=label, n=cage.n_control_points, cells=len(mesh.cells), meshing=float(np.median(alone)),
                   bind=float(np.median(total)), share=float(np.median(share)), ratio_mean=float(ratio.mean()),
                   ratio_low=float(np.percentile(ratio, 1)))


HEADER = ("| cage | control points | tetrahedra | meshing s | bind s | meshing share | radius ratio mean / 1st pct |\n"
          "| --- | --- | --- | --- | --- | --- | --- |")


def table_row(row):
    """One row of :func:`measure` as a line of the markdown table under HEADER."""
    return (f"| {row['label']} | {row['n']} | {row['cells']} | {row['meshing']:.2f} | {row['bind']:.1f} | "
            f"{100 * row['share']:.0f} % | {row['ratio_mean']:.2f} / {row['ratio_low']:.2f} |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cells", nargs="?", type=int, default=meshing.DEFAULT_CELLS_3D, help="tetrahedra asked")
    parser.add_argument("--quick", action="store_true", help=f"only the first {len(QUICK)} cages, each bound once")
    args = parser.parse_args(argv)
    print(HEADER)
    for row in measure(args.cells, *((QUICK, 1) if args.quick else ())):
        print(table_row(row), flush=True)


if __name__ == "__main__":
    main()
