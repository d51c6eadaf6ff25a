"""Exact derivatives of a radiograph's line integrals with respect to the bodies' poses.

The quantity differentiated is the one :func:`xray_viz.render` writes as
:attr:`~xray_viz.render.Radiograph.line_integral` before the detector model (no noise, blur or
fall-off): per pixel ``-ln(I / I0)``, which for a monochromatic beam is ``sum_b mu_b L_b`` and
for a spectrum ``-ln sum_E w_E exp(-sum_b mu_b(E) L_b)`` (weights of
:func:`~xray_viz.physics.imaging.ray_weights`), averaged over a pixel's supersampled rays in
intensity (:func:`~xray_viz.physics.imaging.pixel_log_mean`).

How a line integral depends on a pose
-------------------------------------
Along a ray ``r(t) = o + t d`` (unit ``d``) the effective path lengths are sums of the
stretches between consecutive hits, each stretch given to the body that wins it
(:func:`xray_viz.attenuation.stretch_materials`: innermost, then later-listed). Moving hit
``i`` by ``dt`` lengthens the stretch before it and shortens the one after it, so

    d ell / d t_i = g(before_i) - g(after_i),       g(b) = d ell / d L_b

(``g = mu_b`` for one energy, ``sum_E p_E mu_b(E)`` with the transmitted share ``p_E`` of bin
``E`` for a spectrum; ``g = 0`` outside every body). This is the precedence rule's own
derivative: the chord of an inner body is taken from the outer one, and a body's hits that
lie inside a body of higher precedence change nothing (the same material on both sides).

A hit on the triangle of normal ``n`` lies on its plane, ``n . (o + t d - v0) = 0``. A rigid
motion of the body with velocity ``tau + omega x (x - c)`` (translation ``tau``, rotation
``omega`` about the world axes through ``c``) moves that plane; to first order

    dt = n . (tau + omega x (p - c)) / (n . d) = [n . tau + omega . ((p - c) x n)] / (n . d)

with ``p`` the hit point: the plane's displacement at the hit, read along the ray. It is the
same as differentiating Moller-Trumbore's ``t = n . (v0 - o) / (n . d)`` with respect to the
three vertices and chaining with their velocities (``tests/registration/test_gradients.py`` checks both
against finite differences). The acquisition's pose (source and detector moved together, a
rigid C-arm) moves every ray instead: the relative motion is the bodies moved the other way.

Two implementations give the same numbers (to ~1e-13 relative, ``tests/registration/test_gradients.py``):
the reference takes every hit with its triangle from the NumPy tracer
(:func:`xray_viz.tracing.hits.trace_rays`) and sweeps them by precedence; the default
``engine="fast"`` runs a numba kernel (``xray_viz._gradient_kernels``) over the fast
engine's path lengths when the moving bodies' bounding boxes are apart from every other
body's and each pixel has one ray (then no other material surrounds their hits), and falls
back to the reference otherwise.
"""

from __future__ import annotations

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["pose_gradient", "acquisition_gradient", "line_integral_gradient", "centroid",
           "pose_matrix", "move_bodies", "nesting", "GradientResult"]


def centroid(body) -> np.ndarray:
    """The centre a body's rotations turn about: the centroid of its volume (mm).

    Parameters
    ----------
    body : Body

    Returns
    -------
    (3,) float

    Examples
    --------
    >>> import trimesh
    >>> from xray_viz.scene import Body
    >>> box = trimesh.creation.box(extents=[2, 2, 2])
    >>> _ = box.apply_translation([1, 2, 3])
    >>> centroid(Body(name="box", mesh=box, mu=1.0)).round(9).tolist()
    [1.0, 2.0, 3.0]
    """
    from xray_viz._gradient_kernels import KERNELS

    v = np.ascontiguousarray(body.mesh.vertices, dtype=np.float64)
    return KERNELS.kernel("volume_centroid")(
        v, np.ascontiguousarray(body.mesh.faces, dtype=np.int64), v.mean(axis=0))


def pose_matrix(params, center) -> np.ndarray:
    """The rigid transform of the six pose parameters about ``center``, as a 4 x 4 matrix.

    ``x -> R (x - c) + c + t`` with ``t = params[:3]`` (mm, world axes) and ``R`` the rotation
    by the vector ``params[3:]`` (radians, axis-angle about the world axes through ``c``): the
    parameters of :func:`pose_gradient`, whose derivatives at zero are ``t`` and
    ``omega x (x - c)``.

    Examples
    --------
    >>> m = pose_matrix([1.0, 0, 0, 0, 0, np.pi / 2], [1.0, 0, 0])
    >>> (m @ [2.0, 0, 0, 1]).round(12).tolist()          # (2,0,0) turns to (1,1,0), then +x
    [2.0, 1.0, 0.0, 1.0]
    """
    from scipy.spatial.transform import Rotation

    p = np.asarray(params, dtype=np.float64)
    c = np.asarray(center, dtype=np.float64)
    r = Rotation.from_rotvec(p[3:6]).as_matrix()
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = c + p[:3] - r @ c
    return m


