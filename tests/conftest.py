"""Session-wide pytest settings."""

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings as hypothesis_settings

import lbc_core
from lbc_core.io import read_cage, read_mesh
from helpers.random_cages import GRID, STAR, inside_polygon

DATA = Path(__file__).parent / "data"

# Property tests draw the same examples on every run and machine, with no example database: a run's verdict must not
# depend on which examples a fresh clone happens to draw.
hypothesis_settings.register_profile("lbc", derandomize=True, database=None)
hypothesis_settings.load_profile("lbc")


class _ExitPastBlenderTeardown:
    """Ends the pytest process with its exit status once pytest is done, skipping C-level teardown.

    The bpy module can fail at process exit once an add-on's classes are registered: 4.5.4 can deadlock (a static
    destructor in its sound code destroys a condition variable that its "delayed close" thread still waits on; gdb:
    ``GlobalState::~GlobalState`` in ``pthread_cond_destroy`` against ``delayed_close_thread_run``), 4.2.0 crashes
    with SIGSEGV. Both happen after everything has run and passed, and would leave the test run (and CI) hanging or
    failing; 5.0 to 5.2 exit cleanly (test_addon_install.py checks a background script's exit on every line).
    """

    status = 0

    def pytest_sessionfinish(self, session, exitstatus):
        self.status = int(exitstatus)

    @pytest.hookimpl(trylast=True)
    def pytest_unconfigure(self, config):
        if "bpy" in sys.modules:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(self.status)


# Binds are the slow part of the add-on tests (seconds each), so a bound gargoyle scene is made once per session,
# saved, and opened again by each test that needs it. bpy is imported only when such a test runs.
@pytest.fixture(scope="session")
def bound_gargoyle_file(tmp_path_factory):
    """A .blend with the gargoyle bound to its L10 cage (67 vertices) through the operator; returns its path."""
    import bpy
    from helpers.blender_scenes import CELLS, bind, gargoyle_scene

    mesh, cage = gargoyle_scene("L10")
    assert bind(mesh, cage, cells=CELLS) == {"FINISHED"}
    path = tmp_path_factory.mktemp("blend") / "bound_gargoyle.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


@pytest.fixture
def bound_gargoyle(bound_gargoyle_file):
    """The bound gargoyle scene, freshly opened; returns (mesh, cage)."""
    import bpy
    from helpers.blender_scenes import register_addon

    register_addon()
    bpy.ops.wm.open_mainfile(filepath=str(bound_gargoyle_file))
    return bpy.data.objects["Gargoyle"], bpy.data.objects["Cage"]


# Bindings that test_pipeline (the bind) and test_binding (the record and its files) both use: bound once per session.
def polygon_points(vertices, count, seed=0):
    """The uniform random points of the polygon's bounding box that fall inside it."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(vertices.min(axis=0), vertices.max(axis=0), (count, 2))
    return points[inside_polygon(vertices, points, 0.0)[0]]


@pytest.fixture(scope="session")
def woody():
    vertices, _ = read_cage(DATA / "woody-control-edgeset.obj")
    vertices = vertices[:, :2]
    points = polygon_points(vertices, 4000)
    return vertices, points, lbc_core.bind(vertices, None, points)


@pytest.fixture(scope="session")
def gargoyle():
    vertices, faces = read_cage(DATA / "cages-3d" / "gargoyle" / "cage_L12.obj")
    points, _ = read_mesh(DATA / "cages-3d" / "gargoyle" / "mesh.off")
    return vertices, faces, points, lbc_core.bind(vertices, faces, points, cells=3000)


@pytest.fixture(scope="session")
def star_binding():
    return lbc_core.bind(STAR, None, GRID, cells=300)


@pytest.fixture(scope="session")
def clothing():
    """The clothing cage, its deformed pose and a binding of the garment's vertices (some outside the cage)."""
    folder = DATA / "cages-3d" / "clothing"
    cage, faces = read_mesh(folder / "cage.obj")
    posed, _ = read_mesh(folder / "cage_deformed.obj")
    mesh, _ = read_mesh(folder / "mesh.obj")
    return cage, faces, posed, lbc_core.bind(cage, faces, mesh, cells=2000)


def pytest_configure(config):
    config.pluginmanager.register(_ExitPastBlenderTeardown(), "lbc-exit-past-blender-teardown")
