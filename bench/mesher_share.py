"""Meshing share of the whole bind on every corpus cage up to N control points, in every variant.

    PYTHONPATH=. .venv/bin/python bench/mesher_share.py N [variant,variant,...]

The gargoyle's cages (tests/data/cages-3d/gargoyle) up to N control points follow, as they are. Each cage binds
1000 points at the default resolution, REPEATS times; printed per row: tetrahedra, the pipeline's
"meshing" stage (the mesher and the boundary values), the whole bind, the meshing share (medians) and the solver's
iterations; at the end, how many rows exceed 15 % and the largest shares. `bench/bench_mesher.py` gives the README's
table of cage families; this covers the smallest cages, whose binds are shortest.
"""

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]

from helpers import cage_corpus  # noqa: E402
import lbc_core  # noqa: E402
from bench_mesher import middle_points  # noqa: E402
from lbc_core import meshing  # noqa: E402
from lbc_core.io import read_cage  # noqa: E402

REPEATS = 3
GOAL = 0.15


def main():
    limit = int(sys.argv[1])
    variants = sys.argv[2].split(",") if len(sys.argv) > 2 else cage_corpus.VARIANTS
    rng = np.random.default_rng(0)
    meshing.mesh_domain(lbc_core.make_cage(*cage_corpus.load("cube")), cells=500)  # warm up
    cages = []
    for name in cage_corpus.names():
        made = cage_corpus.load(name)
        if len(made[0]) <= limit:
            cages += [(name, kind, *cage_corpus.variant(*made, kind)) for kind in variants]
    for path in sorted((ROOT / "tests" / "data" / "cages-3d" / "gargoyle").glob("cage_L*.obj")):
        vertices, faces = read_cage(path)
        if len(vertices) <= limit:
            cages.append((f"gargoyle {path.stem[5:]}", "as-made", vertices, faces))
    rows = []
    for name, kind, vertices, faces in cages:
        points = middle_points(vertices, rng)
        seconds, meshed = [], []
        for _ in range(REPEATS):
            clock = time.perf_counter()
            binding = lbc_core.bind(vertices, faces, points)
            seconds.append(time.perf_counter() - clock)
            meshed.append(binding.timings["meshing"])
        share = float(np.median(np.array(meshed) / np.array(seconds)))
        rows.append((share, name, kind))
        print(f"{name:22s} {kind:14s} n={len(vertices):3d} tets={len(binding.domain.cells):5d} "
              f"meshing={np.median(meshed):.3f}s bind={np.median(seconds):.2f}s share={100 * share:.0f}% "
              f"iterations={binding.iterations}", flush=True)
    above = [row for row in rows if row[0] > GOAL]
    print(f"{len(above)} of {len(rows)} rows above {100 * GOAL:.0f} %; largest:",
          ", ".join(f"{name} {kind} {100 * share:.0f} %" for share, name, kind in sorted(rows, reverse=True)[:8]))


if __name__ == "__main__":
    main()
