"""The demo's bind in Blender stage by stage, against Mesh Deform's in the same process; two versions interleaved.

    PYTHONPATH=. .venv/bin/python bench/bind_stages.py [--rounds 3] [--version DIR[+PATH]]... [--frames 21]
                                                       [--cage L10]

Each round runs one child process per version (``--version``, repeated: a checkout of the repository, e.g.
``git archive <commit> | tar -x -C DIR``, with an optional folder of extra modules on its path after a +, e.g. one
holding threadpoolctl; default: this checkout), in a rotating order. A child builds the demo scene (demo_blender.py's
gargoyle, Catmull-Clark subdivided twice: 64,130 vertices, in cage L10), binds a small scene first (so that no
version pays the imports in the measured bind), then binds the demo through the operator as a user does and Mesh
Deform (precision 5) on the same mesh, in an order that alternates with the round. Each stage is timed in wall and
in CPU seconds (every thread's; a machine shared with other jobs inflates it less): the snapshot, lbc_core's stages
(``Binding.timings``), the thinning and the slots (``BindResult.stages``: these in CPU seconds only), and the writes (attributes,
node group, the rest of :func:`lbc_addon.writing.apply`). Then the per-frame time of both deformers, interleaved
(``bench/blender_deform.py``'s ``measure``, after a cage edit). Printed: per version the median over the rounds of
each figure, and the load before and after.
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

HERE = Path(__file__).resolve().parents[1]
JSON_MARK = "BIND_STAGES_JSON "


class Timed:
    """Wraps ``module.name`` so that each call adds its wall and CPU seconds to ``figures[label]``."""

    def __init__(self, figures, module, name, label):
        self.function = getattr(module, name)
        self.figures, self.label = figures, label
        setattr(module, name, self)

    def __call__(self, *args, **kwargs):
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            return self.function(*args, **kwargs)
        finally:
            walls, cpus = self.figures.setdefault(self.label, [0.0, 0.0])
            self.figures[self.label] = [walls + time.perf_counter() - wall, cpus + time.process_time() - cpu]


def instrument(figures):
    """Time the add-on's parts of a bind into ``figures`` ({label: [wall, cpu]}) and keep each solve's stages."""
    from lbc_addon import deformer, geometry, jobs, node_group, operators, storage, writing
    from lbc_core.kernel import progress

    solves = []
    solve = jobs.solve

    def kept_solve(*args, **kwargs):
        wall, cpu = time.perf_counter(), time.process_time()
        result = solve(*args, **kwargs)
        solves.append(dict(stages=dict(result.stages), wall=time.perf_counter() - wall,
                           cpu=time.process_time() - cpu, slots=int(result.index.shape[1]),
                           influences=float((result.weight > 0).sum(axis=1).mean())))
        return result

    jobs.solve = kept_solve
    # The stages' own clocks (lbc_core's laps, the add-on's thinning and slots) count CPU seconds here.
    cpu_clock = SimpleNamespace(perf_counter=time.process_time)
    progress.time = jobs.time = cpu_clock
    Timed(figures, geometry, "snapshots", "snapshot")
    Timed(figures, writing, "apply", "apply")
    Timed(figures, storage, "write", "apply: attributes")
    Timed(figures, storage, "remove", "apply: attributes")
    Timed(figures, deformer, "attach", "apply: deformer")
    Timed(figures, node_group, "saved_bytes", "apply: group size")
    Timed(figures, writing, "_SavedBinding", "apply: saved")
    assert operators.jobs is jobs
    return solves


def warm_up():
    """A small bind first, so that the measured one does not pay the first imports of scipy's and numpy's parts."""
    import bpy
    from helpers.blender_scenes import bind, sphere_in_box_scene

    mesh, cage = sphere_in_box_scene()
    assert bind(mesh, cage, cells=2000) == {"FINISHED"}
    for obj in (mesh, cage):
        bpy.data.objects.remove(obj)


def bind_both(mesh, cage, lbc_first, figures):
    """Bind LBC (the operator) and Mesh Deform (precision 5) on ``mesh``, in the order asked; their wall and CPU
    seconds into ``figures``."""
    import bpy

    import demo_blender as demo

    def lbc():
        with bpy.context.temp_override(active_object=cage, object=cage, selected_objects=[mesh, cage]):
            assert bpy.ops.object.lbc_bind() == {"FINISHED"}

    modifier = mesh.modifiers.new("Mesh Deform", "MESH_DEFORM")
    modifier.object, modifier.precision = cage, 5

    def mesh_deform():
        demo.toggle_mesh_deform_binding(mesh, modifier)

    for label, run in ([("LBC bind", lbc), ("Mesh Deform bind", mesh_deform)][::1 if lbc_first else -1]):
        wall, cpu = time.perf_counter(), time.process_time()
        run()
        figures[label] = [time.perf_counter() - wall, time.process_time() - cpu]
    return modifier


def frames(mesh, cage, modifier, count):
    """Per-frame milliseconds (wall, CPU) of LBC and Mesh Deform after a cage edit, interleaved: their medians."""
    import bpy
    import numpy as np

    from bench import blender_deform as bd
    from lbc_addon import deformer

    mesh.modifiers.remove(modifier)  # Mesh Deform on a copy of its own, LBC alone on the mesh
    copy = bd.mesh_deform_variant(mesh, cage, "Mesh Deform copy", 5)
    mesh.modifiers[deformer.MODIFIER_NAME].show_viewport = True
    bpy.context.scene.collection.objects.unlink(mesh)
    rest = bd.positions(cage.data)
    times = bd.measure({"LBC": mesh, "Mesh Deform": copy}, cage, rest, count)
    bpy.context.scene.collection.objects.link(mesh)
    return {name: [float(np.median(values[:, 0])), float(np.median(values[:, 1]))] for name, values in times.items()}


def child(lbc_first, frame_count, cage_level):
    import bpy

    import demo_blender as demo
    from helpers.blender_scenes import register_addon

    register_addon()
    load = [os.getloadavg()[0]]
    warm_up()
    mesh, cage = demo.build_scene(cage_level)
    demo.subdivide(mesh, 2)
    figures = {}
    solves = instrument(figures)
    modifier = bind_both(mesh, cage, lbc_first, figures)
    frame_times = frames(mesh, cage, modifier, frame_count) if frame_count else {}
    load.append(os.getloadavg()[0])
    print(JSON_MARK + json.dumps(dict(figures=figures, solve=solves[-1], frames=frame_times, load=load,
                                      vertices=len(mesh.data.vertices), blender=bpy.app.version_string)),
          flush=True)


def run_child(version, lbc_first, frame_count, cage_level):
    """One child process on the checkout ``version`` (DIR[+PATH]): its figures (the JSON the child prints)."""
    code, _, extra = version.partition("+")
    code = Path(code).resolve()
    paths = [str(code), str(code / "tests"), str(HERE)] + ([extra] if extra else [])
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join(paths))
    command = [sys.executable, str(Path(__file__).resolve()), "--child", "--frames", str(frame_count),
               "--cage", cage_level] + (["--lbc-first"] if lbc_first else [])
    run = subprocess.run(command, capture_output=True, text=True, cwd=code, env=environment)
    lines = [line for line in run.stdout.splitlines() if line.startswith(JSON_MARK)]
    if not lines:
        raise RuntimeError(f"the child on {code} failed ({run.returncode}):\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}")
    return json.loads(lines[-1][len(JSON_MARK):])


def rows_of(result):
    """{label: (wall, cpu or None)} of one child's figures, in the order of a bind."""
    figures, solve = result["figures"], result["solve"]
    rows = {"snapshot": figures["snapshot"]}
    for stage, seconds in solve["stages"].items():
        rows[f"solve: {stage} (cpu)"] = [seconds, None]
    rows["solve (jobs.solve)"] = [solve["wall"], solve["cpu"]]
    for label in ("apply", "apply: saved", "apply: attributes", "apply: deformer", "apply: group size"):
        rows[label] = figures.get(label, [0.0, 0.0])
    rows["LBC bind"] = figures["LBC bind"]
    rows["Mesh Deform bind"] = figures["Mesh Deform bind"]
    for name, (wall, cpu) in result["frames"].items():
        rows[f"frame (ms): {name}"] = [wall, cpu]
    return rows


