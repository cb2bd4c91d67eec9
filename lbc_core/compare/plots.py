"""Figures for comparing coordinates: a coordinate function with its locality level set (paper Figs. 4, 7), the
P(t) and Q(k) graphs of several schemes (Figs. 14, 15), and a 2D deformation with a checkerboard (Figs. 10, 17).

Figures are drawn on :class:`matplotlib.figure.Figure` objects without pyplot, so no global backend is switched and
nothing opens a window; the file's extension (.png, .svg, .pdf) picks the format.
"""

import numpy as np
from matplotlib.figure import Figure
from matplotlib.tri import Triangulation

from .statistics import influence, influence_threshold, locality

DPI = 110
THRESHOLDS = np.logspace(-8, 0, 49)  # t for the P(t) graph, dimensionless
LABELS = {"lbc": "LBC", "mvc": "MVC", "harmonic": "harmonic", "bbw": "BBW"}
SCHEME_STYLES = {  # colour, line style: LBC stands out, the baselines are told apart in grey print too
    "lbc": ("#d62728", "-"),
    "mvc": ("#1f77b4", "--"),
    "harmonic": ("#2ca02c", "-."),
    "bbw": ("#9467bd", ":"),
}


def plot_coordinate(binding, index, path, title=None):
    """Draw coordinate function ``index`` over a 2D domain with its 1e-3/n level set and the cage.

    Parameters
    ----------
    binding : Binding
        A 2D binding (its ``domain`` and ``domain_weights`` are drawn).
    index : int
        The control point whose coordinate is drawn.
    path : str or Path
        Output file; the extension picks the format.
    title : str or None
        Defaults to the scheme and control point.
    """
    _require_2d(binding)
    domain, cage = binding.domain, binding.cage
    values = binding.domain_weights[:, index]
    tau = influence_threshold(cage.n_control_points)
    figure = Figure(figsize=(5.0, 5.0), dpi=DPI)
    axes = figure.add_subplot()
    triangulation = Triangulation(domain.vertices[:, 0], domain.vertices[:, 1], domain.cells)
    low = min(0.0, float(values.min()))
    shading = axes.tripcolor(triangulation, values, shading="gouraud", cmap="viridis", vmin=low, vmax=1.0)
    if values.max() > tau > values.min():
        axes.tricontour(triangulation, values, levels=[tau], colors="#ff3030", linewidths=1.2)
    _draw_cage(axes, cage.vertices, cage.facets)
    axes.plot(*cage.vertices[index], "o", color="#ff3030", markersize=7, markeredgecolor="white")
    figure.colorbar(shading, ax=axes, shrink=0.8, label=f"w_{index}   (red: level {tau:.1e} = 1e-3/n)")
    axes.set_title(title or f"{_label(binding)}: coordinate of control point {index}")
    _finish_2d(axes)
    figure.savefig(path, bbox_inches="tight")


def plot_locality(bindings, path):
    """Draw P(t) (Eq. 20) and Q(k) (Eq. 21) of several schemes side by side.

    Parameters
    ----------
    bindings : dict of name -> Binding
        Bindings of one cage (their domains may differ; each is measured on its own).
    path : str or Path
    """
    figure = Figure(figsize=(10.0, 4.0), dpi=DPI)
    p_axes, q_axes = figure.subplots(1, 2)
    n = None
    for name, binding in bindings.items():
        color, style = SCHEME_STYLES.get(binding.scheme, (None, "-"))
        n = binding.domain_weights.shape[1]
        p = locality(binding.domain, binding.domain_weights, THRESHOLDS)
        ks, q = influence(binding.domain, binding.domain_weights)
        p_axes.semilogx(THRESHOLDS, p, style, color=color, label=name)
        q_axes.step(ks, q, style, where="mid", color=color, label=name)
    tau = influence_threshold(n)
    p_axes.axvline(tau, color="0.5", linewidth=0.8)
    p_axes.annotate(" t = 1e-3/n", (tau, 0.02), color="0.4", fontsize=8)
    p_axes.set(xlabel="t", ylabel="P(t)", ylim=(0.0, 1.02), title="P(t): share of the domain where |w_i| ≤ t")
    q_axes.set(
        xlabel="k", ylabel="Q(k)", ylim=(0.0, 1.02), xlim=(0.5, n + 0.5),
        title="Q(k): share influenced by ≥ k control points",
    )
    for axes in (p_axes, q_axes):
        axes.grid(True, alpha=0.3)
        axes.legend()
    figure.tight_layout()
    figure.savefig(path)


