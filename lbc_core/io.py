"""Mesh and cage files: PLY through meshio, OBJ and OFF through small readers and writers of their own.

Faces keep their order and their polygons (a quad stays a quad), so a cage read here gives the same Cage, with the
same ``facet_face`` indices, as the faces the artist made. A file without faces (a point cloud, or a 2D cage given as
``v`` lines in boundary order plus an ``l`` polyline, as in the paper's data) reads as faces = None; the polygon's
order is that of its ``v`` lines, as in the reference code.

Why OBJ and OFF are not read through meshio (5.3.5), the library used for PLY:

* its OBJ reader fails on files whose ``vt`` or ``vn`` count differs from the ``v`` count, i.e. any UV-mapped mesh
  exported with per-corner texture coordinates (tests/data/cages-3d/clothing/mesh.obj is one), and it misreads
  negative (relative) face indices;
* its OFF reader raises on any face that is not a triangle and its writer silently drops such faces, while cages
  are often quad meshes.

Both formats are line-based text, and only ``v`` and ``f`` lines (OBJ), the header, vertex and face lines (OFF)
matter here.
"""

import errno
import os
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .errors import CageError

FORMATS = (".obj", ".off", ".ply")
_FACE_TYPES = ("triangle", "quad", "polygon")  # meshio's cell types that are faces


def read_mesh(path):
    """Read a surface mesh or point set.

    Parameters
    ----------
    path : str or Path
        An .obj, .off or .ply file.

    Returns
    -------
    vertices : (m, 3) float array
    faces : list of (k,) int arrays, in file order, or None when the file has no faces

    Raises
    ------
    CageError
        When the file is missing, of an unknown format or unreadable; the message names the file.
    """
    path = Path(path)
    suffix = _suffix(path)
    if not path.is_file():
        raise CageError(f"{path}: no such file")
    try:
        reader = {".obj": _read_obj, ".off": _read_off, ".ply": _read_ply}[suffix]
        vertices, faces = reader(path)
    except CageError:
        raise
    except Exception as error:  # parsers raise many types; the user needs the file and the reason
        raise CageError(f"{path}: cannot read it as {suffix[1:].upper()} ({error})") from error
    if len(vertices) == 0:
        raise CageError(f"{path}: the file has no vertices")
    _check_faces(path, faces, len(vertices))
    return vertices, faces


def _check_faces(path, faces, n_vertices):
    """Refuse faces with fewer than 3 corners or corners that are not vertices of the file."""
    for index, face in enumerate(faces or ()):
        if len(face) < 3 or face.min() < 0 or face.max() >= n_vertices:
            shown = " ".join(str(int(corner)) for corner in face[:8]) + (" ..." if len(face) > 8 else "")
            raise CageError(
                f"{path}: face {index} ({shown}) is invalid: a face needs 3 or more of the file's {n_vertices} "
                "vertices (counted from 0 here); fix or delete it"
            )


def read_cage(path):
    """Read a cage: a 3D polygon mesh, or a 2D polygon (vertices in boundary order, no faces).

    Returns
    -------
    vertices : (n, 3) float array for a mesh cage, (n, 2) for a polygon (its constant z dropped)
    faces : list of (k,) int arrays, or None for a polygon

    Raises
    ------
    CageError
        As :func:`read_mesh`, and when a file without faces does not lie in a plane z = constant.
    """
    vertices, faces = read_mesh(path)
    if faces is None:
        return planar(vertices, path), None
    return vertices, faces


def planar(points, path="points"):
    """Drop the constant z of points that lie in a plane z = constant (2D data stored in a 3D file).

    Parameters
    ----------
    points : (m, 2) or (m, 3) float array
    path : str
        Named in the error message.

    Returns
    -------
    (m, 2) float array
    """
    points = np.asarray(points, dtype=float)
    if points.shape[1] == 2:
        return points
    extent = max(float(np.ptp(points[:, :2])), 1e-300)
    if np.ptp(points[:, 2]) > 1e-9 * extent:
        raise CageError(f"{path}: 2D data must lie in a plane z = constant, but z varies")
    return points[:, :2].copy()


