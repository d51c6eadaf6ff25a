"""Self-intersecting one-piece meshes and exact nesting (issue 12).

A closed, outward, edge-manifold single piece whose surface passes through itself must not be
traced by the signed depth sum (which counts the overlap twice): every engine gives the
nonzero-winding answer, checked against exact chords of a self-crossing square tube. Nesting
means *wholly* inside (no surface crossing, a point inside); any other overlap follows list
order, so a body 75 % or 99 % inside another is not nested and moving it by a few mm flips
nothing.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.cli import main
from xray_viz.meshes.repair import MeshWarning, body_inside, check_mesh, ensure_traceable
from xray_viz.scene import Body, Detector, Scene, Source

HALF = 2.0          # the tube's square cross-section is 4 x 4 mm


def square_tube(path, half=HALF):
    """A closed tube of square cross-section (side 2 half, z in [-half, half]) swept along a
    polyline in the z = 0 plane with mitred corners and flat end caps: ONE edge-connected,
    outward piece; a path that crosses itself gives a surface that passes through itself."""
    path = np.asarray(path, dtype=float)
    n = len(path)
    seg = np.diff(path, axis=0)
    seg /= np.linalg.norm(seg, axis=1)[:, None]
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)        # left of each segment
    rings = []
    for k in range(n):
        if k == 0:
            offset = normals[0]
        elif k == n - 1:
            offset = normals[-1]
        else:
            bis = normals[k - 1] + normals[k]
            offset = bis / (bis @ normals[k])                  # mitre
        p = path[k]
        left, right = p + half * offset, p - half * offset
        rings.append([[*left, -half], [*right, -half], [*right, half], [*left, half]])
    v = np.array(rings, dtype=float).reshape(-1, 3)
    faces = []
    for k in range(n - 1):
        a, b = 4 * k, 4 * (k + 1)
        for q in range(4):
            i, j = a + q, a + (q + 1) % 4
            faces += [[i, j, b + (q + 1) % 4], [i, b + (q + 1) % 4, b + q]]
    faces += [[0, 2, 1], [0, 3, 2]]
    e = 4 * (n - 1)
    faces += [[e, e + 1, e + 2], [e, e + 2, e + 3]]
    mesh = trimesh.Trimesh(v, np.array(faces), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


#: A path whose last leg crosses its first one at (8, 0): the tube overlaps itself there.
CROSSING = [(0, 0), (20, 0), (20, 10), (8, 10), (8, -8)]


def _scene(meshes, mus, *, kind="parallel", shape=(61, 41), pitch=0.5, center=(10.13, 1.07, -100)):
    bodies = tuple(Body(name=f"b{k}", mesh=m, mu=float(u)) for k, (m, u) in
                   enumerate(zip(meshes, mus)))
    c = np.asarray(center, float)
    return Scene(source=Source(position=c + [0, 0, 300], kind=kind),
                 detector=Detector(center=c, up=[0, 1, 0], shape=shape, pitch=pitch),
                 bodies=bodies)


def test_the_crossing_tube_is_one_closed_outward_piece_that_passes_through_itself():
    tube = square_tube(CROSSING)
    report = check_mesh(tube)
    assert report.watertight and report.winding_consistent and report.outward
    assert report.components == 1
    assert report.self_intersections > 0 and not report.simple
    plain = check_mesh(square_tube([(0, 0), (20, 0), (20, 10), (8, 10)]))
    assert plain.self_intersections == 0 and plain.simple


def test_loading_a_self_intersecting_body_warns_once():
    with pytest.warns(MeshWarning, match="passes through itself"):
        ensure_traceable(square_tube(CROSSING), name="tube")


@pytest.mark.parametrize("kind", ["parallel", "point"])
@pytest.mark.parametrize("engine", ["fast", "numpy"])
def test_self_intersecting_tube_is_traced_by_the_nonzero_rule(engine, kind):
    scene = _scene([square_tube(CROSSING)], [0.5], kind=kind)
    image = xray_viz.render(scene, engine=engine)
    L = image.total_path_length
    assert L.min() >= 0
    assert np.all(image.intensity <= 1.0)
    if kind == "parallel":
        # every vertical ray inside the footprint crosses 4 mm of material, the crossing too
        inside = L > 1e-9
        np.testing.assert_allclose(L[inside], 2 * HALF, atol=1e-9)
        rays = xray_viz.detector_rays(scene)
        ends = rays.origins.reshape(41, 61, 3)
        at = np.unravel_index(np.argmin(np.hypot(ends[..., 0] - 8, ends[..., 1] - 0.3)),
                              L.shape)
        assert L[at] == pytest.approx(2 * HALF, abs=1e-9)        # the overlap counts once
    reference = xray_viz.render(scene, engine="numpy" if engine == "fast" else "fast")
    np.testing.assert_allclose(L, reference.total_path_length, atol=1e-9)


def test_folded_cap_engines_agree_and_stay_physical():
    ball = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    v = ball.vertices.copy()
    cap = v[:, 2] > 6.0
    v[cap, 2] -= 14.0                    # the north cap pushed through the south side
    folded = trimesh.Trimesh(v, ball.faces, process=False)
    report = check_mesh(folded)
    assert report.components == 1 and report.self_intersections > 0 and not report.simple
    scene = _scene([folded], [1.0], kind="point", center=(0.13, 0.07, -100), shape=(48, 48))
    fast = xray_viz.render(scene)
    numpy = xray_viz.render(scene, engine="numpy")
    assert fast.total_path_length.min() >= 0 and np.all(fast.intensity <= 1.0)
    np.testing.assert_allclose(fast.total_path_length, numpy.total_path_length, atol=1e-9)


def test_mesh_command_reports_self_intersections(tmp_path, capsys):
    src = tmp_path / "tube.stl"
    square_tube(CROSSING).export(src)
    rc = main(["mesh", str(src), "-o", str(tmp_path / "out.stl")])
    assert rc == 0
    out = capsys.readouterr().out
    row = [line for line in out.splitlines() if line.startswith("self-intersecting faces")]
    # the input column is the STL as stored (a triangle soup, not checked: "-"), the output
    # column the merged, closed tube
    assert row and row[0].split()[2] == "-" and int(row[0].split()[-1]) > 0


# --------------------------------------------------------------------------------------------
# nesting is exact: wholly inside, or list order


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(bounds=[lo, hi])


BIG_LO, BIG_HI = np.array([-20.0, -20, -20]), np.array([20.0, 20, 20])


def _small_at(fraction_inside):
    """A 10 mm cube whose x-extent is ``fraction_inside`` inside the big cube's x = 20 face."""
    x1 = 20.0 + 10.0 * (1.0 - fraction_inside)
    return _box([x1 - 10.0, -5, -5], [x1, 5, 5])


