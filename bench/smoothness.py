"""The smoothness figures, measured in one process: smoothness on the bent capsule, and where speed and locality stand.

    .venv/bin/python bench/smoothness.py [--capsule] [--addon] [--thinning] [--speed] [--l08] [--iterations]
                                         [--tolerance]
                                         (no flag: --capsule)

--capsule     docs/benchmarks.md's Smoothness table on the capsule scene (bench/capsule.py): LBC at 8000 cells (the default, smoothed)
              and the same solve evaluated piecewise linearly, LBC at 32000 cells both ways, Mesh Deform precision 5
              through bpy, mean value coordinates; bind seconds, kinks, influences per point.
--addon       the capsule bound through the Blender add-on (lbc_addon.api.bind, its thinned weights in float32
              slots) and deformed by its Geometry Nodes deformer: its defaults and other Threshold / Max Influences
              settings (``--settings 0.002:0,0.005:12``), against Mesh Deform precision 5 in the same process.
--thinning    the add-on's thinning levers on the weights of lbc_core binds (float64): the capsule,
              Suzanne in its box cage and the demo gargoyle (bench/blender_deform.py's scenes); per setting
              ``--thinnings floor:cap`` (lbc_core.evaluate.thinning.thin_weights) the influences per point, the capsule's
              kinks, the kinks a 60° bend of Suzanne's and the gargoyle's cage gains over every weight (Mesh Deform's
              too, as a yardstick), and the largest distance to every weight over blender_deform.py's three poses,
              beside every weight's distance to a 16,000-cell bind.
--speed       item 2: default bind of the demo gargoyle (subdivided to 64k vertices, cage L10) and of Suzanne
              subdivided to ~48k vertices in a 56-vertex box cage, against Mesh Deform precision 5, same process:
              lbc_core.bind, then the add-on's whole bind (snapshot, lbc_core, thinning, slots, writing) by stage,
              with the evaluation, reduction and thinning of ``--baseline`` (default main; one thread), then current.
--evaluation  item 2, the bind's time outside the solve: the demo gargoyle's evaluation at its 64k points (smooth
              rows, reduction) and the add-on's thinning, timed against the code of a baseline revision
              (``--baseline``, default main) loaded from git into the same process: interleaved, CPU seconds, one
              thread, then the current code on every core (wall seconds); the largest weight difference.
--l08         item 3: gargoyle cage L08 (168 control points) at 8000 and 32000 cells.
--iterations  item 4: iterations of every gargoyle cage at the default resolution.
--tolerance   the 3D stopping tolerance as a lever of item 2: for the capsule and gargoyle cages L10 and L12, binds
              stopped at several tolerances against a tight one (1e-5): iterations, solve seconds, objective, the
              deformation's distance from the tight one over three poses, set against what remeshing alone changes
              (8000 against 9000 cells, same poses), and the capsule's kinks.
--picture P   renders the bent capsule with LBC (smooth), Mesh Deform and LBC evaluated piecewise linearly side by
              side into the PNG file P (Workbench, smooth shading, a striped reflection that bends at every crease).
"""

import argparse
import inspect
import os
import re
import subprocess
import sys
import types
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lbc_core  # noqa: E402
from bench import capsule  # noqa: E402
from lbc_core.compare.baselines import bind_mvc  # noqa: E402
from lbc_core.evaluate.interpolation import interpolation_matrix  # noqa: E402
from lbc_core.io import read_cage, read_mesh  # noqa: E402
from lbc_core.evaluate.reduction import interpolate_and_reduce  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"


def load():
    return f"load average {os.getloadavg()[0]:.1f}"


def piecewise_linear(binding):
    """The binding's own solve evaluated at its points by P1 interpolation (the evaluation before smoothing).

    Returns
    -------
    weights : (m, n) scipy.sparse.csr_matrix
    seconds : float
        The time of that evaluation.
    """
    start = time.perf_counter()
    domain = binding.domain
    located, _, _ = interpolation_matrix(domain.vertices, domain.cells, binding.points)
    weights = interpolate_and_reduce(located, binding.domain_weights, binding.cage.vertices, domain.vertices,
                                     binding.outcome.threshold, 1e-9 * binding.cage.bbox_diagonal)
    return weights, time.perf_counter() - start


