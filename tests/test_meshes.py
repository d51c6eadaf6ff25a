"""Mesh import, checking, repair and decimation: invariants and analytic volumes."""

from __future__ import annotations

import argparse
import io
import subprocess
import sys
import textwrap
import types

import numpy as np
import pytest
import trimesh

from xray_viz import scene as scene_module
from xray_viz.errors import MeshError, SceneError, SceneFileNotFoundError
from xray_viz.meshes import (
    MeshRepairWarning,
    check_mesh,
    decimate,
    ensure_traceable,
    hausdorff_distance,
    load_mesh,
    repair_mesh,
)
from xray_viz.meshes.command import add_mesh_parser, mesh_command

R = 40.0


@pytest.fixture(autouse=True)
def _attenuation_module(monkeypatch):
    """The scene loader calls xray_viz.attenuation.check_source_outside; stub it until the
    physics branch is merged, so that these tests check the geometry either way."""
    try:
        import xray_viz.attenuation  # noqa: F401
    except ImportError:
        stub = types.ModuleType("xray_viz.attenuation")
        stub.check_source_outside = lambda scene: None
        monkeypatch.setitem(sys.modules, "xray_viz.attenuation", stub)


@pytest.fixture(scope="module")
def ball():
    return trimesh.creation.icosphere(subdivisions=3, radius=R)


def assert_repaired(mesh, report, intact):
    assert report.after.watertight and report.after.outward and report.after.traceable
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.volume == pytest.approx(intact.volume, rel=0.01)


# --------------------------------------------------------------------------------------------
# check_mesh


def test_check_box_volume_and_flags():
    report = check_mesh(trimesh.creation.box(extents=[10.0, 20.0, 30.0]))
    assert report.watertight and report.outward and report.winding_consistent
    assert report.volume == pytest.approx(6000.0, rel=1e-12)
    assert (report.faces, report.vertices, report.boundary_edges, report.components) == (12, 8, 0, 1)


def test_check_counts_boundary_edges_of_a_hole(ball):
    holed = trimesh.Trimesh(ball.vertices, ball.faces[1:], process=False)
    report = check_mesh(holed)
    assert not report.watertight and not report.traceable
    assert report.boundary_edges == 3


def test_check_inside_out_has_negative_volume(ball):
    report = check_mesh(trimesh.Trimesh(ball.vertices, ball.faces[:, ::-1], process=False))
    assert report.watertight and not report.outward
    assert report.volume == pytest.approx(-ball.volume)


# --------------------------------------------------------------------------------------------
# repair, one kind of damage at a time


def test_repair_closes_holes(ball):
    rng = np.random.default_rng(0)
    keep = np.ones(len(ball.faces), bool)
    keep[rng.choice(len(ball.faces), 6, replace=False)] = False
    holed = trimesh.Trimesh(ball.vertices, ball.faces[keep], process=False)
    assert not check_mesh(holed).watertight
    mesh, report = repair_mesh(holed)
    assert_repaired(mesh, report, ball)
    assert any("hole" in c for c in report.changes)


