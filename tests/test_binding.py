"""The Binding record and its files: save and load give identical deformations, the path written is the path
given, a damaged, edited or foreign file is refused as a whole (fuzzed), a cage of another size is refused."""

import re
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers.random_cages import STAR
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import lbc_core
from lbc_core.binding.files import FILE_ARRAYS, OPTIONAL_FILE_ARRAYS
from lbc_core.binding.record import SolvedAgain, Start
from lbc_core.errors import CageError
from lbc_core.io import read_mesh

pytestmark = pytest.mark.slow  # binds end to end: left out of the fast tier

DATA = Path(__file__).parent / "data"


def test_save_and_load_give_identical_deformations(gargoyle, tmp_path):
    vertices, faces, points, binding = gargoyle
    path = tmp_path / "binding.npz"
    binding.save(path)
    loaded = lbc_core.load_binding(path, vertices, faces)
    posed = vertices + np.random.default_rng(2).normal(0, 0.01, vertices.shape)
    np.testing.assert_array_equal(loaded.deform(posed), binding.deform(posed))
    assert loaded.options == binding.options and loaded.cage.fingerprint() == binding.cage.fingerprint()
    assert loaded.outcome == binding.outcome and loaded.outcome.start == "harmonic"


def test_a_warm_rebinds_outcome_is_saved_apart_from_its_options(tmp_path):
    """A binding keeps what it was asked (options, a BindOptions) apart from how it went (outcome), typed both."""
    first = lbc_core.bind(SQUARE, None, INSIDE, cells=200)
    edited = SQUARE.copy()
    edited[2] += 0.01
    warm = lbc_core.rebind(first, edited)
    assert warm.outcome.start is Start.WARM and isinstance(warm.outcome.solved_again, SolvedAgain)
    assert warm.options == first.options == lbc_core.BindOptions(cells=200)
    assert warm.outcome.cells == len(warm.domain.cells) and warm.outcome.threshold == 1e-3 / 4
    warm.save(tmp_path / "warm.npz")
    loaded = lbc_core.load_binding(tmp_path / "warm.npz")
    assert loaded.outcome == warm.outcome and loaded.options == warm.options
    assert (loaded.iterations, loaded.converged) == (warm.iterations, warm.converged)


def test_files_of_version_0_1_load_with_their_options_and_outcome_and_bind_again(tmp_path):
    """Files 0.1.0 wrote (tests/data/bindings-0.1.0, made by that release): their options record held the cells
    reached, the cells asked as cells_asked and the threshold resolved; their solved-again counts had prose names; they
    predate the smoothness option, and were evaluated as at smoothness 0."""
    cold = lbc_core.load_binding(DATA / "bindings-0.1.0" / "square.npz")
    assert cold.options == lbc_core.BindOptions(cells=200, epsilon=0.01, threshold=0.00025, smoothness=0.0)
    assert (cold.outcome.start, cold.outcome.cells, cold.outcome.threshold) == (Start.COLD, 206, 0.00025)
    warm = lbc_core.load_binding(DATA / "bindings-0.1.0" / "square-warm.npz")
    assert warm.outcome.start is Start.WARM and warm.outcome.solved_again == SolvedAgain(203, 206, 5, 5)
    assert warm.outcome.report.endswith("203 of 206 cells solved, 5 of 5 points evaluated")
    again = lbc_core.rebind(cold, SQUARE * 1.01)  # bound from scratch (no solver state in a file), as asked then
    assert again.options == cold.options and again.outcome.cells == 206


def test_files_before_0_1_holding_the_outcome_among_the_options_load(tmp_path):
    """Files written while the options record held the outcome's fields ("start", "rebind", "solved_again",
    "travel"), and before that without a start, load with them as the outcome."""
    import json

    source = DATA / "bindings-0.1.0" / "square-warm.npz"
    warm = lbc_core.load_binding(source)

    def options_holding_the_outcome(arrays):
        outcome = json.loads(str(arrays.pop("outcome")))
        outcome["rebind"] = outcome.pop("report")
        arrays["options"] = np.array(json.dumps(dict(json.loads(str(arrays["options"])), **outcome)))

    old = lbc_core.load_binding(_rewritten(source, tmp_path / "old.npz", options_holding_the_outcome))
    assert old.outcome == warm.outcome and old.options == warm.options

    def before_the_outcome(arrays):  # a bind from scratch recorded no start
        del arrays["outcome"]

    first = lbc_core.load_binding(DATA / "bindings-0.1.0" / "square.npz")
    old = lbc_core.load_binding(_rewritten(DATA / "bindings-0.1.0" / "square.npz", tmp_path / "old.npz",
                                           before_the_outcome))
    assert old.outcome == first.outcome and old.outcome.start is Start.COLD