def write_mesh(path, vertices, faces=None):
    """Write a mesh (or a point set when faces is None); 2D vertices get z = 0.

    Parameters
    ----------
    path : str or Path
        .obj, .off or .ply (PLY is written binary).
    vertices : (m, 2) or (m, 3) float array
    faces : sequence of index sequences, or None

    Raises
    ------
    CageError
        For an unknown format, faces with corners that are not among the vertices, or a file that cannot be
        written (a file this call created is removed again).
    """
    path = Path(path)
    suffix = _suffix(path)
    vertices = np.asarray(vertices, dtype=float)
    if vertices.shape[1] == 2:
        vertices = np.column_stack([vertices, np.zeros(len(vertices))])
    faces = [] if faces is None else [np.asarray(f, dtype=np.int64) for f in faces]
    _check_faces(path, faces, len(vertices))
    if suffix != ".ply":
        with writing(path) as handle:
            {".obj": _write_obj, ".off": _write_off}[suffix](handle, vertices, faces)
        return
    meshio = _meshio_ply()
    with writing(path) as handle:
        meshio.ply.write(handle, meshio.Mesh(vertices, _cell_blocks(faces)))


def write_posed_obj(template, path, vertices):
    """Write an OBJ mesh as the OBJ file ``template`` with its vertices moved to ``vertices``: texture coordinates,
    objects, groups, materials and smoothing kept line for line.

    Vertex normals (``vn``, and the normal index of each face corner) are left out: they were the rest pose's, and
    importers recompute them.

    Parameters
    ----------
    template : str or Path
        The OBJ file the positions belong to (the mesh that was bound).
    path : str or Path
    vertices : (m, 3) float array
        One position per ``v`` line of ``template``, in order.

    Raises
    ------
    CageError
        When ``template`` has another number of vertices, or ``path`` cannot be written.
    """
    vertices = np.asarray(vertices, dtype=float)
    lines, count = [], 0
    with open(template, encoding="utf-8", errors="replace") as handle:
        for line in handle:
            words = line.split("#", 1)[0].split()
            if words and words[0] == "v":
                if count < len(vertices):
                    x, y, z = vertices[count].tolist()
                    line = " ".join(["v", repr(x), repr(y), repr(z), *words[4:]]) + "\n"
                count += 1
            elif words and words[0] == "vn":
                continue
            elif words and words[0] == "f":
                line = " ".join(["f", *("/".join(word.split("/")[:2]).rstrip("/") for word in words[1:])]) + "\n"
            lines.append(line)
    if count != len(vertices):
        raise CageError(f"{template} has {count} vertices, not the {len(vertices)} positions given: give the mesh that "
                        "was bound")
    with writing(path) as handle:
        handle.write("".join(lines).encode("utf-8"))


def check_output(path, formats=None, inputs=()):
    """Refuse, before any long work, an output path that cannot be written, or that would overwrite an input.

    Parameters
    ----------
    path : str or Path
    formats : sequence of str, optional
        Accepted suffixes (".obj"), checked when given.
    inputs : sequence of str or Path or None
        The files the command reads (None entries are skipped).

    Raises
    ------
    CageError
        Naming the path and what to do: an unknown suffix, a missing folder, a folder in the way, no permission, one
        of ``inputs``.
    """
    path = Path(path)
    for given in filter(None, inputs):
        # The same file by any name (a link too); a missing input is the reader's to report.
        if path.exists() and Path(given).exists() and os.path.samefile(path, given):
            raise CageError(f"{path} is also an input of this command: writing it would destroy it; give another "
                            "output path")
    if formats is not None and path.suffix.lower() not in formats:
        raise CageError(f"{path}: unknown output format {path.suffix or '(none)'!r}; use one of {', '.join(formats)}")
    folder = path.parent
    if not folder.is_dir():
        raise CageError(f"{path}: the folder {folder} does not exist; create it first or write elsewhere")
    if path.is_dir():
        raise CageError(f"{path} is a folder: give a file name")
    if not os.access(path if path.exists() else folder, os.W_OK):
        raise CageError(f"{path}: no permission to write {'it' if path.exists() else 'in ' + str(folder)}; "
                        "write elsewhere")


@contextmanager
def writing(path):
    """An open binary handle to write exactly ``path``; failures become one CageError.

    A file this call created is removed again when writing fails (a full disk leaves no truncated file behind).
    """
    path = Path(path)
    existed = path.exists()
    try:
        with open(path, "wb") as handle:
            yield handle
    except OSError as error:
        if not existed and path.is_file():
            path.unlink()
        if error.errno == errno.ENOSPC:
            raise CageError(f"could not write {path}: the disk is full (no space left on the device); free some "
                            "space or write elsewhere") from None
        raise CageError(f"could not write {path}: {error.strerror or error}; check the folder and permissions, or "
                        "write elsewhere") from None


