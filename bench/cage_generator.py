"""The cage generator against hand-made cages: time, vertices, volume ratio, distance, binding.

    OMP_NUM_THREADS=1 taskset -c 0 .venv/bin/python bench/cage_generator.py [FOLDER ...] [--bind] [--markdown]

Each FOLDER holds ``mesh.*`` and a hand-made ``cage.*`` (tests/data/cages-3d/*, the public pairs of /work/data/* when
present, gargoyle's Nested Cage L10 standing in for a hand-made one). The generator is asked for the hand-made
cage's vertex count at its defaults, in a process of its own per mesh (so that each is timed alone). Columns: mesh
vertices, the count asked, seconds, the generated cage's vertices, its volume over the hand-made cage's, the
clearance (least distance from a mesh vertex to the cage) and the mean distance from the cage's vertices to the mesh,
both in % of the mesh's bounding-box diagonal, for the generated and the hand-made cage, the mesh vertices outside
each cage (winding number below 1/2), attempts, and with --bind the mesh points outside the cage after lbc's bind at
its defaults (none is the goal). Quads and mirror symmetry are not made yet: the cages are all triangles.
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lbc_core.io import read_mesh  # noqa: E402

DATA = ROOT / "tests" / "data" / "cages-3d"
COLUMNS = ("mesh", "mesh V", "N", "s", "V", "vol ×", "clear %", "dist %", "hand clear %", "hand dist %",
           "out", "hand out", "tries", "bind out")


def files(folder):
    mesh = next(path for path in sorted(folder.glob("mesh.*")) if path.suffix in (".obj", ".off", ".ply"))
    cages = [path for path in sorted(folder.glob("cage*.*")) if path.suffix in (".obj", ".off", ".ply")]
    cage = next((path for path in cages if path.stem == "cage"), None) or folder / "cage_L10.obj"
    return mesh, cage


def triangles(faces):
    return np.array([[face[0], face[k], face[k + 1]] for face in faces for k in range(1, len(face) - 1)])


def measure(folder, bind):
    """The row of one folder (run in its own process)."""
    from lbc_core import bind as lbc_bind, generate_cage
    from lbc_core.cage_generator.check import distances
    from lbc_core.cage_generator.extraction import signed_volume
    from lbc_core.kernel.geometry import winding_numbers

    mesh_path, cage_path = files(folder)
    vertices, faces = read_mesh(mesh_path)
    hand, hand_faces = read_mesh(cage_path)
    hand_triangles = triangles(hand_faces)
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    started = time.process_time()
    made = generate_cage(vertices, faces, n_vertices=len(hand))
    seconds = time.process_time() - started
    hand_clear, hand_mean = distances(vertices, hand, hand_triangles, made.margin / 4)
    row = {"mesh": folder.name, "mesh V": len(vertices), "N": len(hand), "s": seconds, "V": made.vertex_count,
           "vol ×": made.volume / abs(signed_volume(hand, hand_triangles)),
           "clear %": 100 * made.clearance / diagonal, "dist %": 100 * made.mean_distance / diagonal,
           "hand clear %": 100 * hand_clear / diagonal, "hand dist %": 100 * hand_mean / diagonal,
           "out": int(np.count_nonzero(winding_numbers(made.vertices, made.faces, vertices) < 0.5)),
           "hand out": int(np.count_nonzero(winding_numbers(hand, hand_triangles, vertices) < 0.5)),
           "tries": made.attempts, "bind out": None}
    if bind:
        binding = lbc_bind(made.vertices, made.faces, vertices)
        row["bind out"] = int(np.count_nonzero(binding.outside))
    return row


def folders(given):
    if given:
        return [Path(folder) for folder in given]
    found = [DATA / name for name in ("arm", "gargoyle", "hand", "clothing")]
    public = Path("/work/data")
    return found + (sorted(path for path in public.iterdir() if path.is_dir()) if public.is_dir() else [])


def cell(value):
    if value is None:
        return "–"
    return f"{value:.2f}" if isinstance(value, float) else str(value)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="*")
    parser.add_argument("--bind", action="store_true", help="bind each mesh to its generated cage")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # a folder measured in this process, printed as JSON
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure(Path(args.one), args.bind)))
        return
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + " --- |" * len(COLUMNS))
    for folder in folders(args.folders):
        command = [sys.executable, __file__, "--one", str(folder)] + (["--bind"] if args.bind else [])
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode:
            print(f"| {folder.name} | failed: {done.stderr.strip().splitlines()[-1][:200]} |", flush=True)
            continue
        row = json.loads(done.stdout.strip().splitlines()[-1])
        print("| " + " | ".join(cell(row[column]) for column in COLUMNS) + " |", flush=True)


if __name__ == "__main__":
    main()