def move_bodies(scene, transforms: dict):
    """The scene with some bodies moved rigidly (each by its own 4 x 4 transform).

    The bodies keep their checks and precedence (a rigid motion keeps each mesh closed; the
    nesting is assumed kept, as for small pose changes); bodies read from a mesh file get the
    composed placement, so that :meth:`~xray_viz.scene.Scene.to_toml` writes them where they
    now are.

    Parameters
    ----------
    scene : Scene
    transforms : dict
        Body name -> (4, 4) rigid transform.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        An unknown body name.
    """
    import dataclasses

    import trimesh

    from xray_viz.bodies import Bodies
    from xray_viz.scene_file import _compose_placement

    names = scene.body_names
    unknown = [n for n in transforms if n not in names]
    if unknown:
        raise SceneError(f"no body named {unknown[0]!r}; the scene has {', '.join(names)}")
    moved = []
    for body in scene.bodies:
        m = transforms.get(body.name)
        if m is None:
            moved.append(body)
            continue
        m = np.asarray(m, dtype=np.float64)
        # a new mesh of the moved vertices (trimesh's copy and apply_transform also carry
        # and transform every cached array: several times slower for a large mesh)
        mesh = trimesh.Trimesh(vertices=body.vertices @ m[:3, :3].T + m[:3, 3],
                               faces=body.faces, process=False)
        changes = {}
        if body.source_file is not None:
            placement = _compose_placement(body.placement, m)
            changes = {"placement": placement} if placement is not None else \
                {"placement": None, "source_file": None}
        moved.append(dataclasses.replace(body, mesh=mesh, **changes))
    bodies = Bodies(moved, where=scene._where(), check=False, reports=scene.bodies.reports,
                    precedence=scene.bodies.precedence if len(moved) > 1 else None)
    return dataclasses.replace(scene, bodies=bodies)


class GradientResult:
    """The line-integral image and its derivatives from one trace (:func:`line_integral_gradient`).

    Attributes
    ----------
    line_integral : (H, W) float
        ``-ln(I / I0)`` per pixel, as :attr:`xray_viz.render.Radiograph.line_integral` without
        the detector model.
    pose : (n_bodies, 6, H, W) float
        d(line integral)/d(pose) of each body asked for.
    acquisition : (6, H, W) float or None
        d(line integral)/d(pose of the source and detector together), when asked for.
    names : list of str
        The bodies of :attr:`pose`, in order.
    centers : (n_bodies, 3) float
        The centre each body's rotations turn about.
    """

    def __init__(self, line_integral, pose, acquisition, names, centers):
        self.line_integral = line_integral
        self.pose = pose
        self.acquisition = acquisition
        self.names = names
        self.centers = centers


def _body_indices(scene, bodies) -> list[int]:
    names = scene.body_names
    if bodies is None:
        return list(range(len(names)))
    if isinstance(bodies, str):
        bodies = [bodies]
    out = []
    for b in bodies:
        if b not in names:
            raise SceneError(f"no body named {b!r}; the scene has {', '.join(names)}")
        out.append(names.index(b))
    return out


def _per_ray_slopes(L, scene, supersample):
    """Per ray: its line integral ``ell`` and ``g = d ell / d L_b`` (n_rays, n_bodies)."""
    from xray_viz.physics.imaging import MM_PER_CM, body_mu, detector_weights, ray_weights
    from xray_viz.physics.spectra import source_spectrum

    # the bins the detector weighs, as the log-transmission of render keeps them
    spectrum = source_spectrum(scene.source)
    keep = detector_weights(spectrum, scene.detector.response) > 0
    mu = body_mu(scene, spectrum.energies[keep]) / MM_PER_CM           # (K, B) 1/mm
    if len(mu) == 1 and not scene.source.heel:
        ell = L @ mu[0]
        return ell, np.broadcast_to(mu[0], L.shape)
    w = ray_weights(scene, supersample=supersample)                    # (n_rays, K)
    with np.errstate(divide="ignore"):
        a = np.log(w) - L @ mu.T                                      # ln(w_E T_E)
    top = a.max(axis=1, keepdims=True)
    e = np.exp(a - top)
    s = e.sum(axis=1, keepdims=True)
    ell = -(top[:, 0] + np.log(s[:, 0]))
    p = e / s                                                          # share of each bin
    return ell, p @ mu


