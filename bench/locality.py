"""Issue 12, item 3's lever measured, not shipped: the ADMM state held only where a coordinate can be non-zero.

    .venv/bin/python bench/locality.py [--cages L10:8000,L08:8000,L08:32000] [--first 40] [--rings 2] [--block 256]

Each bind runs twice on the same mesh (the pipeline is deterministic): the solver as it is, and the same solver
whose iterations after the first ``--first`` (dense, as today) keep the split gradient X only on the (cell,
coordinate) pairs a coordinate can reach: the interior vertices where its clamped weight W is positive after those
iterations, grown by ``--rings`` rings of cells, and every cell with a boundary value of it. Cells go in blocks of
``--block`` consecutive cells in Morton order of their centroids; a block holds the union of its cells' pairs, a
dense (d, F_b, a_b) array, so the per-cell work stays vectorised. W's clamp is [0, 0] outside a coordinate's
reach (its dual stays, so Z follows it to zero there), and the Y-step keeps a zero gradient target with no dual on
the pairs not held (their cells' vertices are all held at zero). Printed: iterations, solve and bind seconds, the share of pairs held,
the objectives and the largest weight difference at the points.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lbc_core  # noqa: E402
from lbc_core import solver  # noqa: E402
from lbc_core.io import read_cage, read_mesh  # noqa: E402
from lbc_core.parallel import thread_map, worker_count  # noqa: E402

GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
DENSE_ADMM, PROBLEM_INIT = solver._admm, solver._Problem.__init__


def remember_mesh(self, vertices, cells, *args, **kwargs):
    """solver._Problem.__init__, keeping the cells and vertices (the blocks need the centroids)."""
    PROBLEM_INIT(self, vertices, cells, *args, **kwargs)
    self.cells, self.vertices = cells, vertices


def morton_order(points, bits=10):
    """Indices sorting (k, 3) points along a Z-order curve of a 2^bits grid over their bounding box."""
    low, high = points.min(axis=0), points.max(axis=0)
    grid = ((points - low) / np.maximum(high - low, 1e-300) * (2 ** bits - 1)).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(bits):
        for axis in range(3):
            code |= ((grid[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


class Block:
    """A run of cells with the coordinates any of them can reach, and their rows of the gradient operator."""

    def __init__(self, problem, cells, coords, dtype):
        d, F = problem.d, problem.n_cells
        rows = (np.arange(d)[:, None] * F + cells[None, :]).ravel()
        G = problem.G64[rows]
        self.vertices = np.unique(G.indices)
        self.G = G[:, self.vertices].astype(dtype).tocsr()
        self.GT = self.G.T.tocsr()
        self.cells, self.coords = cells, coords
        self.shape = (d, len(cells), len(coords))
        self.E = problem.E64[rows][:, coords].reshape(self.shape).astype(dtype)
        self.ix = np.ix_(self.vertices, coords)

    @property
    def size(self):
        return int(np.prod(self.shape))


class CompactStep:
    """A Douglas-Rachford step (solver._DouglasRachford's) with X held on blocks of (cell, coordinate) pairs."""

    def __init__(self, dense, start, allowed, active, block_size):
        p = self.p = dense.p
        self.dense, self.alpha, self.epsilon = dense, dense.alpha, dense.epsilon
        dtype = p.G.dtype
        order = morton_order(p.vertices[p.cells].mean(axis=1))
        self.blocks = []
        for begin in range(0, len(order), block_size):
            cells = np.sort(order[begin:begin + block_size])
            self.blocks.append(Block(p, cells, np.flatnonzero(active[cells].any(axis=0)), dtype))
        self.offsets = np.cumsum([0] + [block.size for block in self.blocks])
        self.size_x = int(self.offsets[-1])
        self.shape_w = dense.shape_w
        self.thresholds = dense.thresholds
        self.block_thresholds = [dense.thresholds[block.cells][:, block.coords] for block in self.blocks]
        self.tv_weights = [dense.tv_weights[block.cells][:, block.coords] for block in self.blocks]
        self.sqrt_cell = [p.sqrt_cell[block.cells] for block in self.blocks]
        self.boundary_load = dense.boundary_load
        self.threads = worker_count()
        v_x, v_w = dense.split(start)
        self.start = np.concatenate([v_x[:, block.cells][:, :, block.coords].ravel() for block in self.blocks]
                                    + [v_w.ravel()])
        self.share = self.size_x / dense.size_x
        self.bound = p.sqrt_mass * allowed  # W's clamp: [0, √(β m)] where the coordinate may live, 0 elsewhere

    def initial_state(self):
        return self.start

    def _views(self, flat):
        return [flat[a:b].reshape(block.shape) for a, b, block in zip(self.offsets[:-1], self.offsets[1:],
                                                                      self.blocks)]

    def _groups(self):
        """The blocks split into one contiguous group per thread."""
        bounds = np.linspace(0, len(self.blocks), self.threads + 1).astype(int)
        return [range(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    def __call__(self, state):
        p, alpha = self.p, self.alpha
        v_x_flat, v_w = state[:self.size_x], state[self.size_x:].reshape(self.shape_w)
        v_x = self._views(v_x_flat)
        new_state = np.empty_like(state)
        new_x = self._views(new_state[:self.size_x])
        shrink_flat = np.empty(self.size_x, dtype=state.dtype)
        shrink = self._views(shrink_flat)
        gradient_flat = np.empty(self.size_x, dtype=state.dtype)
        gradient = self._views(gradient_flat)

        def reflect(group):
            rhs = np.zeros(self.shape_w, dtype=state.dtype)
            for k in group:
                block = self.blocks[k]
                factor = solver._shrink_factor(v_x[k], self.block_thresholds[k], self.epsilon)
                shrink[k][:] = factor[None]
                reflected = v_x[k] * (2.0 * shrink[k] - 1.0)
                rhs[block.ix] += block.GT @ reflected.reshape(-1, block.shape[2])
            return rhs

        def update(group):
            for k in group:
                block = self.blocks[k]
                g = gradient[k]
                np.add((block.G @ Z[block.ix]).reshape(block.shape), block.E, out=g)
                np.multiply(v_x[k], 1.0 - alpha * shrink[k], out=new_x[k])
                new_x[k] += alpha * g

        W = np.minimum(np.maximum(v_w, 0.0), self.bound)
        reflected_w = 2.0 * W - v_w
        rhs = sum(thread_map(reflect, self._groups()))
        rhs -= self.boundary_load
        rhs += p.sqrt_mass * reflected_w
        Z = self.dense.solve(rhs @ p.MT) @ p.M
        Z += p.H
        thread_map(update, self._groups())
        new_w = new_state[self.size_x:].reshape(self.shape_w)
        np.multiply(p.sqrt_mass, Z, out=new_w)
        new_w -= W
        new_w *= alpha
        new_w += v_w
        return new_state, solver._Step(v_x_flat, v_w, shrink_flat, W, Z, gradient_flat)

    def objective(self, gradient_flat):
        """Σ ω |c| |∇w| over the pairs held (the others' gradient is driven to zero)."""
        total = 0.0
        for k, g in enumerate(self._views(gradient_flat)):
            total += float((self.tv_weights[k] * self.sqrt_cell[k] * np.sqrt((g.astype(float) ** 2).sum(0))).sum())
        return total


def reach(problem, W, rings):
    """Where each coordinate may live: (N_in, n) bool, the interior vertices where W > 0 grown by ``rings`` rings of
    cells, and (F, n) bool, the cells with such a vertex or a boundary value of the coordinate."""
    d, F = problem.d, problem.n_cells
    incidence = abs(problem.G64[:F]) + abs(problem.G64[F:2 * F]) + (abs(problem.G64[2 * F:]) if d == 3 else 0)
    incidence = (incidence > 0).astype(np.float32).tocsr()  # (F, N_in) cell–interior-vertex
    support = (W > 0).astype(np.float32)
    for _ in range(rings):
        support = (incidence.T @ (incidence @ support) > 0).astype(np.float32)
    boundary = np.abs(problem.E64).reshape(d, F, -1).max(axis=0) > 0
    return support > 0, (incidence @ support > 0) | boundary


def compact_admm(first, rings, block_size, record):
    """A stand-in for solver._admm: ``first`` dense iterations, then the compact step."""

    def admm(problem, tv_weights, epsilon, tolerance, max_iterations, penalty, alpha, check_every, memory, period,
             progress, start=None):
        Z, W, done, converged, history, final = DENSE_ADMM(problem, tv_weights, epsilon, tolerance, first, penalty,
                                                           alpha, check_every, memory, period, progress, start)
        if converged:
            return Z, W, done, converged, history, final
        dense = solver._DouglasRachford(problem, tv_weights, epsilon, alpha, penalty, progress.check)
        clock = time.perf_counter()
        step = CompactStep(dense, final.state, *reach(problem, W, rings), block_size)
        record["setup"] = time.perf_counter() - clock
        record["share"] = step.share
        original = solver._DouglasRachford
        solver._DouglasRachford = lambda *args: step
        try:
            Z, W, more, converged, history2, final = DENSE_ADMM(problem, tv_weights, epsilon, tolerance,
                                                                max_iterations - done, penalty, alpha, check_every,
                                                                memory, period, progress)
        finally:
            solver._DouglasRachford = original
        return Z, W, done + more, converged, history + history2, final

    return admm


def bind(cage, faces, points, cells, admm):
    solver._admm = admm
    try:
        start = time.perf_counter()
        binding = lbc_core.bind(cage, faces, points, cells=cells)
        return binding, time.perf_counter() - start
    finally:
        solver._admm = DENSE_ADMM


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cages", default="L10:8000,L08:8000,L08:32000")
    parser.add_argument("--first", type=int, default=40)
    parser.add_argument("--rings", type=int, default=2)
    parser.add_argument("--block", type=int, default=256)
    args = parser.parse_args(argv)
    solver._Problem.__init__ = remember_mesh
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    print("| cage | cells | solver | iterations | solve s | bind s | pairs held | objective | max weight difference |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for item in args.cages.split(","):
        level, cells = item.split(":")
        cage, faces = read_cage(GARGOYLE / f"cage_{level}.obj")
        dense, dense_seconds = bind(cage, faces, points, int(cells), DENSE_ADMM)
        record = {}
        compact, seconds = bind(cage, faces, points, int(cells), compact_admm(args.first, args.rings, args.block,
                                                                              record))
        difference = abs(compact.weights - dense.weights).max()
        for name, binding, total, share in (("dense", dense, dense_seconds, 1.0),
                                            (f"compact after {args.first}", compact, seconds, record.get("share", 1))):
            print(f"| {level} | {len(binding.domain.cells)} | {name} | {binding.iterations} | "
                  f"{binding.timings['solve']:.2f} | {total:.2f} | {share:.1%} | {binding.objective:.6f} | "
                  f"{difference if binding is compact else 0:.2e} |", flush=True)
        print(f"(blocks built in {record.get('setup', 0):.2f} s; load {os.getloadavg()[0]:.1f})", flush=True)


if __name__ == "__main__":
    main()
