"""Warm re-bind: the carried mesh, the warm result's guarantees, its match with a cold solve, and every fallback."""

import types
from pathlib import Path

import numpy as np
import pytest

import lbc_core
from lbc_core.solve.boundary import boundary_weights
from lbc_core.kernel.frame import UnitFrame
from lbc_core.solve.geodesics import geodesic_distances, tv_weights
from lbc_core.io import read_cage, read_mesh
from lbc_core.kernel.geometry import orient_positive, signed_measures
from lbc_core.binding.carry import _squashed, carry_domain, flipped_slivers
from lbc_core.binding.rebinding import STALE, rebind
from lbc_core.evaluate.smoothing import median_edge
from lbc_core.solve.solver import solve_on_mesh


DATA = Path(__file__).parent / "data"
GARGOYLE = DATA / "cages-3d" / "gargoyle"
UNITY, REPRODUCTION, NEGATIVE = 1e-9, 1e-9, -1e-12


@pytest.fixture(scope="module")
def gargoyle():
    cage, faces = read_cage(GARGOYLE / "cage_L12.obj")
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    return cage, faces, points, lbc_core.bind(cage, faces, points, cells=3000)


@pytest.fixture(scope="module")
def gargoyle_l10():
    """A finer cage (67 control points), whose coordinates are more local: an edit leaves some points alone."""
    cage, faces = read_cage(GARGOYLE / "cage_L10.obj")
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    return cage, faces, points, lbc_core.bind(cage, faces, points, cells=3000)


def moved(cage, vertices, share, direction=(0.3, -0.5, 0.8)):
    """``cage`` with ``vertices`` moved by ``share`` of its diagonal along ``direction``."""
    direction = np.asarray(direction[:cage.shape[1]], dtype=float)
    edited = cage.copy()
    edited[vertices] += share * np.linalg.norm(np.ptp(cage, axis=0)) * direction / np.linalg.norm(direction)
    return edited


def assert_guarantees(binding, points):
    """Partition of unity, reproduction and non-negativity at the domain's vertices and at the points (the rows of
    points outside the cage extrapolate: signed); Lagrange at the control vertices; the rest pose exact."""
    controls = binding.cage.vertices
    diagonal = binding.cage.bbox_diagonal
    domain_weights = binding.domain_weights
    assert np.abs(domain_weights.sum(axis=1) - 1).max() <= UNITY
    assert np.abs(domain_weights @ controls - binding.domain.vertices).max() <= REPRODUCTION * diagonal
    assert domain_weights.min() >= NEGATIVE
    np.testing.assert_array_equal(domain_weights[binding.domain.control_vertices], np.eye(len(controls)))
    weights = binding.weights.toarray()
    inside = ~binding.outside
    assert np.abs(weights.sum(axis=1) - 1).max() <= UNITY
    assert np.abs(weights[inside] @ controls - points[inside]).max() <= REPRODUCTION * diagonal
    assert weights[inside].min() >= NEGATIVE
    np.testing.assert_array_equal(binding.deform(controls[binding.cage.vertex_map]), points)


