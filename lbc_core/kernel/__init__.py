"""What every layer shares: the geometry kernel (predicates, closest points, winding numbers, simplex measures), the
P1 finite-element operators, the unit and meshing frames, the least-norm corrections that restore partition of unity
and reproduction, one sparse Cholesky factorisation, one thread pool, and progress and cancel. Nothing here knows
what a cage, a binding or a solver is; every other sub-package may import from here, and this package imports from
none of them (only :mod:`lbc_core.errors`).
"""
