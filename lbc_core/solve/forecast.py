"""What a solve will cost, told before it starts (memory, time) and while it runs (time left), and the stopping
tolerance that cost is measured at."""

import os
from dataclasses import dataclass

import numpy as np

from ..errors import CageError
from .stretch import Stretch

# Relative primal residual a solve stops at by default, per dimension (bench/RESULTS.md, "The stopping tolerance"),
# and for 3D cages of at most SMALL_CAGE control points, whose coordinates remeshing hardly changes (same section).
DEFAULT_TOLERANCE = {2: 1e-4, 3: 5e-4}
SMALL_CAGE, SMALL_CAGE_TOLERANCE = 12, 2e-4

# (cell, control point) pairs per cell at a solve's widest: PAIRS_SCALE[d] · n^PAIRS_POWER for n control points
# (bench/RESULTS.md, "Memory and the cost model").
PAIRS_SCALE, PAIRS_POWER = {2: 2.2, 3: 2.5}, 0.5
# A convex 3D cage (enclosing CONVEX_SHARE of its hull) spreads its coordinates wider: times the pairs (memory),
# times the iterations, and seconds per step and pair of every (cell, control point) (bench/RESULTS.md, "The forecast
# for convex cages", "The forecast recalibrated for small cages").
CONVEX_SHARE, WIDE_PAIRS, WIDE_ITERATIONS, WIDE_SECONDS_PER_PAIR_STEP = 0.95, 2.5, 2.6, 3.6e-8
# Peak bytes per pair (bench/RESULTS.md, "The locality solver, third round"), and per entry of the (cells, n) TV
# weights the caller holds.
BYTES_PER_PAIR = 620
# The dense splitting's peak bytes per (cell, control point): its state's entries, (d + 0.23) per pair in 3D, at 120
# bytes each (the last release's measured figure).
DENSE_BYTES_PER_PAIR = 390
BYTES_PER_WEIGHT = 8


def default_tolerance(dim, n_control_points):
    """The stopping tolerance of a solve that is given none: DEFAULT_TOLERANCE, tighter for a 3D cage of at most
    SMALL_CAGE control points.

    Parameters
    ----------
    dim, n_control_points : int

    Returns
    -------
    float, a relative primal residual
    """
    if dim == 3 and n_control_points <= SMALL_CAGE:
        return SMALL_CAGE_TOLERANCE
    return DEFAULT_TOLERANCE[dim]


def spreads_wide(n_control_points, dim, convexity):
    """Whether a cage's coordinates are expected to spread wider, over more iterations, than the gargoyle's cages the
    model was fitted to: a convex 3D cage of more than SMALL_CAGE control points (``convexity``:
    :attr:`Cage.convexity`; 0 when unknown)."""
    return dim == 3 and n_control_points > SMALL_CAGE and convexity >= CONVEX_SHARE


def estimate_memory(n_control_points, n_cells, dim, convexity=0.0):
    """Peak memory of a solve, estimated before it starts.

    Parameters
    ----------
    n_control_points : int
    n_cells : int
        Triangles (dim 2) or tetrahedra (dim 3).
    dim : int
    convexity : float
        :attr:`Cage.convexity` (0 when unknown).

    Returns
    -------
    int, bytes
    """
    if takes_dense_splitting(n_control_points, n_cells, dim, convexity):
        return int((DENSE_BYTES_PER_PAIR + BYTES_PER_WEIGHT) * n_control_points * n_cells)
    pairs = estimate_pairs(n_control_points, n_cells, dim, convexity)
    return int(BYTES_PER_PAIR * pairs + BYTES_PER_WEIGHT * n_control_points * n_cells)


def estimate_pairs(n_control_points, n_cells, dim, convexity=0.0):
    """The (cell, control point) pairs a solve holds at its widest, about."""
    pairs = PAIRS_SCALE[dim] * n_control_points ** PAIRS_POWER * n_cells
    if spreads_wide(n_control_points, dim, convexity):
        pairs = min(WIDE_PAIRS * pairs, n_control_points * n_cells)
    return pairs