def row(name, seconds, figures, influences):
    print(f"| {name} | {seconds:.2f} s | {figures['mean']:.2f}° / {figures['p99']:.2f}° / {figures['max']:.2f}° "
          f"| {figures['creased']:.2f} % | {influences} |", flush=True)


def bench_capsule(cells_list=(8000, 32000)):
    mesh, faces = capsule.capsule()
    cage, cage_faces = capsule.cage()
    posed = capsule.bend(cage)
    print(f"capsule: {len(mesh)} vertices; cage: {len(cage)} vertices; bent 90°; {load()}")
    print("| scheme | bind | kink mean / p99 / max | edges creased > 2° | influences per point, mean / max |")
    print("| --- | --- | --- | --- | --- |")
    for cells in cells_list:
        start = time.perf_counter()
        binding = lbc_core.bind(cage, cage_faces, mesh, cells=cells)
        seconds = time.perf_counter() - start
        counts = np.diff(binding.weights.indptr)
        row(f"LBC, {cells} cells, smooth", seconds, capsule.kink_figures(mesh, binding.deform(posed), faces),
            f"{counts.mean():.1f} / {counts.max()}")
        linear, linear_seconds = piecewise_linear(binding)
        counts = np.diff(linear.indptr)
        displacement = binding.cage.control_points_from_input(posed) - binding.rest_cage_vertices
        row(f"LBC, {cells} cells, piecewise linear", seconds - binding.timings["reduction"] + linear_seconds,
            capsule.kink_figures(mesh, mesh + linear @ displacement, faces), f"{counts.mean():.1f} / {counts.max()}")
        print(f"  ({len(binding.domain.cells)} tets, {binding.iterations} iterations, stages "
              + ", ".join(f"{k} {v:.2f}" for k, v in binding.timings.items()) + f"; {load()})", flush=True)
    seconds, moved = capsule.mesh_deform(mesh, faces, cage, cage_faces, posed, precision=5)
    row("Mesh Deform, precision 5", seconds, capsule.kink_figures(mesh, moved, faces), "—")
    start = time.perf_counter()
    mvc = bind_mvc(cage, cage_faces, mesh)
    row("mean value coordinates", time.perf_counter() - start, capsule.kink_figures(mesh, mvc.deform(posed), faces),
        f"{len(cage)} (dense)")
    print(f"  ({load()})")


def bench_addon(settings):
    """Kinks of the bent capsule as the add-on deforms it: one bind per (threshold, influences) setting."""
    import bpy

    sys.path.insert(0, str(ROOT / "tests"))
    from helpers.blender_scenes import evaluated_positions, register_addon

    from lbc_addon import api

    register_addon()
    mesh, faces = capsule.capsule()
    cage, cage_faces = capsule.cage()
    posed = capsule.bend(cage)
    print(f"capsule through the add-on: {len(mesh)} vertices; cage: {len(cage)} vertices; bent 90°; {load()}")
    print("| add-on setting (Threshold : Max Influences) | bind | kink mean / p99 / max | edges creased > 2° "
          "| influences per vertex, mean / max |")
    print("| --- | --- | --- | --- | --- |")
    for threshold, influences in settings:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        mesh_obj = capsule.blender_object(bpy, "Capsule", mesh, faces)
        cage_obj = capsule.blender_object(bpy, "Cage", cage, cage_faces)
        start = time.perf_counter()
        summary = api.bind(mesh_obj, cage_obj, thinning=threshold, influences=influences)
        seconds = time.perf_counter() - start
        cage_obj.data.vertices.foreach_set("co", posed.astype(np.float32).ravel())
        cage_obj.data.update()
        name = f"{threshold:g} : {influences}" + (" (defaults)" if (threshold, influences) == (0.0, 0) else "")
        row(name, seconds, capsule.kink_figures(mesh, evaluated_positions(mesh_obj), faces),
            f"{summary.mean_influences:.1f} / {summary.slots}")
    seconds, moved = capsule.mesh_deform(mesh, faces, cage, cage_faces, posed, precision=5)
    row("Mesh Deform, precision 5", seconds, capsule.kink_figures(mesh, moved, faces), "—")
    print(f"  ({load()})")


