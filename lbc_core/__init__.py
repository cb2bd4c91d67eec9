"""Local Barycentric Coordinates (Zhang, Deng et al., SIGGRAPH Asia 2014) for cage deformation.

    import lbc_core
    b = lbc_core.bind(cage_vertices, cage_faces, points)   # cage_faces=None for a 2D polygon
    deformed = b.deform(new_cage_vertices)
    b = lbc_core.rebind(b, edited_cage_vertices, cage_faces)  # after editing the cage at rest: warm where it can
    made = lbc_core.generate_cage(mesh_vertices, mesh_faces, n_vertices=100)  # a cage for a mesh: made.vertices, .faces
"""

from .binding.files import load_binding
from .binding.options import BindOptions
from .binding.pipeline import bind
from .binding.rebinding import rebind
from .binding.record import Binding
from .cage import Cage, make_cage
from .cage_generator import GeneratedCage, generate_cage
from .compare.baselines import bind_bbw, bind_harmonic, bind_mvc, mean_value_coordinates
from .errors import CageError, Cancelled, PointsOutside
from .io import read_cage, read_mesh, write_mesh
from .solve.solver import SolveResult, solve_on_mesh
from .version import __version__

__all__ = [
    "BindOptions", "Binding", "Cage", "CageError", "Cancelled", "GeneratedCage", "SolveResult", "bind",
    "bind_bbw", "bind_harmonic", "bind_mvc", "generate_cage", "load_binding", "make_cage",
    "mean_value_coordinates", "PointsOutside", "read_cage", "read_mesh", "rebind", "solve_on_mesh", "write_mesh",
    "__version__",
]
