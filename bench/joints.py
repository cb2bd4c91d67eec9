"""Joints against Mesh Deform: folds, kinks and influences per Smoothness, on posed characters, hands and capsules.

    PYTHONPATH=. .venv/bin/python bench/joints.py [--scenes capsule,arm,hand,smpl,cactus,beast,figure,tentacle]
                                                  [--smoothness 0,0.25,0.5,0.75,1] [--data DIR]
    PYTHONPATH=. .venv/bin/python bench/joints.py --plot OUTPUT.txt PICTURE.png    (the trade-off, from a run's output)

Each scene is bound once (``lbc_core.bind`` at its defaults: the solve does not depend on the smoothness), then
evaluated again at each smoothness as the bind evaluates (``lbc_core.binding.pipeline.evaluate``: the fit's radius
``lbc_core.evaluate.smoothing.radius_for``, through the domain) and thinned as the add-on thins (``lbc_core.evaluate.thinning.floor_for``):
what the add-on binds at that Smoothness, on the same domain mesh. Mesh Deform (precision 5, through bpy) deforms the
same mesh by the same posed cages. Per pose: kinks (the change of each edge's dihedral angle, bench/capsule.py) p99 /
max in degrees, edges folded by more than 30°, triangles turned over; per scene the influences per vertex after
thinning and the evaluation's seconds (the bind's reduction stage).

Scenes: ``capsule`` (bench/capsule.py, twisted and bent 90°); ``arm`` (SuperCages' arm and hand, its authors' three
poses); ``hand`` (tests/data/cages-3d/hand: each finger box's far ring turned 60° about its near ring's centre, toward
either side of the palm); ``figure``, ``tentacle`` (bench/figure.py); from ``--data`` (bench/RESULTS.md names the
sources and licences; not in the repository): ``smpl`` (the SMPL body in Neural Cages' hand-made 126-vertex cage,
posed by its authors' T-pose cage), ``cactus`` and ``beast`` (hanyanghyhyhy/cage-based-deformation's posed cages).
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lbc_core  # noqa: E402
from bench import capsule, figure  # noqa: E402
from bench.creases import Evaluation, deformed  # noqa: E402
from bench.public_data import public_data  # noqa: E402
from lbc_core.evaluate import thinning  # noqa: E402
from lbc_core.io import read_mesh  # noqa: E402
from lbc_core.binding.pipeline import REPRODUCTION_TOLERANCE  # noqa: E402
from lbc_core.evaluate.reduction import interpolate_and_reduce  # noqa: E402
from lbc_core.evaluate.smoothing import SmoothInterpolation, radius_for  # noqa: E402

DATA = ROOT / "tests" / "data" / "cages-3d"


def triangles(faces):
    """Polygons fanned into triangles, (F, 3) int array."""
    return np.array([[face[0], face[k], face[k + 1]] for face in faces for k in range(1, len(face) - 1)])


def capsule_scene():
    mesh, faces = capsule.capsule()
    cage, cage_faces = capsule.cage()
    return mesh, faces, cage, cage_faces, {"twist 90°": capsule.twist(cage), "bend 90°": capsule.bend(cage)}


def arm_scene():
    mesh, faces = read_mesh(DATA / "arm" / "mesh.obj")[:2]
    cage, cage_faces = read_mesh(DATA / "arm" / "cage.obj")[:2]
    poses = {name: np.asarray(read_mesh(DATA / "arm" / f"pose{k}.obj")[0])
             for k, name in enumerate(("elbow", "elbow + wrist", "fist"), start=1)}
    return np.asarray(mesh), triangles(faces), np.asarray(cage), cage_faces, poses


def bent_fingers(cage, degrees):
    """The hand cage (make_hand.py's numbering) with each finger box's far ring turned by ``degrees`` about the line
    through its near ring's centre, across the finger (the near ring's first edge)."""
    posed = np.array(cage, dtype=float)
    for finger in range(4):
        near, far = np.arange(8 + 4 * finger, 12 + 4 * finger), np.arange(24 + 4 * finger, 28 + 4 * finger)
        axis = posed[near[1]] - posed[near[0]]
        turn = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()
        centre = posed[near].mean(axis=0)
        posed[far] = (posed[far] - centre) @ turn.T + centre
    return posed


def hand_scene():
    mesh, faces = read_mesh(DATA / "hand" / "mesh.obj")[:2]
    cage, cage_faces = read_mesh(DATA / "hand" / "cage.obj")[:2]
    return (np.asarray(mesh), triangles(faces), np.asarray(cage), cage_faces,
            {"fingers 60°": bent_fingers(cage, 60.0), "fingers -60°": bent_fingers(cage, -60.0)})


def figure_scene():
    mesh, faces, cage, cage_faces, pose = figure.figure()
    return mesh, triangles(faces), cage, cage_faces, {name: pose(r) for name, r in figure.FIGURE_POSES.items()}


def tentacle_scene():
    mesh, faces, cage, cage_faces, pose = figure.tentacle()
    return mesh, triangles(faces), cage, cage_faces, {"curl 270°": pose(270.0), "curl 180° + twist 90°": pose(180.0, 90.0)}


def data_scene(folder, mesh_name, cage_name, poses):
    """A scene of --data: (mesh, triangles, cage, cage faces, {name: posed cage})."""
    def load():
        if ARGS.data is None:
            raise SystemExit(f"the scene of {folder} needs the public pairs: see bench/public-data.md, then set "
                             f"LBC_PUBLIC_DATA or pass --data")
        mesh, faces = read_mesh(ARGS.data / folder / mesh_name)[:2]
        cage, cage_faces = read_mesh(ARGS.data / folder / cage_name)[:2]
        posed = {name: np.asarray(read_mesh(ARGS.data / folder / file)[0]) for name, file in poses.items()}
        return np.asarray(mesh), triangles(faces), np.asarray(cage), cage_faces, posed
    return load


SCENES = {"capsule": capsule_scene, "arm": arm_scene, "hand": hand_scene, "figure": figure_scene,
          "tentacle": tentacle_scene,
          "smpl": data_scene("smpl_neuralcage", "mesh.ply", "cage.obj", {"to T-pose": "pose_tpose.ply"}),
          "cactus": data_scene("hanyang_cactus", "mesh.off", "cage.off", {"pose": "pose1.off"}),
          "beast": data_scene("hanyang_beast", "mesh.off", "cage.off", {"pose": "pose1.off"})}


def evaluated(evaluation, smoothness):
    """The binding's weights as a bind at ``smoothness`` evaluates them (pipeline.evaluate), and the seconds."""
    binding = evaluation.binding
    start = time.perf_counter()
    smooth = SmoothInterpolation(evaluation.vertices, evaluation.cells, evaluation.located,
                                 radius_edges=radius_for(smoothness), points=evaluation.points,
                                 outside=binding.outside)
    weights = interpolate_and_reduce(smooth, binding.domain_weights, evaluation.unit_cage.vertices,
                                     evaluation.vertices, binding.outcome.threshold,
                                     REPRODUCTION_TOLERANCE * evaluation.unit_cage.bbox_diagonal)
    return weights, time.perf_counter() - start


