"""The unit frame: the cage centred on the origin and scaled to about unit diagonal, where every stage computes.

Far from the origin, differences of coordinates lose the digits the offset takes (at 1e6, a unit cage keeps ten), and
a constraint like Σ w c = x mixes numbers of very different sizes with Σ w = 1. In the unit frame every stage sees
coordinates of order one whatever the cage's position and size; weights do not change under this similarity, and
what is stored in the cage's units is mapped back.

The scale is the power of two nearest the bounding box's diagonal, so scaling and unscaling are exact in floating
point and the diagonal in the frame lies in [1/√2, √2]; only the translation rounds.
"""

import dataclasses

import numpy as np

from .meshing import DomainMesh
from .meshing.common import bary_positions


@dataclasses.dataclass(frozen=True)
class UnitFrame:
    """A similarity x ↦ (x - centre) / scale.

    Attributes
    ----------
    centre : (d,) float array
        The centre of the cage's bounding box, in the cage's units.
    scale : float
        A power of two, within a factor √2 of the cage's bounding-box diagonal.
    """

    centre: np.ndarray
    scale: float

    @classmethod
    def of(cls, cage):
        """The frame of a :class:`~lbc_core.cage.Cage`: its bounding box's centre, its diagonal rounded to 2^k."""
        low, high = cage.vertices.min(axis=0), cage.vertices.max(axis=0)
        return cls(centre=(low + high) / 2, scale=float(2.0 ** np.round(np.log2(cage.bbox_diagonal))))

    def to_unit(self, positions):
        """(m, d) positions in the cage's units → (m, d) in the frame."""
        return (np.asarray(positions, dtype=float) - self.centre) / self.scale

    def from_unit(self, positions):
        """(m, d) positions in the frame → (m, d) in the cage's units."""
        return np.asarray(positions, dtype=float) * self.scale + self.centre

    def cage_to_unit(self, cage):
        """The same cage (topology, welding, warnings) with its control points in the frame."""
        return dataclasses.replace(cage, vertices=self.to_unit(cage.vertices))

    def domain_to_unit(self, domain):
        """A :class:`DomainMesh` in the cage's units → the same mesh in the frame."""
        return dataclasses.replace(domain, vertices=self.to_unit(domain.vertices))

    def domain_from_unit(self, domain, cage):
        """A :class:`DomainMesh` made in the frame → the same mesh in the units of ``cage`` (not in the frame).

        Interior vertices are mapped back; boundary vertices are placed again as their barycentric combination of
        their facet's corners and control vertices copied, so the mesh keeps :class:`DomainMesh`'s contract bitwise.
        """
        vertices = self.from_unit(domain.vertices)
        vertices[domain.boundary_vertices] = bary_positions(cage, domain.boundary_facet, domain.boundary_bary)
        vertices[domain.control_vertices] = cage.vertices
        return DomainMesh(vertices, domain.cells, domain.boundary_vertices, domain.boundary_facet,
                          domain.boundary_bary, domain.control_vertices)
