"""The ADMM penalty balanced against the residuals against the penalty fixed, same meshes (hard cages converge).

    .venv/bin/python bench/penalty_balance.py [CAGE ...] [--cells N]

CAGE: a gargoyle cage (L08 ... L16), ``uv:S:R`` (a UV sphere of S segments and R rings, as Blender makes it: 24:13
has 290 vertices), ``capsule``, or ``corpus:NAME:VARIANT`` (tests/helpers/cage_corpus.py, e.g.
corpus:thin-plate:as-made, corpus:torus:squashed-1e-3); ``corpus:as-made`` or ``corpus:squashed-1e-3`` stands for every
corpus cage in that variant. Each cage is meshed once, as the pipeline does; then solved with balancing off (``BALANCE_UNTIL`` 0) and on.
Prints iterations, objective, seconds and the penalty changes of each. ``--lows 0.05,0.1`` solves with balancing
on at each of these floors of the residuals' ratio (``BALANCE_LOW``) instead.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from bench.run import GARGOYLE  # noqa: E402
from lbc_core.solve import solver  # noqa: E402
from lbc_core.solve.boundary import boundary_weights  # noqa: E402
from lbc_core.cage.make import make_cage  # noqa: E402
from lbc_core.kernel.frame import UnitFrame  # noqa: E402
from lbc_core.solve.geodesics import geodesic_distances, tv_weights  # noqa: E402
from lbc_core.io import read_cage  # noqa: E402
from lbc_core.meshing import mesh_domain  # noqa: E402

DEFAULT = ["uv:24:13", "L08", "L10", "L12", "capsule", "corpus:thin-plate:as-made", "corpus:torus:as-made"]


def uv_sphere(segments, rings):
    """Blender's UV sphere of unit radius: poles, ``rings - 1`` rings of ``segments`` vertices, quads and pole fans."""
    vertices = [[0.0, 0.0, 1.0]]
    for ring in range(1, rings):
        theta = np.pi * ring / rings
        for segment in range(segments):
            phi = 2 * np.pi * segment / segments
            vertices.append([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    vertices.append([0.0, 0.0, -1.0])
    last = len(vertices) - 1
    faces = [[0, 1 + s, 1 + (s + 1) % segments] for s in range(segments)]
    for ring in range(rings - 2):
        a, b = 1 + ring * segments, 1 + (ring + 1) * segments
        faces += [[a + s, b + s, b + (s + 1) % segments, a + (s + 1) % segments] for s in range(segments)]
    base = 1 + (rings - 2) * segments
    faces += [[base + s, last, base + (s + 1) % segments] for s in range(segments)]
    return np.array(vertices), faces


def load(name):
    """(vertices, faces) of a cage named as in the module's docstring."""
    from helpers import cage_corpus

    if name.startswith("uv:"):
        _, segments, rings = name.split(":")
        return uv_sphere(int(segments), int(rings))
    if name == "capsule":
        from bench.capsule import cage
        return cage()
    if name.startswith("corpus:"):
        _, base, variant = name.split(":")
        vertices, faces = cage_corpus.load(base)
        return (vertices, faces) if variant == "as-made" else cage_corpus.variant(vertices, faces, variant)
    return read_cage(GARGOYLE / f"cage_{name}.obj")


def expand(names):
    """``corpus:VARIANT`` becomes every corpus cage in that variant."""
    from helpers import cage_corpus

    for name in names:
        parts = name.split(":")
        if parts[0] == "corpus" and len(parts) == 2:
            yield from (f"corpus:{base}:{parts[1]}" for base in cage_corpus.names())
        else:
            yield name


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cages", nargs="*", default=DEFAULT)
    parser.add_argument("--cells", type=int, default=8000)
    parser.add_argument("--lows", type=lambda text: [float(low) for low in text.split(",")])
    args = parser.parse_args()
    balance_until, balance_low = solver.BALANCE_UNTIL, solver.BALANCE_LOW
    # (column title, BALANCE_UNTIL, BALANCE_LOW) of each solve
    variants = ([(f"floor {low}", balance_until, low) for low in args.lows] if args.lows else
                [("fixed", 0, balance_low), ("balanced", balance_until, balance_low)])
    print(f"| cage | n | tetrahedra | {' | '.join(f'{title}: iterations, objective, s' for title, _, _ in variants)} "
          "| changes |")
    print("| --- | --- | --- |" + " --- |" * (len(variants) + 1))
    for name in expand(args.cages):
        cage = make_cage(*load(name))
        unit = UnitFrame.of(cage).cage_to_unit(cage)
        domain = mesh_domain(unit, args.cells, "auto")
        problem = (domain.vertices, domain.cells, domain.boundary_vertices, boundary_weights(domain, unit),
                   unit.vertices, tv_weights(domain.cells, geodesic_distances(domain.vertices, domain.cells,
                                                                              domain.control_vertices), "quadratic"))
        cells = []
        for _, until, low in variants:
            solver.BALANCE_UNTIL, solver.BALANCE_LOW = until, low
            start = time.perf_counter()
            result = solver.solve_on_mesh(*problem)
            seconds = time.perf_counter() - start
            changes = [(record["iteration"], round(record["penalty"], 4)) for record in result.history
                       if "penalty" in record]
            cells.append((f"{result.iterations}{'' if result.converged else ' (not converged)'}, "
                          f"{result.objective:.6f}, {seconds:.1f}", changes))
        solver.BALANCE_UNTIL, solver.BALANCE_LOW = balance_until, balance_low
        print(f"| {name} | {cage.n_control_points} | {len(domain.cells)} | "
              f"{' | '.join(text for text, _ in cells)} | {'; '.join(str(changes or 'none') for _, changes in cells)} |",
              flush=True)


if __name__ == "__main__":
    main()
