"""The cage as the user gives it, checked and put into one form: :func:`make_cage` welds, triangulates and orients a
closed 2D polygon or 3D polygon mesh into a :class:`Cage`, or refuses it with a :class:`~lbc_core.errors.CageError`
that says what is wrong and what to do (:mod:`.make`, with :mod:`.triangulate`, :mod:`.topology` and
:mod:`.messages`); :mod:`.planar` turns a flat 3D cage with its points into a 2D bind. Everything downstream
(meshing, the solve, the evaluation) takes a ``Cage``, never the user's arrays. The names below are the package's
face: other packages import them from here.
"""

from .make import MAX_CONTROL_POINTS, ZERO_LENGTH, check_coordinates, make_cage
from .messages import real_array, some_indices
from .record import POSED_APART, Cage
from .topology import edge_pairing
from .triangulate import POKE_SIDES

__all__ = ["MAX_CONTROL_POINTS", "POKE_SIDES", "POSED_APART", "ZERO_LENGTH", "Cage", "check_coordinates",
           "edge_pairing", "make_cage", "real_array", "some_indices"]
