"""Which coordinates each interior vertex may hold, and the solver's operators restricted to them.

A vertex's *working set* is the control points whose coordinates may be non-zero there; each (vertex, control point)
of it is a *slot*. The coordinates outside the working sets are held at 0, so the problem on the working sets is the
LBC problem with more zeros imposed: the same problem wherever the working sets cover the solution's support. The
solver keeps one ring of mesh vertices of margin around the support, growing the sets (:meth:`WorkingSets.grown`)
where a coordinate turns positive next to a vertex that cannot hold it. Sets that hold most of all the slots anyway
(cages whose coordinates spread wide, as Blender's Cylinder with its n-gon caps) are made whole, so that every control
point's block of the step's matrix is the same and one factorisation serves them all.

A coordinate's gradient is non-zero only on the cells that touch a vertex holding it (a slot or a fixed non-zero
boundary value): the (cell, control point) *pairs*. :class:`PairOperators` holds, on the pairs, the gradient operator,
the boundary values' part of it, the matrix of the least-squares step (P1 stiffness + β mass, block-diagonal over
the control points, factorised once per layout), and the rows padded per vertex for the projection. Their sizes
follow the slots and pairs, not the number of control points.
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..kernel import fem
from .pairs import PaddedRows, key_positions
from .projection import project_rows

# The harmonic coordinates' largest entries a vertex's first working set takes, then twice as many until the vertex's
# position lies in their control points' hull (bench/RESULTS.md, "The locality solver").
FIRST_SET_SIZE = 12
# Working sets holding more than this share of all (vertex, control point) slots are made whole: every control
# point's block of the step's matrix is then the same, one factor for all (bench/RESULTS.md, "The locality solver,
# third round").
WHOLE_FROM = 0.6


@dataclass
class WorkingSets:
    """The slots: for each interior vertex (in ``interior`` order) the sorted control points it may hold.

    Attributes
    ----------
    indptr : (N_in + 1,) int array
        Slots of interior vertex k: ``indptr[k]:indptr[k + 1]``.
    controls : (S,) int array
        The control point of each slot.
    n_controls : int
    """

    indptr: np.ndarray
    controls: np.ndarray
    n_controls: int

    @property
    def n_slots(self):
        return len(self.controls)

    @property
    def vertex_of_slot(self):
        """(S,) int array: the interior vertex (its position in ``interior``) of each slot."""
        return np.repeat(np.arange(len(self.indptr) - 1), np.diff(self.indptr))

    def matrix(self, values=None):
        """The slots as an (N_in, n) CSR matrix holding ``values`` (1 by default)."""
        data = np.ones(self.n_slots) if values is None else values
        return sp.csr_matrix((data, self.controls, self.indptr), shape=(len(self.indptr) - 1, self.n_controls))

    @classmethod
    def from_matrix(cls, matrix):
        """The working sets of an (N_in, n) sparse matrix's non-zero pattern."""
        matrix = sp.csr_matrix(matrix)
        matrix.sum_duplicates()
        matrix.sort_indices()
        return cls(matrix.indptr.astype(np.int64), matrix.indices.astype(np.int64), matrix.shape[1])

    @property
    def whole(self):
        """Whether every interior vertex holds every control point."""
        return self.n_slots == (len(self.indptr) - 1) * self.n_controls

    def widened(self):
        """These sets, or every control point at every vertex where they hold more than WHOLE_FROM of them all."""
        if self.whole or self.n_slots <= WHOLE_FROM * (len(self.indptr) - 1) * self.n_controls:
            return self
        n_rows, n = len(self.indptr) - 1, self.n_controls
        return WorkingSets(np.arange(n_rows + 1, dtype=np.int64) * n, np.tile(np.arange(n, dtype=np.int64), n_rows), n)

    def reshaped(self, required, kept):
        """These working sets with the pattern of ``required`` added and the slots outside ``kept`` dropped (both
        (N_in, n) sparse patterns, ``kept`` covering ``required``), :meth:`widened`; None when nothing changes."""
        if self.whole:
            return None
        current = self.matrix()
        union = (current.multiply(kept) + sp.csr_matrix(required, dtype=float)).astype(bool).astype(float)
        union.eliminate_zeros()
        if union.nnz == self.n_slots and current.multiply(union).nnz == self.n_slots:
            return None
        return WorkingSets.from_matrix(union).widened()

    def grown(self, required):
        """These working sets with the pattern of ``required`` added; None when it adds nothing."""
        return self.reshaped(required, self.matrix() + sp.csr_matrix(required, dtype=float))

    def slot_positions(self, other):
        """Where each of this layout's slots sits in ``other``, -1 where ``other`` has no such slot."""
        keys = self.vertex_of_slot * self.n_controls + self.controls
        return key_positions(keys, other.vertex_of_slot * other.n_controls + other.controls)




