"""The part of Make Cage that runs without Blender: the options, the request, the cage made on a worker thread.

1. :func:`lbc_addon.cage_scene.snapshot` (main thread) copies the selected meshes into a :class:`CageRequest`.
2. :func:`make` (any thread; this module never imports ``bpy``) calls ``lbc_core.generate_cage``.
3. :func:`lbc_addon.cage_scene.write` (main thread) checks the meshes did not change meanwhile, then adds the cage.

Nothing in the scene changes before step 3, so a failed or cancelled Make Cage leaves the scene exactly as it was.
The modal operator runs step 2 in a :class:`lbc_addon.jobs.Worker` (``Worker([request], work=make)``).
"""

import numbers
import time
from dataclasses import dataclass

import numpy as np

from .core import CageError, generate_cage

# The Symmetry choices: a cage mirror-symmetric about the plane through the meshes' bounding-box centre, normal to
# this axis of the first mesh's own frame.
SYMMETRY_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class CageOptions:
    """The options of one Make Cage, as the operator, ``api.make_cage`` and its redo name them; checked when made.

    A Blender property cannot be None, so 0 stands for lbc_core's default (``vertices``, ``margin``).

    Attributes
    ----------
    vertices : int
        The cage's vertex count, met within 15 % (0: one lbc_core chooses for the meshes' shape).
    margin : float
        The space between the meshes and the cage, a share of their bounding-box diagonal (0: lbc_core's default).
    symmetry : str or None
        "x", "y" or "z": a cage mirror-symmetric about the plane through the meshes' bounding-box centre normal to
        that axis of the first mesh's frame; None: no symmetry.
    vertex_group : str
        A partial cage: only the vertices of this group (and the faces with all their corners in it); "": the whole
        meshes.

    Examples
    --------
    >>> CageOptions(vertices=40).core_keywords()
    {'n_vertices': 40, 'margin': None, 'symmetry': None}
    >>> CageOptions(symmetry="w")
    Traceback (most recent call last):
    lbc_core.errors.CageError: symmetry must be None or one of 'x', 'y', 'z', not 'w'
    """

    vertices: int = 0
    margin: float = 0.0
    symmetry: str | None = None
    vertex_group: str = ""

    def __post_init__(self):
        vertices, margin = self.vertices, self.margin
        if isinstance(vertices, bool) or not isinstance(vertices, numbers.Integral) or vertices < 0:
            raise CageError(f"vertices must be a whole number of at least 0 (0: chosen for the mesh), not {vertices!r}")
        if isinstance(margin, bool) or not isinstance(margin, numbers.Real) or not margin >= 0:
            raise CageError(f"margin must be a number of at least 0, a share of the mesh's size (0.01 is 1 %; 0: the "
                            f"default), not {margin!r}")
        if isinstance(self.symmetry, str):  # "X" as the operator's menu says it
            object.__setattr__(self, "symmetry", self.symmetry.lower())
        if self.symmetry is not None and self.symmetry not in SYMMETRY_AXES:
            raise CageError(f"symmetry must be None or one of {', '.join(map(repr, SYMMETRY_AXES))}, "
                            f"not {self.symmetry!r}")
        if not isinstance(self.vertex_group, str):
            raise CageError(f"vertex_group must be a vertex group's name (\"\": the whole mesh), not "
                            f"{self.vertex_group!r}")
        object.__setattr__(self, "vertices", int(vertices))
        object.__setattr__(self, "margin", float(margin))

    def core_keywords(self):
        """The keywords of ``lbc_core.generate_cage`` for these options: the one place the add-on's names and
        defaults meet lbc_core's."""
        return {"n_vertices": self.vertices or None, "margin": self.margin or None, "symmetry": self.symmetry}


@dataclass
class CageRequest:
    """Everything Make Cage needs, copied out of Blender; identifies the meshes by ``session_uid``.

    The vertices are in the frame of the first mesh (its world transform ``frame``), which the cage object takes:
    the other meshes' vertices are brought into it from where they are in the world.
    """

    mesh_uids: tuple
    mesh_names: tuple
    vertices: np.ndarray  # (n, 3) every mesh's vertices (a vertex group's only), in the first mesh's frame
    faces: list  # their faces, indices into ``vertices``
    frame: np.ndarray  # (4, 4) the first mesh's world transform: the cage object's
    options: CageOptions
    fingerprint: str  # cage_scene.fingerprint of the meshes: their transforms and vertices, to tell a change

    @property
    def mesh_name(self):
        """The meshes' names, for progress lines ("Body, Shirt: shaping the cage")."""
        return ", ".join(self.mesh_names)


@dataclass(frozen=True)
class CageResult:
    """What :func:`lbc_addon.cage_scene.write` adds to the scene, and how long the making took."""

    cage: object  # lbc_core's GeneratedCage
    seconds: float


def make(request, progress=None, cancel=None, earlier=()):
    """Make the cage of ``request`` (no ``bpy`` here: safe in a worker thread); ``earlier`` is for
    :class:`lbc_addon.jobs.Worker`'s call and unused. Raises CageError (what to change) or lbc_core.Cancelled."""
    start = time.perf_counter()
    made = generate_cage(request.vertices, request.faces, progress=progress, cancel=cancel,
                         **request.options.core_keywords())
    return CageResult(made, time.perf_counter() - start)


def face_lists(faces):
    """A generated cage's faces as lists of ints, whatever their form ((F, 3) or (F, 4) arrays, or a list of
    n-gons), as ``Mesh.from_pydata`` takes them."""
    return [[int(index) for index in np.ravel(face)] for face in faces]
