"""The bind job: a cancelled or failed solve changes nothing; apply refuses objects that changed meanwhile."""

import bpy
import numpy as np
import pytest

from lbc_addon import jobs
from lbc_addon.properties import is_bound
from lbc_core import CageError, Cancelled
from blender_scenes import mesh_state, sphere_in_box_scene

OPTIONS = {"resolution": 1000}


def _request(mesh, cage, **options):
    return jobs.snapshot(mesh, cage, bpy.context.evaluated_depsgraph_get(), **{**OPTIONS, **options})


def test_cancelled_worker_leaves_the_scene_unchanged():
    mesh, cage = sphere_in_box_scene()
    before = mesh_state(mesh), sorted(bpy.data.node_groups.keys())
    worker = jobs.Worker([_request(mesh, cage)])
    worker.cancel()  # before the thread runs: the solve stops at its first check
    worker.start()
    worker.join()
    assert worker.done and worker.cancelled
    assert isinstance(worker.error, Cancelled) and worker.results == []
    assert (mesh_state(mesh), sorted(bpy.data.node_groups.keys())) == before
    assert not is_bound(mesh)


def test_cancel_during_the_solve_stops_it():
    mesh, cage = sphere_in_box_scene()
    request = _request(mesh, cage)
    calls = []

    def cancel():
        calls.append(1)
        return len(calls) > 3  # let the solve start, then stop it

    with pytest.raises(Cancelled):
        jobs.solve(request, cancel=cancel)
    assert len(calls) == 4


def test_worker_solves_in_its_thread_and_reports_progress():
    mesh, cage = sphere_in_box_scene()
    worker = jobs.Worker([_request(mesh, cage)])
    worker.start()
    worker.join()
    assert worker.error is None and len(worker.results) == 1
    assert worker.fraction == pytest.approx(1.0)
    request, result = worker.results[0]
    assert result.index.shape == result.weight.shape == (len(mesh.data.vertices), result.index.shape[1])
    np.testing.assert_allclose(result.weight.sum(axis=1), 1.0, atol=1e-5)
    jobs.apply(request, result)
    assert is_bound(mesh)


def test_apply_refuses_a_mesh_edited_during_the_solve():
    mesh, cage = sphere_in_box_scene()
    request = _request(mesh, cage)
    result = jobs.solve(request)
    mesh.data.vertices.add(1)  # the user added a vertex while the worker ran
    before = mesh_state(mesh)
    with pytest.raises(CageError, match="edited during the bind"):
        jobs.apply(request, result)
    assert mesh_state(mesh) == before


def test_apply_refuses_a_cage_deleted_during_the_solve():
    mesh, cage = sphere_in_box_scene()
    request = _request(mesh, cage)
    result = jobs.solve(request)
    bpy.data.objects.remove(cage)
    with pytest.raises(CageError, match="deleted during the bind"):
        jobs.apply(request, result)
    assert not is_bound(mesh)


def test_snapshot_refuses_shared_mesh_data_and_non_mesh_cages():
    mesh, cage = sphere_in_box_scene()
    twin = bpy.data.objects.new("Twin", mesh.data)
    bpy.context.scene.collection.objects.link(twin)
    with pytest.raises(CageError, match="shared by 2 objects"):
        _request(mesh, cage)
    empty = bpy.data.objects.new("Empty", None)
    with pytest.raises(CageError, match="not a mesh"):
        _request(twin, empty)
