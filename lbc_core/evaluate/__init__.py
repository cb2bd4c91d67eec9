"""From coordinates at the domain mesh's vertices to weights at the user's points: locating each point in its cell
(:mod:`.interpolation`), the smooth moving least-squares fit that replaces the mesh's piecewise-linear creases
(:mod:`.smoothing`), sparse rows with the small weights dropped and the constraints restored (:mod:`.reduction`), and
the add-on's fewer influences per point (:mod:`.thinning`). In: a domain mesh, its coordinates and points; out: sparse
(points × control points) matrices.
"""
