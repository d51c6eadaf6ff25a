"""Property-based tests (hypothesis): random scenes against exact chords and engine against engine.

Every scene is built from *convex* pieces - convex hulls of random points, boxes, icospheres,
ellipsoids (scaled icospheres) - under random rigid transforms and scales. A body is one mesh of
one or several pieces: overlapping pieces give their union (the nonzero winding rule), a
scaled-down inward copy inside a piece carves a cavity, and a separate body can sit inside a
piece of another (innermost wins). Because every piece is convex, the exact length of any ray
inside it is found by clipping the ray against the planes of its faces (Cyrus-Beck), with no
ray tracing at all; the union, the cavities and the bodies' precedence then follow from the
sorted interval ends. That reference is independent of both engines.

The properties:

* the fast engine equals the NumPy engine (path lengths, line integrals, intensities);
* every path length is >= 0 and, without noise, I <= I0 in every pixel, for monochromatic,
  tabulated and tube spectra, constant ``mu`` and xraylib materials;
* path lengths equal the exact chords: per body (with the scene's precedence) and in total (the
  union of everything, whatever the precedence);
* an icosphere / ellipsoid lies between its inscribed and circumscribed ellipsoids' chords, a
  rotated box gives the slab-method chord, nested boxes give the inner material where nested,
  the pieces of a union of boxes give the union of their slab intervals.

Not generated: a *single-piece* mesh that passes through itself (a known limitation of the
fast engine's one-body shortcut, under repair), and sources inside bodies (the Scene refuses
them): every body lies within ~210 mm of the centre of the scene's bounding box, and the
source is 300-2000 mm from it.

Budget: the default hypothesis profile (``tests/conftest.py``) is derandomized and bounded so
that this file takes well under a minute; ``HYPOTHESIS_PROFILE=slow`` runs many more examples
of every test, and the tests marked ``slow`` (``-m slow``) add long runs on larger detectors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, assume, given, note, settings
from hypothesis import strategies as st

import xray_viz
from xray_viz.geometry import detector_rays
from xray_viz.physics.spectra import Spectrum
from xray_viz.scene import Body, Detector, Scene, Source
from helpers import box_chord, ellipsoid_chord, icosphere_radii, random_rotation

#: Examples per test in the active profile (``HYPOTHESIS_PROFILE``; see tests/conftest.py).
EXAMPLES = settings().max_examples

#: Agreement asked for, relative to the size of the scene (mm): both engines are float64
#: throughout; the exact chords are float64 plane clipping.
RTOL = 1e-9


def _examples(fraction: float) -> int:
    return max(2, int(round(EXAMPLES * fraction)))


def _slow(**kw):
    """Settings of the ``-m slow`` long runs: many examples, randomised."""
    return settings(max_examples=400, deadline=None, derandomize=False,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
                    **kw)


# --------------------------------------------------------------------------------------------
# scene descriptions (plain data: a failing example prints as code that rebuilds it)

PIECE_KINDS = ("hull", "box", "icosphere", "ellipsoid")


@dataclass(frozen=True)
class Piece:
    """One convex piece: ``kind`` of about ``size`` mm, shaped and turned by ``seed``,
    centred at ``offset`` from its body's centre. ``detail``: hull points or icosphere
    subdivisions. ``hollow`` > 0: an inward copy scaled by that factor carves a cavity."""

    kind: str
    seed: int
    size: float
    offset: tuple
    detail: int
    hollow: float = 0.0


@dataclass(frozen=True)
class BodySpec:
    """A body: the union of ``pieces`` (one mesh), or, with ``inside = (body, piece, factor)``,
    a copy of that piece of an earlier body scaled down about its centroid (a nested body)."""

    pieces: tuple = ()
    inside: tuple | None = None
    mu: float = 0.2


@dataclass(frozen=True)
class Camera:
    kind: str                 # "point" or "parallel"
    direction: tuple          # beam direction (normalised when used)
    source_distance: float    # mm from the origin, against the beam
    detector_distance: float  # mm from the origin, along the beam (may cut through bodies)
    up: tuple
    shape: tuple              # (W, H)
    coverage: float           # detector width / projected scene width
    aspect: float             # pitch_v / pitch_u
    supersample: int


@dataclass(frozen=True)
class SceneSpec:
    bodies: tuple
    camera: Camera
    rotation_seed: int        # the rigid transform applied to the whole scene
    scale: float
    shift: tuple


# --------------------------------------------------------------------------------------------
# strategies

def _vector(lo, hi):
    return st.tuples(*(st.floats(lo, hi, allow_nan=False, allow_infinity=False),) * 3)


@st.composite
def pieces(draw, *, kinds=PIECE_KINDS, hollow=True, max_offset=20.0):
    kind = draw(st.sampled_from(kinds))
    detail = draw(st.integers(4, 30)) if kind == "hull" else (
        draw(st.integers(1, 2)) if kind in ("icosphere", "ellipsoid") else 0)
    return Piece(kind=kind, seed=draw(st.integers(0, 2**32 - 1)), size=draw(st.floats(5.0, 40.0)),
                 offset=draw(_vector(-max_offset, max_offset)), detail=detail,
                 hollow=draw(st.sampled_from([0.0, 0.0, 0.0, 0.45, 0.9])) if hollow else 0.0)


@st.composite
def cameras(draw, *, kinds=("point", "parallel"), max_shape=(48, 40), supersample=(1, 2),
            cut=True):
    """A camera looking along a random direction with a random detector roll and ``up``
    tilted up to 80 degrees towards the beam (never parallel to it). ``cut``: the detector
    may pass through the bodies (else it is at least 150 mm beyond their centre)."""
    z, phi = draw(st.floats(-1.0, 1.0)), draw(st.floats(0.0, 2 * np.pi))
    d = np.array([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
    e1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    roll, tilt = draw(st.floats(0.0, 2 * np.pi)), draw(st.floats(-1.4, 1.4))
    up = np.cos(tilt) * (np.cos(roll) * e1 + np.sin(roll) * e2) + np.sin(tilt) * d
    return Camera(
        kind=draw(st.sampled_from(kinds)), direction=tuple(d.tolist()),
        source_distance=draw(st.floats(300.0, 2000.0)),
        detector_distance=draw(st.one_of(st.floats(150.0, 800.0), st.floats(0.0, 150.0))
                               if cut else st.floats(150.0, 800.0)),
        up=tuple(up.tolist()),
        shape=(draw(st.integers(16, max_shape[0])), draw(st.integers(12, max_shape[1]))),
        coverage=draw(st.floats(0.3, 1.3)), aspect=draw(st.floats(0.7, 1.4)),
        supersample=draw(st.integers(*supersample)),
    )


@st.composite
def scene_specs(draw, *, max_bodies=3, max_pieces=3, nested=True, kinds=PIECE_KINDS,
                camera=None):
    n = draw(st.integers(1, max_bodies))
    bodies = []
    for _ in range(n):
        k = draw(st.integers(1, max_pieces))
        bodies.append(BodySpec(pieces=tuple(draw(pieces(kinds=kinds)) for _ in range(k)),
                               mu=draw(st.floats(0.0, 0.6))))
    if nested and draw(st.booleans()):
        outer = draw(st.integers(0, n - 1))
        bodies.append(BodySpec(
            inside=(outer, draw(st.integers(0, len(bodies[outer].pieces) - 1)),
                    draw(st.floats(0.5, 0.85))),   # never a cavity's 0.45 or 0.9
            mu=draw(st.floats(0.0, 1.0))))
    return SceneSpec(bodies=tuple(bodies), camera=draw(cameras() if camera is None else camera),
                     rotation_seed=draw(st.integers(0, 2**32 - 1)),
                     scale=draw(st.floats(0.5, 1.5)), shift=draw(_vector(-30.0, 30.0)))


# --------------------------------------------------------------------------------------------
# building scenes

def _flat(mesh) -> bool:
    """A degenerate (nearly flat) convex piece, whose chords would be ill-conditioned."""
    diag = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    return not mesh.volume > 2e-3 * diag ** 3


def piece_mesh(p: Piece) -> trimesh.Trimesh:
    """The outward mesh of a piece, in its body's frame."""
    rng = np.random.default_rng(p.seed)
    half = p.size / 2
    if p.kind == "hull":
        axes = half * rng.uniform(0.4, 1.0, 3)
        points = rng.uniform(-1, 1, (p.detail, 3)) * axes
        mesh = trimesh.convex.convex_hull(points)
    elif p.kind == "box":
        mesh = trimesh.creation.box(extents=p.size * rng.uniform(0.3, 1.0, 3))
    elif p.kind == "icosphere":
        mesh = trimesh.creation.icosphere(subdivisions=p.detail, radius=half)
    elif p.kind == "ellipsoid":
        mesh = trimesh.creation.icosphere(subdivisions=p.detail, radius=1.0)
        mesh = trimesh.Trimesh(mesh.vertices * (half * rng.uniform(0.3, 1.0, 3)), mesh.faces,
                               process=False)
    else:
        raise ValueError(p.kind)
    m = np.eye(4)
    m[:3, :3] = random_rotation(rng)
    m[:3, 3] = p.offset
    mesh.apply_transform(m)
    return mesh