def test_a_binding_made_with_a_weighting_function_loads_and_refuses_to_bind_again(tmp_path):
    def flat(distances):
        return np.ones_like(distances)

    binding = lbc_core.bind(SQUARE, None, INSIDE, cells=200, weighting=flat)
    binding.save(tmp_path / "own.npz")
    loaded = lbc_core.load_binding(tmp_path / "own.npz")
    np.testing.assert_array_equal(loaded.deform(SQUARE + 1.0), binding.deform(SQUARE + 1.0))
    with pytest.raises(lbc_core.CageError, match=r"weighting function of its own \(flat\).*weighting=that function"):
        lbc_core.rebind(loaded, SQUARE * 1.01)


def test_load_against_another_cage_is_refused(woody, tmp_path):
    vertices, _, binding = woody
    path = tmp_path / "binding.npz"
    binding.save(path)
    with pytest.raises(lbc_core.CageError, match="another cage"):
        lbc_core.load_binding(path, vertices[:-1], None)
    (tmp_path / "junk.npz").write_bytes(b"not a binding")
    with pytest.raises(lbc_core.CageError, match="not an lbc binding"):
        lbc_core.load_binding(tmp_path / "junk.npz")


def test_saved_polygon_binding_deforms_identically(tmp_path, star_binding):
    star_binding.save(tmp_path / "star.npz")
    loaded = lbc_core.load_binding(tmp_path / "star.npz", STAR)
    posed = STAR + np.random.default_rng(0).normal(scale=0.1, size=STAR.shape)
    np.testing.assert_array_equal(loaded.deform(posed), star_binding.deform(posed))
    np.testing.assert_array_equal(loaded.outside, star_binding.outside)


def test_saved_3d_binding_deforms_identically(tmp_path, clothing):
    cage, faces, posed, binding = clothing
    binding.save(tmp_path / "clothing.npz")
    loaded = lbc_core.load_binding(tmp_path / "clothing.npz", posed, faces)  # the posed cage has the same topology
    np.testing.assert_array_equal(loaded.deform(posed), binding.deform(posed))


def test_load_against_another_3d_cage_of_the_same_size_is_refused(tmp_path, clothing):
    _, _, _, binding = clothing
    binding.save(tmp_path / "clothing.npz")
    # The gargoyle's L13 cage has as many vertices (18) and triangles (32) as the clothing cage, but other faces.
    other, other_faces = read_mesh(DATA / "cages-3d" / "gargoyle" / "cage_L13.obj")
    with pytest.raises(CageError, match=r"bound to another cage \(18 vertices, 32 faces; this one has 18 vertices, "
                                        r"32 faces \(face \d+ differs\)\): bind this cage again"):
        lbc_core.load_binding(tmp_path / "clothing.npz", other, other_faces)


