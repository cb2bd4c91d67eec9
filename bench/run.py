"""The project's benchmark: prints figures, measured side by side in one run (no timed assertions anywhere).

1. 2D: our solver against the faithful re-implementation of the reference's ADMM on the paper's packs (bench_2d).
2. 3D: whole binds of gargoyle cages (27, 106 and 168 control points) with the time of each stage and peak memory,
   each in a child process so its peak resident memory is its own.
3. Deform: per-frame cost of moving a 100k-vertex mesh with the reduced LBC weights, against a bare CSR product of
   the same size and a dense mean-value-coordinates product (the paper's Table 1 comparison).

    .venv/bin/python bench/run.py [--skip-2d] [--skip-3d] [--skip-deform]
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
CAGES_3D = ["L12", "L09", "L08"]


def machine():
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def bench_3d(level, cells=None, cage_path=None, tree=None):
    """Bind the gargoyle mesh to one cage in a child process; return its stage times, counts and peak memory.

    ``level`` names a gargoyle cage (``cage_path`` another OBJ cage instead); ``cells`` None is the default
    resolution; ``tree`` a source tree whose lbc_core binds instead of this one (a baseline's checkout)."""
    cage_path = cage_path or GARGOYLE / f"cage_{level}.obj"
    script = f"""
import sys
sys.path.insert(0, {str(tree or ROOT)!r})
import json, resource, time, numpy as np, lbc_core
assert lbc_core.__file__.startswith({str(tree or ROOT)!r}), lbc_core.__file__
from lbc_core.io import read_cage, read_mesh
cage, faces = read_cage({str(cage_path)!r})
points, _ = read_mesh({str(GARGOYLE / "mesh.off")!r})
start = time.perf_counter()
b = lbc_core.bind(cage, faces, points, cells={cells!r})
total = time.perf_counter() - start
counts = b.influence_counts()
print(json.dumps({{"n": b.cage.n_control_points, "cells": len(b.domain.cells), "total": total, "stages": b.timings,
    "iterations": b.iterations, "converged": b.converged, "mean": float(counts.mean()), "max": int(counts.max()),
    "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}}))
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    return json.loads(run.stdout.strip().splitlines()[-1])


def print_3d(results):
    stages = ["checks", "meshing", "geodesics", "factorisation", "solve", "interpolation", "reduction"]
    print(f"{'cage':6s} {'n':>4s} {'tets':>6s} {'total s':>8s} " + " ".join(f"{s[:8]:>8s}" for s in stages)
          + f" {'iters':>6s} {'infl mean/max':>14s} {'peak MB':>8s}")
    for level, r in results.items():
        share = (r["stages"].get("meshing", 0) + r["stages"].get("geodesics", 0)) / r["total"]
        print(f"{level:6s} {r['n']:4d} {r['cells']:6d} {r['total']:8.1f} "
              + " ".join(f"{r['stages'].get(s, 0.0):8.2f}" for s in stages)
              + f" {r['iterations']:6d} {r['mean']:7.2f} / {r['max']:<4d} {r['peak_mb']:8.0f}"
              + f"   (meshing + geodesics {100 * share:.0f} %)")


def dense_points(count, seed=0):
    """``count`` points on the gargoyle's surface (inside every cage): its vertices plus samples of its triangles."""
    from lbc_core.io import read_mesh

    vertices, faces = read_mesh(GARGOYLE / "mesh.off")
    faces = np.asarray(faces)
    rng = np.random.default_rng(seed)
    extra = count - len(vertices)
    chosen = faces[rng.integers(0, len(faces), extra)]
    bary = rng.dirichlet(np.ones(3), extra)
    return np.concatenate([vertices, np.einsum("mk,mkd->md", bary, vertices[chosen])])


def timed(function, repeats=20, batches=5):
    """Seconds per call: the best of several batches (on a shared machine noise only adds)."""
    function()
    best = float("inf")
    for _ in range(batches):
        start = time.perf_counter()
        for _ in range(repeats):
            function()
        best = min(best, (time.perf_counter() - start) / repeats)
    return best


def bench_deform(level="L09", count=100_000):
    """Per-frame cost of deforming ``count`` points bound to the gargoyle cage ``level``: printed, and returned as a
    dict (seconds per frame of LBC, of a bare CSR product of the same pattern and of a dense MVC product; bytes of
    both weight matrices)."""
    import scipy.sparse as sp

    import lbc_core
    from lbc_core.compare.baselines import mean_value_coordinates
    from lbc_core.io import read_cage

    cage_vertices, faces = read_cage(GARGOYLE / f"cage_{level}.obj")
    points = dense_points(count)
    binding = lbc_core.bind(cage_vertices, faces, points)
    posed = cage_vertices + np.random.default_rng(1).normal(0, 0.01, cage_vertices.shape)
    weights = binding.weights
    bare = sp.csr_matrix((np.ones_like(weights.data), weights.indices, weights.indptr), shape=weights.shape)
    mvc = mean_value_coordinates(binding.cage, points)
    lbc_s = timed(lambda: binding.deform(posed))
    bare_s = timed(lambda: bare @ posed)
    mvc_s = timed(lambda: mvc @ posed)
    lbc_bytes = weights.data.nbytes + weights.indices.nbytes + weights.indptr.nbytes
    print(f"{count} points, cage {level} ({binding.cage.n_control_points} control points), "
          f"{weights.nnz / count:.2f} weights per point")
    print(f"  LBC deform (reduced, displacement form) {1e3 * lbc_s:7.2f} ms/frame")
    print(f"  bare CSR product, same pattern           {1e3 * bare_s:7.2f} ms/frame   LBC / bare  = {lbc_s / bare_s:.2f}")
    print(f"  dense MVC product                        {1e3 * mvc_s:7.2f} ms/frame   LBC / MVC   = {lbc_s / mvc_s:.2f}")
    print(f"  memory: LBC {lbc_bytes / 2**20:.1f} MB, dense MVC {mvc.nbytes / 2**20:.1f} MB "
          f"({100 * lbc_bytes / mvc.nbytes:.0f} %)")
    return dict(level=level, points=count, n=binding.cage.n_control_points, per_point=weights.nnz / count,
                lbc_s=lbc_s, bare_s=bare_s, mvc_s=mvc_s, lbc_bytes=lbc_bytes, mvc_bytes=mvc.nbytes)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-2d", action="store_true")
    parser.add_argument("--skip-3d", action="store_true")
    parser.add_argument("--skip-deform", action="store_true")
    args = parser.parse_args(argv)
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.1f}")
    if not args.skip_2d:
        from bench import bench_2d

        print("\n## 2D: ours vs the reference's ADMM, same process")
        bench_2d.main([])
    if not args.skip_3d:
        print("\n## 3D: gargoyle binds, stage split (seconds) and peak memory")
        print_3d({level: bench_3d(level) for level in CAGES_3D})
    if not args.skip_deform:
        print("\n## Deform: per-frame cost at 100k vertices")
        bench_deform()


if __name__ == "__main__":
    main()
