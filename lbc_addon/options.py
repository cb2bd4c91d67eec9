"""The add-on's bind options as one frozen record, :class:`AddonOptions`: what the Bind operator's properties,
``Object.lbc`` and ``api.bind``'s keywords hold, checked when made, and the one place they become lbc_core's
``BindOptions``. No ``bpy`` here: :mod:`lbc_addon.jobs` uses it on a worker thread.
"""

import numbers
from dataclasses import dataclass, fields

import numpy as np

from .core import DEFAULT_CELLS, DEFAULT_SMOOTHNESS, MESHERS, BindOptions, CageError, floor_for, method_names

# Influences per mesh vertex by default, 0 for no cap (the Thinning floor alone): a cap creases where a vertex's weight
# ranks swap (bench/RESULTS.md, "Second round: the smooth evaluation's weights thinned, continuously").
DEFAULT_INFLUENCES = 0
# The Dimension choices (properties.MODE_ITEMS).
MODES = ("AUTO", "2D", "3D")
# The Mesher choices (properties.MESHER_ITEMS): lbc_core's "auto", then its bundled meshers of 3D cages; the others
# need a library the extension does not ship.
MESHER_NAMES = (method_names(3)[0],) + tuple(name for name, mesher in MESHERS[3].items() if mesher.bundled)
# The options a warm start needs unchanged, as the bind resolves them (Thinning and Max Influences are applied after
# the bind; the Dimension is the bind's own, which the warm start compares).
SOLVE_FIELDS = ("cells", "weighting", "epsilon", "tolerance", "mesher", "smoothness")


@dataclass(frozen=True)
class AddonOptions:
    """The options of one bind, as the panel names them; checked on construction (a script can pass anything).

    A Blender property cannot be None, so 0 stands for lbc_core's default (``cells``, ``tolerance``, ``thinning``).
    ``epsilon``, ``tolerance``, ``thinning`` and ``smoothness`` are kept at float32, as ``Object.lbc`` stores them, so that a Rebind,
    which reads them back, asks for the very same solve.

    Attributes
    ----------
    cells : int
        About how many cells fill the cage (0: lbc_core's default for the dimension).
    weighting : str
        One of lbc_core's weightings ("quadratic", "linear", "sqrt", "constant").
    epsilon : float
        The relaxation ε, 0 or more.
    tolerance : float
        The solver's tolerance (0: its default).
    thinning : float
        The floor every weight is lowered by (0: Smoothness's, lbc_core's ``floor_for``).
    influences : int
        Max Influences, at most this many cage vertices per mesh vertex (0: no cap).
    mode : str
        The Dimension: "AUTO", "2D" or "3D".
    mesher : str
        What fills a 3D cage with tetrahedra: "auto" or a bundled mesher of lbc_core (:data:`MESHER_NAMES`); a 2D
        bind uses lbc_core's own choice.
    smoothness : float
        Smooth ↔ local, 0 to 1: how far the smooth evaluation reaches, and the floor a Thinning of 0 takes.

    Raises
    ------
    CageError
        For a value the bind would fail on or misuse, before any work: lbc_core's message for its options.

    Examples
    --------
    >>> AddonOptions(cells=20000, thinning=0.01).core_options(3).cells
    20000
    >>> AddonOptions(mode="3d")
    Traceback (most recent call last):
    lbc_core.errors.CageError: mode must be one of 'AUTO', '2D', '3D', not '3d'
    """

    cells: int = 0
    weighting: str = "quadratic"
    epsilon: float = 0.0
    tolerance: float = 0.0
    thinning: float = 0.0
    influences: int = DEFAULT_INFLUENCES
    mode: str = "AUTO"
    mesher: str = MESHER_NAMES[0]
    smoothness: float = DEFAULT_SMOOTHNESS

    def __post_init__(self):
        self.core_options(3)  # lbc_core checks its own options
        thinning, influences = self.thinning, self.influences
        if isinstance(thinning, bool) or not isinstance(thinning, numbers.Real) or not thinning >= 0:
            raise CageError(f"thinning must be a number of at least 0 (0: from Smoothness), not {thinning!r}")
        if isinstance(influences, bool) or not isinstance(influences, numbers.Integral) or influences < 0:
            raise CageError(f"influences must be a whole number of at least 0 (0: no limit), not {influences!r}")
        for name, allowed in (("mode", MODES), ("mesher", MESHER_NAMES)):
            if getattr(self, name) not in allowed:
                raise CageError(f"{name} must be one of {', '.join(map(repr, allowed))}, not {getattr(self, name)!r}")
        for name in ("epsilon", "tolerance", "thinning", "smoothness"):
            object.__setattr__(self, name, float(np.float32(getattr(self, name))))
        object.__setattr__(self, "cells", int(self.cells))
        object.__setattr__(self, "influences", int(influences))

    def core_options(self, dimension):
        """lbc_core's ``BindOptions`` for a bind in ``dimension`` (2 or 3): the one place the add-on's names and
        defaults meet lbc_core's. Thinning and Max Influences are the add-on's own (:func:`lbc_addon.jobs.solve`
        thins the weights with them)."""
        return BindOptions(
            cells=self.cells or None,
            weighting=self.weighting,
            epsilon=self.epsilon,
            tolerance=self.tolerance or None,
            smoothness=self.smoothness,
            # "auto" is lbc_core's bundled mesher: Shewchuk's Triangle (2D), whose licence is not GPL-compatible, is
            # not bundled, and the Mesher option names 3D meshers.
            method=self.mesher if dimension == 3 else MESHER_NAMES[0],
        )

    @property
    def floor_and_cap(self):
        """(floor, Max Influences) the weights are thinned with (Thinning 0: Smoothness's floor)."""
        return self.thinning or floor_for(self.smoothness), self.influences

    def solve_changes(self, other, dimension):
        """The names of the :data:`SOLVE_FIELDS` in which ``other`` asks another solve of a ``dimension``-D cage: a
        warm start needs none. Cells 0 and the default's count ask the same, as do the Mesher "auto" and the mesher it
        runs (a redo in Adjust Last Operation that sets them stays warm)."""
        mine, theirs = self._solve_values(dimension), other._solve_values(dimension)
        return [name for name in SOLVE_FIELDS if mine[name] != theirs[name]]

    def _solve_values(self, dimension):
        """{name of :data:`SOLVE_FIELDS`: the value a bind of a ``dimension``-D cage resolves it to}."""
        core = self.core_options(dimension)
        return {"cells": core.cells or DEFAULT_CELLS[dimension], "weighting": core.weighting, "epsilon": core.epsilon,
                "tolerance": core.tolerance, "mesher": _mesher_run(core.method, dimension),
                "smoothness": core.smoothness}

    @classmethod
    def read(cls, properties):
        """The options held by Blender ``properties`` (``Object.lbc``, or an operator's): the one place they are
        read."""
        return cls(**{field.name: getattr(properties, field.name) for field in fields(cls)})

    def write(self, properties):
        """Store the options in Blender ``properties`` (``Object.lbc``): the one place they are written."""
        for field in fields(self):
            setattr(properties, field.name, getattr(self, field.name))



def _mesher_run(method, dimension):
    """The name of the mesher ``method`` runs for a ``dimension``-D cage ("auto": the first bundled one)."""
    if method != MESHER_NAMES[0]:
        return method
    return next(name for name, mesher in MESHERS[dimension].items() if mesher.bundled)
