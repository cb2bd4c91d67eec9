"""The paper's locality statistics (Section 5, Eqs. 20-21, Table 1), for any scheme's :class:`Binding`.

Discretisation. The coordinate functions are the binding's ``domain_weights``, taken as linear on each cell of its
``domain`` mesh (exact for LBC and harmonic coordinates, the P1 interpolant of mean value coordinates).

* P(t) (Eq. 20) = (1/n) Σ_i |{x ∈ Ω : |w_i(x)| ≤ t}| / |Ω|. Each cell's share is exact for the linear interpolant:
  the measure of {w ≤ s} in a simplex has a closed form in the sorted corner values (a corner simplex, its
  complement, or in 3D a prism cut into three tetrahedra), and {|w| ≤ t} = {w ≤ t} minus {w < -t}.
* Q(k) (Eq. 21) = |{x ∈ Ω : #{i : |w_i(x)| > τ} ≥ k}| / |Ω| with τ = 1e-3 / n. The joint count of n linear
  functions has no per-cell closed form, so it is taken at each cell's centroid (where the linear interpolant is the
  mean of the corner values), weighted by the cell's measure. Counting at the vertices instead would give the cage
  boundary, where only d coordinates are non-zero, a share of the domain that vanishes only as the mesh is refined.
* Influence counts per point: #{i : |w_i(p)| > τ} for each bound point p, from the stored weights.
* Memory and deform time (Table 1): LBC's reduced weights as stored (CSR: float64 values, int32 column indices,
  int32 row pointers), the baselines as the dense float64 (m, n) array they are naturally stored in; deform time is
  the product weights @ cage of that storage, the least over repeated runs.
"""

import time

import numpy as np
import scipy.sparse as sp

from ..binding.record import influence_counts, influence_threshold
from ..kernel.fem import cell_gradients

SPARSE_SCHEMES = ("lbc",)  # stored as CSR; every other scheme's weights are dense