def _apart(scene, idx) -> bool:
    """Whether the bounding boxes of the bodies ``idx`` meet no other body's box."""
    box = scene.bodies.bounds                                   # (n, 2, 3)
    for b in idx:
        for o in range(len(box)):
            if o != b and np.all(box[b, 0] <= box[o, 1]) and np.all(box[o, 0] <= box[b, 1]):
                return False
    return True


def nesting(scene) -> list[list[int]]:
    """For each body, the bodies it lies wholly inside
    (:func:`xray_viz.meshes.repair.containers`, cached on disk by the meshes' content): what
    :func:`line_integral_gradient` needs to use its kernel on nested bodies. A registration
    computes it once for the input scene (rigid moves that keep the bodies' nesting keep it).
    """
    from xray_viz.meshes.repair import containers

    bodies = scene.bodies
    return containers([b.mesh for b in bodies], bounds=bodies.bounds, reports=bodies.reports)


def _parents(scene, idx, inside):
    """Each body's parent (``{body: the innermost body containing it, or -1}``), or None when
    a body of ``idx`` shares bounding-box space with a body that neither contains it nor lies
    inside it (a partial overlap, or a disjoint body the boxes cannot tell apart)."""
    box = scene.bodies.bounds
    rank = np.asarray(scene.bodies.precedence)
    parents = {}
    for b in idx:
        for o in range(len(box)):
            if o == b or not (np.all(box[b, 0] <= box[o, 1]) and np.all(box[o, 0] <= box[b, 1])):
                continue
            if o not in inside[b] and b not in inside[o]:
                return None
        parents[b] = max(inside[b], key=lambda o: rank[o]) if inside[b] else -1
    return parents


def _fast_gradient(scene, idx, centers, acquisition, center, parents=None, *, projector):
    """:func:`line_integral_gradient` by the numba kernel (one ray per pixel, bodies apart):
    the (compiled) ``projector``'s path lengths give each ray's slopes, the kernel the hits'
    terms."""
    from xray_viz._gradient_kernels import KERNELS, pixel_grid

    acq = scene.acquisition
    w, h = scene.detector.shape
    L = projector.path_lengths(acq, supersample=1)
    ell, g = _per_ray_slopes(np.asarray(L, dtype=np.float64), scene, 1)
    g = np.ascontiguousarray(np.asarray(g, dtype=np.float64).T)       # (bodies, rays)
    # the detector grid from the rays of its first two rows: pixel (col, row) at
    # p00 + col eu + row ev (tilted and offset detectors too)
    rays = acq.rays(supersample=1, rows=(0, 2))
    ends = rays.ends
    p00, eu, ev = ends[0], ends[1] - ends[0], ends[w] - ends[0]
    axes = np.stack([eu, ev], axis=1)
    inv = np.ascontiguousarray(np.linalg.inv(axes.T @ axes))
    parallel = bool(acq.parallel)
    source = np.ascontiguousarray(rays.origins[0], dtype=np.float64)
    direction = np.ascontiguousarray(rays.directions[0], dtype=np.float64)
    pixels = pixel_grid(p00, eu, ev, inv, source, direction, rays.t_max[0], parallel, w, h)
    body_pose_gradient = KERNELS.kernel("body_pose_gradient")

    def one(b, c):
        body = scene.bodies[b]
        out = np.zeros((6, w * h))
        # the material outside the body's surface is its parent's (nested bodies): an entry
        # changes ell by g(parent) - g(b) per mm, an exit by g(b) - g(parent)
        p = -1 if parents is None else parents[b]     # every body asked for has one
        slope = g[b] if p < 0 else np.ascontiguousarray(g[b] - g[p])
        body_pose_gradient(np.ascontiguousarray(body.vertices, dtype=np.float64),
                           np.ascontiguousarray(body.faces, dtype=np.int64),
                           np.ascontiguousarray(c, dtype=np.float64), pixels,
                           np.ascontiguousarray(slope, dtype=np.float64), out)
        return out
    pose = np.zeros((len(idx), 6, w * h))
    for k, b in enumerate(idx):
        pose[k] = one(b, centers[k])
    acq_grad = None
    if acquisition:
        acq_grad = np.zeros((6, w * h))
        for b in range(len(scene.bodies)):
            acq_grad -= one(b, center)
    return GradientResult(
        line_integral=ell.reshape(h, w), pose=pose.reshape(len(idx), 6, h, w),
        acquisition=None if acq_grad is None else acq_grad.reshape(6, h, w),
        names=[scene.body_names[b] for b in idx], centers=centers)