def _scaled_about_centroid(vertices, factor):
    c = vertices.mean(axis=0)          # interior for a convex piece (not degenerate)
    return c + factor * (vertices - c)


def aim(camera: Camera, vertices, **detector_kw):
    """``(source position, Detector)`` of ``camera`` aimed at the centre of the bounding box of
    ``vertices``; the detector spans ``coverage`` times the projected bounding sphere."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    c = (lo + hi) / 2
    radius = float(np.linalg.norm(vertices - c, axis=1).max())
    d = np.asarray(camera.direction, float)
    d /= np.linalg.norm(d)
    mag = 1.0 if camera.kind == "parallel" else (
        (camera.source_distance + camera.detector_distance) / (camera.source_distance - radius))
    w, _ = camera.shape
    pitch_u = camera.coverage * 2 * radius * mag / (w - 1)
    detector = Detector(center=c + camera.detector_distance * d, up=camera.up, shape=camera.shape,
                        pitch=(pitch_u, pitch_u * camera.aspect),
                        supersample=camera.supersample, **detector_kw)
    return c - camera.source_distance * d, detector


@dataclass
class Built:
    """A scene and, per body, its convex pieces ``(vertices, faces, sign)`` (sign -1: cavity)
    as given to the engines (after the scene's transform), for the exact reference."""

    scene: Scene
    pieces: list
    size: float                       # bounding diameter of everything, mm


def build(spec: SceneSpec, *, source_kw=None, detector_kw=None, materials=None) -> Built:
    """Build a :class:`Scene` from a description (``assume``-s away degenerate pieces)."""
    rng = np.random.default_rng(spec.rotation_seed)
    g = np.eye(4)
    g[:3, :3] = spec.scale * random_rotation(rng)
    g[:3, 3] = spec.shift
    convex = []                                          # per body: [(verts, faces, sign)]
    local = []                                           # per body: outward piece vertices
    for b in spec.bodies:
        if b.inside is not None:
            outer, k, factor = b.inside
            v, f = local[outer][k]
            parts = [(_scaled_about_centroid(v, factor), f, 1)]
            local.append([(parts[0][0], f)])
        else:
            parts, mine = [], []
            for p in b.pieces:
                mesh = piece_mesh(p)
                assume(not _flat(mesh))
                v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
                parts.append((v, f, 1))
                mine.append((v, f))
                if p.hollow:
                    parts.append((_scaled_about_centroid(v, p.hollow), f[:, ::-1], -1))
            local.append(mine)
        convex.append([(v @ g[:3, :3].T + g[:3, 3], f, s) for v, f, s in parts])
    bodies = []
    for i, (b, parts) in enumerate(zip(spec.bodies, convex)):
        verts, faces, offset = [], [], 0
        for v, f, _ in parts:
            verts.append(v)
            faces.append(f + offset)
            offset += len(v)
        mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
        kw = {"mu": b.mu} if materials is None else materials(i)
        bodies.append(Body(name=f"b{i}", mesh=mesh, **kw))
    allv = np.concatenate([v for parts in convex for v, _, _ in parts])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    size = float(np.linalg.norm(hi - lo))
    source, detector = aim(spec.camera, allv, **(detector_kw or {}))
    scene = Scene(source=Source(position=source, kind=spec.camera.kind, **(source_kw or {})),
                  detector=detector, bodies=tuple(bodies))
    return Built(scene=scene, pieces=convex, size=size)


# --------------------------------------------------------------------------------------------
# the exact reference

def convex_interval(vertices, faces, origins, directions):
    """``(t_in, t_out)`` of each ray ``o + t d`` (``d`` unit) inside a closed convex outward
    mesh, by clipping the line against the plane of every face (empty: ``t_out <= t_in``).
    Only rays passing within the mesh's bounding sphere are clipped (the others miss it)."""
    t_in, t_out = np.zeros(len(origins)), np.zeros(len(origins))
    c = vertices.mean(axis=0)
    r = np.linalg.norm(vertices - c, axis=1).max()
    rel = c - origins
    along = np.einsum("ij,ij->i", rel, directions)
    near = np.einsum("ij,ij->i", rel, rel) - along ** 2 <= (1.0 + 1e-6) * r * r
    o, d = origins[near], directions[near]
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])   # outward
    n /= np.linalg.norm(n, axis=1)[:, None]
    rhs = np.einsum("ij,ij->i", n, tri[:, 0])[None, :] - o @ n.T   # n.(o + t d) <= n.a
    nd = d @ n.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = rhs / nd
    lo = np.where(nd < 0, t, -np.inf).max(axis=1)
    hi = np.where(nd > 0, t, np.inf).min(axis=1)
    outside = np.any((nd == 0) & (rhs < 0), axis=1)
    t_in[near] = np.where(outside, 0.0, lo)
    t_out[near] = np.where(outside, 0.0, hi)
    return t_in, t_out


