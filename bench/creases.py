"""Creases on posed characters and capsules: LBC at its defaults against Mesh Deform precision 5, and each lever.

    .venv/bin/python bench/creases.py [--scenes capsule,arm,figure,tentacle] [--levers] [--binds cells:epsilon,...]
                                      [--evaluations radius:fade:floor:outside[:deep],...]

Scenes (each a mesh, its cage and posed cages):

capsule   bench/capsule.py's capsule (12,002 vertices, 74-vertex cage) in each of its POSES: bent 90°, twisted 90°,
          bent 45° and twisted 45°, stretched 1.5 and tapered.
arm       SuperCages' arm and hand (tests/data/cages-3d/arm: 2089 vertices, a 58-vertex cage with a box per finger)
          in three of its authors' poses: bent elbow, bent elbow and turned wrist, closed fist.
figure    bench/figure.py's figure (25,416 vertices, a 244-vertex box-modelled cage, limbs one or two quads across,
          fingertips and toe tips poking out: 353 vertices outside) walking and crouching.
tentacle  bench/figure.py's tentacle (4250 vertices, a 50-vertex tapered cage, its tip poking out: 49 outside)
          curled 270°, and curled 180° with a 90° twist.

Per pose: kinks (the change of each mesh edge's dihedral angle, bench/capsule.py) p99 / max in degrees, edges
folded by more than 30°, triangles turned over against their neighbours. LBC "defaults" is what the add-on binds:
``lbc_core.bind`` at its defaults, then ``thin_weights`` at the add-on's default floor.

The default run prints, per scene, LBC's defaults (the rows of the points outside the cage extrapolated to them:
lbc_core.evaluate.smoothing's ``points`` and ``outside``), the same with those points following their closest point inside
(as before the pipeline passed them) and Mesh Deform (precision 5, through bpy) in the same process, with their bind seconds (``--baseline REV``: also LBC's defaults with
the evaluation, reduction and thinning of git revision REV). ``--levers`` prints, per scene, one bind per ``--binds`` setting (cells, 0 for the default,
and the relaxation ε) and, on each, the evaluation per ``--evaluations`` setting: the fit's radius and fade (median
edges), the thinning's floor (0: every weight) and the
treatment of the points outside the cage ("near": each follows its closest point; "tilt": the closest point's
coordinates plus the offset times their gradient, which reproduces the point: lbc_core.evaluate.smoothing's ``points`` and
``outside``), and optionally the fit's radius where the cage is thick (``deep``, median edges: the lever of
bench/RESULTS.md, "A wider fit where the cage is thick"); with each the evaluation's and thinning's seconds.
"""

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lbc_core  # noqa: E402
from bench import capsule, figure  # noqa: E402
from lbc_core.evaluate import thinning  # noqa: E402
from lbc_core.kernel.frame import UnitFrame  # noqa: E402
from lbc_core.evaluate.interpolation import interpolation_matrix  # noqa: E402
from lbc_core.io import read_mesh  # noqa: E402
from lbc_core.binding.pipeline import REPRODUCTION_TOLERANCE  # noqa: E402
from lbc_core.evaluate.reduction import interpolate_and_reduce  # noqa: E402
from lbc_core.evaluate.smoothing import FADE_EDGES, RADIUS_EDGES, SmoothInterpolation  # noqa: E402
from lbc_core.evaluate.thinning import DEFAULT_FLOOR  # noqa: E402

ARM = ROOT / "tests" / "data" / "cages-3d" / "arm"


def load():
    return f"load {os.getloadavg()[0]:.1f}"


def capsule_scene():
    mesh, faces = capsule.capsule()
    cage, cage_faces = capsule.cage()
    return mesh, faces, cage, cage_faces, {name: pose(cage) for name, pose in capsule.POSES.items()}


def arm_scene():
    mesh, faces = read_mesh(ARM / "mesh.obj")
    cage, cage_faces = read_mesh(ARM / "cage.obj")
    poses = {name: np.asarray(read_mesh(ARM / f"pose{k}.obj")[0])
             for k, name in enumerate(("elbow", "elbow + wrist", "fist"), start=1)}
    return np.asarray(mesh), np.asarray(faces), np.asarray(cage), cage_faces, poses