def figures(rest, posed, faces):
    found = capsule.kink_figures(rest, posed, faces)
    return f"{found['p99']:.2f} / {found['max']:.2f}, {found['folded']}, {found['flipped']}"


def bench_scene(name, smoothness_values):
    mesh, faces, cage, cage_faces, poses = SCENES[name]()
    start = time.perf_counter()
    binding = lbc_core.bind(cage, cage_faces, mesh)
    bound = time.perf_counter() - start
    evaluation = Evaluation(binding)
    print(f"\n{name}: {len(mesh)} vertices, {len(cage)}-vertex cage, {int(binding.outside.sum())} outside; bound in "
          f"{bound:.1f} s (reduction {binding.timings['reduction']:.1f} s); {os.getloadavg()[0]:.1f} load")
    print("| smoothness | influences | evaluation s | " + " | ".join(poses) + " |")
    print("| --- | --- | --- | " + " | ".join("---" for _ in poses) + " |")
    for smoothness in smoothness_values:
        weights, seconds = evaluated(evaluation, smoothness)
        rest = binding.rest_cage_vertices
        weights = thinning.thin_weights(weights, rest, weights @ rest, thinning.floor_for(smoothness))
        print(f"| {smoothness:g} | {np.diff(weights.indptr).mean():.1f} | {seconds:.1f} | "
              + " | ".join(figures(mesh, deformed(binding, weights, pose), faces) for pose in poses.values())
              + " |", flush=True)
    moved = {pose_name: capsule.mesh_deform(mesh, faces, cage, cage_faces, pose, precision=5)
             for pose_name, pose in poses.items()}
    print(f"| Mesh Deform 5 | | {np.mean([seconds for seconds, _ in moved.values()]):.1f} (bind) | "
          + " | ".join(figures(mesh, posed, faces) for _, posed in moved.values()) + " |", flush=True)


