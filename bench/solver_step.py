"""The locality solver's step, part by part, on a bind's own mesh (one run).

    .venv/bin/python bench/solver_step.py [--cage L08] [--cells 32000]

Binds the gargoyle's mesh to one of its cages, then times on the solve's final working sets (medians of 7): the
gradient on the pairs (G·z), its transpose (Gᵀ·r), the block-diagonal least-squares solve, the per-vertex projection
from the last step's duals, the TV prox, and the whole Douglas–Rachford step; and prints the sets' size (slots,
pairs, pairs per cell). Compare with ``bench/floors.py``, the dense splitting's floor.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lbc_core.solve import solver  # noqa: E402
from lbc_core.solve.boundary import boundary_weights  # noqa: E402
from lbc_core.cage.make import make_cage  # noqa: E402
from lbc_core.kernel.frame import UnitFrame  # noqa: E402
from lbc_core.solve.geodesics import geodesic_distances, tv_weights  # noqa: E402
from lbc_core.io import read_cage  # noqa: E402
from lbc_core.meshing import mesh_domain  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
REPEATS = 7


def median_ms(function):
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1000 * sorted(times)[REPEATS // 2]


def final_step(cage_name, cells):
    """The solve's last step map and state on the cage's mesh (the solver's own run, kept at its end)."""
    vertices, faces = read_cage(GARGOYLE / f"cage_{cage_name}.obj")
    cage = make_cage(vertices, faces)
    unit = UnitFrame.of(cage).cage_to_unit(cage)
    domain = mesh_domain(unit, cells)
    omega = tv_weights(domain.cells, geodesic_distances(domain.vertices, domain.cells, domain.control_vertices))
    kept = {}
    iterate = solver._Run._iterate

    def keep(run, step, state):
        state, out, step = iterate(run, step, state)
        kept.update(step=step, state=state)
        return state, out, step

    solver._Run._iterate = keep
    try:
        result = solver.solve_on_mesh(domain.vertices, domain.cells, domain.boundary_vertices,
                                      boundary_weights(domain, unit), unit.vertices, omega)
    finally:
        solver._Run._iterate = iterate
    return kept["step"], kept["state"], result, len(domain.cells)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cage", default="L08")
    parser.add_argument("--cells", type=int, default=32000)
    args = parser.parse_args(argv)
    step, state, result, n_cells = final_step(args.cage, args.cells)
    ops = step.ops
    v_x, v_w = step.split(state)
    z = v_w / ops.slot_mass
    r = v_x.ravel().copy()
    duals = step.duals.copy()
    print(f"gargoyle {args.cage}, {n_cells} cells, {result.iterations} iterations; {ops.sets.n_slots} slots "
          f"({ops.sets.n_slots / len(ops.padded.targets):.1f} a vertex), {ops.n_pairs} pairs "
          f"({ops.n_pairs / n_cells:.1f} a cell); load average {os.getloadavg()[0]:.1f}")
    parts = {"G·z": lambda: ops.gradients(z), "Gᵀ·r": lambda: ops.transposed(r), "solve": lambda: ops.solve(z),
             "projection": lambda: ops.project(z.astype(np.float64), duals.copy()),
             "prox": lambda: step.shrink_factors(v_x, step.thresholds), "whole step": lambda: step(state)}
    print("| " + " | ".join(parts) + " |")
    print("| " + " | ".join("---" for _ in parts) + " |")
    print("| " + " | ".join(f"{median_ms(part):.1f} ms" for part in parts.values()) + " |")


if __name__ == "__main__":
    main()
