"""Meshing cages whose parts nearly touch, side by side with another tree of the project: cells, conforming passes
and tetrahedralisations, CPU and wall seconds, quality (least radius ratio, 1st percentile, share below 0.1) and the
longest silence of the progress messages.

    python bench/mesher_gaps.py --baseline /path/to/other/tree [--cells 2000,8000] [--repeats 3] [CAGE ...]

A CAGE is a name below or a path to a cage file (OBJ / OFF): ``hand`` (tests/data/cages-3d/hand), ``hand-gap-P``
(that hand's cage made again by make_hand.py with slots P % of the diagonal wide), ``arm``, ``L08`` ... ``L16`` (the
gargoyle's cages), ``prism-G`` (the corpus test's slotted prism, slot G), ``notch-A`` (tests/test_meshing.py's block
with a V notch whose walls meet at A degrees), ``corpus`` (every corpus cage as made). ``told`` is the meshing time
the forecast tells on an idle machine (trees without ``sizing.wedge_work``: per cell alone).
Each (tree, cage, cells) runs in a process of its own, the trees interleaved; the figures are medians of the repeats.
"""

import argparse
import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "cages-3d"
GARGOYLE = [f"L{level:02d}" for level in range(8, 17)]


def load_cage(spec):
    """(vertices, faces) of a CAGE spec (see the module's doc)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from lbc_core.io import read_mesh

    if spec == "hand" or spec == "arm":
        return read_mesh(DATA / spec / "cage.obj")[:2]
    if spec in GARGOYLE:
        return read_mesh(DATA / "gargoyle" / f"cage_{spec}.obj")[:2]
    if spec.startswith("hand-gap-"):
        return hand_with_gap(float(spec.split("-")[-1]))
    if spec.startswith("prism-"):
        return slotted_prism(float(spec.split("-", 1)[1]))
    if spec.startswith("notch-"):
        from test_meshing import notched_block

        return notched_block(float(spec.split("-", 1)[1]))
    if spec.startswith("corpus:"):
        from helpers import cage_corpus

        return cage_corpus.load(spec.split(":", 1)[1])
    return read_mesh(spec)[:2]


def slotted_prism(gap):
    """tests/test_meshing_corpus.py's prism: a unit square with a slot ``gap`` wide cut to x = 0.3, extruded."""
    profile = np.array([[0, 0], [1, 0], [1, 0.5 - gap / 2], [0.3, 0.5 - gap / 2], [0.3, 0.5 + gap / 2],
                        [1, 0.5 + gap / 2], [1, 1], [0, 1]], dtype=float)
    n = len(profile)
    vertices = np.concatenate([np.c_[profile, np.zeros(n)], np.c_[profile, np.ones(n)]])
    faces = [list(range(n))[::-1], list(range(n, 2 * n))] + [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    return vertices, faces


def hand_with_gap(percent):
    """The hand's cage made again by make_hand.py with slots ``percent`` % of its diagonal wide."""
    from lbc_core.io import read_mesh

    spec = importlib.util.spec_from_file_location("make_hand", DATA / "hand" / "make_hand.py")
    make_hand = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_hand)
    vertices, faces = read_mesh(DATA / "hand" / "mesh.obj")[:2]
    make_hand.GAP = percent / 100.0 * 1.307  # the cage's diagonal, 1.307 units
    return make_hand.cage_around(vertices, np.asarray(faces))


def child(spec, cells):
    """Mesh one cage with the tree on sys.path; print the figures as JSON."""
    import scipy.spatial

    from lbc_core.cage import make_cage
    from lbc_core.kernel.geometry import radius_ratios
    from lbc_core.meshing import mesh_domain, tetrahedra

    counts = {"tetrahedralisations": 0, "passes": 0}

    def counted_delaunay(points, qhull_options=None):
        counts["tetrahedralisations"] += 1
        return scipy.spatial.Delaunay(points, qhull_options=qhull_options)

    conforming = tetrahedra._conforming_delaunay

    def counted_pass(*args):
        counts["passes"] += 1
        return conforming(*args)

    tetrahedra.Delaunay, tetrahedra._conforming_delaunay = counted_delaunay, counted_pass
    cage = make_cage(*load_cage(spec))
    reports = [time.perf_counter()]
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        mesh = mesh_domain(cage, cells=cells, progress=lambda fraction, message: reports.append(time.perf_counter()))
    except Exception as error:  # a refusal is a result here
        print(json.dumps({"error": str(error)[:80], "seconds": time.perf_counter() - wall, **counts}))
        return
    seconds, cpu = time.perf_counter() - wall, time.process_time() - cpu
    from lbc_core.meshing import sizing
    from lbc_core.solve.forecast import MESHING_SECONDS_PER_CELL

    work = sizing.wedge_work(cage.surface_vertices, cage.facets) if hasattr(sizing, "wedge_work") else 1.0
    counts["told"] = MESHING_SECONDS_PER_CELL * cells * work
    ratios = radius_ratios(mesh.vertices, mesh.cells)
    print(json.dumps({"cells": len(mesh.cells), "seconds": seconds, "cpu": cpu, **counts,
                      "least": float(ratios.min()), "p1": float(np.percentile(ratios, 1)),
                      "below_0_1": float(np.mean(ratios < 0.1)),
                      "silence": float(np.diff(reports + [time.perf_counter()]).max())}))


def run(tree, spec, cells):
    out = subprocess.run([sys.executable, __file__, "--child", spec, str(cells)], capture_output=True, text=True,
                         env={"PYTHONPATH": f"{tree}:{ROOT / 'tests'}", "PATH": "/usr/bin:/bin"}, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def median_row(results):
    if any("error" in r for r in results):
        return results[0]
    return {key: float(np.median([r[key] for r in results])) for key in results[0]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cages", nargs="*", default=["hand", "hand-gap-0.04", "hand-gap-0.5", "hand-gap-3", "arm"])
    parser.add_argument("--baseline", type=Path, required=False)
    parser.add_argument("--cells", default="8000")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--child", nargs=2, metavar=("CAGE", "CELLS"))
    args = parser.parse_args()
    if args.child:
        child(args.child[0], int(args.child[1]))
        return
    sys.path.insert(0, str(ROOT / "tests"))
    specs = []
    for spec in args.cages:
        if spec == "corpus":
            from helpers import cage_corpus

            specs += [f"corpus:{name}" for name in cage_corpus.names()]
        else:
            specs.append(spec)
    trees = ([("baseline", args.baseline.resolve())] if args.baseline else []) + [("this tree", ROOT)]
    with open("/proc/loadavg") as load:
        print(f"load before: {load.read().split()[:3]}")
    for cells in map(int, args.cells.split(",")):
        for spec in specs:
            results = {name: [] for name, _ in trees}
            for _ in range(args.repeats):
                for name, tree in trees:
                    results[name].append(run(tree, spec, cells))
            for name, _ in trees:
                print(json.dumps({"cage": spec, "target": cells, "tree": name, **median_row(results[name])}),
                      flush=True)
    with open("/proc/loadavg") as load:
        print(f"load after: {load.read().split()[:3]}")


if __name__ == "__main__":
    main()