# Seconds per iteration on a 2-core x86_64, the reshapes included: per cell and per (cell, control point) pair
# (bench/RESULTS.md, "The forecast recalibrated for small cages"); rough by design: the running solve tells its own
# time left.
SECONDS_PER_CELL_STEP, SECONDS_PER_PAIR_STEP = {2: 0.0, 3: 1.3e-6}, {2: 1.0e-7, 3: 4.25e-8}
# The dense splitting's seconds per iteration (3D, same machine): per (cell, control point) pair, and per pair and
# control point for its null-space basis's products (bench/RESULTS.md, "The splitting chosen by its cost").
DENSE_SECONDS_PER_PAIR_STEP, DENSE_SECONDS_PER_BASIS_STEP = 2.0e-8, 9e-11
# The dense splitting stops at these shares of the default tolerance from DENSE_TIGHTER_FROM control points and on
# convex cages (at the default: up to 0.39 % above the optimum); its iterations grow as share^-DENSE_ITERATIONS_POWER
# (bench/RESULTS.md, "The dense splitting's tolerance").
DENSE_TIGHTER_FROM, DENSE_TIGHTER_SHARE, DENSE_WIDE_TOLERANCE_SHARE, DENSE_ITERATIONS_POWER = 40, 0.6, 0.4, 0.45
# Iterations at the default tolerance: ITERATIONS_SCALE[d] · n^ITERATIONS_POWER[d] · (cells / 8000)^CELLS_POWER[d]
# (same section).
ITERATIONS_SCALE, ITERATIONS_POWER, CELLS_POWER = {2: 113, 3: 66}, {2: 0.3, 3: 0.18}, {2: 0.25, 3: 0.17}
# Seconds per cell of meshing on a 2-core x86_64: 0.03-0.6 s for ordinary cages at 8000 cells, 1.5 s for a hand
# whose fingers face each other across narrow gaps (bench/RESULTS.md, "Cages whose parts face each other across a
# narrow gap").
MESHING_SECONDS_PER_CELL = 5e-5
# Seconds per point for the work after the solve: smooth fit, reduction, thinning (bench/RESULTS.md, "The progress
# bar shared by the time told").
SECONDS_PER_POINT = 2e-5
# A stretched solve (a very thin cage): factor on the iterations and on each one's cost (bench/thin_cages.py).
STRETCHED_ITERATIONS, STRETCHED_STEP_COST = 2, 5
# Principal aspect from which a thin cage needs more iterations: 1 + log10(aspect / THIN_FROM_ASPECT) times as many
# (bench/RESULTS.md, "The forecast told before a solve, on thin cages").
THIN_FROM_ASPECT = 5


# From this busy factor on, the forecast says that the machine's load lengthens it.
BUSY_TOLD_FROM = 1.5


@dataclass
class BindSeconds:
    """A bind's time told before it starts, by stage: seconds at the machine's load now."""

    meshing: float
    solve: float
    points: float  # the work after the solve: the smooth fit, the reduction, the thinning


def bind_seconds(n_control_points, n_cells, dim, stretched=False, aspect=1.0, busy=1.0, n_points=0, convexity=0.0,
                 meshing_work=1.0):
    """The time of a bind's meshing, solve and points, told before it starts; the arguments as for
    :func:`solve_forecast`.

    Example
    -------
    >>> told = bind_seconds(67, 8000, 3, n_points=64130)
    >>> round(told.solve), round(told.points, 1)
    (2, 1.3)
    """
    if takes_dense_splitting(n_control_points, n_cells, dim, convexity):
        iterations = (forecast_iterations(n_control_points, dim, stretched, aspect, n_cells)
                      * dense_tolerance_share(n_control_points, dim, convexity) ** -DENSE_ITERATIONS_POWER)
        step = dense_step_seconds(n_control_points, n_cells)
    else:
        iterations = forecast_iterations(n_control_points, dim, stretched, aspect, n_cells, convexity)
        step = working_sets_step_seconds(n_control_points, n_cells, dim, convexity)
    solve = step * iterations * busy * (STRETCHED_STEP_COST if stretched else 1.0)
    meshing = MESHING_SECONDS_PER_CELL * n_cells * meshing_work * busy
    return BindSeconds(meshing, solve, SECONDS_PER_POINT * n_points * busy)


def working_sets_step_seconds(n_control_points, n_cells, dim, convexity=0.0):
    """About the seconds of one iteration of the splitting on working sets, its reshapes included."""
    if spreads_wide(n_control_points, dim, convexity):  # every pair held, no reshapes
        return WIDE_SECONDS_PER_PAIR_STEP * n_control_points * n_cells
    return (SECONDS_PER_CELL_STEP[dim] * n_cells
            + SECONDS_PER_PAIR_STEP[dim] * estimate_pairs(n_control_points, n_cells, dim, convexity))


