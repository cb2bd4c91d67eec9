"""Warm re-bind against a cold bind of the same edited cage, side by side in one process.

    .venv/bin/python bench/rebinding.py [--skip-64k] [--addon [--cage L10] [--vertex V ...] [--face F ...]]
    .venv/bin/python bench/rebinding.py --rings [--cage L10]
    .venv/bin/python bench/rebinding.py --quads

For each scene: bind the gargoyle to its cage, move 1, 3 or 5 cage vertices (seeded random directions) by 1-10 % of
the cage's diagonal, then bind the edited cage cold (lbc_core.bind) and warm (lbc_core.rebind from the first
binding). Printed per edit: both times and iterations, the objectives (and, on the warm re-bind's own carried mesh, a
cold solve's: the same problem, so any difference is the solver's tolerance), the largest weight difference at the
points, and the largest difference of the points deformed by one pose, over the cage's diagonal. "mesh noise" is the
same comparison between two cold binds at 8000 and 9000 cells: what remeshing alone changes.

--quads  the corpus's quad cages as Blender makes them (tests/helpers/cage_corpus.py: a subdivided cube, limbs, a
         torus, an 8-sided prism of 5 rings, Blender's 8- and 16-sided cylinders) and Blender's Cylinder with two loop cuts,
         3000 points spread inside each, the same table
         (edits 1 × 1 %, 1 × 2 %, 3 × 1 %, 1 × 5 %): any edit bends the quads at the moved vertices.
--rings  the rings of vertices solved again around the moved coordinates' supports (2, 1 and 0) on the gargoyle
         mesh (2674 points) in the cage ``--cage`` names, or on one of the paper's 2D cages (``--cage woody``,
         ``cactus``, ``Gil_Gecko``): each warm re-bind against a tight solve on its mesh.
--addon  only the demo gargoyle (64k points), through the add-on's bind (lbc_addon.jobs.solve: lbc_core, thinning,
         slots; no bpy): a cold bind of the edited cage against the warm re-bind, which thins again only the rows the
         re-bind changed, and the same warm re-bind thinning every row (the path before); CPU seconds of every
         thread (wall seconds in brackets), the best of two interleaved runs; the warm re-bind's stages in wall
         seconds. ``--cage`` names the gargoyle cage (L08 to L16; default L10, the demo's); ``--vertex V`` adds an
         edit moving cage vertex V outward from the centroid by 2 % (37, L10's top, grows the cage's extent);
         ``--face F`` one pulling the vertices of cage face F out along its normal by 2 % (a few neighbouring
         vertices moved together, as an artist edits a region).
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lbc_core  # noqa: E402
from lbc_core.solve.boundary import boundary_weights  # noqa: E402
from lbc_core.kernel.frame import UnitFrame  # noqa: E402
from lbc_core.io import read_cage, read_mesh  # noqa: E402
from lbc_core.binding import rebinding  # noqa: E402
from lbc_core.binding.carry import carry_domain, split_as_before  # noqa: E402
from lbc_core.binding.rebinding import rebind  # noqa: E402
from lbc_core.solve.geodesics import geodesic_distances, tv_weights  # noqa: E402
from lbc_core.solve.solver import solve_on_mesh  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
EDITS = [(1, 0.01), (1, 0.02), (3, 0.01), (5, 0.01), (1, 0.05), (3, 0.10)]
ROUNDS = 2  # --addon: each bind repeated, interleaved, the best CPU time kept


def edited(cage, faces, count, share, seed=1):
    """``cage`` with ``count`` vertices moved by ``share`` of its diagonal in random directions (a direction that
    makes the cage invalid is drawn again)."""
    rng = np.random.default_rng(seed)
    moved = cage.copy()
    for vertex in rng.choice(len(cage), count, replace=False):
        for _ in range(20):
            trial = pushed(moved, [vertex], rng.normal(size=cage.shape[1]), share)
            try:
                lbc_core.make_cage(trial, faces)
            except lbc_core.CageError:
                continue
            moved = trial
            break
    return moved


def pushed(cage, vertices, direction, share):
    """A copy of ``cage`` with ``vertices`` moved along ``direction`` (any length) by ``share`` of its diagonal."""
    moved = cage.copy()
    moved[vertices] += share * np.linalg.norm(np.ptp(cage, axis=0)) * direction / np.linalg.norm(direction)
    return moved


def outward(cage, vertex, share):
    """``cage`` with ``vertex`` moved away from the cage's centroid by ``share`` of its diagonal (an artist's edit of
    one vertex; an extreme vertex moved so changes the cage's extent)."""
    return pushed(cage, [vertex], cage[vertex] - cage.mean(axis=0), share)


