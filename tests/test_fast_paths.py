"""The one-body fast paths of the fast engine: cell-code culling, single-sample triangles, and
the per-mesh vertex numbering (first use by the Morton-sorted faces)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from xray_viz.render import ENGINES
from xray_viz.tracing import _raster as R
from xray_viz.tracing.fast import _spatial_order, fast_path_lengths
from helpers import make_scene


def test_first_use_rank_is_a_permutation_in_order_of_first_use():
    faces = np.array([[5, 2, 7], [2, 0, 5], [1, 7, 0]])
    rank = R.first_use_rank(faces.ravel(), 9)
    assert sorted(rank.tolist()) == list(range(9))
    assert rank[[5, 2, 7, 0, 1]].tolist() == [0, 1, 2, 3, 4]
    assert rank[[3, 4, 6, 8]].tolist() == [5, 6, 7, 8]      # unused: after, in order


def test_spatial_order_keeps_the_mesh():
    m = trimesh.creation.icosphere(subdivisions=5, radius=10.0)
    v, f = _spatial_order(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
    assert sorted(map(tuple, v[f].reshape(-1, 9).round(12).tolist())) == \
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
    return v[order][new], renumber[f]


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
    R._kernel("_first_use_rank")               # compiled (or loaded): the kernel's answer
    got, want, ours = _spatial_order(v, f), _numpy_spatial_order(v, f), R.spatial_order_numpy(v, f)
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