def plot_deformation(binding, new_cage_vertices, path, squares=10, subdivisions=4):
    """Draw a 2D domain with a checkerboard before and after moving the cage.

    Parameters
    ----------
    binding : Binding
        A 2D binding; the deformed domain is ``domain_weights @ new control points``.
    new_cage_vertices : (n_input, 2) float array
        The cage's vertices (as given to bind) in the new pose.
    path : str or Path
    squares : int
        Checker squares along the longer side of the cage's bounding box.
    subdivisions : int
        Each domain triangle is split into subdivisions² triangles for drawing, so the squares' edges are sharp
        (the deformation is linear on each domain triangle, so the split triangles are exact).
    """
    _require_2d(binding)
    cage, domain = binding.cage, binding.domain
    moved = cage.control_points_from_input(np.asarray(new_cage_vertices, dtype=float))
    deformed = binding.domain_weights @ moved
    barycentric, sub_cells = _lattice(subdivisions)
    rest_points = np.einsum("sk,fkx->fsx", barycentric, domain.vertices[domain.cells]).reshape(-1, 2)
    moved_points = np.einsum("sk,fkx->fsx", barycentric, deformed[domain.cells]).reshape(-1, 2)
    cells = (np.arange(len(domain.cells))[:, None, None] * len(barycentric) + sub_cells[None]).reshape(-1, 3)
    side = np.ptp(cage.vertices, axis=0).max() / squares
    lower = cage.vertices.min(axis=0)
    checker = np.sin(np.pi * (rest_points[:, 0] - lower[0]) / side) * np.sin(np.pi * (rest_points[:, 1] - lower[1]) / side)
    figure = Figure(figsize=(10.0, 5.0), dpi=DPI)
    for axes, points, control, title in zip(
        figure.subplots(1, 2), (rest_points, moved_points), (cage.vertices, moved), ("rest", "deformed")
    ):
        triangulation = Triangulation(points[:, 0], points[:, 1], cells)
        # Squares are the sign of a product of sines: contour-filling it gives sharp, straight-where-linear edges.
        axes.tricontourf(triangulation, checker, levels=[-1.5, 0.0, 1.5], colors=["#e8e8e8", "#5a5a5a"])
        _draw_cage(axes, control, cage.facets)
        axes.set_title(f"{_label(binding)}, {title}")
        _finish_2d(axes)
    figure.tight_layout()
    figure.savefig(path)


def _lattice(subdivisions):
    """The regular split of a triangle: barycentric points (s, 3) and sub-triangles (subdivisions², 3)."""
    r = subdivisions
    index, points = {}, []
    for i in range(r + 1):
        for j in range(r + 1 - i):
            index[i, j] = len(points)
            points.append((r - i - j, i, j))
    cells = []
    for i in range(r):
        for j in range(r - i):
            cells.append((index[i, j], index[i + 1, j], index[i, j + 1]))
            if i + j < r - 1:
                cells.append((index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]))
    return np.array(points, dtype=float) / r, np.array(cells)


def _draw_cage(axes, vertices, facets):
    segments = vertices[facets]  # (E, 2, 2)
    for a, b in segments:
        axes.plot([a[0], b[0]], [a[1], b[1]], color="black", linewidth=1.3)
    axes.plot(vertices[:, 0], vertices[:, 1], "o", color="black", markersize=3.5)


def _finish_2d(axes):
    # A margin, so the cage's outermost vertices are not cut by the frame (filled contours pin the limits to the data).
    axes.use_sticky_edges = False
    axes.margins(0.03)
    axes.set_aspect("equal")
    axes.set_xticks([])
    axes.set_yticks([])


def _label(binding):
    return LABELS.get(binding.scheme, binding.scheme)


def _require_2d(binding):
    if binding.cage.dim != 2:
        raise ValueError("this figure draws 2D bindings only; for 3D cages use plot_locality")