def first_working_sets(mesh, harmonic, check):
    """The working sets a cold solve starts from, and its first weights on them.

    Each vertex takes the FIRST_SET_SIZE control points of its largest harmonic coordinates, then twice as many until
    its position lies in their control points' hull (the harmonic row itself is feasible, so this ends), and its
    first weights are the harmonic row's projection onto its constraints on that set.

    Parameters
    ----------
    mesh : MeshData
    harmonic : (N_in, n) float array
        The harmonic coordinates at the interior vertices.
    check : callable() raising Cancelled

    Returns
    -------
    WorkingSets, (S,) float array of weights, (N_in, d+1) float array of the projection's duals
    """
    return _until_feasible(mesh, sp.csr_matrix(harmonic.shape), np.argsort(-harmonic, axis=1), harmonic, None, check)


def feasible_working_sets(mesh, sets, values, duals, check):
    """``sets`` with control points added, nearest first, at the vertices whose position lies outside the hull of
    their set's control points (a warm start's mesh, moved): the sets, the projection of ``values`` (S,) onto them,
    and the projection's duals."""
    distances = np.linalg.norm(mesh.unit_interior[:, None, :] - mesh.unit_controls[None, :, :], axis=2)
    return _until_feasible(mesh, sets.matrix(), np.argsort(distances, axis=1), sets.matrix(values).toarray(), duals,
                           check, first_size=np.zeros(len(distances), dtype=np.int64))


def _until_feasible(mesh, base, order, values, duals, check, first_size=None):
    """The slots of ``base`` (an (N_in, n) pattern) plus, per vertex, the first ``size`` control points of its row of
    ``order``, ``size`` doubling (from FIRST_SET_SIZE, or ``first_size``) where the vertex's position lies outside
    their hull; the rows of ``values`` (N_in, n) projected onto their constraints."""
    n_rows, n = values.shape
    size = np.full(n_rows, min(FIRST_SET_SIZE, n)) if first_size is None else np.asarray(first_size)
    while True:
        check()
        keep = np.arange(n)[None, :] < size[:, None]
        rows = np.repeat(np.arange(n_rows), size)
        added = sp.csr_matrix((np.ones(len(rows)), (rows, order[keep])), shape=values.shape)
        sets = WorkingSets.from_matrix(added + base.astype(bool).astype(float))
        padded = PaddedRows(sets, mesh)
        weights, duals_out, feasible = project_rows(padded.gather(values[sets.vertex_of_slot, sets.controls]),
                                                    padded.corners, padded.targets, duals,
                                                    products=padded.products)
        # Rows that hold every control point already can grow no further (a cage so thin that the projection's
        # tolerance is out of reach there): doubling the others' would loop for ever.
        if feasible.all() or (size[~feasible] >= n).all():
            weights, whole = padded.scatter(weights), sets.widened()
            if whole is not sets:  # the weights are feasible on the wider sets too, zero in the new slots
                widened = np.zeros(whole.n_slots)
                widened[sets.slot_positions(whole)] = weights
                sets, weights = whole, widened
            return sets, weights, duals_out
        size[~feasible] = np.minimum(np.maximum(2 * size[~feasible], size[~feasible] + 4), n)


