"""Does the locality solver deform as the dense solver of 5715f72 did, within what remeshing alone changes?

Binds the gargoyle's mesh to its cages with this tree and with a baseline tree (5715f72, the last release of the
dense solver), each twice: on the cage as it is (mesh A) and on the cage and points rotated rigidly (mesh B: the
same density, other cells; the deformation is rotated back). Both deform under the same bend of the cage, through
their domain weights interpolated linearly in their cells (the steps after the solve, which changed since, left
out). Prints,
as RMS and largest point displacement over the cage's diagonal:

- solver: this tree's deformation against the baseline's, same mesh (A), the baseline run to its default tolerance
  or to ``--tight``;
- remeshing: the baseline's deformation on mesh B against mesh A.

The locality solver passes where "solver" is at most half of "remeshing".

    .venv/bin/python bench/solver_agreement.py --baseline DIR [--cages L12 L10 L08] [--cells N] [--tight 1e-5]

DIR: e.g. ``git archive 5715f72 | tar -x -C out/baseline-5715f72``.
"""

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
# The rigid rotation that remeshes: 23° about a skew axis.
ROTATION_DEGREES, ROTATION_AXIS = 23.0, (0.3, 0.8, 0.52)


def rotation():
    axis = np.asarray(ROTATION_AXIS) / np.linalg.norm(ROTATION_AXIS)
    angle = np.radians(ROTATION_DEGREES)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def bent(cage):
    """The cage bent about its long axis: each vertex turned by an angle that grows with its height."""
    low, high = cage.min(axis=0), cage.max(axis=0)
    axis = int(np.argmax(high - low))
    height = (cage[:, axis] - low[axis]) / (high[axis] - low[axis])
    angle = np.radians(35.0) * height ** 2
    centre = (low + high) / 2
    other = (axis + 1) % 3
    out = cage.copy()
    offset_a, offset_o = cage[:, axis] - low[axis], cage[:, other] - centre[other]
    out[:, axis] = low[axis] + np.cos(angle) * offset_a - np.sin(angle) * offset_o
    out[:, other] = centre[other] + np.sin(angle) * offset_a + np.cos(angle) * offset_o
    return out


def deformed(tree, cage_path, cells, rotate, tolerance=None, smooth=False):
    """The gargoyle's points deformed by the bent cage through ``tree``'s domain weights (its solver, in a child
    process), interpolated linearly in their cells by this tree (so that only the solver and the mesh differ)."""
    from lbc_core.evaluate.interpolation import interpolation_matrix
    from lbc_core.io import read_cage, read_mesh
    from lbc_core.binding.pipeline import REPRODUCTION_TOLERANCE
    from lbc_core.evaluate.reduction import interpolate_and_reduce
    from lbc_core.evaluate.smoothing import SmoothInterpolation

    # The baseline's binds are kept between runs (out/agreement/): it does not change.
    baseline = Path(tree).resolve() != ROOT
    name = f"{Path(tree).name}-{cage_path.stem}-{cells}-{rotate}-{tolerance}.npz" if baseline else f"{os.getpid()}.npz"
    out = ROOT / "out" / "agreement" / name
    out.parent.mkdir(parents=True, exist_ok=True)
    script = f"""
import sys, json, numpy as np
sys.path.insert(0, {str(tree)!r})
sys.path.insert(0, {str(ROOT / 'bench')!r})
import lbc_core
assert lbc_core.__file__.startswith({str(tree)!r}), lbc_core.__file__
from lbc_core.io import read_cage, read_mesh
from solver_agreement import bent, rotation
cage, faces = read_cage({str(cage_path)!r})
points, _ = read_mesh({str(GARGOYLE / 'mesh.off')!r})
cage, points = np.asarray(cage, float), np.asarray(points, float)
posed = bent(cage)
if {rotate!r}:
    turn = rotation()
    cage, points, posed = cage @ turn.T, points @ turn.T, posed @ turn.T
binding = lbc_core.bind(cage, faces, points, cells={cells!r}, tolerance={tolerance!r})
domain = binding.domain
np.savez({str(out)!r}, vertices=domain.vertices, cells=domain.cells, weights=binding.domain_weights)
"""
    if not (baseline and out.exists()):
        subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                       env=dict(os.environ, PYTHONPATH=""))
    result = dict(np.load(out))
    if not baseline:
        os.remove(out)
    cage, _ = read_cage(cage_path)
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    cage, points = np.asarray(cage, float), np.asarray(points, float)
    posed, turn = bent(cage), rotation()
    if rotate:
        points, posed = points @ turn.T, posed @ turn.T
    located = interpolation_matrix(result["vertices"], result["cells"], points)[0]
    if smooth:  # this tree's evaluation at the points: the smooth fit, reduced at threshold 0
        fit = SmoothInterpolation(result["vertices"], result["cells"], located)
        diagonal = np.linalg.norm(cage.max(axis=0) - cage.min(axis=0))
        located = interpolate_and_reduce(fit, result["weights"], cage @ turn.T if rotate else cage,
                                         result["vertices"], 0.0, REPRODUCTION_TOLERANCE * diagonal)
    moved = located @ (result["weights"] @ posed) if not smooth else located @ posed
    return (moved @ turn if rotate else moved), len(result["cells"])


def gap(a, b, diagonal):
    distances = np.linalg.norm(a - b, axis=1) / diagonal
    return float(np.sqrt(np.mean(distances ** 2))), float(distances.max())


def main(argv=None):
    from lbc_core.io import read_cage

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of 5715f72")
    parser.add_argument("--cages", nargs="+", default=["L12", "L10", "L08"])
    parser.add_argument("--cells", type=int, default=None, help="domain cells (default: lbc_core's)")
    parser.add_argument("--tight", type=float, default=None,
                        help="run the baseline to this tolerance (e.g. 1e-5) instead of its default")
    parser.add_argument("--smooth", action="store_true",
                        help="evaluate at the points with this tree's smooth fit, not linearly in the cells")
    parser.add_argument("--ours", type=float, default=None, help="run this tree to this tolerance, not its default")
    args = parser.parse_args(argv)
    print("| cage | cells | solver RMS / max | remeshing RMS / max | solver / remeshing (RMS) |")
    print("| --- | --- | --- | --- | --- |")
    for name in args.cages:
        cage_path = GARGOYLE / f"cage_{name}.obj"
        cage = np.asarray(read_cage(cage_path)[0], dtype=float)
        diagonal = float(np.linalg.norm(cage.max(axis=0) - cage.min(axis=0)))
        ours, cells = deformed(ROOT, cage_path, args.cells, False, args.ours, args.smooth)
        theirs, _ = deformed(args.baseline, cage_path, args.cells, False, args.tight, args.smooth)
        theirs_b, _ = deformed(args.baseline, cage_path, args.cells, True, args.tight, args.smooth)
        solver, remeshing = gap(ours, theirs, diagonal), gap(theirs_b, theirs, diagonal)
        print(f"| {name} | {cells} | {solver[0]:.2e} / {solver[1]:.2e} | {remeshing[0]:.2e} / {remeshing[1]:.2e} "
              f"| {solver[0] / remeshing[0]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
