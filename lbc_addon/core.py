"""The one place the add-on imports ``lbc_core`` (the bpy-free solver) from; every other module takes it from here.

It takes only the small API lbc_core made for the add-on, ``lbc_core.addon_api``, and only the names listed there
(docs/ARCHITECTURE.md lists them too; tests/test_architecture.py checks both).

In the extension, lbc_core is bundled as a sub-package of the add-on (``bl_ext.<repository>.lbc.lbc_core``), so that
every bundled wheel is one from PyPI, unmodified; in the project's tree (tests, the project's environments) it is the
top-level package beside ``lbc_addon``.
"""

from pathlib import Path

if (Path(__file__).parent / "lbc_core").is_dir():  # the extension: lbc_core bundled beside this module
    from .lbc_core import addon_api as _api
else:  # the project's tree: lbc_core the top-level package beside lbc_addon
    from lbc_core import addon_api as _api

BindOptions = _api.BindOptions
CageError = _api.CageError
CageGenerationFailed = _api.CageGenerationFailed
CageVertexError = _api.CageVertexError
Cancelled = _api.Cancelled
GeneratedCage = _api.GeneratedCage
NothingToCage = _api.NothingToCage
PointsOutside = _api.PointsOutside
DEFAULT_CELLS = _api.DEFAULT_CELLS
DEFAULT_FLOOR = _api.DEFAULT_FLOOR
DEFAULT_SMOOTHNESS = _api.DEFAULT_SMOOTHNESS
DEFAULT_TOLERANCE = _api.DEFAULT_TOLERANCE
FEW_CELLS_PER_CONTROL_POINT = _api.FEW_CELLS_PER_CONTROL_POINT
MAX_CONTROL_POINTS = _api.MAX_CONTROL_POINTS
MESHERS = _api.MESHERS
POSED_APART = _api.POSED_APART
__version__ = _api.__version__
bind = _api.bind
flatten = _api.flatten
floor_for = _api.floor_for
format_size = _api.format_size
generate_cage = _api.generate_cage
make_cage = _api.make_cage
method_names = _api.method_names
rebind = _api.rebind
rebind_report = _api.rebind_report
reframed = _api.reframed
solved_again = _api.solved_again
some_indices = _api.some_indices
thin_changed_rows = _api.thin_changed_rows
thin_weights = _api.thin_weights
too_small_warning = _api.too_small_warning