def cold_on_carried_mesh(previous, cage_vertices, faces):
    """A cold solve of the edited cage on the very mesh a warm re-bind carries: the same problem, on working sets as
    the warm re-bind solves it (a cold bind of this cage takes the dense splitting, within the same tolerance of the
    optimum but not the same weights to 0.05)."""
    cage = lbc_core.make_cage(cage_vertices, faces)
    frame = UnitFrame.of(cage)
    unit_cage = frame.cage_to_unit(cage)
    mesh, reason = carry_domain(previous, unit_cage)
    assert reason is None
    weights = tv_weights(mesh.cells, geodesic_distances(mesh.vertices, mesh.cells, mesh.control_vertices))
    result = solve_on_mesh(mesh.vertices, mesh.cells, mesh.boundary_vertices, boundary_weights(mesh, unit_cage),
                           unit_cage.vertices, weights, splitting="working sets")
    return result, frame


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_warm_rebind_meets_every_guarantee_and_matches_a_cold_solve_on_its_mesh(gargoyle):
    cage, faces, points, first = gargoyle
    edited = moved(cage, [3, 11], 0.01)
    warm = rebind(first, edited, faces)
    assert warm.outcome.start == "previous solution"
    assert warm.outcome.report.startswith("bound again from the previous binding: ")
    assert warm.converged
    assert_guarantees(warm, points)
    # The mesh is the previous one, carried: same cells, boundary vertices on the same facets, control vertices on
    # the moved control points.
    np.testing.assert_array_equal(warm.domain.cells, first.domain.cells)
    np.testing.assert_array_equal(warm.domain.vertices[warm.domain.control_vertices], warm.cage.vertices)
    cold, frame = cold_on_carried_mesh(first, edited, faces)
    assert warm.iterations < cold.iterations / 2
    # The same optimum within the solver's tolerance: objectives within 0.1 %, weights within a few hundredths.
    assert abs(warm.objective / (cold.objective * frame.scale ** 2) - 1) < 1e-3
    assert np.abs(warm.domain_weights - cold.weights).max() < 0.05


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_warm_rebind_runs_the_pipelines_stages_on_one_progress_bar_and_times_them(gargoyle):
    """The re-bind's stages are the pipeline's (one table of shares, STAGES): the bar runs from 0 to 1 without going
    back, and the timings name the pipeline's stages (the solve by the solver's own parts)."""
    from lbc_core.binding.pipeline import REBIND_STAGES, STAGES

    cage, faces, points, first = gargoyle
    fractions = []
    warm = rebind(first, moved(cage, [3], 0.01), faces, progress=lambda fraction, message: fractions.append(fraction))
    assert warm.outcome.start == "previous solution"
    assert fractions[-1] == pytest.approx(1.0) and np.all(np.diff(fractions) >= -1e-12)
    assert set(REBIND_STAGES) <= set(STAGES)
    assert {"checks", "carry", "geodesics", "interpolation", "reduction"} <= set(warm.timings)
    assert set(first.timings) - set(STAGES) == set(warm.timings) - set(STAGES)  # the solver's parts, named alike


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_warm_rebind_follows_a_cold_bind_of_the_edited_cage(gargoyle):
    cage, faces, points, first = gargoyle
    edited = moved(cage, [5], 0.02)
    warm = rebind(first, edited, faces)
    cold = lbc_core.bind(edited, faces, points, cells=3000)
    posed = moved(edited, [0, 1, 2], 0.1)
    # Two cold binds on different meshes differ by about as much (see bench/RESULTS.md, "Warm re-bind").
    gap = np.linalg.norm(warm.deform(posed) - cold.deform(posed), axis=1).max()
    assert gap < 5e-3 * warm.cage.bbox_diagonal


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_points_out_of_reach_of_the_edit_keep_their_weights_and_the_rest_match_a_full_evaluation(gargoyle_l10):
    cage, faces, points, first = gargoyle_l10
    edited = moved(cage, [4], 0.01)
    warm = rebind(first, edited, faces)
    counts = warm.outcome.solved_again
    evaluated = counts.points_evaluated
    assert 0 < evaluated < counts.points == len(points)
    assert warm.outcome.report.endswith(f"{evaluated} of {len(points)} points evaluated")
    kept = np.flatnonzero(np.asarray(abs(warm.weights - first.weights).sum(axis=1)).ravel() == 0)
    assert len(kept) >= len(points) - evaluated
    assert_guarantees(warm, points)
    # One point more: every point is evaluated again on the same solve.
    extra = np.r_[points, points[:1]]
    full = rebind(first, edited, faces, points=extra)
    np.testing.assert_array_equal(full.domain_weights, warm.domain_weights)
    difference = np.asarray(abs(full.weights[:len(points)] - warm.weights).max(axis=1).todense()).ravel()
    assert difference[np.setdiff1d(np.arange(len(points)), kept)].max() < 1e-9
    # The rows kept near vertices that changed by less than STALE are within a fifth of it of their evaluation.
    assert 0 < difference[kept].max() <= STALE / 5
    assert np.all(full.stale == 0) and warm.stale.max() <= STALE


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_staleness_adds_up_over_warm_rebinds_until_the_points_are_evaluated_again(gargoyle_l10):
    cage, faces, points, first = gargoyle_l10
    assert first.stale is None
    once = rebind(first, moved(cage, [4], 0.003), faces)
    twice = rebind(once, moved(cage, [4], 0.006), faces)
    frame = UnitFrame.of(twice.cage)
    old, new = (frame.to_unit(binding.domain.vertices) for binding in (once, twice))
    change = (np.abs(twice.domain_weights - once.domain_weights).max(axis=1)
              + np.linalg.norm(new - old, axis=1) / median_edge(new, twice.domain.cells))
    total = once.stale + change
    over = total > STALE
    assert np.all(twice.stale[over] == 0)  # the points near them were evaluated again
    np.testing.assert_allclose(twice.stale[~over], total[~over], atol=1e-12)
    assert np.any(over & (once.stale > 0) & (change < STALE))  # over only with the first edit's change counted


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_second_warm_rebind_starts_from_the_first(gargoyle):
    cage, faces, points, first = gargoyle
    once = rebind(first, moved(cage, [3], 0.01), faces)
    twice = rebind(once, moved(cage, [3, 20], 0.01), faces)
    assert twice.outcome.start == "previous solution"
    assert_guarantees(twice, points)
    assert twice.iterations <= first.iterations / 2


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_an_unmoved_cage_gives_the_previous_weights_back(gargoyle):
    cage, faces, points, first = gargoyle
    again = rebind(first, cage, faces)
    assert again.iterations == 0
    # Said plainly, not as "0 of 2939 cells solved, 0 of 2674 points evaluated" (a colleague's Rebind after Undo).
    assert again.outcome.report == ("bound again from the previous binding: it was made for the cage as it is now, "
                                    "so nothing was solved or evaluated again")
    np.testing.assert_array_equal(again.domain_weights, first.domain_weights)
    assert abs(again.weights - first.weights).max() < 1e-9


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_an_edit_that_would_fold_the_mesh_falls_back_to_a_cold_bind(gargoyle):
    cage, faces, points, first = gargoyle
    # A vertex pushed deep inward drags the cells around it through their neighbours.
    centre = cage.mean(axis=0)
    edited = cage.copy()
    edited[0] += 0.6 * (centre - cage[0])
    messages = []
    warm = rebind(first, edited, faces, progress=lambda fraction, message: messages.append(message))
    assert warm.outcome.start == "harmonic"
    reason = warm.outcome.report
    assert reason.startswith("bound from scratch: the edit would turn inside out some of the cells the last "
                              "bind filled the cage with (") and "near cage vertices 0" in reason
    assert any(message.startswith("binding from scratch") for message in messages)
    assert_guarantees(warm, points)
    assert warm.solver_state is not None  # and the next re-bind can be warm again


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_an_edit_that_squashes_a_cell_rebinds_warm_once_its_free_corners_are_polished(gargoyle):
    """Cage vertex 4 moved by 8 % squashes a carried cell (the previous weights put it below a quarter of its shape;
    vertex 6 did on the mesh before the lattice side was counted); its free corners are moved as the mesher polishes,
    those vertices are solved again, and the re-bind stays warm: every guarantee, and the optimum of a cold solve on
    the same mesh."""
    cage, faces, points, first = gargoyle
    edited = moved(cage, [4], 0.08)
    edited_cage = lbc_core.make_cage(edited, faces)
    carried_to = first.domain_weights @ UnitFrame.of(edited_cage).cage_to_unit(edited_cage).vertices
    assert _squashed(first.domain, carried_to).any()
    warm = rebind(first, edited, faces)
    assert warm.outcome.start == "previous solution"
    assert_guarantees(warm, points)
    polished = np.linalg.norm(warm.domain.vertices - first.domain_weights @ warm.cage.vertices, axis=1)
    assert np.any(polished > 1e-9 * warm.cage.bbox_diagonal)
    cold, frame = cold_on_carried_mesh(first, edited, faces)
    assert abs(warm.objective / (cold.objective * frame.scale ** 2) - 1) < 1e-3


