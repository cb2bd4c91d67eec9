"""Binding: the record of a bind (sparse coordinates of points with respect to a cage) and deformation.

:func:`lbc_core.binding.pipeline.bind` makes one; :meth:`Binding.save` and :func:`~lbc_core.binding.files.load_binding`
write and read it. What the bind was asked (``Binding.options``, a :class:`~lbc_core.binding.options.BindOptions`) and
how it went (:class:`BindOutcome`) are kept apart.
"""

import enum
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from ..cage import Cage
from ..kernel.parallel import thread_map, worker_count
from ..meshing import DomainMesh
from .options import BindOptions

# Deforming fewer points than this is faster on one thread.
PARALLEL_MIN_POINTS = 50_000
INFLUENCE_FACTOR = 1e-3  # τ = INFLUENCE_FACTOR / n, the paper's threshold for "influenced"


def influence_threshold(n_control_points):
    """The paper's threshold τ = 1e-3 / n above which a coordinate influences a point (dimensionless)."""
    return INFLUENCE_FACTOR / n_control_points


def influence_counts(weights, threshold=None):
    """How many control points influence each point: #{i : |w_i| > threshold}.

    Parameters
    ----------
    weights : (m, n) scipy.sparse matrix or float array
    threshold : float, optional
        None: the paper's τ = 1e-3 / n (:func:`influence_threshold`).

    Returns
    -------
    (m,) int array
    """
    if threshold is None:
        threshold = influence_threshold(weights.shape[1])
    if sp.issparse(weights):
        weights = sp.csr_matrix(weights)
        large = np.abs(weights.data) > threshold
        rows = np.repeat(np.arange(weights.shape[0]), np.diff(weights.indptr))
        return np.bincount(rows[large], minlength=weights.shape[0])
    return np.count_nonzero(np.abs(weights) > threshold, axis=1)


class Start(str, enum.Enum):
    """Where a bind's solver started (:attr:`BindOutcome.start`); each member equals its text, as files hold it.

    Examples
    --------
    >>> Start.WARM == "previous solution", str(Start.COLD)
    (True, 'harmonic')
    """

    COLD = "harmonic"  # a bind from scratch: the harmonic-like start
    WARM = "previous solution"  # a warm re-bind, from the previous binding's solver state

    def __str__(self):
        return self.value


WARM, COLD = Start.WARM, Start.COLD


@dataclass(frozen=True)
class SolvedAgain:
    """What a warm re-bind solved and evaluated again (:attr:`BindOutcome.solved_again`).

    Attributes
    ----------
    cells_solved, cells : int
        Cells of the domain mesh solved again, of all its cells.
    points_evaluated, points : int
        Points whose weights were evaluated again, of all the points.
    """

    cells_solved: int
    cells: int
    points_evaluated: int
    points: int

    def __str__(self):
        return (f"{self.cells_solved} of {self.cells} cells solved, {self.points_evaluated} of {self.points} points "
                "evaluated")


@dataclass(frozen=True)
class BindOutcome:
    """How a bind went, apart from what it was asked (``Binding.options``).

    Attributes
    ----------
    start : Start or None
        Where the solver started: :attr:`Start.COLD` for a bind from scratch, :attr:`Start.WARM` for a warm
        re-bind; None for a baseline.
    iterations : int
        The solver's iterations (0 when there was nothing to iterate).
    converged : bool
        Whether the solve met its tolerance before its iteration limit.
    cells : int
        Cells of the domain mesh the bind reached (``options.cells`` is what it asked for, None for the default).
    threshold : float or None
        The reduction threshold the bind used (``options.threshold`` resolved); None for a baseline.
    solved_again : SolvedAgain or None
        A warm re-bind's counts; None for any other bind.
    report : str
        A re-bind's account, for the user: what it solved again, or why it bound from scratch; "" for a bind.
    travel : float
        How far the cage's vertices moved in all since its last bind from scratch: each warm re-bind's largest move
        of a control point, over the cage's diagonal, summed (0 for a bind from scratch).
    """

    start: Start = None
    iterations: int = 0
    converged: bool = True
    cells: int = 0
    threshold: float = None
    solved_again: SolvedAgain = None
    report: str = ""
    travel: float = 0.0


