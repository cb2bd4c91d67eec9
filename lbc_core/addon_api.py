"""What the Blender add-on uses of lbc_core, and nothing more: the one door it comes through.

``lbc_addon.core`` takes every name of :data:`__all__` from here and no other name of lbc_core, and
tests/test_architecture.py checks that (the list is in docs/ARCHITECTURE.md). A change inside lbc_core that keeps
these names and their meaning leaves the add-on alone; a name the add-on needs is added here, to the doc's list, and
to ``lbc_addon.core``.
"""

from .binding import options
from .binding.options import BindOptions
from .binding.pipeline import bind, too_small_warning
from .binding.rebinding import rebind
from .binding.record import Start
from .cage import MAX_CONTROL_POINTS, POSED_APART, make_cage, some_indices
from .cage.planar import flatten, reframed
from .cage_generator import CageGenerationFailed, GeneratedCage, NothingToCage, generate_cage
from .errors import CageError, CageVertexError, Cancelled, PointsOutside
from .evaluate.smoothing import DEFAULT_SMOOTHNESS
from .evaluate.thinning import DEFAULT_FLOOR, floor_for, thin_changed_rows, thin_weights
from .meshing import FEW_CELLS_PER_CONTROL_POINT, MESHERS, method_names
from .solve import forecast
from .solve.forecast import format_size
from .version import __version__

__all__ = [
    "BindOptions", "CageError", "CageGenerationFailed", "CageVertexError", "Cancelled", "DEFAULT_CELLS",
    "DEFAULT_FLOOR", "DEFAULT_SMOOTHNESS", "DEFAULT_TOLERANCE", "FEW_CELLS_PER_CONTROL_POINT", "GeneratedCage",
    "MAX_CONTROL_POINTS", "MESHERS", "NothingToCage", "POSED_APART", "PointsOutside", "__version__", "bind",
    "flatten", "floor_for", "format_size", "generate_cage", "make_cage", "method_names", "rebind", "rebind_report",
    "reframed", "solved_again", "some_indices", "thin_changed_rows", "thin_weights", "too_small_warning",
]

DEFAULT_CELLS = options.DEFAULT_CELLS
"""Cells of the domain mesh when the option is left at its default, by dimension: {2: triangles, 3: tetrahedra}."""

DEFAULT_TOLERANCE = forecast.DEFAULT_TOLERANCE
"""The solver's tolerance when the option is left at its default, by dimension: {2: ..., 3: ...}."""


def rebind_report(binding):
    """How :func:`rebind` went, for the user: the cells solved again, or why it bound from scratch; "" for a binding
    from :func:`bind`."""
    return binding.outcome.report


def solved_again(binding):
    """What a warm re-bind solved again, for the user ("s of c cells solved, e of p points evaluated"); "" for any
    other binding, one bound from scratch included."""
    if binding.outcome.start is not Start.WARM:
        return ""
    return str(binding.outcome.solved_again)