def test_a_sliver_on_the_cage_turned_inside_out_is_mended_by_a_3_2_flip():
    """A sliver with every corner on the cage between two cells of one apex p, the three all around its inner edge
    a-b: an edit raising a-b above the cage edge e1-e2 turns the sliver inside out, and the three cells become the two
    across e1-e2-p, positively oriented; with a fourth cell around a-b there is no 3-2 flip."""
    e1, e2, a, b, p, q = range(6)
    rest = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, -0.1], [0.5, -1, -0.1], [0.5, 0, 1], [0.5, 0, -1]], dtype=float)
    cells = orient_positive(rest, np.array([[e1, e2, a, b], [e2, a, b, p], [e1, a, b, p]]))
    edited = rest + [[0, 0, 0], [0, 0, 0], [0, 0, 0.2], [0, 0, 0.2], [0, 0, 0], [0, 0, 0]]
    folded = signed_measures(edited, cells) <= 0
    assert folded.tolist() == [True, False, False]
    mended = flipped_slivers(edited, cells, np.array([e1, e2, a, b]), folded)
    assert sorted(map(sorted, mended.tolist())) == [[e1, e2, a, p], [e1, e2, b, p]]
    assert np.all(signed_measures(edited, mended) > 0)
    crowded = np.concatenate([cells, [[a, b, q, e1]]])
    assert np.array_equal(flipped_slivers(edited, crowded, np.array([e1, e2, a, b]), np.r_[folded, False]), crowded)


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_an_edit_that_turns_a_sliver_on_the_cage_inside_out_rebinds_warm():
    """The kind of edit a colleague made in Blender (cage L09, a vertex moved outward by 2 % of the diagonal; vertex 48
    on today's mesh) bound from scratch: it turns inside out a sliver on the cage. Mended by a 3-2 flip, the re-bind stays warm, meets every guarantee and
    reaches the optimum of a cold solve on the same cells."""
    cage, faces = read_cage(GARGOYLE / "cage_L09.obj")
    points, _ = read_mesh(GARGOYLE / "mesh.off")
    first = lbc_core.bind(cage, faces, points)
    corners = cage[np.array(faces)]
    normals = np.zeros_like(cage)
    for k in range(3):
        np.add.at(normals, np.array(faces)[:, k], np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    edited = cage.copy()
    edited[48] += 0.02 * np.linalg.norm(np.ptp(cage, axis=0)) * normals[48] / np.linalg.norm(normals[48])
    edited_cage = lbc_core.make_cage(edited, faces)
    carried_to = first.domain_weights @ UnitFrame.of(edited_cage).cage_to_unit(edited_cage).vertices
    assert np.any(signed_measures(carried_to, first.domain.cells) <= 0)  # the edit folds the carried mesh
    warm = rebind(first, edited, faces)
    assert warm.outcome.start == "previous solution"
    assert len(warm.domain.cells) == len(first.domain.cells) - 1
    assert_guarantees(warm, points)
    cold, frame = cold_on_carried_mesh(first, edited, faces)
    assert abs(warm.objective / (cold.objective * frame.scale ** 2) - 1) < 1e-3


def test_a_squashed_cell_counts_only_with_a_corner_off_the_cage():
    """A cell carried to a sliver refuses the carried mesh when a corner of it is free; with every corner on the cage
    its values are fixed boundary values, its shape never enters the solve, and it does not (the gargoyle's L09 cage
    fell back to a cold bind for one such cell at an edit of 3 vertices by 1 %)."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    flattened = vertices.copy()
    flattened[3] = [0.45, 0.5, 0.02]  # both cells keep their orientation and lose most of their shape
    for on_cage, squashed in (([0, 1, 2, 3, 4], [False, False]), ([0, 1, 2, 4], [True, True]),
                              ([0, 1, 2, 3], [False, True])):
        mesh = types.SimpleNamespace(vertices=vertices, cells=cells, boundary_vertices=np.array(on_cage))
        assert _squashed(mesh, flattened).tolist() == squashed


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_another_topology_or_a_loaded_binding_falls_back_to_a_cold_bind(gargoyle, tmp_path):
    cage, faces, points, first = gargoyle
    path = tmp_path / "b.npz"
    first.save(path)
    loaded = lbc_core.load_binding(path)
    assert loaded.solver_state is None
    edited = moved(cage, [3], 0.01)
    again = rebind(loaded, edited, faces)
    assert again.outcome.report.startswith("bound from scratch: the previous binding's solver state is not at hand")
    # From scratch is the bind the artist made, at the cells asked for (not those the first mesh reached).
    fresh = lbc_core.bind(edited, faces, points, cells=3000)
    assert len(first.domain.cells) != 3000 and again.options.cells == 3000
    assert abs(again.weights - fresh.weights).max() == 0
    # The cube's quads split along their other diagonals: other facets, so the carried mesh no longer fits.
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    bound = lbc_core.bind(cube, quads, cube * 0.5 + 0.25, cells=300)
    other_split = [triangle for a, b, c, d in quads for triangle in ([a, b, d], [b, c, d])]
    reason = rebind(bound, cube, other_split).outcome.report
    assert reason == "bound from scratch: the cage's vertices, faces or welding changed"


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_quad_bent_out_of_its_plane_rebinds_warm_when_the_mesh_follows_its_diagonal():
    """An artist's edit at rest bends the quads around the moved vertex along their diagonals; the mesher made the
    well-shaped quads' diagonals features, so the carried mesh stays on the bent cage."""
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    points = cube * 0.5 + 0.25
    first = lbc_core.bind(cube, quads, points, cells=300)
    edited = cube.copy()
    edited[7] -= 0.01  # towards the centre: each quad at vertex 7 keeps its split, but bends
    again = rebind(first, edited, quads)
    assert again.outcome.report.startswith("bound again from the previous binding"), again.outcome.report
    assert_guarantees(again, points)
    fresh = lbc_core.bind(edited, quads, points, cells=300)
    assert abs(again.weights - fresh.weights).max() < 0.05  # within the remeshing noise of a 300-cell bind


def surface_off_cage(binding):
    """How far the domain's boundary triangles leave the cage (at their centroids and edge midpoints: chords across a
    bent cage edge), over the median cell edge."""
    from lbc_core.kernel.fem import boundary_facets
    from lbc_core.kernel.geometry import closest_on_facets
    from lbc_core.evaluate.smoothing import median_edge

    cage, domain = binding.cage, binding.domain
    corners = domain.vertices[boundary_facets(domain.cells)]  # (K, 3, 3)
    samples = np.concatenate([corners.mean(axis=1), ((corners + np.roll(corners, 1, axis=1)) / 2).reshape(-1, 3)])
    nearest = np.full(len(samples), np.inf)
    for facet in cage.surface_vertices[cage.facets]:
        squared = closest_on_facets(samples, np.broadcast_to(facet, (len(samples), 3, 3)).copy())[0]
        nearest = np.minimum(nearest, squared)
    return float(np.sqrt(nearest.max()) / median_edge(domain.vertices, domain.cells))


def test_a_quad_bent_a_little_rebinds_warm_with_the_mesh_split_along_its_diagonal(monkeypatch):
    """A flat box's sides are too skinny for their diagonals to be features (16.7° angles), so the previous mesh has
    boundary faces across them. Bent by a small edit, a diagonal is a crease of the boundary values: the mesh edges
    it crosses are split there, so the carried surface follows it, and no face is left across it (the re-bind stays
    warm even with no chord allowed, CHORD_KEPT 0)."""
    import lbc_core.binding.carry as carry

    box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 0.3)], dtype=float)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    points = box * 0.5 + [0.25, 0.25, 0.075]
    first = lbc_core.bind(box, quads, points, cells=300)
    assert surface_off_cage(first) < 1e-12
    edited = box.copy()
    edited[7, 0] -= 0.01  # bends the faces at vertex 7 that are not perpendicular to x
    monkeypatch.setattr(carry, "CHORD_KEPT", 0.0)
    again = rebind(first, edited, quads)
    assert again.outcome.start == "previous solution", again.outcome.report
    assert len(again.domain.vertices) > len(first.domain.vertices)  # the crossed mesh edges split
    assert surface_off_cage(again) < 1e-3
    assert_guarantees(again, points)


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_side_vertex_of_a_loop_cut_cylinder_moved_out_rebinds_warm_with_the_surface_on_the_cage():
    """Blender's Cylinder with two loop cuts: moving a side vertex out turns the loop's edges and the quads' diagonals
    around it into creases, which the previous mesh's faces crossed. Carried as they were, they left the cage by 7 %
    of a cell here, and the re-bind lay twice as far from a fine bind as a cold one, posed at that vertex
    (bench/RESULTS.md); split along the bent edges, the carried surface lies on the cage."""
    angles = 2 * np.pi * np.arange(32) / 32
    cylinder = np.array([[np.cos(a), np.sin(a), z] for z in (-1, -1 / 3, 1 / 3, 1) for a in angles])
    faces = [[r * 32 + s, r * 32 + (s + 1) % 32, (r + 1) * 32 + (s + 1) % 32, (r + 1) * 32 + s]
             for r in range(3) for s in range(32)] + [list(range(32))[::-1], list(range(96, 128))]
    points = np.random.default_rng(2).uniform(-0.6, 0.6, (400, 3))
    first = lbc_core.bind(cylinder, faces, points, cells=2000)
    edited = cylinder.copy()
    edited[40, :2] *= 1.07
    again = rebind(first, edited, faces)
    assert again.outcome.start == "previous solution", again.outcome.report
    assert surface_off_cage(again) < 1e-3
    assert_guarantees(again, points)


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_loop_cut_cylinder_rebinds_warm_after_a_loop_is_scaled_or_a_cap_vertex_lifted():
    """Blender's Cylinder with two loop cuts: scaling a loop keeps its quads planar trapezoids, lifting a cap vertex
    bends the 32-gon cap; neither moves the carried mesh's faces off the cage by more than CHORD_KEPT of a cell. (The
    check once judged faces by the facets their corners were recorded on, any facet at a cage vertex, and bound
    every such edit from scratch.)"""
    angles = 2 * np.pi * np.arange(32) / 32
    cylinder = np.array([[np.cos(a), np.sin(a), z] for z in (-1, -1 / 3, 1 / 3, 1) for a in angles])
    faces = [[r * 32 + s, r * 32 + (s + 1) % 32, (r + 1) * 32 + (s + 1) % 32, (r + 1) * 32 + s]
             for r in range(3) for s in range(32)] + [list(range(32))[::-1], list(range(96, 128))]
    points = np.array([[0.3, 0.2, -0.5], [-0.4, 0.1, 0.0], [0.0, -0.5, 0.6], [0.6, 0.0, 0.9], [0.1, 0.1, 0.1]])
    first = lbc_core.bind(cylinder, faces, points, cells=2000)
    scaled, lifted = cylinder.copy(), cylinder.copy()
    scaled[32:64, :2] *= 1.05
    lifted[100, 2] += 0.05
    for edited in (scaled, lifted):
        again = rebind(first, edited, faces)
        assert again.outcome.start == "previous solution", again.outcome.report
        assert_guarantees(again, points)