@dataclass
class Binding:
    """Coordinates of a set of points with respect to a cage, ready to deform them (made by :func:`lbc_core.bind`).

    Attributes
    ----------
    cage : Cage
    rest_cage_vertices : (n, d) float array
        Control points at bind time.
    weights : (m, n) scipy.sparse.csr_matrix
        Each point's coordinates; rows sum to 1 and reproduce the point's bound position.
    domain : DomainMesh
        The mesh of the cage's interior the coordinates were computed on.
    domain_weights : (N, n) float array
        Coordinates at the domain's vertices.
    outside : (m,) bool array
        Points outside the cage, whose rows extrapolate from the closest point of the domain, with signed weights:
        they reproduce the point, unless far outside a thin part of the cage (the extrapolation shortened toward that
        closest point) or where the fit there is too poor (the closest point itself).
    points : (m, d) float array
        The points at bind time; deformation is exact at the rest pose.
    scheme : str
        "lbc", or a baseline's name ("mvc", "harmonic", "bbw").
    options : BindOptions
        What the bind was asked (None: the default); what it reached or resolved (the cells, the threshold) is in
        ``outcome``.
    outcome : BindOutcome
        How it went: where the solver started, its iterations, what a re-bind solved again and why.
    timings : dict
        Seconds per stage.
    iterations, converged
        ``outcome.iterations`` and ``outcome.converged``.
    objective : float
        The weighted total variation of ``domain_weights`` (NaN for baselines).
    solver_state : lbc_core.solve.solver.SolverState or None
        The solver's final state, kept in memory (not saved) for a warm re-bind (:func:`lbc_core.rebind`).
    stale : (N,) float array or None
        Per domain vertex, how much its coordinates (the largest change of one) and position (in median cell edges)
        have changed since the points near it were last evaluated (None: not at all); kept in memory for a warm
        re-bind, which evaluates the points near a vertex again once this passes
        :data:`lbc_core.binding.rebinding.STALE`.
    """

    cage: Cage
    rest_cage_vertices: np.ndarray
    weights: sp.csr_matrix
    domain: DomainMesh
    domain_weights: np.ndarray
    outside: np.ndarray
    points: np.ndarray
    scheme: str = "lbc"
    options: BindOptions = field(default_factory=BindOptions)
    outcome: BindOutcome = field(default_factory=BindOutcome)
    timings: dict = field(default_factory=dict)
    objective: float = float("nan")
    solver_state: object = field(default=None, repr=False)
    stale: np.ndarray = field(default=None, repr=False)

    @property
    def iterations(self):
        return self.outcome.iterations

    @property
    def converged(self):
        return self.outcome.converged

    @property
    def outside_count(self):
        return int(np.count_nonzero(self.outside))

    def influence_counts(self, threshold=None):
        """Number of control points with a weight above ``threshold`` per point; (m,) int array.

        None: the paper's 1e-3 / n, as :func:`lbc_core.binding.record.influence_counts` counts.
        """
        return influence_counts(self.weights, threshold)

    def deform(self, new_cage_vertices):
        """Positions of the points for a moved cage.

        Displacement form, p + Σ w_i (c_i - c_i^rest), so the rest pose is exact; points outside the cage follow it
        by extrapolation (exactly under any affine move of the cage where their rows reproduce them).

        Parameters
        ----------
        new_cage_vertices : (n_input, d) float array
            The cage's vertices, in the order and number given to :func:`bind`.

        Returns
        -------
        (m, d) float array
        """
        displacement = self.cage.control_points_from_input(new_cage_vertices) - self.rest_cage_vertices
        moved = self.points.copy()

        def move(block):
            rows, weights = block
            moved[rows] += weights @ displacement

        thread_map(move, self._row_blocks)
        return moved

    @cached_property
    def _row_blocks(self):
        """The weights split into row blocks, one per thread for large meshes (CSR row slices copy: done once)."""
        m = self.weights.shape[0]
        count = worker_count() if m >= PARALLEL_MIN_POINTS else 1
        bounds = np.linspace(0, m, count + 1).astype(int)
        return [(slice(a, b), self.weights[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]

    def save(self, path):
        """Write the binding to ``path`` exactly (no suffix is added), as a compressed .npz archive with the cage's
        fingerprint, the options and the version.

        Raises
        ------
        CageError
            When the file cannot be written (missing folder, no permission, full disk); a file this call created
            is removed again.
        """
        from .files import save_binding  # the file format's own module, which imports this one

        save_binding(self, path)
