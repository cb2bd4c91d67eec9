"""Domain meshing: fill a cage with triangles (2D) or tetrahedra (3D) whose boundary lies exactly on the cage.

Every backend returns a :class:`DomainMesh` with the same guarantees, which the later stages rely on:

* control point i is mesh vertex ``control_vertices[i]`` at exactly (bitwise) ``cage.vertices[i]`` (Lagrange);
* every mesh vertex on the cage is listed in ``boundary_vertices`` with the facet it lies on and its barycentric
  coordinates there, and its position is that barycentric combination of the facet's corners, evaluated as
  ``sum_k bary[k] * corner[k]`` from k = 0 upward; so boundary values, linear on each facet, are exact at every
  boundary vertex (Lagrange, partition of unity and reproduction hold there);
* the listed boundary vertices are exactly the vertices of the mesh's boundary, every cell is positively oriented;
* the mesh's boundary facets tile the cage: in 2D each lies on one cage edge; in 3D each lies on one *planar
  region* of the cage, a connected set of facets whose planes agree within :data:`COPLANAR_ANGLE` (the triangles an
  n-gon or a quad was split into are one region). A boundary triangle may straddle the split lines inside a region
  (they are no features), never an edge between two regions.

Backends (modules of this package, listed by name in :data:`MESHERS`)
---------------------------------------------------------------------
``polygon``: 2D. ``"delaunay"`` (bundled; also ``"auto"``): boundary samples at the reference solver's spacing, a
hexagonal lattice inside, scipy's Delaunay triangulation, boundary recovery by splitting missing boundary pieces,
Laplacian smoothing. ``"triangle"``: Shewchuk's Triangle with the reference solver's switches, only when asked for
by name (its licence is not GPL-compatible, and "auto" must give the same weights everywhere, Blender included).
``surface``: 3D surface samples on the cage's planar regions and their feature edges, and each region's 2D
Delaunay triangulation. ``tetrahedra``: 3D. ``"delaunay"`` (also ``"auto"``): a conforming Delaunay
tetrahedralisation of the surface samples and a body-centred cubic lattice (see :mod:`.tetrahedra`).

Every backend works on the cage moved to its centre and scaled to unit diagonal (3D: also stretched along its
principal axes when it is very thin, see :class:`lbc_core.kernel.frame.MeshingFrame`); the result is mapped back, its
boundary vertices recomputed from their barycentric coordinates on the original cage, so the guarantees above hold in
the user's units.

fTetWild (pytetwild) was measured and not used: its tetrahedra do not contain the cage vertices (misses up to 0.35 %
of the cage diagonal on the gargoyle cage_L08), its boundary lies only within an envelope of the cage and does not
follow the cage edges, so boundary values could not be exactly linear on the facets; it is also slower (2.3 to 5.0 s
for 11k to 19k tetrahedra on one thread, against 0.5 to 1.5 s here), and has no macOS wheels.
"""

from dataclasses import dataclass, replace

import numpy as np

from ..errors import CageError, GapTooNarrow
from ..kernel.progress import Progress

# Triangles / tetrahedra filling the cage by default: 2D the paper's reference resolution, 3D chosen by fidelity and
# time (bench/RESULTS.md, "3D (gargoyle cage L08: 168 control points, 4083 tetrahedra)", "The resolution's price").
DEFAULT_CELLS = {2: 3000, 3: 8000}
DEFAULT_CELLS_2D = DEFAULT_CELLS[2]
DEFAULT_CELLS_3D = DEFAULT_CELLS[3]
# Below this many tetrahedra per control point a fine cage may not mesh: Blender's cube subdivided with 9 cuts (602
# vertices) failed at 8000 cells (13 per control point) and meshed at 16,000; with 5-8 cuts (16-37 per point) it
# meshed at 8000. A refusal there suggests more cells.
FEW_CELLS_PER_CONTROL_POINT = 20
# Facets whose normals differ by less than this (radians) along a shared edge form one planar region: n-gon splits,
# quads, and planes dented by round-off or by an artist's nudge. 1e-3 rad bends a boundary triangle of side h off
# the cage by at most about 2.5e-4 h.
COPLANAR_ANGLE = 1e-3
# What the method "auto" means, per dimension: a mesher that is bundled, so that "auto" gives the same weights
# everywhere, Blender included.
AUTO = "auto"


