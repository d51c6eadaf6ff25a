"""The one-body fast paths of the fast engine: cell-code culling, single-sample triangles, and
the per-mesh vertex numbering (first use by the Morton-sorted faces)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from xray_viz.render import ENGINES
from xray_viz.tracing import _raster as R, _raster_calls as RC
from xray_viz.tracing.fast import _spatial_order, fast_path_lengths
from helpers import make_scene


def test_first_use_rank_is_a_permutation_in_order_of_first_use():
    faces = np.array([[5, 2, 7], [2, 0, 5], [1, 7, 0]])
    rank = RC.first_use_rank(faces.ravel(), 9)
    assert sorted(rank.tolist()) == list(range(9))
    assert rank[[5, 2, 7, 0, 1]].tolist() == [0, 1, 2, 3, 4]
    assert rank[[3, 4, 6, 8]].tolist() == [5, 6, 7, 8]      # unused: after, in order


def test_spatial_order_keeps_the_mesh():
    m = trimesh.creation.icosphere(subdivisions=5, radius=10.0)
    v, f = _spatial_order(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
    assert v.shape == (3, len(m.vertices)) and v.flags.c_contiguous   # the kernels' layout
    assert sorted(map(tuple, v.T[f].reshape(-1, 9).round(12).tolist())) == \
        sorted(map(tuple, m.vertices[m.faces].reshape(-1, 9).round(12).tolist()))
    # Vertices numbered in order of first use by the faces.
    first = np.unique(f.ravel(), return_index=True)[1]
    assert np.all(np.diff(first) > 0)



def _numpy_spatial_order(v, f):
    """The spatial order spelt in NumPy: Morton codes, stable argsorts, first use."""
    lo, hi = v.min(0), v.max(0)
    q = ((v - lo) / np.maximum(hi - lo, 1e-300) * 1023).astype(np.uint64)
    code = np.zeros(len(v), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    order = np.argsort(code, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    f = rank[f]
    f = f[np.argsort(f.min(axis=1), kind="stable")]
    first = np.unique(f.ravel(), return_index=True)
    used = first[0][np.argsort(first[1])]                     # in order of first use
    new = np.concatenate([used, np.setdiff1d(np.arange(len(v)), used)])
    renumber = np.empty_like(new)
    renumber[new] = np.arange(len(new))
    return v[order][new].T, renumber[f]


@pytest.mark.parametrize("case", ["sphere", "ties", "unused"])
def test_compiled_spatial_order_is_the_numpy_one(case):
    rng = np.random.default_rng(3)
    if case == "sphere":
        m = trimesh.creation.icosphere(subdivisions=6, radius=40.0)
        v, f = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    elif case == "ties":              # many vertices share a Morton cell, faces share keys
        v = np.round(rng.normal(size=(20000, 3)), 1)
        f = rng.integers(0, 20000, size=(50000, 3))
    else:                             # vertices used by no face
        v = rng.normal(size=(6000, 3))
        f = rng.integers(0, 5000, size=(3000, 3))
    R.KERNELS.kernel("_first_use_rank")               # compiled (or loaded): the kernel's answer
    got, want, ours = _spatial_order(v, f), _numpy_spatial_order(v, f), RC.spatial_order_numpy(v, f)
    for a in (got, ours):
        np.testing.assert_array_equal(a[0], want[0])
        np.testing.assert_array_equal(a[1], want[1])
        assert a[1].dtype == np.int32

def _cull(codes):
    ka, kb, kc = (np.int64(k) for k in codes)
    d = (ka ^ kb) | (ka ^ kc)
    return ((d & 0xFFFF) | (ka & 1)) == 0 or ((d >> 16) | ((ka >> 16) & 1)) == 0


def test_cell_codes_only_cull_triangles_covering_no_sample():
    """Random snapped triangles (many exactly on sample rows/columns, some off the grid):
    culled by their cell codes -> their sample box is empty."""
    rng = np.random.default_rng(1)
    nW, nH = 7, 5
    one = R.ONE
    culled = 0
    for _ in range(20000):
        base = rng.integers(-2, 9, size=2)
        xy = base * one + rng.integers(-one // 2, one + one // 2, size=(3, 2))
        snap = rng.random((3, 2)) < 0.2
        xy[snap] = (xy[snap] // one) * one
        codes = [R._axis_code(int(x), nW) | (R._axis_code(int(y), nH) << 16) for x, y in xy]
        if not _cull(codes):
            continue
        culled += 1
        xmin, ymin = xy.min(0)
        xmax, ymax = xy.max(0)
        X0, X1 = max(-((-xmin) >> R.FRAC_BITS), 0), min(xmax >> R.FRAC_BITS, nW - 1)
        Y0, Y1 = max(-((-ymin) >> R.FRAC_BITS), 0), min(ymax >> R.FRAC_BITS, nH - 1)
        assert X0 > X1 or Y0 > Y1, (xy.tolist(), codes)
    assert culled > 1000


@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("shift", [(0.0, 0.0), (0.75, -0.375)])
def test_fine_mesh_of_sub_sample_triangles_matches_numpy(kind, shift):
    """82k faces on 64 x 48 rays: nearly every triangle covers at most one ray (the cell-code
    cull and the single-sample path), at two placements."""
    m = trimesh.creation.icosphere(subdivisions=6, radius=30.0)
    m.apply_translation([shift[0], shift[1], 0.0])
    scene = make_scene(m, kind=kind, pitch=1.5)
    L, _ = fast_path_lengths(scene, cache=False)
    ref, _ = ENGINES["numpy"](scene, keep_hits=False)
    assert ref.max() > 50
    assert np.all(np.abs(L - ref) <= 1e-9 * ref.max())


def _numpy_projection(V, r0, f, eu, ev, sx, bx, sy, by, perspective, nW, nH):
    """The projection and snap of :func:`R._project_vertices` spelt in NumPy (the same
    operations in the same order), with the cell codes of the documented rule."""
    r = V - r0
    w = r[:, 0] * f[0] + r[:, 1] * f[1] + r[:, 2] * f[2]
    a = r[:, 0] * eu[0] + r[:, 1] * eu[1] + r[:, 2] * eu[2]
    b = r[:, 0] * ev[0] + r[:, 1] * ev[1] + r[:, 2] * ev[2]
    with np.errstate(all="ignore"):
        if perspective:
            ahead = w > 0
            x = np.where(ahead, sx * (a / w) + bx, np.inf)
            y = np.where(ahead, sy * (b / w) + by, np.inf)
        else:
            x, y = sx * a + bx, sy * b + by
        ok = (np.abs(x) < R.COORD_LIMIT) & (np.abs(y) < R.COORD_LIMIT)

        def snapped(c):                   # snapped when it can be, else clamped (cull only)
            near = np.floor(np.where(ok, c, 0.0) * R.ONE + 0.5).astype(np.int64)
            far = np.clip(np.nan_to_num(c, nan=0.0), -R.COORD_LIMIT, R.COORD_LIMIT) * R.ONE
            return np.where(ok, near, np.where(c == c, far, 0).astype(np.int64))

        XY = np.stack([snapped(x), snapped(y)], 1)

    def code(c, n):
        k = 2 * (c >> R.FRAC_BITS) + ((c & (R.ONE - 1)) == 0) + 2
        return np.where(c < 0, 0, np.where(c > (n - 1) * R.ONE, 2 * n + 2, k))

    if nW <= R.CODE_MAX_SAMPLES and nH <= R.CODE_MAX_SAMPLES:
        K = (code(XY[:, 0], nW) | (code(XY[:, 1], nH) << 16)).astype(np.int32)
    else:
        K = np.full(len(V), R.NO_CODE, np.int32)
    K[~ok] = R.NO_CODE
    finite = w[w == w]
    wmin, wmax = (finite.min(), finite.max()) if len(finite) else (np.inf, -np.inf)
    return XY, w, ~ok, K, (wmin, wmax, bool((~ok).any() or (w != w).any()))


@pytest.mark.parametrize("perspective", [True, False])
@pytest.mark.parametrize("case", ["plain", "odd", "on samples", "wide"])
def test_projection_is_the_numpy_spelling_bit_for_bit(perspective, case):
    """The vectorised projection (blocks of 256 vertices, the vertices that cannot be snapped
    written again after their block) gives the bits of the same formulas in NumPy: the snapped
    coordinates, depths, huge flags, cell codes and depth range, for vertex counts that end
    mid-block; with NaN vertices, vertices behind the source and far off the grid; with
    coordinates exactly on samples; with a grid too wide for cell codes."""
    rng = np.random.default_rng(7)
    n = 3 * R._PROJ_BLOCK + 37
    V = rng.normal(size=(n, 3)) * 40.0
    nW, nH, sx, sy = 512, 384, 2560.0, 2560.0
    if case == "odd":
        V[5] = np.nan                      # a NaN vertex
        V[300, 2] = 1000.0                 # in the plane of the source
        V[301, 2] = 1500.0                 # behind it
        V[600, 0] = 1e30                   # far off the grid: huge
        V[-1, 1] = -1e25
    elif case == "on samples":
        V = np.round(V * 4) / 4
        sx = sy = 1000.0
    elif case == "wide":
        nW = R.CODE_MAX_SAMPLES + 1
    r0, f = np.array([0.3, -0.2, 1000.0]), np.array([0.0, 0.0, -1.0])
    eu, ev = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    if not perspective:
        sx, sy = 2.5, 2.5
    bx, by = (nW - 1) / 2, (nH - 1) / 2
    XY = np.full((n, 2), -7, np.int64)
    w, huge, K = np.full(n, -7.0), np.zeros(n, np.bool_), np.full(n, -7, np.int32)
    got = RC.project_vertices(V.T.copy(), r0, f, eu, ev, sx, bx, sy, by, perspective, XY, w, huge,
                              nW, nH, K)
    XYn, wn, hn, Kn, want = _numpy_projection(V, r0, f, eu, ev, sx, bx, sy, by, perspective,
                                              nW, nH)
    np.testing.assert_array_equal(w.view(np.int64), wn.view(np.int64))
    np.testing.assert_array_equal(XY, XYn)
    np.testing.assert_array_equal(huge, hn)
    np.testing.assert_array_equal(K, Kn)
    assert got == want
    if case == "odd":
        assert got[2] and huge[600] and huge[n - 1] and (huge[301] or not perspective)
    else:
        assert not got[2] and 0 < got[0] < got[1]


def _pair(rng=None, jitter=0.0):
    """Two disjoint spheres one behind the other along the beam (one simple body): four
    surfaces on a central ray, so that a sample's sum depends on the order of its terms."""
    a = trimesh.creation.icosphere(subdivisions=6, radius=25.0)
    b = trimesh.creation.icosphere(subdivisions=5, radius=20.0)
    a.apply_translation([0.0, 0.0, 30.0])
    b.apply_translation([3.0, -2.0, -30.0])
    m = trimesh.util.concatenate([a, b])
    if jitter:
        v = m.vertices.copy()
        for sign in (1, -1):
            part = np.sign(v[:, 2]) == sign
            c = v[part].mean(0)
            v[part] = c + (v[part] - c) * (1.0 + jitter * rng.standard_normal(part.sum()))[:, None]
        m = trimesh.Trimesh(v, m.faces, process=False)
    return m


