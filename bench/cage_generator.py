"""The cage generator against hand-made cages: time, vertices, volume ratio, distance, quads, symmetry, binding, folds.

    OMP_NUM_THREADS=1 taskset -c 0 .venv/bin/python bench/cage_generator.py [FOLDER ...] [--bind] [--auto]
        [--symmetry] [--folds] [--big MESH]

Each FOLDER holds ``mesh.*`` and a hand-made ``cage.*`` (tests/data/cages-3d/*, and the public pairs of bench/public-data.md
when LBC_PUBLIC_DATA names them, gargoyle's Nested Cage L10 standing in for a hand-made one). Each row runs in a process of its own, timed
in CPU seconds. Columns: mesh vertices, the count asked (the hand-made cage's; with --auto none, the generator
chooses), seconds, the cage's vertices, its volume over the hand-made cage's, the clearance (least distance from a
mesh vertex to the cage) and the mean distance from the cage's vertices to the mesh in % of the mesh's bounding-box
diagonal (the generated cage's, then the hand-made one's), the share of quads among its faces (then the hand-made
cage's), attempts, and with --bind the mesh points outside the cage after lbc's bind at its defaults (none is the
goal). --symmetry: the meshes symmetric within 2 % (symmetry.asymmetry) about an axis, made with symmetry about it;
"mirror %" is the generated cage's mirror error and the hand-made cage's (the largest distance from a vertex's
mirror image to the nearest vertex, % of the diagonal). --folds: the arm bent at the elbow through its hand-made and
its generated cage (the same rigid turn of each cage's vertices beyond the elbow, fitted to the authors' first
pose), the mesh's edges folded by more than 30° (bench/capsule.py's kink_figures). --big MESH: the mesh alone at
N = 100 and 500 (the 64k-vertex gargoyle: bench/rebinding.py's gargoyle_64k).
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

from bench.public_data import public_data  # noqa: E402
from lbc_core.io import read_mesh  # noqa: E402

DATA = ROOT / "tests" / "data" / "cages-3d"
COLUMNS = ("mesh", "mesh V", "N", "sym", "s", "V", "vol ×", "clear %", "dist %", "hand clear %", "hand dist %",
           "quads %", "hand quads %", "mirror %", "hand mirror %", "tries", "bind out")


def files(folder):
    mesh = next(path for path in sorted(folder.glob("mesh.*")) if path.suffix in (".obj", ".off", ".ply"))
    cages = [path for path in sorted(folder.glob("cage*.*")) if path.suffix in (".obj", ".off", ".ply")]
    cage = next((path for path in cages if path.stem == "cage"), None) or folder / "cage_L10.obj"
    return mesh, cage


def triangles(faces):
    return np.array([[face[0], face[k], face[k + 1]] for face in faces for k in range(1, len(face) - 1)])


def symmetric_axis(vertices, faces):
    """The axis ("x", "y", "z") the mesh is most symmetric about, when within the generator's tolerance, else None."""
    from lbc_core.cage_generator.mesh_input import input_mesh
    from lbc_core.cage_generator.symmetry import SYMMETRY_TOLERANCE, asymmetry, mirror_frame

    mesh = input_mesh(vertices, faces)
    off = [asymmetry(mesh, mirror_frame(mesh, axis)) for axis in range(3)]
    best = int(np.argmin(off))
    return "xyz"[best] if off[best] <= SYMMETRY_TOLERANCE else None


def measure(folder, bind, auto, symmetry):
    """The row of one folder (run in its own process)."""
    from lbc_core import bind as lbc_bind, generate_cage
    from lbc_core.cage_generator.check import CageSamples, distances
    from lbc_core.cage_generator.extraction import signed_volume
    from lbc_core.cage_generator.symmetry import AXES, mirror_error

    mesh_path, cage_path = files(folder)
    vertices, faces = read_mesh(mesh_path)
    hand, hand_faces = read_mesh(cage_path)
    hand_triangles = triangles(hand_faces)
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    axis = symmetric_axis(vertices, faces) if symmetry else None
    if symmetry and axis is None:
        return None
    started = time.process_time()
    made = generate_cage(vertices, faces, n_vertices=None if auto else len(hand), symmetry=axis)
    seconds = time.process_time() - started
    samples = CageSamples(hand, hand_triangles, made.margin / 4)
    hand_clear, hand_mean = distances(vertices, hand, hand_triangles, samples.lower(vertices)[1], made.margin / 4)
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    row = {"mesh": folder.name, "mesh V": len(vertices), "N": "auto" if auto else len(hand), "sym": axis or "–",
           "s": seconds, "V": made.vertex_count, "vol ×": made.volume / abs(signed_volume(hand, hand_triangles)),
           "clear %": 100 * made.clearance / diagonal, "dist %": 100 * made.mean_distance / diagonal,
           "hand clear %": 100 * hand_clear / diagonal, "hand dist %": 100 * hand_mean / diagonal,
           "quads %": 100 * made.quad_share,
           "hand quads %": 100 * sum(len(face) == 4 for face in hand_faces) / len(hand_faces),
           "mirror %": None if axis is None else 100 * made.mirror_error / diagonal,
           "hand mirror %": None if axis is None else
           100 * mirror_error(hand, AXES[axis], centre[AXES[axis]]) / diagonal,
           "tries": made.attempts, "bind out": None}
    if bind:
        binding = lbc_bind(made.vertices, [list(face) for face in made.faces], vertices)
        row["bind out"] = int(np.count_nonzero(binding.outside))
    return row


