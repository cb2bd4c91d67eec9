"""The paper's problem and its solver: the fixed values on the cage (:mod:`.boundary`), the geodesic total-variation
weights ω (:mod:`.geodesics`), and :func:`~lbc_core.solve.solver.solve_on_mesh`, which minimises Σ ω A |∇w| over
coordinates with partition of unity, reproduction and non-negativity by an Anderson-accelerated Douglas–Rachford
splitting on working sets that follow the coordinates' supports (:mod:`.working_sets`, :mod:`.splitting`,
:mod:`.projection`, :mod:`.shrink`, :mod:`.anderson`), with its cost model (:mod:`.forecast`). In: a domain mesh and
arrays; out: coordinates at the mesh's vertices. It knows nothing of the points a user binds.
"""
