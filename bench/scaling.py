"""How a bind's time and peak memory grow with the control points and with the cells, beside a baseline.

    .venv/bin/python bench/scaling.py [--baseline DIR] [--picture PATH] [--quick]
    .venv/bin/python bench/scaling.py --interleaved DIR [DIR ...] [--cages SET] [--repeats 2] [--cells 8000]

The gargoyle mesh (2674 points) bound to its cages L12 (27 control points), L10 (67), L08 (168), L09 with every
triangle split in four at its edges' midpoints (418) and L10 split twice (1042), at 4000 to 64,000 cells asked;
each bind in a child process, so its peak resident memory is its own (`bench/run.py`'s ``bench_3d``). With
``--baseline DIR`` (a tree of an earlier version: ``git archive 5715f72 | tar -x -C DIR``) each bind runs there too,
in the same run; a bind the memory check would refuse on this machine is skipped and said so. Prints a table and
the exponents of a least-squares fit time ∝ cells^a · n^b (and the same for memory), and draws time and memory
against cells, one line per cage, on log-log axes into PATH (default out/scaling.png).

``--interleaved`` binds every cage of a set (``gargoyle``: L08..L16; ``corpus``: the cage corpus as Blender made it,
1000 points over each cage's middle; ``data``: the hand, arm and clothing with their meshes; ``all``) with each tree
in turn, each bind in its own process, the trees interleaved cage by cage and the whole round repeated; prints the
median bind and solve seconds (wall), the bind's CPU seconds (its process's, every thread: steadier than the wall
time on a loaded machine), iterations and objective per tree, and each tree's over the first's.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.run import GARGOYLE, bench_3d  # noqa: E402
from lbc_core.errors import CageError  # noqa: E402
from lbc_core.io import read_cage  # noqa: E402
from lbc_core.solve.forecast import check_memory  # noqa: E402

# (cage, cell counts asked): the larger cages stop where a bind would take many minutes on this 2-core machine.
PLAN = [("L12", (4000, 16000, 64000)), ("L10", (4000, 16000, 64000)), ("L08", (8000, 32000)),
        ("L09 split", (8000, 16000)), ("L10 split twice", (32000,))]
QUICK_PLAN = [("L12", (4000, 8000)), ("L10", (4000, 8000))]
# The baseline binds only up to this many cells times control points (its time and memory grow as cells · n).
BASELINE_MOST = 7_000_000


def split_cage(path, out):
    """Write the triangle cage at ``path`` with every triangle split in four at its edges' midpoints to ``out``.

    Returns the number of vertices written."""
    vertices, faces = read_cage(path)
    faces = np.asarray(faces)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    middle = len(vertices) + inverse.reshape(3, -1).T  # (F, 3): the midpoints of edges 01, 12, 20
    vertices = np.vstack([vertices, vertices[unique].mean(axis=1)])
    a, b, c = faces.T
    ab, bc, ca = middle.T
    split = np.concatenate([np.stack(corners, axis=1) for corners in
                            ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    with open(out, "w") as file:
        file.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices)
        file.writelines(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in split)
    return len(vertices)


def fit(rows, key):
    """Exponents (a, b) of ``key`` ≈ C · cells^a · n^b, least squares in log space."""
    design = np.array([[1.0, np.log(r["cells"]), np.log(r["n"])] for r in rows])
    values = np.log([r[key] for r in rows])
    coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
    return coefficients[1], coefficients[2]


def draw(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name in dict.fromkeys(r["cage"] for r in rows):
        own = [r for r in rows if r["cage"] == name]
        label = f"{name} ({own[0]['n']} control points)"
        axes[0].loglog([r["cells"] for r in own], [r["total"] for r in own], "o-", label=label)
        axes[1].loglog([r["cells"] for r in own], [r["peak_mb"] for r in own], "o-", label=label)
    axes[0].set(xlabel="tetrahedra", ylabel="bind time (s)", title="Bind time")
    axes[1].set(xlabel="tetrahedra", ylabel="peak resident memory (MB)", title="Peak memory")
    for axis in axes:
        axis.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    print(f"wrote {path}")


def cage_paths(folder):
    """{cage name: OBJ path} of the planned cages, the split ones written into ``folder``."""
    paths = {name: GARGOYLE / f"cage_{name}.obj" for name in ("L12", "L10", "L08")}
    paths["L09 split"] = Path(folder) / "cage_L09_split.obj"
    split_cage(GARGOYLE / "cage_L09.obj", paths["L09 split"])
    once = Path(folder) / "cage_L10_split.obj"
    split_cage(GARGOYLE / "cage_L10.obj", once)
    paths["L10 split twice"] = Path(folder) / "cage_L10_split_twice.obj"
    split_cage(once, paths["L10 split twice"])
    return paths


def bind_row(name, path, cells, tree=None):
    """One bind's row, or None where the memory check refuses it (said)."""
    n = len(read_cage(path)[0])
    try:
        check_memory(n, cells, 3)
    except CageError as error:
        print(f"| {name} | {n} | {cells} asked | refused: {error} |", flush=True)
        return None
    return dict(bench_3d(name, cells=cells, cage_path=path, tree=tree), cage=name)


