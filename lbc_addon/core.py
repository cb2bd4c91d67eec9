"""The one place the add-on imports ``lbc_core`` (the bpy-free solver) from; every other module takes it from here.

In the extension, lbc_core is bundled as a sub-package of the add-on (``bl_ext.<repository>.lbc.lbc_core``), so that
every bundled wheel is one from PyPI, unmodified; in the project's tree (tests, the project's environments) it is the
top-level package beside ``lbc_addon``.
"""

import importlib
import importlib.util

_BUNDLED = f"{__package__}.lbc_core"

lbc_core = importlib.import_module(_BUNDLED if importlib.util.find_spec(_BUNDLED) else "lbc_core")
_cage = importlib.import_module(f"{lbc_core.__name__}.cage")
_errors = importlib.import_module(f"{lbc_core.__name__}.errors")
_options = importlib.import_module(f"{lbc_core.__name__}.options")
_planar = importlib.import_module(f"{lbc_core.__name__}.planar")
_rebinding = importlib.import_module(f"{lbc_core.__name__}.rebinding")
_forecast = importlib.import_module(f"{lbc_core.__name__}.forecast")
_thinning = importlib.import_module(f"{lbc_core.__name__}.thinning")

CageError = lbc_core.CageError
CageVertexError = _errors.CageVertexError
Cancelled = lbc_core.Cancelled
DEFAULT_CELLS_2D = _options.DEFAULT_CELLS[2]
DEFAULT_CELLS_3D = _options.DEFAULT_CELLS[3]
DEFAULT_TOLERANCE = _forecast.DEFAULT_TOLERANCE
POSED_APART = _cage.POSED_APART
MAX_CONTROL_POINTS = _cage.MAX_CONTROL_POINTS
some_indices = _cage.some_indices
flatten = _planar.flatten
reframed = _planar.reframed
DEFAULT_FLOOR = _thinning.DEFAULT_FLOOR
thin_weights = _thinning.thin_weights
thin_changed_rows = _thinning.thin_changed_rows
WARM = _rebinding.WARM  # lbc_core.rebind's mark of a binding that started from the previous solution
solved_again_text = _rebinding.solved_again_text
