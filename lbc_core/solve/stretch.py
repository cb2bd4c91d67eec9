"""The frame a very thin 3D cage is solved in, where its cells are round, and how the total variation reads there."""

import numpy as np

from ..kernel.frame import MeshingFrame

# The stretch (in the meshing frame: frame.ASPECT_FLOOR / the cage's thinnest aspect) from which the solve runs
# stretched, and the most control points it does so for (bench/RESULTS.md, "Thin cages").
STRETCHED_SOLVE_FROM = 20.0
STRETCHED_MOST_CONTROL_POINTS = 20


class Stretch:
    """The linear map into the frame a thin 3D cage was meshed in (:class:`lbc_core.kernel.frame.MeshingFrame`), where its
    cells are round, and how the total variation reads there.

    u = x A with A = R diag(σ) (R the cage's principal axes), so ∇ₓw = A ∇ᵤw and |∇ₓw| = |σ ∘ ∇ᵤw|, and
    |c|ₓ = |c|ᵤ / Π σ. With a = σ / min σ: ω |c|ₓ |∇ₓw| = (ω min σ / Π σ) |c|ᵤ |a ∘ ∇ᵤw|.

    Attributes
    ----------
    matrix : (3, 3) float array, A
    axis_scale : (3,) float array, a (1 along the cage's long axes)
    tv_scale : float, min σ / Π σ
    """

    def __init__(self, matrix):
        self.matrix = matrix
        sigma = np.linalg.norm(matrix, axis=0)
        self.axis_scale = sigma / sigma.min()
        self.tv_scale = float(sigma.min() / np.prod(sigma))

    @classmethod
    def of(cls, controls, epsilon):
        """The stretch a solve uses for the cage with these (n, d) control points, or None: where it is not 3D, is
        stretched less than STRETCHED_SOLVE_FROM times, has more than STRETCHED_MOST_CONTROL_POINTS, or the total
        variation is Huber-relaxed (``epsilon`` > 0: its prox has no per-entry root form)."""
        if controls.shape[1] != 3 or epsilon > 0 or len(controls) > STRETCHED_MOST_CONTROL_POINTS:
            return None
        frame = MeshingFrame(controls)
        sigma = np.linalg.norm(frame.matrix, axis=0)
        return None if sigma.max() < STRETCHED_SOLVE_FROM * sigma.min() else cls(frame.matrix)

    def apply(self, points):
        """(P, 3) points → the stretched frame (linear: the solve does not care where the origin is)."""
        return points @ self.matrix

