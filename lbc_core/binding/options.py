"""What a bind is asked to do: one frozen :class:`BindOptions`, checked field by field when it is made.

``None`` means "the default" for every field. Defaults that do not depend on the cage are filled in on construction
(``BindOptions().weighting == "quadratic"``); ``cells``, ``threshold`` and ``tolerance`` stay None until a stage that
knows the cage's dimension or size resolves them (:data:`DEFAULT_CELLS`, 1e-3 / n, the solver's
``DEFAULT_TOLERANCE``). Every bad value is refused with one :class:`~lbc_core.errors.CageError` that lists all of
them, before any meshing or solving.
"""

import math
import numbers
from dataclasses import dataclass, replace

import numpy as np

from ..errors import CageError
from ..evaluate.evaluators import DEFAULT_EVALUATION, EVALUATORS
from ..evaluate.smoothing import DEFAULT_SMOOTHNESS
from ..meshing import AUTO, DEFAULT_CELLS, mesher, method_names
from ..solve.geodesics import WEIGHTINGS as _RHO

MIN_CELLS = 10
# The names of ρ in the geodesic TV weights ω = ρ(D), the paper's first: those lbc_core.solve.geodesics implements.
WEIGHTINGS = tuple(_RHO)
DEFAULT_EPSILON = 0.0
DEFAULT_MAX_ITERATIONS = 10000
# Weights below this fraction of 1/n are dropped from the stored coordinates by default.
DEFAULT_THRESHOLD_SHARE = 1e-3


@dataclass(frozen=True)
class BindOptions:
    """The options of :func:`lbc_core.bind`, checked on construction.

    Attributes
    ----------
    cells : int or None
        About how many triangles (2D) or tetrahedra (3D) fill the cage; at least 10. None: :data:`DEFAULT_CELLS`.
    weighting : str or callable
        ρ of the TV weights: one of :data:`WEIGHTINGS`, or a function mapping an (F, n) array of normalised
        geodesic distances in [0, 1] to non-negative weights of the same shape.
    epsilon : float
        C¹ relaxation width, ≥ 0, in units of the unit-diagonal cage (0: plain total variation).
    threshold : float or None
        Weights below it are dropped; in [0, 1/n) for a cage of n control points. None: 1e-3 / n.
    tolerance : float or None
        ADMM's relative stopping tolerance, > 0. None: the solver's default for the dimension.
    max_iterations : int
        At least 1.
    method : str
        Domain mesher: "auto" (the default, the bundled mesher) or a name of :data:`lbc_core.meshing.MESHERS` for
        the cage's dimension.
    smoothness : float or None
        Smooth ↔ local, in [0, 1]: the smooth evaluation's reach (:func:`lbc_core.evaluate.smoothing.radius_for`; 1
        folds bent joints least, 0 keeps each point's weights on the fewest cage vertices). None:
        :data:`DEFAULT_SMOOTHNESS`.
    evaluation : str
        How the coordinates at the domain mesh's vertices become weights at the points: a name of
        :data:`lbc_core.evaluate.evaluators.EVALUATORS`, "smooth" (the default) or "linear" (the paper's
        piecewise-linear interpolation).

    Raises
    ------
    CageError
        Naming every bad value, what it must be, and an example.
    """

    cells: int = None
    weighting: object = None
    epsilon: float = None
    threshold: float = None
    tolerance: float = None
    max_iterations: int = None
    method: str = None
    smoothness: float = None
    evaluation: str = None

    def __post_init__(self):
        problems = []
        for name in ("cells", "weighting", "epsilon", "threshold", "tolerance", "max_iterations", "method",
                     "smoothness", "evaluation"):
            try:
                value = _CHECKS[name](getattr(self, name))
            except _Bad as bad:
                problems.append(f"{name} {bad}")
            else:
                object.__setattr__(self, name, value)
        if problems:
            raise CageError("bad bind option" + ("s" if len(problems) > 1 else "") + ": " + "; ".join(problems))

    @classmethod
    def of(cls, options=None, **fields):
        """``options`` (a BindOptions or None) with the given fields that are not None put in, checked."""
        given = {name: value for name, value in fields.items() if value is not None}
        if options is None:
            return cls(**given)
        if not isinstance(options, cls):
            raise CageError(f"options must be a BindOptions, got {type(options).__name__}")
        return replace(options, **given)

    def check_for_cage(self, n_control_points, dim):
        """Refuse what only a cage can tell is wrong: the threshold against 1/n, the method against the dimension.

        Parameters
        ----------
        n_control_points : int
        dim : int, 2 or 3
        """
        if self.threshold is not None and self.threshold >= 1.0 / n_control_points:
            raise CageError(
                f"threshold {self.threshold:g} would drop every weight of a point whose {n_control_points} weights "
                f"are equal (they are 1/n = {1.0 / n_control_points:.4g}): give a threshold below that, e.g. "
                f"{DEFAULT_THRESHOLD_SHARE / n_control_points:.2g} (the default), or 0 to keep every weight"
            )
        mesher(dim, self.method)  # refuses a name that meshes no cage of this dimension

    def threshold_for(self, n_control_points):
        """The reduction threshold for a cage of ``n_control_points`` (the default 1e-3 / n when None)."""
        if self.threshold is None:
            return DEFAULT_THRESHOLD_SHARE / n_control_points
        return self.threshold