def test_chord_distances_measure_how_far_a_face_across_a_fold_leaves_the_cage():
    """A triangle across the fold of a roof (two facets meeting at 90° along x = 0) leaves it at its midpoints;
    one lying in a facet does not."""
    from lbc_core.cage.record import Cage
    from lbc_core.binding.carry import _chord_distances

    roof = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [-1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [1.0, 0.0, 0.0],
                     [1.0, 1.0, 0.0]])
    facets = np.array([[0, 2, 3], [0, 3, 1], [0, 1, 5], [0, 5, 4]])
    cage = Cage(roof, facets, np.arange(4), np.arange(6), [])
    across = np.array([[[-0.5, 0.2, 0.5], [0.5, 0.2, 0.5], [0.0, 0.8, 1.0]]])  # corners on facets 0, 3 and the ridge
    within = np.array([[[-0.5, 0.2, 0.5], [-0.2, 0.5, 0.8], [0.0, 0.8, 1.0]]])
    # The edge between the first two corners passes 0.5 under the ridge, its midpoint (0, 0.2, 0.5) is 0.5 / √2 off.
    assert _chord_distances(across, np.array([[0, 3, 1]]), cage) == pytest.approx([0.5 / np.sqrt(2)])
    assert _chord_distances(within, np.array([[0, 0, 1]]), cage) == pytest.approx([0.0], abs=1e-12)


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_cold_bind_for_many_bent_faces_names_five_and_counts_the_others(monkeypatch):
    """A new user read a list of bent faces cut at five as if it were all of them."""
    import lbc_core.binding.carry as carry

    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    first = lbc_core.bind(cube, quads, cube * 0.5 + 0.25, cells=300)
    monkeypatch.setattr(carry, "_faces_off_cage", lambda *args: np.arange(7))
    assert rebind(first, cube * 1.01, quads).outcome.report.startswith(
        "bound from scratch: cage faces 0, 1, 2, 3, 4 and 2 more bent too far")


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_an_edit_that_changes_only_how_faces_split_into_triangles_rebinds_warm():
    """Widening a pyramid's rhombus base in its plane brings its diagonals within QUAD_SPLIT_TIE of each other, so it
    splits from its first vertex instead of along the shorter diagonal; the base stays flat, and the carried mesh
    lies on the previous split, which still fits the same faces."""
    pyramid = np.array([[1.0, 0.0, 0.0], [0.0, 0.7, 0.0], [-1.0, 0.0, 0.0], [0.0, -0.7, 0.0], [0.0, 0.0, 1.0]])
    faces = [[2, 1, 0, 3], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]  # the base first (from a long diagonal)
    points = np.array([[0.1, 0.05, 0.2], [-0.2, 0.1, 0.3], [0.0, -0.1, 0.5], [0.3, 0.0, 0.1]])
    first = lbc_core.bind(pyramid, faces, points, cells=2000)
    edited = pyramid.copy()
    edited[[1, 3], 1] *= 1.1  # diagonals 2 and 1.54: within QUAD_SPLIT_TIE
    assert lbc_core.make_cage(edited, faces).fingerprint() != first.cage.fingerprint()
    again = rebind(first, edited, faces)
    assert again.outcome.start == "previous solution", again.outcome.report
    assert again.cage.fingerprint() == first.cage.fingerprint()
    assert_guarantees(again, points)
    # Bent as well, the base's surface is its split: the previous one would bind another cage than a cold bind.
    edited[1, 2] = 0.05
    again = rebind(first, edited, faces)
    assert again.outcome.report == ("bound from scratch: cage face 0 bent and now split into other triangles (the "
                                    "edit changed which diagonal a bind splits it along), which the cells the last "
                                    "bind filled the cage with do not follow")
    assert again.cage.fingerprint() == lbc_core.make_cage(edited, faces).fingerprint()


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_cancel_stops_a_warm_rebind_and_leaves_the_previous_binding_as_it_was(gargoyle):
    cage, faces, points, first = gargoyle
    state = [part.copy() for part in (first.solver_state.pair_state, first.solver_state.slot_state)]
    domain_weights = first.domain_weights.copy()
    polls = []

    def cancel():
        polls.append(1)
        return len(polls) > 20

    with pytest.raises(lbc_core.Cancelled):
        rebind(first, moved(cage, [3], 0.01), faces, cancel=cancel)
    np.testing.assert_array_equal(first.solver_state.pair_state, state[0])
    np.testing.assert_array_equal(first.solver_state.slot_state, state[1])
    np.testing.assert_array_equal(first.domain_weights, domain_weights)