@pytest.mark.parametrize("case", ["fine", "jittered", "on samples", "parallel", "supersampled"])
@pytest.mark.parametrize("threads", [1, 3])
def test_the_vectorised_one_sample_passes_add_the_bits_of_the_scalar_path(case, threads,
                                                                          monkeypatch):
    """The one-body raster decides its one-sample triangles in vectorised passes and adds
    their depths in triangle order among the general path's; with ``depth_ok`` False every
    triangle takes the scalar path (same decisions, no cell-code cull). Both give the same
    depth sums bit for bit: two spheres one behind the other (four surfaces on a
    ray, so the order of a sample's terms shows), radially jittered (a mix of one-sample and
    larger boxes in a block), with vertices on sample rows and columns (zero edge functions: the general path
    inside a one-sample block), a parallel beam, and 2 x 2 supersampling."""
    rng = np.random.default_rng(3)
    mesh = _pair(rng, 0.004 if case == "jittered" else 0.0)
    pitch = {"fine": 1.5, "jittered": 0.9, "on samples": 1.0, "parallel": 0.75,
             "supersampled": 1.5}[case]
    if case == "on samples":      # vertices on the detector's sample lines (magnification 2/3)
        v = mesh.vertices.copy()
        v[:, :2] = np.round(v[:, :2] / 1.5) * 1.5
        mesh = trimesh.Trimesh(v, mesh.faces, process=False)
    scene = make_scene(mesh, kind="parallel" if case == "parallel" else "point", pitch=pitch,
                       shape=(96, 80))
    calls = []
    real = RC.raster_direct
    monkeypatch.setattr(RC, "raster_direct", lambda *a: calls.append(a) or real(*a))
    fast_path_lengths(scene, supersample=2 if case == "supersampled" else 1, cache=False)
    (args,) = calls
    n_chunks, *rest = args
    depth_ok = rest[14]
    assert depth_ok                      # every vertex between the source and detector
    out = []
    for ok in (True, False):
        err = np.empty(threads, np.int64)
        S = np.zeros((threads,) + rest[15].shape[1:])
        real(threads, *rest[:14], ok, S, err, *rest[17:])
        assert (err == -1).all()
        out.append(S)
    np.testing.assert_array_equal(out[0].view(np.int64), out[1].view(np.int64))
    span = out[0].sum(0)                 # depth spans: two shells, so up to two chords a ray
    assert np.count_nonzero(span) > 2000 and span.min() > -1e-9


