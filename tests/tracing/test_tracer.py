"""The all-hits tracer against mathematics: analytic chords, shared edges, the thesis' bugs."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.geometry import detector_rays
from xray_viz.tracing import moller_trumbore, trace_rays, watertight_intersect
from helpers import (box_chord, ellipsoid_chord, icosphere_radii, make_scene,
                     random_rotation)

CAMERAS = [
    # (source, detector centre, up): on axis, away from the origin, tilted, oblique
    ((0, 0, 1000), (0, 0, -500), (0, 1, 0)),
    ((300, -200, 900), (-180, 120, -540), (0.3, 1, 0.2)),
    ((-800, 400, 150), (600, -300, -112.5), (0, 0.2, 1)),
]


def _render_lengths(scene):
    return xray_viz.render(scene).total_path_length


@pytest.mark.parametrize("camera", CAMERAS)
def test_sphere_chords_between_inscribed_and_circumscribed(camera):
    source, center, up = camera
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    r_in, r_out = icosphere_radii(mesh)
    offset = np.array([10.0, -5.0, 20.0])
    mesh.apply_translation(offset)
    dist = np.linalg.norm(np.subtract(source, center))
    scene = make_scene(mesh, source=source, center=center, up=up, shape=(61, 47),
                       pitch=130.0 * dist / np.linalg.norm(np.subtract(source, offset)) / 60)
    L = _render_lengths(scene).ravel()
    rays = detector_rays(scene)
    # Distance of each ray's line from the sphere centre.
    rel = offset - rays.origins
    b = np.linalg.norm(rel - np.sum(rel * rays.directions, axis=1)[:, None] * rays.directions, axis=1)
    inner = 2 * np.sqrt(np.maximum(r_in**2 - b**2, 0))
    outer = 2 * np.sqrt(np.maximum(r_out**2 - b**2, 0))
    assert np.all(L >= inner - 1e-9)
    assert np.all(L <= outer + 1e-9)
    assert np.count_nonzero(L) > 0.1 * L.size      # the sphere is in view


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotated_box_chords_exact(seed):
    rng = np.random.default_rng(seed)
    extents = rng.uniform(10, 60, size=3)
    rot = random_rotation(rng)
    shift = rng.uniform(-15, 15, size=3)
    box = trimesh.creation.box(extents=extents)
    transform = np.eye(4)
    transform[:3, :3] = rot
    transform[:3, 3] = shift
    box.apply_transform(transform)
    source, center, up = CAMERAS[seed % len(CAMERAS)]
    scene = make_scene(box, source=source, center=center, up=up, shape=(41, 37), pitch=2.5)
    L = _render_lengths(scene).ravel()
    rays = detector_rays(scene)
    # In the box frame the box is axis aligned: the slab method is exact.
    o = (rays.origins - shift) @ rot
    d = rays.directions @ rot
    ref, _, _ = box_chord(o, d, -extents / 2, extents / 2)
    assert np.count_nonzero(ref) > 50
    np.testing.assert_allclose(L, ref, atol=1e-6, rtol=0)


@pytest.mark.parametrize("seed", [3, 4])
def test_rotated_ellipsoid_chords_between_bounds(seed):
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    r_in, r_out = icosphere_radii(sphere)
    axes = np.diag(rng.uniform(15, 45, size=3))
    A = random_rotation(rng) @ axes
    c = rng.uniform(-10, 10, size=3)
    mesh = sphere.copy()
    mesh.vertices = sphere.vertices @ A.T + c
    source, center, up = CAMERAS[1]
    scene = make_scene(mesh, source=source, center=center, up=up, shape=(45, 45), pitch=3.0)
    L = _render_lengths(scene).ravel()
    rays = detector_rays(scene)
    inner = ellipsoid_chord(rays.origins, rays.directions, c, A * r_in)
    outer = ellipsoid_chord(rays.origins, rays.directions, c, A * r_out)
    assert np.count_nonzero(inner) > 100
    assert np.all(L >= inner - 1e-9)
    assert np.all(L <= outer + 1e-9)


def _cube_scene(kind, shape, pitch, center_z):
    cube = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
    assert len(cube.faces) == 12
    return make_scene(cube, source=(0.0, 0.0, -1000.0), center=(0.0, 0.0, center_z),
                      up=(0.0, 1.0, 0.0), shape=shape, pitch=pitch, kind=kind)


@pytest.mark.parametrize("kind,shape,pitch,z", [
    ("point", (161, 161), 0.5, 249.5),      # rows of rays on edges, diagonals and vertices
    ("parallel", (161, 161), 0.5, 249.5),   # includes rays in the side-face planes x, y = +-20
    ("point", (81, 81), 24.5 / 40, 200.0),  # the detector edge rays graze the cube's silhouette
])
def test_cube_edges_and_vertices_counted_once(kind, shape, pitch, z):
    scene = _cube_scene(kind, shape, pitch, z)
    rays = detector_rays(scene)
    hits = trace_rays(scene, rays.origins, rays.directions, t_max=rays.t_max)
    n = len(rays)
    entries = np.bincount(hits.ray, weights=hits.entering, minlength=n)
    exits = np.bincount(hits.ray, weights=~hits.entering, minlength=n)
    np.testing.assert_array_equal(entries, exits)           # every entry has its exit
    assert entries.max() == 1                                # a convex body: at most one each
    L = xray_viz.render(scene).total_path_length.ravel()
    ref, tn, tf = box_chord(rays.origins, rays.directions, [-20] * 3, [20] * 3, rays.t_max)
    ok = np.abs(L - ref) <= 1e-6
    if kind == "parallel":
        # Rays lying in a face plane cross a set of measure zero: either one-sided limit is right.
        x, y = rays.origins[:, 0], rays.origins[:, 1]
        in_face = (np.abs(np.abs(x) - 20) < 1e-12) | (np.abs(np.abs(y) - 20) < 1e-12)
        in_face &= (np.abs(x) <= 20) & (np.abs(y) <= 20)
        assert in_face.sum() > 100
        ok |= in_face & ((np.abs(L) <= 1e-6) | (np.abs(L - 40.0) <= 1e-6))
    assert np.all(ok), f"{np.count_nonzero(~ok)} rays wrong"
    # Rays through the centre and along the face diagonals cross two triangles per face.
    centre = rays.shape[0] * (rays.shape[1] // 2) + rays.shape[0] // 2
    assert np.count_nonzero(hits.ray == centre) == 2


def test_textbook_moller_trumbore_double_counts_shared_edges():
    """The reason for the watertight test: the inclusive textbook test counts diagonal rays twice."""
    scene = _cube_scene("point", (161, 161), 0.5, 249.5)
    rays = detector_rays(scene)
    tris = scene.triangles
    k = np.repeat(np.arange(len(rays)), len(tris))
    j = np.tile(np.arange(len(tris)), len(rays))
    hit, *_ = moller_trumbore(rays.origins[k], rays.directions[k], tris[j, 0], tris[j, 1],
                              tris[j, 2], t_max=rays.t_max[k])
    counts = np.bincount(k[hit], minlength=len(rays))
    assert counts[len(rays) // 2] == 4                       # centre ray: both triangles, twice
    whit, *_ = watertight_intersect(rays.origins[k], rays.directions[k], tris[j, 0], tris[j, 1],
                                    tris[j, 2], t_max=rays.t_max[k])
    wcounts = np.bincount(k[whit], minlength=len(rays))
    assert wcounts[len(rays) // 2] == 2
    assert np.count_nonzero(counts % 2) + np.count_nonzero(counts == 4) > 100
    assert np.all(wcounts % 2 == 0)


def test_listing_bug_multiplies_by_C():
    """Listing 1 multiplies by C instead of 1/C: wrong unless C happens to be 1."""
    o = np.array([[0.2, 0.3, 10.0]])
    d = np.array([[0.0, 0.0, -1.0]])
    v0, v1, v2 = np.array([[0.0, 0, 0]]), np.array([[4.0, 0, 0]]), np.array([[0.0, 4, 0]])
    hit, t, beta, gamma = moller_trumbore(o, d, v0, v1, v2)
    assert hit[0] and t[0] == pytest.approx(10.0) and beta[0] == pytest.approx(0.05)
    assert gamma[0] == pytest.approx(0.075)
    _, t_bug, beta_bug, _ = moller_trumbore(o, d, v0, v1, v2, listing_bug=True)
    assert t_bug[0] != pytest.approx(10.0)                   # C = 16 here, so t comes out 256x off
    assert beta_bug[0] == pytest.approx(0.05 * 16**2)


def test_parallel_test_is_relative_not_absolute():
    """Listing 1's |C| < 1e-9 rejects a 10-micron triangle; a relative test does not."""
    s = 1e-5
    o = np.array([[0.25 * s, 0.25 * s, 1.0]])
    d = np.array([[0.0, 0.0, -1.0]])
    v0, v1, v2 = np.array([[0.0, 0, 0]]), np.array([[s, 0, 0]]), np.array([[0.0, s, 0]])
    C = np.dot(v1[0] - v0[0], np.cross(d[0], v2[0] - v0[0]))
    assert abs(C) < 1e-9                                     # the listing would call it parallel
    hit, t, *_ = moller_trumbore(o, d, v0, v1, v2)
    assert hit[0] and t[0] == pytest.approx(1.0)
    whit, wt, *_ = watertight_intersect(o, d, v0, v1, v2)
    assert whit[0] and wt[0] == pytest.approx(1.0)
    # A ray truly parallel to the plane is rejected by both.
    dp = np.array([[1.0, 0.0, 0.0]])
    assert not moller_trumbore(o, dp, v0, v1, v2)[0][0]
    assert not watertight_intersect(o, dp, v0, v1, v2)[0][0]


