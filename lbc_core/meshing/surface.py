"""3D surface samples: the cage cut into planar regions, samples on the regions' boundaries and inside them, and
each region's 2D Delaunay triangulation.

A planar region is a connected set of cage facets whose normals agree within
:data:`~lbc_core.meshing.COPLANAR_ANGLE` across their shared edges: the triangles an n-gon or a quad was split into,
a grid-subdivided side of a box, a plane nudged by round-off. The edges between facets of different regions are the
*feature edges*; only they are sampled as edges. Inside a region the split lines of n-gons are no features: a
cap's skinny triangles and their small angles never reach the tetrahedraliser, which meets only the angles between
feature edges. Every sample still keeps the facet it lies on and its barycentric coordinates there,
so boundary values stay exact at every sample. A region facing another region of the cage across a gap narrower than
the spacing (two fingers' walls, also where they meet at the web between them) is sampled finer, by the gap
(:data:`GAP_SPACING`).

A quad whose two triangles are well shaped for the spacing (:func:`split_facets`) is the exception: each of its
triangles is a region of its own, its diagonal and edges features. An artist's edit at rest bends the quads around
the moved vertex along those lines, and a mesh that follows them keeps every boundary triangle on the bent cage: the
warm re-bind (:mod:`lbc_core.binding.rebinding`) can carry it instead of meshing again.
"""

from collections import namedtuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from ..kernel.geometry import (
    circumcircles,
    closest_on_segments,
    closest_on_triangles,
    cross2,
    distance_to_segments,
    orient_positive,
    triangle_normals,
    unit,
)
from . import COPLANAR_ANGLE
from .common import bary_positions, far_points, rows_in, split_counts

JITTER = 0.05  # random shift of samples, × their spacing: breaks co-circular and co-spherical ties
# Region samples stay this far (× spacing) from the region's boundary and from the cage vertices in it: beyond
# half a boundary piece, so no region sample encroaches a boundary piece to begin with.
_MARGIN = 0.7
# A quad's triangles are regions of their own (see split_facets) when every angle of both is at least this (degrees):
# Blender's 64-sided cylinder's sides (diagonals at 2.8°) made five times the cells asked for at 2000.
SPLIT_MIN_ANGLE = 20.0
# ... and every edge of both at least this many sample spacings: shorter ones would add samples the cell count does
# not pay for (the corpus's quad cages at 2000 cells: 1.35-1.54 times the cells asked for at 1 spacing, on target at
# 1.5; bench/RESULTS.md).
SPLIT_MIN_EDGE = 1.5
# qhull joggles its input, as in 3D (see tetrahedra._QHULL_OPTIONS): a region's boundary samples are collinear
# along its edges, and joggling once costs less than merging; 300 points 0.78 -> 0.51 ms.
_QHULL_OPTIONS = "QJ Qbb Q3 Q5 Q8"
_ROUNDS_2D = 30  # rounds of splitting boundary pieces missing from a region's triangulation
# Regions facing another part of the cage across a gap narrower than the spacing are sampled at GAP_SPACING ×
# sqrt(gap × band) from the start (bench/RESULTS.md, "Cages whose parts face each other across a narrow gap").
GAP_SPACING = 2.0
# Facets face each other when their normals are this close to opposite (cosine), and the gap runs along the normal.
_FACING = 0.7
# Points per cage facet (barycentric) at which the gaps between facets are measured.
_GAP_PROBES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5],
                        [1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])
SHELL_HAIR = 1e-3  # relative spread of the shells' radii between the edges of one vertex (see Surface._split)

Samples = namedtuple("Samples", "points facet bary triangles triangle_region incidence")
Samples.__doc__ = """The cage-surface samples of one refinement round.

points : (P, 3) float array, control points first (in cage order)
facet : (P,) int array, a cage facet each point lies on
bary : (P, 3) float array, its barycentric coordinates there
triangles : (S, 3) int array, the regions' triangulations, oriented outward
triangle_region : (S,) int array
incidence : (P, R) scipy.sparse.csr_matrix, 1 where a point lies on a region (closed: its boundary included)
"""