def dense_step_seconds(n_control_points, n_cells):
    """About the seconds of one iteration of the dense splitting (3D): every (cell, control point) pair, and the
    null-space basis's products, which grow with the control points squared."""
    return n_control_points * n_cells * (DENSE_SECONDS_PER_PAIR_STEP
                                         + DENSE_SECONDS_PER_BASIS_STEP * n_control_points)


def takes_dense_splitting(n_control_points, n_cells, dim, convexity=0.0):
    """Whether a cold 3D solve takes the dense splitting, whose iterations its cost model tells cheaper than the working
    sets' where every coordinate spreads over much of the cage (few control points, or a convex cage): counts only, so
    that the same input takes the same splitting under any load (bench/RESULTS.md, "The splitting chosen by its
    cost").

    Example
    -------
    >>> takes_dense_splitting(27, 8000, 3), takes_dense_splitting(168, 8000, 3)
    (True, False)
    """
    if dim != 3:
        return False
    working_sets = working_sets_step_seconds(n_control_points, n_cells, dim, convexity)
    if spreads_wide(n_control_points, dim, convexity):
        working_sets *= WIDE_ITERATIONS  # the whole sets' tighter stop
    return dense_step_seconds(n_control_points, n_cells) < working_sets


def dense_tolerance_share(n_control_points, dim, convexity=0.0):
    """The share of the default tolerance the dense splitting stops at (DENSE_TIGHTER_SHARE, DENSE_WIDE_TOLERANCE_SHARE;
    1 below DENSE_TIGHTER_FROM control points on a cage that is not convex)."""
    if spreads_wide(n_control_points, dim, convexity):
        return DENSE_WIDE_TOLERANCE_SHARE
    return DENSE_TIGHTER_SHARE if n_control_points >= DENSE_TIGHTER_FROM else 1.0


def solve_forecast(n_control_points, n_cells, dim, stretched=False, aspect=1.0, busy=1.0, n_points=0,
                   meshing=False, convexity=0.0, meshing_work=1.0):
    """What a solve will take, told before it starts: its memory and roughly its time.

    Parameters
    ----------
    n_control_points, n_cells, dim : int
    stretched : bool
        Whether the solve runs in a stretched frame (:func:`solves_stretched`).
    aspect : float
        The cage's largest extent over its smallest along its principal axes (:func:`frame.principal_aspect`).
    busy : float
        How many times an idle machine's time the work takes now (:func:`parallel.busy_factor`): a new user's
        forecasts on a machine loaded 1.4-4 were half the time taken.
    n_points : int
        The points the bind evaluates after the solve (0: the solve alone is told).
    meshing : bool
        Whether the bind meshes the cage first (its time is told before the solve's).
    convexity : float
        :attr:`Cage.convexity` (0 when unknown): a convex cage's coordinates spread wider (:func:`spreads_wide`).
    meshing_work : float
        The meshing's work relative to an ordinary cage's of as many cells (a cage with narrow wedges takes more:
        :func:`lbc_core.meshing.sizing.wedge_work`).

    Returns
    -------
    str, e.g. "solving 106 control points on about 8000 cells: about 128 MB of memory for the solve and roughly 3 s"
    """
    told = bind_seconds(n_control_points, n_cells, dim, stretched, aspect, busy, n_points, convexity, meshing_work)
    seconds = told.solve
    text = ""
    if meshing:
        text = f"meshing {'' if told.meshing < 1 else 'roughly '}{format_duration(told.meshing)}, then "
    text += (f"solving {n_control_points} control points on about {n_cells} cells: about "
            f"{format_size(estimate_memory(n_control_points, n_cells, dim, convexity))} of memory for the solve and "
            f"{'' if seconds < 1 else 'roughly '}{format_duration(seconds)}")
    if n_points:
        text += (f", then {'' if told.points < 1 else 'about '}{format_duration(told.points)} for the {n_points} "
                 "points")
    if busy >= BUSY_TOLD_FROM:
        text += f" (the machine is busy: {busy:.1f} times the time it would take idle)"
    if seconds > 3600:
        text += " (beyond an hour on a 2-core machine: fewer cells or a coarser cage bind faster)"
    return text