def _suffix(path):
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise CageError(f"{path}: unknown mesh format {suffix or '(none)'!r}; use one of {', '.join(FORMATS)}")
    return suffix


def _meshio_ply():
    try:
        import meshio
        import meshio.ply
    except ImportError:
        raise CageError("PLY files need meshio: pip install meshio (or use OBJ or OFF)") from None
    return meshio


def _read_ply(path):
    meshio = _meshio_ply()

    # The format's own reader: meshio.read() prints and calls sys.exit(1) when a file does not parse.
    mesh = meshio.ply.read(path)
    vertices = np.asarray(mesh.points, dtype=float)
    if vertices.shape[1] == 2:
        vertices = np.column_stack([vertices, np.zeros(len(vertices))])
    # meshio splits faces into blocks of equal size, in file order: concatenating them restores that order.
    faces = [np.asarray(f, dtype=np.int64) for block in mesh.cells if block.type in _FACE_TYPES for f in block.data]
    return vertices, (faces or None)


def _cell_blocks(faces):
    """meshio cell blocks for faces in order: one block per run of faces of equal size."""
    blocks = []
    for face in faces:
        kind = {3: "triangle", 4: "quad"}.get(len(face), "polygon")
        if blocks and len(blocks[-1][1][-1]) == len(face):
            blocks[-1][1].append(face)
        else:
            blocks.append((kind, [face]))
    return [(kind, np.array(block, dtype=np.int32)) for kind, block in blocks]  # PLY stores 32-bit indices


def _read_obj(path):
    """OBJ ``v`` and ``f`` lines; ``f`` words may be i, i/t, i//n or i/t/n, 1-based or negative (relative)."""
    vertices, faces = [], []
    with open(path, encoding="utf-8", errors="replace") as handle:
        for line in handle:
            words = line.split("#", 1)[0].split()
            if not words:
                continue
            if words[0] == "v":
                if len(words) < 4:
                    raise CageError(f"{path}: the vertex line {line.strip()!r} needs x, y and z")
                vertices.append([float(w) for w in words[1:4]])  # colours after xyz are ignored
            elif words[0] == "f":
                indices = np.array([int(w.split("/", 1)[0]) for w in words[1:]], dtype=np.int64)
                if np.any(indices == 0):
                    raise CageError(f"{path}: the face line {line.strip()!r} has the index 0; OBJ counts vertices "
                                    "from 1 (or back from -1): fix the file")
                # 1-based; negative counts back from the vertices read so far
                faces.append(np.where(indices > 0, indices - 1, indices + len(vertices)))
    return np.array(vertices, dtype=float).reshape(-1, 3), (faces or None)


def _write_obj(handle, vertices, faces):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    lines += ["f " + " ".join(str(int(i) + 1) for i in face) for face in faces]
    handle.write(("\n".join(lines) + "\n").encode("utf-8"))


def _read_off(path):
    """Plain OFF, one vertex or face per line; extra words on a line (colours) are ignored."""
    with open(path, encoding="utf-8", errors="replace") as handle:
        lines = [words for words in (line.split("#", 1)[0].split() for line in handle) if words]
    if not lines or lines[0][0].upper() != "OFF":
        raise CageError(f"{path}: not an OFF file (it should start with the word OFF)")
    # The counts follow "OFF" on its own line or on the next one.
    counts, body = (lines[0][1:], lines[1:]) if len(lines[0]) > 1 else (lines[1] if len(lines) > 1 else [], lines[2:])
    try:
        n_vertices, n_faces = int(counts[0]), int(counts[1])
        if len(body) < n_vertices + n_faces:
            raise CageError(f"{path}: the header promises {n_vertices} vertices and {n_faces} faces, the file is shorter")
        vertices = np.array([[float(w) for w in line[:3]] for line in body[:n_vertices]]).reshape(n_vertices, 3)
        faces = []
        for line in body[n_vertices : n_vertices + n_faces]:
            size = int(line[0])
            if len(line) < size + 1:
                raise CageError(f"{path}: the face line {' '.join(line)!r} has fewer than {size} indices")
            faces.append(np.array([int(w) for w in line[1 : size + 1]], dtype=np.int64))
    except (ValueError, IndexError) as error:
        raise CageError(f"{path}: malformed OFF ({error})") from None
    return vertices, (faces or None)


def _write_off(handle, vertices, faces):
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [" ".join(repr(float(c)) for c in vertex) for vertex in vertices]
    lines += [" ".join(str(int(i)) for i in [len(face), *face]) for face in faces]
    handle.write(("\n".join(lines) + "\n").encode("utf-8"))
