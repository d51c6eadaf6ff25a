"""CT scans: projection stacks of a scene's fixed bodies along an orbit, their files, Dask.

A scan is ``n`` projections of the scene's one :class:`~xray_viz.bodies.Bodies` by the
acquisitions of an :class:`~xray_viz.orbit.Orbit` (circular, helical or explicit poses):
every per-mesh set-up (mesh checks, bounds, the fast engine's spatial order) is paid once per
process. The stack layout (in memory and in a Zarr v3 store) is the one ``CT-LAYOUT``
documents and ``xray_viz.reconstruct`` reads: ``projections`` float32 ``(n, H, W)`` plus a
JSON-serialisable ``geometry`` dict (:func:`scan_geometry`).

* :func:`scan` renders in this process, or on a Dask cluster (``client=``): each task renders a
  batch of projections and writes its own chunks of the Zarr store, then their ``done`` flags;
  workers load the scene once (its scene-file text, keyed by a content hash).
* Writers: :func:`open_store` / Zarr (resumable: a re-run fills only the projections whose
  ``done`` flag is not set), :func:`write_tiff_stack`, :func:`write_nexus`.
* Geometry for other toolkits: :func:`rtk_geometry` (+ :func:`rtk_geometry_xml`),
  :func:`astra_vectors`, :func:`tigre_geometry`, and their inverses (``poses_from_*``).
* ``xray-viz scan SCENE -o scan.zarr`` (:func:`add_scan_parser`, :func:`scan_command`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xray_viz.errors import OutputError, SceneError
from xray_viz.orbit import Orbit, orbit_from_dict
from xray_viz.poses import (  # noqa: F401  (the exports: importable here as documented)
    POSE_ROWS,
    acquisition_pose,
    astra_vectors,
    pose_arrays_of,
    pose_dict,
    pose_frames,
    pose_lists,
    pose_table,
    poses_from_astra,
    poses_from_tigre,
    projection_matrices,
    tigre_geometry,
)

__all__ = ["Scan", "Orbit", "orbit_from_dict", "scan", "projection", "Projections",
           "scan_geometry",
           "projection_seed", "open_store", "write_zarr", "read_zarr", "write_tiff_stack",
           "write_nexus", "astra_vectors", "poses_from_astra", "default_orbit", "render_batch",
           "add_scan_parser", "scan_command", "SCAN_QUANTITIES", "flat_dark",
           "trim_memory", "warm_kernels", "tigre_geometry", "poses_from_tigre",
           "pose_table", "done_flags", "damaged_projections", "bodies_digest", "LAYOUT_VERSION",
           "ARRAYS_LAYOUT_VERSION", "INLINE_POSES_MAX", "POSE_ROWS"]

#: What a projection holds: ``-ln(I / I0)`` (default) or the detected intensity.
SCAN_QUANTITIES = ("line-integral", "intensity")
#: The layout version of a store that keeps its whole geometry in its JSON attributes.
LAYOUT_VERSION = 1
#: The layout version of a store whose per-projection poses and projection matrices are
#: Zarr arrays (``per_projection_arrays`` in the geometry attributes), not JSON.
ARRAYS_LAYOUT_VERSION = 2
#: Above this many projections a store keeps its poses and projection matrices as arrays.
INLINE_POSES_MAX = 1000
#: From this many projections ``xray-viz scan`` says it is building the poses (random ones
#: take about 30 us each) before its progress bar starts.
POSES_NOTICE = 100_000
PLUGIN_NAME = "xray_viz-scenes"


# ---------------------------------------------------------------------------------- geometry

def projection_seed(seed: int | None, k: int) -> int | None:
    """The noise seed of projection ``k`` of a scan whose detector has ``seed`` (None: fresh
    randomness): distinct per projection, the same in every run and on every worker.

    Examples
    --------
    >>> projection_seed(7, 0) != projection_seed(7, 1), projection_seed(None, 3)
    (True, None)
    """
    if seed is None:
        return None
    return int(np.random.SeedSequence([int(seed), int(k)]).generate_state(1, np.uint64)[0])


def scan_geometry(scene, orbit: Orbit, *, acquisitions=None) -> dict:
    """The geometry dict of a scan (the shared layout: angles, axis, SID, SOD, detector,
    per-projection poses and projection matrices), JSON-serialisable.

    ``acquisitions`` (optional): the orbit's acquisitions, when the caller has built them
    already (:attr:`Projections.acquisitions`): the poses are then read from them, not built
    again.

    Random poses are built over all projections at once (:func:`pose_table`): 100,000 of them
    in about a second.

    Examples
    --------
    >>> import xray_viz
    >>> g = scan_geometry(xray_viz.load_scene("sphere"), Orbit(projections=4, axis=[0, 1, 0]))
    >>> g["sid_mm"], g["sod_mm"], g["angles_deg"]
    (1500.0, 1000.0, [0.0, 90.0, 180.0, 270.0])
    """
    out = _geometry_head(scene, orbit, acquisitions=acquisitions)
    out["poses"], out["projection_matrices"] = pose_lists(
        *pose_table(scene, orbit, acquisitions=acquisitions))
    return out


def _geometry_head(scene, orbit: Orbit, *, acquisitions=None) -> dict:
    """:func:`scan_geometry` with ``poses`` and ``projection_matrices`` left None (in their
    places): nothing per projection but the angles."""
    base = scene.acquisition
    det = scene.detector
    angles = orbit.angles()
    first = (acquisitions[0] if acquisitions else orbit.acquisition(base, 0)).frame
    if orbit.kind == "poses":
        axis = center = sod = None
    else:
        axis, center = orbit.axis.tolist(), orbit.center.tolist()
        rel = first.source - orbit.center
        sod = float(np.linalg.norm(rel - (rel @ orbit.axis) * orbit.axis))
    out = {
        "orbit": orbit.kind,
        "beam": "parallel" if base.parallel else "cone",
        "projections": orbit.projections,
        "angles_deg": None if angles is None else angles.tolist(),
        "axis": axis, "center": center,
        "pitch_mm_per_turn": orbit.pitch,
        "sid_mm": first.sid,
        "sod_mm": sod,
        "detector": {"shape": list(det.shape), "pitch_mm": list(det.pitch),
                     "offset_mm": list(det.offset)},
        "poses": None,
        "projection_matrices": None,
    }
    if orbit.random is not None:           # how the poses were drawn (axis, centre, ranges)
        out["random"] = {**orbit.random.to_dict(), "axis": orbit.axis.tolist(),
                         "center": orbit.center.tolist()}
    return out


def _physics(scene, scatter=None, histories=None, smoothing=None) -> dict:
    src, det = scene.source, scene.detector
    out = {"I0": det.i0, "response": det.response, "noise": det.noise, "seed": det.seed}
    if scatter not in (None, "none"):          # only then: the stores of before stay the same
        out["scatter"] = {"mode": scatter}
        if histories is not None:
            out["scatter"]["histories"] = int(histories)
        if smoothing:
            out["scatter"]["smoothing_mm"] = float(smoothing)
    if src.spectrum is not None:
        try:
            out["spectrum"] = scene.to_dict()["source"]["spectrum"]
        except SceneError:
            out["spectrum"] = repr(src.spectrum)
    else:
        out["energy_kev"] = src.energy
    return out


def flat_dark(scene, geometry, quantity: str = "intensity"):
    """The open-beam (flat) and dark fields of a scan, ``(H, W)`` float32 each, or
    ``(None, None)`` for line integrals (already flat-field corrected).

    ``flat`` is the detector model's noise-free reading without any body at projection 0's
    pose (:func:`xray_viz.physics.imaging.flat_field`: ``gain * I0 * F * A``, the fall-off and
    the heel effect included); ``dark`` the reading without any beam: zero, the detector model
    having no electronic offset (its electronic noise has mean 0). So that
    ``(projection - dark) / (flat - dark) = exp(-line integral)``. Every projection of a
    circular or helical orbit shares projection 0's flat (the source and detector turn
    together); poses at other distances (random ``sod``/``sid``) differ from it only through
    the fall-off.

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> flat, dark = flat_dark(scene, scan_geometry(scene, Orbit(projections=2, axis=[0, 1, 0])))
    >>> flat.shape, float(flat.max()), float(dark.max())
    ((256, 256), 1.0, 0.0)
    """
    from xray_viz.poses import pose_acquisition
    from xray_viz.physics.imaging import flat_field

    _check_quantity(quantity)
    if quantity != "intensity":
        return None, None
    first = pose_acquisition(scene.acquisition, geometry["poses"][0])
    flat = np.asarray(flat_field(scene.replace(acquisition=first)), np.float32)
    return flat, np.zeros_like(flat)


# ---------------------------------------------------------------------------------- rendering

def _check_quantity(quantity):
    if quantity not in SCAN_QUANTITIES:
        raise SceneError(f"unknown scan quantity {quantity!r}; choose one of "
                         f"{', '.join(SCAN_QUANTITIES)}")


def projection(scene, orbit: Orbit, k: int, *, quantity: str = "line-integral",
               engine: str = "fast") -> np.ndarray:
    """Projection ``k`` of a scan, ``(H, W)`` float32, rendered with the scene's bodies.

    The detector's noise seed becomes :func:`projection_seed` ``(seed, k)``. A loop over
    projections builds one :class:`Projections` instead (its stages once for all of them).
    """
    return Projections(scene, orbit, quantity=quantity, engine=engine)(k)


class Projections:
    """The projections of a scan: a loop over the orbit's acquisitions through one
    :class:`~xray_viz.tracing.engines.Projector`, one :class:`~xray_viz.physics.beam.Beam` and
    one :class:`~xray_viz.physics.detector_model.DetectorModel`, built here once.

    ``Projections(scene, orbit)(k)`` is projection ``k``, ``(H, W)`` float32: the orbit's
    acquisition ``k`` (no scene is built), the noise seeded with :func:`projection_seed`
    ``(seed, k)``; bit for bit :func:`xray_viz.render` of the scene moved to that pose.
    With ``scatter`` (``"mc"`` with ``histories``, or ``"kernel"``: see
    :func:`xray_viz.render`) each projection has its scatter, the Monte Carlo seeded with
    :func:`projection_seed` ``(seed, k)`` (``seed`` 0 for a detector without one): bit for
    bit the render of the scene moved to that pose with that detector seed.
    With ``keep=True`` the orbit's acquisitions are built once here and kept
    (:attr:`acquisitions`), for :func:`scan_geometry` to read the poses from them.

    Examples
    --------
    >>> import dataclasses, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> small = scene.replace(detector=dataclasses.replace(scene.detector, shape=(32, 24),
    ...                                                    pitch=(8.0, 8.0)))
    >>> project = Projections(small, Orbit(projections=4, axis=[0, 1, 0]))
    >>> project(3).shape, round(float(project(0).max()), 1)        # 80 mm at 0.2 /cm
    ((24, 32), 1.6)
    """

    def __init__(self, scene, orbit: Orbit, *, quantity: str = "line-integral",
                 engine: str = "fast", keep: bool = False, scatter=None, histories=None,
                 scatter_smoothing=None):
        from xray_viz.render import ScatterSource, check_memory, scene_projector, stages

        _check_quantity(quantity)
        #: Where the scatter comes from (:class:`~xray_viz.render.ScatterSource`, built once:
        #: the kernel model once for every projection), or None.
        self.scatter = ScatterSource.of(scene, scatter, histories=histories,
                                        smoothing=scatter_smoothing)
        self.projector = scene_projector(scene, engine)
        self.beam, self.model = stages(scene)
        self.base, self.orbit, self.quantity = scene.acquisition, orbit, quantity
        #: With ``keep``: the orbit's acquisitions, built once, shared by the images and the
        #: geometry export (``scan_geometry(..., acquisitions=)``); else None (each built
        #: when its projection is rendered: bounded memory for large scans).
        self.acquisitions = list(orbit.acquisitions(self.base)) if keep else None
        self.supersample = scene.detector.supersample
        check_memory(scene, supersample=self.supersample, engine=engine,
                     scatter=None if self.scatter is None else self.scatter.mode)

    def __call__(self, k: int) -> np.ndarray:
        """Projection ``k``, ``(H, W)`` float32."""
        from xray_viz.render import image

        acq = self.acquisitions[k] if self.acquisitions is not None \
            else self.orbit.acquisition(self.base, k)
        seed = acq.detector.seed
        mc_seed = None
        if self.scatter is not None:          # the Monte Carlo's, per projection
            mc_seed = projection_seed(self.scatter.seed(seed), k)
        intensity, line_integral = image(
            self.projector, self.beam, self.model, acq, supersample=self.supersample,
            seed=None if seed is None else projection_seed(seed, k), scatter=self.scatter,
            scatter_seed=mc_seed)
        return np.asarray(intensity if self.quantity == "intensity" else line_integral,
                          dtype=np.float32)


@dataclass(frozen=True, eq=False)
class Scan:
    """A projection stack and its geometry.

    Attributes
    ----------
    projections : (n, H, W) float32 numpy.ndarray or zarr.Array
        ``projections[k]`` is the image of projection ``k`` (row 0 at the top of the
        detector, column 0 at its left seen from the source). A scan written to a store (or
        ``read_zarr(lazy=True)``) keeps the store's array, read on indexing.
    geometry : dict
        :func:`scan_geometry`.
    quantity : str
        ``"line-integral"`` (``-ln(I / I0)``) or ``"intensity"``.
    physics : dict
        Energy or spectrum, ``I0``, detector response, noise and seed.
    scene : Scene
    flat, dark : (H, W) float or None
        The open-beam and dark fields, where a store holds them.
    """

    projections: np.ndarray
    geometry: dict
    quantity: str
    physics: dict
    scene: object = dataclasses.field(repr=False, default=None)
    flat: np.ndarray | None = dataclasses.field(repr=False, default=None)
    dark: np.ndarray | None = dataclasses.field(repr=False, default=None)

    @property
    def units(self) -> str:
        """``"1"`` for line integrals, ``"photons"`` for intensities."""
        return "1" if self.quantity == "line-integral" else "photons"


def default_orbit(scene, **changes) -> Orbit:
    """The orbit of a scene without a ``[scan]`` table: a full circle of 360 projections about
    the detector's up axis through the centre of the bodies (as ``--angle`` and the viewer
    turn the acquisition), so the source goes round the bodies whatever way the scene faces.

    Examples
    --------
    >>> import xray_viz
    >>> o = default_orbit(xray_viz.load_scene("sphere"), projections=4)
    >>> o.axis.tolist(), o.projections
    ([0.0, 1.0, 0.0], 4)
    """
    from xray_viz.volume import imaged_centre

    centre = imaged_centre(scene)          # the bodies' and the voxel volumes' box
    if centre is None:
        centre = np.asarray(scene.detector.center, float)
    return Orbit(**{"projections": 360, "axis": np.asarray(scene.detector.up, float),
                    "center": centre, **changes})


def _orbit_of(scene, orbit) -> Orbit:
    if orbit is None:
        orbit = scene.orbit or default_orbit(scene)
    elif isinstance(orbit, dict):
        orbit = orbit_from_dict(orbit)
    if not isinstance(orbit, Orbit):
        raise SceneError(f"orbit must be an Orbit or a [scan] table, got {orbit!r}")
    return orbit


def scan(scene, orbit=None, *, quantity: str = "line-integral", engine: str = "fast",
         store=None, client=None, batch: int = 8, progress: bool = False,
         scatter: str | None = None, histories: int | None = None,
         scatter_smoothing: float | None = None) -> Scan:
    """Scan a scene: render every projection of an orbit.

    Parameters
    ----------
    scene : Scene
    orbit : Orbit or dict, optional
        Default: the scene file's ``[scan]`` (:attr:`Scene.orbit`), else a full circular scan
        of 360 projections about z through the origin.
    quantity : {"line-integral", "intensity"}
    engine : {"fast", "numpy"}
    store : path-like, optional
        A Zarr v3 store to write (and resume: projections flagged ``done`` are not rendered
        again). Needed with ``client``.
    client : distributed.Client, optional
        Render on a Dask cluster; tasks write their chunks of ``store`` themselves.
    batch : int
        Projections per Dask task.
    progress : bool
        A progress bar (tqdm) on stderr.
    scatter : {None, "mc", "kernel"}
        Scatter in every projection, as :func:`xray_viz.render`'s ``scatter`` (the stages
        and the kernel model built once; the Monte Carlo per projection, seeded with
        :func:`projection_seed` ``(seed, k)``, ``seed`` 0 for a detector without one). The
        scan's physics record it (a store resumes only the same scatter).
    histories : int, optional
        Photons per projection for ``scatter="mc"`` (required there).
    scatter_smoothing : float, optional
        mm: the Gaussian smoothing of each projection's Monte Carlo scatter, as
        :func:`xray_viz.render`'s.

    Returns
    -------
    Scan
        With ``store``, its ``projections`` are the store's (lazy) ``zarr.Array``: memory stays
        bounded by the batch whatever the stack's size (index it, ``projections[k]``, or
        ``projections[:]`` for all of it in memory).

    Examples
    --------
    >>> import dataclasses, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> small = scene.replace(detector=dataclasses.replace(scene.detector, shape=(32, 24),
    ...                                                    pitch=(8.0, 8.0)))
    >>> s = xray_viz.scan(small, Orbit(projections=3, axis=[0, 1, 0]))
    >>> s.projections.shape, s.projections.dtype.name
    ((3, 24, 32), 'float32')
    """
    _check_quantity(quantity)
    from xray_viz.render import ScatterSource

    scatter, histories = ScatterSource.options(scene, scatter, histories)  # before any work
    scatter_smoothing = ScatterSource.check_smoothing(scatter, scatter_smoothing)
    mc = {"scatter": scatter, "histories": histories, "scatter_smoothing": scatter_smoothing}
    orbit = _orbit_of(scene, orbit)
    if client is not None and store is None:
        raise SceneError("scan(client=...) writes a Zarr store: give store= (a path)")
    if store is None:
        w, h = scene.detector.shape
        _check_stack(orbit.projections, h, w, "give store= (a .zarr path): a store keeps "
                     "memory bounded by the batch")
        # the stack is in memory anyway: the acquisitions are built once, for the images
        # and the geometry (random poses: the geometry's arrays, built all at once)
        project = Projections(scene, orbit, quantity=quantity, engine=engine,
                              keep=orbit.random is None, **mc)
        geometry = scan_geometry(scene, orbit, acquisitions=project.acquisitions)
        out = np.empty((orbit.projections, h, w), np.float32)
        bar = _bar(orbit.projections, progress)
        for k in range(orbit.projections):
            out[k] = project(k)
            bar.update(1)
        bar.close()
        flat, dark = flat_dark(scene, geometry, quantity)
        return Scan(out, geometry, quantity,
                    _physics(scene, scatter, histories, scatter_smoothing), scene,
                    flat=flat, dark=dark)
    _scan_to_store(scene, orbit, store, quantity=quantity, engine=engine, client=client,
                   batch=batch, progress=progress, **mc)
    return read_zarr(store, scene=scene, lazy=True, verify=False)   # verified as resumed


def _store_geometry(scene, orbit) -> tuple:
    """``(geometry, tables)`` for a store: above :data:`INLINE_POSES_MAX` projections the
    geometry without its per-projection lists (None) and ``tables`` = :func:`pose_table`'s
    arrays (no million small dicts made), else :func:`scan_geometry` and None."""
    if orbit.projections <= INLINE_POSES_MAX:
        return scan_geometry(scene, orbit), None
    return _geometry_head(scene, orbit), pose_table(scene, orbit)


def _with_lists(geometry, tables) -> dict:
    """``geometry`` with its per-projection lists (made from ``tables`` where None)."""
    if geometry.get("poses") is not None or tables is None:
        return geometry
    out = dict(geometry)
    out["poses"], out["projection_matrices"] = pose_lists(*tables)
    return out


def _scan_to_store(scene, orbit, store, *, quantity, engine, client, batch,
                   progress, scatter=None, histories=None,
                   scatter_smoothing=None) -> tuple[int, int]:
    """Fill the missing projections of a Zarr store; ``(filled, total)``. Memory: one
    projection per worker (the stack is never held), the poses as arrays."""
    geometry, tables = _store_geometry(scene, orbit)
    group = open_store(store, scene=scene, quantity=quantity, geometry=geometry,
                       _tables=tables,
                       physics=_physics(scene, scatter, histories, scatter_smoothing))
    del geometry, tables
    _repair_done(group, store)            # what a resume skips is verified, not trusted
    todo = [int(k) for k in np.flatnonzero(~done_flags(group))]
    if client is not None:
        _scan_dask(client, scene, orbit, store, todo, quantity=quantity, engine=engine,
                   batch=batch, progress=progress, scatter=scatter, histories=histories,
                   scatter_smoothing=scatter_smoothing)
    else:
        bar = _bar(len(todo), progress)
        project = Projections(scene, orbit, quantity=quantity, engine=engine,
                              scatter=scatter, histories=histories,
                              scatter_smoothing=scatter_smoothing) if todo else None
        for i, k in enumerate(todo):
            _write_projection(group, k, project(k))
            bar.update(1)
            if (i + 1) % max(1, batch) == 0:
                trim_memory()
        bar.close()
    return len(todo), orbit.projections


def _check_stack(n, h, w, fix, *, where="") -> None:
    """Refuse, in one line and before any work, a float32 stack of ``n`` projections of
    ``w x h`` that cannot fit in the memory this process may still take
    (:mod:`xray_viz._memory`: available memory, RLIMIT_AS, the cgroup's limit)."""
    from xray_viz._memory import check_allocation

    check_allocation(int(n) * int(h) * int(w) * 4,
                     f"{where}a stack of {n} projections of {w} x {h} float32 pixels", fix,
                     error=SceneError if not where else OutputError)


def _check_complete(path) -> None:
    """Refuse in one line a store whose ``done`` flags are not all set (as :func:`read_zarr`
    does, without reading its geometry back)."""
    done = done_flags(_zarr().open_group(str(path), mode="r"))
    if not done.all():
        missing = np.flatnonzero(~done)
        raise OutputError(f"{path}: {len(missing)} of {len(done)} projections are missing "
                          f"(first: {missing[0]}); run the same scan again to fill them")


def _bar(total, progress):
    from tqdm import tqdm

    return tqdm(total=total, unit="proj", disable=not (progress and sys.stderr.isatty()),
                file=sys.stderr)


# ---------------------------------------------------------------------------------- Zarr

def _zarr():
    try:
        import zarr
    except ImportError:
        raise OutputError("Zarr stores need the ct extra: pip install 'xray_viz[ct]'") from None
    return zarr


def _canonical(doc) -> str:
    return json.dumps(doc, sort_keys=True)


def _attrs(scene, quantity, geometry, arrays: bool = False, physics=None) -> dict:
    try:
        text = scene.to_toml()
    except SceneError:
        text = None                 # bodies built in Python: no scene file to keep
    return {"version": ARRAYS_LAYOUT_VERSION if arrays else LAYOUT_VERSION,
            "quantity": quantity, "units": "1" if quantity == "line-integral" else "photons",
            "geometry": _geometry_attr(geometry) if arrays else geometry,
            "physics": _physics(scene) if physics is None else physics, "scene": text,
            "bodies": bodies_digest(scene)}


def bodies_digest(scene) -> str:
    """Hex SHA-256 of what the bodies are: each body's name, material or ``mu``, and its
    mesh's vertex and face arrays (dtype, shape, bytes); then, when the scene has voxel
    volumes, each volume's name, materials, interpolation, affine, classes and weights (a
    scene without volumes has the digest it had before volumes existed). A store keeps it:
    the scene file names its mesh and CT files by path, so a file changed between two runs
    would otherwise resume a scan with other bodies (or two scenes built in Python, which
    have no scene file, would pass for one).

    Examples
    --------
    >>> import xray_viz
    >>> len(bodies_digest(xray_viz.load_scene("sphere")))
    64
    """
    h = hashlib.sha256(b"xray_viz bodies 1")
    for body in scene.bodies:
        h.update(repr((body.name, body.material, body.mu)).encode())
        for a in (body.mesh.vertices, body.mesh.faces):
            a = np.ascontiguousarray(a)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(memoryview(a).cast("B"))
    for vol in scene.volumes:
        h.update(repr(("volume", vol.name, vol.interpolation,
                       [(m.name, m.mu, m.material, m.density) for m in vol.materials])).encode())
        for a in (vol.affine, vol.classes, vol.weights):
            a = np.ascontiguousarray(a)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def _geometry_attr(geometry) -> dict:
    """The geometry as a store with pose arrays keeps it in JSON: ``poses`` and
    ``projection_matrices`` replaced (in place, key order kept) by ``per_projection_arrays``,
    the names of the arrays that hold them."""
    out = {}
    for key, value in geometry.items():
        if key == "poses":
            out["per_projection_arrays"] = {"poses": "poses", "pose_rows": list(POSE_ROWS),
                                            "projection_matrices": "projection_matrices"}
        elif key != "projection_matrices":
            out[key] = value
    return out


def _geometry_from_store(group, geometry) -> dict:
    """The geometry dict of a store's attributes, the per-projection arrays read back into
    lists (the dict :func:`scan_geometry` made, whichever way the store keeps it)."""
    where = geometry.get("per_projection_arrays")
    if where is None:
        return geometry
    poses, mats = pose_lists(group[where["poses"]][:],
                                        group[where["projection_matrices"]][:])
    out = {}
    for key, value in geometry.items():
        if key == "per_projection_arrays":
            out["poses"], out["projection_matrices"] = poses, mats
        else:
            out[key] = value
    return out


def open_store(path, *, scene, geometry, quantity="line-integral", pose_arrays=None,
               _tables=None, physics=None):
    """The Zarr v3 group of a scan at ``path``: created (whole, or not at all) if missing,
    otherwise opened for resuming after checking that it holds the same scan.

    Layout: array ``projections`` ``(n, H, W)`` float32 in chunks of one projection, array
    ``done`` ``(n,)`` bool (one chunk per projection, so concurrent writers never share a
    chunk), for intensities arrays ``flat`` and ``dark`` ``(H, W)`` float32
    (:func:`flat_dark`), attributes ``{"xray_viz": {"version", "quantity", "units",
    "geometry", "physics", "scene"}}``. With ``pose_arrays`` (default: more than
    :data:`INLINE_POSES_MAX` projections) the per-projection poses and projection matrices
    are arrays ``poses`` ``(n, 4, 3)`` float64 (rows :data:`POSE_ROWS`) and
    ``projection_matrices`` ``(n, 3, 4)`` float64, the geometry attribute names them
    (``per_projection_arrays``) and the version is :data:`ARRAYS_LAYOUT_VERSION`: the JSON
    stays small whatever ``n`` (:func:`read_zarr` gives the same geometry dict either way).
    A store being resumed keeps its own way.

    Raises
    ------
    OutputError
        If ``path`` holds something else (another scan, or not a scan store).
    """
    zarr = _zarr()
    path = Path(path)
    n = geometry["projections"]
    if pose_arrays is None:
        pose_arrays = n > INLINE_POSES_MAX
    if path.exists():
        try:
            return _open_existing(zarr, path, scene=scene, geometry=geometry,
                                  quantity=quantity, tables=_tables, physics=physics)
        except OutputError:
            raise
        except Exception as exc:               # damaged metadata: any of zarr's errors
            raise OutputError(f"{path}: cannot be read as a scan store ({_reason(exc)}); it "
                              "is damaged or not a store: remove it or choose another -o") \
                from None
    return _create_store(zarr, path, scene=scene, geometry=geometry, quantity=quantity,
                         pose_arrays=pose_arrays, tables=_tables, physics=physics)


def _open_existing(zarr, path, *, scene, geometry, quantity, tables=None, physics=None):
    """The group of an existing store holding the same scan, its arrays checked
    (``tables``: the per-projection arrays where ``geometry`` has no lists)."""
    n = geometry["projections"]
    try:
        group = zarr.open_group(str(path), mode="r+")
        old = dict(group.attrs).get("xray_viz")
    except Exception as exc:               # zarr raises many kinds for a non-store
        raise OutputError(f"{path} exists and is not a Zarr scan store ({exc}); remove it "
                          "or choose another -o") from None
    arrays = isinstance(old, dict) and isinstance(old.get("geometry"), dict) and \
        "per_projection_arrays" in old["geometry"]
    if not arrays:
        geometry = _with_lists(geometry, tables)
    new = json.loads(_canonical(_attrs(scene, quantity, geometry, arrays, physics)))
    same = isinstance(old, dict) and all(
        _canonical(old.get(k)) == _canonical(new[k])
        for k in ("version", "quantity", "geometry", "physics", "scene")
        + (("bodies",) if "bodies" in old else ()))     # older stores: without it
    if same and arrays:
        poses, mats = pose_arrays_of(geometry) if tables is None else tables
        try:
            same = np.array_equal(group["poses"][:], poses) and \
                np.array_equal(group["projection_matrices"][:], mats)
        except KeyError:
            same = False
        except Exception as exc:             # a damaged chunk: a codec's error
            raise OutputError(f"{path}: its pose arrays cannot be read "
                              f"({_reason(exc)}); remove it and scan again") from None
    if not same:
        raise OutputError(f"{path} holds another scan (its geometry, physics, quantity, "
                          "scene, voxel volumes or bodies' meshes differ); remove it or "
                          "choose another -o to keep both")
    w, h = geometry["detector"]["shape"]
    proj, done = group["projections"], group["done"]
    if (proj.shape, proj.chunks, proj.dtype, done.shape, done.chunks, done.dtype) != \
            ((n, h, w), (1, h, w), np.float32, (n,), (1,), np.bool_):
        raise OutputError(f"{path}: its arrays' metadata do not match its scan (projections "
                          f"{list(proj.shape)} {proj.dtype}, done {list(done.shape)} "
                          f"{done.dtype}); it is damaged: remove it and scan again")
    return group


def _create_store(zarr, path, *, scene, geometry, quantity, pose_arrays, tables=None,
                  physics=None):
    """A new store at ``path``, made whole in a temporary folder and renamed."""
    n = geometry["projections"]
    if not pose_arrays:
        geometry = _with_lists(geometry, tables)
    attrs = _attrs(scene, quantity, geometry, pose_arrays, physics)
    w, h = geometry["detector"]["shape"]
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        group = zarr.open_group(str(tmp), mode="w")
        group.create_array("projections", shape=(n, h, w), chunks=(1, h, w), dtype="float32",
                           fill_value=np.nan, compressors=_checked_codecs())
        group.create_array("done", shape=(n,), chunks=(1,), dtype="bool", fill_value=False)
        first = geometry if geometry.get("poses") is not None else \
            {"poses": [pose_dict(tables[0][0])]}
        flat, dark = flat_dark(scene, first, quantity)
        for name, field in (("flat", flat), ("dark", dark)):
            if field is not None:
                group.create_array(name, shape=(h, w), chunks=(h, w), dtype="float32",
                                   fill_value=np.nan, compressors=_checked_codecs())[:] = field
        if pose_arrays:
            for name, table in zip(("poses", "projection_matrices"),
                                   pose_arrays_of(geometry) if tables is None else tables):
                group.create_array(name, shape=table.shape, dtype="float64", fill_value=np.nan,
                                   chunks=(min(n, 1 << 16),) + table.shape[1:],
                                   compressors=_checked_codecs())[:] = table
        group.attrs["xray_viz"] = attrs
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return zarr.open_group(str(path), mode="r+")


def done_flags(group) -> np.ndarray:
    """``(n,)`` bool: the ``done`` flags of a scan store's group.

    A flag is set by writing ``True`` into its own one-element chunk, and Zarr stores no chunk
    that equals the fill value (``False``; ``array.write_empty_chunks`` off, Zarr's default):
    so in a local store the flags are the names of the chunk files present, one directory
    listing, instead of one read per projection (100,000 reads take minutes). Other stores,
    other chunk key encodings or settings: the array read whole.
    """
    import zarr

    done = group["done"]
    n = done.shape[0]
    try:
        enc = done.metadata.chunk_key_encoding
        root = Path(group.store.root) / group.path / "done" / "c"
        fast = (not zarr.config.get("array.write_empty_chunks")
                and getattr(enc, "name", None) == "default"
                and getattr(enc, "separator", None) == "/" and done.chunks == (1,)
                and isinstance(group.store, zarr.storage.LocalStore))
    except (AttributeError, TypeError):
        fast = False
    if not fast:
        try:
            return np.asarray(done[:], bool)
        except Exception:                   # a damaged flag's chunk: read them one by one
            return np.array([_flag(done, k) for k in range(n)], bool)
    out = np.zeros(n, bool)
    if root.is_dir():
        with os.scandir(root) as entries:
            ks = [int(e.name) for e in entries if e.name.isdigit()]
        ks = np.asarray(ks, np.int64)
        out[ks[ks < n]] = True
    return out


def _checked_codecs():
    """Zstd, then a CRC-32C of the compressed bytes: a chunk cut short or with a flipped bit
    fails to decode instead of giving wrong numbers (Zstd alone checks neither)."""
    from zarr.codecs import Crc32cCodec, ZstdCodec

    return [ZstdCodec(), Crc32cCodec()]


def _reason(exc) -> str:
    from xray_viz.errors import one_line

    return one_line(f"{type(exc).__name__}: {exc}", limit=120)


#: Bytes of projections :func:`damaged_projections` reads at a time.
VERIFY_BLOCK_BYTES = 32 << 20


def damaged_projections(group, done=None) -> np.ndarray:
    """The projections flagged ``done`` whose chunk is missing or does not decode (cut
    short; a flipped bit where the store keeps a checksum, as :func:`open_store` makes it):
    their indices, sorted.

    Every flagged chunk is read and decoded, a block of :data:`VERIFY_BLOCK_BYTES` at a time
    (memory stays bounded whatever the store's size); a chunk that is absent reads as the
    fill value NaN in every pixel, which no rendered projection holds.
    """
    arr = group["projections"]
    done = done_flags(group) if done is None else np.asarray(done, bool)
    ks = np.flatnonzero(done)
    h, w = arr.shape[1:]
    block = max(1, VERIFY_BLOCK_BYTES // max(1, 4 * h * w))
    bad = []

    def one(k):
        try:
            return np.isnan(arr[int(k)]).all()
        except Exception:                  # a codec's error: cut short, checksum mismatch
            return True

    for i in range(0, len(ks), block):
        part = ks[i:i + block]
        try:
            data = arr.get_orthogonal_selection((part, slice(None), slice(None)))
        except Exception:
            bad.extend(int(k) for k in part if one(k))
            continue
        bad.extend(int(k) for k in part[np.isnan(data).all(axis=(1, 2))])
    return np.asarray(bad, np.int64)


def _damaged_message(path, bad) -> str:
    many = f"{len(bad)} projections flagged done are" if len(bad) > 1 else \
        "a projection flagged done is"
    return (f"{path}: {many} damaged or missing (projection {bad[0]}"
            f"{', ...' if len(bad) > 1 else ''}: its chunk is absent or does not decode)")


def _repair_done(group, path) -> int:
    """Unset the ``done`` flags of :func:`damaged_projections` (so that they are rendered
    again), saying so on stderr; how many."""
    try:
        done = done_flags(group)
        if not done.any():
            return 0
        bad = damaged_projections(group, done)
    except Exception as exc:
        raise OutputError(f"{path}: its projections cannot be checked ({_reason(exc)}); it is "
                          "damaged: remove it and scan again") from None
    for k in bad:
        group["done"][int(k)] = False
    if len(bad):
        print(f"xray-viz: {_damaged_message(path, bad)}; rendering "
              f"{'them' if len(bad) > 1 else 'it'} again", file=sys.stderr)
    return len(bad)


def _flag(done, k) -> bool:
    """``done[k]``, False where its chunk does not read (the projection is then rendered
    again)."""
    try:
        return bool(done[int(k)])
    except Exception:
        return False


def _write_projection(group, k, image) -> None:
    """Chunk first, then the flag: a store never claims a projection it does not hold."""
    group["projections"][k] = image
    group["done"][k] = True


def write_zarr(result: Scan, path) -> None:
    """Write a :class:`Scan` held in memory as a complete Zarr store (see :func:`open_store`)."""
    group = open_store(path, scene=result.scene, quantity=result.quantity,
                       geometry=result.geometry, physics=result.physics)
    for k in np.flatnonzero(~done_flags(group)):
        _write_projection(group, int(k), result.projections[k])


def read_zarr(path, *, scene=None, require_complete: bool = True, lazy: bool = False,
              verify: bool = True) -> Scan:
    """The :class:`Scan` of a Zarr store.

    ``lazy``: ``projections`` is the store's read-only ``zarr.Array`` (read projection by
    projection as it is indexed) instead of the whole stack in memory.

    The one reader of the layout (CT-LAYOUT.md): :func:`xray_viz.reconstruct.reconstruct_file`
    reads its stores through it. A projection flagged ``done`` whose chunk is missing or
    damaged is refused, never handed out as the fill value NaN (``verify``: with ``lazy``,
    every flagged chunk is read once to check it, a block at a time; False skips that, for a
    store just written and verified).

    Raises
    ------
    OutputError
        In one line: no such store, not a Zarr scan store (no ``xray_viz`` attributes with a
        geometry, no ``projections``), projections missing (their ``done`` flag unset) when
        ``require_complete``, or projections flagged done but damaged or missing (always).
    """
    zarr = _zarr()
    path = Path(path)
    if not path.exists():
        raise OutputError(f"{path}: no such scan store; write one with `xray-viz scan SCENE -o "
                          "scan.zarr`")
    try:
        return _read_zarr(zarr, path, scene=scene, require_complete=require_complete,
                          lazy=lazy, verify=verify)
    except OutputError:
        raise
    except Exception as exc:        # damaged metadata: any of zarr's (or JSON's) errors
        raise OutputError(f"{path}: cannot be read as a scan store ({_reason(exc)}); it is "
                          "damaged: remove it and scan again") from None


def _read_zarr(zarr, path, *, scene, require_complete, lazy, verify) -> Scan:
    """:func:`read_zarr` of a store that exists."""
    try:
        group = zarr.open_group(str(path), mode="r")
        meta = dict(group.attrs).get("xray_viz")
        names = set(group.array_keys())
    except Exception as exc:    # zarr raises many kinds for a folder that is not a store
        raise OutputError(f"{path}: not a Zarr scan store ({type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:200]})") from None
    if not isinstance(meta, dict) or "geometry" not in meta:
        raise OutputError(f"{path}: no 'xray_viz' attributes with a geometry; is it a store "
                          "written by `xray-viz scan`?")
    version = meta.get("version", LAYOUT_VERSION)
    if not isinstance(version, int) or version > ARRAYS_LAYOUT_VERSION:
        raise OutputError(f"{path}: layout version {version!r} is newer than this xray_viz "
                          f"reads (<= {ARRAYS_LAYOUT_VERSION}); upgrade xray_viz")
    where = meta["geometry"].get("per_projection_arrays") \
        if isinstance(meta["geometry"], dict) else None
    if where is not None and not {where.get("poses"), where.get("projection_matrices")} <= names:
        raise OutputError(f"{path}: the geometry's per-projection arrays "
                          f"{where.get('poses')!r}, {where.get('projection_matrices')!r} are "
                          "missing from the store")
    if "projections" not in names:
        raise OutputError(f"{path}: has no 'projections' array")
    again = "run the same scan again to render them again"
    what = "its done flags"
    try:
        n = group["projections"].shape[0]
        done = done_flags(group) if "done" in names else np.ones(n, bool)
        if require_complete and not done.all():
            missing = np.flatnonzero(~done)
            raise OutputError(f"{path}: {len(missing)} of {len(done)} projections are missing "
                              f"(first: {missing[0]}); run the same scan again to fill them")

        def field(name):
            return np.asarray(group[name][:], np.float64) if name in names else None

        what = "its flat or dark field"
        flat, dark = field("flat"), field("dark")
        what = "its per-projection poses"
        geometry = _geometry_from_store(group, meta["geometry"])
        what = "its projections"
        if not lazy:
            _check_stack(*group["projections"].shape, "read it with lazy=True (projection by "
                         "projection)", where=f"{path}: ")
        if lazy:
            stack = group["projections"]
            bad = damaged_projections(group, done) if verify else ()
        else:
            try:
                stack = group["projections"][:]
                bad = np.flatnonzero(done & np.isnan(stack).all(axis=(1, 2)))
            except OutputError:
                raise
            except Exception:                   # which ones: read them one by one
                stack, bad = None, damaged_projections(group, done)
                if not len(bad):
                    raise
        if len(bad):
            raise OutputError(f"{_damaged_message(path, bad)}; {again}")
    except OutputError:
        raise
    except Exception as exc:                    # a codec's error on a damaged chunk
        raise OutputError(f"{path}: {what} cannot be read ({_reason(exc)}); the store is "
                          "damaged: remove it and scan again") from None
    return Scan(stack, geometry, meta.get("quantity", "line-integral"),
                meta.get("physics") or {}, scene, flat=flat, dark=dark)


# ---------------------------------------------------------------------------------- TIFF, NeXus

def _units(quantity) -> str:
    return "1" if quantity == "line-integral" else "photons"


def _file_geometry(geometry, poses=None, mats=None):
    """``(geometry for the file's JSON, per-projection tables or None)``: above
    :data:`INLINE_POSES_MAX` projections the JSON names the tables (``per_projection_arrays``,
    as a Zarr store's attributes do) instead of listing every pose."""
    if geometry.get("poses") is not None and geometry["projections"] <= INLINE_POSES_MAX:
        return geometry, None
    if poses is None:
        poses, mats = pose_arrays_of(geometry)
    return _geometry_attr(geometry), (np.asarray(poses, np.float64),
                                      np.asarray(mats, np.float64))


@contextlib.contextmanager
def _tiff_writer(folder, *, n, quantity, physics, geometry, tables):
    """Yield ``write(k, image)``: one float32 TIFF per projection as it comes, into a
    temporary folder renamed to ``folder`` when the block ends without an error (removed
    otherwise); ``geometry.json`` (and ``poses.npy``, ``projection_matrices.npy`` when
    ``tables``) written first."""
    import tifffile

    folder = Path(folder)
    if folder.exists():
        raise OutputError(f"{folder} exists; remove it or choose another -o")
    tmp = folder.with_name(f".{folder.name}.partial-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        meta = {"quantity": quantity, "units": _units(quantity), "geometry": geometry,
                "physics": physics}
        (tmp / "geometry.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
        if tables is not None:
            np.save(tmp / "poses.npy", tables[0])
            np.save(tmp / "projection_matrices.npy", tables[1])
        digits = max(5, len(str(n - 1)))

        def write(k, image):
            tifffile.imwrite(tmp / f"proj_{int(k):0{digits}d}.tif",
                             np.asarray(image, np.float32))

        yield write
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_tiff_stack(result: Scan, folder) -> Path:
    """One float32 TIFF per projection (``proj_00000.tif`` ...) and ``geometry.json`` in
    ``folder`` (written into a temporary folder, then renamed; refused if it exists). Above
    :data:`INLINE_POSES_MAX` projections ``geometry.json`` names ``poses.npy`` and
    ``projection_matrices.npy`` (``per_projection_arrays``) instead of listing every pose."""
    n = result.projections.shape[0]
    geometry, tables = _file_geometry(result.geometry)
    with _tiff_writer(folder, n=n, quantity=result.quantity, physics=result.physics,
                      geometry=geometry, tables=tables) as write:
        for k in range(n):               # one at a time: a store's lazy stack stays on disk
            write(k, result.projections[k])
    return Path(folder)


@contextlib.contextmanager
def _nexus_writer(path, *, n, shape, quantity, physics, geometry, tables, flush_every=8):
    """Yield ``write(k, image)``: projection ``k`` into the NXtomo file's ``data`` as it comes
    (flushed every ``flush_every``), in a temporary file renamed to ``path`` when the block
    ends without an error (removed otherwise)."""
    import h5py

    from xray_viz.output import check_room

    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    g = geometry
    check_room(path, 4 * n * int(np.prod(shape)), what="the NeXus file")
    angles = np.asarray(g["angles_deg"] if g["angles_deg"] is not None else np.zeros(n))
    w, h = shape
    try:
        with h5py.File(tmp, "w") as f:
            entry = f.create_group("entry")
            entry.attrs["NX_class"] = "NXentry"
            entry["definition"] = "NXtomo"
            inst = entry.create_group("instrument")
            inst.attrs["NX_class"] = "NXinstrument"
            src = inst.create_group("source")
            src.attrs["NX_class"] = "NXsource"
            src["type"] = "Fixed Tube X-ray"
            src["probe"] = "x-ray"
            det = inst.create_group("detector")
            det.attrs["NX_class"] = "NXdetector"
            data = det.create_dataset("data", shape=(n, h, w), dtype="float32",
                                      chunks=(1, h, w))
            data.attrs["units"] = _units(quantity)
            det["image_key"] = np.zeros(n, np.int32)          # 0: a projection
            for name, value in (("x_pixel_size", g["detector"]["pitch_mm"][0]),
                                ("y_pixel_size", g["detector"]["pitch_mm"][1]),
                                ("distance", g["sid_mm"] - (g["sod_mm"] or 0.0))):
                det[name] = value
                det[name].attrs["units"] = "mm"
            sample = entry.create_group("sample")
            sample.attrs["NX_class"] = "NXsample"
            sample["name"] = "xray_viz scene"
            sample["rotation_angle"] = angles
            sample["rotation_angle"].attrs["units"] = "degree"
            nxdata = entry.create_group("data")
            nxdata.attrs["NX_class"] = "NXdata"
            nxdata.attrs["signal"] = "data"
            nxdata["data"] = data
            nxdata["rotation_angle"] = sample["rotation_angle"]
            nxdata["image_key"] = det["image_key"]
            entry["xray_viz_geometry"] = json.dumps({"quantity": quantity, "geometry": g,
                                                     "physics": physics})
            if tables is not None:          # named by the geometry's per_projection_arrays
                entry["poses"] = tables[0]
                entry["projection_matrices"] = tables[1]
            f.flush()

            def write(k, image):
                data[int(k)] = np.asarray(image, np.float32)
                if (int(k) + 1) % max(1, flush_every) == 0:
                    f.flush()

            yield write
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_nexus(result: Scan, path) -> Path:
    """HDF5 in the NeXus NXtomo layout (``/entry/instrument/detector/data`` ``(n, H, W)``,
    ``image_key``, ``/entry/sample/rotation_angle`` in degrees, ``/entry/data`` links), with
    the geometry dict as JSON in ``/entry/xray_viz_geometry`` (above
    :data:`INLINE_POSES_MAX` projections it names the datasets ``/entry/poses`` and
    ``/entry/projection_matrices``, ``per_projection_arrays``, instead of listing every
    pose). Written to a temporary file, projection by projection, then renamed."""
    n, h, w = result.projections.shape
    geometry, tables = _file_geometry(result.geometry)
    with _nexus_writer(path, n=n, shape=(w, h), quantity=result.quantity,
                       physics=result.physics, geometry=geometry, tables=tables) as write:
        for k in range(n):               # one at a time: a store's lazy stack stays on disk
            write(k, result.projections[k])
    return Path(path)


def _check_disk(out, nbytes: int) -> None:
    """Refuse, in one line and before any work, a file of ``nbytes`` where the disk has less
    free (HDF5 running out of space mid-write cannot close its file cleanly: the process
    then crashes; a disk that fills up meanwhile is not foreseen)."""
    from xray_viz._memory import format_bytes

    folder = Path(out).absolute().parent
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return
    free = st.f_bavail * st.f_frsize
    if nbytes > free:
        raise OutputError(f"{out}: the scan needs about {format_bytes(nbytes)} on disk and "
                          f"{folder} has {format_bytes(free)} free; free some space or choose "
                          "another -o")


def _scan_to_file(scene, orbit, out, kind, *, quantity, engine, batch, progress,
                  scatter=None, histories=None, scatter_smoothing=None) -> int:
    """Render a scan straight into a NeXus file or a TIFF folder (``kind``), projection by
    projection as they come: memory is one projection, the geometry is built as arrays
    (:func:`pose_table`, no per-projection dicts), the first projections are on disk while
    the rest render. The number of projections."""
    _check_quantity(quantity)
    n = orbit.projections
    poses, mats = pose_table(scene, orbit)
    geometry, tables = _file_geometry({**_geometry_head(scene, orbit), "poses": None},
                                      poses, mats)
    if n <= INLINE_POSES_MAX:
        geometry = _geometry_head(scene, orbit)
        geometry["poses"], geometry["projection_matrices"] = pose_lists(poses, mats)
        tables = None
    del poses, mats
    w, h = scene.detector.shape
    _check_disk(out, n * (h * w * 4 + (1024 if kind == "tiff" else 64))
                + (0 if tables is None else tables[0].nbytes + tables[1].nbytes) + (1 << 20))
    opener = _nexus_writer if kind == "nexus" else _tiff_writer
    extra = {"shape": tuple(scene.detector.shape), "flush_every": batch} \
        if kind == "nexus" else {}
    with opener(out, n=n, quantity=quantity,
                physics=_physics(scene, scatter, histories, scatter_smoothing),
                geometry=geometry, tables=tables, **extra) as write:
        project = Projections(scene, orbit, quantity=quantity, engine=engine,
                              scatter=scatter, histories=histories,
                              scatter_smoothing=scatter_smoothing)
        bar = _bar(n, progress)
        for k in range(n):
            write(k, project(k))
            bar.update(1)
            if (k + 1) % max(1, batch) == 0:
                trim_memory()
        bar.close()
    return n


# ---------------------------------------------------------------------------------- Dask

def _scene_text(scene) -> str:
    try:
        return scene.to_toml()
    except SceneError as exc:
        raise SceneError(f"a scan on a Dask cluster ships the scene as a scene file, and this "
                         f"scene has none: {exc}") from None


def trim_memory() -> bool:
    """Give freed heap memory back to the operating system (glibc's ``malloc_trim(0)``): a
    batch's scratch images, freed by Python, otherwise stay in the process's resident set.
    True if memory was released; False where there is no glibc (macOS, Windows, musl).

    Examples
    --------
    >>> trim_memory() in (True, False)
    True
    """
    import ctypes
    import ctypes.util

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.malloc_trim(0))
    except (OSError, AttributeError):
        return False


def _one_numba_thread() -> None:
    """One numba thread for this thread's kernels (numba's count is per thread: the worker
    plugin's ``setup`` runs on the event loop, the tasks on the executor's thread)."""
    try:
        import numba

        if numba.get_num_threads() != 1:
            numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass


def warm_kernels(engine: str = "fast") -> list:
    """Compile, or load from numba's cache (shared by every process of the machine), the
    fast engine's kernels now; their names. A worker calls it when it starts, so no task pays
    for it."""
    from xray_viz.tracing.engines import ENGINES

    if not ENGINES[engine].compiled:
        return []
    from xray_viz.tracing import _raster

    return _raster.KERNELS.compile()


def _scene_plugin(engine: str = "fast"):
    """A worker plugin that holds the scenes a worker has loaded (by content hash), runs
    numba on one thread per worker process and warms the kernels when the worker starts."""
    from distributed import WorkerPlugin

    class ScenePlugin(WorkerPlugin):
        name = PLUGIN_NAME
        idempotent = True       # a second scan on the cluster keeps the workers' loaded scenes

        def setup(self, worker):
            self.scenes = {}
            _one_numba_thread()
            # on the task thread, ahead of any task (the event loop stays free meanwhile)
            executor = worker.executors.get("default")
            self.warm = executor.submit(_warm_thread, engine) if executor is not None else None

    return ScenePlugin()


def _warm_thread(engine: str) -> dict:
    """A worker's start on its task thread: one numba thread, the kernels warmed."""
    import time

    _one_numba_thread()
    t0 = time.perf_counter()
    names = warm_kernels(engine)
    import numba

    return {"kernels": names, "seconds": time.perf_counter() - t0,
            "numba_threads": numba.get_num_threads()}


def _worker_scenes():
    """The loaded-scene dict of this Dask worker's plugin, or None outside a worker."""
    try:
        from distributed import get_worker

        plugin = get_worker().plugins.get(PLUGIN_NAME)
    except (ImportError, ValueError):
        return None
    return getattr(plugin, "scenes", None)


def _load_scene_text(text: str, digest: str):
    """The scene of a scene-file text, loaded once per worker process (keyed by ``digest``,
    the SHA-256 of the text, then ``:`` and :func:`bodies_digest` of the client's scene,
    checked against the meshes the worker reads): its per-mesh set-up is then reused by
    every task."""
    import tomllib

    from xray_viz.scene_file import scene_from_dict

    cache = _worker_scenes()
    if cache is not None and digest in cache:
        return cache[digest]
    text_digest, _, bodies = digest.partition(":")
    if hashlib.sha256(text.encode()).hexdigest() != text_digest:
        raise SceneError("the scene text does not match its hash")
    scene = scene_from_dict(tomllib.loads(text))
    if bodies and bodies_digest(scene) != bodies:    # a mesh or CT file changed since
        raise SceneError("the scene's mesh files read on this worker differ from those the "
                         "scan started with, or its CT or label volumes do (changed since, or "
                         "another file at that path); scan again once they are fixed")
    if cache is not None:
        cache.clear()                           # one scene per worker: memory stays bounded
        cache[digest] = scene
    return scene


def render_batch(scene_text: str, digest: str, orbit: Orbit, indices, *, store: str,
                 quantity: str = "line-integral", engine: str = "fast", scatter=None,
                 histories=None, scatter_smoothing=None) -> list[int]:
    """A Dask task: render projections ``indices`` of a scan and write each into the Zarr
    ``store`` (chunk, then ``done`` flag). Projections already flagged are skipped.

    Returns
    -------
    list of int
        The projections this task wrote.
    """
    zarr = _zarr()
    if _worker_scenes() is not None:
        _one_numba_thread()
    scene = _load_scene_text(scene_text, digest)
    group = zarr.open_group(store, mode="r+")
    wrote = []
    project = Projections(scene, orbit, quantity=quantity, engine=engine, scatter=scatter,
                          histories=histories, scatter_smoothing=scatter_smoothing)
    try:
        for k in indices:
            k = int(k)
            if _flag(group["done"], k):
                continue
            _write_projection(group, k, project(k))
            wrote.append(k)
    finally:
        trim_memory()                   # the batch's scratch memory back to the system
    return wrote


def _scan_dask(client, scene, orbit, store, todo, *, quantity, engine, batch, progress,
               scatter=None, histories=None, scatter_smoothing=None):
    import uuid

    from distributed import as_completed

    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise SceneError(f"batch must be a whole number >= 1, got {batch!r}")
    text = _scene_text(scene)
    # the text names the mesh files by path: the bodies' own digest keys the workers' scenes
    digest = f"{hashlib.sha256(text.encode()).hexdigest()}:{bodies_digest(scene)}"
    client.register_plugin(_scene_plugin(engine), name=PLUGIN_NAME)
    if progress and sys.stderr.isatty():
        print(f"xray-viz: Dask dashboard: {client.dashboard_link}", file=sys.stderr)
    run = uuid.uuid4().hex[:8]
    store = str(Path(store).resolve())
    futures = [client.submit(render_batch, text, digest, orbit, todo[i:i + batch],
                             store=store, quantity=quantity, engine=engine,
                             scatter=scatter, histories=histories,
                             scatter_smoothing=scatter_smoothing,
                             key=f"xray-viz-scan-{run}-{i}", retries=2)
               for i in range(0, len(todo), batch)]
    sizes = {f.key: len(todo[i * batch:(i + 1) * batch]) for i, f in enumerate(futures)}
    bar = _bar(len(todo), progress)
    try:
        for future in as_completed(futures):
            bar.update(sizes[future.key])
            future.result()                 # a failed task raises here; finished ones stay
    finally:
        bar.close()
        for future in futures:
            future.cancel()


def local_cluster(workers: int):
    """A ``distributed.LocalCluster`` of ``workers`` processes on 127.0.0.1, one thread (and
    one numba thread) each."""
    from distributed import LocalCluster

    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                        host="127.0.0.1", dashboard_address="127.0.0.1:0",
                        env={"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})


# ---------------------------------------------------------------------------------- CLI

def add_scan_parser(subparsers) -> None:
    """Register ``xray-viz scan`` on an argparse sub-parser collection."""
    p = subparsers.add_parser(
        "scan", help="scan a scene along a CT orbit into a projection stack",
        description="Render every projection of a CT orbit (the scene's [scan] table, "
                    "changed by the options) and write the stack: OUT ending in .zarr is a "
                    "Zarr v3 store (resumable: running the command again fills only the "
                    "missing projections), .nxs/.h5 HDF5 NeXus NXtomo, no suffix a folder of "
                    "TIFFs with geometry.json.")
    p.add_argument("scene", metavar="SCENE", help="a scene .toml file or a bundled phantom")
    p.add_argument("-o", "--output", required=True, metavar="OUT")
    p.add_argument("--orbit", choices=("circular", "helical"), default=None)
    p.add_argument("--projections", type=int, default=None, metavar="N")
    p.add_argument("--arc", type=float, default=None, metavar="DEG")
    p.add_argument("--pitch", type=float, default=None, metavar="MM",
                   help="helical: mm along the axis per turn")
    p.add_argument("--axis", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"))
    p.add_argument("--center", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"))
    p.add_argument("--quantity", choices=SCAN_QUANTITIES, default="line-integral")
    p.add_argument("--engine", choices=("fast", "numpy"), default="fast")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="N > 1: a Dask LocalCluster of N worker processes on 127.0.0.1")
    p.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="an existing Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--batch", type=int, default=8, metavar="N",
                   help="projections per Dask task (default %(default)s)")
    from xray_viz.render import add_scatter_arguments

    add_scatter_arguments(p, per="projection")
    p.set_defaults(func=scan_command)


def _cli_orbit(scene, args) -> Orbit:
    table = (scene.orbit if scene.orbit is not None
             else default_orbit(scene)).to_dict()
    for key in ("orbit", "projections", "arc", "pitch", "axis", "center"):
        value = getattr(args, key)
        if value is not None:
            table[key] = value
    if table.get("orbit") in ("circular", "helical"):
        table.pop("poses", None)
    if table.get("orbit") == "circular" and args.orbit == "circular":
        if args.pitch:                       # not dropped without a word
            raise SceneError(f"--pitch {args.pitch:g} does not apply to --orbit circular (a "
                             "circle has no pitch): use --orbit helical")
        table["pitch"] = 0.0
    if table.get("orbit") == "helical" and "pitch" not in table:
        raise SceneError("--orbit helical needs --pitch (mm per turn)")
    return orbit_from_dict(table)


#: Seconds to wait for a Dask scheduler at ``--scheduler`` to connect and greet.
SCHEDULER_TIMEOUT = 10.0
#: Largest first message a Dask scheduler's greeting (its handshake) may announce, bytes.
_HANDSHAKE_MAX = 1 << 24


def check_scheduler(address: str, *, timeout: float | None = None) -> str:
    """Check that ``address`` (``--scheduler``) is ``tcp://HOST:PORT`` and that a Dask
    scheduler answers there, before Dask is handed the address; the address, normalised.

    A Dask scheduler greets every connection with its handshake, a message whose 8-byte
    length is small; an SSH server's banner read as that length asks for exabytes, an HTTP
    server says nothing until asked. Both are refused here in one line, within ``timeout``
    seconds (:data:`SCHEDULER_TIMEOUT`), as are a malformed address and one where nothing
    listens.

    Raises
    ------
    SceneError
        One line naming the address and what answered (or did not).
    """
    import re
    import socket
    import struct

    timeout = SCHEDULER_TIMEOUT if timeout is None else float(timeout)
    m = re.fullmatch(r"(?:tcp://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})", address.strip())
    if m is None or not 0 < int(m.group(2)) < 65536:
        raise SceneError(f"--scheduler {address!r}: not a Dask scheduler address; give "
                         "tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786, the address `dask "
                         "scheduler` prints)")
    host, port = m.group(1).strip("[]"), int(m.group(2))
    where = f"--scheduler tcp://{m.group(1)}:{port}"
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            sock.settimeout(timeout)
            head = b""
            while len(head) < 8:
                got = sock.recv(8 - len(head))
                if not got:
                    break
                head += got
    except socket.timeout:
        raise SceneError(f"{where}: no answer within {timeout:g} s (a Dask scheduler greets "
                         "at once: is this another kind of server, e.g. HTTP, or the "
                         "dashboard's port instead of the scheduler's?)") from None
    except OSError as exc:
        raise SceneError(f"{where}: cannot connect: {exc.strerror or exc}; is the Dask "
                         "scheduler running there?") from None
    if len(head) < 8:
        raise SceneError(f"{where}: the server closed the connection without a Dask "
                         "scheduler's greeting; is it the scheduler's port?")
    (length,) = struct.unpack("<Q", head)
    if not 0 < length <= _HANDSHAKE_MAX:
        kind = "an SSH server" if head.startswith(b"SSH-") else "not a Dask scheduler"
        raise SceneError(f"{where}: the server there is {kind} (its first bytes are not a "
                         "Dask handshake); give the scheduler's address (default port 8786)")
    return f"tcp://{m.group(1)}:{port}"


def scan_command(args) -> int:
    """``xray-viz scan``: see :func:`add_scan_parser`."""
    from xray_viz.scene_file import load_scene

    from xray_viz.output import SUFFIX_FORMATS, format_of, suffixes

    out = Path(args.output)
    if format_of(out) not in suffixes(stack=True):   # output.SUFFIX_FORMATS: the one table
        raise SceneError(f"-o {out}: end it in .zarr (Zarr store), .nxs/.h5 (NeXus) or give a "
                         "folder name without a suffix (TIFF stack)")
    kind = SUFFIX_FORMATS[format_of(out)].stack
    if args.workers < 1:
        raise SceneError(f"--workers must be >= 1, got {args.workers}")
    from xray_viz.render import scatter_arguments

    scatter, _, _ = scatter_arguments(args)
    if kind != "zarr" and (args.workers > 1 or args.scheduler):
        raise SceneError("--workers/--scheduler write a Zarr store: give -o NAME.zarr")
    if args.scheduler:
        args.scheduler = check_scheduler(args.scheduler)
    if kind == "zarr" and out.exists() and not (out / "zarr.json").exists():
        raise OutputError(f"{out} exists and is not a Zarr store; remove it or choose another -o")
    if kind == "tiff" and out.exists():            # before any work, not after it
        raise OutputError(f"{out} exists; remove it or choose another -o")
    scene = load_scene(args.scene)
    orbit = _cli_orbit(scene, args)
    if orbit.projections >= POSES_NOTICE:         # the poses take a while: say so first
        print(f"xray-viz: building the poses of {orbit.projections} projections ...",
              file=sys.stderr, flush=True)
    if kind == "zarr":
        import contextlib

        with contextlib.ExitStack() as stack:
            client = None
            if args.scheduler or args.workers > 1:
                from distributed import Client

                if args.scheduler:
                    client = stack.enter_context(Client(args.scheduler,
                                                        timeout=SCHEDULER_TIMEOUT))
                else:
                    cluster = stack.enter_context(local_cluster(args.workers))
                    client = stack.enter_context(Client(cluster))
            filled, total = _scan_to_store(scene, orbit, out, quantity=args.quantity,
                                           engine=args.engine, client=client,
                                           batch=args.batch, progress=True,
                                           scatter=scatter, histories=args.histories,
                                           scatter_smoothing=args.scatter_smoothing)
        # complete, or one line saying what is not (its chunks were verified as it resumed)
        _check_complete(out)
        print(f"{out}: {total} projections ({filled} rendered now), "
              f"{scene.detector.shape[1]} x {scene.detector.shape[0]} pixels, {args.quantity}")
        return 0
    n = _scan_to_file(scene, orbit, out, kind, quantity=args.quantity, engine=args.engine,
                      batch=args.batch, progress=True, scatter=scatter,
                      histories=args.histories,
                      scatter_smoothing=args.scatter_smoothing)
    print(f"{out}: {n} projections, {args.quantity}")
    return 0

