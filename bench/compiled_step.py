"""Issue 12, items 2 and 3: what a compiled per-cell pass gains in the 3D solver's step (measured, not shipped).

    pip install numba   # into any environment with lbc_core's requirements; the extension does not use it
    python bench/compiled_step.py [--cage L10] [--cells 8000] [--steps 20]

The solver's Douglas–Rachford step (``solver._DouglasRachford.__call__``) does its per-cell work as a dozen numpy
passes over the (d, F, n) X block: the shrink factors, the reflection, Gᵀ times it, G times Z, the update. Here the
same work is two fused numba loops (one before the Y-step's solve, one after), run on the solver's own chunks of
cells in its threads (``nogil``), the solve itself unchanged. Printed, the gargoyle's cage meshed at the given cells,
from the state after ``--steps`` plain steps: milliseconds per step of each, interleaved, the median of ``--steps``
each, and the largest difference of the new states (float32 rounding only).
"""

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402

import lbc_core  # noqa: E402
from lbc_core import fem, solver  # noqa: E402
from lbc_core.boundary import boundary_weights  # noqa: E402
from lbc_core.frame import UnitFrame  # noqa: E402
from lbc_core.geodesics import geodesic_distances, tv_weights  # noqa: E402
from lbc_core.io import read_cage, read_mesh  # noqa: E402
from lbc_core.parallel import thread_map  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"


@numba.njit(nogil=True, fastmath=True)
def shrink_and_reflect(v_x, thresholds, corners, values, first, last, shrink, rhs):
    """Cells first..last-1: shrink factors s (F, n), and rhs (N_in, n) += Gᵀ (v_X (2 s − 1)). Two sweeps, the
    factors, then the reflection and its scatter through a (d, n) buffer: written as one loop nest the scatter does
    not vectorise (3.7 against 1.6 ms on L10 at 8000 cells)."""
    d, _, n = v_x.shape
    tiny = v_x.dtype.type(1e-30)
    for c in range(first, last):
        for j in range(n):
            squared = v_x[0, c, j] * v_x[0, c, j]
            for k in range(1, d):
                squared += v_x[k, c, j] * v_x[k, c, j]
            shrink[c, j] = max(1 - thresholds[c, j] / max(np.sqrt(squared), tiny), 0)
    reflected = np.empty((d, n), dtype=v_x.dtype)
    for c in range(first, last):
        for k in range(d):
            for j in range(n):
                reflected[k, j] = v_x[k, c, j] * (2 * shrink[c, j] - 1)
        for corner in range(d + 1):
            vertex = corners[c, corner]
            if vertex < 0:
                continue
            row = rhs[vertex]
            for k in range(d):
                value = values[k, c, corner]
                for j in range(n):
                    row[j] += value * reflected[k, j]


@numba.njit(nogil=True, fastmath=True)
def update(v_x, shrink, corners, values, Z, E, alpha, first, last, new_x, gradient):
    """Cells first..last-1: gradient = G Z + E, new_x = v_X (1 − α s) + α gradient."""
    d, _, n = v_x.shape
    for c in range(first, last):
        for k in range(d):
            for j in range(n):
                gradient[k, c, j] = E[k, c, j]
        for corner in range(d + 1):
            vertex = corners[c, corner]
            if vertex < 0:
                continue
            for k in range(d):
                value = values[k, c, corner]
                for j in range(n):
                    gradient[k, c, j] += value * Z[vertex, j]
        for k in range(d):
            for j in range(n):
                new_x[k, c, j] = v_x[k, c, j] * (1 - alpha * shrink[c, j]) + alpha * gradient[k, c, j]


