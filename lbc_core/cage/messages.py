"""How the cage checks name what they refuse: input vertices by their first index in the user's list, a few
items of a long list, counts in words, and every defect raised at once in one :class:`~lbc_core.errors.CageError`;
and the user's values taken as real arrays, or refused in words.
"""

import numpy as np

from ..errors import CageError, CageVertexError

LISTED = 5  # how many offending items a message names


def count_of(number, singular, plural=None):
    """'1 edge', '4 edges': a count with its noun, for messages."""
    return f"{number} {singular if number == 1 else plural or singular + 's'}"


def some_indices(indices):
    """'3, 7, 9' or '3, 7, 9, 12, 15, ...': a few of the offending indices for a message."""
    return some_items([str(int(i)) for i in np.ravel(indices)])


def some_items(items):
    """The first few of the strings ``items``, comma-separated, with ', ...' when some are left out."""
    return ", ".join(items[:LISTED]) + (", ..." if len(items) > LISTED else "")


class NamesVertices(str):
    """A defect message that names cage vertices by their input numbers (:func:`raise_all` raises it as a
    CageVertexError)."""

def raise_all(defects):
    """Raise one CageError listing every defect message found (nothing when there is none); a CageVertexError when
    one of them names cage vertices."""
    error = CageVertexError if any(isinstance(defect, NamesVertices) for defect in defects) else CageError
    if len(defects) == 1:
        raise error(str(defects[0]))
    if defects:
        raise error(f"the cage has {len(defects)} kinds of defect, all listed here: "
                    + "; ".join(f"({k}) {defect}" for k, defect in enumerate(defects, 1)))


def first_inputs(vertex_map):
    """(n,) int array: the first input vertex of each welded vertex, to name vertices as the user numbers them."""
    return np.unique(vertex_map, return_index=True)[1]


def real_array(values, what, shape):
    """``values`` as a float array; CageError when they are not real numbers (text, complex numbers, ragged rows).

    Parameters
    ----------
    values : array-like
    what : str
        What the values are, for the message ("cage vertices").
    shape : str
        The expected shape, for the message ("(n, 2) or (n, 3)").
    """
    try:
        array = np.asarray(values)
        if array.dtype.kind in "cSUV" or (array.dtype.kind == "O" and any(isinstance(v, complex) for v in array.flat)):
            raise TypeError(array.dtype)
        return array.astype(float)
    except (TypeError, ValueError):
        raise CageError(f"{what} must be real numbers in an {shape} array") from None