def locality(domain, weights, thresholds):
    """P(t), Eq. 20: the fraction of the domain where |w_i| ≤ t, averaged over the control points.

    Parameters
    ----------
    domain : DomainMesh
    weights : (N, n) float array
        Coordinate values at the domain's vertices, linear on each cell.
    thresholds : (T,) float array
        Values of t, dimensionless, non-negative.

    Returns
    -------
    (T,) float array in [0, 1]
    """
    weights = np.asarray(weights, dtype=float)
    _, measures = cell_gradients(domain.vertices, domain.cells)
    share = measures / measures.sum()
    n = weights.shape[1]
    result = np.zeros(len(np.atleast_1d(thresholds)))
    # Column blocks keep the (F, d+1, block) sorted corner values to a few tens of MB.
    block = max(1, 2_000_000 // domain.cells.size)
    for start in range(0, n, block):
        corners = np.sort(weights[domain.cells, start : start + block], axis=1)  # (F, d+1, b)
        corners = np.moveaxis(corners, 1, 2).reshape(-1, corners.shape[1])  # (F b, d+1), cell-major
        cell_share = np.repeat(share, corners.shape[0] // len(share))
        for k, t in enumerate(np.atleast_1d(thresholds)):
            inside = _fraction_below(corners, t, strict=False) - _fraction_below(corners, -t, strict=True)
            result[k] += cell_share @ inside
    return result / n


def _fraction_below(corners, s, strict):
    """Fraction of each simplex where the linear interpolant of its corner values is ≤ s (or < s if strict).

    Parameters
    ----------
    corners : (K, d+1) float array
        Corner values of K simplices, each row sorted ascending, d = 2 or 3.
    s : float
    strict : bool
        Only differs from non-strict on cells where the function is constant and equal to s.

    Returns
    -------
    (K,) float array in [0, 1]
    """
    a = corners
    count = np.count_nonzero(a < s if strict else a <= s, axis=1)  # corners below: which closed form applies
    fraction = (count == a.shape[1]).astype(float)
    # Each branch divides only by differences that are positive where it applies.
    one = count == 1  # the corner simplex at v0, scaled by (s - a0) / (aj - a0) along edge j
    fraction[one] = np.prod((s - a[one, :1]) / (a[one, 1:] - a[one, :1]), axis=1)
    all_but_one = count == a.shape[1] - 1  # the complement of the corner simplex at the top vertex
    fraction[all_but_one] = 1.0 - np.prod(
        (a[all_but_one, -1:] - s) / (a[all_but_one, -1:] - a[all_but_one, :-1]), axis=1
    )
    if a.shape[1] == 4:
        two = count == 2
        fraction[two] = _prism_fraction(a[two], s)
    return np.clip(fraction, 0.0, 1.0)


def _prism_fraction(a, s):
    """Fraction of tetrahedra with sorted corner values a0 ≤ a1 ≤ s ≤ a2 ≤ a3 where the interpolant is ≤ s.

    That region is a prism with triangles (v0, q02, q03) and (v1, q12, q13), qij being where the level s crosses
    edge ij; its lateral faces are planar, so it splits exactly into three tetrahedra, whose volume fractions are the
    absolute determinants of their corners' barycentric coordinates.

    Parameters
    ----------
    a : (K, 4) float array
    s : float

    Returns
    -------
    (K,) float array
    """
    eye = np.eye(4)

    def crossing(i, j):  # barycentric coordinates (K, 4) of the level crossing on edge ij
        t = ((s - a[:, i]) / (a[:, j] - a[:, i]))[:, None]
        return (1.0 - t) * eye[i] + t * eye[j]

    v0 = np.broadcast_to(eye[0], (len(a), 4))
    v1 = np.broadcast_to(eye[1], (len(a), 4))
    q02, q03, q12, q13 = crossing(0, 2), crossing(0, 3), crossing(1, 2), crossing(1, 3)
    total = np.zeros(len(a))
    for tet in ((v0, q02, q03, v1), (q02, q03, v1, q12), (q03, v1, q12, q13)):
        total += np.abs(np.linalg.det(np.stack(tet, axis=1)))
    return total


def influence(domain, weights, ks=None):
    """Q(k), Eq. 21: the fraction of the domain influenced by at least k control points (|w_i| > 1e-3 / n).

    Parameters
    ----------
    domain : DomainMesh
    weights : (N, n) float array
        Coordinate values at the domain's vertices.
    ks : (K,) int array or None
        Values of k; None for 1 … n.

    Returns
    -------
    ks : (K,) int array
    q : (K,) float array in [0, 1], non-increasing in k
    """
    weights = np.asarray(weights, dtype=float)
    n = weights.shape[1]
    ks = np.arange(1, n + 1) if ks is None else np.asarray(ks, dtype=int)
    _, measures = cell_gradients(domain.vertices, domain.cells)
    threshold = influence_threshold(n)
    counts = np.zeros(len(domain.cells), dtype=int)
    block = max(1, 2_000_000 // domain.cells.size)
    for start in range(0, n, block):
        centroid_values = weights[domain.cells, start : start + block].mean(axis=1)  # (F, b)
        counts += np.count_nonzero(np.abs(centroid_values) > threshold, axis=1)
    # Measure influenced by exactly c control points, then the tail sums: Q(k) = share with count >= k.
    by_count = np.bincount(counts, weights=measures, minlength=n + 1)
    at_least = np.minimum(np.cumsum(by_count[::-1])[::-1] / measures.sum(), 1.0)  # round-off can pass 1
    return ks, np.where(ks > n, 0.0, at_least[np.clip(ks, 0, n)])


def stored_weights(binding):
    """The binding's point weights in the storage Table 1 measures: CSR for LBC, dense for the baselines.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix or float array
    """
    if binding.scheme in SPARSE_SCHEMES:
        return sp.csr_matrix(binding.weights)
    return np.asarray(binding.weights.toarray() if sp.issparse(binding.weights) else binding.weights, dtype=float)


def memory_bytes(weights):
    """Bytes of the stored weights: CSR arrays (values, column indices, row pointers) or the dense array."""
    if sp.issparse(weights):
        weights = sp.csr_matrix(weights)
        # int32 indices are what any matrix with fewer than 2^31 entries needs.
        return weights.data.nbytes + 4 * (weights.indices.size + weights.indptr.size)
    return np.asarray(weights).nbytes


def deform_seconds(weights, control_points, min_total=0.2, max_repeats=200):
    """Time of one deformation weights @ control_points, the least over repeated runs.

    Parameters
    ----------
    weights : (m, n) scipy.sparse.csr_matrix or float array
    control_points : (n, d) float array
    min_total : float
        Repeat until this many seconds have been spent (or ``max_repeats`` runs), so short products are timed stably.

    Returns
    -------
    float, seconds
    """
    control_points = np.ascontiguousarray(control_points, dtype=float)
    best, spent, repeats = np.inf, 0.0, 0
    while (spent < min_total or repeats < 3) and repeats < max_repeats:
        start = time.perf_counter()
        weights @ control_points
        elapsed = time.perf_counter() - start
        best, spent, repeats = min(best, elapsed), spent + elapsed, repeats + 1
    return best


def summary(binding):
    """The locality figures of one binding, as a flat dict of plain numbers (JSON-ready).

    Returns
    -------
    dict with keys scheme, control_points, points, domain_vertices, domain_cells, influence_max, influence_mean
    (per bound point), P_tau (P at τ = 1e-3/n), Q_2, Q_4, Q_8 (Q at k = 2, 4, 8), memory_bytes, deform_seconds,
    and the binding's timings as time_<stage> in seconds.
    """
    n = binding.weights.shape[1]
    tau = influence_threshold(n)
    counts = influence_counts(binding.weights)
    _, q = influence(binding.domain, binding.domain_weights, ks=[2, 4, 8])
    stored = stored_weights(binding)
    result = {
        "scheme": binding.scheme,
        "control_points": int(n),
        "points": int(binding.weights.shape[0]),
        "domain_vertices": int(len(binding.domain.vertices)),
        "domain_cells": int(len(binding.domain.cells)),
        "influence_max": int(counts.max()) if len(counts) else 0,
        "influence_mean": float(counts.mean()) if len(counts) else 0.0,
        "P_tau": float(locality(binding.domain, binding.domain_weights, [tau])[0]),
        "Q_2": float(q[0]),
        "Q_4": float(q[1]),
        "Q_8": float(q[2]),
        "memory_bytes": int(memory_bytes(stored)),
        "deform_seconds": float(deform_seconds(stored, binding.cage.vertices)),
    }
    for stage, seconds in (binding.timings or {}).items():
        result[f"time_{stage}"] = float(seconds)
    return result


def table1_row(lbc_binding, mvc_binding):
    """Table 1: memory and deform time of reduced LBC relative to dense MVC, for one (cage, mesh) pair.

    Returns
    -------
    dict with keys control_points, points, lbc_bytes, mvc_bytes, memory_ratio, lbc_seconds, mvc_seconds,
    time_ratio (ratios LBC / MVC, dimensionless), lbc_nonzeros_per_point
    """
    lbc = stored_weights(lbc_binding)
    mvc = stored_weights(mvc_binding)
    control_points = lbc_binding.cage.vertices
    lbc_bytes, mvc_bytes = memory_bytes(lbc), memory_bytes(mvc)
    lbc_seconds = deform_seconds(lbc, control_points)
    mvc_seconds = deform_seconds(mvc, control_points)
    return {
        "control_points": int(lbc.shape[1]),
        "points": int(lbc.shape[0]),
        "lbc_bytes": int(lbc_bytes),
        "mvc_bytes": int(mvc_bytes),
        "memory_ratio": lbc_bytes / mvc_bytes,
        "lbc_seconds": lbc_seconds,
        "mvc_seconds": mvc_seconds,
        "time_ratio": lbc_seconds / mvc_seconds,
        "lbc_nonzeros_per_point": lbc.nnz / max(lbc.shape[0], 1),
    }
