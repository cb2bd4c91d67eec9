"""Local Barycentric Coordinates (Zhang, Deng et al., SIGGRAPH Asia 2014) for cage deformation.

    import lbc_core
    b = lbc_core.bind(cage_vertices, cage_faces, points)   # cage_faces=None for a 2D polygon
    deformed = b.deform(new_cage_vertices)
"""

__version__ = "0.1.0"

from .errors import CageError, Cancelled  # noqa: E402
from .cage import Cage, make_cage  # noqa: E402
from .options import BindOptions  # noqa: E402
from .solver import SolveResult, solve_on_mesh  # noqa: E402
from .binding import Binding, bind, load_binding  # noqa: E402
from .baselines import bind_bbw, bind_harmonic, bind_mvc, mean_value_coordinates  # noqa: E402
from .io import read_cage, read_mesh, write_mesh  # noqa: E402

__all__ = [
    "BindOptions", "Binding", "Cage", "CageError", "Cancelled", "SolveResult", "bind", "bind_bbw", "bind_harmonic", "bind_mvc",
    "load_binding", "make_cage", "mean_value_coordinates", "read_cage", "read_mesh", "solve_on_mesh", "write_mesh",
    "__version__",
]