def forecast_iterations(n_control_points, dim, stretched=False, aspect=1.0, n_cells=8000, convexity=0.0):
    """About how many iterations a solve takes at the default tolerance (see :data:`ITERATIONS_SCALE`,
    :data:`STRETCHED_ITERATIONS`, :data:`THIN_FROM_ASPECT`, :data:`WIDE_ITERATIONS`); the arguments as for
    :func:`solve_forecast`."""
    iterations = (ITERATIONS_SCALE[dim] * n_control_points ** ITERATIONS_POWER[dim]
                  * (n_cells / 8000) ** CELLS_POWER[dim])
    if stretched:
        iterations *= STRETCHED_ITERATIONS
    elif dim == 3 and aspect > THIN_FROM_ASPECT:
        iterations *= 1 + np.log10(aspect / THIN_FROM_ASPECT)
    if spreads_wide(n_control_points, dim, convexity):
        iterations *= WIDE_ITERATIONS
    return float(iterations)


def solves_stretched(control_points, epsilon=0.0):
    """Whether a cage with these (n, d) control points is solved in its stretched frame with the C¹ relaxation
    width ``epsilon`` (a 3D cage 1/200 as thick as wide or thinner with few control points, plain total variation; see
    :data:`STRETCHED_SOLVE_FROM`)."""
    return Stretch.of(np.asarray(control_points, dtype=float), epsilon) is not None


def format_size(count):
    """'512 B', '16 KB', '12 MB', '3.1 GB' (of 2^10, 2^20 and 2^30 bytes): a byte count for messages and panels.

    Examples
    --------
    >>> format_size(512), format_size(16 * 2**10), format_size(12 * 2**20), format_size(3.1 * 2**30)
    ('512 B', '16 KB', '12 MB', '3.1 GB')
    """
    if count < 2**10:
        return f"{count:.0f} B"
    if count < 2**20:
        return f"{count / 2**10:.0f} KB"
    return f"{count / 2**20:.0f} MB" if count < 2**30 else f"{count / 2**30:.1f} GB"


def format_duration(seconds):
    """'under 1 s', '7 s', '3 min', '2.5 h': a duration for messages."""
    if seconds < 1:
        return "under 1 s"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def seconds_left(elapsed, fraction, checks, max_iterations):
    """The time a solve has left, from two views of its residual, both read at its progress checks.

    The share of the way done in log scale (``fraction``) says 0.4-0.5 of the time actually left: ADMM's residual falls
    fast at first, then about as a power of the iteration count. That power, fitted between the check nearest half
    the iterations so far and the last, says 1.1-2.4 of it (the fall steepens as Anderson acceleration takes hold).
    Their geometric mean said 0.67-0.99 on the gargoyle cages L08-L12 (bench/RESULTS.md).

    Parameters
    ----------
    elapsed : float
        Seconds since the solve began.
    fraction : float
        The share of the way done, in (0, 1].
    checks : list of (iteration, distance)
        Each check's iteration and residual as a multiple of the tolerance, the last one now.
    max_iterations : int
    """
    by_share = elapsed * (1 - fraction) / fraction
    iteration, distance = checks[-1]
    reference, reference_distance = min(checks, key=lambda check: abs(check[0] - iteration / 2))
    if reference >= iteration or not reference_distance > distance > 1:
        return by_share
    power = np.log(reference_distance / distance) / np.log(iteration / reference)
    with np.errstate(over="ignore"):  # a residual that hardly fell: no end in sight, the iteration limit bounds it
        iterations_left = min(iteration * (distance ** (1 / power) - 1), max_iterations - iteration)
    return float(np.sqrt(by_share * iterations_left * elapsed / iteration))


def format_remaining(seconds):
    """'under 1 s left', 'about 7 s left': the time left, for progress messages."""
    duration = format_duration(seconds)
    return f"{duration} left" if duration.startswith("under") else f"about {duration} left"


def check_memory(n_control_points, n_cells, dim, convexity=0.0):
    """Raise CageError, with the estimate, if a solve would need more memory than the machine has available
    (``convexity`` as for :func:`estimate_memory`)."""
    needed = estimate_memory(n_control_points, n_cells, dim, convexity)
    available = _available_memory()
    if available is not None and needed > MEMORY_SHARE * available:
        raise CageError(
            f"binding {n_control_points} control points on {n_cells} cells would need about {needed / 2**30:.1f} GB "
            f"of memory, more than {MEMORY_SHARE:.0%} of the {available / 2**30:.1f} GB available now (the rest is "
            "left to the system and the estimate's margin): lower the resolution (cells) or use a cage with fewer "
            "vertices"
        )


# The share of the memory available when a bind starts that its estimate may take.
MEMORY_SHARE = 0.8


def _available_memory():
    """Bytes of memory available now, or None where the system does not say."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None

