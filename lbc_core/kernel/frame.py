"""The two frames lbc computes in, both owned here.

:class:`UnitFrame`, where every stage of a bind computes: the cage centred on the origin and scaled to about unit
diagonal, a similarity, so the weights are those of the user's cage. :class:`MeshingFrame`, where the domain mesher
alone works: the unit frame's centring and scaling, and for a very thin 3D cage also a stretch along its principal
axes, an affine map the mesh is mapped back through (the weights are never computed in it).

Far from the origin, differences of coordinates lose the digits the offset takes (at 1e6, a unit cage keeps ten), and
a constraint like Σ w c = x mixes numbers of very different sizes with Σ w = 1. In the unit frame every stage sees
coordinates of order one whatever the cage's position and size; weights do not change under this similarity, and
what is stored in the cage's units is mapped back.

The scale is the power of two nearest the bounding box's diagonal, so scaling and unscaling are exact in floating
point and the diagonal in the frame lies in [1/√2, √2]; only the translation rounds.
"""

import dataclasses

import numpy as np

from .geometry import bary_positions


@dataclasses.dataclass(frozen=True)
class UnitFrame:
    """A similarity x ↦ (x - centre) / scale.

    Attributes
    ----------
    centre : (d,) float array
        The centre of the cage's bounding box, in the cage's units.
    scale : float
        A power of two within a factor √2 of the cage's bounding-box diagonal (:meth:`of`), or the diagonal itself
        (:meth:`exact`).
    """

    centre: np.ndarray
    scale: float

    @classmethod
    def of(cls, cage):
        """The frame of a :class:`~lbc_core.cage.make.Cage`: its bounding box's centre, its diagonal rounded to 2^k."""
        low, high = cage.vertices.min(axis=0), cage.vertices.max(axis=0)
        return cls(centre=(low + high) / 2, scale=float(2.0 ** np.round(np.log2(cage.bbox_diagonal))))

    @classmethod
    def exact(cls, points):
        """The frame of (m, d) points with their bounding box's diagonal exactly 1, not rounded to 2^k.

        The solver works in it: its penalty and tolerances are calibrated on a unit diagonal.
        """
        low, high = points.min(axis=0), points.max(axis=0)
        return cls(centre=(low + high) / 2, scale=float(np.linalg.norm(high - low)))

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
        return dataclasses.replace(domain, vertices=vertices)


def principal_extents(vertices):
    """The principal directions of a point set and its extent along each.

    Parameters
    ----------
    vertices : (n, d) float array

    Returns
    -------
    axes : (d, d) float array
        Columns: the principal directions, largest spread first, a right-handed frame in 3D.
    extents : (d,) float array
        The points' extent along each column of ``axes``, in the units of ``vertices``.
    """
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    axes = axes.T
    if len(axes) == 3 and np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return axes, np.ptp(centred @ axes, axis=0)


def principal_aspect(vertices):
    """The points' largest extent over their smallest along their principal axes (:func:`principal_extents`)."""
    extents = principal_extents(vertices)[1]
    return float(extents.max() / max(extents.min(), np.finfo(float).tiny))


# A 3D cage thinner than this along a principal axis (× its largest extent) is meshed stretched to this aspect. At 0.1
# rather than 0.25 a thin cage gets finer cells along its width for as many in all, rounder in its own frame: the
# corpus squashed to 1/1000 converges in 0.65 of the iterations to objectives mostly lower (bench/RESULTS.md).
ASPECT_FLOOR = 0.1


class MeshingFrame:
    """The affine map from the user's coordinates to the frame the domain mesher's backends mesh in.

    x → (x − centre) M: the cage's bounding-box centre goes to the origin, its diagonal to length 1. A 3D cage whose
    extent along one of its principal axes is below :data:`ASPECT_FLOOR` × its largest is also stretched along
    those axes up to that aspect: barycentric coordinates and planarity are affine invariants, so a mesh made in the
    stretched frame and mapped back still conforms to the cage, with ASPECT_FLOOR times as many cells across the thin
    direction as along the largest (isotropic cells would need the thickness as their size: 1e8 cells for a
    1 × 1 × 1e-4 box).

    Parameters
    ----------
    vertices : (n, d) float array, the cage's vertices
    """

    def __init__(self, vertices):
        low, high = vertices.min(axis=0), vertices.max(axis=0)
        self.centre = 0.5 * (low + high)
        dim = vertices.shape[1]
        matrix = np.eye(dim)
        if dim == 3:
            axes, extents = principal_extents(vertices)
            stretch = np.maximum(1.0, ASPECT_FLOOR * extents.max() / np.maximum(extents, np.finfo(float).tiny))
            if np.any(stretch > 1.0):
                matrix = axes * stretch[None, :]
        diagonal = np.linalg.norm(np.ptp((vertices - self.centre) @ matrix, axis=0))
        self.matrix = matrix / diagonal
        self.inverse = np.linalg.inv(self.matrix)

    def cage(self, cage):
        """The cage in this frame (same facets and numbering)."""
        return dataclasses.replace(cage, vertices=self.to_local(cage.vertices), warnings=list(cage.warnings))

    def to_local(self, points):
        """(P, d) points in this frame."""
        return (points - self.centre) @ self.matrix

    def to_world(self, points):
        """(P, d) points in the user's coordinates."""
        return points @ self.inverse + self.centre
