"""The least time the paper's dense splitting (lbc_core.solve.dense, the solver up to 5715f72) can take, one run.

    .venv/bin/python bench/floors.py [--baseline DIR] [--scene l08|gargoyle ...]

The dense splitting's ADMM (``lbc_core.solve.nullspace.DenseSplitting``): every iteration solves the Y-step (one factorised solve with
n − d − 1 right-hand sides) and sweeps the (d, F, n) X block of split gradients, which holds every (cell,
coordinate) pair. However it were compiled, an iteration cannot take less than its Y-step plus one read-and-write
pass over that block. Printed per scene: the default bind (lbc_core.bind on the gargoyle's 2674-point mesh) with its
iterations and stages, then per iteration the numpy step, the Y-step's solve and one pass over the X block timed on
the bind's own mesh (medians of 7), and the floor: iterations × (Y-step + one pass) plus the bind's stages outside
the solve as they are.

--baseline DIR  a tree of an earlier version (``git archive 89a6c11 | tar -x -C DIR``): its bind of cage L08 at 8000
                cells, in a child process of this run, is the budget a bind of L08 at 32,000 cells is held to.
The locality solver's own step, part by part: ``bench/solver_step.py``.
"""

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lbc_core  # noqa: E402
from lbc_core.solve import nullspace  # noqa: E402
from lbc_core.solve import dense as solver  # noqa: E402  (the paper's dense splitting, as 5715f72 solved)
from lbc_core.solve.boundary import boundary_weights  # noqa: E402
from lbc_core.kernel.frame import UnitFrame  # noqa: E402
from lbc_core.solve.geodesics import geodesic_distances, tv_weights  # noqa: E402
from lbc_core.io import read_cage, read_mesh  # noqa: E402
from lbc_core.kernel.progress import Progress  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
SCENES = {"l08": ("L08", 32000), "gargoyle": ("L10", 8000)}
REPEATS = 7


def median_seconds(function, repeats=REPEATS):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return sorted(times)[repeats // 2]


def per_iteration(binding):
    """Seconds per iteration on ``binding``'s own domain: (numpy step, Y-step's solve, one pass over X)."""
    frame = UnitFrame.of(binding.cage)
    unit, domain = frame.cage_to_unit(binding.cage), frame.domain_to_unit(binding.domain)
    fixed = boundary_weights(domain, unit)
    omega = tv_weights(domain.cells, geodesic_distances(domain.vertices, domain.cells, domain.control_vertices),
                       "quadratic")
    # As solve_on_mesh does: the domain centred and scaled to unit diagonal.
    centre = domain.vertices.mean(axis=0)
    scale = np.linalg.norm(np.ptp(domain.vertices, axis=0))
    vertices, controls = (domain.vertices - centre) / scale, (unit.vertices - centre) / scale
    interior = np.setdiff1d(np.arange(len(vertices)), domain.boundary_vertices)
    n, d = controls.shape
    progress = Progress.of(None, None)
    problem = nullspace.DenseProblem(vertices, domain.cells, domain.boundary_vertices, fixed, controls, interior,
                              solver.BETA[d], np.float32, progress)
    step = nullspace.DenseSplitting(problem, omega, 0.0, solver.RELAXATION[d], solver._default_penalty(d, n),
                                    progress.check)
    state = step.initial_state()
    rhs = np.random.default_rng(0).random((len(interior), n)).astype(np.float32) @ problem.MT
    x_block = state[:step.size_x]
    out = np.empty_like(x_block)
    y_step = median_seconds(lambda: step.solve(rhs))
    one_pass = median_seconds(lambda: np.multiply(x_block, 1.5, out=out))
    numpy_step = median_seconds(lambda: step(state))
    return numpy_step, y_step, one_pass, step.size_x


def bench_scene(name):
    cage_name, cells = SCENES[name]
    cage, faces = read_cage(GARGOYLE / f"cage_{cage_name}.obj")
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    start = time.perf_counter()
    binding = lbc_core.bind(cage, faces, points, cells=cells)
    total = time.perf_counter() - start
    outside_solve = total - binding.timings["solve"]
    numpy_step, y_step, one_pass, size_x = per_iteration(binding)
    floor = binding.iterations * (y_step + one_pass) + outside_solve
    print(f"{cage_name} ({binding.cage.n_control_points} control points) at {cells} cells, {len(binding.domain.cells)} "
          f"tetrahedra, X block {size_x / 1e6:.1f} M entries: bind {total:.2f} s, {binding.iterations} iterations, "
          f"solve {binding.timings['solve']:.2f} s, outside the solve {outside_solve:.2f} s "
          f"({', '.join(f'{k} {v:.2f}' for k, v in binding.timings.items() if k != 'solve')})", flush=True)
    print(f"  per iteration: numpy step {numpy_step * 1e3:.1f} ms, Y-step's solve {y_step * 1e3:.1f} ms, one pass "
          f"over X {one_pass * 1e3:.1f} ms; floor {binding.iterations} × ({y_step * 1e3:.1f} + {one_pass * 1e3:.1f}) "
          f"ms + {outside_solve:.2f} s = {floor:.2f} s; {load()}", flush=True)


def bench_baseline(tree):
    """The earlier version's bind of L08 at 8000 cells, in a child process on ``tree``."""
    code = ("import sys, time; sys.path.insert(0, sys.argv[1]); import lbc_core; "
            "from lbc_core.io import read_cage, read_mesh; from pathlib import Path; "
            "g = Path(sys.argv[2]); c, f = read_cage(g / 'cage_L08.obj'); p, _ = read_mesh(g / 'mesh.off'); "
            "t = time.perf_counter(); b = lbc_core.bind(c, f, p, cells=8000); "
            "print(f'{time.perf_counter() - t:.2f} s, {b.iterations} iterations, {len(b.domain.cells)} tetrahedra')")
    result = subprocess.run([sys.executable, "-c", code, str(Path(tree).resolve()), str(GARGOYLE)],
                            capture_output=True, text=True, check=True)
    print(f"budget of a 32,000-cell bind, {tree} (L08 at 8000 cells): {result.stdout.strip()}; {load()}", flush=True)


def load():
    return f"load average {os.getloadavg()[0]:.1f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="a tree of 89a6c11: its L08 bind at 8000 cells is the budget at 32,000")
    parser.add_argument("--scene", action="append", choices=sorted(SCENES), help="default: both")
    args = parser.parse_args()
    if args.baseline:
        bench_baseline(args.baseline)
    for name in args.scene or ["gargoyle", "l08"]:
        bench_scene(name)
    if args.baseline:
        bench_baseline(args.baseline)


if __name__ == "__main__":
    main()