def summary(results):
    """The median of each figure over a version's rounds, as printed lines."""
    import numpy as np

    lines = []
    versions = list(results)
    labels = list(rows_of(results[versions[0]][0]))
    lines.append(f"{'':34}" + "".join(f"{version[-28:]:>30}" for version in versions))
    for label in labels:
        cells = []
        for version in versions:
            values = [rows_of(result).get(label, [float("nan"), None]) for result in results[version]]
            wall = float(np.median([value[0] for value in values]))
            cpus = [value[1] for value in values if value[1] is not None]
            cells.append(f"{wall:14.3f}" + (f" (cpu {float(np.median(cpus)):7.3f})" if cpus else " " * 16))
        lines.append(f"{label:34}" + "".join(cells))
    for version in versions:
        first = results[version][0]
        lines.append(f"{version}: {first['solve']['slots']} slots, {first['solve']['influences']:.2f} influences "
                     f"per vertex, {first['vertices']} vertices; load {[result['load'] for result in results[version]]}")
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--version", action="append", help="a checkout DIR[+PATH of extra modules] (repeated)")
    parser.add_argument("--frames", type=int, default=21, help="frames timed per deformer (0: none)")
    parser.add_argument("--cage", default="L10")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--lbc-first", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.lbc_first, args.frames, args.cage)
        sys.stdout.flush()
        os._exit(0)  # the bpy module can deadlock in a static destructor at exit
    versions = args.version or [str(HERE)]
    results = {str(version): [] for version in versions}
    for number in range(args.rounds):
        order = versions[number % len(versions):] + versions[:number % len(versions)]
        for version in order:
            results[str(version)].append(run_child(version, number % 2 == 0, args.frames, args.cage))
            print(f"round {number + 1}, {version}: LBC {results[str(version)][-1]['figures']['LBC bind']}", flush=True)
    print("\n".join(summary(results)))
    print(json.dumps(results))


if __name__ == "__main__":
    main()
