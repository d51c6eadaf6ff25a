"""The fast engine against the NumPy reference engine, and its own contract."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz import phantoms
from xray_viz.errors import SceneError
from xray_viz.geometry import detector_rays
from xray_viz.render import ENGINES, render
from xray_viz.tracing.fast import clear_caches, fast_path_lengths, trace_once
from helpers import ball_union_chord, box_chord, make_scene


def _sphere(r=40.0, sub=3, at=(0, 0, 0)):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    m.apply_translation(at)
    return m


def _boxes():
    a = trimesh.creation.box(extents=[40, 40, 40])
    b = trimesh.creation.box(extents=[40, 30, 50])
    b.apply_translation([15, 10, 5])
    return [a, b]


def _cube():
    return trimesh.creation.box(extents=[40, 40, 40])


SCENES = {
    "sphere": lambda kind: make_scene(_sphere(), kind=kind, pitch=1.5),
    "nested": lambda kind: make_scene([_sphere(), _sphere(20, 2, (5, 3, -4))], kind=kind,
                                      pitch=1.5),
    "overlapping-boxes": lambda kind: make_scene(_boxes(), kind=kind, pitch=1.5),
    "three-overlapping": lambda kind: make_scene(
        _boxes() + [_sphere(22, 2, (-10, -5, 8))], kind=kind, pitch=1.5),
    "cube": lambda kind: make_scene(_cube(), source=(0, 0, -1000), center=(0, 0, 249.5),
                                    shape=(161, 161), pitch=0.5, kind=kind),
    # Projected faces larger than 256 grid steps: the exact limb-arithmetic path.
    "cube-giant-triangles": lambda kind: make_scene(
        _cube(), source=(0, 0, -1000), center=(0, 0, 249.5), shape=(121, 101), pitch=0.125,
        kind=kind),
    "tilted-up": lambda kind: make_scene([_sphere(), _sphere(20, 2)], kind=kind, pitch=1.5,
                                         up=(0.3, 1, 0.2)),
    "camera-away": lambda kind: make_scene(
        [_sphere(at=(10, -5, 20)), _sphere(15, 2, (20, -5, 20))], kind=kind, pitch=1.5,
        source=(300, -200, 900), center=(-180, 120, -540), up=(0.3, 1, 0.2)),
    "crossing-detector": lambda kind: make_scene(
        _sphere(at=(0, 0, -480)), kind=kind, pitch=1.5, center=(0, 0, -500)),
}


def _in_face_plane(scene):
    """Parallel-beam cube rays lying in a side-face plane (ideal grid, exact)."""
    w, h = scene.detector.shape
    row, col = np.divmod(np.arange(w * h), w)
    p = scene.detector.pitch[0]
    x, y = (col - (w - 1) / 2) * p, ((h - 1) / 2 - row) * p
    return ((np.abs(x) == 20) | (np.abs(y) == 20)) & (np.abs(x) <= 20) & (np.abs(y) <= 20)


@pytest.mark.parametrize("supersample", [1, 2])
@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_agrees_with_numpy_engine(name, kind, supersample):
    scene = SCENES[name](kind)
    L, hits = fast_path_lengths(scene, supersample=supersample, cache=False)
    ref, _ = ENGINES["numpy"](scene, supersample=supersample, keep_hits=False)
    assert hits is None
    assert L.shape == ref.shape == (len(detector_rays(scene, supersample=supersample)),
                                    len(scene.bodies))
    assert ref.max() > 0
    ok = np.abs(L - ref) <= 1e-9 * np.abs(ref).max()
    if name.startswith("cube") and kind == "parallel" and supersample == 1:
        # In a face plane the length is ambiguous (0 or 40): either one-sided limit.
        amb = _in_face_plane(scene)[:, None]
        ok |= amb & ((np.abs(L) < 1e-9) | (np.abs(L - 40) < 1e-9))
    assert np.all(ok), f"{np.count_nonzero(~ok)} rays differ"


@functools.lru_cache(maxsize=None)
def _phantom(name):
    return xray_viz.load_scene(name)


def _reduced(scene, kind, width=64):
    """The scene on a ~64-pixel-wide detector with the same field of view (pitch scaled)."""
    det = scene.detector
    (w, h), (sw, sh) = det.shape, det.size
    nw, nh = width, max(8, round(width * h / w))
    small = dataclasses.replace(det, shape=(nw, nh), pitch=(sw / (nw - 1), sh / (nh - 1)),
                                noise=False, supersample=1)
    return scene.replace(detector=small, source=dataclasses.replace(scene.source, kind=kind))


@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("name", phantoms.names())
def test_every_bundled_phantom_agrees_with_numpy_engine(name, kind):
    """Every phantom of the library (frog: 16 bodies, 173k faces), both engines, 1e-9 relative
    on path lengths and on the line integral."""
    scene = _reduced(_phantom(name), kind)
    fast = render(scene, engine="fast")
    ref = render(scene, engine="numpy")
    assert fast.engine == "fast" and ref.path_length.max() > 0
    for a, b in ((fast.path_length, ref.path_length), (fast.line_integral, ref.line_integral)):
        assert a.shape == b.shape
        bad = np.abs(a - b) > 1e-9 * np.abs(b).max()
        assert not bad.any(), f"{name}: {np.count_nonzero(bad)} values differ"


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_cube_edges_exact(kind):
    """Rows of rays through edges, diagonals and vertices: zero miscounted rays."""
    scene = SCENES["cube"](kind)
    rays = detector_rays(scene)
    L = fast_path_lengths(scene, cache=False)[0][:, 0]
    ref, _, _ = box_chord(rays.origins, rays.directions, [-20] * 3, [20] * 3, rays.t_max)
    ok = np.abs(L - ref) <= 1e-9
    if kind == "parallel":
        amb = _in_face_plane(scene)
        ok |= amb & ((np.abs(L) < 1e-9) | (np.abs(L - 40) < 1e-9))
    assert np.all(ok)
    centre = 161 * 80 + 80
    assert L[centre] == pytest.approx(40.0, abs=1e-9)


def test_sphere_phantom_diameter_and_default_engine():
    scene = xray_viz.load_scene("sphere")
    image = render(scene)
    assert image.engine == "fast"
    assert image.total_path_length.max() == pytest.approx(80.0, abs=0.05)
    ref = render(scene, engine="numpy")
    np.testing.assert_allclose(image.path_length, ref.path_length, rtol=0, atol=1e-9 * 80)


def test_trace_once_cached_and_reused_when_materials_change():
    scene = make_scene(_sphere(), pitch=1.5)
    clear_caches(scene)
    L1, _ = fast_path_lengths(scene)
    L2, _ = fast_path_lengths(scene)
    assert L2 is L1 and not L1.flags.writeable
    # Another material, same meshes and camera: the trace is reused.
    body = dataclasses.replace(scene.bodies[0], mu=0.7)
    L3, _ = fast_path_lengths(scene.replace(bodies=(body,)))
    assert L3 is L1
    # Another camera: traced again.
    moved = scene.replace(source=dataclasses.replace(scene.source, position=[0, 0, 900]))
    L4, _ = fast_path_lengths(moved)
    assert L4 is not L1
    np.testing.assert_array_equal(trace_once(scene), L1)
    # The image changes with the material, not the trace.
    a = render(scene).line_integral
    b = render(scene.replace(bodies=(body,))).line_integral
    np.testing.assert_allclose(b, a * 3.5, rtol=1e-12)


def test_keep_hits_delegates_to_the_reference_engine():
    scene = make_scene(_sphere(), pitch=1.5, shape=(16, 12))
    L, hits = fast_path_lengths(scene, keep_hits=True)
    assert hits is not None and len(hits) > 0
    assert render(scene, keep_hits=True).hits is not None


def test_body_crossing_the_source_plane_inside_the_beam_is_refused():
    # A thin bar beside the source, reaching behind it and into the beam pyramid in front of
    # it (at z = 900 the pyramid is 3.15 mm wide each way): the source is outside every body.
    bar = trimesh.creation.box(extents=[2, 2, 200])
    bar.apply_translation([3, 0, 1000])
    scene = make_scene([_sphere(), bar], pitch=1.5)
    with pytest.raises(SceneError, match="crosses the plane of the source") as err:
        fast_path_lengths(scene, cache=False)
    # One line naming the fallback for the API and for the command line.
    msg = str(err.value)
    assert "\n" not in msg and "engine='numpy'" in msg and "--engine numpy" in msg
    # Alone, the bar goes through the one-body path: refused the same way.
    with pytest.raises(SceneError, match="--engine numpy"):
        fast_path_lengths(make_scene(bar, pitch=1.5), cache=False)
    # The reference engine handles it (any rays).
    ref = ENGINES["numpy"](scene, supersample=1, keep_hits=False)[0]
    assert ref[:, 1].max() > 0


@pytest.mark.parametrize("where", ["beside", "corner"])
def test_body_crossing_the_source_plane_outside_the_beam_renders(where):
    """A bar crossing the plane of the source far outside the beam meets no ray: culled, not
    refused. "corner": its box straddles the pyramid's planes, so it is not culled as a body,
    but each triangle crossing the source plane is outside a side plane: skipped, not refused.
    """
    bar = trimesh.creation.box(extents=[10, 10, 400])
    if where == "beside":
        bar.apply_translation([200, 0, 1000])
    else:
        # A long thin ellipsoid leaning into the beam in front of the source (rays meet it)
        # and crossing z = 1000 over 200 mm outside the beam's +x side plane.
        bar = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
        bar.apply_scale([3, 3, 320])
        bar.apply_transform(trimesh.transformations.rotation_matrix(0.6, [0, 1, 0]))
        bar.apply_translation([150, 0, 900])
    scene = make_scene([_sphere(), bar], pitch=1.5)
    for part in (scene, scene.replace(bodies=scene.bodies[1:])):
        L = fast_path_lengths(part, cache=False)[0]
        ref = ENGINES["numpy"](part, supersample=1, keep_hits=False)[0]
        np.testing.assert_allclose(L, ref, rtol=0, atol=1e-9 * 80)
        assert (ref[:, -1].max() > 1) == (where == "corner")
    from xray_viz.tracing.fast import visible_bodies

    assert visible_bodies(scene) == ((0,) if where == "beside" else (0, 1))


def test_body_crossing_the_parallel_source_plane_outside_the_slab_renders():
    bar = trimesh.creation.box(extents=[10, 10, 400])
    bar.apply_translation([200, 0, 1000])
    scene = make_scene([_sphere(), bar], pitch=1.5, kind="parallel")    # accepted
    L = fast_path_lengths(scene, cache=False)[0]
    ref = ENGINES["numpy"](scene, supersample=1, keep_hits=False)[0]
    assert np.all(L[:, 1] == 0) and ref[:, 0].max() > 70
    np.testing.assert_allclose(L, ref, rtol=0, atol=1e-9 * 80)
    # Inside the slab it is still refused when the scene is made (rays would start in it).
    bar.apply_translation([-190, 0, 0])
    with pytest.raises(SceneError, match="crosses the plane of the parallel-beam source"):
        make_scene([_sphere(), bar], pitch=1.5, kind="parallel")
    # And a huge body whose cross-section holds the whole slab (no face near the beam).
    big = trimesh.creation.box(extents=[4000, 4000, 400])
    big.apply_translation([0, 0, 1000])
    with pytest.raises(SceneError, match="crosses the plane of the parallel-beam source"):
        make_scene(big, pitch=1.5, kind="parallel")


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_bodies_outside_the_beam_are_culled_as_a_whole(kind, monkeypatch):
    """Bodies behind the source, beside the beam or beyond the detector are never projected;
    they get zero path length and change nothing else (nesting included)."""
    import xray_viz.tracing.fast as fast

    behind = _sphere(10, 1, (0, 0, 1500))
    aside = _sphere(10, 1, (5000, 0, 0))
    beyond = _sphere(10, 1, (0, 0, -700))
    below = _sphere(10, 1, (0, 120, 0))
    inner = _sphere(20, 2, (5, 3, -4))
    scene = make_scene([_sphere(), behind, inner, aside, beyond, below], pitch=1.5, kind=kind)
    assert fast.visible_bodies(scene) == (0, 2)
    seen = []
    project = fast._geometry

    def spy(scene, keep=None):
        seen.append(keep)
        return project(scene, keep)

    monkeypatch.setattr(fast, "_geometry", spy)
    L = fast_path_lengths(scene, cache=False)[0]
    assert seen == [(0, 2)]                    # only the bodies in the beam are projected
    ref = ENGINES["numpy"](scene, supersample=1, keep_hits=False)[0]
    assert np.all(L[:, [1, 3, 4, 5]] == 0)
    np.testing.assert_allclose(L, ref, rtol=0, atol=1e-9 * 80)
    # The same lengths as without the culled bodies; the inner sphere still wins inside.
    alone = fast_path_lengths(scene.replace(bodies=(scene.bodies[0], scene.bodies[2])),
                              cache=False)[0]
    np.testing.assert_array_equal(L[:, [0, 2]], alone)
    assert L[:, 2].max() > 35 and L[:, 0].max() > 70
    # One body left in the beam: the one-body path, written to its column.
    scene1 = scene.replace(bodies=(scene.bodies[1], scene.bodies[0], scene.bodies[3]))
    L1 = fast_path_lengths(scene1, supersample=2, cache=False)[0]
    ref1 = ENGINES["numpy"](scene1, supersample=2, keep_hits=False)[0]
    assert np.all(L1[:, [0, 2]] == 0)
    np.testing.assert_allclose(L1, ref1, rtol=0, atol=1e-9 * 80)
    # Nothing in the beam.
    none = scene.replace(bodies=(scene.bodies[1], scene.bodies[3]))
    assert np.all(fast_path_lengths(none, cache=False)[0] == 0)


def test_culling_is_conservative_at_the_edge_of_the_beam():
    """Bodies just inside the outermost rays are kept (supersampled rays reach past the pixel
    rays): the culled result equals the reference for boxes straddling each side plane."""
    from xray_viz.tracing.fast import visible_bodies

    scene = make_scene(_sphere(), pitch=1.5, shape=(16, 12))
    # Edge ray of the fine grid at supersampling 3: offset (8 - 1/6) * 1.5 mm on the detector,
    # 1500 mm from the source; a small cube touching it at z = 0 (1000 mm from the source).
    x = (8 - 1 / 6) * 1.5 * 1000 / 1500
    for dx in (-0.01, 0.0, 0.01):
        cube = trimesh.creation.box(extents=[2, 2, 2])
        cube.apply_translation([x + 1 + dx, 0, 0])
        part = scene.replace(bodies=(dataclasses.replace(scene.bodies[0], mesh=cube),))
        L = fast_path_lengths(part, supersample=3, cache=False)[0]
        ref = ENGINES["numpy"](part, supersample=3, keep_hits=False)[0]
        np.testing.assert_allclose(L, ref, rtol=0, atol=1e-9 * 2)
        if dx <= 0:
            assert visible_bodies(part) == (0,) and ref.max() > 0


def test_zero_area_triangles_and_empty_scene():
    m = _sphere(sub=2)
    faces = m.faces.tolist()
    a, b, c = faces[0]
    # Split edge (a, b) on its neighbour's side only and close the T-junction with the
    # zero-area triangle (b, a, mid): still closed, never hit, no effect on path lengths.
    k = next(k for k, f in enumerate(faces)
             if k > 0 and any(f[i] == b and f[(i + 1) % 3] == a for i in range(3)))
    f = faces[k]
    i = next(i for i in range(3) if f[i] == b and f[(i + 1) % 3] == a)
    d = f[(i + 2) % 3]
    v = np.vstack([m.vertices, (m.vertices[a] + m.vertices[b]) / 2])
    mid = len(v) - 1
    faces[k] = [b, mid, d]
    faces += [[mid, a, d], [b, a, mid]]
    scene = make_scene(trimesh.Trimesh(v, np.array(faces), process=False), pitch=1.5)
    ref = make_scene(m, pitch=1.5)
    np.testing.assert_allclose(fast_path_lengths(scene, cache=False)[0],
                               fast_path_lengths(ref, cache=False)[0], rtol=0, atol=1e-9)
    empty = scene.replace(bodies=())
    assert fast_path_lengths(empty, cache=False)[0].shape == (64 * 48, 0)


def test_single_row_detector_with_supersampling_matches():
    scene = make_scene(_sphere(), pitch=1.5, shape=(40, 1))
    L = fast_path_lengths(scene, supersample=2, cache=False)[0]
    ref = ENGINES["numpy"](scene, supersample=2, keep_hits=False)[0]
    np.testing.assert_allclose(L, ref, rtol=0, atol=1e-9 * 80)



@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_band_path_for_large_detectors_matches_direct_path(kind, monkeypatch):
    """One body on a detector too large for per-thread accumulators goes through the banded
    raster; both paths agree."""
    import xray_viz.tracing.fast as fast

    scene = SCENES["camera-away"](kind).replace(bodies=SCENES["camera-away"](kind).bodies[:1])
    direct = trace_once(scene, supersample=2)
    monkeypatch.setattr(fast, "_DIRECT_MAX_SAMPLES", 0)
    banded = trace_once(scene, supersample=2)
    np.testing.assert_allclose(banded, direct, rtol=0, atol=1e-12 * 100)
    cube = SCENES["cube-giant-triangles"](kind)
    ref = ENGINES["numpy"](cube, supersample=1, keep_hits=False)[0]
    ok = np.abs(trace_once(cube) - ref) <= 1e-9 * 40
    if kind == "parallel":
        ok |= _in_face_plane(cube)[:, None]
    assert np.all(ok)


def test_body_bounds_are_kept_by_the_bodies_not_measured_per_scene(monkeypatch):
    """Scene.replace (the viewer moving the source) checks the source against the boxes the
    bodies keep: no pass over the vertices, no module-level cache."""
    from xray_viz.bodies import Bodies

    m = _sphere(sub=2)
    scene = make_scene(m, pitch=1.5)
    box = scene.bodies.bounds
    assert scene.bodies.bounds is box and not box.flags.writeable
    np.testing.assert_array_equal(box[0, 0], m.vertices.min(0))
    np.testing.assert_array_equal(box[0, 1], m.vertices.max(0))
    fast_path_lengths(scene, cache=False)              # what the engine needs, once
    calls = []
    build = Bodies._value

    def counting(self, name, make):
        return build(self, name, lambda: calls.append(name) or make())
    monkeypatch.setattr(Bodies, "_value", counting)
    for z in (900.0, 800.0, 700.0):
        moved = scene.replace(source=dataclasses.replace(scene.source, position=[0, 0, z]))
        assert moved.bodies is scene.bodies
        scene.replace(source=dataclasses.replace(scene.source, kind="parallel"))
    fast_path_lengths(scene, cache=False)
    assert calls == []
    # A mesh changed in place is measured again.
    lo = box[0, 0].copy()
    m.apply_translation([5, 0, 0])
    assert scene.bodies.bounds[0, 0, 0] == pytest.approx(lo[0] + 5) and calls == ["bounds"]


def test_a_frame_hashes_each_mesh_once_and_a_change_in_place_is_still_seen(monkeypatch):
    """The engine's set-up reads a dozen derived values of the bodies inside one
    ``Bodies.checked()`` block: each mesh is hashed (trimesh's change detection) once for the
    block, not once per lookup; a mesh changed in place inside the block is found changed at
    the next lookup after it (the bounds measured again)."""
    from xray_viz import bodies as B

    meshes = [_sphere(r, 2, (20.0 * k - 20.0, 0, 0)) for k, r in enumerate((5.0, 6.0, 7.0))]
    scene = make_scene(meshes, pitch=1.5)
    trace_once(scene)
    hashed = []
    real = B._mesh_hash
    monkeypatch.setattr(B, "_mesh_hash", lambda m: hashed.append(id(m)) or real(m))
    trace_once(scene)
    assert sorted(hashed) == sorted(id(m) for m in meshes)     # one each, for the whole frame
    box = scene.bodies.bounds.copy()
    with scene.bodies.checked():
        meshes[1].apply_translation([0, 4, 0])
        assert scene.bodies.bounds[1, 0, 1] == box[1, 0, 1]       # taken as unchanged inside
    assert scene.bodies.bounds[1, 0, 1] == pytest.approx(box[1, 0, 1] + 4)


def _projected_ball():
    """A projected sphere of 20,480 faces on a 128 x 96 grid (every vertex between the source
    and detector planes): the arguments of the cull, and the cell codes."""
    from xray_viz.tracing import _raster_calls as RC

    ball = _sphere(20.0, 5)
    V = np.ascontiguousarray(ball.vertices.T, float)      # coordinate-major, as the kernels
    F = np.ascontiguousarray(ball.faces, np.int32)
    r0, f = np.array([0.3, -0.2, 1000.0]), np.array([0, 0, -1.0])
    eu, ev = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    planes = np.zeros((4, 4))
    planes[:, 0] = 1.0
    planes[:, 3] = 1e9
    n = V.shape[1]
    XY, w = np.empty((n, 2), np.int64), np.empty(n)
    huge, K = np.empty(n, np.bool_), np.empty(n, np.int32)
    RC.project_vertices(V, r0, f, eu, ev, 3000.0, 63.5, 3000.0, 47.5, True, XY, w, huge, 128,
                        96, K)
    return F, XY, w, huge, V, r0, planes, K


def test_the_banded_cull_s_cell_code_pass_gives_the_same_status_and_list():
    """With every vertex between the source and detector planes, the banded rasters' cull
    first drops the triangles whose cell codes say they cover no sample: the same status and
    boxes as the full test of every triangle, and the list of kept triangles is the non-zero
    statuses in order."""
    from xray_viz.tracing import _raster_calls as RC

    F, XY, w, huge, V, r0, planes, K = _projected_ball()
    assert w.min() > 0 and w.max() < 1500.0 and not huge.any()
    out = []
    for depth_ok in (False, True):
        status, box = np.full(len(F), 9, np.int8), np.zeros((len(F), 4), np.int64)
        kept = RC.cull_triangles(F, XY, w, huge, True, 1500.0, 128, 96, status, box, V, r0,
                                 planes, K=K, depth_ok=depth_ok)
        np.testing.assert_array_equal(kept, np.flatnonzero(status))
        out.append((status, box * (status != 0)[:, None]))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1], out[1][1])
    skipped = out[0][0] == 0
    assert 0.2 < skipped.mean() < 0.9          # many triangles between samples, many not


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_band_lists_hold_each_kept_triangle_in_every_band_its_rows_meet(monkeypatch, threads):
    """``cull_and_bin``: each piece of the cull counts its kept triangles per band (a row
    table, not divisions), then lists them by band. Against NumPy: band b's lists, the
    pieces' in turn, are in triangle order exactly the kept triangles whose sample rows meet
    its rows, however many pieces (a band height of 7 rows, not a power of two; the last
    band cut by the grid)."""
    from xray_viz.tracing import _raster_calls as RC

    monkeypatch.setattr(RC, "_threads", lambda: threads)
    F, XY, w, huge, V, r0, planes, K = _projected_ball()
    status, box = np.full(len(F), 9, np.int8), np.full((len(F), 4), -1, np.int64)
    band_start, tris = RC.cull_and_bin(F, XY, w, huge, True, 1500.0, 128, 96, status, box, V,
                                       r0, planes, 7, K=K, depth_ok=True)
    kept = np.flatnonzero(status)
    assert len(kept) > 1000
    assert band_start.shape == (threads, 15)       # 14 bands of 7 rows cover 96 rows
    assert band_start[0, 0] == 0 and band_start[-1, -1] == len(tris)
    spans = 0
    for b in range(14):
        want = kept[(box[kept, 2] <= 7 * b + 6) & (box[kept, 3] >= 7 * b)]
        got = np.concatenate([tris[band_start[c, b]:band_start[c, b + 1]]
                              for c in range(threads)])
        np.testing.assert_array_equal(got, want)
        spans += len(want)
    assert spans == len(tris) > len(kept)         # some triangles meet two bands


def test_bands_taken_by_any_number_of_threads_give_the_same_bits(monkeypatch):
    """The banded raster's bands are taken by the threads from one shared counter, longest
    first (``fast._band_order``: by triangle entries, a permutation), so a thread that
    starts late takes fewer; the path lengths are the same bits for 1, 2, 3 and 5 threads,
    and when one thread starts a frame late (each band writes its own rays)."""
    from xray_viz.tracing import _raster_calls as RC
    from xray_viz.tracing import fast as fast_mod

    entries = np.array([0, 5, 900, 40, 1000, 3, 3, 77, 600, 0, 12])
    order = fast_mod._band_order(entries)
    assert sorted(order.tolist()) == list(range(len(entries)))
    assert np.all(np.diff(entries[order]) <= 0)                    # longest first
    assert order.tolist()[-2:] == [0, 9]                           # ties in band order
    scene = xray_viz.load_scene("frog")
    out = []
    for k in (1, 2, 3, 5):          # the cull's pieces and the raster's threads
        monkeypatch.setattr(fast_mod.numba, "get_num_threads", lambda k=k: k)
        monkeypatch.setattr(RC, "_threads", lambda k=k: k)
        out.append(fast_mod.trace_once(scene))
    assert out[0].shape[1] == 16 and out[0].max() > 10
    for L in out[1:]:
        np.testing.assert_array_equal(L, out[0])
    # one of two threads starts late: the other takes the bands it finds free
    import time

    from xray_viz import _threads

    real = _threads.run_pieces
    seen = []

    def late(fn, k):
        def piece(j):
            if j:
                time.sleep(0.05)
            seen.append(j)
            return fn(j)
        return real(piece, k)

    monkeypatch.setattr(fast_mod.numba, "get_num_threads", lambda: 2)
    monkeypatch.setattr(RC, "_threads", lambda: 2)
    monkeypatch.setattr(_threads, "run_pieces", late)
    np.testing.assert_array_equal(fast_mod.trace_once(scene), out[0])
    assert seen.count(1) == seen.count(0) >= 3     # each kernel of the frame on both threads


# --------------------------------------------------------------------------------------------
# one body of several pieces: the nonzero rule, whatever else is in the scene


def _pieces(*meshes):
    return trimesh.util.concatenate(list(meshes))


def _union_chord(rays, balls):
    """Length of each ray inside the union of balls ``(centre, r)``."""
    return ball_union_chord(rays.origins, rays.directions, balls)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_overlapping_pieces_of_one_body_give_their_union_with_or_without_culled_bodies(kind):
    balls = [((-12, 0, 0), 25.0), ((12, 0, 0), 25.0)]
    two = _pieces(*(_sphere(r, 3, c) for c, r in balls))
    far = _sphere(2, 1, (5000, 0, 0))                     # outside the beam: culled
    alone = make_scene(two, kind=kind, pitch=1.0, shape=(81, 61))
    with_far = make_scene([two, far], kind=kind, pitch=1.0, shape=(81, 61))
    L1 = fast_path_lengths(alone, cache=False)[0][:, 0]
    L2 = fast_path_lengths(with_far, cache=False)[0]
    assert np.all(L2[:, 1] == 0)
    np.testing.assert_array_equal(L1, L2[:, 0])           # the culled body changes nothing
    ref = ENGINES["numpy"](alone, supersample=1, keep_hits=False)[0][:, 0]
    assert np.abs(L1 - ref).max() <= 1e-9 * ref.max()
    # the union of the two balls (an icosphere lies between its in- and circumscribed balls)
    rays = detector_rays(alone)
    ico = _sphere(25.0, 3)
    r_in = np.abs(np.einsum("ij,ij->i", ico.face_normals, ico.triangles[:, 0])).min()
    outer, inner = _union_chord(rays, balls), _union_chord(rays, [(c, r_in) for c, _ in balls])
    assert np.all(L1 <= outer + 1e-9) and np.all(L1 >= inner - 1e-9)
    assert 49 < L1.max() < 51                               # about a diameter; doubled: 87


def test_one_body_of_one_piece_keeps_the_signed_sum_path(monkeypatch):
    import xray_viz.tracing._raster_calls as RC

    calls = []
    multi = RC.raster_multi

    def spy(*args, **options):
        calls.append(1)
        return multi(*args, **options)

    monkeypatch.setattr(RC, "raster_multi", spy)
    one = make_scene(_sphere(), pitch=1.5)
    apart = make_scene(_pieces(_sphere(10, 2, (-30, 0, 0)), _sphere(10, 2, (30, 0, 0))), pitch=1.5)
    for scene in (one, apart):
        fast_path_lengths(scene, cache=False)
    assert calls == []                                     # one piece, or disjoint pieces
    nested = make_scene(_pieces(_sphere(), _sphere(20, 2)), pitch=1.5)
    L = fast_path_lengths(nested, cache=False)[0]
    assert calls == [1]                                    # nested pieces: sorted and swept
    ref = ENGINES["numpy"](nested, supersample=1, keep_hits=False)[0]
    assert np.abs(L - ref).max() <= 1e-9 * 80 and 79 < L.max() <= 80 + 1e-9


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_nested_and_hollow_pieces_of_one_body_agree_with_numpy(kind):
    outer = _sphere(40, 3)
    d = outer.vertices[0] / 40
    touching = _sphere(20, 3, tuple(d * 20))               # shares outer's vertex 0
    tangent = _pieces(outer, touching)
    tangent.merge_vertices()
    cavity = _sphere(20, 3)
    hollow = _pieces(outer, trimesh.Trimesh(cavity.vertices, cavity.faces[:, ::-1],
                                            process=False))
    three = _pieces(_sphere(40, 3), _sphere(30, 3, (3, 0, 0)), _sphere(15, 3, (5, 2, 0)))
    for mesh, longest in ((tangent, 80.0), (hollow, 80.0), (three, 80.0)):
        scene = make_scene(mesh, kind=kind, pitch=1.0, shape=(91, 91))
        for n in (1, 2):
            L = fast_path_lengths(scene, supersample=n, cache=False)[0]
            ref = ENGINES["numpy"](scene, supersample=n, keep_hits=False)[0]
            assert np.abs(L - ref).max() <= 1e-9 * 80
        assert ref.max() <= longest + 1e-9 and ref.min() >= 0