def test_repair_flipped_faces(ball):
    faces = ball.faces.copy()
    flip = np.random.default_rng(1).choice(len(faces), len(faces) // 10, replace=False)
    faces[flip] = faces[flip][:, ::-1]
    broken = trimesh.Trimesh(ball.vertices, faces, process=False)
    assert not check_mesh(broken).winding_consistent
    mesh, report = repair_mesh(broken)
    assert_repaired(mesh, report, ball)
    assert len(mesh.faces) == len(ball.faces)


def test_repair_duplicate_vertices_triangle_soup(ball):
    soup = trimesh.Trimesh(ball.vertices[ball.faces].reshape(-1, 3),
                           np.arange(3 * len(ball.faces)).reshape(-1, 3), process=False)
    assert not check_mesh(soup).watertight
    mesh, report = repair_mesh(soup)
    assert_repaired(mesh, report, ball)
    assert len(mesh.vertices) == len(ball.vertices)
    assert any("duplicate vertices" in c for c in report.changes)


def test_repair_zero_area_and_duplicate_faces(ball):
    f = ball.faces
    degenerate = np.column_stack([f[:5, 0], f[:5, 0], f[:5, 1]])
    broken = trimesh.Trimesh(ball.vertices, np.vstack([f, degenerate, f[10:13]]), process=False)
    assert not check_mesh(broken).watertight
    mesh, report = repair_mesh(broken)
    assert_repaired(mesh, report, ball)
    assert len(mesh.faces) == len(ball.faces)
    # pymeshlab drops (a, a, b) faces with the duplicate vertices; then the copies
    assert any("-5 faces" in c for c in report.changes)
    assert any("duplicate faces (-3 faces)" in c for c in report.changes)


def test_repair_non_manifold_fin(ball):
    a, b = ball.faces[0, 0], ball.faces[0, 1]
    tip = (ball.vertices[a] + ball.vertices[b]) * 0.75  # outside the ball
    vertices = np.vstack([ball.vertices, tip])
    fin = [[a, b, len(ball.vertices)]]
    broken = trimesh.Trimesh(vertices, np.vstack([ball.faces, fin]), process=False)
    assert not check_mesh(broken).watertight
    mesh, report = repair_mesh(broken)
    assert_repaired(mesh, report, ball)
    assert len(mesh.faces) == len(ball.faces)


def test_repair_inside_out(ball):
    inside_out = trimesh.Trimesh(ball.vertices, ball.faces[:, ::-1], process=False)
    mesh, report = repair_mesh(inside_out)
    assert_repaired(mesh, report, ball)
    assert report.before.volume < 0 < report.after.volume
    assert any("inside-out" in c for c in report.changes)


def test_repair_keeps_a_cavity_inward():
    outer = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    shell = trimesh.util.concatenate([outer, trimesh.Trimesh(inner.vertices, inner.faces[:, ::-1])])
    mesh, report = repair_mesh(shell)
    assert mesh.volume == pytest.approx(outer.volume - inner.volume, rel=1e-9)
    assert report.changes == ()


def test_repair_report_table_lists_changes(ball):
    _, report = repair_mesh(trimesh.Trimesh(ball.vertices, ball.faces[:, ::-1], process=False))
    table = report.table()
    assert "before" in table and "after" in table and "inside-out" in table


# --------------------------------------------------------------------------------------------
# ensure_traceable: what the scene loader calls


def test_ensure_traceable_leaves_good_mesh_alone(ball):
    mesh, changes = ensure_traceable(ball, name="ball")
    assert mesh is ball and changes == []


def test_ensure_traceable_repairs_and_says_what(ball):
    holed = trimesh.Trimesh(ball.vertices, ball.faces[2:], process=False)
    mesh, changes = ensure_traceable(holed, name="ball")
    assert check_mesh(mesh).traceable
    assert changes[0].startswith("was not watertight")


def test_ensure_traceable_refuses_when_told(ball):
    holed = trimesh.Trimesh(ball.vertices, ball.faces[2:], process=False)
    with pytest.raises(MeshError, match="'ball'.*not watertight"):
        ensure_traceable(holed, name="ball", repair=False)


def test_ensure_traceable_refuses_what_cannot_be_closed():
    sheet = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(MeshError, match="repair failed"):
        ensure_traceable(sheet, name="sheet")


# --------------------------------------------------------------------------------------------
# decimation


@pytest.fixture(scope="module")
def fine_ball():
    return trimesh.creation.icosphere(subdivisions=4, radius=R)


def test_decimate_to_face_count(fine_ball):
    mesh, err = decimate(fine_ball, target_faces=1000)
    assert len(mesh.faces) == 1000
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.volume == pytest.approx(fine_ball.volume, rel=0.02)
    assert 0 < err < 2.0
    # every decimated vertex stays within err of the original surface, which lies between the
    # sphere of radius R and the inscribed sphere of the original's inradius
    r_in = np.min(np.abs(np.einsum("ij,ij->i", fine_ball.face_normals,
                                   fine_ball.triangles_center)))
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert np.all(radius <= R + err + 1e-9) and np.all(radius >= r_in - err - 1e-9)


def test_decimate_to_error_budget(fine_ball):
    budget = 0.25
    mesh, err = decimate(fine_ball, max_error=budget)
    assert err <= budget
    assert mesh.is_watertight and mesh.volume > 0
    assert len(mesh.faces) < len(fine_ball.faces) / 2
    assert hausdorff_distance(fine_ball, mesh) <= budget * 1.05  # independent re-measure


def test_decimate_needs_exactly_one_goal(fine_ball):
    with pytest.raises(MeshError):
        decimate(fine_ball)
    with pytest.raises(MeshError):
        decimate(fine_ball, target_faces=100, max_error=1.0)
    with pytest.raises(MeshError):
        decimate(fine_ball, max_error=-1.0)


def test_decimate_above_face_count_is_identity(ball):
    mesh, err = decimate(ball, target_faces=10 * len(ball.faces))
    assert mesh is ball and err == 0.0


# --------------------------------------------------------------------------------------------
# import


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj", ".off", ".glb", ".vtp", ".vtk"])
def test_load_mesh_round_trip(tmp_path, ball, suffix):
    path = tmp_path / f"ball{suffix}"
    if suffix in (".vtp", ".vtk"):
        import pyvista as pv

        pv.PolyData.from_regular_faces(ball.vertices, ball.faces).save(path)
    else:
        ball.export(path)
    mesh = load_mesh(path)
    assert mesh.is_watertight and mesh.volume == pytest.approx(ball.volume, rel=1e-6)
    assert len(mesh.faces) == len(ball.faces)


def test_load_mesh_ascii_stl(tmp_path, ball):
    path = tmp_path / "ball.stl"
    path.write_text(trimesh.exchange.stl.export_stl_ascii(ball))
    assert load_mesh(path).volume == pytest.approx(ball.volume, rel=1e-6)


def test_load_vtk_quads_are_triangulated(tmp_path):
    import pyvista as pv

    path = tmp_path / "cube.vtp"
    pv.Cube(x_length=2, y_length=3, z_length=4).save(path)
    mesh = load_mesh(path)
    assert len(mesh.faces) == 12 and mesh.volume == pytest.approx(24.0)


def test_load_mesh_errors(tmp_path):
    with pytest.raises(SceneFileNotFoundError):
        load_mesh(tmp_path / "missing.vtp")
    bad = tmp_path / "bad.vtp"
    bad.write_text("not a vtk file")
    with pytest.raises(MeshError, match="bad.vtp"):
        load_mesh(bad)


def test_importing_meshes_does_not_import_vtk():
    code = ("import sys, xray_viz.meshes, xray_viz.scene; "
            "print(any(m.split('.')[0] in ('vtk', 'pyvista', 'vtkmodules', 'pymeshlab') "
            "for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# --------------------------------------------------------------------------------------------
# scene loading: transforms, repair at load time


def write_scene(tmp_path, body_lines: str, mesh) -> object:
    mesh.export(tmp_path / "part.stl")
    (tmp_path / "scene.toml").write_text(textwrap.dedent("""\
        [source]
        position = [0.0, 0.0, 1000.0]
        [detector]
        center = [0.0, 0.0, -500.0]
        shape = [8, 8]
        pitch = 1.0
        [[body]]
        name = "part"
        mesh = "part.stl"
        mu = 0.2
        """) + textwrap.dedent(body_lines))
    return tmp_path / "scene.toml"


def load_body(path):
    return scene_module.load_scene(path).bodies[0]


def test_transform_position_scale_units(tmp_path):
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    body = load_body(write_scene(tmp_path, 'position = [5, 6, 7]\nscale = 2\nunits = "cm"\n', box))
    assert body.mesh.volume == pytest.approx(6.0 * 20.0 ** 3)
    np.testing.assert_allclose(body.mesh.bounds, [[-5, -14, -23], [15, 26, 37]], atol=1e-9)


def test_transform_rotation_angles_and_matrix_agree(tmp_path):
    box = trimesh.creation.box(extents=[10.0, 20.0, 30.0])
    b1 = load_body(write_scene(tmp_path, "rotation = [0, 0, 90]\n", box))
    # 90 degrees about z takes x to y: the 10 mm side now runs along y
    np.testing.assert_allclose(np.ptp(b1.mesh.vertices, axis=0), [20, 10, 30], atol=1e-9)
    b2 = load_body(write_scene(tmp_path, "rotation = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]\n", box))
    np.testing.assert_allclose(b1.mesh.vertices, b2.mesh.vertices, atol=1e-9)
    assert b1.mesh.volume == pytest.approx(6000.0)  # a rotation keeps the mesh outward


def test_transform_per_axis_scale(tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    body = load_body(write_scene(tmp_path, "scale = [10, 20, 30]\n", ball))
    assert body.mesh.volume == pytest.approx(ball.volume * 6000.0, rel=1e-6)  # float32 STL


def test_broken_mesh_is_repaired_at_load_with_a_warning(tmp_path, ball):
    holed = trimesh.Trimesh(ball.vertices, ball.faces[3:][:, ::-1], process=False)
    path = write_scene(tmp_path, "", holed)
    with pytest.warns(MeshRepairWarning, match="body 'part'.*repaired.*not watertight"):
        body = load_body(path)
    assert check_mesh(body.mesh).traceable
    assert body.mesh.volume == pytest.approx(ball.volume, rel=0.01)


def test_broken_mesh_is_refused_when_repair_is_off(tmp_path, ball):
    holed = trimesh.Trimesh(ball.vertices, ball.faces[3:], process=False)
    with pytest.raises(MeshError, match="scene.toml.*'part'.*not watertight"):
        load_body(write_scene(tmp_path, "repair = false\n", holed))


def test_unrepairable_mesh_is_refused_at_load(tmp_path):
    sheet = trimesh.Trimesh([[0, 0, 0], [10, 0, 0], [0, 10, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(MeshError, match="repair failed"):
        load_body(write_scene(tmp_path, "", sheet))


def test_repair_key_must_be_boolean(tmp_path, ball):
    with pytest.raises(SceneError, match="repair must be true or false"):
        load_body(write_scene(tmp_path, 'repair = "yes"\n', ball))


def test_good_mesh_loads_without_warning(tmp_path, ball):
    body = load_body(write_scene(tmp_path, "", ball))  # filterwarnings=error catches any
    assert len(body.mesh.faces) == len(ball.faces)


# --------------------------------------------------------------------------------------------
# xray-viz mesh


def run_mesh(*argv):
    parser = argparse.ArgumentParser(prog="xray-viz")
    add_mesh_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["mesh", *map(str, argv)])
    out = io.StringIO()
    return args.func(args, stdout=out), out.getvalue()


def test_mesh_command_repairs_and_decimates(tmp_path, fine_ball):
    src = tmp_path / "in.stl"
    trimesh.Trimesh(fine_ball.vertices, fine_ball.faces[4:][:, ::-1]).export(src)
    rc, text = run_mesh(src, "-o", tmp_path / "out.ply", "--decimate", 800)
    assert rc == 0
    out = load_mesh(tmp_path / "out.ply")
    assert len(out.faces) == 800 and check_mesh(out).traceable
    assert "input" in text and "repaired" in text and "decimated" in text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.stl", "out.ply"]  # no temp left


def test_mesh_command_max_error(tmp_path, fine_ball):
    src = tmp_path / "in.off"
    fine_ball.export(src)
    rc, text = run_mesh(src, "-o", tmp_path / "out.stl", "--max-error", 0.5)
    out = load_mesh(tmp_path / "out.stl")
    assert rc == 0 and check_mesh(out).traceable and len(out.faces) < len(fine_ball.faces)
    assert hausdorff_distance(fine_ball, out) <= 0.5 * 1.05


def test_mesh_command_errors(tmp_path, ball):
    ball.export(tmp_path / "in.stl")
    with pytest.raises(MeshError, match="use one of"):
        run_mesh(tmp_path / "in.stl", "-o", tmp_path / "out.xyz")
    with pytest.raises(SceneFileNotFoundError):
        run_mesh(tmp_path / "missing.stl", "-o", tmp_path / "out.stl")
    with pytest.raises(SystemExit):  # argparse: the two decimation modes exclude each other
        run_mesh(tmp_path / "in.stl", "-o", tmp_path / "o.stl", "--decimate", 10,
                 "--max-error", 1)


def test_check_mesh_reuses_its_report_until_the_mesh_changes():
    from xray_viz.meshes.repair import check_mesh

    mesh = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    first = check_mesh(mesh)
    assert first.outward and first.watertight
    assert check_mesh(mesh) is first                  # same data: the cached report
    mesh.invert()                                     # in place: faces flipped
    flipped = check_mesh(mesh)
    assert flipped is not first and not flipped.outward and flipped.volume < 0
    mesh.vertices *= 2.0                              # in place: scaled
    scaled = check_mesh(mesh)
    assert scaled.volume == pytest.approx(8 * flipped.volume)
