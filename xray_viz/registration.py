"""2D/3D registration: the poses of bodies found from their X-ray images.

:func:`register` moves the chosen bodies rigidly until the scene's simulated line integrals
match the given images (one view, or several: biplane, frames of a sequence), with the exact
derivatives of :mod:`xray_viz.gradients`:

* similarity ``"ssd"``: the sum of squared differences of the line integrals, minimised by
  SciPy's trust-region least squares (:func:`scipy.optimize.least_squares`) with the exact
  Jacobian of the residuals;
* ``"ncc"``: one minus the normalised cross-correlation of the images, and ``"gc"``: one
  minus the gradient correlation (the mean of the NCCs of the images' differences along the
  rows and along the columns, Penney et al. 1998), both by L-BFGS
  (:func:`scipy.optimize.minimize`) with their exact gradients.

A coarse-to-fine pyramid widens the capture range: each level renders a detector with
``f`` times fewer pixels along each axis and an ``f`` times larger pitch over the same
field, against the images averaged over ``f x f`` blocks; each level starts from the
previous one's pose.

A body's pose is six numbers, as for :func:`~xray_viz.gradients.pose_gradient`: a
translation (mm, world axes) and a rotation vector (radians, world axes) about the body's
centroid in the *input* scene; the fitted transform is
:func:`~xray_viz.gradients.pose_matrix` of them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from xray_viz.errors import SceneError
from xray_viz.gradients import (centroid, line_integral_gradient, move_bodies, nesting,
                                pose_matrix)

__all__ = ["Registration", "register", "SIMILARITIES", "target_registration_error", "demo_stem"]

#: The similarity measures :func:`register` accepts.
SIMILARITIES = ("ssd", "ncc", "gc")


@dataclass(frozen=True, eq=False)
class Registration:
    """The result of :func:`register`.

    Attributes
    ----------
    scene : Scene
        The input scene with the fitted body placements.
    transforms : dict
        Body name -> (4, 4) rigid transform from its input placement to the fitted one.
    loss : float
        The final value of the similarity's loss at the finest level (``"ssd"``: the mean
        squared difference of the line integrals per pixel; ``"ncc"``, ``"gc"``: one minus
        the mean correlation over the views).
    iterations : int
        Optimiser iterations over all levels.
    history : list of dict
        One entry per evaluation: ``level`` (the pyramid factor), ``loss`` and ``pose``
        (name -> the six parameters).
    similarity : str
    initial_loss : float
        The loss at the input pose, finest level.
    poses : dict
        Body name -> (6,) fitted parameters: translation (mm), rotation vector (radians)
        about the body's input centroid.
    """

    scene: object
    transforms: dict
    loss: float
    iterations: int
    history: list = field(repr=False)
    similarity: str = "ssd"
    initial_loss: float = float("nan")
    poses: dict = field(default_factory=dict)


def target_registration_error(body, transform, true_transform=None) -> float:
    """Mean distance (mm) over a body's vertices between two placements of it (mTRE).

    Parameters
    ----------
    body : Body
    transform, true_transform : (4, 4) array_like
        ``true_transform`` defaults to the identity.

    Examples
    --------
    >>> import trimesh
    >>> from xray_viz.scene import Body
    >>> b = Body(name="b", mesh=trimesh.creation.box(), mu=1.0)
    >>> shift = np.eye(4)
    >>> shift[:3, 3] = [3.0, 4.0, 0.0]
    >>> target_registration_error(b, shift)
    5.0
    """
    v = np.c_[body.vertices, np.ones(len(body.vertices))]
    a = v @ np.asarray(transform, dtype=float).T
    b = v if true_transform is None else v @ np.asarray(true_transform, dtype=float).T
    return float(np.linalg.norm(a[:, :3] - b[:, :3], axis=1).mean())


def demo_stem(subdivisions: int = 3):
    """A smooth, asymmetric implant-like mesh for registration tests and examples: a tapered,
    bent stem about 80 mm long along y (7 x 5 mm across at its middle), with a neck to one
    side at its top; an icosphere deformed, so closed and free of sharp edges.

    Parameters
    ----------
    subdivisions : int
        Of the icosphere (3: 1280 faces, 4: 5120).

    Returns
    -------
    trimesh.Trimesh

    Examples
    --------
    >>> m = demo_stem()
    >>> len(m.faces), bool(m.is_volume), m.extents.round(0).tolist()
    (1280, True, [18.0, 80.0, 16.0])
    """
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    x, y, z = m.vertices.T
    r = 1 + 0.35 * z                                    # tapered along the stem
    neck = 6 * np.exp(-((z - 0.8) ** 2 + (x - 0.5) ** 2) / 0.05) * (1 + np.tanh(x / 0.1)) / 2
    along = 40 * z
    m.vertices = np.c_[7 * x * r + neck, along, -(5 * y * r + 0.006 * along**2)]
    return m


def _left_jacobian(phi) -> np.ndarray:
    """SO(3)'s left Jacobian: ``R(phi + d) = exp(J(phi) d) R(phi)`` to first order."""
    theta = float(np.linalg.norm(phi))
    k = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    if theta < 1e-8:
        return np.eye(3) + 0.5 * k
    return (np.eye(3) + (1 - np.cos(theta)) / theta**2 * k
            + (theta - np.sin(theta)) / theta**3 * (k @ k))