def figure_scene():
    mesh, faces, cage, cage_faces, pose = figure.figure()
    return mesh, faces, cage, cage_faces, {name: pose(rotations) for name, rotations in figure.FIGURE_POSES.items()}


def tentacle_scene():
    mesh, faces, cage, cage_faces, pose = figure.tentacle()
    return mesh, faces, cage, cage_faces, {"curl 270°": pose(270.0), "curl 180° + twist 90°": pose(180.0, 90.0)}


SCENES = {"capsule": capsule_scene, "arm": arm_scene, "figure": figure_scene, "tentacle": tentacle_scene}


def figures_text(rest, posed, faces):
    found = capsule.kink_figures(rest, posed, faces)
    return f"{found['p99']:.2f} / {found['max']:.2f}, {found['folded']}, {found['flipped']}"


def deformed(binding, weights, pose):
    return binding.points + weights @ (binding.cage.control_points_from_input(pose) - binding.rest_cage_vertices)


class Evaluation:
    """A binding's solve evaluated again at its points, in the unit frame, as the pipeline's evaluation does."""

    def __init__(self, binding):
        self.binding = binding
        frame = UnitFrame.of(binding.cage)
        self.unit_cage = frame.cage_to_unit(binding.cage)
        self.vertices, self.cells = frame.to_unit(binding.domain.vertices), binding.domain.cells
        self.points = frame.to_unit(binding.points)
        self.located, _, _ = interpolation_matrix(self.vertices, self.cells, self.points)

    def weights(self, radius=RADIUS_EDGES, fade=FADE_EDGES, outside="near", deep=None):
        """The evaluation at the points; ``outside`` "tilt": the outside points' rows extrapolate to them
        (SmoothInterpolation's ``points`` and ``outside``), "near": they reproduce their closest domain point."""
        binding = self.binding
        extra = dict(points=self.points, outside=binding.outside) if outside == "tilt" else {}
        smooth = SmoothInterpolation(self.vertices, self.cells, self.located, radius_edges=radius, fade_edges=fade,
                                     deep_radius_edges=radius if deep is None else deep,
                                     **extra)
        return interpolate_and_reduce(smooth, binding.domain_weights, self.unit_cage.vertices, self.vertices,
                                      binding.outcome.threshold,
                                      REPRODUCTION_TOLERANCE * self.unit_cage.bbox_diagonal)


def thinned(binding, weights, floor=DEFAULT_FLOOR):
    """The add-on's thinning (lbc_core.evaluate.thinning.thin_weights, no cap) at ``floor``; 0 keeps every weight."""
    rest = binding.rest_cage_vertices
    return thinning.thin_weights(weights, rest, weights @ rest, floor) if floor else sp.csr_matrix(weights)


def bench_defaults(names, baseline=None):
    """LBC's defaults (and ``baseline``'s, and with the outside points following their closest point) against Mesh
    Deform, per pose."""
    columns = ([f"LBC defaults at {baseline}"] if baseline else []) + [
        "LBC defaults", "LBC, outside points following their closest point", "Mesh Deform precision 5"]
    print(f"Kinks p99 / max (degrees), edges folded > 30°, triangles turned over; {load()}")
    print("| scene | pose | " + " | ".join(columns) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in columns) + " |")
    for name in names:
        mesh, faces, cage, cage_faces, poses = SCENES[name]()
        found, seconds, influences = [], [], []
        if baseline:
            with baseline_code(baseline):
                binding, weights, spent = default_bind(mesh, cage, cage_faces)
            found.append(weights)
            seconds.append(spent)
        binding, weights, spent = default_bind(mesh, cage, cage_faces)
        found.append(weights)
        seconds.append(spent)
        start = time.perf_counter()
        found.append(thinned(binding, Evaluation(binding).weights(outside="near")))
        seconds.append(spent - binding.timings["reduction"] + time.perf_counter() - start)
        influences = [np.diff(weights.indptr) for weights in found]
        rows = []
        for pose_name, pose in poses.items():
            md_seconds, moved = capsule.mesh_deform(mesh, faces, cage, cage_faces, pose, precision=5)
            rows.append(f"| {name} | {pose_name} | "
                        + " | ".join(figures_text(mesh, deformed(binding, weights, pose), faces) for weights in found)
                        + f" | {figures_text(mesh, moved, faces)} |")
        print("\n".join(rows))
        print(f"| {name} | bind s, influences mean / max | "
              + " | ".join(f"{spent:.2f}, {counts.mean():.1f} / {counts.max()}"
                           for spent, counts in zip(seconds, influences))
              + f" | {md_seconds:.2f} |", flush=True)
    print(f"({load()})")


