"""The evaluators: how a bind turns the coordinates at its domain mesh's vertices into rows at its points.

An evaluator is a function ``(domain, located, request) -> rows``: ``located`` holds each point's barycentric row
in its cell (:func:`~lbc_core.evaluate.interpolation.interpolation_matrix`), ``request`` is an
:class:`EvaluationRequest`, and ``rows`` is what :func:`~lbc_core.evaluate.reduction.interpolate_and_reduce` reads:
an (m, N) CSR matrix, or an object with ``shape`` whose row slices are CSR matrices and which may carry ``linear``
(the points' barycentric rows, the fallback where a reduced row cannot meet the constraints) and ``outside`` (rows
that extrapolate to points outside the cage). :data:`EVALUATORS` names them; ``BindOptions(evaluation=...)``, ``lbc
bind --evaluation`` and the warm re-bind choose one by name. CONTRIBUTING.md says how to add one.
"""

from dataclasses import dataclass

import numpy as np

from ..kernel.progress import Progress
from .smoothing import SmoothInterpolation, radius_for


@dataclass(frozen=True)
class EvaluationRequest:
    """What an evaluator is told besides the mesh and the located points.

    Attributes
    ----------
    smoothness : float
        Smooth ↔ local, in [0, 1] (``BindOptions.smoothness``).
    reach : float
        Scales every length of the fit, in median cell edges: a warm re-bind's previous mesh's edge over this one's.
    points : (m, d) float array or None
        The points themselves (unit frame), so that the rows of those outside can extrapolate to them.
    outside : (m,) bool array or None
        The points outside the cage.
    progress : Progress
        Checked for cancellation as the rows are made.
    """

    smoothness: float
    reach: float = 1.0
    points: np.ndarray = None
    outside: np.ndarray = None
    progress: Progress = None


def smooth_rows(domain, located, request):
    """The default: each point's moving least-squares fit of the vertices around it (reaching as far as the
    smoothness says, not across gaps between parts of the cage), faded into its barycentric row near the cage
    (:class:`~lbc_core.evaluate.smoothing.SmoothInterpolation`): smooth in the point, where the mesh's own
    piecewise-linear interpolation creases along its cells' faces."""
    return SmoothInterpolation(domain.vertices, domain.cells, located, radius_edges=radius_for(request.smoothness),
                               reach=request.reach, progress=request.progress, points=request.points,
                               outside=request.outside)


def linear_rows(domain, located, request):
    """The paper's own evaluation: each point's barycentric row in its cell, the coordinates' piecewise-linear
    interpolation (exactly the solved values at the vertices, creased along the cells' faces, the fewest influences);
    a point outside the cage takes its closest domain point's row."""
    return located


# Every evaluator by name, the default first.
EVALUATORS = {"smooth": smooth_rows, "linear": linear_rows}
DEFAULT_EVALUATION = next(iter(EVALUATORS))