def line_integral_gradient(scene, bodies=None, *, acquisition: bool = False,
                           center=(0.0, 0.0, 0.0), centers=None,
                           supersample: int | None = None,
                           engine: str = "fast", inside=None) -> GradientResult:
    """The line-integral image and its exact pose derivatives, from one trace.

    Parameters
    ----------
    scene : Scene
    bodies : sequence of str, optional
        The moving bodies (default: all), in the order of the result.
    acquisition : bool
        Also the derivative with respect to the acquisition's pose (source and detector moved
        together as one rigid C-arm, rotations about the world axes through ``center``).
    center : (3,) float
        The acquisition's centre of rotation (mm; default the origin, the usual isocentre).
    centers : (n, 3) float, optional
        The centre of each moving body's rotations (default: :func:`centroid`).
    supersample : int, optional
        Rays per pixel along each axis (default: the detector's).
    engine : {"fast", "numpy"}
        ``"fast"``: the numba kernel of ``xray_viz._gradient_kernels`` over the fast
        engine's path lengths where it applies (one ray per pixel; the moving bodies, or
        all of them for ``acquisition``, with bounding boxes apart from every other body's),
        the reference otherwise; ``"numpy"``: the reference, every hit from
        :func:`~xray_viz.tracing.hits.trace_rays` swept by precedence.
    inside : list of list of int, optional
        :func:`nesting` of the scene, when known: with it the kernel also takes bodies that
        lie inside others or contain them (computed here when some boxes meet).

    Returns
    -------
    GradientResult
    """
    from xray_viz.attenuation import path_lengths, stretch_materials
    from xray_viz.physics.imaging import pixel_log_mean
    from xray_viz.tracing.hits import trace_rays

    from xray_viz.tracing.engines import ENGINES, Projector

    if not isinstance(engine, str) or engine not in ENGINES:
        raise SceneError(f"unknown gradient engine {engine!r}; choose one of "
                         f"{', '.join(map(repr, ENGINES))}")
    # a compiled engine may use the numba kernel; the reference (NumPy) engine never does
    projector = Projector(scene.bodies, engine)
    kernel = projector.compiled
    idx = _body_indices(scene, bodies)
    n = int(supersample or scene.detector.supersample)
    nn = n * n
    w, h = scene.detector.shape
    if centers is None:
        centers = np.array([centroid(scene.bodies[b]) for b in idx]).reshape(-1, 3)
    else:
        centers = np.asarray(centers, dtype=np.float64).reshape(len(idx), 3)
    if kernel and nn == 1 and w > 1 and h > 1:
        every = list(range(len(scene.bodies)))
        if _apart(scene, every if acquisition else idx):
            return _fast_gradient(scene, idx, centers, acquisition, center,
                                  projector=projector)
        parents = _parents(scene, every if acquisition else idx,
                           nesting(scene) if inside is None else inside)
        if parents is not None:
            return _fast_gradient(scene, idx, centers, acquisition, center, parents,
                                  projector=projector)
    acq = scene.acquisition
    rays = acq.rays(supersample=n)
    nb = len(scene.bodies)
    hits = trace_rays(scene.bodies, rays.origins, rays.directions, t_min=0.0,
                      t_max=rays.t_max, axis=acq.frame.forward)
    prec = scene.bodies.precedence
    L = path_lengths(hits.ray, hits.t, hits.body, hits.entering, n_rays=len(rays), n_bodies=nb,
                     precedence=prec, t_max=rays.t_max)
    ell, g = _per_ray_slopes(L, scene, n)
    line = -pixel_log_mean(-ell, nn) if nn > 1 else ell
    # d pixel / d ray: each sub-ray's share of the pixel's transmitted intensity
    if nn > 1:
        a = -ell.reshape(-1, nn)
        e = np.exp(a - a.max(axis=1, keepdims=True))
        share = (e / e.sum(axis=1, keepdims=True)).reshape(-1)
    else:
        share = np.ones(len(ell))
    n_pixels = w * h
    pose = np.zeros((len(idx), 6, n_pixels))
    acq_grad = np.zeros((6, n_pixels)) if acquisition else None
    if len(hits):
        winner = stretch_materials(hits.ray, hits.body, hits.entering, precedence=prec)
        first = np.ones(len(hits), bool)
        first[1:] = hits.ray[1:] != hits.ray[:-1]
        before = np.empty_like(winner)
        before[0] = -1
        before[1:] = winner[:-1]
        before[first] = -1
        gz = np.concatenate([np.asarray(g), np.zeros((len(g), 1))], axis=1)  # column -1: 0
        slope = (gz[hits.ray, before] - gz[hits.ray, winner]) * share[hits.ray]
        live = slope != 0
        ray, body, tri, p = hits.ray[live], hits.body[live], hits.triangle[live], hits.point[live]
        slope = slope[live]
        pixel = ray // nn
        normal = np.zeros((len(ray), 3))
        for b in np.unique(body):
            sel = body == b
            v = scene.bodies[int(b)].vertices[scene.bodies[int(b)].faces[tri[sel]]]
            normal[sel] = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        nd = np.einsum("ij,ij->i", normal, rays.directions[ray])
        with np.errstate(divide="ignore", invalid="ignore"):
            coef = np.where(nd != 0, slope / nd, 0.0)
        for k, b in enumerate(idx):
            sel = body == b
            if not sel.any():
                continue
            cn = coef[sel, None] * normal[sel]
            moment = np.cross(p[sel] - centers[k], cn)
            for j in range(3):
                pose[k, j] = np.bincount(pixel[sel], weights=cn[:, j], minlength=n_pixels)
                pose[k, 3 + j] = np.bincount(pixel[sel], weights=moment[:, j],
                                             minlength=n_pixels)
        if acquisition:
            # the rays move with (tau, omega) about center: the bodies move by (-tau, -omega)
            cn = coef[:, None] * normal
            moment = np.cross(p - np.asarray(center, dtype=np.float64), cn)
            for j in range(3):
                acq_grad[j] = -np.bincount(pixel, weights=cn[:, j], minlength=n_pixels)
                acq_grad[3 + j] = -np.bincount(pixel, weights=moment[:, j], minlength=n_pixels)
    return GradientResult(
        line_integral=line.reshape(h, w), pose=pose.reshape(len(idx), 6, h, w),
        acquisition=None if acq_grad is None else acq_grad.reshape(6, h, w),
        names=[scene.body_names[b] for b in idx], centers=centers)