def test_a_binding_of_poked_n_gons_loads_with_them_and_so_does_a_file_from_before_they_were_poked(tmp_path,
                                                                                                  monkeypatch):
    """A pentagonal prism: its caps are poked (a centre each), saved and loaded with the binding, and checked against
    the facets around them. A file written while n-gons were ear-clipped has no centres: it loads, with a warning
    that binding again evens its n-gons out, and the same cage given beside it (poked now) is the cage it was bound
    to, its faces split otherwise."""
    import lbc_core.cage.triangulate as triangulate

    angles = 2 * np.pi * np.arange(5) / 5
    prism = np.array([[np.cos(a), np.sin(a), z] for z in (0.0, 1.0) for a in angles])
    faces = [[4, 3, 2, 1, 0], [5, 6, 7, 8, 9]] + [[i, (i + 1) % 5, 5 + (i + 1) % 5, 5 + i] for i in range(5)]
    points = np.array([[0.1, 0.2, 0.3], [-0.3, 0.1, 0.8], [0.0, 0.0, 0.5]])
    binding = lbc_core.bind(prism, faces, points, cells=300)
    assert len(binding.cage.centres) == 2
    binding.save(tmp_path / "poked.npz")
    loaded = lbc_core.load_binding(tmp_path / "poked.npz", prism, faces)
    assert [corners.tolist() for corners in loaded.cage.centres] == [c.tolist() for c in binding.cage.centres]
    assert loaded.cage.warnings == []
    np.testing.assert_array_equal(loaded.cage.surface_vertices, binding.cage.surface_vertices)

    def other_centre(arrays):
        arrays["cage_centre_corners"] = np.roll(arrays["cage_centre_corners"], 5)

    with pytest.raises(CageError, match="poked n-gon 0 does not match the facets around its centre"):
        lbc_core.load_binding(_rewritten(tmp_path / "poked.npz", tmp_path / "edited.npz", other_centre))

    monkeypatch.setattr(triangulate, "POKE_SIDES", 1000)
    clipped = lbc_core.bind(prism, faces, points, cells=300)
    assert clipped.cage.centres == ()
    clipped.save(tmp_path / "clipped.npz")
    monkeypatch.undo()

    def before_centres(arrays):
        del arrays["cage_centre_sizes"], arrays["cage_centre_corners"]

    old = _rewritten(tmp_path / "clipped.npz", tmp_path / "old.npz", before_centres)
    loaded = lbc_core.load_binding(old, prism, faces)
    assert loaded.cage.centres == () and len(lbc_core.make_cage(prism, faces).centres) == 2
    assert loaded.cage.warnings == [
        f"{old} was bound by an earlier version, which split n-gon faces (face 0, 1) into fans of triangles from one "
        "of their vertices: that vertex moves most of the face while the others barely do; bind again for every "
        "vertex to move its share"]
    np.testing.assert_array_equal(loaded.deform(prism * 1.1), clipped.deform(prism * 1.1))


def test_load_of_a_file_that_is_not_a_binding_is_refused(tmp_path):
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(CageError, match="not an lbc binding"):
        lbc_core.load_binding(tmp_path / "other.npz")


def test_deforming_with_a_cage_of_another_size_is_refused(star_binding):
    with pytest.raises(CageError, match="bind again"):
        star_binding.deform(STAR[:-1])


# Save and load: the path written is the path given; a damaged or edited file is refused as a whole, never used.

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
INSIDE = np.array([[0.5, 0.5], [0.2, 0.7], [0.9, 0.1], [0.4, 0.3]])
FUZZ = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def square_file(tmp_path_factory):
    """A small binding (with one point outside the cage) saved to a file, and its bytes."""
    path = tmp_path_factory.mktemp("square") / "square.npz"
    lbc_core.bind(SQUARE, None, np.r_[INSIDE, [[1.5, 0.5]]], cells=200).save(path)
    return path, path.read_bytes()


def test_save_writes_exactly_the_path_given(tmp_path):
    binding = lbc_core.bind(SQUARE, None, INSIDE, cells=200)
    binding.save(tmp_path / "binding.dat")
    assert [p.name for p in tmp_path.iterdir()] == ["binding.dat"]
    np.testing.assert_array_equal(lbc_core.load_binding(tmp_path / "binding.dat").weights.toarray(),
                                  binding.weights.toarray())


def test_save_to_a_missing_folder_or_a_full_disk_is_a_cage_error(tmp_path):
    binding = lbc_core.bind(SQUARE, None, INSIDE, cells=200)
    with pytest.raises(lbc_core.CageError, match="could not write .*nowhere.*No such file"):
        binding.save(tmp_path / "nowhere" / "b.npz")
    if Path("/dev/full").exists():
        with pytest.raises(lbc_core.CageError, match="the disk is full"):
            binding.save("/dev/full")


def _rewritten(source, target, edit):
    """Copy a binding file, changing its arrays with ``edit(dict of arrays)``."""
    with np.load(source) as data:
        arrays = {key: data[key] for key in data.files}
    edit(arrays)
    with open(target, "wb") as handle:
        np.savez(handle, **arrays)
    return target


def _times_five(arrays):
    arrays["weights_data"] = arrays["weights_data"] * 5


def _reversed(arrays):
    arrays["weights_data"] = arrays["weights_data"][::-1].copy()


def _index_out_of_range(arrays):
    arrays["weights_indices"] = arrays["weights_indices"] + 1000


def _negative_face(arrays):
    arrays["cage_facet_face"] = arrays["cage_facet_face"] - 1  # found by test_fuzz_edited_arrays: a crash, not a refusal