def test_a_2d_polygon_rebinds_warm():
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]])
    rng = np.random.default_rng(0)
    points = rng.uniform(0.05, 0.95, (300, 2))
    first = lbc_core.bind(polygon, None, points, cells=800)
    edited = moved(polygon, [2], 0.02)
    warm = rebind(first, edited)
    assert warm.outcome.start == "previous solution"
    assert_guarantees(warm, points)
    assert warm.iterations < first.iterations


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_saved_binding_made_with_a_weighting_function_is_refused_and_told_what_to_do(tmp_path):
    """A reviewer's finding: the saved binding keeps the function's name only, which rebind fed back to BindOptions
    ("weighting '<function ...>' is not one of ..."), an option the user never typed."""
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]])
    points = np.random.default_rng(0).uniform(0.05, 0.95, (50, 2))
    first = lbc_core.bind(polygon, None, points, cells=300, weighting=np.square)
    assert rebind(first, moved(polygon, [2], 0.02)).outcome.start == "previous solution"  # in memory: kept
    path = tmp_path / "custom.npz"
    first.save(path)
    with pytest.raises(lbc_core.CageError, match=r"weighting function of its own \(.*square.*\), which a saved "
                                                 r"binding does not keep: bind from scratch"):
        rebind(lbc_core.load_binding(path), moved(polygon, [2], 0.02))


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_baseline_binding_is_refused(gargoyle):
    cage, faces, points, _ = gargoyle
    mvc = lbc_core.bind_mvc(cage, faces, points[:50])
    with pytest.raises(lbc_core.CageError, match="needs an LBC binding"):
        rebind(mvc, cage, faces)


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_3d_binding_without_the_cages_faces_is_told_to_pass_them(gargoyle):
    """A new user's find: rebind(binding, vertices) of a 3D binding said a 2D polygon must lie in a plane."""
    cage, _, _, binding = gargoyle
    with pytest.raises(lbc_core.CageError, match="the previous binding is 3D: pass the edited cage's faces too"):
        rebind(binding, cage)