# One bind of a cage written by ``write_scene`` (vertices, faces, points) with the lbc_core of a tree, timed.
_BIND_SCRIPT = """
import sys
sys.path.insert(0, {tree!r})
import json, resource, time, numpy as np, lbc_core
assert lbc_core.__file__.startswith({tree!r}), lbc_core.__file__
def cpu():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime
scene = np.load({scene!r})
faces = [f.tolist() for f in np.split(scene["faces"], np.cumsum(scene["sizes"])[:-1])]
start, start_cpu = time.perf_counter(), cpu()
b = lbc_core.bind(scene["vertices"], faces, scene["points"], cells={cells!r})
total, total_cpu = time.perf_counter() - start, cpu() - start_cpu
print(json.dumps({{"n": b.cage.n_control_points, "cells": len(b.domain.cells), "total": total, "cpu": total_cpu,
    "stages": b.timings,
    "iterations": b.iterations, "objective": float(b.objective)}}))
"""


def interleaved_scenes(which):
    """[(label, vertices, faces, points)] of a cage set (see the module's docstring)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from helpers import cage_corpus
    from lbc_core.io import read_mesh

    scenes = []
    if which in ("gargoyle", "all"):
        points = read_mesh(GARGOYLE / "mesh.off")[0]
        scenes += [(f"gargoyle {level}", *read_cage(GARGOYLE / f"cage_{level}.obj"), points)
                   for level in ("L08", "L09", "L10", "L11", "L12", "L13", "L14", "L15", "L16")]
    if which in ("data", "all"):
        data = ROOT / "tests" / "data" / "cages-3d"
        scenes += [(name, *read_cage(data / name / "cage.obj"), read_mesh(data / name / "mesh.obj")[0])
                   for name in ("hand", "arm", "clothing")]
    if which in ("corpus", "all"):
        for name in cage_corpus.names():
            vertices, faces = cage_corpus.load(name)
            low, high = vertices.min(axis=0), vertices.max(axis=0)
            middle = np.random.default_rng(0).uniform(-1.0, 1.0, (1000, 3))
            scenes.append((name, vertices, faces, 0.5 * (low + high) + 0.25 * (high - low) * middle))
    return scenes


def write_scene(path, vertices, faces, points):
    np.savez(path, vertices=np.asarray(vertices, dtype=float), faces=np.concatenate([np.asarray(f) for f in faces]),
             sizes=np.array([len(f) for f in faces]), points=np.asarray(points, dtype=float))


def bind_in(tree, scene, cells):
    """One bind of the scene file ``scene`` by ``tree``'s lbc_core in a child process: its record."""
    script = _BIND_SCRIPT.format(tree=str(tree), scene=str(scene), cells=cells)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    return json.loads(run.stdout.strip().splitlines()[-1])


def tree_label(tree):
    """The short commit of a worktree (its directory's name if git cannot tell), with '+' if it has changes."""
    try:
        head = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return head + ("+" if dirty else "")
    except (subprocess.CalledProcessError, FileNotFoundError):
        return Path(tree).name