@pytest.mark.parametrize("perspective", [True, False])
@pytest.mark.parametrize("n", [1, 2])
def test_the_finish_from_per_thread_sums_is_the_finish_of_their_reduction(perspective, n):
    """The one-body finish reads the per-thread accumulators itself (vectorised rows when
    there is no supersampling): bit for bit the finish of the sums that ``reduce_chunks``
    stores, for the whole grid and for windows of rows at an offset into the rays; zero depth
    spans (and -0.0) give +0.0. With crossing counts (the banded one-body raster's), the
    reduction adds ``FL`` per net crossing."""
    rng = np.random.default_rng(11)
    W, H = 37, 23
    nW, nH = W * n, H * n
    S = rng.normal(size=(3, nH, nW)) * 50.0
    N = rng.integers(-2, 3, size=(3, nH, nW)).astype(np.int32)
    S[:, :, :5] = 0.0
    N[:, :, :5] = 0
    S[0, :, 5] = -0.0
    S[1:, :, 5] = 0.0
    N[:, :, 5] = 0
    FL = 1500.0
    P00, Ex, Ey = np.array([-40.0, -30.0, -1500.0]), np.array([0.8, 0.1, 0.0]), np.array(
        [0.0, 0.9, 0.05])
    total, counted = np.empty((nH, nW)), np.empty((nH, nW))
    RC.reduce_chunks(S, None, FL, total)
    RC.reduce_chunks(S, N, FL, counted)
    np.testing.assert_allclose(total, S.sum(0), rtol=1e-15, atol=1e-12)
    np.testing.assert_allclose(counted - total, N.sum(0) * FL, rtol=1e-13, atol=1e-11)
    assert np.count_nonzero(N.sum(0)) > 100
    for y0, y1 in ((0, nH), (n * 4, n * 11)):
        r0, r1 = H - y1 // n, H - y0 // n
        ray0, n_rays = r0 * W * n * n, (r1 - r0) * W * n * n
        got, want = np.full((n_rays, 1), np.nan), np.full((n_rays, 1), np.nan)
        RC.finish_chunks(S, FL, perspective, P00, Ex, Ey, n, W, H, got, y0, y1, ray0)
        RC.finish(total, np.zeros((1, 1, 1)), True, FL, perspective, P00, Ex, Ey, n, W, H, want,
                  y0, y1, 0, ray0)
        np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))
        assert np.count_nonzero(got == 0) >= 6 * (y1 - y0)        # six zero columns
        assert not np.signbit(got[got == 0]).any()


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_a_body_reaching_beyond_the_detector_takes_the_bands_and_ends_rays_there(kind):
    """The one-body raster sums hit depths without counting crossings, which needs every
    vertex before the detector plane; a ball through that plane is traced by bands (which
    count the crossings dropped beyond it), and rays still inside at the detector end there:
    against the NumPy engine, and the analytic chord cut at the detector for the central ray."""
    from xray_viz.tracing import fast

    ball = trimesh.creation.icosphere(subdivisions=5, radius=30.0)
    modes = {}
    for z, name in ((-480.0, "through"), (-300.0, "before")):
        m = ball.copy()
        m.apply_translation([0.0, 0.0, z])
        scene = make_scene(m, kind=kind, pitch=1.5, center=(0, 0, -500), shape=(41, 41))
        with fast._locked(scene.bodies):
            modes[name] = fast._Plan(scene.bodies, scene.acquisition, 1, None).mode
        L, _ = fast_path_lengths(scene, cache=False)
        ref, _ = ENGINES["numpy"](scene, keep_hits=False)
        assert np.all(np.abs(L - ref) <= 1e-9 * ref.max()) and ref.max() > 40
        if name == "through":
            # the central ray: from the near pole (z + 30) to the detector plane (-500)
            assert abs(L[(41 * 41) // 2, 0] - (z + 30.0 + 500.0)) < 0.05
    assert modes == {"through": "single", "before": "direct"}


@pytest.mark.parametrize("case", ["fine", "on samples", "parallel"])
def test_the_banded_raster_s_small_boxes_cover_what_the_one_body_rows_cover(case, monkeypatch):
    """The banded raster decides a box of at most 4 x 4 samples in one branch-free mask (the
    edge functions at its 16 places, the tie rule), wider boxes by rows: the same samples as
    the one-body raster. Two spheres one behind the other, fine enough that most boxes are
    that small, with vertices on sample rows and columns (zero edge functions: the tie rule
    decides) or not, point and parallel beams. One body by bands (depth sums and crossing
    counts) and, unsnapped, the two spheres as two bodies (sorted hits, lengths per body)
    against the one-body raster: a sample covered differently would be a chord off."""
    from xray_viz.scene import Body
    from xray_viz.tracing import fast

    mesh = _pair()
    if case == "on samples":      # vertices on the detector's sample lines (magnification 2/3)
        v = mesh.vertices.copy()
        v[:, :2] = np.round(v[:, :2] / 1.5) * 1.5
        mesh = trimesh.Trimesh(v, mesh.faces, process=False)
    pitch = {"fine": 1.5, "on samples": 1.0, "parallel": 0.75}[case]
    scene = make_scene(mesh, kind="parallel" if case == "parallel" else "point", pitch=pitch,
                       shape=(96, 80))
    direct = fast.trace_once(scene)
    assert np.count_nonzero(direct) > 1500
    monkeypatch.setattr(fast, "_DIRECT_MAX_SAMPLES", 0)          # one body, by bands
    np.testing.assert_allclose(fast.trace_once(scene), direct, rtol=0, atol=1e-9)
    if case == "on samples":
        return    # (snapped vertices fold some triangles over: winding numbers other than 0
        #          and 1, where a sweep of sorted hits and a signed sum differ by design)
    parts = mesh.split(only_watertight=False)
    assert len(parts) == 2
    two = scene.replace(bodies=[Body(name=f"s{k}", mesh=p, mu=0.2) for k, p in enumerate(parts)])
    L = fast.trace_once(two)
    np.testing.assert_allclose(L.sum(1), direct[:, 0], rtol=0, atol=1e-9)
    assert (L > 0).all(axis=1).sum() > 500       # rays through both spheres
