"""Thin cages: the solve in the cage's frame against the solve in the stretched frame, same mesh, same process.

    PYTHONPATH=. .venv/bin/python bench/thin_cages.py [name:thickness ...] [--max-iterations 3000]

Each case is a corpus cage (tests/data/cage-corpus) flattened along z to ``thickness`` × its width (the corpus's
"squashed-1e-3" variant is thickness 0.001; "thin-plate:as-made" is the plate as it is), meshed once as the pipeline
meshes it and solved twice on that mesh, whatever its stretch and control points: in the unit frame of the cage (as
every cage below ``solver.STRETCHED_SOLVE_FROM`` or above ``solver.STRETCHED_MOST_CONTROL_POINTS`` is solved) and in
the frame the mesher stretched it into, the total variation's norm weighted per axis. Printed per solve: iterations, whether the stopping rule was met, CPU and wall seconds, the objective
(Σ ω |c| |∇w|, unit-diagonal cage) and its excess over the lower of the two.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from helpers import cage_corpus  # noqa: E402
from lbc_core.solve import solver  # noqa: E402
from lbc_core.solve.boundary import boundary_weights  # noqa: E402
from lbc_core.cage.make import make_cage  # noqa: E402
from lbc_core.kernel.frame import UnitFrame  # noqa: E402
from lbc_core.solve.geodesics import geodesic_distances, tv_weights  # noqa: E402
from lbc_core.meshing import mesh_domain  # noqa: E402

CASES = ["cube:0.001", "cylinder-3-ngon:0.001", "cone-8-ngon:0.001", "cylinder-8-fan:0.001", "thin-plate:as-made",
         "prism-8-rings-2:0.001", "cylinder-16-ngon:0.001", "cone-32-ngon:0.001", "grid-box:0.002", "limbs:0.001",
         "torus:0.001", "cube:0.01", "limbs:0.01", "cube:0.05", "limbs:0.05"]


def flattened(name, thickness):
    """A corpus cage's (vertices, faces), flattened along z to ``thickness`` × its width ("as-made": unchanged)."""
    vertices, faces = cage_corpus.load(name)
    vertices = np.array(vertices, dtype=float)
    if thickness != "as-made":
        low = vertices[:, 2].min()
        vertices[:, 2] = low + (vertices[:, 2] - low) * float(thickness) * np.ptp(vertices[:, :2], axis=0).max() / (
            np.ptp(vertices[:, 2]))
    return vertices, faces


def problem(name, thickness):
    """solve_on_mesh's arguments for the flattened cage, as the pipeline makes them, and the cage's stretch."""
    cage = make_cage(*flattened(name, thickness))
    unit = UnitFrame.of(cage).cage_to_unit(cage)
    domain = mesh_domain(unit, None, "auto")
    omega = tv_weights(domain.cells, geodesic_distances(domain.vertices, domain.cells, domain.control_vertices),
                       "quadratic")
    arguments = (domain.vertices, domain.cells, domain.boundary_vertices, boundary_weights(domain, unit),
                 unit.vertices, omega)
    sigma = np.linalg.norm(solver.MeshingFrame(unit.vertices).matrix, axis=0)
    return arguments, sigma.max() / sigma.min()


def timed_solve(arguments, stretched, max_iterations):
    """One solve, in the stretched frame or the cage's; returns (result, cpu s, wall s)."""
    saved = solver.STRETCHED_SOLVE_FROM, solver.STRETCHED_MOST_CONTROL_POINTS
    solver.STRETCHED_SOLVE_FROM = 1.0 + 1e-9 if stretched else np.inf
    solver.STRETCHED_MOST_CONTROL_POINTS = np.inf
    try:
        cpu, wall = time.process_time(), time.perf_counter()
        result = solver.solve_on_mesh(*arguments, max_iterations=max_iterations)
        return result, time.process_time() - cpu, time.perf_counter() - wall
    finally:
        solver.STRETCHED_SOLVE_FROM, solver.STRETCHED_MOST_CONTROL_POINTS = saved


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", default=CASES)
    parser.add_argument("--max-iterations", type=int, default=3000)
    args = parser.parse_args()
    print(f"{'cage':24s} {'stretch':>7s} {'n':>4s} {'cells':>6s} | {'frame':9s} {'iters':>6s} {'conv':>5s} "
          f"{'cpu s':>7s} {'wall s':>7s} {'objective':>11s} {'excess':>8s}")
    for case in args.cases:
        name, thickness = case.split(":")
        arguments, stretch = problem(name, thickness)
        solves = {frame: timed_solve(arguments, frame == "stretched", args.max_iterations)
                  for frame in ("cage", "stretched")}
        best = min(result.objective for result, _, _ in solves.values())
        for frame, (result, cpu, wall) in solves.items():
            print(f"{case:24s} {stretch:7.1f} {len(arguments[4]):4d} {len(arguments[1]):6d} | {frame:9s} "
                  f"{result.iterations:6d} {result.converged!s:>5s} {cpu:7.2f} {wall:7.2f} {result.objective:11.6g} "
                  f"{result.objective / best - 1:8.2%}", flush=True)


if __name__ == "__main__":
    main()
