"""The ``lbc`` command line: bind, deform, inspect and compare coordinates from scripts and pipelines.

    lbc bind CAGE MESH -o binding.npz [--scheme lbc|mvc|harmonic|bbw] [--cells N] [--weighting W] [--epsilon E]
             [--threshold T] [--tolerance T] [--max-iterations N]
    lbc deform binding.npz NEW_CAGE -o deformed.obj [--mesh MESH] [--plot before_after.png]
    lbc stats binding.npz [--plot pq.png] [--coordinate INDEX coordinate.png]
    lbc compare CAGE [MESH] --schemes lbc,mvc,harmonic [--plot pq.png]
    lbc table1 [DATA ...] [--pair CAGE MESH] [--min-control N] [--max-control N]
    lbc cage MESH -o CAGE.obj [--vertices N] [--margin M]

Every command takes --quiet (no progress or warnings on stderr) and --json (figures as JSON on stdout). Bad input
(unreadable files, invalid cages, points that do not fit the cage) exits with code 2 and one line on stderr; a
cancelled run (Ctrl-C) exits with 130.
"""

import argparse
import json
import os
import shutil
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

from .binding.options import DEFAULT_CELLS, WEIGHTINGS, BindOptions
from .errors import CageError, Cancelled
from .evaluate.smoothing import DEFAULT_SMOOTHNESS
from .meshing import MESHERS, method_names
from .version import __version__

SCHEMES = ("lbc", "mvc", "harmonic", "bbw")
EXIT_BAD_INPUT = 2
EXIT_CANCELLED = 130
DEFAULT_TABLE1_DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "cages-3d"


