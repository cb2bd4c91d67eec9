"""lbc_core demo: bind the paper's woody 2D cage and a gargoyle 3D cage, print timings and quality, draw pictures.

    .venv/bin/python demo.py          (or: make demo)

Writes out/woody_coordinate.png (one coordinate function with its 1e-3/n level set) and out/woody_deformation.png
(a checkerboard before and after moving one cage vertex).
"""

from pathlib import Path

import numpy as np

import lbc_core
from lbc_core.io import read_cage, read_mesh
from lbc_core.compare.plots import plot_coordinate, plot_deformation

ROOT = Path(__file__).resolve().parent
DATA = ROOT / "tests" / "data"
OUT = ROOT / "out"


def report(name, binding, points):
    weights = binding.weights
    diagonal = binding.cage.bbox_diagonal
    unity = np.abs(np.asarray(weights.sum(axis=1)).ravel() - 1).max()
    reproduction = np.abs(weights @ binding.rest_cage_vertices - points).max() / diagonal
    counts = binding.influence_counts()
    n = binding.cage.n_control_points
    stages = ", ".join(f"{stage} {seconds:.2f}" for stage, seconds in binding.timings.items())
    print(f"{name}: {n} control points, {len(binding.domain.cells)} cells, {len(points)} points")
    print(f"  time {sum(binding.timings.values()):.1f} s ({stages})")
    print(f"  ADMM iterations {binding.iterations} ({'converged' if binding.converged else 'NOT converged'}), "
          f"objective {binding.objective:.6g}")
    print(f"  partition of unity error {unity:.1e}, reproduction error {reproduction:.1e} of the diagonal, "
          f"smallest weight {weights.data.min():.1e}")
    print(f"  control points felt per point: mean {counts.mean():.2f}, max {counts.max()} (of {n}); "
          f"points outside the cage: {binding.outside_count}")


def woody():
    cage, _ = read_cage(DATA / "woody-control-edgeset.obj")
    cage = cage[:, :2]
    # A grid of points over the character, as an image's pixels would be.
    axes = [np.linspace(low, high, 120) for low, high in zip(cage.min(axis=0), cage.max(axis=0))]
    grid = np.stack(np.meshgrid(*axes), axis=-1).reshape(-1, 2)
    from matplotlib.path import Path as PolygonPath

    points = grid[PolygonPath(cage).contains_points(grid)]
    binding = lbc_core.bind(cage, None, points)
    report("woody (2D)", binding, points)
    OUT.mkdir(exist_ok=True)
    plot_coordinate(binding, 5, OUT / "woody_coordinate.png")
    posed = cage.copy()
    posed[5] += [0.15 * np.ptp(cage[:, 0]), 0.05 * np.ptp(cage[:, 1])]
    plot_deformation(binding, posed, OUT / "woody_deformation.png")
    print(f"  wrote {OUT / 'woody_coordinate.png'} and {OUT / 'woody_deformation.png'}")


def gargoyle(level="L10"):
    cage, faces = read_cage(DATA / "cages-3d" / "gargoyle" / f"cage_{level}.obj")
    points, _ = read_mesh(DATA / "cages-3d" / "gargoyle" / "mesh.off")
    binding = lbc_core.bind(cage, faces, points)
    report(f"gargoyle cage {level} (3D)", binding, points)
    moved = cage.copy()
    moved[0] += 0.05 * binding.cage.bbox_diagonal
    displaced = np.linalg.norm(binding.deform(moved) - points, axis=1) > 1e-9 * binding.cage.bbox_diagonal
    print(f"  moving cage vertex 0 moves {displaced.sum()} of {len(points)} mesh vertices "
          f"({100 * displaced.mean():.1f} %)")


if __name__ == "__main__":
    woody()
    gargoyle()
