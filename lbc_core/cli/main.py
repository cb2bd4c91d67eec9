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
import os
import sys

from ..binding.options import DEFAULT_CELLS, WEIGHTINGS
from ..errors import CageError, Cancelled
from ..evaluate.evaluators import EVALUATORS
from ..evaluate.smoothing import DEFAULT_SMOOTHNESS
from ..meshing import MESHERS, method_names
from ..version import __version__
from .commands import bind_options, run_bind, run_cage, run_compare, run_deform, run_stats, run_table1

SCHEMES = ("lbc", "mvc", "harmonic", "bbw")
EXIT_BAD_INPUT = 2
EXIT_CANCELLED = 130




def main(argv=None):
    """Run the command line; returns the exit code (0, 2 on bad input, 130 when cancelled)."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        if hasattr(args, "cells"):  # a command that binds: its options are checked before any file is read
            args.options = bind_options(args)
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
    solving.add_argument("--evaluation", choices=tuple(EVALUATORS), help="how the weights are read at the points: "
                         "smooth (the default) or linear (the paper's piecewise-linear interpolation)")
    return solving


def _parser():
    parser = argparse.ArgumentParser(prog="lbc", description="Local Barycentric Coordinates for cage deformation.")
    parser.add_argument("--version", action="version", version=f"lbc {__version__}")
    commands = parser.add_subparsers(required=True, metavar="COMMAND")

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quiet", action="store_true", help="no progress or warnings on stderr (bind and cage list "
                        "their warnings in --json)")
    common.add_argument("--json", action="store_true", help="print the figures as JSON on stdout")

    solving = _solving_options()

    bind = commands.add_parser("bind", parents=[common, solving], help="bind a mesh to a cage, save the binding")
    bind.add_argument("cage", help="cage file (.obj/.off/.ply); a file without faces is a 2D polygon")
    bind.add_argument("mesh", help="mesh or point file whose vertices are bound")
    bind.add_argument("-o", "--output", required=True, help="binding file to write (.npz)")
    bind.add_argument("--scheme", default="lbc", choices=SCHEMES, help="coordinates to use (default lbc)")
    bind.set_defaults(command=run_bind)

    deform = commands.add_parser("deform", parents=[common], help="deform a bound mesh with a posed cage")
    deform.add_argument("binding", help="binding file from `lbc bind`")
    deform.add_argument("new_cage", help="the cage in its new pose (same vertices and faces as bound)")
    deform.add_argument("-o", "--output", required=True, help="deformed mesh to write (.obj/.off/.ply)")
    deform.add_argument("--mesh", help="the bound mesh, whose faces the output keeps (else points only)")
    deform.add_argument("--plot", help="2D only: figure of the domain before and after, with a checkerboard")
    deform.set_defaults(command=run_deform)

    stats = commands.add_parser("stats", parents=[common], help="locality figures of a binding",
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=STATS_COLUMNS)
    stats.add_argument("binding", help="binding file from `lbc bind`")
    stats.add_argument("--plot", help="figure of P(t) and Q(k) (.png/.svg)")
    stats.add_argument(
        "--coordinate", nargs=2, metavar=("INDEX", "PATH"), help="2D only: figure of one coordinate function"
    )
    stats.set_defaults(command=run_stats)

    compare = commands.add_parser("compare", parents=[common, solving], help="compare schemes on one cage")
    compare.add_argument("cage", help="cage file")
    compare.add_argument("mesh", nargs="?", help="mesh or point file (default: the domain mesh's vertices)")
    compare.add_argument("--schemes", default="lbc,mvc,harmonic", type=_scheme_list, help="comma-separated")
    compare.add_argument("--plot", help="figure of P(t) and Q(k) for every scheme (.png/.svg)")
    compare.set_defaults(command=run_compare)

    table1 = commands.add_parser(
        "table1", parents=[common, solving], help="Table 1: memory and deform time of reduced LBC vs dense MVC"
    )
    table1.add_argument(
        "data", nargs="*", help="folders searched for mesh.* with cage*.* beside it (default: the test data)"
    )
    table1.add_argument("--pair", nargs=2, action="append", default=[], metavar=("CAGE", "MESH"), help="a pair")
    table1.add_argument("--min-control", type=int, default=0, help="skip cages with fewer control points")
    table1.add_argument("--max-control", type=int, default=None, help="skip cages with more control points")
    table1.set_defaults(command=run_table1)
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
    cage.set_defaults(command=run_cage)
    return parser


def _scheme_list(text):
    schemes = [s.strip().lower() for s in text.split(",") if s.strip()]
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown or not schemes:
        raise argparse.ArgumentTypeError(f"unknown scheme(s) {', '.join(unknown)}: choose from {', '.join(SCHEMES)}")
    return schemes


def _meshers():
    """The meshers' names for --help: which dimensions each meshes, and which are not bundled."""
    told = ["auto (the default: lbc's own)"]
    for name in method_names()[1:]:
        found = [MESHERS[dim][name] for dim in (2, 3) if name in MESHERS[dim]]
        unbundled = "" if all(m.bundled for m in found) else ", installed apart"
        told.append(f"{name} ({', '.join(f'{m.dim}D' for m in found)}{unbundled})")
    return ", ".join(told)


