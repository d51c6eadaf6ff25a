"""VTK datasets that are not surfaces (a tetrahedral .vtu, a legacy unstructured .vtk, a
structured .vts) load as their boundary surface and render as the solid they bound."""

import numpy as np
import pytest
import pyvista as pv

import xray_viz
from xray_viz._toml import dumps
from xray_viz.cli import main
from xray_viz.errors import MeshError
from xray_viz.meshes import load_mesh

#: The box: x in [-15, 15], y in [-10, 10], z in [-4, 4] (8 mm thick along the beam).
DIMS, SPACING, ORIGIN = (4, 5, 3), (10.0, 5.0, 4.0), (-15.0, -10.0, -4.0)


def _tetrahedral_box():
    grid = pv.ImageData(dimensions=DIMS, spacing=SPACING, origin=ORIGIN).triangulate()
    assert isinstance(grid, pv.UnstructuredGrid)
    assert set(np.unique(grid.celltypes)) == {pv.CellType.TETRA}
    return grid


def _write(folder, suffix):
    path = folder / f"box{suffix}"
    if suffix == ".vts":
        pv.ImageData(dimensions=DIMS, spacing=SPACING,
                     origin=ORIGIN).cast_to_structured_grid().save(path)
    else:
        _tetrahedral_box().save(path)             # .vtu XML, or legacy UNSTRUCTURED_GRID
    return path


@pytest.mark.parametrize("suffix", [".vtu", ".vtk", ".vts"])
def test_a_volume_mesh_loads_as_its_boundary_surface(tmp_path, suffix):
    path = _write(tmp_path, suffix)
    if suffix == ".vtk":
        assert b"UNSTRUCTURED_GRID" in path.read_bytes()[:300]
    mesh = load_mesh(path)
    # the boundary of a 3 x 4 x 2 cell grid: 2 (3*4 + 3*2 + 4*2) quads, two triangles each;
    # the faces between tetrahedra are gone
    assert len(mesh.faces) == 2 * 2 * (3 * 4 + 3 * 2 + 4 * 2)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert abs(mesh.volume) == pytest.approx(30 * 20 * 8)
    np.testing.assert_array_equal(mesh.bounds, [[-15, -10, -4], [15, 10, 4]])


def test_a_tetrahedral_vtu_renders_the_box_thickness(tmp_path):
    _write(tmp_path, ".vtu")
    doc = {"source": {"position": [0.0, 0.0, 1000.0], "kind": "parallel", "energy": 60.0},
           "detector": {"center": [0.0, 0.0, -500.0], "up": [0.0, 1.0, 0.0],
                        "shape": [40, 30], "pitch": 1.0},
           "body": [{"name": "box", "mesh": "box.vtu", "mu": 0.05}]}
    (tmp_path / "scene.toml").write_text(dumps(doc))
    scene = xray_viz.load_scene(tmp_path / "scene.toml")
    path = xray_viz.render(scene, engine="numpy").total_path_length
    x = np.arange(40) - 19.5                      # pixel centres: never on the box's edges
    y = 14.5 - np.arange(30)
    inside = (np.abs(x)[None, :] < 15) & (np.abs(y)[:, None] < 10)
    np.testing.assert_allclose(path, np.where(inside, 8.0, 0.0), rtol=0, atol=1e-9)
    fast = xray_viz.render(scene, engine="fast").total_path_length
    np.testing.assert_allclose(fast, path, rtol=0, atol=1e-9)
    assert "mesh = " in scene.to_toml() and "box.vtu" in scene.to_toml()


def test_a_corrupt_vtu_is_one_line_naming_the_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "junk.vtu").write_bytes(
        np.random.default_rng(3).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    with pytest.raises(MeshError) as info:
        load_mesh("junk.vtu")
    text = str(info.value)
    assert text.startswith("junk.vtu: cannot read mesh (corrupt or not a .vtu file): ")
    assert "\n" not in text and len(text) < 300
    assert main(["mesh", "junk.vtu", "-o", "x.stl"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"xray-viz: error: {text}"] and not (tmp_path / "x.stl").exists()