def test_rays_through_vertices_of_a_closed_mesh_cross_once():
    """Rays aimed exactly at vertices (fans of 5-6 triangles) enter once and leave once."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    rng = np.random.default_rng(7)
    targets = mesh.vertices[rng.choice(len(mesh.vertices), 40, replace=False)]
    # Through vertex then on through the body: from outside, towards the sphere's inside.
    origins = targets * 3.0 + rng.normal(scale=5, size=targets.shape)
    directions = targets - origins
    scene = make_scene(mesh)
    hits = trace_rays(scene, origins, directions)
    counts = np.bincount(hits.ray, minlength=len(origins))
    entries = np.bincount(hits.ray, weights=hits.entering, minlength=len(origins))
    assert np.all(counts == 2) and np.all(entries == 1)
    first = hits.t[np.searchsorted(hits.ray, np.arange(len(origins)))]
    np.testing.assert_allclose(first, 1.0, atol=1e-12)      # the first hit is the vertex itself


def test_rays_along_edges_points_cross_once():
    """Rays through points on edges (shared by exactly two triangles)."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    rng = np.random.default_rng(11)
    edges = mesh.edges_unique[rng.choice(len(mesh.edges_unique), 60, replace=False)]
    s = rng.uniform(0.1, 0.9, size=(60, 1))
    targets = mesh.vertices[edges[:, 0]] * (1 - s) + mesh.vertices[edges[:, 1]] * s
    origins = -targets * 2.5 + rng.normal(scale=3, size=targets.shape)
    hits = trace_rays(make_scene(mesh), origins, targets - origins, t_max=2.0)
    counts = np.bincount(hits.ray, minlength=60)
    entries = np.bincount(hits.ray, weights=hits.entering, minlength=60)
    assert np.all(counts == 2) and np.all(entries == 1)


