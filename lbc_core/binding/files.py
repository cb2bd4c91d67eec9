"""Binding files: :meth:`Binding.save` writes a compressed .npz archive with a format mark, the cage's fingerprint,
the options, the outcome and the version; :func:`load_binding` reads one back, checked as a whole before it is used
(the archive and its format, every array's presence, type and shape, every index, finite numbers, weights that sum to
1 and reproduce their points, the cage's fingerprint).
"""

import json
import math
import zipfile
from dataclasses import asdict, fields
from functools import partial
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ..cage import POKE_SIDES, Cage, make_cage, some_indices
from ..errors import CageError
from ..io import writing
from ..meshing import DomainMesh
from ..solve.forecast import format_size
from ..version import __version__
from .options import WEIGHTINGS, BindOptions, SavedWeighting
from .record import COLD, Binding, BindOutcome, SolvedAgain, Start

FORMAT = "lbc-binding-1"
# What load_binding accepts: a stored binding's rows sum to 1 and reproduce its points (the bound position) within
# 1e-9 of the cage's diagonal; edited or damaged weights miss by far more.
LOAD_TOLERANCE = 1e-7
# Schemes whose weights reproduce the points (bounded biharmonic weights have no linear precision).
_REPRODUCING = ("lbc", "mvc", "harmonic")


