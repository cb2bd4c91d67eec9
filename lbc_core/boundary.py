"""Boundary values: the fixed coordinates on the cage (Lagrange and linearity properties)."""

import numpy as np


def boundary_weights(domain, cage):
    """Fixed weights of the domain's boundary vertices: linear on each cage facet, 1 at the own control point.

    A vertex on facet f with barycentric coordinates b gets weight b_k for the facet's k-th control point and 0 for
    every other, so each coordinate is linear along cage edges (2D) and across cage triangles (3D), equals 1 at its own
    control point and 0 on every facet that does not touch it. A facet corner that is a poked n-gon's centre passes
    its share on to the n-gon's control points (:attr:`Cage.centre_values`).

    Parameters
    ----------
    domain : meshing.DomainMesh
    cage : cage.Cage

    Returns
    -------
    (B, n) float array, rows in the order of ``domain.boundary_vertices``
    """
    n_boundary, n = len(domain.boundary_vertices), cage.n_control_points
    weights = np.zeros((n_boundary, len(cage.surface_vertices)))
    corners = cage.facets[domain.boundary_facet]  # (B, d)
    rows = np.repeat(np.arange(n_boundary), corners.shape[1])
    np.add.at(weights, (rows, corners.ravel()), domain.boundary_bary.ravel())
    if cage.centres:
        weights = weights[:, :n] + (cage.centre_values.T @ weights[:, n:].T).T
    # Control points are exact: snap their rows to unit vectors (bary may carry round-off there).
    position = {v: k for k, v in enumerate(domain.boundary_vertices)}
    for i, vertex in enumerate(domain.control_vertices):
        weights[position[vertex]] = 0.0
        weights[position[vertex], i] = 1.0
    return weights
