"""bind end to end: rest pose, locality of an edit, save and load, outside points, progress, refusals.

Quality at the points and affine exactness on every shipped cage are in test_acceptance.py.
"""

from pathlib import Path

import time

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import lbc_core
from lbc_core.io import read_cage, read_mesh

DATA = Path(__file__).parent / "data"
L_POLYGON = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]])
CUBE = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
CUBE_FACES = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
# Float64 itself rounds a coordinate x by up to half its ulp, so no binding can follow an affine map of the cage more
# closely than a few ulps of the largest coordinate involved; this many are allowed.
AFFINE_ULPS = 8


def polygon_points(vertices, count, seed=0):
    from matplotlib.path import Path as PolygonPath

    rng = np.random.default_rng(seed)
    points = rng.uniform(vertices.min(axis=0), vertices.max(axis=0), (count, 2))
    return points[PolygonPath(vertices).contains_points(points)]


@pytest.fixture(scope="module")
def woody():
    vertices, _ = read_cage(DATA / "woody-control-edgeset.obj")
    vertices = vertices[:, :2]
    points = polygon_points(vertices, 4000)
    return vertices, points, lbc_core.bind(vertices, None, points)


@pytest.fixture(scope="module")
def gargoyle():
    vertices, faces = read_cage(DATA / "cages-3d" / "gargoyle" / "cage_L12.obj")
    points, _ = read_mesh(DATA / "cages-3d" / "gargoyle" / "mesh.off")
    return vertices, faces, points, lbc_core.bind(vertices, faces, points, cells=3000)


def test_rest_pose_is_exact_and_moving_one_vertex_is_local(gargoyle):
    vertices, faces, points, binding = gargoyle
    np.testing.assert_array_equal(binding.deform(vertices), points)
    moved = vertices.copy()
    moved[0] += 0.1 * binding.cage.bbox_diagonal
    displaced = np.linalg.norm(binding.deform(moved) - points, axis=1) > 0
    assert displaced.mean() < 0.5


def test_save_and_load_give_identical_deformations(gargoyle, tmp_path):
    vertices, faces, points, binding = gargoyle
    path = tmp_path / "binding.npz"
    binding.save(path)
    loaded = lbc_core.load_binding(path, vertices, faces)
    posed = vertices + np.random.default_rng(2).normal(0, 0.01, vertices.shape)
    np.testing.assert_array_equal(loaded.deform(posed), binding.deform(posed))
    assert loaded.options == binding.options and loaded.cage.fingerprint() == binding.cage.fingerprint()


def test_load_against_another_cage_is_refused(woody, tmp_path):
    vertices, _, binding = woody
    path = tmp_path / "binding.npz"
    binding.save(path)
    with pytest.raises(lbc_core.CageError, match="another cage"):
        lbc_core.load_binding(path, vertices[:-1], None)
    (tmp_path / "junk.npz").write_bytes(b"not a binding")
    with pytest.raises(lbc_core.CageError, match="not an lbc binding"):
        lbc_core.load_binding(tmp_path / "junk.npz")


def test_points_outside_are_bound_and_counted():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    points = np.array([[0.5, 0.5], [1.5, 0.5], [0.25, -0.5]])
    binding = lbc_core.bind(square, None, points, cells=200)
    np.testing.assert_array_equal(binding.outside, [False, True, True])
    assert binding.outside_count == 2
    # Outside points follow their closest domain point: a translation moves them rigidly.
    np.testing.assert_allclose(binding.deform(square + [2.0, 3.0]), points + [2.0, 3.0], atol=1e-12)


def test_progress_is_monotonic_and_cancel_stops():
    house = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, 1.5], [0.0, 1.0]])
    fractions = []
    lbc_core.bind(house, None, np.array([[0.5, 0.5]]), cells=300,
                  progress=lambda fraction, message: fractions.append(fraction))
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    with pytest.raises(lbc_core.Cancelled):
        lbc_core.bind(house, None, np.array([[0.5, 0.5]]), cells=300, cancel=lambda: True)


