"""The cage as the user gives it, checked and put into one form: :func:`~lbc_core.cage.make.make_cage` welds,
triangulates and orients a closed 2D polygon or 3D polygon mesh into a :class:`~lbc_core.cage.make.Cage`, or refuses
it with a :class:`~lbc_core.errors.CageError` that says what is wrong and what to do; :mod:`~lbc_core.cage.planar`
turns a flat 3D cage with its points into a 2D bind. Everything downstream (meshing, the solve, the evaluation) takes
a ``Cage``, never the user's arrays.
"""