def face_pulled(cage, faces, face, share):
    """``cage`` with the vertices of ``face`` moved together along its normal (outward for a cage whose faces turn
    counter-clockwise seen from outside) by ``share`` of its diagonal: an artist pulling out one face."""
    corners = cage[faces[face]]
    return pushed(cage, faces[face], np.cross(corners[1] - corners[0], corners[2] - corners[0]), share)


def pose(cage):
    """A smooth pose of the cage: a twist about its vertical axis growing with height, 40° at the top."""
    low, high = cage.min(axis=0), cage.max(axis=0)
    centre = (low + high) / 2
    angle = np.radians(40) * (cage[:, 2] - low[2]) / (high[2] - low[2])
    x, y = cage[:, 0] - centre[0], cage[:, 1] - centre[1]
    posed = cage.copy()
    posed[:, 0] = centre[0] + np.cos(angle) * x - np.sin(angle) * y
    posed[:, 1] = centre[1] + np.sin(angle) * x + np.cos(angle) * y
    return posed


def differences(a, b, cage):
    """Largest weight difference at the points, and of the points deformed by :func:`pose`, over the diagonal."""
    diagonal = np.linalg.norm(np.ptp(cage, axis=0))
    weights = abs(a.weights - b.weights).max()
    posed = pose(cage)
    return weights, np.linalg.norm(a.deform(posed) - b.deform(posed), axis=1).max() / diagonal


def on_carried_mesh(previous, edited_cage, faces, tolerance=None):
    """A cold solve (SolveResult, unit frame) on the mesh the warm re-bind carries, at ``tolerance`` (None: the
    default); None where the carried mesh is not valid."""
    cage, why_not = split_as_before(previous.cage, lbc_core.make_cage(edited_cage, faces))
    if why_not is not None:
        return None
    unit_cage = UnitFrame.of(cage).cage_to_unit(cage)
    mesh, _ = carry_domain(previous, unit_cage)
    if mesh is None:
        return None
    weights = tv_weights(mesh.cells, geodesic_distances(mesh.vertices, mesh.cells, mesh.control_vertices),
                         previous.options.weighting)
    return solve_on_mesh(mesh.vertices, mesh.cells, mesh.boundary_vertices, boundary_weights(mesh, unit_cage),
                         unit_cage.vertices, weights, max_iterations=20000,
                         **({} if tolerance is None else {"tolerance": tolerance}))


def same_mesh_objective(previous, edited_cage, faces):
    """A cold solve's objective on the mesh the warm re-bind carries (in the cage's units)."""
    result = on_carried_mesh(previous, edited_cage, faces)
    if result is None:
        return float("nan"), 0
    cage = lbc_core.make_cage(edited_cage, faces)
    return result.objective * UnitFrame.of(cage).scale ** (cage.dim - 1), result.iterations


def timed(function, *args, **keywords):
    start = time.perf_counter()
    result = function(*args, **keywords)
    return result, time.perf_counter() - start