def save_binding(binding, path):
    """Write ``binding`` to ``path`` (:meth:`~lbc_core.binding.record.Binding.save`)."""
    weights = binding.weights.tocsr()
    arrays = dict(
        format=np.array(FORMAT),
        version=np.array(__version__),
        scheme=np.array(binding.scheme),
        fingerprint=np.array(binding.cage.fingerprint()),
        cage_vertices=binding.cage.vertices,
        cage_facets=binding.cage.facets,
        cage_facet_face=binding.cage.facet_face,
        cage_vertex_map=binding.cage.vertex_map,
        cage_centre_sizes=np.array([len(corners) for corners in binding.cage.centres], dtype=np.int64),
        cage_centre_corners=np.concatenate(binding.cage.centres + (np.zeros(0, np.int64),)).astype(np.int64),
        rest_cage_vertices=binding.rest_cage_vertices,
        weights_data=weights.data,
        weights_indices=weights.indices,
        weights_indptr=weights.indptr,
        weights_shape=np.array(weights.shape),
        points=binding.points,
        outside=binding.outside,
        domain_vertices=binding.domain.vertices,
        domain_cells=binding.domain.cells,
        domain_boundary_vertices=binding.domain.boundary_vertices,
        domain_boundary_facet=binding.domain.boundary_facet,
        domain_boundary_bary=binding.domain.boundary_bary,
        domain_control_vertices=binding.domain.control_vertices,
        domain_weights=binding.domain_weights,
        options=np.array(json.dumps(_options_record(binding.options))),
        outcome=np.array(json.dumps(_outcome_record(binding.outcome))),
        timings=np.array(json.dumps(binding.timings)),
        iterations=np.array(binding.iterations),
        converged=np.array(binding.converged),
        objective=np.array(binding.objective),
    )
    # np.savez_compressed's archive, written through a handle (numpy appends .npz to a name without it) and
    # closed in a with block (numpy leaves it open when a write fails, and its finaliser then prints a traceback).
    with writing(path) as handle, zipfile.ZipFile(handle, "w", zipfile.ZIP_DEFLATED) as archive:
        for key, value in arrays.items():
            with archive.open(key + ".npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def load_binding(path, cage_vertices=None, cage_faces=None):
    """Read a binding written by :meth:`Binding.save`, checked as a whole before it is used.

    Checked: the archive and its format, every array's presence, type and shape, every index against what it
    indexes, finite numbers, weights whose rows sum to 1 and reproduce the stored points, and the cage's fingerprint.

    Parameters
    ----------
    path : str or path-like
    cage_vertices, cage_faces : optional
        The cage the binding will deform; if given, it must have the topology the binding was made for.

    Returns
    -------
    Binding

    Raises
    ------
    CageError
        If the file is missing, not a binding, damaged or edited, or the given cage differs from the bound one.
    """
    arrays = _read_archive(path)
    damaged = partial(_damaged, path)
    cage, domain, weights = _checked_parts(arrays, damaged)
    if str(arrays["fingerprint"]) != cage.fingerprint():
        damaged("its cage does not match its fingerprint")
    ngons = np.flatnonzero(np.bincount(cage.facet_face) >= POKE_SIDES - 2)  # faces of POKE_SIDES sides or more
    if arrays["before_pokes"] and len(ngons):
        cage.warnings.append(
            f"{path} was bound by an earlier version, which split n-gon faces (face {some_indices(ngons)}) into "
            "fans of triangles from one of their vertices: that vertex moves most of the face while the others barely "
            "do; bind again for every vertex to move its share")
    if cage_vertices is not None:
        given = make_cage(cage_vertices, cage_faces)
        # The faces, not their split: a file of a version that split n-gons otherwise serves the same cage.
        bound_faces, given_faces = cage.face_corners(), given.face_corners()
        if not np.array_equal(given.vertex_map, cage.vertex_map) or given_faces != bound_faces:
            differ = next((f" (face {a[0]} differs)" for a, b in zip(bound_faces, given_faces) if a != b), "")
            raise CageError(
                f"{path} was bound to another cage ({len(cage.vertex_map)} vertices, {len(bound_faces)} faces; this "
                f"one has {len(given.vertex_map)} vertices, {len(given_faces)} faces{differ}): bind this cage again"
            )
    options, outcome = _options_and_outcome(arrays, damaged)
    return Binding(
        cage=cage,
        rest_cage_vertices=arrays["rest_cage_vertices"],
        weights=weights,
        domain=domain,
        domain_weights=arrays["domain_weights"],
        outside=arrays["outside"],
        points=arrays["points"],
        scheme=str(arrays["scheme"]),
        options=options,
        outcome=outcome,
        timings=_json_record(arrays, "timings", damaged),
        objective=float(arrays["objective"]),
    )


# The arrays of a binding file: (dtype kinds accepted, number of dimensions).
FILE_ARRAYS = {
    "format": ("U", 0), "version": ("U", 0), "scheme": ("U", 0), "fingerprint": ("U", 0),
    "cage_vertices": ("f", 2), "cage_facets": ("iu", 2), "cage_facet_face": ("iu", 1), "cage_vertex_map": ("iu", 1),
    "rest_cage_vertices": ("f", 2), "weights_data": ("f", 1), "weights_indices": ("iu", 1),
    "weights_indptr": ("iu", 1), "weights_shape": ("iu", 1), "points": ("f", 2), "outside": ("b", 1),
    "domain_vertices": ("f", 2), "domain_cells": ("iu", 2), "domain_boundary_vertices": ("iu", 1),
    "domain_boundary_facet": ("iu", 1), "domain_boundary_bary": ("f", 2), "domain_control_vertices": ("iu", 1),
    "domain_weights": ("f", 2), "options": ("U", 0), "timings": ("U", 0), "iterations": ("iu", 0),
    "converged": ("b", 0), "objective": ("f", 0),
}
# Arrays a file may lack: the poked n-gons' control points (their counts, then the points one n-gon after the other),
# which files written while every n-gon was ear-clipped do not hold; the outcome (JSON), which files written while
# the options held it do not.
OPTIONAL_FILE_ARRAYS = {"cage_centre_sizes": ("iu", 1), "cage_centre_corners": ("iu", 1), "outcome": ("U", 0)}
# What an absent optional array stands for.
_ABSENT = {"cage_centre_sizes": np.zeros(0, np.int64), "cage_centre_corners": np.zeros(0, np.int64),
           "outcome": None}
# The outcome's fields a file's options record held before the outcome had a record of its own, by their key there.
_OUTCOME_IN_OPTIONS = {"start": "start", "rebind": "report", "solved_again": "solved_again", "travel": "travel"}


def _damaged(path, what):
    """Raise the one message of a damaged binding file."""
    raise CageError(f"{path} is damaged or was edited: {what}; bind again to make a new one")


def _read_archive(path):
    """Every array of a binding file; CageError for anything that is not a readable binding.

    Every member's header (type, shape) is checked before any array is read: a few MB of deflated zeros can declare
    gigabytes, which reading would allocate before any later check could refuse them.
    """
    data = _open_archive(path)
    with data:
        try:
            if not _has_format_mark(data):
                raise CageError(f"{path} is not an lbc binding file (it has no {FORMAT!r} format mark): bind again "
                                "to make one")
            missing = [key for key in FILE_ARRAYS if key not in data.files]
            if missing:
                _damaged(path, f"it lacks {', '.join(missing)}")
            present = [key for key in {**FILE_ARRAYS, **OPTIONAL_FILE_ARRAYS} if key in data.files]
            _check_headers({key: _header(data, key) for key in present}, Path(path).stat().st_size,
                           partial(_damaged, path))
            arrays = {key: _read_member(data, key) for key in present}
            arrays["before_pokes"] = "cage_centre_sizes" not in present
        except CageError:
            raise
        except Exception as error:  # a damaged member: bad CRC, truncated stream, bad header
            _damaged(path, f"it cannot be read ({_reason(error)})")
    arrays.update({key: _ABSENT[key] for key in OPTIONAL_FILE_ARRAYS if key not in arrays})
    return arrays


def _open_archive(path):
    """The open .npz archive of a binding file (nothing read yet); CageError for a missing file or another kind."""
    if not Path(path).is_file():
        raise CageError(f"{path}: no such file")
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as error:  # numpy and zipfile raise many types on foreign or damaged files
        raise CageError(f"{path} is not an lbc binding file ({_reason(error)}): bind again to make one") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise CageError(f"{path} is not an lbc binding file (it holds a single array, not an .npz archive): bind "
                        "again to make one")
    return data


def _has_format_mark(data):
    """Whether the archive holds the format mark, its header checked first (a mark is a short string)."""
    if "format" not in data.files:
        return False
    shape, dtype = _header(data, "format")
    if shape != () or dtype.kind != "U" or dtype.itemsize != np.dtype(f"U{len(FORMAT)}").itemsize:
        return False
    return str(_read_member(data, "format")) == FORMAT


_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def _member(data, key):
    """One array's member of an open .npz archive, opened for reading (np.savez names it key.npy)."""
    names = data.zip.namelist()
    return data.zip.open(key + ".npy" if key + ".npy" in names else key)


def _header(data, key):
    """(shape, dtype) of one array of an open .npz archive, read from its .npy header alone."""
    with _member(data, key) as member:
        version = np.lib.format.read_magic(member)
        if version not in _HEADER_READERS:
            raise ValueError(f"{key} is in .npy format {version[0]}.{version[1]}, which binding files never use")
        shape, _, dtype = _HEADER_READERS[version](member)
    return shape, dtype


def _read_member(data, key):
    with _member(data, key) as member:
        return np.lib.format.read_array(member, allow_pickle=False)


# A binding's arrays take about twice its file (deflate gains little on floats; 1.8 to 2.8 for the test cages, 49 for
# 100,000 copies of one point). Headers declaring more than this many times the file, and more than the free
# allowance, are refused unread: memory stays within max(allowance, MAX_EXPANSION × the file's size).
MAX_EXPANSION = 64
EXPANSION_ALLOWANCE = 64 * 2**20


def _check_headers(headers, file_size, damaged):
    """Each array's type and shape, as its header declares them, and the memory they would take, before reading."""
    for key, (shape, dtype) in headers.items():
        kinds, ndim = {**FILE_ARRAYS, **OPTIONAL_FILE_ARRAYS}[key]
        if dtype.kind not in kinds or len(shape) != ndim:
            damaged(f"{key} has type {dtype} and {len(shape)} dimensions")
    _check_shapes({key: shape for key, (shape, _) in headers.items()}, damaged)
    declared = sum(math.prod(shape) * dtype.itemsize for shape, dtype in headers.values())
    if declared > max(EXPANSION_ALLOWANCE, MAX_EXPANSION * file_size):
        damaged(f"its arrays would take {format_size(declared)}, {declared / file_size:,.0f} times the file's "
                f"{format_size(file_size)}, where a binding's take about twice its file")


def _check_shapes(shapes, damaged):
    """Every array's shape against the sizes the others imply, the weights' count against what the points can hold."""
    n, d = shapes["cage_vertices"]
    facets = shapes["cage_facets"]
    if d not in (2, 3) or n < d + 1 or facets[1:] != (d,) or not facets[0]:
        damaged(f"its cage has {n} vertices in {d}D and facets of shape {facets}")
    m, n_domain = shapes["points"][0], shapes["domain_vertices"][0]
    count, indices = shapes["weights_data"][0], shapes["weights_indices"][0]
    if count != indices or count > m * n:
        damaged(f"its weights declare {count} numbers and {indices} indices, where {m} points of {n} control points "
                f"hold at most {m * n}")
    n_boundary = shapes["domain_boundary_vertices"][0]
    expected = {
        "cage_facet_face": (facets[0],), "rest_cage_vertices": (n, d), "points": (m, d), "outside": (m,),
        "weights_shape": (2,), "domain_vertices": (n_domain, d), "domain_cells": (shapes["domain_cells"][0], d + 1),
        "domain_boundary_facet": (n_boundary,), "domain_boundary_bary": (n_boundary, d),
        "domain_control_vertices": (n,), "domain_weights": (n_domain, n), "weights_indptr": (m + 1,),
    }
    for key, shape in expected.items():
        if shapes[key] != shape:
            damaged(f"{key} has shape {shapes[key]}, not {shape}")


def _reason(error):
    return f"{type(error).__name__}: {error}" if str(error) else type(error).__name__


def _checked_parts(arrays, damaged):
    """The cage, domain mesh and weights of a binding file (shapes checked), after checking indices and numbers."""
    cage_vertices, facets = arrays["cage_vertices"], arrays["cage_facets"]
    n, d = cage_vertices.shape
    sizes, centre_corners = arrays["cage_centre_sizes"], arrays["cage_centre_corners"]
    if np.any(sizes < 3) or np.sum(sizes) != len(centre_corners) or np.any((centre_corners < 0)
                                                                          | (centre_corners >= n)):
        damaged(f"its {len(sizes)} poked n-gons name {len(centre_corners)} control points of {n}")
    centres = tuple(np.split(centre_corners.astype(np.int64), np.cumsum(sizes)[:-1])) if len(sizes) else ()
    for c, corners in enumerate(centres):  # each centre's triangles run around its n-gon's control points
        around = facets[np.any(facets == n + c, axis=1)]
        if len(around) != len(corners) or set(around[around < n].tolist()) != set(corners.tolist()):
            damaged(f"its poked n-gon {c} does not match the facets around its centre")
    m = len(arrays["points"])
    domain_vertices, cells = arrays["domain_vertices"], arrays["domain_cells"]
    n_domain = len(domain_vertices)
    if tuple(arrays["weights_shape"]) != (m, n):
        damaged(f"its weights claim shape {tuple(arrays['weights_shape'])} for {m} points and {n} control points")
    ranges = {
        "cage_facets": n + len(centres), "cage_facet_face": len(facets), "cage_vertex_map": n, "weights_indices": n,
        "domain_cells": n_domain,
        "domain_boundary_vertices": n_domain, "domain_boundary_facet": len(facets),
        "domain_control_vertices": n_domain,
    }
    for key, size in ranges.items():
        if arrays[key].size and not (arrays[key].min() >= 0 and arrays[key].max() < size):
            damaged(f"{key} holds indices outside 0 … {size - 1}")
    for key in ("cage_vertices", "rest_cage_vertices", "weights_data", "points", "domain_vertices",
                "domain_boundary_bary", "domain_weights"):
        if not np.all(np.isfinite(arrays[key])):
            damaged(f"{key} holds NaN or infinite numbers")
    indptr = arrays["weights_indptr"]
    if indptr[0] != 0 or indptr[-1] != len(arrays["weights_data"]) or np.any(np.diff(indptr.astype(np.int64)) < 0):
        damaged("its weights' row pointers do not run from 0 to the number of weights")
    weights = sp.csr_matrix((arrays["weights_data"], arrays["weights_indices"], indptr), shape=(m, n))
    _check_weights(weights, arrays, damaged)
    cage = Cage(cage_vertices, facets, arrays["cage_facet_face"], arrays["cage_vertex_map"], centres=centres)
    domain = DomainMesh(domain_vertices, cells, arrays["domain_boundary_vertices"], arrays["domain_boundary_facet"],
                        arrays["domain_boundary_bary"], arrays["domain_control_vertices"])
    return cage, domain, weights


def _check_weights(weights, arrays, damaged):
    """Rows sum to 1 and, for schemes with linear precision, reproduce the stored points (bound position inside)."""
    rest = arrays["rest_cage_vertices"]
    diagonal = float(np.linalg.norm(np.ptp(rest, axis=0)))
    sums = np.asarray(weights.sum(axis=1)).ravel()
    if len(sums) and np.max(np.abs(sums - 1.0)) > LOAD_TOLERANCE:
        row = int(np.argmax(np.abs(sums - 1.0)))
        damaged(f"the weights of point {row} sum to {sums[row]:.9g}, not 1")
    if str(arrays["scheme"]) in _REPRODUCING:
        inside = ~arrays["outside"]
        # About the cage's centre, as bind computes: far from the origin Σ w c - x would be the rounding of the
        # offset times |Σ w - 1|, not the weights' miss.
        centre = (rest.min(axis=0) + rest.max(axis=0)) / 2
        miss = np.linalg.norm(weights[inside] @ (rest - centre) - (arrays["points"][inside] - centre), axis=1)
        if len(miss) and np.max(miss) > LOAD_TOLERANCE * diagonal:
            row = int(np.flatnonzero(inside)[np.argmax(miss)])
            damaged(f"the weights of point {row} place it {np.max(miss) / diagonal:.3g} of the cage's size away from "
                    "where it is")


def _json_record(arrays, key, damaged):
    try:
        record = json.loads(str(arrays[key]))
    except ValueError as error:
        damaged(f"its {key} record is not valid JSON ({error})")
    if not isinstance(record, dict):
        damaged(f"its {key} record is not a JSON object")
    return record


def _options_record(options):
    """What a file holds of a :class:`BindOptions` (JSON): every field, None for a default, a weighting function by
    its name (a file keeps no function)."""
    record = {field.name: getattr(options, field.name) for field in fields(options)}
    weighting = record["weighting"]
    if not isinstance(weighting, str):
        record["weighting"] = getattr(weighting, "name", None) or getattr(weighting, "__name__", repr(weighting))
    return record


def _outcome_record(outcome):
    """What a file holds of a :class:`BindOutcome` (JSON-able): all but the iterations and convergence, which have
    arrays of their own."""
    record = {field.name: getattr(outcome, field.name) for field in fields(outcome)}
    del record["iterations"], record["converged"]
    record["start"] = None if outcome.start is None else outcome.start.value
    record["solved_again"] = None if outcome.solved_again is None else asdict(outcome.solved_again)
    return record


def _options_and_outcome(arrays, damaged):
    """The :class:`BindOptions` and the :class:`BindOutcome` of a binding file. Files of earlier versions: before
    0.2 the options record held the cells reached and the threshold resolved (the cells asked as ``cells_asked``);
    before that, it held the outcome's fields too."""
    options = _json_record(arrays, "options", damaged)
    if arrays["outcome"] is None:
        record = {field: options.pop(key) for key, field in _OUTCOME_IN_OPTIONS.items() if key in options}
        if str(arrays["scheme"]) == "lbc":  # a bind from scratch recorded no start
            record.setdefault("start", COLD.value)
    else:
        record = _json_record(arrays, "outcome", damaged)
    if "cells" not in record:  # before 0.2: what the bind reached and resolved among its options
        record["cells"] = options.get("cells") or 0
        record["threshold"] = options.get("threshold")
        options["cells"] = options.pop("cells_asked", options.get("cells"))
    options.setdefault("smoothness", 0.0)  # bindings saved before the option were evaluated as at 0
    _check_outcome(record, damaged)
    return _bind_options(options, damaged), _bind_outcome(record, arrays)


def _bind_options(record, damaged):
    """The BindOptions of a file's options record; a weighting function it names as a :class:`SavedWeighting`."""
    known = {field.name for field in fields(BindOptions)}
    values = {key: value for key, value in record.items() if key in known}
    if isinstance(values.get("weighting"), str) and values["weighting"] not in WEIGHTINGS:
        values["weighting"] = SavedWeighting(values["weighting"])
    try:
        return BindOptions(**values)
    except CageError as error:
        damaged(f"its options record holds {error}")


def _bind_outcome(record, arrays):
    """The BindOutcome of a file's checked outcome record (solved-again counts named as files before 0.2 did, too)."""
    counts = record.pop("solved_again", None)
    if counts is not None:
        counts = SolvedAgain(**{_OLD_COUNT_NAMES.get(key, key): value for key, value in counts.items()})
    start = record.pop("start", None)
    return BindOutcome(iterations=int(arrays["iterations"]), converged=bool(arrays["converged"]),
                       start=None if start is None else Start(start), solved_again=counts, **record)


# The fields of a file's outcome record and the types each may have.
_OUTCOME_FIELDS = {"start": (str, type(None)), "solved_again": (dict, type(None)), "report": (str,),
                   "travel": (int, float), "cells": (int,), "threshold": (int, float, type(None))}
# The solved-again counts as files before 0.2 named them.
_OLD_COUNT_NAMES = {"cells solved": "cells_solved", "points evaluated": "points_evaluated"}


def _check_outcome(record, damaged):
    """A file's outcome record: known fields of their types, where it started, a warm re-bind's four counts, finite
    numbers."""
    for key, value in record.items():
        if key not in _OUTCOME_FIELDS or isinstance(value, bool) or not isinstance(value, _OUTCOME_FIELDS[key]):
            damaged(f"its outcome record holds {key} = {value!r}")
    if record.get("start") is not None and record["start"] not in {start.value for start in Start}:
        damaged(f"its outcome record holds start = {record['start']!r}")
    counts = record.get("solved_again")
    names = {_OLD_COUNT_NAMES.get(key, key) for key in counts or ()}
    if counts is not None and (names != {field.name for field in fields(SolvedAgain)} or len(names) != len(counts)
                               or not all(isinstance(count, int) and not isinstance(count, bool)
                                          for count in counts.values())):
        damaged(f"its outcome record holds solved_again = {counts!r}")
    for key in ("travel", "threshold"):
        if not math.isfinite(record.get(key) or 0.0):
            damaged(f"its outcome record holds {key} = {record[key]!r}")