class OutOfBudget(RuntimeError):
    """Refinement would need more samples (or rounds) than its budget allows; ``Surface.trouble`` says where."""


def split_facets(cage, spacing):
    """Which facets are regions of their own: both triangles of each quad whose triangles have every angle at least
    :data:`SPLIT_MIN_ANGLE` and every edge at least :data:`SPLIT_MIN_EDGE` spacings.

    Parameters
    ----------
    cage : Cage (3D), in the meshing frame
    spacing : float, the sample spacing (length units of the meshing frame)

    Returns
    -------
    (E,) bool array, one per facet
    """
    corners = cage.vertices[cage.facets]
    sides = np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2)  # side k joins corners k and k + 1
    # The angle at corner k lies between sides k and k - 1, opposite side k + 1: cos = (a² + b² − c²) / (2ab).
    adjacent, previous, opposite = sides, sides[:, [2, 0, 1]], sides[:, [1, 2, 0]]
    cosines = (adjacent**2 + previous**2 - opposite**2) / np.maximum(2.0 * adjacent * previous, np.finfo(float).tiny)
    well_shaped = ((cosines <= np.cos(np.radians(SPLIT_MIN_ANGLE))).all(axis=1)
                   & (sides.min(axis=1) >= SPLIT_MIN_EDGE * spacing))
    face_facets = np.bincount(cage.facet_face)
    face_well_shaped = np.ones(len(face_facets), dtype=bool)
    np.logical_and.at(face_well_shaped, cage.facet_face, well_shaped)
    return (face_facets[cage.facet_face] == 2) & face_well_shaped[cage.facet_face]


def _planar_regions(normals, areas, edge_facets, split):
    """Each facet's region: facets joined across edges flatter than COPLANAR_ANGLE (none across a facet ``split``
    marks), a region whose facets stray from its mean plane by over 4 × COPLANAR_ANGLE taken apart: (F,) int."""
    n_facets = len(normals)
    flat = np.einsum("ij,ij->i", normals[edge_facets[:, 0]], normals[edge_facets[:, 1]]) > np.cos(COPLANAR_ANGLE)
    if split is not None:
        flat &= ~split[edge_facets[:, 0]] & ~split[edge_facets[:, 1]]
    links = edge_facets[flat]
    graph = sp.coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n_facets, n_facets))
    _, region = connected_components(graph, directed=False)
    # Small bends add up along a curved surface: a region whose facets stray from its mean plane is taken apart
    # into single facets.
    mean = np.zeros((region.max() + 1, 3))
    np.add.at(mean, region, normals * areas[:, None])
    mean = unit(mean)
    straying = np.unique(region[np.einsum("ij,ij->i", normals, mean[region]) < np.cos(4 * COPLANAR_ANGLE)])
    if len(straying):
        apart = np.isin(region, straying)
        region[apart] = region.max() + 1 + np.arange(np.count_nonzero(apart))
        region = np.unique(region, return_inverse=True)[1].ravel()
    return region


