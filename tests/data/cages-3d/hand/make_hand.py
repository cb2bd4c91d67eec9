"""Make mesh.obj and cage.obj here from the hand of odedstein/meshes (objects/hand/hand_lowres.obj, CC BY 4.0).

    python tests/data/cages-3d/hand/make_hand.py path/to/hand_lowres.obj

mesh.obj: that hand with the index, ring and little fingers turned about their bases, in the palm's plane, until
they lie along the middle finger (blended in over their first 0.08 units, so the mesh stays whole): fingers close
together. cage.obj: 44 vertices, a box around the palm, one around each finger and the thumb, 0.01 units clear of
the mesh; neighbouring finger boxes face each other across slots 0.0015 wide (0.11 % of the cage's diagonal).
"""

import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[3]))

from lbc_core.io import read_mesh, write_mesh  # noqa: E402

CLEAR, GAP, WEB, THUMB, BLEND = 0.01, 0.0015, 0.6, -0.22, 0.08


def parts(vertices, faces, mask):
    """The connected pieces (index arrays, more than 5 vertices) of the mesh's vertices where mask holds."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = edges[mask[edges[:, 0]] & mask[edges[:, 1]]]
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2)
    label = connected_components(graph, directed=False)[1]
    pieces = [np.flatnonzero((label == i) & mask) for i in np.unique(label[mask])]
    return [p for p in pieces if len(p) > 5]


def principal(points):
    return np.linalg.svd(points - points.mean(axis=0))[2]


def close_fingers(vertices, faces):
    fingers = sorted(parts(vertices, faces, vertices[:, 1] > WEB), key=lambda p: vertices[p, 0].mean())
    fingers[3] = max(parts(vertices, faces, vertices[:, 1] > 0.5), key=lambda p: vertices[p, 0].mean())  # lower base
    normal = principal(vertices)[2]
    normal *= np.sign(normal[2])

    def axis(piece):
        d = principal(vertices[piece])[0]
        d -= (d @ normal) * normal
        return d / np.linalg.norm(d) * np.sign(d[1])

    target, posed = axis(fingers[1]), vertices.copy()
    for piece in (fingers[0], fingers[2], fingers[3]):
        d = axis(piece)
        angle = np.arctan2(np.cross(d, target) @ normal, d @ target)
        height = (vertices[piece] - vertices[piece].mean(axis=0)) @ d
        base = vertices[piece][np.argsort(height)[:max(3, len(piece) // 10)]].mean(axis=0)
        t = np.clip((height - height.min()) / BLEND, 0.0, 1.0)
        turn = (angle * t * t * (3 - 2 * t))[:, None]
        r = vertices[piece] - base
        posed[piece] = (base + r * np.cos(turn) + np.cross(normal, r) * np.sin(turn)
                        + normal * (r @ normal)[:, None] * (1 - np.cos(turn)))
    return posed


def cage_around(vertices, faces):
    thumb = max(parts(vertices, faces, vertices[:, 0] < THUMB), key=len)
    fingers = sorted(parts(vertices, faces, vertices[:, 1] > WEB), key=lambda p: vertices[p, 0].mean())
    palm = np.ones(len(vertices), dtype=bool)
    for piece in [thumb] + fingers:
        palm[piece] = False
    palm = np.flatnonzero(palm)
    # The palm's frame: a across (index to little finger), b along the middle finger, c the palm's normal.
    centre = vertices[palm].mean(axis=0)
    normal = principal(vertices[palm])[2]
    normal *= np.sign(normal[2])
    along = principal(vertices[fingers[1]])[0]
    along *= np.sign(along[1])
    b_axis = along - (along @ normal) * normal
    b_axis /= np.linalg.norm(b_axis)
    frame = np.stack([np.cross(b_axis, normal), b_axis, normal])
    local = (vertices - centre) @ frame.T
    lo, hi = local[palm].min(axis=0) - CLEAR, local[palm].max(axis=0) + CLEAR
    mids = [0.5 * (local[fingers[i], 0].max() + local[fingers[i + 1], 0].min()) for i in range(3)]
    webs = [min(local[fingers[i], 1].min(), local[fingers[i + 1], 1].min()) for i in range(3)]
    a_edges = [lo[0]] + [m + s * GAP / 2 for m in mids for s in (-1, 1)] + [hi[0]]
    heights = [webs[0]] + [w for w in webs for _ in (0, 1)] + [webs[-1]]
    points, cage_faces = [], []

    def add(p):
        points.append(np.asarray(p, dtype=float))
        return len(points) - 1

    def box(base, tip):
        """Side faces from the base ring to the tip ring, and the tip."""
        cage_faces.extend([base[k], tip[k], tip[(k + 1) % 4], base[(k + 1) % 4]] for k in range(4))
        cage_faces.append(tip[::-1])

    wrist = [add([lo[0], lo[1], lo[2]]), add([hi[0], lo[1], lo[2]]), add([hi[0], lo[1], hi[2]]),
             add([lo[0], lo[1], hi[2]])]
    near = thumb[local[thumb, 0] > lo[0] - 0.03]
    b0, b1 = local[thumb, 1].min() - 4 * CLEAR, local[near, 1].max() + CLEAR
    root = [add([lo[0], b0, lo[2]]), add([lo[0], b0, hi[2]]), add([lo[0], b1, hi[2]]), add([lo[0], b1, lo[2]])]
    bases = [[add([a_edges[2 * i], heights[2 * i], lo[2]]), add([a_edges[2 * i + 1], heights[2 * i + 1], lo[2]]),
              add([a_edges[2 * i + 1], heights[2 * i + 1], hi[2]]), add([a_edges[2 * i], heights[2 * i], hi[2]])]
             for i in range(4)]
    for i, (base, piece) in enumerate(zip(bases, fingers)):
        top = local[piece, 1].max() + CLEAR
        c0, c1 = local[piece, 2].min() - CLEAR, local[piece, 2].max() + CLEAR
        a0 = min(a_edges[0], local[piece, 0].min() - CLEAR) if i == 0 else a_edges[2 * i]
        a1 = max(a_edges[-1], local[piece, 0].max() + CLEAR) if i == 3 else a_edges[2 * i + 1]
        box(base, [add([a0, top, c0]), add([a1, top, c0]), add([a1, top, c1]), add([a0, top, c1])])
    # The thumb: a box in its own frame (d its axis, e across it in the palm's plane, n = e x d).
    pts = local[thumb]
    d = principal(pts)[0]
    d *= -np.sign(d[0])
    e = np.array([0.0, 1.0, 0.0]) - d[1] * d
    e /= np.linalg.norm(e)
    n = np.cross(e, d)
    t, s, u = pts @ d, pts @ e, pts @ n
    tip = [add((t.max() + CLEAR) * d + ss * e + uu * n) for ss, uu in
           [(s.min() - CLEAR, u.min() - CLEAR), (s.max() + CLEAR, u.min() - CLEAR),
            (s.max() + CLEAR, u.max() + CLEAR), (s.min() - CLEAR, u.max() + CLEAR)]]
    box(root[::-1], [tip[1], tip[2], tip[3], tip[0]])
    top_back = [q for base in bases[::-1] for q in (base[1], base[0])]
    top_front = [q for base in bases[::-1] for q in (base[2], base[3])]
    cage_faces += [wrist,
                   ([wrist[0], wrist[1]] + top_back + [root[3], root[0]])[::-1],  # back
                   [wrist[3], wrist[2]] + top_front + [root[2], root[1]],  # front
                   [wrist[1], bases[3][1], bases[3][2], wrist[2]],  # little finger's side
                   [wrist[3], root[1], root[0], wrist[0]],  # index side, below the thumb
                   [root[2], bases[0][3], bases[0][0], root[3]]]  # index side, above the thumb
    cage_faces += [[bases[i][1], bases[i][2], bases[i + 1][3], bases[i + 1][0]] for i in range(3)]  # the slots' ends
    return np.array(points) @ frame + centre, cage_faces


if __name__ == "__main__":
    vertices, faces = read_mesh(sys.argv[1])[:2]
    faces = np.asarray(faces)
    posed = close_fingers(vertices, faces)
    write_mesh(HERE / "mesh.obj", posed, faces)
    write_mesh(HERE / "cage.obj", *cage_around(posed, faces))
