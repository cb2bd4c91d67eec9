"""Small meshes made in code, for examples and tests: a box, and two boxes apart."""

import numpy as np


def box(low=(0.0, 0.0, 0.0), high=(1.0, 0.6, 0.4), cuts=4):
    """(vertices, quads) of a box with each face cut into ``cuts`` × ``cuts`` quads, facing out."""
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    t = np.linspace(0.0, 1.0, cuts + 1)
    vertices, quads = [], []
    for axis in range(3):
        u_axis, v_axis = (axis + 1) % 3, (axis + 2) % 3
        for side in (0.0, 1.0):
            base = len(vertices)
            for u in t:
                for v in t:
                    point = np.empty(3)
                    point[axis], point[u_axis], point[v_axis] = side, u, v
                    vertices.append(low + point * (high - low))
            for i in range(cuts):
                for j in range(cuts):
                    a, b = base + i * (cuts + 1) + j, base + (i + 1) * (cuts + 1) + j
                    quad = [a, b, b + 1, a + 1] if side else [a, a + 1, b + 1, b]
                    quads.append(quad)
    return np.array(vertices), np.array(quads)
