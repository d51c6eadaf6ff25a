"""The fast engine's calls of its kernels (:mod:`xray_viz.tracing._raster`).

Each function here normalises its arguments to the types of the kernel's one signature
(inputs made C-contiguous of the signature's dtype, without a copy when they already are; the
fields of a named tuple typed read-only made read-only views, as numba converts no named
tuple), asks :data:`xray_viz.tracing._raster.KERNELS` for the kernel (compiled or loaded on
first use) and runs it.

The kernels are serial and release the GIL (``nogil=True``); the functions below split the
loop into one contiguous range per thread (the library's count, :mod:`xray_viz._threads`) and
run them on its pool of threads. Every iteration writes its own outputs, so the results do not
depend on the split (bit for bit).
"""

from __future__ import annotations

import numpy as np

from xray_viz.tracing._raster import (
    CODE_MAX_SAMPLES,
    COORD_LIMIT,
    FRAC_BITS,
    KERNELS,
    NO_CODE,
    ONE,
    Bands,
    Cull,
    DepthSums,
    Frame,
    Grid,
    Projected,
    Projection,
    Rays,
    Sweep,
    Triangles,
    depth_key,
)


def body_ranks(precedence):
    """``(rank, by_rank)``: each body's place in the order of the banded sweep's winners
    (precedence descending, then index ascending; -1 for a precedence below 0, which never
    wins), and the body of each place (and one more entry, unused)."""
    precedence = np.asarray(precedence, np.int64)
    order = [q for q in sorted(range(len(precedence)), key=lambda q: (-precedence[q], q))
             if precedence[q] > -1]
    rank = np.full(len(precedence), -1, np.int64)
    rank[order] = np.arange(len(order))
    return rank, np.array(order + [0], np.int64)


#: Least vertices or triangles (rows, for the per-row kernels) given to a thread.
_MIN_ITEMS = 4096
_MIN_ROWS = 16


def _threads() -> int:
    """Threads to split a kernel's range over: the library's count (numba's setting,
    ``NUMBA_NUM_THREADS`` / ``numba.set_num_threads``, as the ``parallel=True`` kernels used)."""
    from xray_viz._threads import count

    return count()