def test_bad_points_are_refused():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    with pytest.raises(lbc_core.CageError, match="NaN"):
        lbc_core.bind(square, None, np.array([[np.nan, 0.5]]))
    with pytest.raises(lbc_core.CageError, match="2D"):
        lbc_core.bind(square, None, np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.7]]))
    with pytest.raises(lbc_core.CageError, match="points must be real numbers"):
        lbc_core.bind(square, None, np.array([[0.5 + 1j, 0.5]]))
    with pytest.raises(lbc_core.CageError, match="the 2D cage lies in the plane z = 0 but the points in z = 5"):
        lbc_core.bind(np.c_[square, np.zeros(4)], None, np.array([[0.5, 0.5, 5.0]]))
    lbc_core.bind(np.c_[square, np.full(4, 5.0)], None, np.array([[0.5, 0.5, 5.0]]), cells=100)


@pytest.mark.parametrize(
    "cage, faces",
    [("[[0, 0], [1, 0], [0, 1]]", "None"),
     ("[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]", "[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]")],
    ids=["triangle", "tetrahedron"],
)
def test_simplex_cages_bind(cage, faces):
    # A simplex leaves the solver nothing to optimise; run in a child process so a crash fails the test, not the run.
    import subprocess
    import sys

    script = (
        "import numpy as np, lbc_core\n"
        f"cage = np.array({cage}, dtype=float)\n"
        f"b = lbc_core.bind(cage, {faces}, cage.mean(axis=0, keepdims=True), cells=300)\n"
        "w = b.weights.toarray()\n"
        "assert np.allclose(w, 1 / len(cage), atol=1e-9), w\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"bind on a simplex cage failed (exit code {run.returncode}): {run.stderr[-2000:]}"


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


def _missing_key(arrays):
    del arrays["weights_indptr"]


def _short_indptr(arrays):
    arrays["weights_indptr"] = arrays["weights_indptr"][:-1]


def _bad_options_json(arrays):
    arrays["options"] = np.array("{cells: 3")


@pytest.mark.parametrize(
    "edit, message",
    [
        (_times_five, "sum to 5, not 1"),  # every row does; which one is named depends on rounding
        (_reversed, "the weights of point"),
        (_index_out_of_range, "weights_indices holds indices outside 0 … 3"),
        (_missing_key, "it lacks weights_indptr"),
        (_short_indptr, "weights_indptr has shape (5,), not (6,)"),
        (_bad_options_json, "its options record is not valid JSON"),
    ],
    ids=["times-five", "reversed", "index-out-of-range", "missing-key", "short-indptr", "bad-options-json"],
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
@given(key=st.sampled_from(sorted(lbc_core.binding._ARRAYS)), edit=st.sampled_from(sorted(_EDITS)),
       seed=st.integers(0, 2**16))
def test_fuzz_edited_arrays(square_file, tmp_path, key, edit, seed):
    rng = np.random.default_rng(seed)

    def change(arrays):
        arrays[key] = _EDITS[edit](arrays[key], rng)

    path = _rewritten(square_file[0], tmp_path / "edited.npz", change)
    _loads_to_a_sound_binding_or_is_refused(path)


def inside_points(dim, count, rng):
    """Points well inside the unit-size L polygon (2D) or the unit cube (3D)."""
    if dim == 3:
        return rng.uniform(0.02, 0.98, (count, 3))
    points = rng.uniform(0.02, 1.98, (4 * count, 2))
    return points[(points[:, 0] < 0.98) | (points[:, 1] < 0.98)][:count]


def affine_error_bound(diagonal, *arrays):
    """max(1e-9 × the diagonal, AFFINE_ULPS ulps of the largest coordinate in ``arrays``)."""
    largest = max(np.abs(array).max() for array in arrays)
    return max(1e-9 * diagonal, AFFINE_ULPS * np.spacing(largest))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(dim=st.sampled_from([2, 3]), log_scale=st.floats(-9, 9), log_offset=st.floats(-3, 8),
       direction=st.lists(st.floats(-1, 1), min_size=3, max_size=3), matrix=st.lists(st.floats(-2, 2), min_size=9,
       max_size=9), log_shift=st.floats(-3, 8), seed=st.integers(0, 2**16))
def test_an_affine_map_of_the_cage_is_followed_at_any_offset_and_scale(dim, log_scale, log_offset, direction, matrix,
                                                                       log_shift, seed):
    """Issue 11, item 4: within 1e-9 of the diagonal, or a few ulps where float64 cannot do better (offset 1e8)."""
    rng = np.random.default_rng(seed)
    scale = 10.0**log_scale
    offset = 10.0**log_offset * np.array(direction[:dim])
    if np.any(np.abs(offset) > 1e12 * scale):  # beyond, float64 rounds the cage's own shape by 1e-4 of its size
        offset = offset / np.abs(offset).max() * 1e12 * scale
    unit_cage, faces = (L_POLYGON, None) if dim == 2 else (CUBE, CUBE_FACES)
    cage = unit_cage * scale + offset
    points = inside_points(dim, 60, rng) * scale + offset
    binding = lbc_core.bind(cage, faces, points, cells=300)
    assert not binding.outside.any()
    linear = np.array(matrix[:dim * dim]).reshape(dim, dim)
    shift = 10.0**log_shift * rng.uniform(-1, 1, dim)
    posed = cage @ linear.T + shift
    expected = points @ linear.T + shift
    error = np.abs(binding.deform(posed) - expected).max()
    assert error <= affine_error_bound(binding.cage.bbox_diagonal, cage, posed, points, expected)
    np.testing.assert_allclose(np.asarray(binding.weights.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_cages_far_from_the_origin_bind(dim):
    """An L polygon and a unit cube at 1e6 from the origin (they never finished meshing in the cage's coordinates;
    in 2D the bundled Delaunay mesher, which Blender uses, did not)."""
    unit_cage, faces = (L_POLYGON, None) if dim == 2 else (CUBE, CUBE_FACES)
    cage = unit_cage + 1e6
    points = inside_points(dim, 200, np.random.default_rng(5)) + 1e6
    binding = lbc_core.bind(cage, faces, points, method="delaunay")
    posed = cage * 1.5 + 3.0
    error = np.abs(binding.deform(posed) - (points * 1.5 + 3.0)).max()
    assert error <= affine_error_bound(binding.cage.bbox_diagonal, posed)
    # What is stored in the cage's units is in the cage's units: the domain and its control vertices, bitwise.
    assert binding.domain.vertices[binding.domain.control_vertices].tobytes() == binding.cage.vertices.tobytes()
    assert np.all(binding.domain.vertices >= 1e6 - 1e-9)


@pytest.mark.parametrize("size, offset", [(1.0, 1e8), (1e-6, 1e4), (1e-9, 10.0)])
def test_a_binding_far_from_the_origin_saves_and_loads(tmp_path, size, offset):
    """The load check measures reproduction about the cage's centre, as bind does (it refused these before)."""
    cage = L_POLYGON * size + offset
    binding = lbc_core.bind(cage, None, inside_points(2, 20, np.random.default_rng(7)) * size + offset, cells=300)
    binding.save(tmp_path / "far.npz")
    loaded = lbc_core.load_binding(tmp_path / "far.npz", cage)
    np.testing.assert_array_equal(loaded.deform(cage * 2.0), binding.deform(cage * 2.0))


@pytest.mark.parametrize("dim", [2, 3])
def test_a_scaled_cage_gives_the_same_weights(dim):
    """Scaling by a power of two is exact in the unit frame: identical weights, every length scaled exactly."""
    unit_cage, faces = (L_POLYGON, None) if dim == 2 else (CUBE, CUBE_FACES)
    points = inside_points(dim, 100, np.random.default_rng(6))
    small = lbc_core.bind(unit_cage, faces, points, cells=400)
    large = lbc_core.bind(unit_cage * 2.0**20, faces, points * 2.0**20, cells=400)
    assert (large.weights != small.weights).nnz == 0
    np.testing.assert_array_equal(large.domain.vertices, small.domain.vertices * 2.0**20)
    np.testing.assert_array_equal(large.domain_weights, small.domain_weights)
    assert large.objective == small.objective * 2.0 ** (20 * (dim - 1))


# Issue 11, item 3: each stage of a bind, told by the first progress message it sends, and the 0.5 s within which a
# cancel must stop it.
STAGE_MESSAGES = {
    "meshing": "",  # the first message of a bind is the mesher's
    "geodesics": "geodesic distances",
    "factorisation": "factorising the solver's matrix",
    "ADMM": "ADMM iteration",
    "projection": "projecting onto the constraints",
    "interpolation": "Interpolation",
    "reduction": "reducing the weights",
}
CANCEL_LATENCY = 0.5


def cancel_latency(cage_vertices, cage_faces, points, stage, **options):
    """Seconds from ``cancel()`` turning true, at the stage's first progress message, to :class:`Cancelled`."""
    turned_true = []

    def progress(fraction, message):
        if not turned_true and message.startswith(STAGE_MESSAGES[stage]):
            turned_true.append(time.perf_counter())

    with pytest.raises(lbc_core.Cancelled):
        lbc_core.bind(cage_vertices, cage_faces, points, progress=progress, cancel=lambda: bool(turned_true),
                      **options)
    assert turned_true, f"the {stage} stage sent no progress message"
    return time.perf_counter() - turned_true[0]


def longest_waits(cage_vertices, cage_faces, points, **options):
    """The longest time between two polls of ``cancel`` in each stage of a whole bind: the latency of a cancel that
    turns true at the worst moment. A wait is the stage's whose message came last before it began."""
    events = []  # (time, stage or None for a poll)

    def progress(fraction, message):
        stages = [name for name, prefix in STAGE_MESSAGES.items() if prefix and message.startswith(prefix)]
        events.append((time.perf_counter(), stages[0] if stages else None))

    def cancel():
        events.append((time.perf_counter(), "poll"))
        return False

    start = time.perf_counter()
    lbc_core.bind(cage_vertices, cage_faces, points, progress=progress, cancel=cancel, **options)
    longest, stage, last_poll = {}, "meshing", start
    for moment, kind in events:
        if kind == "poll":
            longest[stage] = max(longest.get(stage, 0.0), moment - last_poll)
            last_poll = moment
        elif kind is not None:
            stage = kind
    return longest


@pytest.fixture(scope="module")
def gargoyle_waits():
    """The waits of the 168-control-point gargoyle cage at the default resolution, where one ADMM iteration takes
    tens of milliseconds and the geodesics (uninterrupted before issue 11) a second; 60 iterations show the loop's."""
    vertices, faces = read_cage(DATA / "cages-3d" / "gargoyle" / "cage_L08.obj")
    points, _ = read_mesh(DATA / "cages-3d" / "gargoyle" / "mesh.off")
    return longest_waits(vertices, faces, points, cells=8000, max_iterations=60)


@pytest.fixture(scope="module")
def woody_waits(woody):
    vertices, points, _ = woody
    return longest_waits(vertices, None, points)


@pytest.mark.parametrize("stage", list(STAGE_MESSAGES))
def test_cancel_stops_every_stage_of_a_3d_bind_promptly(gargoyle, gargoyle_waits, stage):
    vertices, faces, points, _ = gargoyle
    latency = cancel_latency(vertices, faces, points, stage, cells=8000)
    assert latency < CANCEL_LATENCY, f"cancel took {latency:.2f} s to stop the {stage} stage"
    if stage != "meshing":  # the mesher's own loops are tested with it
        assert gargoyle_waits[stage] < CANCEL_LATENCY, f"{stage}: {gargoyle_waits[stage]:.2f} s between cancel polls"


@pytest.mark.parametrize("stage", list(STAGE_MESSAGES))
def test_cancel_stops_every_stage_of_a_2d_bind_promptly(woody, woody_waits, stage):
    vertices, points, _ = woody
    latency = cancel_latency(vertices, None, points, stage)
    assert latency < CANCEL_LATENCY, f"cancel took {latency:.2f} s to stop the {stage} stage"
    if stage != "meshing":
        assert woody_waits[stage] < CANCEL_LATENCY, f"{stage}: {woody_waits[stage]:.2f} s between cancel polls"
