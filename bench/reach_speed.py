"""The fit through the domain's price: the evaluation stage and the whole bind, this code against another revision's.

    PYTHONPATH=. .venv/bin/python bench/reach_speed.py --baseline NAME=DIR [--baseline NAME=DIR ...]
                            [--scenes hand,arm,smpl,figure,gargoyle] [--rounds 3] [--cache /tmp/reach_scenes]
                            [--data DIR]

Each DIR holds a baseline's source (``git archive REV | tar -x -C DIR``); this checkout is "after". Each scene's points and cage are written once
to ``--cache`` (the gargoyle subdivided through bpy, as the demo does); then every (round, scene, variant) binds in a
process of its own, the variants interleaved, at the defaults (``lbc_core.bind``), and prints the reduction stage's
seconds (``Binding.timings``: the evaluation) and the whole bind's, in wall-clock and in CPU seconds (the process's, all
threads: less sensitive to the machine's load). Medians per scene and variant, the load, and
each baseline's weights' largest difference from this code's are printed at the end.

Scenes: ``hand``, ``arm`` (tests/data/cages-3d), ``smpl`` (Neural Cages' SMPL body in --data, not in the repository),
``figure`` (bench/figure.py), ``gargoyle`` (the demo's: the mesh Catmull-Clark subdivided twice, 64,130 points, cage
L10).
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "cages-3d"
sys.path.insert(0, str(ROOT))
from bench.public_data import public_data  # noqa: E402

CHILD = """
import json, sys, time
import numpy as np
import scipy.sparse as sp
import lbc_core
from lbc_core.binding.record import pipeline
cpu = []
evaluate = pipeline.evaluate
def timed(*args, **kwargs):
    start = time.process_time()
    try:
        return evaluate(*args, **kwargs)
    finally:
        cpu.append(time.process_time() - start)
pipeline.evaluate = timed
scene = np.load(sys.argv[1], allow_pickle=True)
faces = [list(face) for face in scene["faces"]]
start, start_cpu = time.perf_counter(), time.process_time()
binding = lbc_core.bind(scene["cage"], faces, scene["points"])
seconds, seconds_cpu = time.perf_counter() - start, time.process_time() - start_cpu
sp.save_npz(sys.argv[2], sp.csr_matrix(binding.weights))
print(json.dumps({"bind": seconds, "evaluation": binding.timings["reduction"], "bind cpu": seconds_cpu,
                  "evaluation cpu": sum(cpu), "timings": binding.timings}))
"""


def scene_arrays(name, data):
    """(points, cage vertices, cage faces) of a scene."""
    sys.path.insert(0, str(ROOT))
    from lbc_core.io import read_mesh

    if name in ("hand", "arm"):
        return (np.asarray(read_mesh(DATA / name / "mesh.obj")[0]), *read_mesh(DATA / name / "cage.obj")[:2])
    if name == "smpl":
        if data is None:
            raise SystemExit("the smpl scene needs the public pairs: see bench/public-data.md, then set "
                             "LBC_PUBLIC_DATA or pass --data")
        return (np.asarray(read_mesh(data / "smpl_neuralcage" / "mesh.ply")[0]),
                *read_mesh(data / "smpl_neuralcage" / "cage.obj")[:2])
    if name == "figure":
        from bench import figure

        mesh, _, cage, cage_faces, _ = figure.figure()
        return mesh, cage, cage_faces
    if name == "gargoyle":
        from bench.rebinding import gargoyle_64k

        return (gargoyle_64k(), *read_mesh(DATA / "gargoyle" / "cage_L10.obj")[:2])
    raise ValueError(f"unknown scene {name!r}")


def cached(name, cache, data):
    """The scene's file in ``cache``, written by a process of its own the first time (bpy for the gargoyle)."""
    path = cache / f"{name}.npz"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        folder = str(data) if data is not None else None
        code = (f"import sys; sys.path.insert(0, {str(ROOT)!r}); from pathlib import Path; import numpy as np; "
                f"from bench.reach_speed import scene_arrays; p, c, f = scene_arrays({name!r}, {folder!r} and Path({folder!r})); "
                f"np.savez({str(path)!r}, points=np.asarray(p, float), cage=np.asarray(c, float), "
                f"faces=np.array([list(x) for x in f], dtype=object)); import os; os._exit(0)")
        subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
    return path


def run(source, scene_file, weights_file):
    """One bind in a process of its own with ``source``'s lbc_core: its figures."""
    environment = dict(os.environ, PYTHONPATH=str(source))
    done = subprocess.run([sys.executable, "-c", CHILD, str(scene_file), str(weights_file)], check=True,
                          capture_output=True, text=True, env=environment, cwd=source)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", action="append", required=True, help="NAME=DIR")
    parser.add_argument("--scenes", default="hand,arm,smpl,figure,gargoyle")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/reach_scenes"))
    parser.add_argument("--data", type=Path, default=public_data(),
                        help="the public pairs of bench/public-data.md (default: $LBC_PUBLIC_DATA)")
    args = parser.parse_args(argv)
    scenes = args.scenes.split(",")
    files = {name: cached(name, args.cache, args.data) for name in scenes}
    variants = dict((text.split("=", 1)[0], Path(text.split("=", 1)[1])) for text in args.baseline)
    variants["after"] = ROOT
    found = {(name, variant): [] for name in scenes for variant in variants}
    loads = []
    for round_ in range(args.rounds):
        for name in scenes:
            for variant, source in (list(variants.items())[::1 if round_ % 2 == 0 else -1]):
                loads.append(os.getloadavg()[0])
                figures = run(source, files[name], args.cache / f"{name}-{variant}.npz")
                found[name, variant].append(figures)
                print(f"round {round_} {name} {variant}: evaluation {figures['evaluation']:.2f} s "
                      f"({figures['evaluation cpu']:.2f} CPU), bind {figures['bind']:.2f} s "
                      f"({figures['bind cpu']:.2f} CPU), load {loads[-1]:.1f}", flush=True)
    report(found, scenes, list(variants), args.cache, loads, args.rounds)


def report(found, scenes, names, cache, loads, rounds):
    """The medians per scene and variant as a markdown table, and the weights' largest differences."""
    print(f"\nload (1 min) {min(loads):.1f}-{max(loads):.1f}; medians of {rounds}, seconds (CPU seconds)")
    print("| scene | " + " | ".join(f"evaluation {name}" for name in names) + " | "
          + " | ".join(f"bind {name}" for name in names) + " | weights: largest difference from after |")
    print("| --- " * (2 * len(names) + 2) + "|")
    for name in scenes:
        def median(variant, key):
            return float(np.median([figures[key] for figures in found[name, variant]]))
        after = sp.load_npz(cache / f"{name}-after.npz")
        differences = []
        for variant in names[:-1]:
            other = sp.load_npz(cache / f"{name}-{variant}.npz")
            differences.append(f"{variant} {abs(other - after).max():.1e}" if other.shape == after.shape else "?")
        cells = [f"{median(v, key):.2f} ({median(v, key + ' cpu'):.2f})" for key in ("evaluation", "bind") for v in names]
        print(f"| {name} | " + " | ".join(cells) + " | " + ", ".join(differences) + " |")


if __name__ == "__main__":
    main()