@dataclass
class MeshData:
    """The mesh of one solve, in the frame it is solved in, with what every layout reads.

    Attributes
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array
    interior : (N_in,) int array
        The vertices not on the cage, sorted.
    interior_position : (N,) int array
        Each vertex's position in ``interior``, -1 on the cage.
    fixed : (N, n) CSR matrix
        The boundary values on the cage's vertices (rows of interior vertices empty).
    boundary_weights : (B, n) float array
        The boundary values as given, row k for the vertex ``boundary_position`` names k.
    boundary_position : (N,) int array
        Each vertex's row in ``boundary_weights``, -1 inside.
    cell_on_cage : (F,) bool array
        Cells with a corner on the cage: only their pairs carry boundary values.
    scaled_gradients : (F, d+1, d) float array
        √|c| ∇φ of each cell's corners.
    sqrt_cell : (F,) float array
    sqrt_mass : (N_in,) float array
        √(β m_v) of each interior vertex.
    adjacency : (N, N) CSR matrix
        Vertices sharing a cell (the diagonal included).
    unit_controls : (n, d) float array
        The control points in the frame of the constraints (the unit frame, even where the solve is stretched).
    unit_interior : (N_in, d) float array
        The interior vertices in that frame.
    system : (N_in, N_in) CSR matrix
        P1 stiffness + diag(β m) on the interior vertices: each control point's block of the least-squares step's
        matrix is its principal submatrix on the vertices holding that control point.
    """

    vertices: np.ndarray
    cells: np.ndarray
    interior: np.ndarray
    interior_position: np.ndarray
    fixed: sp.csr_matrix
    boundary_weights: np.ndarray
    boundary_position: np.ndarray
    cell_on_cage: np.ndarray
    scaled_gradients: np.ndarray
    sqrt_cell: np.ndarray
    sqrt_mass: np.ndarray
    adjacency: sp.csr_matrix
    unit_controls: np.ndarray
    unit_interior: np.ndarray
    system: sp.csr_matrix

    @classmethod
    def of(cls, vertices, cells, boundary_vertices, boundary_weights, beta, unit_controls, unit_vertices):
        n_vertices, n = len(vertices), boundary_weights.shape[1]
        gradients, measures = fem.cell_gradients(vertices, cells)
        sqrt_cell = np.sqrt(measures)
        interior = np.setdiff1d(np.arange(n_vertices), boundary_vertices)
        position = np.full(n_vertices, -1)
        position[interior] = np.arange(len(interior))
        fixed = sp.csr_matrix(boundary_weights)
        fixed.eliminate_zeros()
        fixed = sp.csr_matrix((fixed.data, fixed.indices, fixed.indptr), shape=fixed.shape)
        rows = boundary_vertices[np.repeat(np.arange(len(boundary_vertices)), np.diff(fixed.indptr))]
        fixed = sp.csr_matrix((fixed.data, (rows, fixed.indices)), shape=(n_vertices, n))
        mass = fem.lumped_mass(cells, measures, n_vertices)[interior]
        corners = np.repeat(cells, cells.shape[1], axis=1).ravel()
        others = np.tile(cells, (1, cells.shape[1])).ravel()
        adjacency = sp.csr_matrix((np.ones(len(corners)), (corners, others)), shape=(n_vertices, n_vertices))
        adjacency.data[:] = 1.0
        boundary_position = np.full(n_vertices, -1)
        boundary_position[boundary_vertices] = np.arange(len(boundary_vertices))
        scaled = gradients * sqrt_cell[:, None, None]
        return cls(vertices, cells, interior, position, fixed, boundary_weights, boundary_position,
                   (boundary_position[cells] >= 0).any(axis=1), scaled, sqrt_cell, np.sqrt(beta * mass), adjacency,
                   unit_controls, unit_vertices[interior], _interior_system(scaled, cells, position, beta * mass))

    def margins(self, sets, weights):
        """The slots within one ring and within two rings of mesh vertices around the positive ``weights`` (S,)
        and the boundary values, as (N_in, n) sparse patterns."""
        support = self._on_all_vertices(sets.matrix((weights > 0).astype(float))) + self.fixed
        one_ring = self.adjacency @ support.astype(bool).astype(float)
        two_rings = self.adjacency @ one_ring.astype(bool).astype(float)
        return (one_ring[self.interior].astype(bool).astype(float),
                two_rings[self.interior].astype(bool).astype(float))

    def _on_all_vertices(self, matrix):
        """An (N_in, n) matrix's rows placed at the interior vertices of an (N, n) one."""
        matrix = sp.csr_matrix(matrix)
        matrix.eliminate_zeros()
        counts = np.zeros(len(self.vertices), dtype=np.int64)
        counts[self.interior] = np.diff(matrix.indptr)
        return sp.csr_matrix((matrix.data, matrix.indices, np.r_[0, np.cumsum(counts)]),
                             shape=(len(self.vertices), matrix.shape[1]))


def _interior_system(scaled_gradients, cells, interior_position, mass):
    """Σ_c (√|c| ∇φ_u)·(√|c| ∇φ_v) over the interior vertices u, v, plus diag(``mass``): (N_in, N_in) CSR."""
    corners = cells.shape[1]
    products = np.einsum("fik,fjk->fij", scaled_gradients, scaled_gradients).ravel()
    rows = interior_position[np.repeat(cells, corners, axis=1).ravel()]
    columns = interior_position[np.tile(cells, (1, corners)).ravel()]
    inside = (rows >= 0) & (columns >= 0)
    n_interior = len(mass)
    system = sp.csr_matrix((products[inside], (rows[inside], columns[inside])), shape=(n_interior, n_interior))
    system.sum_duplicates()
    return (system + sp.diags(mass)).tocsr()