def test_a_simplex_cage_binds_again_from_scratch_and_says_why():
    tetrahedron = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
    bary = np.random.default_rng(0).dirichlet(np.ones(4), 50)
    first = lbc_core.bind(tetrahedron, faces, bary @ tetrahedron)
    edited = tetrahedron + [[0, 0, 0], [0.1, 0, 0], [0, 0, 0], [0, 0, 0]]
    again = rebind(first, edited, faces)
    assert again.outcome.report == "bound from scratch: a simplex cage has nothing to solve"
    # The points stay where they were bound: their coordinates in the edited tetrahedron.
    expected = np.linalg.solve(np.c_[edited, np.ones(4)].T, np.c_[bary @ tetrahedron, np.ones(50)].T).T
    np.testing.assert_allclose(again.weights.toarray(), expected, atol=1e-12)


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_a_cage_moved_far_in_all_since_its_last_cold_bind_binds_from_scratch(gargoyle):
    """A new user's finding: a side vertex of a subdivided cube moved out by 10 % and back, re-bound warm both ways,
    ended 2.6 times the remeshing noise from a fresh bind. The moves add up across warm re-binds."""
    from lbc_core.binding.rebinding import CARRY_LIMIT

    cage, faces, points, first = gargoyle
    diagonal = np.linalg.norm(np.ptp(cage, axis=0))
    out = cage.copy()
    out[5, 2] += 0.6 * CARRY_LIMIT * diagonal
    there = rebind(first, out, faces)
    assert there.outcome.start == "previous solution", there.outcome.report
    assert there.outcome.travel == pytest.approx(0.6 * CARRY_LIMIT)
    back = rebind(there, cage, faces)
    assert back.outcome.report == ("bound from scratch: its vertices moved 10% of the cage's diagonal in all since "
                                   "it was last bound from scratch, and a mesh carried that far drifts from a "
                                   "fresh one")
    assert back.outcome.travel == 0.0 and back.outcome.solved_again is None
    assert rebind(back, out, faces).outcome.start == "previous solution"  # counted again from the cold bind