@dataclass(frozen=True)
class Mesher:
    """A domain mesher backend, as :data:`MESHERS` lists it.

    Attributes
    ----------
    name : str
        What ``BindOptions(method=...)``, ``lbc bind --method`` and the add-on's *Mesher* option call it.
    dim : int
        2 (triangles) or 3 (tetrahedra).
    mesh : callable(cage, cells, steps) -> DomainMesh
        Meshes a cage already in its meshing frame (centred, unit diagonal) with about ``cells`` cells, reporting to
        ``steps`` (a :class:`~lbc_core.kernel.progress.Progress`); returns the raw mesh, before :func:`mesh_domain`
        maps it back and checks it.
    bundled : bool
        Shipped with the Blender extension (its licence GPL-compatible): only a bundled mesher may be a default.
    summary : str
        One line for ``--help`` and the docs.
    """

    name: str
    dim: int
    mesh: object
    bundled: bool
    summary: str


def _tetrahedra(cage, cells, steps):
    from . import tetrahedra  # imported on use: the backends import this package's DomainMesh

    return tetrahedra.mesh(cage, cells, steps)


def _polygon_delaunay(cage, cells, steps):
    from . import polygon

    return polygon.mesh_delaunay(cage, cells, steps)


def _polygon_triangle(cage, cells, steps):
    from . import polygon

    return polygon.mesh_triangle(cage, cells, steps)


# Every mesher by dimension and name, the default ("auto") first.
MESHERS = {
    2: {"delaunay": Mesher("delaunay", 2, _polygon_delaunay, True,
                           "boundary samples, a hexagonal lattice, scipy's Delaunay triangulation (bundled)"),
        "triangle": Mesher("triangle", 2, _polygon_triangle, False,
                           "Shewchuk's Triangle, as the paper's reference solver (pip install triangle)")},
    3: {"delaunay": Mesher("delaunay", 3, _tetrahedra, True,
                           "a conforming Delaunay tetrahedralisation of surface samples and a BCC lattice (bundled)")},
}


def method_names(dim=None):
    """The names ``method`` takes: "auto" then the meshers of ``dim`` (2 or 3), or of every dimension (None)."""
    dims = (2, 3) if dim is None else (dim,)
    return (AUTO,) + tuple(dict.fromkeys(name for d in dims for name in MESHERS[d]))


def mesher(dim, method=AUTO):
    """The :class:`Mesher` that ``method`` names for a ``dim``-D cage ("auto": the first bundled one).

    Raises
    ------
    CageError
        When no mesher of that name meshes ``dim``-D cages.
    """
    if method == AUTO:
        return next(m for m in MESHERS[dim].values() if m.bundled)
    if method not in MESHERS[dim]:
        known = "does not mesh {dim}D cages" if method in method_names() else "is an unknown meshing method"
        raise CageError(f"method {method!r} {known.format(dim=dim)}: use one of {', '.join(method_names(dim))}")
    return MESHERS[dim][method]


@dataclass
class DomainMesh:
    """A simplicial mesh of the region a cage encloses.

    Attributes
    ----------
    vertices : (N, d) float array
        Vertex positions, in the cage's units.
    cells : (F, d+1) int array
        Triangles (d = 2) or tetrahedra (d = 3), positively oriented (positive signed area / volume).
    boundary_vertices : (B,) int array
        Every mesh vertex lying on the cage boundary, control vertices included.
    boundary_facet : (B,) int array
        Index into ``cage.facets`` of a facet that each boundary vertex lies on (its corners index
        ``cage.surface_vertices``).
    boundary_bary : (B, d) float array
        Barycentric coordinates of each boundary vertex in that facet: non-negative, summing to 1.
    control_vertices : (n,) int array
        Mesh vertex of each control point: ``vertices[control_vertices]`` equals ``cage.vertices`` bitwise.
    """

    vertices: np.ndarray
    cells: np.ndarray
    boundary_vertices: np.ndarray
    boundary_facet: np.ndarray
    boundary_bary: np.ndarray
    control_vertices: np.ndarray

    @property
    def dim(self):
        return self.vertices.shape[1]