def exact_lengths(built: Built, rays):
    """(n_rays, n_bodies) exact effective path lengths and (n_rays,) exact union length.

    Interval ends of every convex piece along every ray, clipped to ``[0, t_max]`` and sorted;
    on each elementary segment a body's winding number is the signed count of its pieces
    containing it, the body contains the segment when that is > 0 (nonzero rule), and the
    body of highest ``scene.precedence`` among those containing it gets the segment.
    """
    o, d, t_max = rays.origins, rays.directions, rays.t_max
    spans, owner = [], []
    for b, parts in enumerate(built.pieces):
        for v, f, sign in parts:
            faces = f if sign > 0 else f[:, ::-1]            # a cavity: its outward twin
            t_in, t_out = convex_interval(v, faces, o, d)
            t_in, t_out = np.maximum(t_in, 0.0), np.minimum(t_out, t_max)
            empty = t_out <= t_in
            spans.append((np.where(empty, 0.0, t_in), np.where(empty, 0.0, t_out)))
            owner.append((b, sign))
    ends = np.sort(np.concatenate([np.stack(s, axis=1) for s in spans], axis=1), axis=1)
    mid = 0.5 * (ends[:, 1:] + ends[:, :-1])
    seg = np.diff(ends, axis=1)
    n_bodies = len(built.pieces)
    winding = np.zeros((n_bodies,) + mid.shape, np.int64)
    for (t_in, t_out), (b, sign) in zip(spans, owner):
        winding[b] += sign * ((t_in[:, None] < mid) & (mid < t_out[:, None]))
    contains = winding > 0
    rank = np.asarray(built.scene.precedence)
    score = np.where(contains, rank[:, None, None] + 1, 0)
    winner = np.argmax(score, axis=0)
    any_body = contains.any(axis=0)
    L = np.stack([np.sum(seg * (any_body & (winner == b)), axis=1) for b in range(n_bodies)],
                 axis=1)
    return L, np.sum(seg * any_body, axis=1)


