"""Exceptions raised by lbc_core."""


class CageError(ValueError):
    """The cage (or the points bound to it) cannot be used; the message says why and what to do."""


class CageVertexError(CageError):
    """The cage is refused for what is wrong at some of its vertices, which the message names by their numbers in the
    input (counted from 0); a caller that changed the cage before binding (Blender's modifiers) says whose they are."""


class GapTooNarrow(CageError):
    """Parts of the cage nearly touch, far closer than the cells: the mesher cannot follow them, and twice the cells
    would not either (only closing or widening the gap, or far more cells)."""


class Cancelled(RuntimeError):
    """A long computation was cancelled through its ``cancel`` callback; nothing was returned."""


class PointsOutside(CageError):
    """Every point to bind lies outside the cage (raised before the solve): most likely the wrong cage."""
