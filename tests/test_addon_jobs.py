"""The part of a bind that runs without Blender: request, solve on a worker thread, result (no bpy imported here)."""

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lbc_addon import jobs
from lbc_addon.options import AddonOptions
from lbc_core import BindOptions, CageError, Cancelled
from lbc_core.cage.planar import flatten
from lbc_core.evaluate.thinning import floor_for

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[1]
BOX = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-1.1, 1.3) for z in (-1.0, 1.4)])
BOX_FACES = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
OPTIONS = {"cells": 1000}


def request(cage_points=BOX, cage_faces=BOX_FACES, points=None, flat=None, **options):
    """A bind request as geometry.snapshot makes it, from arrays."""
    if points is None:
        points = np.random.default_rng(0).uniform(-0.8, 0.8, (200, 3))
    return jobs.BindRequest(mesh_uid=1, cage_uid=2, mesh_name="Mesh", points=points, cage_points=cage_points,
                            cage_faces=cage_faces, flat=flat, options=AddonOptions(**{**OPTIONS, **options}),
                            cage_topology="", mesh_topology="")


@pytest.fixture
def new_session(monkeypatch):
    """No binding kept from earlier tests: a bind starts as in a new Blender session."""
    monkeypatch.setattr(jobs, "_previous", jobs.OrderedDict())
    monkeypatch.setattr(jobs, "_replaced", {})


