"""What the 2D and 3D backends share: boundary samples' positions, small mesh utilities, and the final check that
packs a :class:`~lbc_core.meshing.DomainMesh`. The frame they mesh in is :class:`lbc_core.kernel.frame.MeshingFrame`."""

import numpy as np
import scipy.sparse as sp

from ..errors import CageError
from ..kernel.geometry import bary_positions, row_keys, signed_measures
from . import DomainMesh


def raw_mesh(vertices, cells, boundary_vertices, boundary_facet, boundary_bary):
    """A DomainMesh as a backend makes it, before :func:`finish` checks it (control points come first)."""
    return DomainMesh(np.asarray(vertices, float), np.asarray(cells, np.int64), np.asarray(boundary_vertices, np.int64),
                      np.asarray(boundary_facet, np.int64), np.asarray(boundary_bary, float), np.zeros(0, np.int64))


def finish(cage, vertices, cells, boundary_vertices, boundary_facet, boundary_bary):
    """Check the mesh and pack it in the cage's own coordinates.

    The boundary vertices are put at their barycentric combination of ``cage``'s facet corners (so they lie on the
    cage exactly as the contract says, whatever frame the mesh was made in); the first n boundary vertices are the
    control points, in cage order, and get the cage's vertices bit for bit.
    """
    n = cage.n_control_points
    boundary_vertices = np.asarray(boundary_vertices, dtype=np.int64)
    boundary_facet = np.asarray(boundary_facet, dtype=np.int64)
    boundary_bary = np.asarray(boundary_bary, dtype=float)
    control_vertices = boundary_vertices[:n]
    vertices = np.array(vertices, dtype=float)
    vertices[boundary_vertices] = bary_positions(cage, boundary_facet, boundary_bary)
    vertices[control_vertices] = cage.vertices
    cells = np.asarray(cells, dtype=np.int64)
    flat = signed_measures(vertices, cells) <= 0
    unused = np.flatnonzero(np.bincount(cells.ravel(), minlength=len(vertices)) == 0)
    if len(cells) == 0 or flat.any() or len(unused):
        near = np.isin(boundary_vertices, np.r_[cells[flat].ravel(), unused])
        faces = np.unique(cage.facet_face[boundary_facet[near]])
        listed = ", ".join(map(str, faces[:10]))
        where = f" near cage faces {listed} (numbered from 0 in input order)" if len(faces) else ""
        raise CageError(f"the mesh has flat or unconnected cells{where}: very sharp angles or nearly touching parts "
                        "of the cage there are the usual cause; widen or separate them, or try a different cell count")
    return DomainMesh(vertices, cells, boundary_vertices, boundary_facet, boundary_bary, control_vertices)


def split_counts(lengths, spacing):
    """Number of equal pieces for each cage edge so that no piece is longer than ``spacing``."""
    return np.maximum(1, np.ceil(lengths / spacing - 1e-9)).astype(np.int64)


def far_points(vertices):
    """Corners of a box three times the points' size: they put every cage sample inside the convex hull, so samples
    along a straight cage edge are never hull points that qhull could drop as coplanar."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    centre, half = 0.5 * (low + high), 1.5 * (high - low).max()
    signs = np.array(np.meshgrid(*[[-1.0, 1.0]] * vertices.shape[1], indexing="ij")).reshape(vertices.shape[1], -1)
    return centre + half * signs.T


def cell_edges(cells):
    """Unique edges (E, 2) of the cells, each sorted."""
    k = cells.shape[1]
    edges = np.concatenate([cells[:, [i, j]] for i in range(k) for j in range(i + 1, k)])
    return np.unique(np.sort(edges, axis=1), axis=0)


def rows_in(rows, table):
    """Whether each row of ``rows`` occurs in ``table`` (non-negative int arrays with the same number of columns).

    Returns
    -------
    (R,) bool array
    """
    if len(table) == 0 or len(rows) == 0:
        return np.zeros(len(rows), dtype=bool)
    base = int(max(rows.max(), table.max())) + 1
    return np.isin(row_keys(rows, base), row_keys(table, base))


def on_common(incidence, rows):
    """Whether all the points of each row lie on one common part (indices past the incidence's rows lie on none).

    Parameters
    ----------
    incidence : (P, K) sparse 0/1 matrix, which parts (cage edges, facets, regions) each point lies on
    rows : (R, k) int array

    Returns
    -------
    (R,) bool array
    """
    result = np.all(rows < incidence.shape[0], axis=1)
    common = incidence[rows[result, 0]]
    for k in range(1, rows.shape[1]):
        common = common.multiply(incidence[rows[result, k]])
    result[result] = sp.csr_matrix(common).getnnz(axis=1) > 0
    return result


def smooth(vertices, cells, movable, passes, steps):
    """Laplacian smoothing of the ``movable`` vertices; a pass that would invert or flatten a cell is undone and
    ends the smoothing.

    Returns
    -------
    (N, d) float array
    """
    edges = cell_edges(cells)
    n = len(vertices)
    adjacency = sp.coo_matrix((np.ones(2 * len(edges)), (edges.ravel(), edges[:, ::-1].ravel())), shape=(n, n))
    adjacency = adjacency.tocsr()
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    floor = 1e-3 * np.min(signed_measures(vertices, cells))
    for _ in range(passes):
        steps.check()
        moved = vertices.copy()
        moved[movable] = (adjacency[movable] @ vertices) / degree[movable, None]
        if np.min(signed_measures(moved, cells)) <= floor:
            break
        vertices = moved
    return vertices