def interleaved(trees, which, repeats, cells):
    """Bind every cage of the set with every tree, interleaved; print one row per cage (medians)."""
    labels = [tree_label(tree) for tree in trees]
    print(f"load average {os.getloadavg()[0]:.1f}; {cells} cells; median of {repeats}; trees {', '.join(labels)}")
    print("| cage | control points | tetrahedra | " + " | ".join(f"{label}: bind s (solve s), CPU s, iterations"
                                                            for label in labels)
          + " | " + " | ".join(f"{label} / {labels[0]}: wall, CPU" for label in labels[1:]) + " | objectives |")
    print("| --- " * (3 + 2 * len(trees) - 1 + 1) + "|")
    with tempfile.TemporaryDirectory() as folder:
        for label, vertices, faces, points in interleaved_scenes(which):
            scene = Path(folder) / "scene.npz"
            write_scene(scene, vertices, faces, points)
            runs = [[] for _ in trees]
            for _ in range(repeats):
                for k, tree in enumerate(trees):
                    runs[k].append(bind_in(tree, scene, cells))
            medians = [float(np.median([r["total"] for r in own])) for own in runs]
            cpus = [float(np.median([r["cpu"] for r in own])) for own in runs]
            solves = [float(np.median([r["stages"].get("solve", 0.0) for r in own])) for own in runs]
            first = runs[0][0]
            cells_made = "/".join(dict.fromkeys(str(own[0]["cells"]) for own in runs))
            print(f"| {label} | {first['n']} | {cells_made} | "
                  + " | ".join(f"{m:.2f} ({s:.2f}), {c:.2f}, {own[0]['iterations']}"
                               for m, s, c, own in zip(medians, solves, cpus, runs))
                  + " | " + " | ".join(f"{m / medians[0]:.2f}×, {c / cpus[0]:.2f}×"
                                       for m, c in zip(medians[1:], cpus[1:]))
                  + " | " + ", ".join(f"{own[0]['objective']:.6g}" for own in runs) + " |", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--interleaved", type=Path, nargs="+", metavar="DIR",
                        help="trees to bind every cage of --cages with, interleaved (the first is the reference)")
    parser.add_argument("--cages", choices=("gargoyle", "corpus", "data", "all"), default="all")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--cells", type=int, default=8000)
    parser.add_argument("--baseline", type=Path, help="a tree of an earlier version to bind beside this one")
    parser.add_argument("--picture", type=Path, default=ROOT / "out" / "scaling.png")
    parser.add_argument("--quick", action="store_true", help="two small cages at two resolutions (a smoke run)")
    args = parser.parse_args(argv)
    if args.interleaved:
        interleaved(args.interleaved, args.cages, args.repeats, args.cells)
        return
    print(f"load average {os.getloadavg()[0]:.1f}")
    print("| cage | control points | tetrahedra | bind s | solve s | iterations | peak memory | baseline bind s "
          "| baseline peak | faster | memory |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        paths = cage_paths(folder)
        for name, cell_counts in (QUICK_PLAN if args.quick else PLAN):
            for cells in cell_counts:
                r = bind_row(name, paths[name], cells)
                if r is None:
                    continue
                rows.append(r)
                line = (f"| {name} | {r['n']} | {r['cells']} | {r['total']:.1f} | {r['stages']['solve']:.1f} "
                        f"| {r['iterations']} | {r['peak_mb']:.0f} MB |")
                base = (bind_row(name, paths[name], cells, args.baseline)
                        if args.baseline and r["n"] * cells <= BASELINE_MOST else None)
                if base is None:
                    line += " | | | |"
                else:
                    line += (f" {base['total']:.1f} | {base['peak_mb']:.0f} MB | {base['total'] / r['total']:.1f}× "
                             f"| {r['peak_mb'] / base['peak_mb']:.2f} |")
                print(line, flush=True)
    for key, what in (("total", "bind time"), ("peak_mb", "peak memory")):
        a, b = fit(rows, key)
        print(f"{what} ∝ cells^{a:.2f} · control points^{b:.2f}")
    print(f"load average {os.getloadavg()[0]:.1f}")
    draw(rows, args.picture)


if __name__ == "__main__":
    main()