def test_hits_are_sorted_complete_and_on_the_triangles():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=25.0)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    scene = make_scene([mesh, inner], mu=[0.2, 0.5])
    rng = np.random.default_rng(3)
    origins = rng.normal(size=(200, 3)) * 5 + [0, 0, 200]
    directions = rng.normal(size=(200, 3)) * 0.1 + [0, 0, -1]
    hits = trace_rays(scene, origins, directions)
    assert np.all(np.diff(hits.ray) >= 0)
    same = np.diff(hits.ray) == 0
    assert np.all(np.diff(hits.t)[same] >= 0)
    # The point is origin + t d, and also the barycentric combination of its triangle.
    np.testing.assert_allclose(hits.point, origins[hits.ray] + hits.t[:, None] * directions[hits.ray])
    tri = np.stack([scene.bodies[b].vertices[scene.bodies[b].faces[f]]
                    for b, f in zip(hits.body, hits.triangle)])
    np.testing.assert_allclose(np.einsum("nk,nkj->nj", hits.barycentric, tri), hits.point, atol=1e-9)
    np.testing.assert_allclose(hits.barycentric.sum(axis=1), 1.0, atol=1e-12)
    # Entering means d . n < 0 for the triangle's outward normal.
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_array_equal(hits.entering, np.sum(normals * directions[hits.ray], 1) < 0)
    # Cross-check the culled tracer against a brute-force pass over every triangle.
    k = np.repeat(np.arange(200), len(scene.triangles))
    j = np.tile(np.arange(len(scene.triangles)), 200)
    tris = scene.triangles
    hit, *_ = watertight_intersect(origins[k], directions[k], tris[j, 0], tris[j, 1], tris[j, 2])
    assert hit.sum() == len(hits)
    # Empty results keep their shapes.
    none = trace_rays(scene, [[1000.0, 0, 0]], [[1.0, 0, 0]])
    assert none.point.shape == (0, 3) and none.barycentric.shape == (0, 3) and len(none) == 0