def pose_gradient(scene, bodies=None, *, supersample: int | None = None,
                  engine: str = "fast") -> np.ndarray:
    """d(line integral)/d(pose) of each moving body, in the image orientation of ``render``.

    The six parameters of a body's pose are a translation in mm along the world x, y and z
    axes and a rotation in radians about the world x, y and z axes through the body's
    :func:`centroid`. The line integral is ``-ln(I / I0)`` per pixel as
    :func:`xray_viz.render` computes it before the detector model (see the module's text for
    the formulas; a spectrum by the chain rule through it). A body outside the beam has
    exact zeros.

    Parameters
    ----------
    scene : Scene
    bodies : sequence of str, optional
        Names of the moving bodies (default: all of them, in scene order).
    supersample : int, optional
        Rays per pixel along each axis (default: the detector's).
    engine : {"fast", "numpy"}
        See :func:`line_integral_gradient`: the numba kernel where it applies, else the
        NumPy reference (the same numbers to rounding).

    Returns
    -------
    (n_bodies, 6, H, W) float
        Per mm for the translations, per radian for the rotations.

    Raises
    ------
    SceneError
        An unknown body name.

    Examples
    --------
    >>> import dataclasses, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(32, 32),
    ...                                                    pitch=(8.0, 8.0)))
    >>> g = pose_gradient(scene)
    >>> g.shape
    (1, 6, 32, 32)
    >>> bool(abs(g[0, 0].sum()) < 1e-9)     # a sphere on the axis: +x and -x cancel
    True
    """
    return line_integral_gradient(scene, bodies, supersample=supersample, engine=engine).pose


def acquisition_gradient(scene, *, center=(0.0, 0.0, 0.0), supersample: int | None = None,
                         engine: str = "fast") -> np.ndarray:
    """d(line integral)/d(pose of the source and detector moved together), ``(6, H, W)``.

    The C-arm's pose: a translation in mm along the world axes and a rotation in radians
    about the world axes through ``center`` (default the origin), applied to the source and
    the detector as one rigid body (:meth:`xray_viz.geometry.Acquisition.rotated` turns it by
    a finite angle); the bodies stay.

    Parameters
    ----------
    scene : Scene
    center : (3,) float
    supersample : int, optional
    engine : {"fast", "numpy"}

    Returns
    -------
    (6, H, W) float
    """
    return line_integral_gradient(scene, [], acquisition=True, center=center,
                                  supersample=supersample, engine=engine).acquisition