class FusedStep:
    """The step of ``dr`` (a plain 3D ``_DouglasRachford``, ε = 0) with its per-cell work in the loops above."""

    def __init__(self, dr, vertices, cells, interior):
        self.dr = dr
        gradients, measures = fem.cell_gradients(vertices, cells)
        dtype = dr.p.G.dtype
        self.values = np.ascontiguousarray(np.transpose(gradients * np.sqrt(measures)[:, None, None], (2, 0, 1)),
                                           dtype=dtype)  # (d, F, d+1), as the solver's G holds them
        index = np.full(len(vertices), -1)
        index[interior] = np.arange(len(interior))
        self.corners = index[cells]
        self.bounds = [(chunk.cells.start, chunk.cells.stop) for chunk in dr.chunks]

    def __call__(self, state):
        dr, p = self.dr, self.dr.p
        v_x, v_w = dr.split(state)
        new_state = np.empty_like(state)
        new_x, new_w = dr.split(new_state)
        shrink = np.empty(dr.shape_x[1:], dtype=state.dtype)
        gradient = np.empty_like(v_x)

        def first_half(bounds):
            rhs = np.zeros(dr.shape_w, dtype=state.dtype)
            shrink_and_reflect(v_x, dr.thresholds, self.corners, self.values, *bounds, shrink, rhs)
            return rhs

        W = dr.clipped(v_w)
        reflected_w = 2.0 * W
        reflected_w -= v_w
        rhs = sum(thread_map(first_half, self.bounds))
        rhs -= dr.boundary_load
        rhs += p.sqrt_mass * reflected_w
        Z = dr.solve(rhs @ p.MT) @ p.M
        Z += p.H
        alpha = state.dtype.type(dr.alpha)
        thread_map(lambda bounds: update(v_x, shrink, self.corners, self.values, Z, dr.boundary_part, alpha,
                                         *bounds, new_x, gradient), self.bounds)
        np.multiply(p.sqrt_mass, Z, out=new_w)
        new_w -= W
        new_w *= dr.alpha
        new_w += v_w
        return new_state


def problem_of(level, cells):
    """The solver's step objects for the gargoyle in cage ``level`` meshed at about ``cells`` cells (unit frame)."""
    cage, faces = read_cage(GARGOYLE / f"cage_{level}.obj")
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    binding = lbc_core.bind(cage, [list(face) for face in faces], points, cells=cells, max_iterations=1)
    frame = UnitFrame.of(binding.cage)
    unit_cage = frame.cage_to_unit(binding.cage)
    vertices = frame.to_unit(binding.domain.vertices)
    mesh_cells = binding.domain.cells
    omega = tv_weights(mesh_cells, geodesic_distances(vertices, mesh_cells, binding.domain.control_vertices))
    # As solve_on_mesh does: the cage scaled to unit diagonal about its vertices' centre.
    centre = vertices.mean(axis=0)
    scale = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    unit_vertices, unit_controls = (vertices - centre) / scale, (unit_cage.vertices - centre) / scale
    boundary = binding.domain.boundary_vertices
    interior = np.setdiff1d(np.arange(len(vertices)), boundary)
    fixed = boundary_weights(binding.domain, unit_cage)
    progress = lbc_core.progress.Progress.of(None, None)
    p = solver._Problem(unit_vertices, mesh_cells, boundary, fixed, unit_controls, interior, solver.BETA[3],
                        np.float32, progress)
    n = len(unit_controls)
    dr = solver._DouglasRachford(p, omega, 0.0, solver.RELAXATION[3], solver._default_penalty(3, n), lambda: None)
    return dr, FusedStep(dr, unit_vertices, mesh_cells, interior)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cage", default="L10")
    parser.add_argument("--cells", type=int, default=8000)
    parser.add_argument("--steps", type=int, default=20)
    arguments = parser.parse_args(argv)
    dr, fused = problem_of(arguments.cage, arguments.cells)
    state = dr.initial_state()
    for _ in range(arguments.steps):
        state, _ = dr(state)
    clock = time.perf_counter()
    fused(state)  # compiles
    compile_seconds = time.perf_counter() - clock
    plain, compiled, largest = [], [], 0.0
    for _ in range(arguments.steps):
        clock = time.perf_counter()
        expected, _ = dr(state)
        plain.append(time.perf_counter() - clock)
        clock = time.perf_counter()
        got = fused(state)
        compiled.append(time.perf_counter() - clock)
        largest = max(largest, float(np.abs(got - expected).max() / np.abs(expected).max()))
        state = expected
    p = dr.p
    print(f"gargoyle {arguments.cage}: {p.n_cells} tetrahedra, {dr.shape_x[2]} control points, {p.n_interior} "
          f"interior vertices, X block {dr.size_x / 1e6:.1f} M entries; numba {numba.__version__}, "
          f"{len(dr.chunks)} chunks; load average {os.getloadavg()[0]:.1f}")
    print(f"step, ms (median of {arguments.steps}): numpy {1e3 * statistics.median(plain):.1f}, fused "
          f"{1e3 * statistics.median(compiled):.1f}; first fused call (compiling) {compile_seconds:.2f} s; largest "
          f"difference of the new states {largest:.1e} of their largest entry")


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)