def pixel_mean(values, scene):
    """Average per-ray values over each pixel's sub-rays: ``(H, W, ...)`` as in a Radiograph."""
    w, h = scene.detector.shape
    n = scene.detector.supersample
    values = np.asarray(values)
    return values.reshape((h * w, n * n) + values.shape[1:]).mean(axis=1).reshape(
        (h, w) + values.shape[1:])


def _render_both(scene):
    return xray_viz.render(scene, engine="fast"), xray_viz.render(scene, engine="numpy")


def _assert_physical(image, *, exact_bound=True):
    """Path lengths >= 0, 0 < I <= I0 (exactly, or to rounding when ``exact_bound`` is False:
    a polychromatic weighted sum, a blur or the fall-off of ``I0`` can land one ulp above it)."""
    i0 = image.scene.detector.i0
    assert np.all(image.path_length >= 0), image.path_length.min()
    assert np.all(np.isfinite(image.intensity)) and np.all(image.intensity > 0)
    bound = i0 if exact_bound else i0 * (1 + 1e-12)
    assert np.all(image.intensity <= bound), (image.intensity.max() - i0) / i0
    assert np.all(np.isfinite(image.line_integral))


# --------------------------------------------------------------------------------------------
# the properties

@settings(max_examples=_examples(1.0), deadline=None)
@given(spec=scene_specs())
def test_fast_engine_equals_numpy_engine(spec):
    built = build(spec)
    note(f"size {built.size:.3g} mm, precedence {built.scene.precedence.tolist()}")
    fast, ref = _render_both(built.scene)
    _assert_physical(fast)
    _assert_physical(ref)
    tol = RTOL * built.size
    np.testing.assert_allclose(fast.path_length, ref.path_length, rtol=0, atol=tol)
    mu = max(b.mu for b in built.scene.bodies)
    np.testing.assert_allclose(fast.line_integral, ref.line_integral, rtol=0,
                               atol=tol * mu / 10 + 1e-15)
    np.testing.assert_allclose(fast.intensity, ref.intensity, rtol=tol * mu / 10 + 1e-15)