def _missing_key(arrays):
    del arrays["weights_indptr"]


def _short_indptr(arrays):
    arrays["weights_indptr"] = arrays["weights_indptr"][:-1]


def _bad_options_json(arrays):
    arrays["options"] = np.array("{cells: 3")


def _bad_outcome(arrays):
    arrays["outcome"] = np.array('{"start": 5, "report": ""}')


def _bad_counts(arrays):
    arrays["outcome"] = np.array('{"start": "previous solution", "solved_again": {"cells": "all"}}')


@pytest.mark.parametrize(
    "edit, message",
    [
        (_times_five, "sum to 5, not 1"),  # every row does; which one is named depends on rounding
        (_reversed, "the weights of point"),
        (_index_out_of_range, "weights_indices holds indices outside 0 … 3"),
        (_negative_face, "cage_facet_face holds indices outside 0 … 3"),
        (_missing_key, "it lacks weights_indptr"),
        (_short_indptr, "weights_indptr has shape (5,), not (6,)"),
        (_bad_options_json, "its options record is not valid JSON"),
        (_bad_outcome, "its outcome record holds start = 5"),
        (_bad_counts, "its outcome record holds solved_again = {'cells': 'all'}"),
    ],
    ids=["times-five", "reversed", "index-out-of-range", "negative-face", "missing-key", "short-indptr", "bad-options-json",
         "bad-outcome", "bad-counts"],
)
def test_edited_binding_files_are_refused(square_file, tmp_path, edit, message):
    path = _rewritten(square_file[0], tmp_path / "edited.npz", edit)
    with pytest.raises(lbc_core.CageError, match="is damaged or was edited") as error:
        lbc_core.load_binding(path)
    assert message in str(error.value)


@pytest.mark.parametrize(
    "content, message",
    [
        (b"", "is not an lbc binding file (EOFError"),
        (b"PK\x03\x04 truncated", "is not an lbc binding file (BadZipFile"),
        ("npy", "holds a single array, not an .npz archive"),
        ("other", "has no 'lbc-binding-1' format mark"),
        (None, "no such file"),
    ],
    ids=["empty", "bad-zip", "npy-renamed", "other-npz", "missing"],
)
def test_files_that_are_not_bindings_are_refused(tmp_path, content, message):
    path = tmp_path / "file.npz"
    if content == "npy":
        with open(path, "wb") as handle:
            np.save(handle, np.eye(3))
    elif content == "other":
        with open(path, "wb") as handle:
            np.savez(handle, weights=np.eye(3))
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(lbc_core.CageError) as error:
        lbc_core.load_binding(path)
    assert message in str(error.value)


def _declaring(source, target, declared):
    """Copy a binding file, the members named in ``declared`` replaced by a header declaring {key: (shape, dtype)}
    followed by 1 MB of deflated zeros: cheap to write, gigabytes to whoever reads what the header declares."""
    with zipfile.ZipFile(source) as original, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as copy:
        for name in original.namelist():
            key = name.removesuffix(".npy")
            if key not in declared:
                copy.writestr(name, original.read(name))
                continue
            shape, dtype = declared[key]
            with copy.open(name, "w", force_zip64=True) as member:
                header = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False,
                          "shape": shape}
                np.lib.format.write_array_header_1_0(member, header)
                member.write(bytes(2**20))
    return target


def _refusal_and_peak_memory(path):
    """The CageError load_binding raises on ``path``, and the most memory it held meanwhile (bytes)."""
    tracemalloc.start()
    try:
        with pytest.raises(CageError, match="is damaged or was edited") as error:
            lbc_core.load_binding(path)
        return str(error.value), tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_file_declaring_far_more_weights_than_it_has_indices_is_refused_unread(square_file, tmp_path):
    path = _declaring(square_file[0], tmp_path / "bomb.npz", {"weights_data": ((200_000_000,), np.float64)})
    message, peak = _refusal_and_peak_memory(path)
    assert re.search(r"its weights declare 200000000 numbers and \d+ indices, where 5 points of 4 control points hold at "
                     r"most 20", message)
    assert peak < 20 * 2**20  # reading the declared weights would allocate 1.6 GB


