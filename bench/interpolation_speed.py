"""Time lbc_core.evaluate.interpolation.interpolation_matrix: 1e6 points against ~50k tetrahedra.

The mesh fills the unit cube minus the block [0.5, 1]^3 (non-convex, like a cage's interior): a grid of cubes split
into 6 tetrahedra each, interior vertices jittered so that it is unstructured and not Delaunay. The points are
uniform in the bounding box grown by 5 % on every side, so about a third are outside (in the notch or around the
cube) and get bound to the boundary; then as many points all inside the domain (the usual case: a mesh inside its
cage). Usage:

    .venv/bin/python bench/interpolation_speed.py [n_points] [n_tets]
"""

import sys
import time

import numpy as np

from lbc_core.kernel import fem
from lbc_core.evaluate.interpolation import interpolation_matrix

# The six tetrahedra of a cube sharing its main diagonal 0-7 (corner index = 4 x + 2 y + z).
_CUBE_TETS = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])


def notched_cube(n_tets, rng):
    """About n_tets tetrahedra filling [0, 1]^3 minus [0.5, 1]^3; vertices (N, 3), cells (F, 4)."""
    n = 2 * max(1, round((n_tets / 6 / (7 / 8)) ** (1 / 3) / 2))  # cubes per axis, even so the notch fits the grid
    index = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    lower = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    lower = lower[~np.all(lower >= n // 2, axis=1)]
    offsets = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
    corners = lower[:, None, :] + offsets[None]  # (cubes, 8, 3)
    cube_vertices = index[corners[..., 0], corners[..., 1], corners[..., 2]]
    cells = cube_vertices[:, _CUBE_TETS].reshape(-1, 4)
    used, cells = np.unique(cells, return_inverse=True)
    cells = cells.reshape(-1, 4)
    vertices = np.stack(np.unravel_index(used, index.shape), axis=1) / n
    interior = np.setdiff1d(np.arange(len(vertices)), fem.boundary_facets(cells))
    vertices[interior] += rng.uniform(-0.15, 0.15, (len(interior), 3)) / n
    return vertices, cells


def run(label, vertices, cells, points):
    """Time one call; CPU time is printed too, as wall time means little on a loaded machine."""
    start, start_cpu = time.perf_counter(), time.process_time()
    P, outside, _ = interpolation_matrix(vertices, cells, points)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    error = np.abs(P @ vertices - points)[~outside].max()
    print(
        f"{label}: {len(points)} points, {len(cells)} tets: {elapsed:.2f} s wall, {cpu:.2f} s CPU "
        f"({outside.sum()} outside, max reproduction error inside {error:.1e})"
    )


def main():
    n_points = int(float(sys.argv[1])) if len(sys.argv) > 1 else 1_000_000
    n_tets = int(float(sys.argv[2])) if len(sys.argv) > 2 else 50_000
    rng = np.random.default_rng(0)
    vertices, cells = notched_cube(n_tets, rng)
    around = rng.uniform(-0.05, 1.05, size=(n_points, 3))
    run("box grown by 5 %", vertices, cells, around)
    candidates = rng.uniform(0.0, 1.0, size=(2 * n_points, 3))
    inside = candidates[~np.all(candidates > 0.5, axis=1)][:n_points]
    run("inside the domain", vertices, cells, inside)


if __name__ == "__main__":
    main()