@settings(max_examples=_examples(1.0), deadline=None)
@given(spec=scene_specs())
def test_path_lengths_equal_the_exact_chords_of_the_convex_pieces(spec):
    built = build(spec)
    scene = built.scene
    rays = detector_rays(scene, supersample=scene.detector.supersample)
    L, union = exact_lengths(built, rays)
    expected, total = pixel_mean(L, scene), pixel_mean(union, scene)
    tol = RTOL * built.size
    for engine in ("fast", "numpy"):
        image = xray_viz.render(scene, engine=engine)
        # the union of everything, whatever the precedence: exact
        np.testing.assert_allclose(image.total_path_length, total, rtol=0, atol=tol,
                                   err_msg=f"{engine}: total path length != union chord")
        np.testing.assert_allclose(image.path_length, expected, rtol=0, atol=tol,
                                   err_msg=f"{engine}: per-body path length != exact")


SPECTRA = st.one_of(
    st.floats(15.0, 150.0).map(lambda e: {"energy": e}),
    st.lists(st.floats(0.0, 1.0), min_size=2, max_size=12).filter(lambda w: sum(w) > 0).flatmap(
        lambda w: st.floats(12.0, 40.0).map(lambda e0: {"energy": None, "spectrum": Spectrum(
            e0 + 10.0 * np.arange(len(w)), np.asarray(w))})),
    st.sampled_from([{"energy": None, "spectrum": {"kvp": kvp, "filters": f}}
                     for kvp in (50.0, 90.0) for f in ({}, {"Al": 2.5})]),
)

MATERIALS = st.sampled_from([None, {"material": "Water, Liquid"}, {"material": "Bone, Cortical (ICRP)"},
                             {"material": "Al", "density": 2.699}])


@settings(max_examples=_examples(1.0), deadline=None)
@given(spec=scene_specs(max_bodies=2, max_pieces=2), beam=SPECTRA,
       materials=st.lists(MATERIALS, min_size=3, max_size=3),
       response=st.sampled_from(["energy", "counting"]), i0=st.floats(1.0, 1e6),
       falloff=st.booleans(), focal_spot=st.sampled_from([0.0, 0.0, 0.3, 1.2]))
def test_lengths_nonnegative_and_intensity_at_most_i0(spec, beam, materials, response, i0,
                                                      falloff, focal_spot):
    mus = [b.mu for b in spec.bodies]

    def material(i):
        given = materials[i % len(materials)]
        return {"mu": mus[i]} if given is None else given

    built = build(spec, source_kw=beam, materials=material,
                  detector_kw=dict(response=response, i0=i0, falloff=falloff,
                                   focal_spot=focal_spot))
    fast, ref = _render_both(built.scene)
    mono = beam.get("spectrum") is None
    for image in (fast, ref):
        # the fall-off divides by the pixel's distance three times and multiplies by SID^3 in
        # place: on the beam axis (distance SID) that can round one ulp above I0
        _assert_physical(image, exact_bound=mono and focal_spot == 0 and not falloff)
    tol = RTOL * built.size
    np.testing.assert_allclose(fast.path_length, ref.path_length, rtol=0, atol=tol)
    # the line integral is >= 0 wherever the beam is unblurred (no focal spot): I <= I0 F
    if focal_spot == 0:
        assert np.all(fast.line_integral >= (0 if mono else -1e-12))


# --- shapes with analytic chords --------------------------------------------------------------

