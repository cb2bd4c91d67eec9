"""The same mesh, cage and options give the same binding, bit for bit, whatever the machine's load and its cores.

A render farm that binds again must get the binding the artist saw: no wall-clock time may decide a result (the
mesher's budgets are counts of work), and no sum may follow the thread count (the solver's row blocks and the
reduction's row chunks are laid out by the problem's size alone).
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lbc_core
from lbc_core.kernel import parallel
from lbc_core.io import read_mesh

DATA = Path(__file__).resolve().parent / "data" / "cages-3d"


def bind(cage, mesh, cells=None):
    cage_vertices, cage_faces = read_mesh(DATA / cage)[:2]
    return lbc_core.bind(cage_vertices, cage_faces, read_mesh(DATA / mesh)[0], cells=cells)


def assert_same(first, second):
    assert np.array_equal(first.domain.vertices, second.domain.vertices)
    assert np.array_equal(first.domain.cells, second.domain.cells)
    a, b = first.weights.tocsr(), second.weights.tocsr()
    assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
    assert np.array_equal(a.data, b.data)


@pytest.mark.slow  # two binds of the hand at the default resolution, one on a loaded machine
def test_a_bind_beside_a_cpu_burner_is_the_same_bit_for_bit():
    """The hand (fingers close together, the slots between them refined) bound at the defaults, then again beside
    one CPU-burning process per core."""
    quiet = bind("hand/cage.obj", "hand/mesh.obj")
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(parallel.worker_count())]
    try:
        loaded = bind("hand/cage.obj", "hand/mesh.obj")
    finally:
        for burner in burners:
            burner.kill()
            burner.wait()
    assert_same(quiet, loaded)


@pytest.mark.parametrize("cage, cells, splitting", [
    pytest.param("gargoyle/cage_L08.obj", 2000, "working sets", marks=pytest.mark.slow),  # 168 control points
    ("gargoyle/cage_L12.obj", 2000, "dense"),  # 27: the dense splitting, its cells in chunks (below)
])
def test_a_bind_is_the_same_whatever_the_thread_count(monkeypatch, cage, cells, splitting):
    """One thread, three and eight, every module that asks the thread count told the same: the working sets'
    transposed product summed one partial product per thread, the dense splitting one per chunk of cells made per
    thread, and the reduction padded each thread's chunk of rows to its longest, so the weights followed the
    machine's cores (the gargoyle's 2674 vertices)."""
    from lbc_core.solve import nullspace

    # The dense splitting chunks its cells from 500,000 entries on (8000 cells of L12); a small bind, chunked too.
    monkeypatch.setattr(nullspace, "PARALLEL_MIN_ENTRIES", 1000)
    asking = [module for name, module in sorted(sys.modules.items())
              if name.startswith("lbc_core.") and hasattr(module, "worker_count")]
    bindings = []
    for threads in (1, 3, 8):
        for module in asking:
            monkeypatch.setattr(module, "worker_count", lambda: threads)
        bindings.append(bind(cage, "gargoyle/mesh.off", cells=cells))
    for other in bindings[1:]:
        assert_same(bindings[0], other)