def measure_big(path):
    """Rows of one big mesh at N = 100 and 500 (each in this process, one after the other)."""
    from lbc_core import generate_cage

    vertices, faces = read_mesh(path)
    rows = []
    for count in (100, 500):
        started = time.process_time()
        made = generate_cage(vertices, faces, n_vertices=count)
        rows.append({"mesh": Path(path).name, "mesh V": len(vertices), "N": count, "s": time.process_time() - started,
                     "V": made.vertex_count, "quads %": 100 * made.quad_share, "tries": made.attempts})
    return rows


def elbow_pose(rest, posed):
    """(rotation, translation, moved): the rigid motion (Kabsch) of the hand-made cage's vertices the authors' pose
    moves by more than 10 % of the cage's diagonal, and which moved."""
    moved = np.linalg.norm(posed - rest, axis=1) > 0.1 * np.linalg.norm(np.ptp(rest, axis=0))
    a, b = rest[moved], posed[moved]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rotation, cb - ca @ rotation.T, moved


def bend(cage, hand_rest, moved, rotation, translation):
    """The cage with its vertices nearest a moved hand-made cage vertex turned by the rigid motion."""
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(hand_rest).query(cage)
    posed = np.array(cage, dtype=float)
    posed[moved[nearest]] = cage[moved[nearest]] @ rotation.T + translation
    return posed


def measure_folds():
    """Folded edges of the arm bent through its hand-made and its generated cage (run in its own process)."""
    sys.path.insert(0, str(ROOT / "bench"))
    import capsule

    from lbc_core import bind as lbc_bind, generate_cage

    mesh, faces = read_mesh(DATA / "arm" / "mesh.obj")
    mesh_triangles = triangles(faces)
    hand, hand_faces = read_mesh(DATA / "arm" / "cage.obj")
    authors = read_mesh(DATA / "arm" / "pose1.obj")[0]
    rotation, translation, moved = elbow_pose(hand, authors)
    made = generate_cage(mesh, faces, n_vertices=len(hand))
    rows = []
    for name, cage, cage_faces, pose in (
            ("hand-made, the authors' pose", hand, hand_faces, authors),
            ("hand-made, rigid elbow turn", hand, hand_faces, bend(hand, hand, moved, rotation, translation)),
            ("generated, rigid elbow turn", made.vertices, [list(face) for face in made.faces],
             bend(made.vertices, hand, moved, rotation, translation))):
        binding = lbc_bind(cage, cage_faces, mesh)
        found = capsule.kink_figures(mesh, binding.deform(pose), mesh_triangles)
        rows.append({"cage": name, "folded": found["folded"], "p99 °": found["p99"], "max °": found["max"],
                     "flipped": found["flipped"], "outside": int(np.count_nonzero(binding.outside))})
    return rows


def folders(given):
    if given:
        return [Path(folder) for folder in given]
    found = [DATA / name for name in ("arm", "gargoyle", "hand", "clothing")]
    public = public_data()
    if public is None:
        return found
    # Only the folders that hold a pair (a folder of other data, e.g. arrays, is not one).
    return found + sorted(path for path in public.iterdir() if any(path.glob("mesh.*")) and any(path.glob("cage.*")))


def cell(value):
    if value is None:
        return "–"
    return f"{value:.2f}" if isinstance(value, float) else str(value)


def table(rows, columns):
    print("| " + " | ".join(columns) + " |")
    print("|" + " --- |" * len(columns))
    for row in rows:
        print("| " + " | ".join(cell(row.get(column)) for column in columns) + " |", flush=True)


def run_one(arguments):
    done = subprocess.run([sys.executable, __file__] + arguments, capture_output=True, text=True)
    if done.returncode:
        return {"error": (done.stderr.strip().splitlines() or ["?"])[-1][:200]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="*")
    parser.add_argument("--bind", action="store_true", help="bind each mesh to its generated cage")
    parser.add_argument("--auto", action="store_true", help="the vertex count chosen by the generator")
    parser.add_argument("--symmetry", action="store_true", help="symmetric meshes, symmetric cages")
    parser.add_argument("--folds", action="store_true", help="the arm bent through both cages")
    parser.add_argument("--big", help="a big mesh at N = 100 and 500")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # one measurement in this process, printed as JSON
    args = parser.parse_args()
    if args.one:
        kind, _, target = args.one.partition(":")
        result = {"folds": measure_folds, "big": lambda: measure_big(target)}.get(
            kind, lambda: measure(Path(target), args.bind, args.auto, args.symmetry))()
        print(json.dumps(result))
        return
    if args.folds:
        table(run_one(["--one", "folds:"]), ("cage", "folded", "p99 °", "max °", "flipped", "outside"))
        return
    if args.big:
        table(run_one(["--one", f"big:{args.big}"]), ("mesh", "mesh V", "N", "s", "V", "quads %", "tries"))
        return
    flags = [flag for flag, on in (("--bind", args.bind), ("--auto", args.auto), ("--symmetry", args.symmetry)) if on]
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + " --- |" * len(COLUMNS))
    for folder in folders(args.folders):
        row = run_one(["--one", f"row:{folder}"] + flags)
        if row is None:
            continue
        if "error" in row:
            print(f"| {folder.name} | failed: {row['error']} |", flush=True)
            continue
        print("| " + " | ".join(cell(row[column]) for column in COLUMNS) + " |", flush=True)


if __name__ == "__main__":
    main()