def test_jobs_imports_and_solves_without_bpy():
    script = (
        "import sys; sys.modules['bpy'] = None  # any import of bpy now fails\n"
        "import numpy as np\n"
        "from lbc_addon import jobs\n"
        "box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)\n"
        "faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]\n"
        "from lbc_addon.options import AddonOptions\n"
        "options = AddonOptions(cells=300)\n"
        "request = jobs.BindRequest(1, 2, 'Mesh', np.full((3, 3), 0.5), box, faces, None, options, '', '')\n"
        "print(jobs.solve(request).weight.shape[0])\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "3"


def test_the_add_on_options_become_lbc_core_options_in_one_place():
    assert AddonOptions(**OPTIONS).core_options(3) == BindOptions(cells=1000, method="auto")
    tuned = AddonOptions(tolerance=1e-3, thinning=2e-3, epsilon=0.5, mesher="delaunay").core_options(3)
    assert tuned == BindOptions(tolerance=np.float32(1e-3), epsilon=0.5, method="delaunay")  # thinning: the add-on's
    assert AddonOptions(mesher="delaunay").core_options(2).method == "auto"  # the Mesher names 3D meshers


def test_the_add_on_options_are_checked_when_made():
    for bad, message in (({"mode": "3d"}, "mode must be one of 'AUTO', '2D', '3D', not '3d'"),
                         ({"mesher": "triangle"}, "mesher must be one of 'auto', 'delaunay', not 'triangle'"),
                         ({"influences": None}, "influences must be a whole number"),
                         ({"thinning": -0.05}, "thinning must be a number of at least 0"),
                         ({"cells": 5}, "cells must be at least 10")):
        with pytest.raises(CageError, match=message):
            AddonOptions(**bad)


def test_a_redo_that_sets_an_option_to_what_the_bind_used_asks_the_same_solve():
    """Adjust Last Operation binds again with the panel's values: Cells 0 and 8000 (the default), the Mesher "auto"
    and "delaunay" (what it runs), the Dimension Automatic and 3D ask the same solve of a 3D cage, which a warm start
    reuses; another weighting does not."""
    first = AddonOptions()
    assert first.solve_changes(AddonOptions(cells=8000, mesher="delaunay", mode="3D", thinning=0.01), 3) == []
    assert first.solve_changes(AddonOptions(cells=9000, weighting="linear"), 3) == ["cells", "weighting"]


def test_solve_thins_the_weights_by_thinning_and_the_max_influences():
    results = {name: jobs.solve(request(**options)) for name, options in
               (("every", {"thinning": 1e-12}), ("thinned", {"thinning": 0.05}),
                ("capped", {"thinning": 1e-12, "influences": 4}))}
    counts = {name: np.count_nonzero(result.weight, axis=1).mean() for name, result in results.items()}
    assert counts["thinned"] < counts["every"] and counts["capped"] < counts["every"]
    for result in results.values():
        np.testing.assert_allclose(result.weight.sum(axis=1), 1.0, atol=1e-5)
        np.testing.assert_allclose(result.rest, request().points, atol=1e-5)


def test_solve_gives_slots_that_sum_to_one_and_reproduce_the_points():
    job = request()
    result = jobs.solve(job)
    assert result.index.shape == result.weight.shape == (200, result.index.shape[1])
    np.testing.assert_allclose(result.weight.sum(axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(result.rest, job.points, atol=1e-5)
    assert result.control_points == 8 and result.outside == 0


def test_a_flat_request_binds_in_2d_on_the_outline_columns():
    vertices = np.array([[c, r, 0.0] for r in range(3) for c in range(3)])
    quads = [[r * 3 + c, r * 3 + c + 1, (r + 1) * 3 + c + 1, (r + 1) * 3 + c] for r in range(2) for c in range(2)]
    points = np.array([[0.5, 0.5, 0.0], [1.5, 1.2, 0.0]])
    job = request(vertices, quads, points, flat=flatten(vertices, quads, points))
    assert job.dimension == 2
    result = jobs.solve(job)
    assert result.control_points == 8 and 4 not in result.index[result.weight > 0]  # the centre controls nothing
    np.testing.assert_allclose(result.rest, points, atol=1e-5)


def test_cancel_during_the_solve_stops_it():
    calls = []

    def cancel():
        calls.append(1)
        return len(calls) > 3  # let the solve start, then stop it

    with pytest.raises(Cancelled):
        jobs.solve(request(), cancel=cancel)
    assert len(calls) == 4


def test_worker_solves_in_its_thread_reports_progress_and_stops_when_cancelled():
    worker = jobs.Worker([request(), request()])
    worker.start()
    worker.join()
    assert worker.done and worker.error is None and len(worker.results) == 2
    assert worker.fraction == pytest.approx(1.0) and worker.message.startswith("Mesh: ")
    cancelled = jobs.Worker([request()])
    cancelled.cancel()  # before the thread runs: the solve stops at its first check
    cancelled.start()
    cancelled.join()
    assert cancelled.cancelled and isinstance(cancelled.error, Cancelled) and cancelled.results == []


def test_a_solve_stopped_at_the_iteration_limit_is_a_warning(monkeypatch):
    from dataclasses import replace

    core_options = AddonOptions.core_options
    monkeypatch.setattr(AddonOptions, "core_options",
                        lambda options, dimension: replace(core_options(options, dimension), max_iterations=6))
    result = jobs.solve(request())
    assert any("stopped at its limit of 6 iterations" in warning for warning in result.warnings), result.warnings
    np.testing.assert_allclose(result.weight.sum(axis=1), 1.0, atol=1e-5)
    monkeypatch.undo()
    assert not any("iterations" in warning for warning in jobs.solve(request()).warnings)


def test_a_warm_re_bind_thins_only_the_rows_it_changed_and_gives_the_same_slots(new_session, monkeypatch):
    from lbc_core.io import read_cage, read_mesh

    gargoyle = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
    cage, faces = read_cage(gargoyle / "cage_L10.obj")
    points, _ = read_mesh(gargoyle / "mesh.off")
    first = request(cage, faces, points, cells=3000)
    bound = jobs.solve(first)
    jobs.remember(first, bound)
    # The control point that moves the fewest points, not on the bounding box (the extent stays): at 3000 cells the
    # smooth fit reaches 3 cells, so moving one near the middle changes nearly every row.
    reach = np.asarray((bound.binding.weights > 0).sum(axis=0)).ravel()[:len(cage)].astype(float)
    reach[np.any((cage == cage.min(axis=0)) | (cage == cage.max(axis=0)), axis=1)] = np.inf
    edited = cage.copy()
    edited[np.argmin(reach)] += 0.01 * np.linalg.norm(np.ptp(cage, axis=0))
    counts = []
    thin_changed_rows = jobs.thin_changed_rows

    def spy(*arguments, **keywords):
        thinned, count = thin_changed_rows(*arguments, **keywords)
        counts.append(count)
        return thinned, count

    monkeypatch.setattr(jobs, "thin_changed_rows", spy)
    second = request(edited, faces, points, cells=3000)
    warm = jobs.solve(second)
    assert warm.rebind.startswith("bound again from the previous binding")
    assert 0 < counts[0] < len(points)
    binding = warm.binding
    rest = binding.rest_cage_vertices
    every_row = jobs.thin_weights(binding.weights, rest, binding.weights @ rest, *second.options.floor_and_cap)
    index, weight = jobs.storage.slot_arrays(every_row, binding.cage.first_inputs)
    np.testing.assert_array_equal(warm.index, index)
    np.testing.assert_allclose(warm.weight, weight, atol=1e-7)


def test_binding_again_at_the_rest_of_the_replaced_binding_reuses_it_unchanged(new_session):
    """A new user's find: undo after a Rebind brings the earlier binding back into the scene, and a Rebind then solved
    again from the edited cage's binding (881 cells), ending beside the binding the undo restored. The binding the
    latest bind replaced is kept, and a cage back at its rest finds it: nothing is solved again."""
    first = request(cells=600)
    rest = jobs.solve(first)
    jobs.remember(first, rest)
    edited = BOX.copy()
    edited[0] *= 1.05
    second = request(cage_points=edited, cells=600)
    jobs.remember(second, jobs.solve(second))
    jobs.remember(second, jobs.solve(second))  # undo, Rebind: nothing solved, nothing replaced
    again = jobs.solve(request(cells=600))  # the cage back at rest, as after an undo
    assert again.rebind == "bound again from the previous binding: it was made for the cage as it is now, so " \
                           "nothing was solved or evaluated again", again.rebind
    np.testing.assert_array_equal(again.index, rest.index)
    np.testing.assert_array_equal(again.weight, rest.weight)
    jobs.forget(first.mesh_uid)  # Unbind drops both
    assert jobs.warm_start(request(cells=600)) is None


def two_meshes(seed, cage_points=BOX):
    """Requests of two meshes in one cage: 'Mesh' (uid 1) and 'Other' (uid 7), their points drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    first = request(cage_points=cage_points, points=rng.uniform(-0.8, 0.8, (150, 3)))
    second = request(cage_points=cage_points, points=rng.uniform(-0.7, 0.7, (120, 3)))
    second.mesh_uid, second.mesh_name = 7, "Other"
    return first, second


def solved_by_a_worker(requests):
    """The (request, result) pairs of a :class:`jobs.Worker` run to its end without error."""
    worker = jobs.Worker(requests)
    worker.start()
    worker.join()
    assert worker.error is None
    return worker.results


def test_a_second_mesh_in_the_same_cage_reuses_the_first_ones_solve(new_session):
    first, second = two_meshes(3)
    results = solved_by_a_worker([first, second])
    shared = results[1][1]
    assert shared.rebind.startswith("started from the binding of 'Mesh' to the same cage: 0 of "), shared.rebind
    alone = jobs.solve(second)  # nothing kept in this session: a cold bind
    assert alone.rebind == ""
    np.testing.assert_array_equal(shared.index, alone.index)
    np.testing.assert_allclose(shared.weight, alone.weight, atol=1e-6)
    jobs.remember(first, results[0][1])  # written: kept, and found by a later bind as well
    assert jobs.solve(second).rebind.startswith("started from the binding of 'Mesh'")
    other_cage = request(cage_points=BOX * 1.1, points=second.points)
    other_cage.mesh_uid, other_cage.cage_uid = 7, 9
    assert jobs.solve(other_cage).rebind == ""  # another cage: never started from the first's


def test_printed_progress_says_each_new_message_and_a_repeated_one_at_most_once_a_second(capsys):
    progress = jobs.printed_progress()
    for step in range(40):  # a stage counting fast: one line, not forty
        progress(0.08 + step / 1000, "geodesic distances: solving")
    progress(0.2, "ADMM iteration 10")
    progress(0.2, "ADMM iteration 10")
    for done in range(8, 169, 8):  # counts in the message: nothing new either (a new user got 21 lines in 0.08 s)
        progress(0.21, f"geodesic distances: solving, {done} of 168 cage vertices done")
    progress(0.3, "ADMM iteration 20, residual 3.5× the tolerance")
    progress(0.3, "ADMM iteration 30, residual 42.0× the tolerance after updating where control points act")
    assert capsys.readouterr().out.splitlines() == [
        "LBC bind:   8% geodesic distances: solving", "LBC bind:  20% ADMM iteration 10",
        "LBC bind:  21% geodesic distances: solving, 8 of 168 cage vertices done",
        "LBC bind:  30% ADMM iteration 20, residual 3.5× the tolerance",
        "LBC bind:  30% ADMM iteration 30, residual 42.0× the tolerance after updating where control points act"]


def test_after_a_cage_edit_the_second_mesh_starts_from_the_first_ones_new_binding(new_session):
    for job in two_meshes(4):
        jobs.remember(job, jobs.solve(job))
    edited = BOX.copy()
    edited[4:, 0] += 0.1  # the +x face moved out: faces stay flat, so a warm re-bind can carry the mesh
    results = solved_by_a_worker(two_meshes(4, edited))
    assert results[0][1].rebind.startswith("bound again from the previous binding")  # its own, warm
    assert results[1][1].rebind.startswith("started from the binding of 'Mesh' to the same cage: 0 of ")


def test_an_error_about_a_cage_with_a_modifier_off_in_viewports_says_so():
    """A Mirror turned off in viewports leaves half a cage: lbc_core says to fill its holes, the add-on says why."""
    from dataclasses import replace

    open_box = replace(request(cage_faces=BOX_FACES[1:]), cage_modifiers_off="modifier 'Mirror'")
    with pytest.raises(jobs.CageError, match=r"^the cage's modifier 'Mirror' is off in viewports, and the cage is "
                                             r"bound as viewports show it \(turn it on, or apply it\); so .*not "
                                             r"closed"):  # the likely cause first (a new user's finding)
        jobs.solve(open_box)


def test_the_note_on_vertex_numbers_follows_only_a_message_that_has_them():
    """A reviewer's finding: "the cage is flat (all its vertices lie in one plane)" got a note on vertex numbers."""
    from dataclasses import replace

    flat = replace(request(cage_points=BOX * [1, 1, 0], mode="3D"), cage_modifiers="modifier 'Solidify'")
    with pytest.raises(jobs.CageError, match=r"the cage is flat .*\(this is the cage as its modifier 'Solidify' "
                                             r"makes it\)$"):
        jobs.solve(flat)


def test_a_2d_re_bind_after_moving_one_cage_vertex_solves_only_near_it(new_session, woody):
    """A code review's finding: the flat cage's plane frame (its mean and principal axes) shifted with the edit, so
    every control point moved in 2D and the re-bind started from scratch. It keeps the first bind's frame now."""
    outline, inside, _ = woody
    cage = np.c_[outline, np.full(len(outline), 0.3)]  # the woody cage as a flat n-gon in Blender
    points = np.c_[inside[:400], np.full(400, 0.3)]
    faces = [list(range(len(outline)))]
    first = request(cage, faces, points, flat=flatten(cage, faces, points))
    jobs.remember(first, jobs.solve(first))
    edited = cage.copy()
    edited[5, :2] += 0.02 * np.ptp(outline, axis=0)  # one vertex moved, in the plane
    again = jobs.solve(request(edited, faces, points, flat=flatten(edited, faces, points)))
    counts = again.binding.outcome.solved_again
    assert 0 < counts.cells_solved < counts.cells / 4
    np.testing.assert_allclose(again.rest, points, atol=1e-5 * np.ptp(outline))  # the mesh at rest, in 3D


def test_from_scratch_after_a_cage_edit_binds_as_a_new_session_would_and_the_second_mesh_shares_its_solve(
        new_session, monkeypatch):
    """From Scratch: a pipeline asks for the result a fresh session gives, whatever this one bound before; the other
    meshes of the same call still start from its own new binding, which is a bind from scratch too."""
    for job in two_meshes(4):
        jobs.remember(job, jobs.solve(job))
    edited = BOX.copy()
    edited[4:, 0] += 0.1
    asked = [replace(job, from_scratch=True) for job in two_meshes(4, edited)]
    results = solved_by_a_worker(asked)
    assert results[0][1].rebind == "bound from scratch, as asked (From Scratch)"
    assert results[1][1].rebind.startswith("started from the binding of 'Mesh' to the same cage, bound from scratch "
                                           "just before (From Scratch): 0 of ")
    for job, result in results:  # written: kept, and a start again for a bind without From Scratch
        jobs.remember(job, result)
    assert jobs.warm_start(two_meshes(4, edited * 1.01)[0]).binding is results[0][1].binding
    monkeypatch.setattr(jobs, "_previous", jobs.OrderedDict())  # a new session: nothing kept
    for (job, result), (_, fresh) in zip(results, solved_by_a_worker(two_meshes(4, edited))):
        np.testing.assert_array_equal(result.index, fresh.index)
        np.testing.assert_allclose(result.weight, fresh.weight, atol=1e-6)


def test_the_thinning_has_its_own_part_of_the_progress_bar_and_bound_comes_last():
    """A new user saw the bar at 100 % "bound" while the demo's 64k vertices were still being thinned (0.4 s)."""
    told = []
    jobs.solve(request(), progress=lambda fraction, message: told.append((fraction, message)))
    assert told[-1] == (1.0, "bound")
    thinning = [fraction for fraction, message in told if message == "thinning the weights"]
    assert thinning and all(1 - jobs.THINNING_SHARE - 1e-12 <= fraction < 1.0 for fraction in thinning)
    before = told[:[message for _, message in told].index("thinning the weights")]
    assert all(fraction <= 1 - jobs.THINNING_SHARE + 1e-12 for fraction, _ in before)
    fractions = [fraction for fraction, _ in told]
    assert all(later >= earlier - 1e-12 for earlier, later in zip(fractions, fractions[1:]))


def test_smoothness_sets_the_fit_and_the_thinning():
    """Smoothness is lbc_core's option (the fit's radius) and, with Thinning 0, the add-on's floor: higher keeps more
    influences per vertex."""
    assert AddonOptions(smoothness=0.8).core_options(3).smoothness == np.float32(0.8)
    assert AddonOptions(smoothness=1.0).floor_and_cap == (floor_for(1.0), 0)
    assert AddonOptions(smoothness=1.0, thinning=0.01).floor_and_cap == (np.float32(0.01), 0)
    assert "smoothness" in AddonOptions(smoothness=0.2).solve_changes(AddonOptions(smoothness=0.8), 3)
    counts = [np.count_nonzero(jobs.solve(request(smoothness=smoothness)).weight, axis=1).mean()
              for smoothness in (0.0, 1.0)]
    assert counts[1] > counts[0]
