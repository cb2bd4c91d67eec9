"""The cage generator: a mesh in, a cage out that lbc binds. The mesh's surface is voxelized and the outside flood-
filled from the grid's border (so open, self-intersecting, non-manifold and multi-part meshes all have an inside), the
solid's surface at the margin extracted by marching cubes and simplified, then brought down to the vertex count by a
progressive hull, whose every edge collapse encloses the surface before it, and the result checked by lbc's own cage
checks and for exact enclosure; a failing cage never comes out (the generator retries with a wider margin or a larger
start, then refuses with what to do). One module per stage: ``mesh_input``, ``voxels``, ``extraction``,
``simplification``, ``hull``, ``check``, and ``generator`` that runs them."""

from .generator import CageGenerationFailed, GeneratedCage, generate_cage
from .mesh_input import NothingToCage

__all__ = ["CageGenerationFailed", "GeneratedCage", "NothingToCage", "generate_cage"]