def _views(scene, images):
    """``[(acquisition, image)]`` from one image or a list of pairs, checked."""
    if isinstance(images, np.ndarray) or (isinstance(images, (list, tuple)) and images
                                          and not isinstance(images[0], (list, tuple))):
        pairs = [(scene.acquisition, images)]
    else:
        pairs = list(images)
    if not pairs:
        raise SceneError("register: give at least one image")
    out = []
    for k, pair in enumerate(pairs):
        if len(pair) != 2:
            raise SceneError(f"register: view {k} must be an (acquisition, image) pair")
        acq, image = pair
        image = np.asarray(image, dtype=np.float64)
        w, h = acq.detector.shape
        if image.shape != (h, w):
            raise SceneError(f"register: image {k} has shape {image.shape}, the detector "
                             f"gives (H, W) = ({h}, {w}); use the detector the image was "
                             "taken with")
        if not np.all(np.isfinite(image)):
            raise SceneError(f"register: image {k} has non-finite values")
        out.append((acq, image))
    return out


def _levels(levels, views) -> list[int]:
    """The pyramid factors that divide every view's detector, coarse to fine, ending at 1."""
    keep = []
    for f in sorted({int(f) for f in levels} | {1}, reverse=True):
        if f < 1:
            raise SceneError(f"register: pyramid factors must be >= 1, got {f}")
        if all(a.detector.shape[0] % f == 0 and a.detector.shape[1] % f == 0
               and min(a.detector.shape) // f >= 8 for a, _ in views):
            keep.append(f)
    return keep


def _coarse(acq, image, f):
    """The view at pyramid factor ``f``: ``f`` times fewer pixels, ``f`` times the pitch."""
    if f == 1:
        return acq, image
    det = acq.detector
    w, h = det.shape
    coarse = dataclasses.replace(det, shape=(w // f, h // f),
                                 pitch=(det.pitch[0] * f, det.pitch[1] * f), supersample=1)
    small = image.reshape(h // f, f, w // f, f).mean(axis=(1, 3))
    return acq.replace(detector=coarse), small


def _ncc(a, b):
    """``(ncc, d ncc / d a)`` of two images."""
    a0, b0 = a - a.mean(), b - b.mean()
    na, nb = np.sqrt((a0 * a0).sum()), np.sqrt((b0 * b0).sum())
    if na == 0 or nb == 0:
        return 0.0, np.zeros_like(a)
    r = float((a0 * b0).sum() / (na * nb))
    grad = b0 / (na * nb) - r * a0 / na**2
    return r, grad                        # centred already: d/da of the mean-removed terms


def _similarity(name, a, b):
    """``(loss, d loss / d a)`` of the simulated image ``a`` against the target ``b``."""
    if name == "ssd":
        d = a - b
        return float((d * d).mean()), 2 * d / d.size
    if name == "ncc":
        r, g = _ncc(a, b)
        return 1 - r, -g
    # gradient correlation: differences along the rows (axis 1) and the columns (axis 0)
    loss, grad = 1.0, np.zeros_like(a)
    for axis in (0, 1):
        da, db = np.diff(a, axis=axis), np.diff(b, axis=axis)
        r, g = _ncc(da, db)
        loss -= 0.5 * r
        back = np.zeros_like(a)               # the transpose of np.diff along the axis
        if axis == 0:
            back[1:] += g
            back[:-1] -= g
        else:
            back[:, 1:] += g
            back[:, :-1] -= g
        grad -= 0.5 * back
    return loss, grad


class _Problem:
    """The simulated images and their Jacobian at a pose vector, kept for the last pose."""

    def __init__(self, scene, names, views, similarity):
        self.scene, self.names, self.views, self.similarity = scene, names, views, similarity
        idx = [scene.body_names.index(n) for n in names]
        self.c0 = np.array([centroid(scene.bodies[i]) for i in idx])
        # rotations scaled by each body's RMS radius: the parameters are all in mm
        self.radius = np.array([
            max(1e-6, float(np.sqrt(((scene.bodies[i].vertices - c) ** 2).sum(axis=1).mean())))
            for i, c in zip(idx, self.c0)])
        self.last_x = None
        self.level = 1
        self.history = []
        # which body lies inside which, once (the moves are assumed to keep it, as the
        # bodies' precedence is kept): the gradient kernel then takes nested bodies too
        box = scene.bodies.bounds
        meet = any(np.all(box[a, 0] <= box[b, 1]) and np.all(box[b, 0] <= box[a, 1])
                   for a in range(len(box)) for b in range(a))
        self.inside = nesting(scene) if meet else [[] for _ in range(len(box))]

    def params(self, x):
        """(n_bodies, 6) pose parameters (mm, rad) of the scaled vector ``x``."""
        p = np.asarray(x, dtype=float).reshape(len(self.names), 6).copy()
        p[:, 3:] /= self.radius[:, None]
        return p

    def transforms(self, x) -> dict:
        return {n: pose_matrix(p, c) for n, p, c in zip(self.names, self.params(x), self.c0)}

    def evaluate(self, x):
        """Per view: the simulated image and its (n_params, H, W) derivatives w.r.t. x."""
        x = np.asarray(x, dtype=float)
        if self.last_x is not None and np.array_equal(x, self.last_x):
            return self.last
        p = self.params(x)
        moved = move_bodies(self.scene, self.transforms(x))
        centers = self.c0 + p[:, :3]
        # chain rule: d pose / d x (translation: identity; rotation: J_l(phi) / radius)
        chain = []
        for k in range(len(self.names)):
            m = np.zeros((6, 6))
            m[:3, :3] = np.eye(3)
            m[3:, 3:] = _left_jacobian(p[k, 3:]) / self.radius[k]
            chain.append(m)
        out = []
        for acq, image in self.views:
            res = line_integral_gradient(moved.replace(acquisition=acq), self.names,
                                         centers=centers, supersample=1, inside=self.inside)
            jac = np.einsum("kij,kihw->kjhw", np.array(chain), res.pose)
            out.append((res.line_integral, jac.reshape(-1, *image.shape), image))
        self.last_x, self.last = x.copy(), out
        return out

    def residuals(self, x):
        parts = [(sim - img).reshape(-1) for sim, _, img in self.evaluate(x)]
        r = np.concatenate(parts) / np.sqrt(sum(len(q) for q in parts))
        self._record(x, float(r @ r))
        return r

    def jacobian(self, x):
        parts = [jac.reshape(len(jac), -1).T for _, jac, _ in self.evaluate(x)]
        n = sum(len(q) for q in parts)
        return np.concatenate(parts) / np.sqrt(n)

    def loss_and_grad(self, x):
        loss, grad = 0.0, np.zeros(len(x))
        views = self.evaluate(x)
        for sim, jac, img in views:
            v, g = _similarity(self.similarity, sim, img)
            loss += v / len(views)
            grad += np.einsum("khw,hw->k", jac, g) / len(views)
        self._record(x, loss)
        return loss, grad

    def loss(self, x) -> float:
        if self.similarity == "ssd":
            r = self.residuals(x)
            return float(r @ r)
        return self.loss_and_grad(x)[0]

    def _record(self, x, loss):
        self.history.append({"level": self.level, "loss": loss,
                             "pose": dict(zip(self.names, self.params(x).tolist()))})


def register(scene, images, *, bodies, similarity: str = "ssd", levels=(4, 2, 1),
             max_iterations: int = 100, initial=None) -> Registration:
    """Find the poses of ``bodies`` from X-ray line-integral images by matching simulated ones.

    Parameters
    ----------
    scene : Scene
        The bodies at their starting poses (the input placement) and, for a single image, the
        acquisition it was taken with.
    images : (H, W) array or list of (Acquisition, (H, W) array)
        Line-integral images (``-ln(I / I0)``, :attr:`xray_viz.render.Radiograph.line_integral`):
        one taken with the scene's own acquisition, or pairs of an acquisition and its image
        (biplane, frames of a sequence).
    bodies : str or sequence of str
        The bodies to move; the others stay where they are.
    similarity : {"ssd", "ncc", "gc"}
        See the module's text.
    levels : sequence of int
        Pyramid factors, coarse to fine (1 is always added; a factor that does not divide a
        detector's shape or leaves fewer than 8 pixels is skipped).
    max_iterations : int
        Per level.
    initial : dict, optional
        Body name -> (6,) starting parameters (default zeros: the input placement).

    Returns
    -------
    Registration

    Raises
    ------
    SceneError
        An unknown body, an image whose shape does not match its detector, an unknown
        similarity, or a body that no view's beam crosses.

    Notes
    -----
    The simulated images are ideal line integrals with one ray per pixel (the detector's
    supersampling, blur and noise are not simulated: the images given carry their own). The
    bodies are assumed to keep their nesting while they move (as their precedence is kept).
    """
    from scipy.optimize import least_squares, minimize

    if similarity not in SIMILARITIES:
        raise SceneError(f"register: unknown similarity {similarity!r}; choose one of "
                         f"{', '.join(SIMILARITIES)}")
    names = [bodies] if isinstance(bodies, str) else list(bodies)
    if not names:
        raise SceneError("register: name at least one body to move")
    for n in names:
        if n not in scene.body_names:
            raise SceneError(f"register: no body named {n!r}; the scene has "
                             f"{', '.join(scene.body_names)}")
    views = _views(scene, images)
    factors = _levels(levels, views)
    problem = _Problem(scene, names, views, similarity)
    x = np.zeros(6 * len(names))
    for k, n in enumerate(names):
        if initial and n in initial:
            start = np.asarray(initial[n], dtype=float).reshape(6)
            x[6 * k:6 * k + 6] = np.r_[start[:3], start[3:] * problem.radius[k]]
    # a body the beam of no view crosses cannot be registered
    first = problem.evaluate(x)
    for k, n in enumerate(names):
        if not any(np.any(jac[6 * k:6 * k + 6]) for _, jac, _ in first):
            raise SceneError(f"register: body {n!r} does not cross the beam of any view; "
                             "start it where the images show it")
    initial_loss = problem.loss(x)
    problem.history.clear()
    iterations = 0
    for f in factors:
        problem.views = [_coarse(a, img, f) for a, img in views]
        problem.level, problem.last_x = f, None
        if similarity == "ssd":
            res = least_squares(problem.residuals, x, jac=problem.jacobian, method="trf",
                                x_scale=1.0, xtol=1e-8, ftol=1e-9, gtol=1e-10,
                                max_nfev=max_iterations)
            iterations += int(res.njev or res.nfev)
        else:
            res = minimize(problem.loss_and_grad, x, jac=True, method="L-BFGS-B",
                           options={"maxiter": max_iterations, "ftol": 1e-12, "gtol": 1e-9})
            iterations += int(res.nit)
        x = res.x
    problem.views, problem.last_x = views, None
    loss = problem.loss(x)
    transforms = problem.transforms(x)
    return Registration(scene=move_bodies(scene, transforms), transforms=transforms,
                        loss=loss, iterations=iterations, history=problem.history,
                        similarity=similarity, initial_loss=initial_loss,
                        poses=dict(zip(names, problem.params(x))))


# --------------------------------------------------------------------------------------------
# the command line: xray-viz register


def add_register_parser(subparsers) -> None:
    """Register ``xray-viz register SCENE IMAGE [IMAGE ...] --body NAME -o fitted.toml``."""
    p = subparsers.add_parser(
        "register", help="find bodies' poses from X-ray images (2D/3D registration)",
        description="Move the named bodies of SCENE rigidly until its simulated line integrals "
                    "match the IMAGEs (files written by `xray-viz render`, or any format "
                    "xray_viz.load_image reads: line integrals, or intensities converted with "
                    "the scene's I0), then write the scene with the fitted placements to OUT "
                    "and print each body's pose change and the final similarity. An image file "
                    "that records its geometry (all but .npy) is compared with a render from "
                    "the source and detector it records; a .npy image is taken with the "
                    "scene's own, or turned by its --angles value.")
    p.add_argument("scene", metavar="SCENE", help="a scene .toml file or a bundled phantom")
    p.add_argument("images", metavar="IMAGE", nargs="+")
    p.add_argument("--body", action="append", required=True, metavar="NAME",
                   help="a body to move (repeat for several)")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="the fitted scene file to write (.toml)")
    p.add_argument("--angles", type=float, nargs="+", default=None, metavar="DEG",
                   help="one per .npy IMAGE (no recorded geometry): the degrees its view is "
                        "turned from the scene's, about the detector's up axis through the "
                        "centre of the SCENE's bodies, as `render --angle` (default 0 for a "
                        "single one)")
    p.add_argument("--similarity", choices=SIMILARITIES, default="ssd",
                   help="ssd (least squares on line integrals, default), ncc (normalised "
                        "cross-correlation) or gc (gradient correlation)")
    p.add_argument("--levels", type=int, nargs="+", default=[4, 2, 1], metavar="F",
                   help="pyramid factors, coarse to fine (default: 4 2 1)")
    p.add_argument("--max-iterations", type=int, default=100, metavar="N",
                   help="per pyramid level (default %(default)s)")
    p.set_defaults(func=register_command)


def _read_line_integral(path, scene):
    """``(image, geometry or None)`` from a file: line integrals as they are, intensities as
    ``-ln(I / I0)`` with the scene's ``I0``; path lengths refused. The geometry is what the
    file records of the view it was taken with (:func:`xray_viz.output.save_image`)."""
    from xray_viz.output import load_image

    image, meta = load_image(path, with_metadata=True)
    if meta.window and image.dtype.kind in "ui":
        image = meta.to_physical(image)
    image = np.asarray(image, dtype=np.float64)
    quantity = meta.quantity
    if quantity == "intensity":
        if not np.all(image > 0):
            raise SceneError(f"{path}: an intensity image with pixels <= 0 has no line "
                             "integral; render it with --quantity line-integral")
        image = -np.log(image / scene.detector.i0)
    elif quantity not in (None, "line-integral"):
        raise SceneError(f"{path}: holds {quantity!r}; register needs line integrals (render "
                         "--quantity line-integral) or intensities")
    return image, meta.geometry or None


def _recorded_view(scene, geometry, path):
    """The scene's acquisition moved to the source and detector a file records."""
    try:
        src, det = geometry["source"], geometry["detector"]
        source = dataclasses.replace(scene.source, position=src["position"])
        detector = dataclasses.replace(scene.detector, center=det["center"], up=det["up"],
                                       shape=tuple(det["shape"]), pitch=tuple(det["pitch_mm"]))
    except (KeyError, TypeError) as exc:
        raise SceneError(f"{path}: its recorded geometry lacks {exc}; give an image written "
                         "by xray-viz render, or a .npy image with --angles") from None
    return scene.replace(source=source, detector=detector).acquisition


def _turned(scene, angle):
    """The acquisition turned ``angle`` degrees about the detector's up axis through the
    centre of the bodies' bounding box, as ``render --angle`` turns it
    (:func:`xray_viz.scene_options.turn_acquisition`, which imports the package)."""
    import math

    if not math.isfinite(angle):
        raise SceneError(f"--angles {angle}: give finite numbers of degrees")
    box = scene.bodies.bounds
    centre = (box[:, 0].min(axis=0) + box[:, 1].max(axis=0)) / 2
    return scene.acquisition.rotated(angle, axis=scene.detector.up, center=centre)


def register_command(args, *, stdout=None) -> int:
    """``xray-viz register``: see :func:`add_register_parser`."""
    import sys
    import tomllib
    from pathlib import Path

    from xray_viz.output import atomic_write, scene_target
    from xray_viz.scene_file import load_scene, scene_from_dict
    out_stream = sys.stdout if stdout is None else stdout
    dst = scene_target(args.output, command="register")
    folder = dst.parent
    if args.max_iterations < 1:
        raise SceneError(f"--max-iterations must be >= 1, got {args.max_iterations}")
    scene = load_scene(args.scene)
    for name in args.body:
        if name not in scene.body_names:
            raise SceneError(f"--body {name!r}: no such body in {args.scene}; it has "
                             f"{', '.join(scene.body_names)}")
    read = [(path, *_read_line_integral(path, scene)) for path in args.images]
    bare = [path for path, _, geometry in read if geometry is None]
    angles = args.angles
    if angles is not None and len(angles) != len(bare):
        raise SceneError(f"--angles gives {len(angles)} angles for {len(bare)} images without "
                         "a recorded geometry (.npy); give one per such image")
    if angles is None:
        if len(bare) > 1:
            raise SceneError(f"{len(bare)} images without a recorded geometry (.npy): give "
                             "--angles with one view angle (degrees) per image")
        angles = [0.0] * len(bare)
    turn = iter(angles)
    pairs = []
    w, h = scene.detector.shape
    for path, image, geometry in read:
        if image.shape != (h, w):
            raise SceneError(f"{path}: image shape {image.shape} does not match the detector "
                             f"of {args.scene} ((H, W) = ({h}, {w})); render it with that "
                             "detector or change [detector] shape")
        if geometry is not None:
            acq = _recorded_view(scene, geometry, path)
        else:
            angle = next(turn)
            acq = _turned(scene, angle) if angle else scene.acquisition
        pairs.append((acq, image))
    try:
        reg = register(scene, pairs, bodies=args.body, similarity=args.similarity,
                       levels=args.levels, max_iterations=args.max_iterations)
    except SceneError as exc:
        raise SceneError(str(exc).removeprefix("register: ")) from None
    for name in args.body:
        p = reg.poses[name]
        print(f"{name}: translation {(np.round(p[:3], 4) + 0.0).tolist()} mm, rotation "
              f"{(np.round(np.degrees(p[3:]), 4) + 0.0).tolist()} deg (about its centroid; "
              f"{np.degrees(np.linalg.norm(p[3:])):.4f} deg in all)", file=out_stream)
    label = {"ssd": "mean squared difference", "ncc": "1 - NCC", "gc": "1 - GC"}[args.similarity]
    print(f"{args.similarity}: {label} {reg.initial_loss:.6g} -> {reg.loss:.6g} in "
          f"{reg.iterations} iterations", file=out_stream)
    text = reg.scene.to_toml(base=folder)

    def verify(tmp):
        doc = tomllib.loads(Path(tmp).read_text(encoding="utf-8"))
        scene_from_dict(doc, base_dir=folder)       # loads: every mesh and value checked

    atomic_write(dst, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"), verify=verify)
    print(f"wrote {dst}", file=out_stream)
    return 0