def _cuts(lo, hi, min_each=1) -> list:
    """Bounds of the contiguous pieces of ``range(lo, hi)``, one per thread (at most one per
    ``min_each`` items): piece j is ``cut[j] .. cut[j + 1] - 1``."""
    k = min(_threads(), max(1, (hi - lo) // max(1, min_each)))
    return [lo + (hi - lo) * j // k for j in range(k + 1)]


def _split(name, lo, hi, args, min_each=1, cuts=None, each=None):
    """Run kernel ``name`` over ``range(lo, hi)`` in one contiguous piece per thread (or the
    pieces ``cuts[j] .. cuts[j + 1] - 1`` given, one per thread), with ``args`` and, when
    ``each`` is given, ``each(j)``'s arguments of piece j after them; returns what each
    piece returned, in order."""
    kernel = KERNELS.kernel(name)
    cut = _cuts(lo, hi, min_each) if cuts is None else list(cuts)
    k = len(cut) - 1

    def piece(j):
        return kernel(cut[j], cut[j + 1], *args, *(each(j) if each else ()))
    if k <= 1:
        return [piece(0)]
    from xray_viz._threads import run_pieces

    return run_pieces(piece, k)


def _in(a, dtype):
    return np.ascontiguousarray(a, dtype=dtype)


def _faces(F, n_vertices):
    """Faces as the kernels take them: C-contiguous uint32 (a view of int32 faces, no copy).

    Unsigned, so that numba indexes the vertex arrays with them without the fix-up of a
    negative index it adds for a signed one (a compare and a select per access;
    ``benchmarks/notes/kernels.md``); at most
    2**31 - 1 vertices and triangles, so that the int32 and uint32 views agree."""
    if len(F) >= 2**31 or (F.dtype != np.int32 and n_vertices >= 2**31):
        from xray_viz.errors import SceneError

        what = f"{len(F)} triangles" if len(F) >= 2**31 else f"{n_vertices} vertices"
        raise SceneError(f"{what}: the fast engine indexes at most 2**31 - 1 vertices and "
                         "triangles; use the NumPy engine (engine='numpy')")
    if F.dtype != np.int32:
        F = F.astype(np.int32)
    return np.ascontiguousarray(F).view(np.uint32)


_f8 = np.float64


def _vertices(V):
    """Vertices as the kernels take them: coordinate-major ``(3, n)`` C-contiguous float64
    (what :func:`spatial_order` gives; no copy then)."""
    V = _in(V, _f8)
    if V.ndim != 2 or V.shape[0] != 3:
        raise ValueError(f"vertices of shape {V.shape}: the kernels take them coordinate-major, "
                         "(3, n_vertices); pass the transpose of an (n, 3) array")
    return V


def first_use_rank(flat_faces, n_vertices):
    """The rank of each of ``n_vertices`` vertices in order of first use by ``flat_faces``
    (:func:`~xray_viz.tracing._raster.first_use_rank`, the kernel's ``spatial=False`` mode)."""
    rank = np.empty(int(n_vertices), np.int64)
    z = np.zeros(0, np.int64)
    KERNELS.kernel("_first_use_rank")(np.zeros((0, 3)), _in(flat_faces, np.int64), False, rank,
                               np.zeros((3, 0)), np.zeros(0, np.int32), z, z, z, z,
                               np.zeros((0, 0), np.int64))
    return rank


def spatial_order(V, F):
    """``(V', F')``: the vertices (coordinate-major, ``(3, n)``: the kernels' layout) and int32
    faces of a mesh (``V`` of shape ``(n, 3)``) in spatial order (see :func:`_first_use_rank`):
    faces along the Morton order, vertices in order of first use.

    By the compiled kernel (compiled here if no background process of :func:`prepare` is
    compiling it, or loaded from numba's cache), except while a background process of this
    one is compiling it (a cold start: the image would wait ~1.2 s for it): then by
    :func:`spatial_order_numpy`, which gives the same arrays."""
    if (KERNELS.workers.get("_first_use_rank") is not None
            and "_first_use_rank" not in KERNELS.ready
            and not KERNELS.is_cached("_first_use_rank")):
        return spatial_order_numpy(V, F)
    V = _in(V, _f8)
    F = _in(F, np.int64).reshape(-1)
    nv = len(V)
    Vout = np.empty((3, nv))
    Fout = np.empty(len(F), np.int32)
    KERNELS.kernel("_first_use_rank")(V, F, True, np.empty(nv, np.int64), Vout, Fout,
                               np.empty(nv, np.int64), np.empty(nv, np.int64),
                               np.empty(max(nv, len(F) // 3), np.int64),
                               np.zeros(nv + 1, np.int64), np.zeros((3, 1025), np.int64))
    return Vout, Fout.reshape(-1, 3)


def spatial_order_numpy(V, F):
    """:func:`spatial_order` in NumPy: the same arrays, from the same Morton codes (the same
    floating-point steps), stable argsorts in place of the kernel's radix and counting sorts,
    and the first use of each vertex from :func:`numpy.unique`.

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> m = trimesh.creation.icosphere(subdivisions=4)
    >>> v, f = spatial_order_numpy(m.vertices, m.faces)
    >>> v.shape == (3, len(m.vertices))
    True
    >>> bool(np.isclose(trimesh.Trimesh(v.T, f).volume, m.volume)), f.dtype.name
    (True, 'int32')
    >>> bool(np.all(np.diff(np.unique(f, return_index=True)[1]) > 0))   # first use order
    True
    """
    V = _in(V, _f8)
    tri = _in(F, np.int64).reshape(-1, 3)
    nv = len(V)
    if nv == 0:
        return np.zeros((3, 0)), tri.astype(np.int32)
    lo, hi = V.min(axis=0), V.max(axis=0)
    x = ((V - lo) / np.maximum(hi - lo, 1e-300) * 1023).astype(np.uint64).astype(np.int64)
    x &= 1023                                   # bits b -> 3 b (the kernel's magic masks)
    x = (x | (x << 16)) & 0x30000FF
    x = (x | (x << 8)) & 0x300F00F
    x = (x | (x << 4)) & 0x30C30C3
    x = (x | (x << 2)) & 0x9249249
    code = x[:, 0] | (x[:, 1] << 1) | (x[:, 2] << 2)
    morton = np.argsort(code, kind="stable")    # the vertices in Morton order
    place = np.empty(nv, np.int64)
    place[morton] = np.arange(nv)
    flat = tri[np.argsort(place[tri].min(axis=1), kind="stable")].reshape(-1)
    seen, first = np.unique(flat, return_index=True)
    unused = np.ones(nv, bool)
    unused[seen] = False
    new = np.concatenate([seen[np.argsort(first)], morton[unused[morton]]])
    rank = np.empty(nv, np.int64)
    rank[new] = np.arange(nv)
    return np.ascontiguousarray(V[new].T), rank[flat].astype(np.int32).reshape(-1, 3)


def project_vertices(V, r0, f, eu, ev, sx, bx, sy, by, perspective, XY, w, huge, nW, nH, K):
    """:func:`_project_vertices` over every vertex (``V`` coordinate-major, ``(3, n)``); returns
    ``(wmin, wmax, odd)`` of them all (the least and largest depth, NaN depths left out:
    ``(inf, -inf)`` when none is left)."""
    if _cold("_project_vertices"):
        return project_vertices_numpy(V, r0, f, eu, ev, sx, bx, sy, by, perspective, XY, w,
                                      huge, nW, nH, K)
    V = _vertices(V)
    view = Projection(_ro(r0, _f8), _ro(f, _f8), _ro(eu, _f8), _ro(ev, _f8), float(sx),
                      float(bx), float(sy), float(by), bool(perspective), int(nW), int(nH))
    parts = _split("_project_vertices", 0, V.shape[1], (V, view, XY, w, huge, K), _MIN_ITEMS)
    kmin, kmax = min(p[0] for p in parts), max(p[1] for p in parts)
    if kmin > kmax:
        return np.inf, -np.inf, any(p[2] for p in parts)
    wmin, wmax = depth_key(np.array([kmin, kmax], np.int64).view(np.float64)).view(np.float64)
    return float(wmin), float(wmax), any(p[2] for p in parts)


def _cold(name) -> bool:
    """Whether kernel ``name`` would be compiled in this process now, on a cold start that
    left it to this process (:meth:`~xray_viz.tracing._compile.KernelSet.prepare`'s share)
    or to a background process still compiling it: then a NumPy twin giving the same bits
    is used (the background process compiles the kernel for the next runs)."""
    return ((name in KERNELS.mine or KERNELS.workers.get(name) is not None)
            and name not in KERNELS.ready and not KERNELS.is_cached(name))


def project_vertices_numpy(V, r0, f, eu, ev, sx, bx, sy, by, perspective, XY, w, huge, nW,
                           nH, K):
    """:func:`project_vertices` in NumPy: the same floating-point operations in the same order
    (no fused multiply-add in either), so the same ``XY``, ``w``, ``huge``, ``K`` and return,
    bit for bit (``tests/tracing/test_cold_start.py`` compares them on the bundled phantoms)."""
    V = _vertices(V)
    r0, f, eu, ev = (np.asarray(a, np.float64) for a in (r0, f, eu, ev))
    sx, bx, sy, by = float(sx), float(bx), float(sy), float(by)
    rx, ry, rz = V[0] - r0[0], V[1] - r0[1], V[2] - r0[2]
    with np.errstate(all="ignore"):
        wi = rx * f[0] + ry * f[1] + rz * f[2]
        a = rx * eu[0] + ry * eu[1] + rz * eu[2]
        b = rx * ev[0] + ry * ev[1] + rz * ev[2]
        if perspective:
            ahead = wi > 0.0
            xs = np.where(ahead, sx * (a / wi) + bx, np.inf)
            ys = np.where(ahead, sy * (b / wi) + by, np.inf)
        else:
            xs = sx * a + bx
            ys = sy * b + by
        ok = (np.abs(xs) < COORD_LIMIT) & (np.abs(ys) < COORD_LIMIT)
        xi = np.floor(np.where(ok, xs, 0.0) * ONE + 0.5).astype(np.int64)
        yi = np.floor(np.where(ok, ys, 0.0) * ONE + 0.5).astype(np.int64)
    w[:] = wi
    XY[:, 0] = xi
    XY[:, 1] = yi
    huge[:] = False
    if nW <= CODE_MAX_SAMPLES and nH <= CODE_MAX_SAMPLES:
        def code(x, n):
            c = 2 * (x >> FRAC_BITS) + ((x & (ONE - 1)) == 0).astype(np.int64) + 2
            c = np.where(x > (n - 1) * ONE, np.int64(2 * n + 2), c)
            return np.where(x < 0, np.int64(0), c)

        K[:] = (code(xi, int(nW)) | (code(yi, int(nH)) << 16)).astype(np.int32)
    else:
        K[:] = NO_CODE
    nan = np.isnan(wi)
    odd = bool(nan.any() or not ok.all())
    bad = np.flatnonzero(~ok)
    if len(bad):
        with np.errstate(all="ignore"):
            for col, c in ((0, xs[bad]), (1, ys[bad])):
                XY[bad, col] = np.where(c == c, (np.clip(c, -COORD_LIMIT, COORD_LIMIT) * ONE)
                                        .astype(np.int64), 0)
        huge[bad] = True
        K[bad] = NO_CODE
    keys = depth_key(wi[~nan])
    if len(keys) == 0:
        return np.inf, -np.inf, odd
    wmin, wmax = depth_key(np.array([keys.min(), keys.max()], np.int64).view(np.float64)).view(
        np.float64)
    return float(wmin), float(wmax), odd


def _band_of(nH, band_height):
    """The band of each of the ``nH`` sample rows (bands of ``band_height`` rows)."""
    return np.arange(max(int(nH), 1), dtype=np.int64) // int(band_height)


def _cull(F, XY, w, huge, perspective, FL, nW, nH, status, box, V, r0, planes, K, depth_ok,
          band_of):
    """:func:`_cull_triangles` over every triangle, one contiguous piece per thread: ``(kept,
    starts, sizes, counts, lists)``, piece c's kept triangles ``kept[starts[c]:starts[c] +
    sizes[c]]``, ``counts[c, b]`` of them in band b (``band_of``: :func:`_band_of`) and its
    band lists ``lists[c]``."""
    if K is None:
        K, depth_ok = np.zeros(0, np.int32), False
    mesh = _projected(F, XY, w, huge, V, K)
    T = mesh.F.shape[0]
    kept = np.empty(T, np.int64)
    cut = _cuts(0, T, _MIN_ITEMS)
    counts = np.empty((len(cut) - 1, int(band_of[-1]) + 1), np.int64)
    cull = Cull(_ro(r0, _f8), _ro(planes, _f8), bool(perspective), float(FL), int(nW), int(nH),
                bool(depth_ok), _ro(band_of, np.int64))
    parts = _split("_cull_triangles", 0, T, (mesh, cull, status, box, kept), cuts=cut,
                   each=lambda j: (counts[j],))
    starts = np.array([a for a, _, _ in parts], np.int64)
    sizes = np.array([n for _, n, _ in parts], np.int64)
    return kept, starts, sizes, counts, [lists for _, _, lists in parts]


def cull_triangles(F, XY, w, huge, perspective, FL, nW, nH, status, box, V, r0, planes, *,
                   K=None, depth_ok=False):
    """:func:`_cull_triangles` over every triangle; returns the triangles of non-zero status
    other than an error, in order (int64). ``K`` and ``depth_ok``: the cell codes and the
    depth check of :func:`project_vertices` (without them, no first pass)."""
    kept, starts, sizes, _, _ = _cull(F, XY, w, huge, perspective, FL, nW, nH, status, box, V,
                                      r0, planes, K, depth_ok, _band_of(nH, max(int(nH), 1)))
    return np.concatenate([kept[a:a + n] for a, n in zip(starts, sizes)])


def cull_and_bin(F, XY, w, huge, perspective, FL, nW, nH, status, box, V, r0, planes,
                 band_height, *, K=None, depth_ok=False):
    """:func:`cull_triangles` and the lists ``(band_start, band_tris)`` of the kept triangles
    whose sample rows ``box[t, 2] .. box[t, 3]`` meet each band of ``band_height`` rows: each
    piece of the cull (one per thread) lists its own triangles by band, and band ``b``'s list
    is ``band_tris[band_start[c, b]:band_start[c, b + 1]]`` over the pieces ``c`` in turn,
    which is triangle order. ``band_tris`` holds triangle indices (uint32, as :func:`_faces`:
    fewer than 2**31 triangles). Not meaningful if a status is an error (the caller refuses
    the scene). Too many triangles are refused by :func:`_faces`.

    Examples
    --------
    >>> import numpy as np
    >>> start = np.array([[0, 2, 3], [3, 3, 5]])          # 2 pieces, 2 bands
    >>> tris = np.array([4, 7, 7, 90, 91])
    >>> [[int(t) for c in range(2) for t in tris[start[c, b]:start[c, b + 1]]] for b in range(2)]
    [[4, 7], [7, 90, 91]]
    """
    band_of = _band_of(nH, band_height)
    _, _, _, counts, lists = _cull(F, XY, w, huge, perspective, FL, nW, nH, status, box, V, r0,
                                   planes, K, depth_ok, band_of)
    band_start = np.zeros((len(lists), counts.shape[1] + 1), np.int64)
    np.cumsum(counts, axis=1, out=band_start[:, 1:])
    band_start += np.cumsum([0] + [len(t) for t in lists[:-1]])[:, None]
    tris = lists[0] if len(lists) == 1 else np.concatenate(lists)
    return band_start, tris


def _ro(a, dtype):
    """``a`` as a read-only C-contiguous array of ``dtype`` (a view: no copy when it already
    is one), for the fields of a named tuple typed read-only (:data:`TUPLES`)."""
    a = np.ascontiguousarray(a, dtype=dtype).view()
    a.flags.writeable = False
    return a


def _band_inputs(order, band_start, band_tris, band_height, nH, nW, status, box, F, XY, V, w,
                 r0, f, tri_body, FL, perspective, P00, Ex, Ey):
    """The :class:`Bands`, :class:`Triangles` and :class:`Frame` of :func:`_raster_bands`."""
    bands = Bands(_ro(order, np.int64), _ro(band_start, np.int64), _ro(band_tris, np.uint32),
                  int(band_height), int(nH), int(nW))
    tris = Triangles(_ro(status, np.int8), _ro(box, np.int64), _ro(_faces(F, 0), np.uint32),
                     _ro(XY, np.int64), _ro(_vertices(V), _f8), _ro(w, _f8),
                     _ro(tri_body, np.int32))
    return bands, tris, _frame(r0, f, FL, perspective, P00, Ex, Ey)


def _projected(F, XY, w, huge, V, K):
    """The :class:`Projected` of these arrays, read-only (numba converts no named tuple)."""
    V = _vertices(V)
    return Projected(_ro(_faces(F, V.shape[1]), np.uint32), _ro(XY, np.int64), _ro(w, _f8),
                     _ro(huge, np.bool_), _ro(V, _f8), _ro(K, np.int32))


def _grid(FL, perspective, P00, Ex, Ey):
    """The :class:`Grid` of these values, arrays read-only (numba converts no named tuple)."""
    return Grid(float(FL), bool(perspective), _ro(P00, _f8), _ro(Ex, _f8), _ro(Ey, _f8))


def _frame(r0, f, FL, perspective, P00, Ex, Ey):
    """The :class:`Frame` of the source ``r0``, a parallel beam's ``f`` and the grid."""
    return Frame(_ro(r0, _f8), _ro(f, _f8), _grid(FL, perspective, P00, Ex, Ey))


def _claimed(bands, tris, frame, single, sums, sweep):
    """:func:`_raster_bands` on the library's threads (:func:`_threads`, at most one per
    band), which take the bands ``bands.order`` in turn from one shared counter."""
    from xray_viz._threads import run_pieces

    kernel = KERNELS.kernel("_raster_bands")
    n = len(bands.order)
    claim = np.zeros(1, np.int64)
    run_pieces(lambda j: kernel(0, n, bands, tris, frame, single, sums, sweep, claim),
               max(1, min(_threads(), n)))


#: The output :func:`_raster_bands` does not write (a one-body raster's sweep, a several-body
#: raster's sums).
_NO_SUMS = DepthSums(np.zeros((1, 1)), np.zeros((1, 1), np.int32), 0)
_NO_SWEEP = Sweep(_ro(np.zeros(1, np.int64), np.int64), _ro(np.zeros(1, np.int64), np.int64),
                  Rays(np.zeros((1, 1)), 0, 1, 1, 1))


def raster_single(order, band_start, band_tris, band_height, nH, nW, status, box, F, XY, V, w,
                  r0, f, tri_body, FL, perspective, P00, Ex, Ey, S, N, row0):
    """:func:`_raster_bands` of one body into the window ``S``, ``N`` of rows ``row0 ..``
    (:class:`DepthSums`), over the library's threads."""
    inputs = _band_inputs(order, band_start, band_tris, band_height, nH, nW, status, box, F,
                          XY, V, w, r0, f, tri_body, FL, perspective, P00, Ex, Ey)
    _claimed(*inputs, True, DepthSums(S, N, int(row0)), _NO_SWEEP)


def raster_multi(order, band_start, band_tris, band_height, nH, nW, status, box, F, XY, V, w,
                 r0, f, tri_body, FL, precedence, perspective, P00, Ex, Ey, n, W, H, L, ray0):
    """:func:`_raster_bands` of several bodies into the path lengths ``L`` of the rays
    ``ray0 ..`` (:class:`Sweep`), over the library's threads."""
    inputs = _band_inputs(order, band_start, band_tris, band_height, nH, nW, status, box, F,
                          XY, V, w, r0, f, tri_body, FL, perspective, P00, Ex, Ey)
    rank, by_rank = body_ranks(precedence)
    _claimed(*inputs, False, _NO_SUMS,
             Sweep(_ro(rank, np.int64), _ro(by_rank, np.int64),
                   Rays(L, int(ray0), int(n), int(W), int(H))))


#: The crossing counts of depth sums that need none (:func:`_raster_direct`'s).
_NO_COUNTS = np.zeros((0, 1, 1), np.int32)


def finish(S, Lf, single, FL, perspective, P00, Ex, Ey, n, W, H, L, y0, y1, s_row0, ray0):
    """:func:`~xray_viz.tracing._raster._finish` of the depth sums ``S`` (one body) or the
    lengths ``Lf`` (several): the fine rows ``y0 .. y1 - 1`` into the rays ``L`` from ``ray0``."""
    _finish_rows(_in(S, _f8)[None], _NO_COUNTS, Lf, single, FL, perspective,
                 P00, Ex, Ey, n, W, H, L, y0, y1, s_row0, ray0)


def finish_chunks(S, FL, perspective, P00, Ex, Ey, n, W, H, L, y0, y1, ray0):
    """:func:`finish` of one body from the per-thread accumulators ``S`` of
    :func:`raster_direct` (summed as :func:`reduce_chunks` does, without storing the sum)."""
    _finish_rows(_in(S, _f8), _NO_COUNTS, np.zeros((1, 1, 1)), True, FL, perspective,
                 P00, Ex, Ey, n, W, H, L, y0, y1, 0, ray0)


def _finish_rows(S, N, Lf, single, FL, perspective, P00, Ex, Ey, n, W, H, L, y0, y1, s_row0,
                 ray0):
    """:func:`_finish` of the fine rows ``y0 .. y1 - 1``, split over the threads."""
    _split("_finish", int(y0), int(y1),
           (S, N, _in(Lf, _f8), bool(single), _grid(FL, perspective, P00, Ex, Ey),
            Rays(L, int(ray0), int(n), int(W), int(H)), int(s_row0)), _MIN_ROWS)


def raster_direct(n_chunks, F, XY, w, huge, V, perspective, r0, P00, Ex, Ey, f, FL, nW, nH,
                  depth_ok, S, err, K, planes):
    """:func:`_raster_direct` over the ``n_chunks`` pieces of the triangles, split over the
    threads (:class:`Projected`, :class:`Frame`)."""
    mesh = _projected(F, XY, w, huge, V, K)
    _split("_raster_direct", 0, int(n_chunks),
           (int(n_chunks), mesh, _frame(r0, f, FL, perspective, P00, Ex, Ey), int(nW), int(nH),
            bool(depth_ok), _in(planes, _f8), S, err))


def reduce_chunks(S, N, FL, out):
    """``out = sum_c S[c] (+ N[c] * FL)``: ``N`` None for :func:`raster_direct`'s sums."""
    N = _NO_COUNTS if N is None else _in(N, np.int32)
    _split("_reduce_chunks", 0, S.shape[1], (_in(S, _f8), N, float(FL), out), _MIN_ROWS)