def scene(name, cage, faces, points, edits):
    first, seconds = timed(lbc_core.bind, cage, faces, points)
    print(f"\n{name}: {len(points)} points, {first.cage.n_control_points} control points, {len(first.domain.cells)} "
          f"tets; first bind {seconds:.2f} s ({first.iterations} iterations); solver state kept "
          f"{first.solver_state.nbytes / 2**20:.1f} MB; load average {os.getloadavg()[0]:.1f}")
    print("| edit | cold s | warm s | speed-up | iterations cold / warm (what was done again) | objective cold / warm / "
          "cold on the warm mesh | max weight difference | max deformation difference / diagonal | warm stages (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for count, share in edits:
        target = edited(cage, faces, count, share)
        cold, cold_seconds = timed(lbc_core.bind, target, faces, points)
        warm, warm_seconds = timed(rebind, first, target, faces)
        same, _ = same_mesh_objective(first, target, faces)
        weights, deformation = differences(warm, cold, target)
        start, note = warm.outcome.start, warm.outcome.report
        stages = ", ".join(f"{k} {v:.2f}" for k, v in warm.timings.items())
        label = f"{count} × {share:.0%}"
        if start != "previous solution":
            print(f"| {label} | {cold_seconds:.2f} | {warm_seconds:.2f} | — ({note}) | | | | | |")
            continue
        print(f"| {label} | {cold_seconds:.2f} | {warm_seconds:.2f} | {cold_seconds / warm_seconds:.1f}× | "
              f"{cold.iterations} / {warm.iterations} ({note.split(': ')[1]}) | "
              f"{cold.objective:.6g} / {warm.objective:.6g} / {same:.6g} | {weights:.3f} | {deformation:.2e} | "
              f"{stages} |", flush=True)
    noise = lbc_core.bind(cage, faces, points, cells=9000)
    weights, deformation = differences(first, noise, cage)
    print(f"mesh noise (cold 8000 against cold 9000 cells, unedited cage): max weight difference {weights:.3f}, "
          f"deformation {deformation:.2e} of the diagonal; load average {os.getloadavg()[0]:.1f}", flush=True)


QUAD_CAGES = ("grid-box", "limbs", "torus", "prism-8-rings-5", "cylinder-8-ngon", "cylinder-16-ngon")


def loop_cut_cylinder(segments=32, cuts=2, depth=2.0):
    """Blender's Cylinder (radius 1, 32-gon caps) with ``cuts`` loop cuts: (vertices (n, 3), faces)."""
    rings = cuts + 2
    angles = 2 * np.pi * np.arange(segments) / segments
    vertices = np.array([[np.cos(a), np.sin(a), depth * (r / (rings - 1) - 0.5)] for r in range(rings) for a in angles])
    faces = [[r * segments + s, r * segments + (s + 1) % segments, (r + 1) * segments + (s + 1) % segments,
              (r + 1) * segments + s] for r in range(rings - 1) for s in range(segments)]
    faces += [list(range(segments))[::-1], list(range((rings - 1) * segments, rings * segments))]
    return vertices, faces


def points_inside(cage, faces, count=3000, seed=0):
    """``count`` random points inside a closed cage (winding number above one half), (count, 3)."""
    from lbc_core.kernel.geometry import winding_numbers

    rng = np.random.default_rng(seed)
    made = lbc_core.make_cage(cage, faces)
    low, high = cage.min(axis=0), cage.max(axis=0)
    inside = np.zeros((0, 3))
    while len(inside) < count:
        trial = low + (high - low) * rng.random((4 * count, 3))
        inside = np.concatenate([inside, trial[winding_numbers(made.surface_vertices, made.facets, trial) > 0.5]])
    return inside[:count]


def gargoyle_64k():
    """The demo's gargoyle: the mesh Catmull-Clark subdivided twice (64,130 vertices), through bpy."""
    import bpy

    from bench import capsule
    from bench.smoothness import apply_modifier, vertices_of

    mesh, faces = read_mesh(GARGOYLE / "mesh.off")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    obj = capsule.blender_object(bpy, "Gargoyle", mesh, faces)
    apply_modifier(bpy, obj, "SUBSURF", levels=2)
    return vertices_of(obj)


def addon_scene(cage, faces, points, edits, level="L10"):
    """The add-on's warm re-bind against its cold bind, and against the warm re-bind thinning every row."""
    from lbc_addon import jobs
    from lbc_addon.options import AddonOptions

    options = AddonOptions(mode="3D")

    def request(cage_points):
        return jobs.BindRequest(mesh_uid=1, cage_uid=2, mesh_name="Gargoyle", points=points, cage_points=cage_points,
                                cage_faces=faces, flat=None, options=options, cage_topology="", mesh_topology="")

    def every_row(thinned, before, weights, controls_before, controls, *thinning, cancel=None):
        return jobs.thin_weights(weights, controls, weights @ controls, *thinning, cancel=cancel), weights.shape[0]

    thin_changed_rows = jobs.thin_changed_rows
    first = request(cage)
    first_result = jobs.solve(first)
    jobs.remember(first, first_result)
    print(f"\nadd-on bind (lbc_addon.jobs.solve), demo gargoyle: {len(points)} points, cage {level}; load average "
          f"{os.getloadavg()[0]:.1f}")
    print("| edit | cold s | warm s | speed-up | warm s, every row thinned (before) | speed-up | rows thinned again | "
          "warm stages (s) | the same slots |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for label, edited_cage in edits:
        target = request(edited_cage)
        counts = []

        def counted(*arguments, **keywords):
            thinned, again = thin_changed_rows(*arguments, **keywords)
            counts.append(again)
            return thinned, again

        def timed_solve(thinning):
            """(CPU seconds of every thread, wall seconds) of jobs.solve(target), the result."""
            jobs.thin_changed_rows = thinning
            clock = time.process_time()
            result = jobs.solve(target)
            jobs.thin_changed_rows = thin_changed_rows
            return (time.process_time() - clock, result.seconds), result

        # Interleaved, the best of ROUNDS: the machine is shared.
        seconds = {"cold": [], "warm": [], "before": []}
        for _ in range(ROUNDS):
            for name, thinning in (("before", every_row), ("warm", counted)):
                spent, result = timed_solve(thinning)
                seconds[name].append(spent)
                if name == "warm":
                    warm = result
                else:
                    before = result
            jobs.forget(1)
            spent, _ = timed_solve(thin_changed_rows)
            seconds["cold"].append(spent)
            jobs.remember(first, first_result)  # the next solve starts warm from the unedited cage's binding again
        (cold, cold_wall), (fast, fast_wall), (slow, slow_wall) = (min(seconds[name]) for name in ("cold", "warm",
                                                                                                    "before"))
        same = (f"indices equal, weights within {np.abs(warm.weight - before.weight).max():.1e}"
                if np.array_equal(warm.index, before.index) else "indices differ")
        print(f"| {label} | {cold:.2f} ({cold_wall:.2f}) | {fast:.2f} ({fast_wall:.2f}) | "
              f"{cold / fast:.1f}× ({cold_wall / fast_wall:.1f}×) | {slow:.2f} ({slow_wall:.2f}) | {cold / slow:.1f}× "
              f"({cold_wall / slow_wall:.1f}×) "
              f"| {counts[0]} of {len(points)} | " + ", ".join(f"{k} {v:.2f}" for k, v in warm.stages.items())
              + f" | {same} |", flush=True)
    print(f"({warm.rebind}; load average {os.getloadavg()[0]:.1f})")


def rings_scene(level):
    """The rings of vertices solved again around the moved coordinates' supports (rebinding.FREE_RINGS 2, 1, 0):
    each warm re-bind's domain weights against a tight solve (1e-5) on the same carried mesh, beside a cold solve's.
    ``level``: a gargoyle cage (L08-L16; the gargoyle mesh bound) or one of the paper's 2D cages (woody, cactus,
    Gil_Gecko; 4000 random points in its box, those inside bound)."""
    edits = [(f"{count} × {share:.0%}", count, share) for count, share in ((3, 0.01), (1, 0.02), (5, 0.01))]
    if level.startswith("L"):
        points, _ = read_mesh(GARGOYLE / "mesh.off")
        cage, faces = read_cage(GARGOYLE / f"cage_{level}.obj")
        faces = [list(face) for face in faces]
        centroids = cage[np.array(faces)].mean(axis=1)
        picks = [int(np.argmax(centroids[:, 2])), int(np.argmax(centroids[:, 0])), len(faces) // 8]
        edits = [(f"face {face} pulled out by {share:.0%}", face_pulled(cage, faces, face, share))
                 for face in picks for share in (0.02, 0.04)] + [
                     (label, edited(cage, faces, count, share)) for label, count, share in edits]
        scene_name = f"gargoyle mesh, cage {level}"
    else:
        cage, faces = read_cage(ROOT / "tests" / "data" / f"{level}-control-edgeset.obj")
        cage, faces = cage[:, :2], None
        points = cage.min(axis=0) + np.ptp(cage, axis=0) * np.random.default_rng(0).random((4000, 2))
        points = points[~lbc_core.bind(cage, None, points).outside]
        edits = [(label, edited(cage, None, count, share)) for label, count, share in edits]
        scene_name = f"2D cage {level}"
    first = lbc_core.bind(cage, faces, points)
    print(f"\n{scene_name} ({len(points)} points); load average {os.getloadavg()[0]:.1f}")
    print("| edit | cold on the carried mesh: from tight (iterations) | rings | s | iterations | cells solved | points "
          "evaluated | from tight: max, p99 of the vertices' largest |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    kept = rebinding.FREE_RINGS
    for label, target in edits:
        tight, cold = (on_carried_mesh(first, target, faces, tolerance) for tolerance in (1e-5, None))
        cold_text = f"{np.abs(cold.weights - tight.weights).max():.4f} ({cold.iterations})"
        for rings in (2, 1, 0):
            rebinding.FREE_RINGS = rings
            warm, seconds = timed(rebind, first, target, faces)
            if warm.outcome.start != rebinding.WARM:
                print(f"| {label} | {cold_text} | — | {warm.outcome.report} | | | | |")
                break
            counts = warm.outcome.solved_again
            largest = np.abs(warm.domain_weights - tight.weights).max(axis=1)
            print(f"| {label} | {cold_text} | {rings} | {seconds:.2f} | {warm.iterations} | {counts['cells solved']} | "
                  f"{counts['points evaluated']} | {largest.max():.4f}, {np.quantile(largest, 0.99):.4f} |", flush=True)
        rebinding.FREE_RINGS = kept


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--skip-64k", action="store_true")
    parser.add_argument("--addon", action="store_true")
    parser.add_argument("--cage", default="L10", help="--addon: the gargoyle's cage, L08 to L16")
    parser.add_argument("--vertex", type=int, action="append", default=[],
                        help="--addon: also move this cage vertex outward from the centroid by 2 %% (repeatable)")
    parser.add_argument("--face", type=int, action="append", default=[],
                        help="--addon: also pull the vertices of this cage face out along its normal by 2 %% "
                             "(repeatable)")
    parser.add_argument("--rings", action="store_true",
                        help="the rings solved again around the supports (2, 1, 0) on the cage --cage names (a "
                             "gargoyle cage or woody, cactus, Gil_Gecko)")
    parser.add_argument("--quads", action="store_true", help="the corpus's quad cages, 3000 points inside each")
    arguments = parser.parse_args(argv)
    if arguments.quads:
        sys.path.insert(0, str(ROOT / "tests"))
        from helpers import cage_corpus

        cages = [(f"corpus {name}", *cage_corpus.load(name)) for name in QUAD_CAGES]
        for name, cage, faces in cages + [("Blender's Cylinder, 2 loop cuts", *loop_cut_cylinder())]:
            scene(name, cage, faces, points_inside(cage, faces), [(1, 0.01), (1, 0.02), (3, 0.01), (1, 0.05)])
        return
    if arguments.rings:
        rings_scene(arguments.cage)
        return
    if arguments.addon:
        cage, faces = read_cage(GARGOYLE / f"cage_{arguments.cage}.obj")
        faces = [list(face) for face in faces]
        edits = [(f"{count} × {share:.0%}", edited(cage, faces, count, share)) for count, share in ((1, 0.02),
                                                                                                  (3, 0.01))]
        edits += [(f"vertex {vertex} outward by 2%", outward(cage, vertex, 0.02)) for vertex in arguments.vertex]
        edits += [(f"face {face} ({len(faces[face])} vertices) pulled out by 2%",
                   face_pulled(cage, faces, face, 0.02)) for face in arguments.face]
        addon_scene(cage, faces, gargoyle_64k(), edits, arguments.cage)
        return
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    for level in ("L10", "L09"):
        cage, faces = read_cage(GARGOYLE / f"cage_{level}.obj")
        scene(f"gargoyle, cage {level}", cage, faces, points, EDITS)
    if not arguments.skip_64k:
        cage, faces = read_cage(GARGOYLE / "cage_L10.obj")
        scene("gargoyle subdivided (demo), cage L10", cage, faces, gargoyle_64k(), [(1, 0.02), (3, 0.01)])


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # the bpy 4.5.4 module can deadlock in a static destructor at exit; everything is written