# What the picture shows of each pose: the larger kink for poses that fold nothing, else the folded edges.
PLOTTED = {"twist 90°": "max", "elbow": "max", "elbow + wrist": "max", "fist": "folded", "fingers 60°": "folded",
           "fingers -60°": "folded", "to T-pose": "folded", "pose": "folded"}


def parsed(text):
    """{scene: (smoothness values, influences, {pose: [(max, folded) per row]}, Mesh Deform's {pose: (max, folded)})}
    from this script's output."""
    found, scene, poses = {}, None, []
    for line in text.splitlines():
        if line and not line.startswith("|") and ":" in line:
            scene = line.split(":")[0]
        elif line.startswith("| smoothness"):
            poses = [cell.strip() for cell in line.strip("|").split("|")[3:]]
            found[scene] = ([], [], {pose: [] for pose in poses}, {})
        elif line.startswith("| ") and not line.startswith("| ---") and scene in found:
            cells = [cell.strip() for cell in line.strip("|").split("|")]
            figures = [(float(cell.split(",")[0].split("/")[1]), int(cell.split(",")[1])) for cell in cells[3:]]
            values, influences, rows, theirs = found[scene]
            if cells[0].startswith("Mesh Deform"):
                theirs.update(zip(poses, figures))
            else:
                values.append(float(cells[0]))
                influences.append(float(cells[1]))
                for pose, figure_ in zip(poses, figures):
                    rows[pose].append(figure_)
    return found


def plot(output, picture):
    """The trade-off as a picture: each pose's fold (or largest kink) over Mesh Deform's, and the influences per
    vertex over Smoothness 0's, against the smoothness."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    found = parsed(Path(output).read_text())
    figure_, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for scene, (values, influences, rows, theirs) in found.items():
        for pose, kind in ((pose, PLOTTED.get(pose)) for pose in rows):
            if kind is None or not theirs.get(pose) or not theirs[pose][kind == "folded"]:
                continue
            ratio = [row[kind == "folded"] / theirs[pose][kind == "folded"] for row in rows[pose]]
            left.plot(values, ratio, marker="o", label=f"{scene}, {pose} ({'folded edges' if kind == 'folded' else 'largest kink'})")
        right.plot(values, np.array(influences) / influences[0], marker="o", label=scene)
    left.axhline(1.0, color="black", linewidth=1)
    left.text(0.0, 1.02, "Mesh Deform, precision 5", fontsize=8)
    left.set(xlabel="Smoothness", ylabel="LBC / Mesh Deform", yscale="log", title="Folds and kinks at the joints")
    left.legend(fontsize=6.5)
    right.axhline(1.5, color="grey", linestyle="--", linewidth=1)
    right.set(xlabel="Smoothness", ylabel="influences per vertex / at 0", title="Influences per vertex")
    right.legend(fontsize=7)
    for axis in (left, right):
        axis.axvline(0.5, color="grey", linewidth=0.8)
    figure_.tight_layout()
    figure_.savefig(picture, dpi=110)
    print(f"wrote {picture}")


def main(argv=None):
    global ARGS
    if argv is None and len(sys.argv) == 4 and sys.argv[1] == "--plot":
        plot(sys.argv[2], sys.argv[3])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="capsule,arm,hand,smpl,cactus,beast,figure,tentacle")
    parser.add_argument("--smoothness", default="0,0.25,0.5,0.75,1")
    parser.add_argument("--data", type=Path, default=public_data(),
                        help="the public pairs of bench/public-data.md (default: $LBC_PUBLIC_DATA)")
    ARGS = parser.parse_args(argv)
    for name in ARGS.scenes.split(","):
        bench_scene(name, [float(value) for value in ARGS.smoothness.split(",")])


ARGS = None

if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # the bpy module can deadlock in a static destructor at exit; everything is written
