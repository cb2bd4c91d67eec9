"""Cages for tests: random star-shaped polygons, radial surfaces over a sphere triangulation, the 8-pointed star with
a grid around it, and Blender's subdivided cube; an even-odd point-in-polygon test (no matplotlib, which the add-on test
environments of the other Blender lines do not install)."""

import numpy as np
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

lengths = st.floats(0.05, 1.0, allow_nan=False)


def inside_polygon(polygon, points, margin):
    """Where points lie relative to a closed polygon (n, 2).

    Returns
    -------
    inside : (m,) bool array
        Inside by the even-odd rule.
    clear : (m,) bool array
        Farther than ``margin`` from every edge (where inside or outside is beyond doubt).
    """
    start, end = polygon, np.roll(polygon, -1, axis=0)
    # Even-odd rule: count the edges a ray towards +x crosses.
    straddle = (start[None, :, 1] > points[:, None, 1]) != (end[None, :, 1] > points[:, None, 1])
    t = (points[:, None, 1] - start[None, :, 1]) / np.where(end[:, 1] == start[:, 1], 1.0, end[:, 1] - start[:, 1])
    crossing_x = start[None, :, 0] + t * (end[None, :, 0] - start[None, :, 0])
    odd = np.count_nonzero(straddle & (crossing_x > points[:, None, 0]), axis=1) % 2 == 1
    along = end - start
    s = np.clip(np.einsum("mnj,nj->mn", points[:, None] - start[None], along) / np.sum(along**2, axis=1), 0, 1)
    distance = np.linalg.norm(points[:, None] - (start[None] + s[..., None] * along[None]), axis=2).min(axis=1)
    return odd, distance > margin


def star_polygon(gaps, radii):
    """Vertices (n, 2) at angles spaced in proportion to ``gaps`` (a full turn) and distances ``radii``."""
    n = min(len(gaps), len(radii))
    angles = 2 * np.pi * np.cumsum(gaps[:n]) / np.sum(gaps[:n])
    return np.c_[np.cos(angles), np.sin(angles)] * np.asarray(radii[:n])[:, None], angles


def sphere_directions(n_points):
    """(n, 3) unit vectors (a Fibonacci spiral) and their convex hull's triangles (2n - 4, 3), outward."""
    index = np.arange(n_points) + 0.5
    polar, azimuth = np.arccos(1 - 2 * index / n_points), np.pi * (1 + 5**0.5) * index
    directions = np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)
    triangles = ConvexHull(directions).simplices
    a, b, c = (directions[triangles[:, k]] for k in range(3))
    inward = np.einsum("ij,ij->i", a, np.cross(b, c)) < 0
    return directions, np.where(inward[:, None], triangles[:, ::-1], triangles)


def draw_dented_sphere(data, n_points, min_radius, max_push, shrink):
    """A sphere triangulation with random radii whose drawn subset of vertices is scaled by ``shrink`` and pushed by
    one random vector of components up to ``max_push``; returns (vertices (n, 3), triangles (T, 3))."""
    directions, triangles = sphere_directions(n_points)
    radii = np.array(data.draw(st.lists(st.floats(min_radius, 1.0), min_size=n_points, max_size=n_points)))
    vertices = directions * radii[:, None]
    dented = np.array(data.draw(st.lists(st.booleans(), min_size=n_points, max_size=n_points)))
    push = np.array(data.draw(st.tuples(*[st.floats(-max_push, max_push)] * 3)))
    vertices[dented] = vertices[dented] * shrink + push
    return vertices, triangles


STAR = star_polygon([1.0] * 8, [1.0, 0.5] * 4)[0]  # an 8-pointed concave star
GRID = np.stack(np.meshgrid(np.linspace(-1.2, 1.2, 13), np.linspace(-1.2, 1.2, 13)), axis=-1).reshape(-1, 2)


def subdivided_cube(cuts):
    """Blender's Cube (side 2) subdivided ``cuts`` times: each side a grid of (cuts + 1)² quads, vertices on a regular
    grid. Returns vertices (V, 3) float array and faces, a list of outward-oriented quads (vertex index lists)."""
    ticks = np.linspace(-1.0, 1.0, cuts + 2)
    index, faces = {}, []
    for axis in range(3):
        u, v = [other for other in range(3) if other != axis]
        for sign in (-1.0, 1.0):
            for i in range(cuts + 1):
                for j in range(cuts + 1):
                    quad = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        point = [0.0, 0.0, 0.0]
                        point[axis], point[u], point[v] = sign, ticks[i + di], ticks[j + dj]
                        quad.append(index.setdefault(tuple(point), len(index)))
                    faces.append(quad if (sign > 0) == ((v - u) % 3 == 1) else quad[::-1])
    return np.array(list(index)), faces