@dataclass(frozen=True)
class SavedWeighting:
    """A weighting function of the user's own, as a saved binding names it: the file keeps its name, not the function,
    so the binding loads and deforms, but nothing can be solved with it again (``lbc_core.rebind`` refuses it)."""

    name: str

    def __call__(self, distances):
        raise CageError(f"this binding was made with a weighting function of its own ({self.name}), which a saved "
                        "binding does not keep: bind from scratch with lbc_core.bind(..., weighting=that function)")


class _Bad(Exception):
    """One bad field: the message continues '<name> ...'."""


def _number(value, whole):
    """``value`` as a finite int (``whole``) or float; _Bad if it is not a real number."""
    if isinstance(value, (bool, np.bool_)):
        raise _Bad(f"must be a number, got {value!r} (a bool)")
    if isinstance(value, str):
        raise _Bad(f"must be a number, got the string {value!r}: pass a number, not text")
    if not isinstance(value, numbers.Real):
        raise _Bad(f"must be a real number, got {value!r} ({type(value).__name__})")
    if not math.isfinite(value):
        raise _Bad(f"must be a finite number, got {value!r}")
    if whole:
        if value != int(value):
            raise _Bad(f"must be a whole number, got {value!r}")
        return int(value)
    return float(value)


def _weighting(value):
    if value is None:
        return WEIGHTINGS[0]
    if isinstance(value, SavedWeighting):
        return value  # a loaded binding's: it refuses to be solved with, with its message
    if isinstance(value, str):
        if value not in WEIGHTINGS:
            raise _Bad(f"{value!r} is not one of {', '.join(WEIGHTINGS)} (or pass a function of the distance)")
        return value
    if not callable(value):
        raise _Bad(f"must be one of {', '.join(WEIGHTINGS)} or a function, got {value!r}")
    # Try the function on a few distances now rather than after meshing and geodesics.
    distances = np.linspace(0.0, 1.0, 6).reshape(3, 2)
    try:
        weights = np.asarray(value(distances), dtype=float)
    except Exception as error:  # the user's function may raise anything; the message names it
        raise _Bad(f"function failed on an array of distances in [0, 1] ({type(error).__name__}: {error})") from None
    if weights.shape != distances.shape:
        raise _Bad(f"function must return weights of its input's shape: on a {distances.shape} array of distances "
                   f"it returned shape {weights.shape}")
    if not np.all(np.isfinite(weights)) or np.any(weights < 0):
        raise _Bad(f"function must return finite, non-negative weights: on distances {distances.ravel().tolist()} it "
                   f"returned {weights.ravel().tolist()}")
    return value


def _bounded(default, whole, accept, advice):
    """A check of a number: None gives ``default``; else a finite real (whole when ``whole``) that ``accept`` takes,
    or _Bad with ``advice`` formatted with the value."""

    def check(value):
        if value is None:
            return default
        value = _number(value, whole)
        if not accept(value):
            raise _Bad(advice.format(value=value))
        return value

    return check


def _evaluation(value):
    if value is None:
        return DEFAULT_EVALUATION
    if not isinstance(value, str) or value not in EVALUATORS:
        raise _Bad(f"{value!r} is not one of {', '.join(EVALUATORS)}")
    return value


def _method(value):
    if value is None:
        return AUTO
    names = method_names()
    if not isinstance(value, str) or value not in names:
        raise _Bad(f"{value!r} is not one of {', '.join(names)}")
    return value


_CHECKS = {
    "cells": _bounded(None, True, lambda value: value >= MIN_CELLS,
                      f"must be at least {MIN_CELLS}, got {{value}}: e.g. {DEFAULT_CELLS[2]} in 2D or {DEFAULT_CELLS[3]} "
                      "in 3D (left out, or None: these defaults)"),
    "weighting": _weighting,
    "epsilon": _bounded(DEFAULT_EPSILON, False, lambda value: value >= 0,
                        "must be 0 or more, got {value:g}: 0 is the paper's plain total variation, e.g. 0.01 smooths"),
    "threshold": _bounded(None, False, lambda value: 0 <= value < 1,
                          "must be in [0, 1/n) for a cage of n control points, got {value:g}: left out (None) it "
                          "is 1e-3/n"),
    "tolerance": _bounded(None, False, lambda value: value > 0,
                          "must be more than 0, got {value:g}: e.g. 1e-4 (left out, or None: the solver's default)"),
    "max_iterations": _bounded(DEFAULT_MAX_ITERATIONS, True, lambda value: value >= 1,
                               f"must be at least 1, got {{value}} (left out, or None: {DEFAULT_MAX_ITERATIONS})"),
    "method": _method,
    "smoothness": _bounded(DEFAULT_SMOOTHNESS, False, lambda value: 0 <= value <= 1,
                           f"must be in [0, 1], got {{value:g}}: 0 the most local weights, 1 the smoothest joints "
                           f"(left out, or None: {DEFAULT_SMOOTHNESS:g})"),
    "evaluation": _evaluation,
}