def test_culling_matches_brute_force_for_a_detector_grid():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=30.0)
    mesh.apply_translation([12, -7, 30])
    scene = make_scene(mesh, source=(40, 30, 700), center=(-20, -10, -300), up=(0.2, 1, 0),
                       shape=(33, 29), pitch=3.0)
    rays = detector_rays(scene)
    hits = trace_rays(scene, rays.origins, rays.directions, t_max=rays.t_max)
    tris = scene.triangles
    k = np.repeat(np.arange(len(rays)), len(tris))
    j = np.tile(np.arange(len(tris)), len(rays))
    hit, t, *_ = watertight_intersect(rays.origins[k], rays.directions[k], tris[j, 0],
                                      tris[j, 1], tris[j, 2], t_max=rays.t_max[k])
    assert hit.sum() == len(hits) > 0
    np.testing.assert_allclose(np.sort(t[hit]), np.sort(hits.t))


@pytest.mark.parametrize("axis", [None, (0.0, 0.0, -1.0), (0.1, -0.2, -1.0)])
def test_single_rays_and_axis_hints_find_the_same_hits(axis):
    """A single ray shares its origin and its direction with itself; any axis hint is valid."""
    scene = make_scene(trimesh.creation.icosphere(subdivisions=3, radius=30.0))
    rng = np.random.default_rng(5)
    for _ in range(20):
        target = rng.uniform(-25, 25, size=3)
        o = np.array([[0.0, 0.0, 1000.0]])
        d = (target - o) / np.linalg.norm(target - o)
        hits = trace_rays(scene, o, d, axis=axis)
        k = np.zeros(len(scene.triangles), int)
        tris = scene.triangles
        ref, *_ = watertight_intersect(o[k], d[k], tris[:, 0], tris[:, 1], tris[:, 2])
        assert len(hits) == ref.sum()
    # A parallel bundle given a misleading axis hint still finds its hits.
    origins = np.stack([rng.uniform(-20, 20, 50), rng.uniform(-20, 20, 50), np.full(50, 100.0)], 1)
    d = np.tile([0.05, 0.02, -1.0], (50, 1))
    a = trace_rays(scene, origins, d, axis=axis)
    b = trace_rays(scene, origins, d)
    np.testing.assert_array_equal(a.ray, b.ray)
    assert len(a) > 0
