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
from xray_viz.meshes.command import add_mesh_parser
from helpers import REPO, ball_union_chord

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
    # pymeshlab drops (a, a, b) faces with the duplicate vertices (there are none); then the
    # copies
    assert report.changes == ("removed 5 zero-area faces with a repeated corner (-5 faces)",
                              "removed duplicate faces (-3 faces)")


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


def _trimesh_load(path, *, process=True):
    """What load_mesh gave before it read binary STL itself: trimesh's loader and merge."""
    loaded = trimesh.load(path, force="mesh", process=False)
    return trimesh.Trimesh(vertices=np.asarray(loaded.vertices, dtype=np.float64),
                           faces=np.asarray(loaded.faces, dtype=np.int64), process=process,
                           validate=False)


def _same_arrays(a, b):
    return (a.vertices.dtype == b.vertices.dtype and a.faces.dtype == b.faces.dtype
            and np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces))


@pytest.mark.parametrize("process", [True, False])
def test_binary_stl_is_read_as_trimesh_reads_and_merges_it(process):
    """load_mesh reads binary STL itself and merges its vertices itself: the same arrays, bit
    for bit, as trimesh's loader and ``process=True`` (every bundled phantom's file)."""

    files = sorted((REPO / "phantoms").glob("*/*.stl"))
    assert len(files) > 10
    for path in files:
        mine = load_mesh(path, process=process)
        assert _same_arrays(mine, _trimesh_load(path, process=process)), path.name
        assert mine.metadata.get("processed", False) == process