def test_a_file_declaring_huge_arrays_of_consistent_shapes_is_refused_unread(square_file, tmp_path):
    m = 20_000_000  # points, each with one weight: 629 MB of arrays in a file of 16 KB
    declared = {"points": ((m, 2), np.float64), "outside": ((m,), np.bool_), "weights_indptr": ((m + 1,), np.int32),
                "weights_data": ((m,), np.float64), "weights_indices": ((m,), np.int32)}
    message, peak = _refusal_and_peak_memory(_declaring(square_file[0], tmp_path / "bomb.npz", declared))
    assert re.search(r"its arrays would take 629 MB, [\d,]+ times the file's \d+ KB", message)
    assert peak < 20 * 2**20


def test_a_member_that_is_not_an_array_is_refused_unread(square_file, tmp_path):
    path = tmp_path / "raw.npz"
    with zipfile.ZipFile(square_file[0]) as original, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as copy:
        for name in original.namelist():
            copy.writestr(name, bytes(2**20) if name == "points.npy" else original.read(name))
    message, _ = _refusal_and_peak_memory(path)
    assert "it cannot be read (ValueError" in message


def _loads_to_a_sound_binding_or_is_refused(path):
    """The property every fuzzed file must have: a CageError, or a binding whose weights keep their guarantees."""
    try:
        binding = lbc_core.load_binding(path)
    except lbc_core.CageError as error:
        event(f"refused: {str(error).split(': ', 1)[1].split(' (')[0].split(' holds')[0][:40]}")
        return False
    event("loaded")
    weights = binding.weights
    assert weights.indices.min(initial=0) >= 0 and weights.indices.max(initial=-1) < weights.shape[1]
    np.testing.assert_allclose(np.asarray(weights.sum(axis=1)).ravel(), 1.0, atol=1e-7)
    inside = ~binding.outside
    np.testing.assert_allclose(weights[inside] @ binding.rest_cage_vertices, binding.points[inside], atol=1e-7)
    rest = binding.rest_cage_vertices[binding.cage.vertex_map]
    np.testing.assert_allclose(binding.deform(rest + [3.0, -1.0]), binding.points + [3.0, -1.0], atol=1e-6)
    return True


@FUZZ
@given(cut=st.integers(0, 10**6))
def test_fuzz_truncated_files(square_file, tmp_path, cut):
    source, content = square_file
    path = tmp_path / "cut.npz"
    path.write_bytes(content[: cut % len(content)])
    assert not _loads_to_a_sound_binding_or_is_refused(path)


@FUZZ
@given(bit=st.integers(0, 10**7))
def test_fuzz_bit_flips(square_file, tmp_path, bit):
    source, content = square_file
    bit %= 8 * len(content)
    flipped = bytearray(content)
    flipped[bit // 8] ^= 1 << (bit % 8)
    path = tmp_path / "flipped.npz"
    path.write_bytes(bytes(flipped))
    _loads_to_a_sound_binding_or_is_refused(path)


_EDITS = {
    "scale": lambda a, r: a * r.choice([-1.0, 0.5, 5.0]) if a.dtype.kind in "fiu" else a,
    "shift": lambda a, r: a + r.choice([1, -1, 1000]) if a.dtype.kind in "fiu" else a,
    "reverse": lambda a, r: a[::-1].copy() if a.ndim else a,
    "shuffle": lambda a, r: r.permutation(a) if a.ndim else a,
    "truncate": lambda a, r: a[: len(a) // 2] if a.ndim else a,
    "empty": lambda a, r: a[:0] if a.ndim else a,
    "transpose": lambda a, r: a.T.copy(),
    "float": lambda a, r: a.astype(float) if a.dtype.kind != "U" else a,
    "int": lambda a, r: a.astype(np.int64) if a.dtype.kind in "fb" else a,
    "nan": lambda a, r: np.where(r.random(a.shape) < 0.3, np.nan, a) if a.dtype.kind == "f" else a,
    "extra axis": lambda a, r: a[None],
    "text": lambda a, r: np.array("nonsense"),
}


@FUZZ
@given(key=st.sampled_from(sorted({**FILE_ARRAYS, **OPTIONAL_FILE_ARRAYS})), edit=st.sampled_from(sorted(_EDITS)),
       seed=st.integers(0, 2**16))
def test_fuzz_edited_arrays(square_file, tmp_path, key, edit, seed):
    rng = np.random.default_rng(seed)

    def change(arrays):
        arrays[key] = _EDITS[edit](arrays[key], rng)

    path = _rewritten(square_file[0], tmp_path / "edited.npz", change)
    _loads_to_a_sound_binding_or_is_refused(path)