def _camera_scene(mesh, camera: Camera, *, mu=0.2, extra=()):
    """A scene of one mesh (plus ``extra`` bodies) seen by ``camera`` (built as in build())."""
    meshes = [mesh, *extra]
    source, detector = aim(camera, np.concatenate([np.asarray(m.vertices) for m in meshes]))
    mus = np.broadcast_to(mu, (len(meshes),))
    return Scene(source=Source(position=source, kind=camera.kind), detector=detector,
                 bodies=tuple(Body(name=f"b{i}", mesh=m, mu=float(u))
                              for i, (m, u) in enumerate(zip(meshes, mus))))


def _pose(seed, *, shift=30.0):
    rng = np.random.default_rng(seed)
    m = np.eye(4)
    m[:3, :3] = random_rotation(rng)
    m[:3, 3] = rng.uniform(-shift, shift, 3)
    return m


def _in_frame(rays, pose):
    """Ray origins and directions in the frame of ``pose`` (rigid: lengths unchanged)."""
    r, t = pose[:3, :3], pose[:3, 3]
    return (rays.origins - t) @ r, rays.directions @ r


@settings(max_examples=_examples(1.5), deadline=None)
@given(radius=st.floats(5.0, 60.0), subdivisions=st.integers(1, 3),
       axes=st.tuples(*(st.floats(0.3, 1.0),) * 3) | st.just((1.0, 1.0, 1.0)),
       seed=st.integers(0, 2**32 - 1), camera=cameras(cut=False))
def test_icosphere_and_ellipsoid_chords_between_inscribed_and_circumscribed(
        radius, subdivisions, axes, seed, camera):
    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    r_in, r_out = icosphere_radii(ico)
    pose = _pose(seed)
    a = pose[:3, :3] @ np.diag(axes)                       # the ellipsoid {c + A x : |x| <= 1}
    mesh = trimesh.Trimesh(ico.vertices @ a.T + pose[:3, 3], ico.faces, process=False)
    scene = _camera_scene(mesh, camera)
    rays = detector_rays(scene, supersample=camera.supersample)
    # chords are computed per sub-ray; the bounds hold per sub-ray, hence for their mean
    inner = pixel_mean(ellipsoid_chord(rays.origins, rays.directions, pose[:3, 3], a * r_in),
                       scene)
    outer = pixel_mean(ellipsoid_chord(rays.origins, rays.directions, pose[:3, 3], a * r_out),
                       scene)
    tol = RTOL * radius
    for image in _render_both(scene):
        L = image.total_path_length
        assert np.all(L >= inner - tol), (inner - L).max()
        assert np.all(L <= outer + tol), (L - outer).max()


@settings(max_examples=_examples(1.5), deadline=None)
@given(extents=st.tuples(*(st.floats(2.0, 80.0),) * 3), seed=st.integers(0, 2**32 - 1),
       camera=cameras())
def test_rotated_box_chords_equal_the_slab_method(extents, seed, camera):
    pose = _pose(seed)
    box = trimesh.creation.box(extents=extents, transform=pose)
    scene = _camera_scene(box, camera)
    rays = detector_rays(scene, supersample=camera.supersample)
    o, d = _in_frame(rays, pose)
    half = np.asarray(extents) / 2
    chord = pixel_mean(box_chord(o, d, -half, half, rays.t_max)[0], scene)
    for image in _render_both(scene):
        np.testing.assert_allclose(image.total_path_length, chord, rtol=0,
                                   atol=RTOL * np.linalg.norm(extents), err_msg=image.engine)


@settings(max_examples=_examples(1.5), deadline=None)
@given(extents=st.tuples(*(st.floats(5.0, 80.0),) * 3), factor=st.floats(0.2, 0.9),
       where=st.tuples(*(st.floats(-1.0, 1.0),) * 3), seed=st.integers(0, 2**32 - 1),
       inner_first=st.booleans(), camera=cameras())