def test_binary_stl_merge_matches_trimesh_on_soups(tmp_path):
    """Duplicates, near-duplicates closer than trimesh.tol.merge, -0.0 beside 0.0, tiny and
    large coordinates: the merged arrays are trimesh's."""
    rng = np.random.default_rng(7)
    for k in range(40):
        n = 3 * int(rng.integers(1, 400))
        base = rng.normal(size=(max(1, n // 4), 3)) * 10.0 ** rng.uniform(-9, 4)
        corners = base[rng.integers(0, len(base), n)]
        if k % 3 == 0:
            corners = corners + rng.normal(size=corners.shape) * 3e-9
        if k % 4 == 0:
            corners[::2, 1] = -0.0
            corners[1::2, 1] = 0.0
        soup = trimesh.Trimesh(corners, np.arange(n).reshape(-1, 3), process=False)
        path = tmp_path / f"soup{k}.stl"
        soup.export(path)
        assert _same_arrays(load_mesh(path), _trimesh_load(path)), k


def test_ascii_and_empty_stl_still_go_through_trimesh(tmp_path, ball):
    ascii_path = tmp_path / "ascii.stl"
    ascii_path.write_text(trimesh.exchange.stl.export_stl_ascii(ball))
    assert _same_arrays(load_mesh(ascii_path), _trimesh_load(ascii_path))
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"\0" * 84)
    with pytest.raises(MeshError, match="empty"):
        load_mesh(empty)


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


def write_scene(tmp_path, body_lines: str, mesh, *, kind="point", shape=(8, 8),
                pitch=1.0) -> object:
    """Write ``mesh`` as part.stl and a scene file with it as the one body ``part``."""
    mesh.export(tmp_path / "part.stl")
    (tmp_path / "scene.toml").write_text(textwrap.dedent(f"""\
        [source]
        position = [0.0, 0.0, 1000.0]
        kind = "{kind}"
        [detector]
        center = [0.0, 0.0, -500.0]
        shape = [{shape[0]}, {shape[1]}]
        pitch = {pitch}
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


def test_bodies_reuse_their_reports_until_a_mesh_changes():
    """The mesh reports are kept by the Bodies that own the meshes (no module-level cache);
    a mesh changed in place is checked again, and refused if it is no longer traceable."""
    from xray_viz.bodies import Bodies
    from xray_viz.errors import MeshError
    from xray_viz.meshes.repair import check_mesh
    from xray_viz.scene import Body

    mesh = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    bodies = Bodies([Body(name="ball", mesh=mesh, mu=0.2)])
    first = bodies.reports[0]
    assert first.outward and first.watertight
    assert bodies.reports[0] is first                 # same data: the kept report
    assert check_mesh(mesh) == first                  # and it is check_mesh's answer
    mesh.vertices *= 2.0                              # in place: scaled
    scaled = bodies.reports[0]
    assert scaled is not first and scaled.volume == pytest.approx(8 * first.volume)
    mesh.invert()                                     # in place: faces flipped
    flipped = check_mesh(mesh)
    assert not flipped.outward and flipped.volume < 0
    with pytest.raises(MeshError, match="changed in place"):
        bodies.reports


# --------------------------------------------------------------------------------------------
# pieces of one body: the nonzero rule (material where the winding number is positive)


def ball_at(center, radius, *, inside_out=False, subdivisions=4):
    b = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    faces = b.faces[:, ::-1] if inside_out else b.faces
    return trimesh.Trimesh(b.vertices + np.asarray(center, float), faces, process=False)


def two_pieces(a, b):
    return trimesh.util.concatenate([a, b])


def render_part(tmp_path, mesh, *, engine="numpy"):
    """Load ``mesh`` as the one body of a parallel-beam scene (0.5 mm pixels over 96 x 64 mm)
    and render it, with the numpy engine by default. Returns (scene, image, rays)."""
    import xray_viz
    from xray_viz.geometry import detector_rays

    path = write_scene(tmp_path, "", mesh, kind="parallel", shape=(192, 128), pitch=0.5)
    scene = scene_module.load_scene(path)
    image = xray_viz.render(scene, engine=engine)
    return scene, image, detector_rays(scene)


def assert_engines_agree(scene, image):
    """The fast engine gives the numpy engine's path lengths (``image``) to 1e-9 relative."""
    import xray_viz

    fast = xray_viz.render(scene, engine="fast").total_path_length
    ref = image.total_path_length
    assert np.abs(fast - ref).max() <= 1e-9 * max(1.0, ref.max())


def chords(rays, balls):
    """Analytic path length of each ray through balls ``(cx, cy, cz, r, sign)`` by the nonzero
    rule: the union of the outward balls (sign +1) less the union of the cavities (sign -1)."""
    solid = [(c, r) for *c, r, s in balls if s == 1]
    cavities = [(c, r) for *c, r, s in balls if s == -1]
    # cavities lie inside the solid: take out the union of their spans
    total = (ball_union_chord(rays.origins, rays.directions, solid)
             - ball_union_chord(rays.origins, rays.directions, cavities))
    return total.reshape(rays_shape(rays))


def rays_shape(rays):
    return (128, 192)


def assert_chords(image, rays, balls, *, inner=0.9):
    """Path lengths match the analytic chords within 1 % away from every silhouette (an
    icosphere is a little smaller than its sphere); none is negative; I <= I0."""
    L = image.total_path_length
    expected = chords(rays, balls)
    near_rim = np.zeros(L.shape, bool)
    for *c, r, _ in balls:
        rel = np.asarray(c, float) - rays.origins
        along = np.einsum("ij,ij->i", rel, rays.directions)
        d = np.sqrt(np.einsum("ij,ij->i", rel, rel) - along ** 2).reshape(L.shape)
        near_rim |= (d > inner * r) & (d < r / inner)
    assert L.min() >= -1e-9
    assert np.all(image.intensity <= 1.0 + 1e-12)
    np.testing.assert_allclose(L[~near_rim], expected[~near_rim], rtol=0.01, atol=0.05)
    return L


def test_check_flags_an_inside_out_piece_beside_a_good_one():
    mesh = two_pieces(ball_at([-20, 0, 0], 12), ball_at([20, 0, 0], 8, inside_out=True))
    report = check_mesh(mesh)
    assert report.watertight and report.winding_consistent and report.volume > 0
    assert not report.outward and report.misoriented == 1 and not report.traceable
    assert report.problems()[0].startswith("inside-out in 1 of 2 pieces")


def test_check_accepts_outward_pieces_however_they_nest_or_overlap():
    nested = two_pieces(ball_at([0, 0, 0], 20), ball_at([3, 0, 0], 8))
    poking = two_pieces(ball_at([0, 0, 0], 20), ball_at([0, 17, 0], 6))
    for mesh in (nested, poking):
        report = check_mesh(mesh)
        assert report.traceable and report.misoriented == report.crossing == 0
        assert report.components == 2 and not report.simple  # the fast engine sweeps it
    apart = check_mesh(two_pieces(ball_at([-20, 0, 0], 8), ball_at([20, 0, 0], 8)))
    assert apart.traceable and apart.simple                   # disjoint: signed sums are exact


def test_check_accepts_a_hollow_shell_and_an_island_in_its_cavity():
    hollow = two_pieces(ball_at([0, 0, 0], 20), ball_at([0, 0, 0], 14, inside_out=True))
    assert check_mesh(hollow).traceable
    island = two_pieces(hollow, ball_at([2, 0, 0], 6))  # outward inside the cavity: material
    assert check_mesh(island).traceable and check_mesh(island).misoriented == 0


def test_inside_out_piece_is_repaired_with_a_warning_and_renders_right(tmp_path):
    mesh = two_pieces(ball_at([-20, 0, 0], 12), ball_at([20, 0, 0], 8, inside_out=True))
    with pytest.warns(MeshRepairWarning) as record:
        scene, image, rays = render_part(tmp_path, mesh)
    (warning,) = record
    text = str(warning.message)
    assert "body 'part'" in text and "inside-out in 1 of 2 pieces" in text
    assert "turned 1 of 2 inside-out pieces outward" in text
    assert check_mesh(scene.bodies[0].mesh).traceable
    L = assert_chords(image, rays, [(-20, 0, 0, 12, 1), (20, 0, 0, 8, 1)])
    assert L.max() == pytest.approx(24.0, abs=0.05)
    assert_engines_agree(scene, image)


def test_nested_outward_ball_is_redundant_not_a_cavity(tmp_path):
    # nonzero rule: a ball inside a ball adds nothing (no cavity, no double counting)
    mesh = two_pieces(ball_at([0, 0, 0], 30), ball_at([0, 0, 0], 10))
    scene, image, rays = render_part(tmp_path, mesh)  # filterwarnings=error: no repair
    assert scene.bodies[0].mesh is not None and len(scene.bodies[0].mesh.faces) == len(mesh.faces)
    L = assert_chords(image, rays, [(0, 0, 0, 30, 1)])
    assert L[64, 96] == pytest.approx(60.0, abs=0.05)
    assert_engines_agree(scene, image)


def test_three_nested_outward_balls_give_the_outer_chord(tmp_path):
    mesh = trimesh.util.concatenate([ball_at([0, 0, 0], 30), ball_at([2, 0, 0], 20),
                                     ball_at([4, 1, 0], 8)])
    scene, image, rays = render_part(tmp_path, mesh)
    L = assert_chords(image, rays, [(0, 0, 0, 30, 1)])
    assert L.max() == pytest.approx(60.0, abs=0.05)
    assert_engines_agree(scene, image)


def test_nested_outward_ball_sharing_a_vertex_is_two_pieces_and_redundant(tmp_path):
    outer = ball_at([0, 0, 0], 30)
    d = outer.vertices[0] / 30
    inner = ball_at(d * 15, 15)                     # its vertex 0 lands on the outer's vertex 0
    mesh = two_pieces(outer, inner)
    mesh.merge_vertices()
    assert mesh.body_count == 1                     # vertex-connected: one body for trimesh
    report = check_mesh(mesh)
    assert report.components == 2 and report.traceable and not report.simple
    scene, image, rays = render_part(tmp_path, mesh)
    assert_chords(image, rays, [(0, 0, 0, 30, 1)])
    assert image.total_path_length.max() == pytest.approx(60.0, abs=0.05)
    assert_engines_agree(scene, image)


def test_small_ball_poking_out_of_a_big_one_renders_as_their_union(tmp_path):
    # its bounding box is inside the big ball's, and most of it is inside: still not a cavity
    balls = [(0, 0, 0, 30, 1), (18, 18, 0, 8, 1)]     # reaches r = 33.5 > 30
    mesh = two_pieces(ball_at(balls[0][:3], 30), ball_at(balls[1][:3], 8))
    scene, image, rays = render_part(tmp_path, mesh)  # no warning
    assert len(scene.bodies[0].mesh.faces) == len(mesh.faces)
    L = assert_chords(image, rays, balls)
    assert L.min() >= 0
    assert_engines_agree(scene, image)


def test_overlapping_outward_balls_give_their_union(tmp_path):
    balls = [(-10, 0, 0, 20, 1), (10, 0, 0, 20, 1)]
    mesh = two_pieces(ball_at(balls[0][:3], 20), ball_at(balls[1][:3], 20))
    scene, image, rays = render_part(tmp_path, mesh)
    L = assert_chords(image, rays, balls)
    assert L.max() == pytest.approx(40.0, abs=0.05)  # a diameter: the overlap not doubled
    assert_engines_agree(scene, image)


def test_hollow_shell_is_accepted_unchanged(tmp_path):
    mesh = two_pieces(ball_at([0, 0, 0], 30), ball_at([0, 0, 0], 10, inside_out=True))
    scene, image, rays = render_part(tmp_path, mesh)  # filterwarnings=error: no repair
    assert len(scene.bodies[0].mesh.faces) == len(mesh.faces)
    assert scene.bodies[0].mesh.volume == pytest.approx(mesh.volume, rel=1e-6)
    assert_chords(image, rays, [(0, 0, 0, 30, 1), (0, 0, 0, 10, -1)])
    assert_engines_agree(scene, image)
    fixed, report = repair_mesh(mesh)
    assert report.changes == ()


def test_inside_out_hollow_shell_is_turned_over_as_a_whole(tmp_path):
    mesh = two_pieces(ball_at([0, 0, 0], 30, inside_out=True), ball_at([0, 0, 0], 10))
    report = check_mesh(mesh)
    assert report.volume < 0 and report.misoriented == 2 and not report.traceable
    with pytest.warns(MeshRepairWarning, match="body 'part'.*turned the inside-out mesh outward"):
        scene, image, rays = render_part(tmp_path, mesh)
    L = assert_chords(image, rays, [(0, 0, 0, 30, 1), (0, 0, 0, 10, -1)])  # still hollow
    assert L[64, 96] == pytest.approx(40.0, abs=0.05)
    assert_engines_agree(scene, image)


def test_inside_out_piece_crossing_an_outward_one_is_refused_in_one_line(tmp_path):
    mesh = two_pieces(ball_at([0, 0, 0], 20), ball_at([18, 0, 0], 10, inside_out=True))
    report = check_mesh(mesh)
    assert report.crossing == 1 and not report.traceable
    with pytest.raises(MeshError) as info:
        render_part(tmp_path, mesh)
    text = str(info.value)
    assert "\n" not in text and "'part'" in text and "1 of 2 pieces facing inward" in text
    assert "mesh editor" in text
    with pytest.raises(MeshError, match="crossing"):
        ensure_traceable(mesh, name="part", repair=False)


def test_nesting_check_of_many_cavities():
    # (its speed is a benchmark figure, not a timed assertion: BENCHMARKS.md)
    box = trimesh.creation.box(extents=[200, 200, 200])
    small = trimesh.creation.icosphere(subdivisions=0, radius=0.5)
    centres = np.random.default_rng(0).uniform(-90, 90, (2000, 3))
    vertices = np.vstack([box.vertices] + [small.vertices + c for c in centres])
    faces = np.vstack([box.faces] + [small.faces[:, ::-1] + 8 + 12 * k
                                     for k in range(len(centres))])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    report = check_mesh(mesh)
    assert report.traceable and report.components == 2001
    # one of them pushed through the wall: only that one is reported
    moved = vertices.copy()
    moved[8:20] += [99.8 - centres[0, 0], 0, 0]
    report = check_mesh(trimesh.Trimesh(moved, faces, process=False))
    assert report.crossing == 1 and report.misoriented == 0


def test_repair_keeps_the_orientation_of_most_of_a_pieces_faces():
    # a cavity with a few faces flipped: re-oriented to agree with the rest, still a cavity
    inner = ball_at([0, 0, 0], 10, inside_out=True, subdivisions=3)
    inner.faces[:3] = inner.faces[:3, ::-1]
    mesh = two_pieces(ball_at([0, 0, 0], 30, subdivisions=3), inner)
    fixed, report = repair_mesh(mesh)
    assert report.after.traceable
    outer, cavity = (ball_at([0, 0, 0], r, subdivisions=3).volume for r in (30, 10))
    assert fixed.volume == pytest.approx(outer - cavity, rel=1e-9)


def test_check_calls_a_zero_volume_mesh_flat_not_inside_out():
    # two triangles back to back: closed, consistently wound, encloses nothing
    pillow = trimesh.Trimesh([[0, 0, 0], [10, 0, 0], [0, 10, 0]], [[0, 1, 2], [0, 2, 1]],
                             process=False)
    report = check_mesh(pillow)
    assert report.watertight and report.flat and not report.outward
    assert report.problems() == ["flat (zero volume)"]
    assert not any("inside-out" in p for p in report.problems())


# --------------------------------------------------------------------------------------------
# repair: near-duplicate soup, small closed pieces, honest labels


def test_repair_soup_with_jittered_vertices(ball):
    soup = ball.vertices[ball.faces].reshape(-1, 3)
    soup = soup + np.random.default_rng(4).uniform(-1e-4, 1e-4, soup.shape)  # 0.1 um jitter
    mesh = trimesh.Trimesh(soup, np.arange(len(soup)).reshape(-1, 3), process=False)
    assert not check_mesh(mesh).watertight
    fixed, report = repair_mesh(mesh)
    assert_repaired(fixed, report, ball)
    assert len(fixed.vertices) == len(ball.vertices)
    threshold = 1e-4 * np.linalg.norm(np.ptp(soup, axis=0))  # merge_distance = 0.01 %
    assert any(f"closer than {threshold:.3g} mm" in c and f"-{len(soup) - len(ball.vertices)} "
               "vertices" in c for c in report.changes), report.changes


def test_repair_keeps_small_closed_pieces(ball):
    # a ball and twenty closed 12-face boxes: all under min_component_faces, none is debris
    boxes = [trimesh.creation.box(extents=[1, 1, 1]) for _ in range(20)]
    for k, b in enumerate(boxes):
        b.apply_translation([60 + 3 * k, 0, 0])
    good = trimesh.util.concatenate([ball, *boxes])
    fixed, report = repair_mesh(good)
    assert len(fixed.faces) == len(good.faces) and report.changes == ()
    assert fixed.body_count == 21
    # with a hole in the ball and a stray open triangle, only the triangle goes
    stray = trimesh.Trimesh([[0, 0, 70], [1, 0, 70], [0, 1, 70]], [[0, 1, 2]], process=False)
    broken = trimesh.util.concatenate([trimesh.Trimesh(ball.vertices, ball.faces[1:]), *boxes,
                                       stray])
    fixed, report = repair_mesh(broken)
    assert fixed.body_count == 21 and check_mesh(fixed).traceable
    assert fixed.volume == pytest.approx(ball.volume + 20.0, rel=0.01)
    assert "removed 1 small open pieces, stray faces or debris (-1 faces)" in report.changes


def test_repair_labels_say_what_changed(ball):
    # an exact duplicate of a corner that two faces use, and three copied faces
    soup = trimesh.Trimesh(ball.vertices[ball.faces].reshape(-1, 3),
                           np.arange(3 * len(ball.faces)).reshape(-1, 3), process=False)
    _, report = repair_mesh(soup)
    (merge,) = [c for c in report.changes if "duplicate vertices" in c]
    assert merge == (f"merged coincident duplicate vertices "
                     f"(-{3 * len(ball.faces) - len(ball.vertices)} vertices)")
    assert not any("faces" in c and "duplicate vertices" in c for c in report.changes)
    # corners that coincide only after merging: the faces go with the merge, and it says so
    degenerate = ball.vertices[np.column_stack([ball.faces[:5, 0], ball.faces[:5, 0],
                                                ball.faces[:5, 1]])]
    tri = np.vstack([ball.vertices[ball.faces], degenerate]).reshape(-1, 3)
    _, report = repair_mesh(trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3),
                                            process=False))
    (merge,) = report.changes
    assert merge.startswith("merged coincident duplicate vertices; removed 5 faces left with a "
                            "repeated corner (-")
    assert merge.endswith(" vertices, -5 faces)")


def test_mesh_command_input_column_is_the_file_as_stored(tmp_path, ball):
    src = tmp_path / "ball.stl"  # STL: every triangle's corners stored separately
    ball.export(src)
    rc, text = run_mesh(src, "-o", tmp_path / "out.stl")
    assert rc == 0
    rows = {line.split()[0]: line.split()[1:] for line in text.splitlines()[2:10]}
    assert rows["vertices"] == [str(3 * len(ball.faces)), str(len(ball.vertices))]
    assert "changes: none" not in text
    assert (f"merged coincident duplicate vertices "
            f"(-{3 * len(ball.faces) - len(ball.vertices)} vertices)") in text
    clean = tmp_path / "ball.ply"  # PLY keeps shared vertices: nothing to do
    ball.export(clean)
    rc, text = run_mesh(clean, "-o", tmp_path / "out.ply")
    assert rc == 0 and "changes: none" in text


def test_mesh_command_checks_the_output_before_repairing(tmp_path, ball, monkeypatch):
    import xray_viz.meshes.repair as repair_module

    ball.export(tmp_path / "in.stl")
    calls = []
    monkeypatch.setattr(repair_module, "repair_mesh", lambda *a, **k: calls.append(a))
    with pytest.raises(SceneFileNotFoundError, match="folder .*nodir does not exist"):
        run_mesh(tmp_path / "in.stl", "-o", tmp_path / "nodir" / "x.stl")
    (tmp_path / "adir.stl").mkdir()
    with pytest.raises(MeshError, match="is a folder"):
        run_mesh(tmp_path / "in.stl", "-o", tmp_path / "adir.stl")
    assert calls == []


def test_mesh_command_output_errors_print_nothing_but_the_error(tmp_path, ball):
    ball.export(tmp_path / "in.stl")
    proc = subprocess.run([sys.executable, "-m", "xray_viz.cli", "mesh", str(tmp_path / "in.stl"),
                           "-o", str(tmp_path / "nodir" / "x.stl")],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "nodir" in proc.stderr


@pytest.mark.parametrize("name, text", [("bad.vtp", "not a vtk file"), ("bad.vtk", "garbage"),
                                        ("cut.vtp", "<?xml version=\"1.0\"?>\n<VTKFile type=")])
def test_corrupt_vtk_file_is_one_line_on_stderr(tmp_path, name, text):
    bad = tmp_path / name
    bad.write_text(text)
    code = (f"from xray_viz.meshes import load_mesh\ntry:\n    load_mesh({str(bad)!r})\n"
            "except ValueError as exc:\n    print(exc)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr == ""
    assert proc.stdout.startswith(f"{bad}: cannot read mesh (corrupt")
    proc = subprocess.run([sys.executable, "-m", "xray_viz.cli", "mesh", str(bad), "-o",
                           str(tmp_path / "x.stl")], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "cannot read mesh" in proc.stderr, proc.stderr


def test_repair_leaves_the_frog_skeleton_alone():
    """64 closed bones, 12 of them under 25 faces: nothing to repair, nothing removed."""
    from xray_viz import phantoms

    skeleton = load_mesh(phantoms._root() / "frog" / "skeleton.stl")
    assert check_mesh(skeleton).traceable
    fixed, report = repair_mesh(skeleton)
    assert report.changes == ()
    assert fixed.body_count == skeleton.body_count == 64
    assert len(fixed.faces) == len(skeleton.faces)


def test_mesh_command_units(tmp_path):
    # a ball of radius 4 cm stored in cm: the report and --max-error are in mm, OUT in cm
    ball_cm = trimesh.creation.icosphere(subdivisions=4, radius=4.0)
    ball_cm.export(tmp_path / "in.ply")
    rc, text = run_mesh(tmp_path / "in.ply", "-o", tmp_path / "out.ply", "--units", "cm",
                        "--max-error", 0.5)
    assert rc == 0 and "coordinates in cm; the report in mm" in text
    rows = {line.split()[0]: line.split()[1:] for line in text.splitlines()[2:10]}
    assert float(rows["volume"][-3]) == pytest.approx(ball_cm.volume * 1000, rel=1e-5)
    (line,) = [t for t in text.splitlines() if "Hausdorff distance" in t]
    assert float(line.split()[-2]) <= 0.5  # mm, not cm
    out = load_mesh(tmp_path / "out.ply")
    assert out.bounds.max() == pytest.approx(4.0, abs=0.06)  # still cm
    assert len(out.faces) < len(ball_cm.faces)
    with pytest.raises(SystemExit):
        run_mesh(tmp_path / "in.ply", "-o", tmp_path / "o.ply", "--units", "furlong")


def test_mesh_command_notes_an_unreached_face_count_and_a_lost_volume(tmp_path):
    torus = trimesh.creation.torus(major_radius=30, minor_radius=10)
    torus.export(tmp_path / "torus.ply")
    rc, text = run_mesh(tmp_path / "torus.ply", "-o", tmp_path / "t.ply", "--decimate", 4)
    assert rc == 0
    notes = [line for line in text.splitlines() if line.startswith("note: ")]
    assert len(notes) == 2
    assert notes[0].startswith("note: asked for 4 faces, got ")
    assert "enclosed volume changed by -" in notes[1] and "%" in notes[1]
    rc, text = run_mesh(tmp_path / "torus.ply", "-o", tmp_path / "t.ply", "--decimate", 1000)
    assert rc == 0 and "note:" not in text  # reached, volume within 3 %
