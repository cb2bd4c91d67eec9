"""What each ``lbc`` subcommand does once its flags are read: bind, cage, deform, stats, compare and table1, and the
files, options and checks they share.
"""

import time
from pathlib import Path

import numpy as np

from ..binding.options import BindOptions
from ..errors import CageError
from .output import SUMMARY_COLUMNS, ProgressBar, print_json, table, warn

DEFAULT_TABLE1_DATA = Path(__file__).resolve().parents[2] / "tests" / "data" / "cages-3d"
TABLE1_COLUMNS = [
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


def run_bind(args):
    from ..binding.pipeline import too_small_warning
    from ..cage import make_cage
    from ..io import FORMATS, check_output

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
    warn(cage.warnings, args.quiet)  # repairs are told before the long work
    with ProgressBar(f"bind ({args.scheme})", args.quiet) as progress:
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
    warn(late, args.quiet)
    if args.json:
        print_json(figures)
    else:
        total = sum(binding.timings.values())
        outside = figures["outside"]
        print(
            f"bound {figures['points']} points to {figures['control_points']} control points with {binding.scheme}: "
            f"{nonzeros:.2f} stored weights per point, {outside} points outside the cage"
            f"{' (extrapolated from the closest points inside)' if outside else ''}, {total:.2f} s; wrote {args.output}"
        )
    return 0


def run_cage(args):
    from ..cage_generator import generate_cage
    from ..io import FORMATS, check_output, read_mesh, write_mesh

    check_output(args.output, FORMATS, (args.mesh,))
    vertices, faces = read_mesh(args.mesh)
    with ProgressBar("cage", args.quiet) as progress:
        started = time.perf_counter()
        made = generate_cage(vertices, faces, n_vertices=args.vertices, margin=args.margin, symmetry=args.symmetry,
                             quads=not args.triangles, progress=progress)
        seconds = time.perf_counter() - started
    write_mesh(args.output, made.vertices, made.faces)
    figures = {"output": str(args.output), "vertices": made.vertex_count, "asked_vertices": made.asked_vertices,
               "faces": int(len(made.faces)), "quads": int(sum(len(face) == 4 for face in made.faces)),
               "symmetry": made.symmetry, "mirror_error": made.mirror_error, "volume": made.volume,
               "clearance": made.clearance, "mean_distance": made.mean_distance, "margin": made.margin,
               "attempts": made.attempts, "seconds": seconds, "warnings": list(made.warnings)}
    warn(made.warnings, args.quiet)
    if args.json:
        print_json(figures)
    else:
        mirrored = f", mirror-symmetric in {made.symmetry}" if made.symmetry else ""
        print(f"made a cage of {made.vertex_count} vertices and {len(made.faces)} faces ({figures['quads']} quads"
              f"{mirrored}) around {len(vertices)} vertices, about {made.clearance:.4g} to {made.mean_distance:.4g} "
              f"from the mesh, in {seconds:.2f} s; wrote {args.output}")
    return 0


def run_deform(args):
    from ..binding.files import load_binding
    from ..io import FORMATS, check_output, planar, read_mesh, write_mesh, write_posed_obj

    inputs = (args.binding, args.new_cage, args.mesh)
    check_output(args.output, FORMATS, inputs)
    if args.plot:
        _check_figure(args.plot, inputs + (args.output,))
    binding = load_binding(args.binding)
    warn(binding.cage.warnings, args.quiet)
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
        warn([f"{args.output} holds the deformed points only, no faces: give the bound mesh with --mesh MESH to "
               "keep its faces"], args.quiet)
    if args.plot:
        _plots().plot_deformation(binding, new_vertices, args.plot)
    figures = {"output": str(args.output), "points": int(len(deformed)), "deform_seconds": seconds}
    if args.json:
        print_json(figures)
    else:
        print(f"deformed {len(deformed)} points in {seconds * 1e3:.2f} ms; wrote {args.output}")
    return 0


def run_stats(args):
    from ..binding.files import load_binding
    from ..compare.statistics import summary

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
        print_json(figures)
    else:
        print(table([figures], SUMMARY_COLUMNS))
    return 0


def run_compare(args):
    from ..cage import make_cage
    from ..meshing import mesh_domain

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
        with ProgressBar(f"bind ({scheme})", args.quiet) as progress:
            bindings[scheme] = _bind(scheme, cage_vertices, cage_faces, points, args, progress, domain=domain)
        domain = bindings[scheme].domain
    from ..compare.statistics import summary

    rows = [summary(binding) for binding in bindings.values()]
    if args.plot:
        plots = _plots()
        plots.plot_locality({plots.LABELS.get(s, s): binding for s, binding in bindings.items()}, args.plot)
    if args.json:
        print_json({"cage": str(args.cage), "points": points_from, "schemes": rows})
    else:
        first = rows[0]
        print(
            f"{args.cage}: {first['control_points']} control points; {first['points']} points ({points_from}); "
            f"domain {first['domain_vertices']} vertices, {first['domain_cells']} cells"
        )
        print(table(rows, SUMMARY_COLUMNS))
    return 0


def run_table1(args):
    from ..cage import make_cage
    from ..compare.baselines import bind_mvc
    from ..compare.statistics import table1_row

    pairs = [(Path(c), Path(m)) for c, m in args.pair] + _find_pairs(args.data or ([] if args.pair else None))
    rows = []
    for cage_path, mesh_path in pairs:
        cage_vertices, cage_faces, _ = _read_inputs(cage_path)
        n = make_cage(cage_vertices, cage_faces).n_control_points
        if n < args.min_control or (args.max_control is not None and n > args.max_control):
            continue
        points = _read_inputs(cage_path, mesh_path)[2]
        name = f"{cage_path.parent.name}/{cage_path.stem}"
        with ProgressBar(f"{name} (lbc)", args.quiet) as progress:
            lbc = _bind("lbc", cage_vertices, cage_faces, points, args, progress)
        mvc = bind_mvc(cage_vertices, cage_faces, points, domain=lbc.domain)
        rows.append({"model": name, **table1_row(lbc, mvc)})
    if not rows:
        raise CageError("no (cage, mesh) pair to measure: check the folders and the control point limits")
    if args.json:
        print_json({"pairs": rows})
    else:
        print(table(rows, TABLE1_COLUMNS))
    return 0


def _bind(scheme, cage_vertices, cage_faces, points, args, progress, domain=None):
    """One binding with the command's options; the baselines reuse ``domain`` when given."""
    if scheme == "lbc":
        from ..binding.pipeline import bind

        return bind(cage_vertices, cage_faces, points, options=args.options, progress=progress)
    from ..compare import baselines

    if scheme == "bbw" and not baselines.bbw_available():
        raise CageError("bounded biharmonic weights need libigl: pip install libigl")
    function = {"mvc": baselines.bind_mvc, "harmonic": baselines.bind_harmonic, "bbw": baselines.bind_bbw}[scheme]
    return function(cage_vertices, cage_faces, points, domain=domain, cells=args.options.cells, progress=progress)


def bind_options(args):
    """The bind options of the command's flags, checked (a bad value exits 2 before any file is read)."""
    return BindOptions(cells=args.cells, weighting=args.weighting, epsilon=args.epsilon, threshold=args.threshold,
                       tolerance=args.tolerance, max_iterations=args.max_iterations, method=args.method,
                       smoothness=args.smoothness, evaluation=args.evaluation)


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
    from .. import io
    from ..cage.planar import flatten

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
        from ..compare import plots
    except ImportError:
        raise CageError("figures need matplotlib: pip install matplotlib") from None
    return plots


def _check_figure(path, inputs=()):
    """Refuse a figure path matplotlib cannot write (format, folder), or one of the command's ``inputs``, before any
    work is done."""
    from ..io import check_output

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