def default_bind(mesh, cage, cage_faces):
    """lbc_core.bind at its defaults and the add-on's thinning: the binding, its thinned weights, the seconds."""
    start = time.perf_counter()
    binding = lbc_core.bind(cage, cage_faces, mesh)
    weights = thinned(binding, binding.weights)
    return binding, weights, time.perf_counter() - start


@contextlib.contextmanager
def baseline_code(revision):
    """The bind's evaluation, reduction and thinning from ``revision`` (bench/smoothness.py's baseline_modules)."""
    import lbc_core.binding.pipeline as pipeline

    from bench.smoothness import baseline_modules, pipeline_smoothing

    old = baseline_modules(revision)
    saved = pipeline.SmoothInterpolation, pipeline.interpolate_and_reduce, thinning.thin_weights
    pipeline.SmoothInterpolation = pipeline_smoothing(old["smoothing"])
    pipeline.interpolate_and_reduce = old["reduction"].interpolate_and_reduce
    thinning.thin_weights = old["thinning"].thin_weights
    try:
        yield
    finally:
        pipeline.SmoothInterpolation, pipeline.interpolate_and_reduce, thinning.thin_weights = saved


def bench_levers(names, binds, evaluations):
    print(f"Levers; kinks p99 / max, folded > 30°, turned over, per pose; {load()}")
    for name in names:
        mesh, faces, cage, cage_faces, poses = SCENES[name]()
        print(f"\n{name}: {len(mesh)} vertices, cage {len(cage)} vertices; poses: {', '.join(poses)}")
        print("| bind (cells, ε) | bind s | evaluation (radius, fade, floor, outside) | evaluation + thinning s "
              "| influences | " + " | ".join(poses) + " |")
        print("| --- | --- | --- | --- | --- | " + " | ".join("---" for _ in poses) + " |")
        for cells, epsilon in binds:
            start = time.perf_counter()
            binding = lbc_core.bind(cage, cage_faces, mesh, cells=cells or None, epsilon=epsilon)
            seconds = time.perf_counter() - start
            evaluation = Evaluation(binding)
            for radius, fade, floor, outside, deep in evaluations:
                start = time.perf_counter()
                weights = thinned(binding, evaluation.weights(radius, fade, outside, deep), floor)
                evaluated = time.perf_counter() - start
                counts = np.diff(weights.indptr)
                print(f"| {len(binding.domain.cells)} tets, ε {epsilon:g} | {seconds:.2f} | {radius:g}, {fade:g}, "
                      f"{floor:g}, {outside}{'' if deep is None else f', deep {deep:g}'} | {evaluated:.2f} | "
                      f"{counts.mean():.1f} / {counts.max()} | "
                      + " | ".join(figures_text(mesh, deformed(binding, weights, pose), faces)
                                   for pose in poses.values()) + " |", flush=True)
    print(f"({load()})")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="capsule,arm,figure,tentacle")
    parser.add_argument("--levers", action="store_true")
    parser.add_argument("--baseline", help="the default run: also LBC's defaults with the evaluation, reduction and "
                        "thinning of this git revision")
    parser.add_argument("--binds", default="0:0,16000:0,32000:0,0:0.01",
                        help="--levers: cells:epsilon per bind (cells 0: the default)")
    parser.add_argument("--evaluations", default=f"{RADIUS_EDGES:g}:{FADE_EDGES:g}:{DEFAULT_FLOOR:g}:near",
                        help="--levers: radius:fade:floor:outside per evaluation of each bind")
    args = parser.parse_args(argv)
    names = args.scenes.split(",")
    if args.levers:
        binds = [(int(cells), float(epsilon)) for cells, epsilon in (value.split(":") for value in args.binds.split(","))]
        evaluations = [(float(radius), float(fade), float(floor), outside, float(deep[0]) if deep else None)
                       for radius, fade, floor, outside, *deep
                       in (value.split(":") for value in args.evaluations.split(","))]
        bench_levers(names, binds, evaluations)
    else:
        bench_defaults(names, args.baseline)


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # the bpy 4.5.4 module can deadlock in a static destructor at exit; everything is written
