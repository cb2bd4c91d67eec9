"""Figures: each kind is written as PNG and SVG, non-empty, of a sane size, and refuses 3D where it is 2D-only."""

from pathlib import Path

import numpy as np
import pytest

from lbc_core.compare.baselines import bind_harmonic, bind_mvc
from lbc_core.io import read_cage, read_mesh

pytestmark = pytest.mark.slow  # binds end to end: left out of the fast tier

pytest.importorskip("matplotlib", reason="the figures need matplotlib (pyproject.toml's plots extra)")
from lbc_core.compare.plots import _lattice, plot_coordinate, plot_deformation, plot_locality  # noqa: E402

DATA = Path(__file__).parent / "data"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def woody_bindings():
    vertices, _ = read_cage(DATA / "woody-control-edgeset.obj")
    points = np.load(DATA / "woody.npz")["vertices"]
    mvc = bind_mvc(vertices, None, points, cells=1500)
    return vertices, {"MVC": mvc, "harmonic": bind_harmonic(vertices, None, points, domain=mvc.domain)}


def check_image(path, min_bytes=5_000, max_bytes=400_000):
    data = Path(path).read_bytes()
    assert min_bytes < len(data) < max_bytes
    if str(path).endswith(".png"):
        assert data.startswith(PNG_MAGIC)
    else:
        assert data.lstrip().startswith(b"<?xml") and b"<svg" in data[:2000]


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_locality_figure(tmp_path, woody_bindings, suffix):
    path = tmp_path / f"pq{suffix}"
    plot_locality(woody_bindings[1], path)
    check_image(path, max_bytes=400_000)


def test_coordinate_figure(tmp_path, woody_bindings):
    path = tmp_path / "coordinate.png"
    plot_coordinate(woody_bindings[1]["MVC"], 3, path)
    check_image(path)


def test_deformation_figure(tmp_path, woody_bindings):
    vertices, bindings = woody_bindings
    moved = vertices.copy()
    moved[:5] += [60.0, 30.0]
    path = tmp_path / "deformation.png"
    plot_deformation(bindings["harmonic"], moved, path)
    check_image(path)


def test_lattice_splits_a_triangle_into_equal_parts():
    points, cells = _lattice(4)
    assert len(points) == 15 and len(cells) == 16
    corners = points[cells][:, :, 1:]  # two barycentric coordinates as planar coordinates
    edges = corners[:, 1:] - corners[:, :1]
    areas = np.abs(np.linalg.det(edges)) / 2
    np.testing.assert_allclose(areas, 0.5 / 16)


def test_2d_figures_refuse_3d_bindings(tmp_path):
    vertices, faces = read_cage(DATA / "cages-3d" / "gargoyle" / "cage_L16.obj")
    points = read_mesh(DATA / "cages-3d" / "gargoyle" / "mesh.off")[0][::50]
    binding = bind_mvc(vertices, faces, points, cells=500)
    with pytest.raises(ValueError, match="2D"):
        plot_coordinate(binding, 0, tmp_path / "x.png")
    plot_locality({"MVC": binding}, tmp_path / "pq.png")
    check_image(tmp_path / "pq.png")
