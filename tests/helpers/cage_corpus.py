"""The cage corpus: Blender's primitives and artist-style cages (tests/data/cage-corpus), and their variants.

Variants of a cage: scaled by 1e-6 and 1e6, moved 1e6 from the origin, squashed to aspect 1e-3 along z, and one
vertex dented inwards by 1e-8 to 1e-2 of the cage's size.
"""

from pathlib import Path

import numpy as np

CORPUS = Path(__file__).resolve().parents[1] / "data" / "cage-corpus" / "cage-corpus.npz"
VARIANTS = ("as-made", "scaled-1e-6", "scaled-1e6", "moved-1e6", "squashed-1e-3", "dented-1e-8", "dented-1e-5",
            "dented-1e-2")


def names():
    """Names of the corpus cages, in the file's order."""
    with np.load(CORPUS) as data:
        return list(dict.fromkeys(key.split("/")[0] for key in data.files))


def load(name):
    """(vertices (n, 3) float array, faces list of int lists) of one corpus cage, as Blender made it."""
    with np.load(CORPUS) as data:
        vertices, flat, sizes = (data[f"{name}/{part}"] for part in ("vertices", "faces", "sizes"))
    faces = [f.tolist() for f in np.split(flat, np.cumsum(sizes)[:-1])]
    return vertices, faces


def variant(vertices, faces, kind):
    """The cage changed as ``kind`` (one of VARIANTS) says; returns (vertices, faces)."""
    vertices = np.array(vertices, dtype=float)
    size = np.linalg.norm(np.ptp(vertices, axis=0))
    if kind == "as-made":
        return vertices, faces
    if kind.startswith("scaled-"):
        return vertices * float(kind.split("-", 1)[1]), faces
    if kind == "moved-1e6":
        return vertices + np.array([1e6, -1e6, 1e6]) / np.sqrt(3.0), faces
    if kind == "squashed-1e-3":
        low = vertices[:, 2].min()
        vertices[:, 2] = low + (vertices[:, 2] - low) * 1e-3 * np.ptp(vertices[:, :2], axis=0).max() / np.ptp(
            vertices[:, 2])
        return vertices, faces
    if kind.startswith("dented-"):
        # The vertex farthest from the centre moves towards the centre by the given fraction of the size.
        centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
        far = int(np.argmax(np.linalg.norm(vertices - centre, axis=1)))
        towards = (centre - vertices[far]) / np.linalg.norm(centre - vertices[far])
        vertices[far] += float(kind.split("-", 1)[1]) * size * towards
        return vertices, faces
    raise ValueError(f"unknown variant {kind!r}")
