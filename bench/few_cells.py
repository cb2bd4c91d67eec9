"""How far a bind with few cells per control point lands from a finer one: the add-on's "few cells" warning.

    .venv/bin/python bench/few_cells.py

The gargoyle mesh (2674 points) in its cage L08 (168 control points) and in L09 with every triangle split in four
(418, as bench/scaling.py makes it), bound at a few cell counts and at 16,000 (the reference); the largest distance
over three poses (a 30° twist plus 3 % noise per cage vertex, bench/smoothness.py's) between the two deformations,
over the cage's diagonal. One bind at a time, in this process.
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lbc_core  # noqa: E402
from bench.scaling import split_cage  # noqa: E402
from bench.smoothness import twisted_poses  # noqa: E402
from lbc_core.io import read_cage, read_mesh  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
PLAN = (("L08", (2000, 3000, 4000, 8000)), ("L09 split", (4000, 6000, 8000, 12000)))
REFERENCE_CELLS = 16000


def cage_of(name, folder):
    """The cage's (vertices, faces) by its PLAN name."""
    if name.endswith(" split"):
        path = Path(folder) / "split.obj"
        split_cage(GARGOYLE / f"cage_{name.split()[0]}.obj", path)
        return read_cage(path)
    return read_cage(GARGOYLE / f"cage_{name}.obj")


def main():
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    print("| cage | control points | cells asked | tetrahedra | per control point | from 16,000 cells / diagonal "
          "| bind |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as folder:
        for name, counts in PLAN:
            cage, faces = cage_of(name, folder)
            poses = twisted_poses(cage)
            diagonal = np.linalg.norm(np.ptp(cage, axis=0))
            reference = lbc_core.bind(cage, faces, points, cells=REFERENCE_CELLS)
            moved = [reference.deform(pose) for pose in poses]
            n = len(reference.rest_cage_vertices)
            for cells in counts:
                binding = lbc_core.bind(cage, faces, points, cells=cells)
                distance = max(np.linalg.norm(binding.deform(pose) - ref, axis=1).max()
                               for pose, ref in zip(poses, moved)) / diagonal
                tetrahedra = len(binding.domain.cells)
                print(f"| {name} | {n} | {cells} | {tetrahedra} | {tetrahedra / n:.1f} | {distance:.2e} "
                      f"| {sum(binding.timings.values()):.1f} s |", flush=True)
            print(f"| {name} | {n} | {REFERENCE_CELLS} | {len(reference.domain.cells)} "
                  f"| {len(reference.domain.cells) / n:.1f} | (reference) | {sum(reference.timings.values()):.1f} s |",
                  flush=True)


if __name__ == "__main__":
    main()
