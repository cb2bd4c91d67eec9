"""Boundary values: the fixed coordinates on the cage (Lagrange and linearity properties)."""

import numpy as np

from ..kernel.constraints import constraint_residuals, restore_constraints
from ..kernel.geometry import is_convex_polygon, newell_normal, plane_axes, polygon_mean_value_coordinates, unit

# Rows on a poked n-gon take its outline's mean value coordinates when corrected to reproduce their point within this
# share of the cage's diagonal (and to sum to 1 within it); the others keep the values linear on the poke's triangles.
EXACT = 1e-12


def boundary_weights(domain, cage):
    """Fixed weights of the domain's boundary vertices: linear on each cage facet, 1 at the own control point.

    A vertex on facet f with barycentric coordinates b gets weight b_k for the facet's k-th control point and 0 for
    every other, so each coordinate is linear along cage edges (2D) and across cage triangles (3D), equals 1 at its own
    control point and 0 on every facet that does not touch it. A facet corner that is a poked n-gon's centre passes
    its share on to the n-gon's control points (:attr:`Cage.centre_values`).

    On a convex poked n-gon the values are its outline's mean value coordinates instead (Floater 2003, in the plane
    of its Newell normal), smooth across the face where the poke's are linear on each of its triangles, with a crease
    along each spoke (a capsule's tip under Blender's Cylinder's cap creased 18° at worst with those, 11° with these).
    They are linear on the n-gon's edges, as its neighbours' values are. Where the n-gon is not flat, each row is
    corrected on its support to reproduce its point (which lies on the poke's triangles); a row the correction cannot
    make exact keeps the poke's values.

    Parameters
    ----------
    domain : meshing.DomainMesh
    cage : cage.Cage

    Returns
    -------
    (B, n) float array, rows in the order of ``domain.boundary_vertices``
    """
    n_boundary, n = len(domain.boundary_vertices), cage.n_control_points
    weights = np.zeros((n_boundary, n + len(cage.centres)))  # a column per surface vertex
    corners = cage.facets[domain.boundary_facet]  # (B, d)
    rows = np.repeat(np.arange(n_boundary), corners.shape[1])
    np.add.at(weights, (rows, corners.ravel()), domain.boundary_bary.ravel())
    if cage.centres:
        weights = weights @ cage.surface_values  # a centre's column to its n-gon's control points
        _outlines_mean_values(weights, domain, cage, corners)
    # Control points are exact: snap their rows to unit vectors (bary may carry round-off there).
    position = {v: k for k, v in enumerate(domain.boundary_vertices)}
    for i, vertex in enumerate(domain.control_vertices):
        weights[position[vertex]] = 0.0
        weights[position[vertex], i] = 1.0
    return weights


def _outlines_mean_values(weights, domain, cage, corners):
    """Replace, in place, the rows (B, n) of the boundary vertices on each convex poked n-gon by its outline's mean
    value coordinates, corrected to reproduce each vertex; ``corners`` (B, d) are the surface vertices of each row's
    facet."""
    n = cage.n_control_points
    positions = np.einsum("bk,bkd->bd", domain.boundary_bary, cage.surface_vertices[corners])
    tolerance = EXACT * cage.bbox_diagonal
    for centre, ring in enumerate(cage.centres):
        rows = np.flatnonzero(np.any(corners == n + centre, axis=1))
        outline = cage.vertices[ring]
        flat_outline, flat_points = _in_plane(outline, positions[rows])
        if not is_convex_polygon(flat_outline):  # a star: the outline's mean value coordinates would go negative
            continue
        values = restore_constraints(polygon_mean_value_coordinates(flat_outline, flat_points, tolerance), outline,
                                     positions[rows])
        unity, reproduction = constraint_residuals(values, outline, positions[rows])
        exact = (unity <= EXACT) & (reproduction <= tolerance)
        weights[rows[exact]] = 0.0
        weights[rows[exact][:, None], ring] = values[exact]


def _in_plane(outline, points):
    """An n-gon's outline (k, 3) and points (m, 3) in 2D coordinates of its Newell plane: (k, 2), (m, 2)."""
    axes = plane_axes(unit(newell_normal(outline)))
    return outline @ axes.T, points @ axes.T