def bench_thinning(settings):
    import bpy

    sys.path.insert(0, str(ROOT / "tests"))
    from blender_deform import SCENES, pose

    from lbc_core.evaluate.thinning import thin_weights

    mesh, faces = capsule.capsule()
    scenes = {"capsule": (mesh, faces, *capsule.cage())}
    for name in ("suzanne", "gargoyle"):
        mesh_obj, cage_obj = SCENES[name]()
        scenes[name] = (world_vertices(mesh_obj), triangles(faces_of(mesh_obj)), world_vertices(cage_obj),
                        faces_of(cage_obj))
    print(f"thinning levers; {load()}")
    print("| scene | setting (floor : cap) | influences mean / max | kinks p99 / max (capsule: of the bend; "
          "others: gained over every weight) | distance to every weight |")
    print("| --- | --- | --- | --- | --- |")
    for name, (points, faces, cage, cage_faces) in scenes.items():
        binding = lbc_core.bind(cage, cage_faces, points)
        rest = binding.rest_cage_vertices
        diagonal = float(np.linalg.norm(np.ptp(points, axis=0)))
        bent = capsule.bend(cage) if name == "capsule" else bend_along_z(cage, 60.0)

        def moved(weights, cage_pose):
            return binding.points + weights @ (binding.cage.control_points_from_input(cage_pose) - rest)

        def distance(weights, reference):
            return max(float(np.abs(moved(weights - reference, cage_pose) - binding.points).max())
                       for cage_pose in (pose(cage, phase) for phase in (0.7, 2.1, 4.0))) / diagonal

        every = capsule.kinks(points, moved(binding.weights, bent), faces)
        if name != "capsule":
            fine = lbc_core.bind(cage, cage_faces, points, cells=16000)
            _, deformed = capsule.mesh_deform(points, faces, cage, cage_faces, bent)
            gained = capsule.kinks(points, deformed, faces) - every
            print(f"| {name} | every weight, 16,000 cells | — | — | {distance(fine.weights, binding.weights):.2e} |")
            print(f"| {name} | Mesh Deform, precision 5 | — | {np.percentile(gained, 99):.2f}° / {gained.max():.2f}° "
                  "| — |")
        for floor, cap in settings:
            thinned = thin_weights(binding.weights, rest, binding.weights @ rest, floor, cap)
            counts = np.diff(thinned.indptr)
            values = capsule.kinks(points, moved(thinned, bent), faces) - (0 if name == "capsule" else every)
            print(f"| {name} | {floor:g} : {cap} | {counts.mean():.1f} / {counts.max()} "
                  f"| {np.percentile(values, 99):.2f}° / {values.max():.2f}° "
                  f"| {distance(thinned, binding.weights):.2e} |", flush=True)


def bend_along_z(vertices, degrees):
    """:func:`capsule.bend` of a cage of any size: its z extent mapped onto the capsule cage's, bent, mapped back."""
    centre = (vertices.max(axis=0) + vertices.min(axis=0)) / 2
    scale = 2 * capsule.CAGE_HALF_HEIGHT / np.ptp(vertices[:, 2])
    return capsule.bend((vertices - centre) * scale, degrees) / scale + centre


def world_vertices(obj):
    matrix = np.array(obj.matrix_world)
    return vertices_of(obj) @ matrix[:3, :3].T + matrix[:3, 3]


def triangles(polygons):
    """Polygons split into triangle fans, (F, 3) int array."""
    return np.array([[polygon[0], polygon[k], polygon[k + 1]] for polygon in polygons
                     for k in range(1, len(polygon) - 1)])


def vertices_of(obj):
    values = np.empty(len(obj.data.vertices) * 3, dtype=np.float32)
    obj.data.vertices.foreach_get("co", values)
    return values.reshape(-1, 3).astype(float)


def faces_of(obj):
    return [list(polygon.vertices) for polygon in obj.data.polygons]