@pytest.mark.slow  # binds end to end: left out of the fast tier
def test_an_n_gon_edited_out_of_its_poke_rebinds_from_scratch_and_says_so():
    """An octagon prism's caps are split from their middle; one vertex of each pushed far in makes them non-convex with
    the middle too near a side, so they are ear-clipped: other facets, which the carried mesh does not follow."""
    octagon = np.c_[np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)]
    prism = np.concatenate([np.c_[octagon, np.zeros(8)], np.c_[octagon, np.ones(8)]])
    faces = [list(range(8))[::-1], list(range(8, 16))] + [[i, (i + 1) % 8, 8 + (i + 1) % 8, 8 + i] for i in range(8)]
    points = np.array([[-0.2, 0.5, 0.5], [0.0, -0.5, 0.4]])
    first = lbc_core.bind(prism, faces, points, cells=500)
    edited = prism.copy()
    edited[[0, 8], 0] = -0.6
    assert len(first.cage.centres) == 2 and lbc_core.make_cage(edited, faces).centres == ()
    again = rebind(first, edited, faces)
    assert again.outcome.report == (
        "bound from scratch: cage faces 0, 1 changed shape so far that their split into triangles changed (from the "
        "middle to one of the vertices, or back), which the cells the last bind filled the cage with do not follow")
    assert_guarantees(again, points)