def test_nested_boxes_give_the_inner_material_where_nested(extents, factor, where, seed,
                                                           inner_first, camera):
    pose = _pose(seed)
    half = np.asarray(extents) / 2
    inner_half = factor * half
    centre = np.asarray(where) * (half - inner_half) * 0.95   # wholly inside the outer box
    outer = trimesh.creation.box(extents=extents, transform=pose)
    shift = np.eye(4)
    shift[:3, 3] = centre
    inner = trimesh.creation.box(extents=2 * inner_half, transform=pose @ shift)
    meshes, mus = ([inner, outer], [0.9, 0.2]) if inner_first else ([outer, inner], [0.2, 0.9])
    scene = _camera_scene(meshes[0], camera, mu=mus, extra=meshes[1:])
    k_in, k_out = (0, 1) if inner_first else (1, 0)
    assert scene.precedence[k_in] > scene.precedence[k_out]     # innermost wins
    rays = detector_rays(scene, supersample=camera.supersample)
    o, d = _in_frame(rays, pose)
    c_out = box_chord(o, d, -half, half, rays.t_max)[0]
    c_in = box_chord(o, d, centre - inner_half, centre + inner_half, rays.t_max)[0]
    tol = RTOL * np.linalg.norm(extents)
    for image in _render_both(scene):
        np.testing.assert_allclose(image.path_length[..., k_in], pixel_mean(c_in, scene),
                                   rtol=0, atol=tol, err_msg=image.engine)
        np.testing.assert_allclose(image.path_length[..., k_out],
                                   pixel_mean(c_out - c_in, scene), rtol=0, atol=tol,
                                   err_msg=image.engine)


def _interval_union(t_in, t_out):
    """Total length of the union of intervals ``[t_in[:, k], t_out[:, k]]`` per row."""
    order = np.argsort(t_in, axis=1)
    lo, hi = np.take_along_axis(t_in, order, 1), np.take_along_axis(t_out, order, 1)
    total, reach = np.zeros(len(lo)), np.full(len(lo), -np.inf)
    for k in range(lo.shape[1]):
        total += np.clip(hi[:, k] - np.maximum(lo[:, k], reach), 0, None)
        reach = np.maximum(reach, hi[:, k])
    return total


@settings(max_examples=_examples(1.5), deadline=None)
@given(boxes=st.lists(st.tuples(st.tuples(*(st.floats(5.0, 60.0),) * 3),
                                _vector(-25.0, 25.0), st.integers(0, 2**32 - 1)),
                      min_size=2, max_size=5),
       nested_copy=st.booleans(), camera=cameras())
def test_union_of_overlapping_boxes_in_one_mesh_is_the_union_chord(boxes, nested_copy, camera):
    poses, parts = [], []
    for extents, offset, seed in boxes:
        pose = _pose(seed, shift=0.0)
        pose[:3, 3] = offset
        poses.append((pose, np.asarray(extents) / 2))
        parts.append(trimesh.creation.box(extents=extents, transform=pose))
    if nested_copy:                              # an outward copy inside a piece changes nothing
        pose, half = poses[0]
        parts.append(trimesh.creation.box(extents=half, transform=pose))
    mesh = trimesh.util.concatenate(parts)
    assert mesh.body_count == len(parts)         # several pieces, none passing through itself
    scene = _camera_scene(mesh, camera)
    rays = detector_rays(scene, supersample=camera.supersample)
    t_in, t_out = [], []
    for pose, half in poses:
        o, d = _in_frame(rays, pose)
        _, tn, tf = box_chord(o, d, -half, half, rays.t_max)
        hit = tf > tn
        t_in.append(np.where(hit, tn, 0.0))
        t_out.append(np.where(hit, tf, 0.0))
    union = pixel_mean(_interval_union(np.stack(t_in, 1), np.stack(t_out, 1)), scene)
    tol = RTOL * 200
    for image in _render_both(scene):
        np.testing.assert_allclose(image.total_path_length, union, rtol=0, atol=tol,
                                   err_msg=image.engine)


# --- long runs (-m slow) ----------------------------------------------------------------------

@pytest.mark.slow
@_slow()
@given(spec=scene_specs(max_bodies=4, max_pieces=4,
                        camera=cameras(max_shape=(96, 80), supersample=(1, 3))))
def test_many_random_scenes_engines_agree_and_match_exact_chords(spec):
    built = build(spec)
    scene = built.scene
    rays = detector_rays(scene, supersample=scene.detector.supersample)
    L, union = exact_lengths(built, rays)
    tol = RTOL * built.size
    fast, ref = _render_both(scene)
    for image in (fast, ref):
        _assert_physical(image)
        np.testing.assert_allclose(image.total_path_length, pixel_mean(union, scene), rtol=0,
                                   atol=tol, err_msg=image.engine)
        np.testing.assert_allclose(image.path_length, pixel_mean(L, scene), rtol=0, atol=tol,
                                   err_msg=image.engine)
    np.testing.assert_allclose(fast.path_length, ref.path_length, rtol=0, atol=tol)