def bench_speed(baseline):
    import contextlib

    import bpy

    sys.path.insert(0, str(ROOT / "tests"))
    from helpers.blender_scenes import register_addon

    from lbc_addon import geometry, jobs, writing

    register_addon()
    old = baseline_modules(baseline)

    @contextlib.contextmanager
    def baseline_code():
        """The bind's evaluation, reduction and thinning from ``baseline``'s modules, on one thread (as before)."""
        import lbc_core.kernel.parallel as parallel
        import lbc_core.binding.pipeline as pipeline

        saved = pipeline.SmoothInterpolation, pipeline.interpolate_and_reduce, jobs.thin_weights, parallel.worker_count
        pipeline.SmoothInterpolation = pipeline_smoothing(old["smoothing"])
        pipeline.interpolate_and_reduce = old["reduction"].interpolate_and_reduce
        jobs.thin_weights, parallel.worker_count = old["thinning"].thin_weights, lambda: 1
        try:
            yield
        finally:
            (pipeline.SmoothInterpolation, pipeline.interpolate_and_reduce, jobs.thin_weights,
             parallel.worker_count) = saved

    def addon_bind(mesh_obj, cage_obj):
        """The add-on's default bind (what api.bind does), timed by stage: snapshot, lbc_core's stages, thinning,
        slots, writing; from scratch (the session's previous binding of the mesh forgotten)."""
        jobs.forget(mesh_obj.session_uid)
        clock = time.perf_counter()
        request = geometry.snapshot(mesh_obj, cage_obj, bpy.context.evaluated_depsgraph_get())
        snapshot = time.perf_counter() - clock
        result = jobs.solve(request)
        clock = time.perf_counter()
        writing.apply(request, result)
        stages = dict(snapshot=snapshot, **result.stages, writing=time.perf_counter() - clock)
        return sum(stages.values()), stages, result

    def compare(name, mesh_obj, cage_obj):
        points, cage, cage_faces = vertices_of(mesh_obj), vertices_of(cage_obj), faces_of(cage_obj)
        bpy.context.view_layer.update()
        md = capsule.bind_mesh_deform(bpy, mesh_obj, cage_obj)
        start = time.perf_counter()
        binding = lbc_core.bind(cage, cage_faces, points)
        seconds = time.perf_counter() - start
        counts = np.diff(binding.weights.indptr)
        print(f"| {name}, lbc_core.bind | {len(points)} | {len(cage)} | {seconds:.2f} s | {md:.2f} s | "
              f"{seconds / md:.1f}× | {binding.iterations} | {counts.mean():.1f} / {counts.max()} | "
              + ", ".join(f"{k} {v:.2f}" for k, v in binding.timings.items()) + f" | {load()} |", flush=True)
        for code in (baseline, "current"):
            with baseline_code() if code == baseline else contextlib.nullcontext():
                seconds, stages, result = addon_bind(mesh_obj, cage_obj)
            counts = np.count_nonzero(result.weight, axis=1)
            outside_solve = seconds - stages["solve"] - stages.get("factorisation", 0.0)
            print(f"| {name}, add-on bind, {code} | {len(points)} | {len(cage)} | {seconds:.2f} s ({outside_solve:.2f} "
                  f"outside the solve) | {md:.2f} s | {seconds / md:.1f}× | {result.binding.iterations} | "
                  f"{counts.mean():.1f} / {result.index.shape[1]} | "
                  + ", ".join(f"{k} {v:.2f}" for k, v in stages.items()) + f" | {load()} |", flush=True)

    print("| scene | mesh vertices | cage vertices | LBC default bind | Mesh Deform p5 bind | ratio | iterations "
          "| influences mean / max | LBC stages (s) | load |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh_obj = capsule.blender_object(bpy, "Gargoyle", *read_mesh(GARGOYLE / "mesh.off"))
    cage_obj = capsule.blender_object(bpy, "Cage", *read_mesh(GARGOYLE / "cage_L10.obj"))
    apply_modifier(bpy, mesh_obj, "SUBSURF", levels=2)
    compare("gargoyle, Catmull-Clark 2 levels, cage L10", mesh_obj, cage_obj)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_monkey_add()
    suzanne = subdivided(bpy, bpy.context.active_object, cuts=9)
    lo, hi = vertices_of(suzanne).min(axis=0), vertices_of(suzanne).max(axis=0)
    bpy.ops.mesh.primitive_cube_add()
    box = subdivided(bpy, bpy.context.active_object, cuts=2)
    box_vertices = vertices_of(box)  # the cube spans ±1: scale it to Suzanne's box plus 10 % on every side
    box_vertices = (lo + hi) / 2 + box_vertices * (hi - lo) / 2 * 1.2
    box.data.vertices.foreach_set("co", box_vertices.astype(np.float32).ravel())
    box.data.update()
    compare("Suzanne, 9 cuts, cube with 2 cuts", suzanne, box)


def baseline_modules(revision, names=("constraints", "smoothing", "reduction", "thinning")):
    """lbc_core's modules ``names`` as they are at a git ``revision``, loaded beside the current ones: their relative
    imports of each other resolve among them, the others to the current lbc_core. Returns {name: module}."""
    modules = {}
    for name in names:
        source = subprocess.run(["git", "-C", str(ROOT), "show", f"{revision}:lbc_core/{name}.py"], check=True,
                                capture_output=True, text=True).stdout
        source = re.sub(r"^from \.(\w+) import",
                        lambda match: f"from {'baseline_' if match[1] in modules else 'lbc_core.'}{match[1]} import",
                        source, flags=re.M)
        module = types.ModuleType(f"baseline_{name}")
        sys.modules[module.__name__] = module
        exec(compile(source, f"{revision}:lbc_core/{name}.py", "exec"), module.__dict__)
        modules[name] = module
    return modules


def pipeline_smoothing(module):
    """``module``'s SmoothInterpolation as ``lbc_core.binding.pipeline.evaluate`` calls it today (with ``reach``), for a
    baseline whose class took the radius and fade in median edges instead."""
    if "reach" in inspect.signature(module.SmoothInterpolation).parameters:
        return module.SmoothInterpolation

    def smoothing(*args, reach=1.0, **kwargs):
        return module.SmoothInterpolation(*args, radius_edges=module.RADIUS_EDGES * reach,
                                          fade_edges=module.FADE_EDGES * reach, **kwargs)

    return smoothing


def bench_evaluation(baseline, rounds=3):
    """The evaluation at the demo gargoyle's points and the add-on's thinning: current code against ``baseline``'s."""
    import lbc_core.kernel.parallel as parallel
    from bench.rebinding import gargoyle_64k
    from lbc_core.evaluate import smoothing, thinning
    from lbc_core.kernel.frame import UnitFrame
    from lbc_core.binding.pipeline import REPRODUCTION_TOLERANCE

    points = gargoyle_64k()
    cage, faces = read_cage(GARGOYLE / "cage_L10.obj")
    binding = lbc_core.bind(cage, faces, points)
    frame = UnitFrame.of(binding.cage)
    unit_cage = frame.cage_to_unit(binding.cage)
    vertices, cells = frame.to_unit(binding.domain.vertices), binding.domain.cells
    located, _, _ = interpolation_matrix(vertices, cells, frame.to_unit(points))
    threshold = binding.outcome.threshold
    tolerance = REPRODUCTION_TOLERANCE * unit_cage.bbox_diagonal
    old = baseline_modules(baseline)
    current = {"smoothing": smoothing, "reduction": sys.modules["lbc_core.evaluate.reduction"], "thinning": thinning}

    def run(modules):
        """(evaluation and reduction CPU s, wall s), (thinning CPU s, wall s), the reduced and the thinned weights."""
        figures = []
        clock, cpu = time.perf_counter(), time.process_time()
        smooth = modules["smoothing"].SmoothInterpolation(vertices, cells, located)
        reduced = modules["reduction"].interpolate_and_reduce(smooth, binding.domain_weights, unit_cage.vertices,
                                                              vertices, threshold, tolerance)
        figures.append((time.process_time() - cpu, time.perf_counter() - clock))
        clock, cpu = time.perf_counter(), time.process_time()
        thinned = modules["thinning"].thin_weights(reduced, unit_cage.vertices, reduced @ unit_cage.vertices)
        figures.append((time.process_time() - cpu, time.perf_counter() - clock))
        return figures, reduced, thinned

    threads = parallel.worker_count
    seconds = {"baseline": [], "current, one thread": [], "current, every core": []}
    for _ in range(rounds):
        for name, modules in (("baseline", old), ("current, one thread", current), ("current, every core", current)):
            parallel.worker_count = threads if name.endswith("every core") else (lambda: 1)
            figures, reduced, thinned = run(modules)
            seconds[name].append(figures)
            results = (reduced, thinned) if name == "baseline" else results
            if name != "baseline":
                differences = (abs(reduced - results[0]).max(), abs(thinned - results[1]).max())
    parallel.worker_count = threads
    print(f"\ndemo gargoyle, {len(points)} points, cage L10: the evaluation at the points against {baseline} "
          f"({threads()} threads on every core; best of {rounds}, interleaved; {load()})")
    print("| code | evaluation + reduction CPU s (wall) | thinning CPU s (wall) |")
    print("| --- | --- | --- |")
    for name, runs in seconds.items():
        evaluation = min(runs, key=lambda figures: figures[0][0])[0]
        thinning_seconds = min(runs, key=lambda figures: figures[1][0])[1]
        print(f"| {name} | {evaluation[0]:.2f} ({evaluation[1]:.2f}) | {thinning_seconds[0]:.2f} "
              f"({thinning_seconds[1]:.2f}) |")
    print(f"largest difference to {baseline}: reduced weights {differences[0]:.1e}, thinned {differences[1]:.1e}")


def subdivided(bpy, obj, cuts):
    """``obj`` (the active object) with every edge cut ``cuts`` times (Edit Mode's Subdivide)."""
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.subdivide(number_cuts=cuts)
    bpy.ops.object.mode_set(mode="OBJECT")
    return obj


def apply_modifier(bpy, obj, kind, **settings):
    modifier = obj.modifiers.new(kind.title(), kind)
    for key, value in settings.items():
        setattr(modifier, key, value)
    with bpy.context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.modifier_apply(modifier=modifier.name)


def bench_l08(cells_list=(8000, 32000)):
    cage, faces = read_cage(GARGOYLE / "cage_L08.obj")
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    for cells in cells_list:
        start = time.perf_counter()
        binding = lbc_core.bind(cage, faces, points, cells=cells)
        print(f"L08 ({binding.cage.n_control_points} control points), {len(binding.domain.cells)} tets: "
              f"{time.perf_counter() - start:.1f} s, {binding.iterations} iterations; "
              + ", ".join(f"{k} {v:.2f}" for k, v in binding.timings.items()) + f"; {load()}", flush=True)


def bench_iterations():
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    found = {}
    for path in sorted(GARGOYLE.glob("cage_L*.obj")):
        cage, faces = read_cage(path)
        start = time.perf_counter()
        binding = lbc_core.bind(cage, faces, points)
        found[path.stem] = binding.iterations
        print(f"{path.stem}: {binding.cage.n_control_points} control points, {binding.iterations} iterations, "
              f"{time.perf_counter() - start:.1f} s, converged {binding.converged}; {load()}", flush=True)
    median = float(np.median(list(found.values())))
    worst = max(found, key=found.get)
    print(f"median {median:.0f} iterations; most: {worst} with {found[worst]} ({found[worst] / median:.2f}× the median)")


def twisted_poses(cage, count=3, seed=0):
    """``count`` poses of a cage (n, 3): a 30° twist about its z extent plus seeded noise of 3 % of its diagonal per
    vertex."""
    rng = np.random.default_rng(seed)
    centre, low, height = cage.mean(axis=0), cage[:, 2].min(), np.ptp(cage[:, 2])
    angle = np.radians(30) * (cage[:, 2] - low) / height
    x, y = cage[:, 0] - centre[0], cage[:, 1] - centre[1]
    twisted = np.stack([centre[0] + x * np.cos(angle) - y * np.sin(angle),
                        centre[1] + x * np.sin(angle) + y * np.cos(angle), cage[:, 2]], axis=1)
    diagonal = np.linalg.norm(np.ptp(cage, axis=0))
    return [twisted + 0.03 * diagonal * rng.standard_normal(cage.shape) for _ in range(count)]


def bench_tolerance(tolerances=(1e-4, 2e-4, 2.5e-4, 3e-4)):
    mesh, mesh_faces = capsule.capsule()
    scenes = [("capsule", *capsule.cage(), mesh, mesh_faces)]
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    scenes += [(f"gargoyle {level}", *read_cage(GARGOYLE / f"cage_{level}.obj"), points, None)
               for level in ("L10", "L12")]
    print("| scene | tolerance | iterations | solve | objective above the tight one "
          "| deformation from the tight one / diagonal | capsule kinks p99 / max |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for name, cage, cage_faces, scene_points, faces in scenes:
        poses = twisted_poses(cage)
        diagonal = np.linalg.norm(np.ptp(cage, axis=0))

        def distance(binding, reference):
            return max(np.linalg.norm(binding.deform(pose) - reference.deform(pose), axis=1).max()
                       for pose in poses) / diagonal

        tight = lbc_core.bind(cage, cage_faces, scene_points, tolerance=1e-5)
        finer = lbc_core.bind(cage, cage_faces, scene_points, tolerance=1e-5, cells=9000)
        print(f"| {name} | 1e-05 (tight) | {tight.iterations} | {tight.timings['solve']:.2f} s | — "
              f"| remeshed at 9000 cells: {distance(finer, tight):.2e} | — |", flush=True)
        for tolerance in tolerances:
            binding = lbc_core.bind(cage, cage_faces, scene_points, tolerance=tolerance)
            kinks = "—"
            if faces is not None:
                figures = capsule.kink_figures(scene_points, binding.deform(capsule.bend(cage)), faces)
                kinks = f"{figures['p99']:.2f}° / {figures['max']:.2f}°"
            print(f"| | {tolerance:g} | {binding.iterations} | {binding.timings['solve']:.2f} s | "
                  f"{binding.objective / tight.objective - 1:.1e} | {distance(binding, tight):.2e} | {kinks} |",
                  flush=True)
    print(f"  ({load()})")


def render_picture(path):
    """The bent capsule deformed by the three evaluations side by side, rendered with a striped matcap."""
    import bpy

    mesh, faces = capsule.capsule()
    cage, cage_faces = capsule.cage()
    posed = capsule.bend(cage)
    _, mesh_deformed = capsule.mesh_deform(mesh, faces, cage, cage_faces, posed, precision=5)
    binding = lbc_core.bind(cage, cage_faces, mesh)
    linear, _ = piecewise_linear(binding)
    displacement = binding.cage.control_points_from_input(posed) - binding.rest_cage_vertices
    shown = [("LBC, smooth (default)", binding.deform(posed)), ("Mesh Deform, precision 5", mesh_deformed),
             ("LBC, piecewise linear", mesh + linear @ displacement)]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    spacing = 4.2
    for slot, (label, vertices) in enumerate(shown):
        obj = capsule.blender_object(bpy, label, vertices + [slot * spacing, 0, 0], faces)
        obj.data.polygons.foreach_set("use_smooth", np.ones(len(faces), dtype=bool))
        obj.data.update()
        text = bpy.data.curves.new(label, "FONT")
        text.body, text.align_x, text.size = label, "CENTER", 0.32
        caption = bpy.data.objects.new(label + " caption", text)
        caption.location = (slot * spacing + 1.4, 0, -2.9)
        caption.rotation_euler = (np.pi / 2, 0, 0)
        scene.collection.objects.link(caption)
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = (1.0, 1.0, 1.0)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.view_settings.view_transform = "Standard"  # a white background stays white
    scene.render.resolution_x, scene.render.resolution_y = 1500, 560
    scene.display.shading.light = "MATCAP"
    scene.display.shading.studio_light = "reflection_check_horizontal.exr"
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = 3 * spacing - 0.4
    camera.location = (spacing + 1.3, -10.0, -1.0)
    camera.rotation_euler = (np.pi / 2, 0, 0)  # looking along +y, z up: the bend is in the picture's plane
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for flag in ("capsule", "addon", "thinning", "speed", "evaluation", "l08", "iterations", "tolerance"):
        parser.add_argument(f"--{flag}", action="store_true")
    parser.add_argument("--settings", default="0:0,1e-12:0,0.002:0,0.01:0,0.005:12,0.005:16",
                        help="--addon: comma-separated Threshold:Max Influences settings (0:0 is the defaults, "
                        "1e-12:0 every weight)")
    parser.add_argument("--thinnings", default="0.005:0,0.005:12,0.005:14",
                        help="--thinning: comma-separated floor:cap settings (lbc_core.evaluate.thinning.thin_weights)")
    parser.add_argument("--baseline", default="main",
                        help="--evaluation, --speed: the git revision whose evaluation, reduction and thinning to time "
                        "against")
    parser.add_argument("--picture", type=Path)
    args = parser.parse_args(argv)
    if args.picture:
        render_picture(args.picture)
    elif not (args.addon or args.thinning or args.speed or args.evaluation or args.l08 or args.iterations
              or args.tolerance):
        args.capsule = True
    if args.capsule:
        bench_capsule()
    if args.addon:
        bench_addon([(float(value.split(":")[0]), int(value.split(":")[1])) for value in args.settings.split(",")])
    if args.thinning:
        bench_thinning([(float(floor), int(cap))
                        for floor, cap in (value.split(":") for value in args.thinnings.split(","))])
    if args.speed:
        bench_speed(args.baseline)
    if args.evaluation:
        bench_evaluation(args.baseline)
    if args.l08:
        bench_l08()
    if args.iterations:
        bench_iterations()
    if args.tolerance:
        bench_tolerance()


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # the bpy 4.5.4 module can deadlock in a static destructor at exit; everything is written