class Surface:
    """The cage's planar regions and their samples, refined on request.

    Points are numbered: control points (cage order), then the samples inside the feature edges (edge by edge,
    at parameters t in (0, 1) from the edge's lower to its higher vertex index), then the samples inside the
    regions (region by region).

    Parameters
    ----------
    cage : Cage, in the meshing frame
    spacing : float, the sample spacing
    rng : numpy.random.Generator
    budget : int, the most samples refinement may make
    split : (E,) bool array, optional
        The facets that are regions of their own (:func:`split_facets`; chosen once per mesh, so that a retry at
        another spacing keeps the same regions); None: every facet merges with its coplanar neighbours.
    band : float, optional
        How far the lattice stays from the surface; given, regions facing another part of the cage across a gap
        narrower than the spacing are sampled finer (:data:`GAP_SPACING`).
    """

    def __init__(self, cage, spacing, rng, budget, split=None, band=None):
        self.cage, self.rng, self.spacing, self.budget = cage, rng, spacing, budget
        facets = cage.facets
        corners = cage.vertices[facets]
        normals = triangle_normals(corners)
        areas = np.linalg.norm(normals, axis=1)
        normals = normals / areas[:, None]
        directed = np.stack([facets, np.roll(facets, -1, axis=1)], axis=2).reshape(-1, 2)  # row 3 f + k
        edges, inverse = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True)
        inverse = inverse.ravel()
        # A closed manifold cage: every edge has exactly two facets.
        edge_facets = np.repeat(np.arange(len(facets)), 3)[np.argsort(inverse, kind="stable")].reshape(-1, 2)
        region = _planar_regions(normals, areas, edge_facets, split)
        self._region_frames(region, facets, corners, normals, areas)
        # Each region's own sample spacing: finer where it faces another region across a narrow gap.
        self.region_spacing = np.full(self.n_regions, spacing)
        self.near = np.zeros(self.n_regions, dtype=bool)
        if band is not None:
            gaps = self._gaps(spacing)
            self.region_spacing = np.minimum(spacing, GAP_SPACING * np.sqrt(gaps * band))
            self.near = self.region_spacing < spacing
        self._feature_edges(cage, facets, directed, edges, inverse, edge_facets, rng)
        self.inner = [self._region_lattice(r) for r in range(self.n_regions)]  # (facet, bary) per region
        self.triangulations = [None] * self.n_regions  # per region, local numbering; None when out of date
        # the regions refinement worked on last, for error messages: first those sampled finer, if any
        self.trouble = np.flatnonzero(self.near) if self.near.any() else np.arange(self.n_regions)
        self._number()

    def _region_frames(self, region, facets, corners, normals, areas):
        """Each region's facets and vertices, and its plane: normal, in-plane axes (u, v) and origin."""
        self.region = region
        self.n_regions = region.max() + 1
        mean = np.zeros((self.n_regions, 3))
        np.add.at(mean, region, normals * areas[:, None])
        self.normal = unit(mean)
        helper = np.eye(3)[np.argmin(np.abs(self.normal), axis=1)]
        self.axis_u = unit(np.cross(self.normal, helper))
        self.axis_v = np.cross(self.normal, self.axis_u)  # (u, v, normal) right-handed: outward faces are ccw
        self.origin = np.zeros((self.n_regions, 3))
        np.add.at(self.origin, region, corners.mean(axis=1))
        self.origin /= np.bincount(region)[:, None]
        self.region_facets = [np.flatnonzero(region == r) for r in range(self.n_regions)]
        self.region_vertices = [np.unique(facets[f]) for f in self.region_facets]

    def _feature_edges(self, cage, facets, directed, edges, inverse, edge_facets, rng):
        """The edges between regions, each region's boundary and convexity, and the edges' first samples."""
        region = self.region
        feature = region[edge_facets[:, 0]] != region[edge_facets[:, 1]]
        self.edges = edges[feature]  # (K, 2) feature edges, low index first
        self.edge_facet = edge_facets[feature, 0]
        self.edge_regions = region[edge_facets[feature]]  # (K, 2)
        # Each region's boundary as directed edges of its facets (counter-clockwise in its frame), region by region.
        rows = np.flatnonzero(feature[inverse])
        rows = rows[np.argsort(region[rows // 3], kind="stable")]
        split = np.searchsorted(region[rows // 3], np.arange(1, self.n_regions))
        self.convex = np.array([self._convex(r, directed[part]) for r, part in enumerate(np.split(rows, split))])
        self.region_edges = [np.flatnonzero(np.any(self.edge_regions == r, axis=1)) for r in range(self.n_regions)]
        lengths = np.linalg.norm(cage.vertices[self.edges[:, 1]] - cage.vertices[self.edges[:, 0]], axis=1)
        self.edge_length = lengths
        # The refinement's shell radii: per cage vertex, and per edge by a hair (see _split), the hair from a fixed
        # generator of its own.
        self.shell_scale = 1.0 + 0.1 * rng.uniform(-1.0, 1.0, cage.n_control_points)
        self.edge_shell_scale = 1.0 + SHELL_HAIR * np.random.default_rng(0).uniform(-1.0, 1.0, len(lengths))
        # At least two pieces per edge, slightly uneven: evenly split edges give co-circular samples whose
        # Delaunay triangulation is ambiguous, and no sample-free sphere may run through a box's corners.
        # The corner of edge_facet holding each feature edge's lower and higher vertex: (K, 2).
        self.edge_corner = np.argmax(facets[self.edge_facet][:, None, :] == self.edges[:, :, None], axis=2)
        counts = np.maximum(2, split_counts(lengths, self.region_spacing[self.edge_regions].min(axis=1)))
        self.edge_params = [np.sort((np.arange(1, m) + JITTER * rng.uniform(-1.0, 1.0, m - 1)) / m) for m in counts]

    # --- frames and location ---------------------------------------------------------------------------------

    def to_plane(self, r, points):
        """2D coordinates (P, 2) of 3D points in region r's frame."""
        offset = points - self.origin[r]
        return np.stack([offset @ self.axis_u[r], offset @ self.axis_v[r]], axis=1)

    def locate(self, r, xy):
        """The facet of region r holding each 2D point and the point's barycentric coordinates there.

        Returns
        -------
        facet : (P,) int array
        bary : (P, 3) float array, clipped to be non-negative and to sum to 1
        inside : (P,) bool array, False for points outside the region (beyond round-off)
        """
        facets = self.region_facets[r]
        corners = np.stack([self.to_plane(r, self.cage.vertices[self.cage.facets[facets, k]]) for k in range(3)], 1)
        a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
        area = cross2(b - a, c - a)  # (F,)
        best_facet = np.zeros(len(xy), dtype=np.int64)
        best_bary = np.zeros((len(xy), 3))
        best_low = np.full(len(xy), -np.inf)
        for chunk in np.array_split(np.arange(len(facets)), max(1, len(facets) * len(xy) // 1_000_000)):
            p = xy[:, None, :]
            bary = np.stack([cross2(b[chunk] - p, c[chunk] - p), cross2(c[chunk] - p, a[chunk] - p),
                             cross2(a[chunk] - p, b[chunk] - p)], axis=2) / area[chunk, None]
            low = bary.min(axis=2)
            k = np.argmax(low, axis=1)
            better = low[np.arange(len(xy)), k] > best_low
            best_low[better] = low[better, k[better]]
            best_facet[better] = facets[chunk[k[better]]]
            best_bary[better] = bary[better, k[better]]
        inside = best_low > -1e-12
        bary = np.maximum(best_bary, 0.0)
        return best_facet, bary / bary.sum(axis=1, keepdims=True), inside

    def _convex(self, r, boundary):
        """Whether region r is convex: every vertex of it on the inner (left) side of each of its directed boundary
        edges (E, 2), within round-off."""
        xy = self.to_plane(r, self.cage.vertices[self.region_vertices[r]])
        start, end = (self.to_plane(r, self.cage.vertices[boundary[:, k]]) for k in (0, 1))
        turn = cross2(end[:, None] - start[:, None], xy[None] - start[:, None])  # (E, V)
        return bool(np.all(turn >= -1e-12 * np.linalg.norm(end - start, axis=1)[:, None]))

    def _boundary_segments(self, r):
        """2D start and end points (S, 2) of region r's boundary: its feature edges, unsplit."""
        ends = self.cage.vertices[self.edges[self.region_edges[r]]]
        return self.to_plane(r, ends[:, 0]), self.to_plane(r, ends[:, 1])

    def _gaps(self, reach):
        """Per region, how far it faces another region: the distance along its outward normal to an opposite facet
        where below ``reach``, as a quarter of the region's area sees it at least (inf for a region that faces none
        over so much: a strip along an edge is left to refinement). Regions sharing a vertex count too: two fingers'
        walls meet at the web between them and open slowly (bench/RESULTS.md, "Meshing cages whose parts nearly
        touch: sized by counting, bounded by counts").

        Measured at a few points of each facet (:data:`_GAP_PROBES`), each point weighing its facet's area."""
        cage = self.cage
        corners = cage.vertices[cage.facets]
        centres = corners.mean(axis=1)
        radii = np.linalg.norm(corners - centres[:, None], axis=2).max(axis=1)
        normals = triangle_normals(corners)
        areas = 0.5 * np.linalg.norm(normals, axis=1)
        normals = unit(normals)
        gaps = np.full(self.n_regions, np.inf)
        pairs = cKDTree(centres).query_pairs(reach + 2.0 * radii.max(), output_type="ndarray")
        if len(pairs):
            first, second = pairs[:, 0], pairs[:, 1]
            close = np.linalg.norm(centres[first] - centres[second], axis=1) < reach + radii[first] + radii[second]
            facing = np.einsum("ij,ij->i", normals[first], normals[second]) < -_FACING
            pairs = pairs[close & facing]
        pairs = pairs[self.region[pairs[:, 0]] != self.region[pairs[:, 1]]] if len(pairs) else pairs
        if len(pairs) == 0:
            return gaps
        # Both ways: the probes of one facet against the other triangle.
        probe, target = np.concatenate([pairs, pairs[:, ::-1]]).T
        points = np.einsum("pk,fkd->fpd", _GAP_PROBES, corners[probe]).reshape(-1, 3)
        probe, target = np.repeat(probe, len(_GAP_PROBES)), np.repeat(target, len(_GAP_PROBES))
        squared, bary = closest_on_triangles(points, *corners[target].transpose(1, 0, 2))
        across = np.einsum("ik,ikd->id", bary, corners[target]) - points
        distance = np.sqrt(squared)
        ahead = np.einsum("ij,ij->i", across, normals[probe]) > _FACING * distance
        distance[~ahead | (distance >= reach)] = np.inf
        # The least distance at each probe of each facet, then per region the distance a quarter of its area is within.
        at = np.full((len(cage.facets), len(_GAP_PROBES)), np.inf)
        np.minimum.at(at, (probe, np.tile(np.arange(len(_GAP_PROBES)), len(probe) // len(_GAP_PROBES))), distance)
        for r in np.unique(self.region[pairs.ravel()]):
            facets = self.region_facets[r]
            values = at[facets].ravel()
            order = np.argsort(values)
            weight = np.repeat(areas[facets], len(_GAP_PROBES))[order]
            quarter = np.searchsorted(np.cumsum(weight), 0.25 * weight.sum())
            gaps[r] = values[order][min(quarter, len(values) - 1)]
        return gaps

    def _region_lattice(self, r):
        """(facet, bary) of jittered hexagonal lattice points in region r, a margin away from its boundary and from
        the cage vertices in it."""
        spacing = self.region_spacing[r]
        vertices_xy = self.to_plane(r, self.cage.vertices[self.region_vertices[r]])
        low, high = vertices_xy.min(axis=0), vertices_xy.max(axis=0)
        rows = np.arange(low[1], high[1] + spacing, spacing * np.sqrt(3.0) / 2.0)
        cols = np.arange(low[0] - spacing, high[0] + spacing, spacing)
        x = cols[None, :] + 0.5 * spacing * (np.arange(len(rows)) % 2)[:, None]
        xy = np.stack([x.ravel(), np.repeat(rows, len(cols))], axis=1)
        xy += JITTER * spacing * self.rng.uniform(-1.0, 1.0, xy.shape)
        facet, bary, inside = self.locate(r, xy)
        keep = inside.copy()
        starts, ends = self._boundary_segments(r)
        keep[keep] = distance_to_segments(xy[keep], starts, ends) >= _MARGIN * spacing
        if keep.any():
            keep[keep] = cKDTree(vertices_xy).query(xy[keep])[0] >= _MARGIN * spacing
        return facet[keep], bary[keep]

    # --- samples ---------------------------------------------------------------------------------------------

    def _number(self):
        """Number the samples: edge_start[k] is the first point of feature edge k, region_start[r] of region r."""
        n = self.cage.n_control_points
        self.edge_start = np.cumsum([n] + [len(p) for p in self.edge_params])
        self.region_start = np.cumsum([self.edge_start[-1]] + [len(f) for f, _ in self.inner])
        self._local = {}  # local_points per region, valid until the next numbering
        self._region_pieces = {}  # _pieces per region, likewise
        self._samples = None  # what samples() returned, likewise
        if self.region_start[-1] > self.budget:
            raise OutOfBudget(f"{self.region_start[-1]} surface samples")

    def _chain(self, k):
        """Point indices along feature edge k, from its lower to its higher vertex, ends included."""
        chain = np.empty(len(self.edge_params[k]) + 2, dtype=np.int64)  # np.r_ costs more than this on many edges
        chain[0], chain[-1] = self.edges[k]
        chain[1:-1] = self.edge_start[k] + np.arange(len(self.edge_params[k]))
        return chain

    def local_points(self, r):
        """Point indices of region r: its cage vertices, its feature edges' inner samples, its inner samples."""
        if r not in self._local:
            parts = [self.region_vertices[r]]
            parts += [self._chain(k)[1:-1] for k in self.region_edges[r]]
            parts.append(self.region_start[r] + np.arange(len(self.inner[r][0])))
            self._local[r] = np.concatenate(parts)
        return self._local[r]

    def samples(self, steps):
        """All current samples and the regions' triangulations (boundary pieces missing from a region's 2D
        triangulation are split first, a bounded number of rounds).

        Returns
        -------
        Samples
        """
        if self._samples is not None:  # nothing was refined since
            return self._samples
        cage = self.cage
        n, n_facets = cage.n_control_points, len(cage.facets)
        facet_of_vertex = np.empty(n, dtype=np.int64)
        corner_of_vertex = np.empty(n, dtype=np.int64)
        facet_of_vertex[cage.facets.ravel()] = np.repeat(np.arange(n_facets), 3)
        corner_of_vertex[cage.facets.ravel()] = np.tile(np.arange(3), n_facets)
        for _ in range(_ROUNDS_2D):
            steps.check()
            params = np.concatenate(self.edge_params)
            edge = np.repeat(np.arange(len(self.edges)), [len(p) for p in self.edge_params])
            on_edges = np.zeros((len(params), 3))
            on_edges[np.arange(len(params)), self.edge_corner[edge, 0]] = 1.0 - params
            on_edges[np.arange(len(params)), self.edge_corner[edge, 1]] = params
            facet = [facet_of_vertex, self.edge_facet[edge]] + [f for f, _ in self.inner]
            bary = [np.eye(3)[corner_of_vertex], on_edges] + [b for _, b in self.inner]
            facet, bary = np.concatenate(facet), np.concatenate(bary)
            self.points = bary_positions(cage, facet, bary)
            missing = []
            for r in range(self.n_regions):
                steps.check()
                if self.triangulations[r] is None:
                    self.triangulations[r], lost = self._triangulate(r)
                    missing += lost
            if not missing:
                break
            self.trouble = np.unique(self.edge_regions[[k for k, _ in missing]])
            for k, piece in set(missing):
                self._split(k, piece)
        else:
            raise OutOfBudget("region boundaries not recovered")
        triangles = [self.local_points(r)[t] for r, t in enumerate(self.triangulations)]
        self.triangle_region = np.repeat(np.arange(self.n_regions), [len(t) for t in triangles])
        self.triangles = np.concatenate(triangles)
        self._samples = Samples(self.points, facet, bary, self.triangles, self.triangle_region, self._incidence())
        return self._samples

    def _incidence(self):
        """(P, R) sparse 0/1 matrix: the regions each sample lies on (vertices and edge samples on several)."""
        rows, cols = [], []
        for r in range(self.n_regions):
            local = self.local_points(r)
            rows.append(local)
            cols.append(np.full(len(local), r))
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        shape = (len(self.points), self.n_regions)
        return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=shape)

    def _pieces(self, r):
        """Region r's boundary pieces: (K, 2) point index pairs and their (feature edge, piece index) labels."""
        if r not in self._region_pieces:
            pairs, labels = [], []
            for k in self.region_edges[r]:
                chain = self._chain(k)
                pairs.append(np.stack([chain[:-1], chain[1:]], axis=1))
                labels += [(int(k), i) for i in range(len(chain) - 1)]
            self._region_pieces[r] = np.concatenate(pairs), labels
        return self._region_pieces[r]

    def _triangulate(self, r):
        """Region r's 2D Delaunay triangles in local numbering, oriented outward, and the (edge, piece) labels of
        its boundary pieces missing from them."""
        local = self.local_points(r)
        xy = self.to_plane(r, self.points[local])
        simplices = Delaunay(np.concatenate([xy, far_points(xy)]), qhull_options=_QHULL_OPTIONS).simplices
        simplices = simplices[np.all(simplices < len(xy), axis=1)]
        corners = xy[simplices]
        area = 0.5 * cross2(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        simplices = simplices[np.abs(area) > 1e-10 * self.spacing**2]  # collinear boundary samples
        if not self.convex[r]:  # a convex region holds every triangle of its points
            _, _, inside = self.locate(r, xy[simplices].mean(axis=1))
            simplices = simplices[inside]
        simplices = orient_positive(xy, simplices)
        pairs, labels = self._pieces(r)
        position = np.full(len(self.points), -1)
        position[local] = np.arange(len(local))
        edges = np.sort(simplices[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)  # each inner edge twice
        present = rows_in(np.sort(position[pairs], axis=1), edges)
        return simplices, [labels[i] for i in np.flatnonzero(~present)]

    # --- refinement ------------------------------------------------------------------------------------------

    def _split(self, k, piece):
        """Split piece ``piece`` of feature edge k: at its middle, or, next to a cage vertex, at a power-of-two
        distance from it (concentric shells: the splits around a vertex where edges meet at a small angle land on
        common spheres, so they stop encroaching on each other, as in Ruppert's algorithm)."""
        params = np.r_[0.0, self.edge_params[k], 1.0]
        t0, t1 = params[piece], params[piece + 1]
        t = 0.5 * (t0 + t1)
        length = self.edge_length[k]
        if (t0 == 0.0) != (t1 == 1.0):
            from_end = t * length if t0 == 0.0 else (1.0 - t) * length
            # One radius per vertex for all its edges, so that the pieces of two edges at a small angle do not
            # encroach on each other: radii of their own per edge (1 ± 10 %) let them at every scale, and refinement
            # ran down into a UV sphere's pole once an edit folded its fan. Per edge only by a hair (SHELL_HAIR):
            # equal radii put two edges' samples on a circle in their common plane, a flat tetrahedron (the 64-sided
            # cone at 4000 cells); the hair lets a piece be encroached only by an edge within 2.6° of it.
            scale = self.shell_scale[self.edges[k, 0 if t0 == 0.0 else 1]] * self.edge_shell_scale[k]
            shell = 2.0 ** np.round(np.log2(from_end)) * scale
            candidate = shell / length if t0 == 0.0 else 1.0 - shell / length
            if t0 + 0.25 * (t1 - t0) <= candidate <= t1 - 0.25 * (t1 - t0):
                t = candidate
        self.edge_params[k] = np.sort(np.append(self.edge_params[k], t))
        for r in self.edge_regions[k]:
            self.triangulations[r] = None
        self._number()

    def refine(self, missing, steps):
        """Refine around the given missing triangles (indices into the last ``samples()`` output).

        Ruppert's rules: a piece of a feature edge whose diametral sphere holds another sample is split (no
        triangle through that piece could have an empty protecting sphere otherwise). A missing triangle with no
        such piece gets its circumcentre added to its region, unless the circumcentre lies outside the region or
        in the diametral circle of a piece of the region's boundary: then that piece is split instead.
        """
        sides = {}
        self.trouble = np.unique(self.triangle_region[missing])
        for r in self.trouble:
            pairs, labels = self._pieces(r)
            sides.update({tuple(sorted(map(int, pair))): label for pair, label in zip(pairs, labels)})
        split = set()
        triangle_pieces = []
        for s in missing:
            t = self.triangles[s]
            triangle_pieces.append({sides[key] for key in (tuple(sorted((int(p), int(q))))
                                                           for p, q in zip(t, np.roll(t, -1))) if key in sides})
        split.update(self._encroached_by_samples(set().union(*triangle_pieces)))
        centres, radii, inside, encroached = self._circumcentres(np.asarray(missing), steps)
        inserted = {}
        for i, (s, pieces) in enumerate(zip(missing, triangle_pieces)):
            steps.check()
            if split & pieces:
                continue
            r = self.triangle_region[s]
            centre, radius = centres[i], radii[i]
            if encroached[i] or not inside[i] or not np.isfinite(radius):
                split.update(encroached[i] or [self._nearest_piece(r, centre)])
                continue
            # Missing neighbours can share a circumcircle: insert it once. The centres accepted so far in region r
            # fill the first rows of one array (a loop over them made a thousand missing triangles cost 10 s).
            accepted, count = inserted.get(r, (np.empty((len(missing), 2)), 0))
            if count == 0 or np.min(np.linalg.norm(accepted[:count] - centre, axis=1)) > 0.5 * radius:
                accepted[count] = centre
                count += 1
            inserted[r] = accepted, count
        for r, (accepted, count) in inserted.items():
            facet, bary, _ = self.locate(r, accepted[:count])
            self.inner[r] = (np.r_[self.inner[r][0], facet], np.concatenate([self.inner[r][1], bary]))
            self.triangulations[r] = None
        for k, piece in split:
            self._split(k, piece)
        self._number()

    def _encroached_by_samples(self, pieces):
        """The (edge, piece) labels among ``pieces`` whose diametral sphere holds a sample."""
        pieces = list(pieces)
        if not pieces:
            return []
        ends = np.array([self._chain(k)[[i, i + 1]] for k, i in pieces])
        a, b = self.points[ends[:, 0]], self.points[ends[:, 1]]
        near = cKDTree(self.points).query_ball_point(0.5 * (a + b), 0.5 * np.linalg.norm(b - a, axis=1) * (1 - 1e-9))
        return [piece for piece, found, own in zip(pieces, near, ends) if set(found) - set(own)]

    def _piece_ends_2d(self, r):
        pairs, labels = self._pieces(r)
        return self.to_plane(r, self.points[pairs[:, 0]]), self.to_plane(r, self.points[pairs[:, 1]]), labels

    def _circumcentres(self, missing, steps):
        """The missing triangles' circumcircles in their regions' planes, region by region at once.

        Returns
        -------
        centres : (M, 2) float array, each in its region's frame
        radii : (M,) float array, inf for a flat triangle (its centre is then its first corner)
        inside : (M,) bool array, whether the centre lies in the region
        encroached : list of M lists of the (edge, piece) labels of the region's boundary pieces whose diametral
            circle holds the centre
        """
        region = self.triangle_region[missing]
        centres, radii = np.empty((len(missing), 2)), np.empty(len(missing))
        inside, encroached = np.empty(len(missing), dtype=bool), [None] * len(missing)
        for r in np.unique(region):
            steps.check()
            at = np.flatnonzero(region == r)
            corners = self.to_plane(r, self.points[self.triangles[missing[at]]].reshape(-1, 3)).reshape(-1, 3, 2)
            centres[at], radii[at] = circumcircles(corners)
            inside[at] = self.locate(r, centres[at])[2]
            start, end, labels = self._piece_ends_2d(r)
            middle, half = 0.5 * (start + end), 0.5 * np.linalg.norm(end - start, axis=1)
            for chunk in np.array_split(at, max(1, len(at) * len(middle) // 1_000_000)):
                hits = np.linalg.norm(centres[chunk, None] - middle[None], axis=2) < half  # (chunk, pieces)
                for i, row in zip(chunk, hits):
                    encroached[i] = [labels[k] for k in np.flatnonzero(row)]
        return centres, radii, inside, encroached

    def _nearest_piece(self, r, centre):
        """(edge, piece) label of region r's boundary piece nearest to the 2D point ``centre``."""
        start, end, labels = self._piece_ends_2d(r)
        squared, _ = closest_on_segments(np.broadcast_to(centre, start.shape), start, end)
        return labels[int(np.argmin(squared))]