def main(argv=None):
    """Run the command line; returns the exit code (0, 2 on bad input, 130 when cancelled)."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        if hasattr(args, "cells"):  # a command that binds: its options are checked before any file is read
            args.options = _options(args)
        return args.command(args) or 0
    except CageError as error:
        print(f"lbc: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (Cancelled, KeyboardInterrupt):
        print("lbc: cancelled", file=sys.stderr)
        return EXIT_CANCELLED
    except BrokenPipeError:  # stdout's reader stopped reading (`lbc stats b.npz --json | head`): nothing to add
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # so that the exit's flush cannot fail again
        return 1


# What `lbc stats` prints, told by its --help.
STATS_COLUMNS = """The columns (the paper's Section 5, n control points):
  P(1e-3/n)  the mean share of the domain where a coordinate is at most 1e-3/n: near 1 is local
  Q(4), Q(8) the share of the domain where at least 4 (8) coordinates exceed 1e-3/n: near 0 is local"""


def _solving_options():
    """The options of a bind, shared by the commands that bind (a parent parser)."""
    solving = argparse.ArgumentParser(add_help=False)
    solving.add_argument("--cells", type=int, help="about how many domain triangles / tetrahedra (default: "
                         f"{DEFAULT_CELLS[2]} in 2D, {DEFAULT_CELLS[3]} in 3D)")
    solving.add_argument("--weighting", choices=WEIGHTINGS, help=f"LBC's TV weighting (default {WEIGHTINGS[0]})")
    solving.add_argument("--epsilon", type=float, help="LBC's C1 relaxation width (default 0: plain TV)")
    solving.add_argument("--threshold", type=float, help="LBC's reduction threshold (default 1e-3/n)")
    solving.add_argument("--tolerance", type=float, help="LBC's ADMM stopping tolerance (default: the solver's)")
    solving.add_argument("--max-iterations", type=int, help="LBC's ADMM iteration limit (default 10000)")
    solving.add_argument("--method", choices=method_names(), help=f"the mesher that fills the cage: {_meshers()}")
    solving.add_argument("--smoothness", type=float, help="smooth ↔ local in [0, 1]: 1 folds bent joints least, 0 "
                         f"gives each point the fewest influences (default {DEFAULT_SMOOTHNESS:g})")
    return solving


def _parser():
    parser = argparse.ArgumentParser(prog="lbc", description="Local Barycentric Coordinates for cage deformation.")
    parser.add_argument("--version", action="version", version=f"lbc {__version__}")
    commands = parser.add_subparsers(required=True, metavar="COMMAND")

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quiet", action="store_true", help="no progress or warnings on stderr (--json lists the "
                        "cage's warnings)")
    common.add_argument("--json", action="store_true", help="print the figures as JSON on stdout")

    solving = _solving_options()

    bind = commands.add_parser("bind", parents=[common, solving], help="bind a mesh to a cage, save the binding")
    bind.add_argument("cage", help="cage file (.obj/.off/.ply); a file without faces is a 2D polygon")
    bind.add_argument("mesh", help="mesh or point file whose vertices are bound")
    bind.add_argument("-o", "--output", required=True, help="binding file to write (.npz)")
    bind.add_argument("--scheme", default="lbc", choices=SCHEMES, help="coordinates to use (default lbc)")
    bind.set_defaults(command=_run_bind)

    deform = commands.add_parser("deform", parents=[common], help="deform a bound mesh with a posed cage")
    deform.add_argument("binding", help="binding file from `lbc bind`")
    deform.add_argument("new_cage", help="the cage in its new pose (same vertices and faces as bound)")
    deform.add_argument("-o", "--output", required=True, help="deformed mesh to write (.obj/.off/.ply)")
    deform.add_argument("--mesh", help="the bound mesh, whose faces the output keeps (else points only)")
    deform.add_argument("--plot", help="2D only: figure of the domain before and after, with a checkerboard")
    deform.set_defaults(command=_run_deform)

    stats = commands.add_parser("stats", parents=[common], help="locality figures of a binding",
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=STATS_COLUMNS)
    stats.add_argument("binding", help="binding file from `lbc bind`")
    stats.add_argument("--plot", help="figure of P(t) and Q(k) (.png/.svg)")
    stats.add_argument(
        "--coordinate", nargs=2, metavar=("INDEX", "PATH"), help="2D only: figure of one coordinate function"
    )
    stats.set_defaults(command=_run_stats)

    compare = commands.add_parser("compare", parents=[common, solving], help="compare schemes on one cage")
    compare.add_argument("cage", help="cage file")
    compare.add_argument("mesh", nargs="?", help="mesh or point file (default: the domain mesh's vertices)")
    compare.add_argument("--schemes", default="lbc,mvc,harmonic", type=_scheme_list, help="comma-separated")
    compare.add_argument("--plot", help="figure of P(t) and Q(k) for every scheme (.png/.svg)")
    compare.set_defaults(command=_run_compare)

    table1 = commands.add_parser(
        "table1", parents=[common, solving], help="Table 1: memory and deform time of reduced LBC vs dense MVC"
    )
    table1.add_argument(
        "data", nargs="*", help="folders searched for mesh.* with cage*.* beside it (default: the test data)"
    )
    table1.add_argument("--pair", nargs=2, action="append", default=[], metavar=("CAGE", "MESH"), help="a pair")
    table1.add_argument("--min-control", type=int, default=0, help="skip cages with fewer control points")
    table1.add_argument("--max-control", type=int, default=None, help="skip cages with more control points")
    table1.set_defaults(command=_run_table1)
    return _add_cage_command(parser, commands, common)


def _add_cage_command(parser, commands, common):
    cage = commands.add_parser("cage", parents=[common], help="make a cage around a mesh (closed, enclosing, "
                               "checked by lbc)")
    cage.add_argument("mesh", help="mesh file (.obj/.off/.ply): open, multi-part and non-manifold meshes are fine")
    cage.add_argument("-o", "--output", required=True, help="cage file to write (.obj/.off/.ply)")
    cage.add_argument("--vertices", type=int, help="the cage's vertex count, met within 15 %% (default: chosen "
                      "for the mesh)")
    cage.add_argument("--margin", type=float, help="space between mesh and cage, a share of the mesh's "
                      "bounding-box diagonal (default 0.01)")
    cage.add_argument("--symmetry", choices=("x", "y", "z"), help="make the cage mirror-symmetric about the plane "
                      "normal to this axis through the middle of the mesh's bounding box (for X-mirror editing)")
    cage.add_argument("--triangles", action="store_true", help="triangles only (default: pairs of triangles that "
                      "make good quads merged)")
    cage.set_defaults(command=_run_cage)
    return parser


def _scheme_list(text):
    schemes = [s.strip().lower() for s in text.split(",") if s.strip()]
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown or not schemes:
        raise argparse.ArgumentTypeError(f"unknown scheme(s) {', '.join(unknown)}: choose from {', '.join(SCHEMES)}")
    return schemes


# Commands -------------------------------------------------------------------------------------------------------


def _run_bind(args):
    from .binding.pipeline import too_small_warning
    from .cage import make_cage
    from .io import FORMATS, check_output

    check_output(args.output, inputs=(args.cage, args.mesh))
    output = Path(args.output)
    if output.suffix.lower() in FORMATS:  # any other name is the user's choice; a mesh's suffix is a mistake
        raise CageError(f"{output}: bind writes a binding (an .npz archive), not a mesh; name it "
                        f"{output.with_suffix('.npz')}, then `lbc deform {output.with_suffix('.npz').name} NEW_CAGE "
                        f"--mesh {args.mesh} -o deformed{output.suffix}` writes the deformed mesh")
    cage_vertices, cage_faces, points = _read_inputs(args.cage, args.mesh)
    try:
        cage = make_cage(cage_vertices, cage_faces)
    except CageError as error:
        if len(cage_vertices) > len(points):  # most often the two files given the wrong way round
            raise CageError(f"{args.cage} is the cage here but has more vertices than {args.mesh} "
                            f"({len(cage_vertices)} against {len(points)}): were they swapped? The cage comes first "
                            f"(lbc bind CAGE MESH). As a cage, it is refused: {error}") from None
        raise
    _warn(cage.warnings, args.quiet)  # repairs are told before the long work
    with _Progress(f"bind ({args.scheme})", args.quiet) as progress:
        binding = _bind(args.scheme, cage_vertices, cage_faces, points, args, progress)
    binding.save(args.output)
    nonzeros = binding.weights.nnz / max(binding.weights.shape[0], 1)
    figures = {
        "output": str(args.output),
        "scheme": binding.scheme,
        "control_points": int(binding.weights.shape[1]),
        "points": int(binding.weights.shape[0]),
        "outside": int(np.count_nonzero(binding.outside)),
        "nonzeros_per_point": float(nonzeros),
        "timings": {stage: float(seconds) for stage, seconds in binding.timings.items()},
        "iterations": binding.iterations,
        "converged": binding.converged,
        "warnings": list(binding.cage.warnings),
    }
    late = [too_small_warning(figures["outside"], figures["points"])]
    if not binding.converged:  # a new user's --json said only "converged": false, and --quiet still printed it
        late.append(f"not converged: the solve stopped after {binding.iterations} iterations above its tolerance; "
                    "the coordinates are usable but less local (raise --max-iterations, or a larger --tolerance "
                    "stops sooner)")
    late = [warning for warning in late if warning]
    figures["warnings"] += late
    _warn(late, args.quiet)
    if args.json:
        _print_json(figures)
    else:
        total = sum(binding.timings.values())
        outside = figures["outside"]
        print(
            f"bound {figures['points']} points to {figures['control_points']} control points with {binding.scheme}: "
            f"{nonzeros:.2f} stored weights per point, {outside} points outside the cage"
            f"{' (extrapolated from the closest points inside)' if outside else ''}, {total:.2f} s; wrote {args.output}"
        )
    return 0


def _run_cage(args):
    from .cage_generator import generate_cage
    from .io import FORMATS, check_output, read_mesh, write_mesh

    check_output(args.output, FORMATS, (args.mesh,))
    vertices, faces = read_mesh(args.mesh)
    with _Progress("cage", args.quiet) as progress:
        started = time.perf_counter()
        made = generate_cage(vertices, faces, n_vertices=args.vertices, margin=args.margin, symmetry=args.symmetry,
                             quads=not args.triangles, progress=progress)
        seconds = time.perf_counter() - started
    write_mesh(args.output, made.vertices, made.faces)
    figures = {"output": str(args.output), "vertices": made.vertex_count, "asked_vertices": made.asked_vertices,
               "faces": int(len(made.faces)), "quads": int(sum(len(face) == 4 for face in made.faces)),
               "symmetry": made.symmetry, "mirror_error": made.mirror_error, "volume": made.volume,
               "clearance": made.clearance, "mean_distance": made.mean_distance, "margin": made.margin, "attempts": made.attempts,
               "seconds": seconds, "warnings": list(made.warnings)}
    _warn(made.warnings, args.quiet)
    if args.json:
        _print_json(figures)
    else:
        mirrored = f", mirror-symmetric in {made.symmetry}" if made.symmetry else ""
        print(f"made a cage of {made.vertex_count} vertices and {len(made.faces)} faces ({figures['quads']} quads"
              f"{mirrored}) around {len(vertices)} vertices, about {made.clearance:.4g} to {made.mean_distance:.4g} from the mesh, in {seconds:.2f} s; "
              f"wrote {args.output}")
    return 0


def _run_deform(args):
    from .binding.files import load_binding
    from .io import FORMATS, check_output, planar, read_mesh, write_mesh, write_posed_obj

    inputs = (args.binding, args.new_cage, args.mesh)
    check_output(args.output, FORMATS, inputs)
    if args.plot:
        _check_figure(args.plot, inputs + (args.output,))
    binding = load_binding(args.binding)
    _warn(binding.cage.warnings, args.quiet)
    _check_2d_figure(binding, args.plot, "--plot")
    new_vertices, new_faces = read_mesh(args.new_cage)
    try:
        # The count first: another cage's faces would be told as corners out of range.
        binding.cage.control_points_from_input(new_vertices)
        binding.cage.check_faces(new_faces)
    except CageError as error:
        raise CageError(f"{args.new_cage}: {error}") from None
    plane_z = None
    if binding.cage.dim == 2:
        plane_z = new_vertices[0, 2] if new_vertices.shape[1] == 3 else None
        new_vertices = planar(new_vertices, args.new_cage)
    faces = None
    if args.mesh:
        mesh_vertices, faces = read_mesh(args.mesh)
        if len(mesh_vertices) != binding.weights.shape[0]:
            raise CageError(
                f"{args.mesh} has {len(mesh_vertices)} vertices but the binding has {binding.weights.shape[0]} "
                "points: give the mesh that was bound"
            )
        if binding.cage.dim == 2 and mesh_vertices.shape[1] == 3 and len(mesh_vertices):
            planar(mesh_vertices, args.mesh)  # refuses a mesh that left its plane
            plane_z = mesh_vertices[0, 2]
    start = time.perf_counter()
    deformed = binding.deform(new_vertices)
    seconds = time.perf_counter() - start
    if plane_z is not None:  # 2D data in a plane z = constant stays in it (it came out at z = 0)
        deformed = np.column_stack([deformed, np.full(len(deformed), plane_z)])
    if args.mesh and Path(args.mesh).suffix.lower() == Path(args.output).suffix.lower() == ".obj":
        write_posed_obj(args.mesh, args.output, deformed)  # its UVs, groups and materials kept
    else:
        write_mesh(args.output, deformed, faces)
    if not args.mesh:  # a new user took the points-only file for a broken mesh
        _warn([f"{args.output} holds the deformed points only, no faces: give the bound mesh with --mesh MESH to "
               "keep its faces"], args.quiet)
    if args.plot:
        _plots().plot_deformation(binding, new_vertices, args.plot)
    figures = {"output": str(args.output), "points": int(len(deformed)), "deform_seconds": seconds}
    if args.json:
        _print_json(figures)
    else:
        print(f"deformed {len(deformed)} points in {seconds * 1e3:.2f} ms; wrote {args.output}")
    return 0


def _run_stats(args):
    from .binding.files import load_binding
    from .compare.statistics import summary

    for path in ([args.plot] if args.plot else []) + ([args.coordinate[1]] if args.coordinate else []):
        _check_figure(path, (args.binding,))
    binding = load_binding(args.binding)
    _check_2d_figure(binding, args.coordinate, "--coordinate")
    if args.coordinate:
        _control_index(args.coordinate[0], binding.weights.shape[1])
    figures = summary(binding)
    if args.plot:
        plots = _plots()
        plots.plot_locality({plots.LABELS.get(binding.scheme, binding.scheme): binding}, args.plot)
    if args.coordinate:
        index, path = args.coordinate
        _plots().plot_coordinate(binding, _control_index(index, binding.weights.shape[1]), path)
    if args.json:
        _print_json(figures)
    else:
        print(_table([figures], _SUMMARY_COLUMNS))
    return 0


def _run_compare(args):
    from .cage import make_cage
    from .meshing import mesh_domain

    if args.plot:
        # Before binding: matplotlib missing, an unknown format, a missing folder, an input.
        _check_figure(args.plot, (args.cage, args.mesh))
    cage_vertices, cage_faces, points = _read_inputs(args.cage, args.mesh)
    bindings, domain = {}, None
    if args.mesh:
        points_from = str(args.mesh)
    else:
        domain = mesh_domain(make_cage(cage_vertices, cage_faces), args.options.cells)
        points, points_from = domain.vertices, "the domain mesh's vertices"
    # LBC first: the baselines then share its domain mesh, so every scheme is measured on the same cells.
    for scheme in sorted(args.schemes, key=lambda s: s != "lbc"):
        with _Progress(f"bind ({scheme})", args.quiet) as progress:
            bindings[scheme] = _bind(scheme, cage_vertices, cage_faces, points, args, progress, domain=domain)
        domain = bindings[scheme].domain
    from .compare.statistics import summary

    rows = [summary(binding) for binding in bindings.values()]
    if args.plot:
        plots = _plots()
        plots.plot_locality({plots.LABELS.get(s, s): binding for s, binding in bindings.items()}, args.plot)
    if args.json:
        _print_json({"cage": str(args.cage), "points": points_from, "schemes": rows})
    else:
        first = rows[0]
        print(
            f"{args.cage}: {first['control_points']} control points; {first['points']} points ({points_from}); "
            f"domain {first['domain_vertices']} vertices, {first['domain_cells']} cells"
        )
        print(_table(rows, _SUMMARY_COLUMNS))
    return 0


def _run_table1(args):
    from .cage import make_cage
    from .compare.baselines import bind_mvc
    from .compare.statistics import table1_row

    pairs = [(Path(c), Path(m)) for c, m in args.pair] + _find_pairs(args.data or ([] if args.pair else None))
    rows = []
    for cage_path, mesh_path in pairs:
        cage_vertices, cage_faces, _ = _read_inputs(cage_path)
        n = make_cage(cage_vertices, cage_faces).n_control_points
        if n < args.min_control or (args.max_control is not None and n > args.max_control):
            continue
        points = _read_inputs(cage_path, mesh_path)[2]
        name = f"{cage_path.parent.name}/{cage_path.stem}"
        with _Progress(f"{name} (lbc)", args.quiet) as progress:
            lbc = _bind("lbc", cage_vertices, cage_faces, points, args, progress)
        mvc = bind_mvc(cage_vertices, cage_faces, points, domain=lbc.domain)
        rows.append({"model": name, **table1_row(lbc, mvc)})
    if not rows:
        raise CageError("no (cage, mesh) pair to measure: check the folders and the control point limits")
    if args.json:
        _print_json({"pairs": rows})
    else:
        print(_table(rows, _TABLE1_COLUMNS))
    return 0


# Helpers ----------------------------------------------------------------------------------------------------------


def _bind(scheme, cage_vertices, cage_faces, points, args, progress, domain=None):
    """One binding with the command's options; the baselines reuse ``domain`` when given."""
    if scheme == "lbc":
        from .binding.pipeline import bind

        return bind(cage_vertices, cage_faces, points, options=args.options, progress=progress)
    from .compare import baselines

    if scheme == "bbw" and not baselines.bbw_available():
        raise CageError("bounded biharmonic weights need libigl: pip install libigl")
    function = {"mvc": baselines.bind_mvc, "harmonic": baselines.bind_harmonic, "bbw": baselines.bind_bbw}[scheme]
    return function(cage_vertices, cage_faces, points, domain=domain, cells=args.options.cells, progress=progress)


def _meshers():
    """The meshers' names for --help: which dimensions each meshes, and which are not bundled."""
    told = ["auto (the default: lbc's own)"]
    for name in method_names()[1:]:
        found = [MESHERS[dim][name] for dim in (2, 3) if name in MESHERS[dim]]
        unbundled = "" if all(m.bundled for m in found) else ", installed apart"
        told.append(f"{name} ({', '.join(f'{m.dim}D' for m in found)}{unbundled})")
    return ", ".join(told)


def _options(args):
    """The bind options of the command's flags, checked (a bad value exits 2 before any file is read)."""
    return BindOptions(cells=args.cells, weighting=args.weighting, epsilon=args.epsilon, threshold=args.threshold,
                       tolerance=args.tolerance, max_iterations=args.max_iterations, method=args.method,
                       smoothness=args.smoothness)


def _read_inputs(cage_path, mesh_path=None):
    """A cage file and, if given, a mesh or point file, read for binding.

    Returns
    -------
    cage_vertices : (n, 3) or, for a polygon (a file without faces), (n, 2) float array
    cage_faces : list of int arrays, or None
    points : (m, 3) or, for a polygon cage, (m, 2) float array; None without ``mesh_path``

    A flat cage with faces whose mesh lies in its plane is returned as Blender binds it
    (:func:`lbc_core.cage.planar.flatten`): its outline as the polygon, the points in the plane's coordinates.

    Raises
    ------
    CageError
        Besides the files' own errors: 2D points in another plane z = constant than the polygon cage's.
    """
    from . import io
    from .cage.planar import flatten

    vertices, faces = io.read_mesh(cage_path)
    cage = vertices if faces is not None else io.planar(vertices, cage_path)
    if mesh_path is None:
        return cage, faces, None
    points, _ = io.read_mesh(mesh_path)
    if faces is not None:
        flat = flatten(cage, faces, points)
        return (cage, faces, points) if flat is None else (flat.polygon, None, flat.points)
    in_plane = io.planar(points, mesh_path)
    if abs(points[0, 2] - vertices[0, 2]) > 1e-9 * max(float(np.ptp(cage)), 1e-300):
        raise CageError(
            f"{mesh_path} lies in the plane z = {points[0, 2]:g} but the 2D cage {cage_path} in z = "
            f"{vertices[0, 2]:g}: move one into the other's plane"
        )
    return cage, faces, in_plane


def _plots():
    """The plots module; matplotlib is an optional dependency, so its absence is a one-line error."""
    try:
        from .compare import plots
    except ImportError:
        raise CageError("figures need matplotlib: pip install matplotlib") from None
    return plots


def _check_figure(path, inputs=()):
    """Refuse a figure path matplotlib cannot write (format, folder), or one of the command's ``inputs``, before any
    work is done."""
    from .io import check_output

    _plots()
    from matplotlib.backend_bases import FigureCanvasBase

    check_output(path, sorted("." + suffix for suffix in FigureCanvasBase.get_supported_filetypes()), inputs)


def _check_2d_figure(binding, wanted, option):
    """Refuse a 2D-only figure for a 3D binding, and a figure without matplotlib, before any work is done."""
    if wanted and binding.cage.dim != 2:
        raise CageError(f"{option} draws 2D bindings only; this binding is 3D")
    if wanted:
        _plots()


def _control_index(text, n):
    try:
        index = int(text)
    except ValueError:
        raise CageError(f"the coordinate index must be an integer, got {text!r}") from None
    if not 0 <= index < n:
        raise CageError(f"the coordinate index must be in 0 … {n - 1}, got {index}")
    return index


def _find_pairs(folders):
    """(cage, mesh) pairs in folders: each folder holding a mesh.* gives one pair per cage*.* beside it."""
    if folders is None:
        if not DEFAULT_TABLE1_DATA.is_dir():
            raise CageError("give the data folders (each with mesh.* and cage*.* files) or --pair CAGE MESH")
        folders = [DEFAULT_TABLE1_DATA]
    pairs = []
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise CageError(f"{folder}: not a folder")
        for mesh in sorted(p for p in folder.rglob("mesh.*") if p.suffix.lower() in (".obj", ".off", ".ply")):
            cages = sorted(
                p
                for p in mesh.parent.glob("cage*.*")
                if p.suffix.lower() in (".obj", ".off", ".ply") and "deformed" not in p.stem
            )
            pairs += [(cage, mesh) for cage in cages]
    return pairs


def _warn(warnings, quiet):
    if not quiet:
        for warning in warnings:
            print(f"lbc: warning: {warning}", file=sys.stderr)


def _print_json(figures):
    print(json.dumps(figures, indent=2, default=_json_default))


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


# (key, header, format) of the printed tables
_SUMMARY_COLUMNS = [
    ("scheme", "scheme", "{}"),
    ("influence_mean", "influence mean", "{:.2f}"),
    ("influence_max", "max", "{}"),
    ("P_tau", "P(1e-3/n)", "{:.3f}"),
    ("Q_4", "Q(4)", "{:.3f}"),
    ("Q_8", "Q(8)", "{:.3f}"),
    ("memory_bytes", "weights KB", "{:.1f}", 1e-3),
    ("deform_seconds", "deform µs", "{:.1f}", 1e6),
    ("time_total", "bind s", "{:.2f}"),
]
_TABLE1_COLUMNS = [
    ("model", "cage", "{}"),
    ("control_points", "n", "{}"),
    ("points", "points", "{}"),
    ("lbc_nonzeros_per_point", "LBC weights/pt", "{:.2f}"),
    ("lbc_bytes", "LBC KB", "{:.1f}", 1e-3),
    ("mvc_bytes", "MVC KB", "{:.1f}", 1e-3),
    ("memory_ratio", "memory", "{:.0%}"),
    ("lbc_seconds", "LBC µs", "{:.1f}", 1e6),
    ("mvc_seconds", "MVC µs", "{:.1f}", 1e6),
    ("time_ratio", "time", "{:.0%}"),
]


def _table(rows, columns):
    """Rows of figures as an aligned text table (numbers right-aligned)."""
    cells = [[header for _, header, *_ in columns]]
    for row in rows:
        row = dict(row, time_total=sum(v for k, v in row.items() if k.startswith("time_") and k != "time_total"))
        line = []
        for key, _, form, *scale in columns:
            value = row.get(key)
            line.append("-" if value is None else form.format(value * scale[0] if scale else value))
        cells.append(line)
    widths = [max(len(line[k]) for line in cells) for k in range(len(columns))]
    text = []
    for number, line in enumerate(cells):
        parts = [c.ljust(w) if k == 0 else c.rjust(w) for k, (c, w) in enumerate(zip(line, widths))]
        text.append("  ".join(parts))
        if number == 0:
            text.append("  ".join("-" * w for w in widths))
    return "\n".join(text)


BAR = 20  # characters of the progress bar: the message keeps most of an 80-column terminal


class _Progress:
    """A progress bar on stderr for a terminal, a line per tenth of the work otherwise (logs); nothing when quiet.

    Used as a context manager; the instance is the ``progress(fraction, message)`` callback.
    """

    def __init__(self, label, quiet):
        self.label = label
        self.enabled = not quiet
        self.tty = sys.stderr.isatty()
        # One line as wide as the terminal: a wider one wraps, and every redraw then scrolls a new line.
        self.width = shutil.get_terminal_size().columns - 1
        self.last_draw = 0.0
        self.last_tenth = -1
        self.start = time.perf_counter()

    def __call__(self, fraction, message):
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty:
            if fraction == 0.0 and len(message) > self.width // 2:
                # The forecast (memory and time) is told at 0: whole, on lines of its own, not cut to the bar's room.
                sys.stderr.write("\r" + " " * self.width + "\r" + textwrap.fill(message, self.width) + "\n")
            if now - self.last_draw < 0.1 and fraction < 1.0:
                return
            filled = int(round(BAR * min(max(fraction, 0.0), 1.0)))
            bar = "#" * filled + "-" * (BAR - filled)
            line = f"\r{self.label} [{bar}] {fraction:4.0%} {message}"[:self.width + 1]
            sys.stderr.write(line.ljust(self.width + 1))
            sys.stderr.flush()
            self.last_draw = now
        elif int(10 * fraction) > self.last_tenth:
            self.last_tenth = int(10 * fraction)
            sys.stderr.write(f"{self.label}: {fraction:4.0%} {message}\n")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if not self.enabled:
            return False
        if exc[0] is not None:  # the error message is the one line to read: only clear a drawn bar
            if self.tty:
                sys.stderr.write("\r" + " " * self.width + "\r")
            return False
        seconds = time.perf_counter() - self.start
        done = f"{self.label}: done in {seconds:.1f} s"
        sys.stderr.write(("\r" + done.ljust(self.width) if self.tty else done) + "\n")
        return False