@pytest.mark.parametrize("fraction", [0.75, 0.99, 1.0])
def test_nesting_means_wholly_inside(fraction):
    small = _small_at(fraction) if fraction < 1 else _box([9.0, -5, -5], [19.0, 5, 5])
    assert body_inside(small, _box(BIG_LO, BIG_HI)) == (fraction == 1.0)
    # small listed FIRST: it wins only when wholly inside the big cube
    scene = _scene([small, _box(BIG_LO, BIG_HI)], [2.0, 0.2], center=(0.13, 0.07, -100),
                   shape=(81, 41), pitch=1.0)
    rank = scene.precedence
    assert (rank[0] > rank[1]) == (fraction == 1.0)
    for engine in ("fast", "numpy"):
        image = xray_viz.render(scene, engine=engine)
        L_small = image.path_length[..., 0]
        lo, hi = small.bounds
        # exact: in the small cube's material, 10 mm where it is nested, else only the part
        # of it outside the big cube (x > 20)
        expect = 10.0 if fraction == 1.0 else 0.0
        rays = xray_viz.detector_rays(scene)
        x = rays.origins[:, 0].reshape(41, 81)
        y = rays.origins[:, 1].reshape(41, 81)
        core = (np.abs(y) < 4.5) & (x > lo[0] + 0.25) & (x < hi[0] - 0.25)
        if fraction == 1.0:
            np.testing.assert_allclose(L_small[core], expect, atol=1e-9)
        else:
            inside_big = core & (x < 20 - 0.25)
            outside_big = core & (x > 20 + 0.25)
            np.testing.assert_allclose(L_small[inside_big], 0.0, atol=1e-9)
            np.testing.assert_allclose(L_small[outside_big], 10.0, atol=1e-9)


def test_moving_a_partly_inside_body_a_few_mm_flips_nothing():
    ranks = []
    for shift in (0.0, 1.0, 2.0, 2.4):        # from 75 % to 99 % inside
        small = _small_at(0.75)
        small.apply_translation([-shift, 0, 0])
        scene = _scene([small, _box(BIG_LO, BIG_HI)], [2.0, 0.2], center=(0.13, 0.07, -100))
        ranks.append(scene.precedence.tolist())
    assert all(r == [0, 1] for r in ranks)     # list order: the big cube wins the overlap


def test_later_partial_overlap_wins_even_over_a_nested_body():
    """[outer, nested, later]: nested is inside outer; later partly overlaps both and, listed
    last, wins where it overlaps the nested body (the old depth ranking let nested win)."""
    outer = _box([-30, -30, -30], [30, 30, 30])
    nested = _box([-10, -10, -10], [10, 10, 10])
    later = _box([0, -5, -5], [40, 5, 5])
    scene = _scene([outer, nested, later], [0.1, 1.0, 3.0], center=(0.13, 0.07, -100),
                   shape=(81, 41), pitch=1.0)
    rank = scene.precedence
    assert rank[1] > rank[0] and rank[2] > rank[1] and rank[2] > rank[0]
    image = xray_viz.render(scene, engine="numpy")
    rays = xray_viz.detector_rays(scene)
    x = rays.origins[:, 0].reshape(41, 81)
    y = rays.origins[:, 1].reshape(41, 81)
    both = (np.abs(y) < 4.5) & (x > 0.5) & (x < 9.5)
    np.testing.assert_allclose(image.path_length[..., 2][both], 10.0, atol=1e-9)
    np.testing.assert_allclose(image.path_length[..., 1][both], 10.0, atol=1e-9)  # 20 - 10
    fast = xray_viz.render(scene)
    np.testing.assert_allclose(fast.path_length, image.path_length, atol=1e-9)
