"""How long a cancel can wait in each stage of a bind, and the longest calls that cannot be interrupted.

A whole bind of the gargoyle in one of its cages (by default L08, 168 control points) runs with a ``cancel`` that
only records when it is polled; the longest time between two polls in a stage is the latency of a cancel turning true
at the worst moment there (the stages and the instrument are tests/helpers/stages.py's). The sparse Cholesky
factorisations, which hold the GIL and cannot be interrupted, are timed on their own. ADMM iterations are capped: the
waits repeat from one iteration to the next.

    .venv/bin/python bench/cancel_latency.py [--cage L08] [--cells 8000 64000] [--points N] [--iterations K]
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import lbc_core.solve.geodesics as geodesics  # noqa: E402
import lbc_core.solve.working_sets as working_sets  # noqa: E402
from lbc_core.kernel.factor import Factor  # noqa: E402
from lbc_core.io import read_cage, read_mesh  # noqa: E402
from helpers.stages import STAGE_MESSAGES, longest_waits  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"


class _TimedFactor(Factor):
    """The solver's factorisation, recording how long each construction takes (the uninterruptible call)."""

    seconds = []

    def __init__(self, lower, dtype):
        start = time.perf_counter()
        super().__init__(lower, dtype)
        self.seconds.append((lower.shape[0], time.perf_counter() - start))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cage", default="L08", help="gargoyle cage level, L08 to L16")
    parser.add_argument("--cells", type=int, nargs="+", default=[8000, 64000])
    parser.add_argument("--points", type=int, default=0, help="bind this many points near the mesh instead of it")
    parser.add_argument("--iterations", type=int, default=30, help="ADMM iterations per bind (0: to convergence)")
    args = parser.parse_args()
    geodesics.Factor = working_sets.Factor = _TimedFactor  # the two stages that factorise
    vertices, faces = read_cage(GARGOYLE / f"cage_{args.cage}.obj")
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    if args.points:
        rng = np.random.default_rng(0)
        points = points[rng.integers(0, len(points), args.points)] + rng.normal(0, 1e-3, (args.points, 3))
    print(f"gargoyle {args.cage}, {len(points)} points, {args.iterations or 'all'} ADMM iterations; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print("| cells | " + " | ".join(STAGE_MESSAGES) + " | factorisations (size: s) | bind s |")
    print("| --- |" + " --- |" * (len(STAGE_MESSAGES) + 2))
    for cells in args.cells:
        _TimedFactor.seconds.clear()
        start = time.perf_counter()
        waits = longest_waits(vertices, faces, points, cells=cells, max_iterations=args.iterations or 10000)
        total = time.perf_counter() - start
        factors = ", ".join(f"{size}: {seconds:.2f}" for size, seconds in _TimedFactor.seconds)
        print(f"| {cells} | " + " | ".join(f"{waits.get(stage, float('nan')):.3f}" for stage in STAGE_MESSAGES)
              + f" | {factors} | {total:.1f} |", flush=True)


if __name__ == "__main__":
    main()