def simplex_domain(cage):
    """A simplex cage (a triangle in 2D, a tetrahedron in 3D) as its own domain mesh: one cell.

    With n = d + 1 control points the constraints leave the coordinates no freedom: they are the barycentric
    coordinates, linear everywhere, so one cell represents them exactly and a finer mesh would add nothing.

    Parameters
    ----------
    cage : lbc_core.cage.make.Cage
        With ``cage.is_simplex``.

    Returns
    -------
    DomainMesh
        Vertices the control points (in cage order), one positively oriented cell, each vertex on the first facet
        that holds it.
    """
    from .common import finish

    d = cage.dim
    if not cage.is_simplex:
        raise ValueError(f"a {d}D simplex cage has {d + 1} control points, this one {cage.n_control_points}")
    cell = np.arange(d + 1)
    corners = cage.vertices[cell]
    if np.linalg.det(corners[1:] - corners[0]) < 0:
        cell[[0, 1]] = cell[[1, 0]]
    facets = np.asarray(cage.facets)
    facet = np.array([np.flatnonzero((facets == vertex).any(axis=1))[0] for vertex in range(d + 1)])
    bary = (facets[facet] == np.arange(d + 1)[:, None]).astype(float)
    return finish(cage, cage.vertices, cell[None, :], np.arange(d + 1), facet, bary)


def mesh_domain(cage, cells=None, method="auto", progress=None, cancel=None):
    """Mesh the region enclosed by a cage.

    Parameters
    ----------
    cage : lbc_core.cage.make.Cage
    cells : int or None
        About how many triangles / tetrahedra to make; None for DEFAULT_CELLS_2D or DEFAULT_CELLS_3D.
    method : str
        A name of :data:`MESHERS` for the cage's dimension, or "auto" (the bundled default): see :func:`mesher`.
    progress : callable(fraction, message), Progress or None
        Told the fraction done (0 to 1) and what is being done.
    cancel : callable() -> bool or None
        Polled between steps and inside every loop; when it returns True, :class:`Cancelled` is raised.

    Returns
    -------
    DomainMesh

    Raises
    ------
    CageError
        When the cage cannot be meshed, or ``method`` names no mesher of its dimension; the message says why and
        what to do.
    Cancelled
    """
    from ..kernel.frame import MeshingFrame
    from .common import finish

    dim = cage.dim
    backend = mesher(dim, method)
    if cells is None:
        cells = DEFAULT_CELLS[dim]
    if not cells >= 10:
        raise ValueError(f"the target cell count must be at least 10, got {cells}")
    steps = Progress.of(progress, cancel)
    # The backends mesh the surface: a poked n-gon's centre is a vertex of it like the control points.
    surface = cage.surface()
    frame = MeshingFrame(surface.vertices)
    local = frame.cage(surface)
    try:
        mesh = backend.mesh(local, int(cells), steps.part(0.0, 0.95))
        steps(0.95, "checking the mesh")
        mesh = finish(surface, frame.to_world(mesh.vertices), mesh.cells, mesh.boundary_vertices, mesh.boundary_facet,
                      mesh.boundary_bary)
        mesh = replace(mesh, control_vertices=mesh.control_vertices[:cage.n_control_points])
    except CageError as error:
        # A gap far below the cells is no matter of a fine cage: twice the cells fail there too (a vertex of Blender's
        # UV sphere moved past its neighbours near a pole, refused at 8000 and 16,000 cells).
        if (dim == 3 and cells < FEW_CELLS_PER_CONTROL_POINT * cage.n_control_points
                and not isinstance(error, GapTooNarrow)):
            raise CageError(f"this cage has {cage.n_control_points} vertices for about {int(cells)} cells, few for "
                            f"so fine a cage: try more cells ({2 * int(cells)}). The mesher said: {error}") from None
        raise
    steps(1.0, f"meshed: {len(mesh.cells)} cells")
    return mesh
