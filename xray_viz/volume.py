"""Volumes traced as voxels: a CT in Hounsfield units or a label map as one body.

A :class:`VoxelVolume` is a grid (its affine: voxel index -> scene mm, as the readers of
:mod:`xray_viz.meshes.volumes` give it), a material *class* per voxel and a *weight* per voxel.
It is traced by the exact voxel traversal of :mod:`xray_viz.tracing.voxels`: each ray's chord
in each voxel.

A CT (:func:`ct_volume`)
    Each voxel's class is the HU range it falls in (:data:`HU_DENSITY`, the project's
    Schneider et al. 2000 ranges, :data:`xray_viz.meshes.volumes.SCHNEIDER_2000`), and its
    density comes from that class's density-HU calibration line, so the density varies voxel
    by voxel (the HU contrast inside an organ is kept). The class's material is traced at
    1 g/cm3 and each voxel weighs its density: the volume's column for a class holds
    ``sum of rho x chord`` (g/cm3 x mm), and ``mu/rho(E)`` of the class's material times it is
    the line integral at every energy. Voxels below the lowest range (air, -950 HU) are empty.
    A range given with its own ``density`` (or ``mu``) is traced at that one density.
A label map (:func:`label_volume`)
    Each listed label is a class with its own material (``mu``, or ``material`` and
    ``density``); each voxel weighs 1; label 0 and unlisted labels are empty.

Meshes in a volume (the implant in the patient)
    A mesh body that lies in the volume's box replaces the volume's material where it is:
    along each ray, the part of each voxel chord inside the mesh (the stretches between the
    mesh's entry and exit hits, from the NumPy reference engine's exact hits,
    :func:`xray_viz.tracing.hits.trace_rays`) is left out (:func:`volume_path_lengths`). A mesh
    that reaches out of the volume's box gives a :class:`VolumeOverlapWarning` once (it
    replaces the voxels only where it is inside the box; outside it adds as usual). A mesh
    whose box contains the whole volume (a tank around the patient) is not a displacer: the
    volume then adds to it.

Path lengths
    :func:`volume_path_lengths` returns, for rays of the detector, one column per class of
    each volume, appended after the mesh bodies' columns by :func:`xray_viz.render`; the
    physics sees each class as a body through :func:`with_volume_materials` (for a CT class
    the column is in g/cm3 x mm, the material traced at 1 g/cm3: the product is the same).

Memory: the classes as ``uint8`` and the weights as ``float32`` by default (5 bytes a voxel:
175 MB for a 512 x 512 x 133 CT); float32 rounds a density by at most 6e-8 of it, a line
integral by the same fraction. ``dtype=np.float64`` keeps the weights exact.

Examples
--------
>>> import numpy as np
>>> hu = np.full((4, 4, 4), -1000.0); hu[1:3, 1:3, 1:3] = 40.0
>>> vol = ct_volume(hu, np.eye(4), name="ct")
>>> vol.names[2], int(vol.classes.max()), round(float(vol.weights.max()), 6)   # float32
('ct_soft_tissue', 3, 1.04)
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from xray_viz.errors import SceneError
from xray_viz.tracing.voxels import INTERPOLATIONS, check_affine, classify, voxel_sums

__all__ = ["VoxelVolume", "VoxelMaterial", "ct_volume", "label_volume", "HU_DENSITY",
           "volume_path_lengths", "with_volume_materials", "mesh_intervals",
           "VolumeOverlapWarning", "TRACE_MODES", "INTERPOLATIONS", "imaged_centre"]

#: The values of ``trace`` in a ``[[ct]]`` or ``[[labels]]`` table.
TRACE_MODES = ("voxels", "meshes")

#: The CT classes traced as voxels: (name, low HU inclusive, high HU exclusive, material,
#: (a, b) of the density line rho = a + b HU in g/cm3). The HU ranges and materials are
#: :data:`xray_viz.meshes.volumes.SCHNEIDER_2000`'s. Below 120 HU the line is the definition
#: of the Hounsfield scale for water-like tissue, rho = 1 + HU / 1000 (lung at -740 HU: 0.26,
#: adipose at -100: 0.90, soft tissue at 40: 1.04); from 120 HU it is Schneider, Bortfeld and
#: Schlegel's (2000) line for their marrow-bone mixtures, rho = 1.017 + 0.592e-3 HU (1.37 at
#: 600 HU, 1.73 at 1200).
HU_DENSITY = (
    ("lung", -950.0, -120.0, "Lung (ICRP)", (1.0, 1e-3)),
    ("adipose", -120.0, 19.0, "Adipose Tissue (ICRP)", (1.0, 1e-3)),
    ("soft_tissue", 19.0, 120.0, "Tissue, Soft (ICRP)", (1.0, 1e-3)),
    ("cancellous_bone", 120.0, 600.0, "Bone, Cortical (ICRP)", (1.017, 0.592e-3)),
    ("cortical_bone", 600.0, float("inf"), "Bone, Cortical (ICRP)", (1.017, 0.592e-3)),
)


class VolumeOverlapWarning(UserWarning):
    """A mesh body reaches out of a voxel volume's box: it replaces the voxels only inside."""


@dataclass(frozen=True)
class VoxelMaterial:
    """What attenuates in one class of a volume, for the physics (as a body's material).

    Attributes
    ----------
    name : str
    mu : float or None
        1/cm, any energy.
    material : str or None
        xraylib compound or formula.
    density : float or None
        g/cm3 (1 for a CT class traced by voxel densities).
    """

    name: str
    mu: float | None = None
    material: str | None = None
    density: float | None = None


@dataclass(frozen=True, eq=False)
class VoxelVolume:
    """A volume traced as voxels.

    Attributes
    ----------
    name : str
    affine : (4, 4) float
        Voxel index -> scene mm (voxel centres at whole indices).
    classes : (I, J, K) uint8
        0 empty, k the k-th of :attr:`materials`.
    weights : (I, J, K) float32 or float64
        Per voxel: its density (g/cm3, a CT class traced by densities) or 1.
    materials : tuple of VoxelMaterial
    source_file : Path or None
    table : (str, dict) or None
    interpolation : {"nearest", "trilinear"}
        How the voxels are traced (:func:`xray_viz.tracing.voxels.voxel_sums`): each voxel's
        weight over its whole voxel (the default), or the trilinear interpolation between
        voxel centres of each class's weights, integrated exactly.
    """

    name: str
    affine: np.ndarray = field(repr=False)
    classes: np.ndarray = field(repr=False)
    weights: np.ndarray = field(repr=False)
    materials: tuple = field(repr=False)
    source_file: Path | None = None
    #: ``(kind, table)``: the scene file's ``[[ct]]`` or ``[[labels]]`` table it was read from
    #: (``Scene.to_dict`` writes it back); None for a volume built in Python.
    table: tuple | None = field(repr=False, default=None)
    interpolation: str = "nearest"

    def __post_init__(self):
        where = f"{self.source_file or self.name}"
        if self.interpolation not in INTERPOLATIONS:
            raise SceneError(f"{where}: interpolation must be one of {list(INTERPOLATIONS)}, "
                             f"got {self.interpolation!r}")
        object.__setattr__(self, "affine", check_affine(self.affine, where=where))
        c = np.asarray(self.classes)
        if c.ndim != 3 or c.dtype != np.uint8:
            raise SceneError(f"{where}: classes must be a 3D uint8 array")
        w = np.asarray(self.weights)
        if w.shape != c.shape or w.dtype not in (np.float32, np.float64):
            raise SceneError(f"{where}: weights must be float32 or float64, shaped as classes")
        if not np.all(np.isfinite(w)) or (w.size and float(w.min()) < 0):
            raise SceneError(f"{where}: voxel weights must be finite and >= 0")
        object.__setattr__(self, "_warned", set())     # bodies already warned about
        object.__setattr__(self, "_layouts", {})       # a copy in another axis order
        if c.size and int(c.max()) > len(self.materials):
            raise SceneError(f"{where}: a voxel's class {int(c.max())} has no material "
                             f"({len(self.materials)} given)")

    @property
    def shape(self) -> tuple:
        """Voxels along i, j, k."""
        return tuple(self.classes.shape)

    @property
    def corners(self) -> np.ndarray:
        """(8, 3) the grid box's corners in scene mm (half a voxel outside the centres)."""
        n = np.asarray(self.shape, dtype=np.float64)
        c = np.array([[x, y, z] for x in (-0.5, n[0] - 0.5) for y in (-0.5, n[1] - 0.5)
                      for z in (-0.5, n[2] - 0.5)])
        return c @ self.affine[:3, :3].T + self.affine[:3, 3]

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) the axis-aligned box of :attr:`corners`."""
        c = self.corners
        return np.array([c.min(axis=0), c.max(axis=0)])

    @property
    def names(self) -> list:
        """The classes' names (the physics' body names of this volume's columns)."""
        return [m.name for m in self.materials]

    def contains(self, points) -> np.ndarray:
        """Which points lie in the grid's box (its parallelepiped, not its bounds)."""
        inv = np.linalg.inv(self.affine)
        idx = np.asarray(points, dtype=np.float64) @ inv[:3, :3].T + inv[:3, 3]
        return np.all((idx >= -0.5) & (idx <= np.asarray(self.shape) - 0.5), axis=-1)

    def _permutation(self, across):
        """The axis order :meth:`layout` gives for ``across``; None: the grid as it is."""
        if across is None:
            return None
        inv = np.linalg.inv(self.affine[:3, :3])
        a = np.abs(inv @ np.asarray(across, dtype=np.float64) * 1.0)
        last = int(np.argmax(a))
        if last == 2:
            return None
        return tuple(x for x in range(3) if x != last) + (last,)

    def layout_bytes(self, across=None) -> int:
        """Bytes that :meth:`layout` would allocate for ``across``: its copy of the classes
        and weights, 0 when the grid is used as it is or the copy is already kept."""
        perm = self._permutation(across)
        if perm is None or perm in self._layouts:
            return 0
        return int(self.classes.nbytes + self.weights.nbytes)

    def layout(self, across=None):
        """``(affine, classes, weights)`` with the grid's axes in the order that suits rays
        whose neighbours (in ray order) lie along ``across`` (a world direction: the
        detector's u axis): the index axis most aligned with it is made the contiguous one,
        so that neighbouring rays read the same cache lines. The same voxels and chords (to
        rounding: the inverse affine of the permuted grid rounds differently, ~1e-13
        relative). One such copy is kept on the
        volume (another 5 bytes a voxel); None: the grid as it is."""
        perm = self._permutation(across)
        if perm is None:
            return self.affine, self.classes, self.weights
        kept = self._layouts.get(perm)
        if kept is None:
            affine = self.affine.copy()
            affine[:3, :3] = self.affine[:3, list(perm)]
            kept = (affine, np.ascontiguousarray(self.classes.transpose(perm)),
                    np.ascontiguousarray(self.weights.transpose(perm)))
            self._layouts.clear()
            self._layouts[perm] = kept
        return kept

    def trace(self, origins, directions, t_max, *, intervals=None, across=None) -> np.ndarray:
        """``(n, len(materials))``: per ray and class, ``sum of weight x chord`` (mm).
        ``across``: the world direction between neighbouring rays (:meth:`layout`)."""
        affine, classes, weights = self.layout(across)
        return voxel_sums(origins, directions, t_max, affine, classes, weights,
                          n_classes=len(self.materials), intervals=intervals,
                          interpolation=self.interpolation)


def _hu_field(hu, where):
    hu = np.asarray(hu)
    if hu.ndim != 3 or min(hu.shape) < 1:
        raise SceneError(f"{where}: a CT must be a 3D volume, got shape {list(hu.shape)}")
    bad = ~np.isfinite(hu)
    if bad.any():
        first = np.argwhere(bad)[0].tolist()
        raise SceneError(f"{where}: {int(bad.sum())} voxel(s) are NaN or infinite (first at "
                         f"index {first}); fill them (for example with -1000 HU, air) first")
    return hu


def ct_volume(hu, affine, *, name: str = "ct", ranges=None, source_file=None,
              dtype=np.float32) -> VoxelVolume:
    """A CT in Hounsfield units as a voxel volume.

    Parameters
    ----------
    hu : (I, J, K) array
        Hounsfield units, finite.
    affine : (4, 4)
        Voxel index -> scene mm.
    name : str
        Prefix of the classes' names (``<name>_<class>``).
    ranges : sequence, optional
        Classes ``(name, low, high, entry)``: ``low <= HU < high``; ``entry`` a dict with
        ``mu``, or ``material`` and optionally ``density`` (a fixed density), or
        ``material`` and ``line = (a, b)`` (rho = a + b HU). Default :data:`HU_DENSITY`.
    source_file : Path, optional
    dtype : numpy dtype
        Of the weights (float32 default; see the module's notes).

    Returns
    -------
    VoxelVolume

    Raises
    ------
    SceneError
        NaN or infinite voxels, a singular or non-finite affine, a density line giving a
        negative density within its range.
    """
    where = f"{source_file or name}"
    hu = _hu_field(hu, where)
    affine = check_affine(affine, where=where)
    if not hu.flags.c_contiguous and hu.flags.f_contiguous:
        # a NIfTI's array is in Fortran order: its transpose is the same grid in C order,
        # with the axes reversed (no copy; a copy of 512 x 512 x 133 float64 took 2.8 s)
        hu = hu.T
        affine = affine.copy()
        affine[:3, :3] = affine[:3, 2::-1]
    hu = np.ascontiguousarray(hu)
    if ranges is None:
        ranges = [(n, lo, hi, {"material": m, "line": line}) for n, lo, hi, m, line in HU_DENSITY]
    if len(ranges) > 255:
        raise SceneError(f"{where}: at most 255 HU ranges")
    materials, table = [], []
    for cname, lo, hi, entry in ranges:
        full = f"{name}_{cname}"
        if "mu" in entry and entry["mu"] is not None:
            materials.append(VoxelMaterial(full, mu=float(entry["mu"])))
            table.append((lo, hi, 1.0, 0.0))
        elif entry.get("line") is not None:
            materials.append(VoxelMaterial(full, material=entry["material"], density=1.0))
            table.append((lo, hi, *(float(x) for x in entry["line"])))
        else:
            materials.append(VoxelMaterial(full, material=entry["material"],
                                           density=entry.get("density")))
            table.append((lo, hi, 1.0, 0.0))
    classes, weights, lowest = classify(hu, table, dtype=dtype)
    for (cname, lo, hi, entry), (_, _, a, b), low in zip(ranges, table, lowest):
        if low < 0:
            raise SceneError(f"{where}: class {cname!r}: its density line {a:g} + {b:g} HU "
                             f"is negative at some voxel's HU (down to {low:g} g/cm3)")
    return VoxelVolume(name=name, affine=affine, classes=classes, weights=weights,
                       materials=tuple(materials), source_file=source_file)


def label_volume(labels, affine, entries, *, name: str = "labels", source_file=None,
                 names=None, dtype=np.float32) -> VoxelVolume:
    """A label map as a voxel volume: one class per listed label.

    Parameters
    ----------
    labels : (I, J, K) int array
    affine : (4, 4)
    entries : mapping of int to dict
        Label -> ``{"mu": ...}`` or ``{"material": ..., "density": ...}``.
    names : mapping of int to str, optional
        Class names (default ``<name>_<label>``).

    Returns
    -------
    VoxelVolume
        Classes in ascending label order.
    """
    labels = np.ascontiguousarray(labels)
    if labels.ndim != 3:
        raise SceneError(f"{source_file or name}: a label map must be 3D")
    wanted = sorted(int(v) for v in entries)
    if len(wanted) > 255:
        raise SceneError(f"{source_file or name}: at most 255 labels traced as voxels")
    lut = {v: k for k, v in enumerate(wanted, start=1)}
    classes = np.zeros(labels.shape, np.uint8)
    for v, k in lut.items():
        classes[labels == v] = k
    materials = tuple(
        VoxelMaterial((names or {}).get(v, f"{name}_{v}"), mu=entries[v].get("mu"),
                      material=entries[v].get("material"), density=entries[v].get("density"))
        for v in wanted)
    weights = (classes > 0).astype(dtype)
    return VoxelVolume(name=name, affine=affine, classes=classes, weights=weights,
                       materials=materials, source_file=source_file)


# --------------------------------------------------------------------------------------------
# meshes in volumes


def displacers(volume: VoxelVolume, bodies, *, warn: bool = True) -> list:
    """Indices of the mesh bodies that replace the volume's material: those whose box meets
    the volume's and does not contain its whole box. A displacer reaching out of the grid's
    box gives one :class:`VolumeOverlapWarning` naming it."""
    out = []
    corners = volume.corners
    lo_v, hi_v = volume.bounds
    for k, body in enumerate(bodies):
        v = np.asarray(body.vertices, dtype=np.float64)
        if not len(v):
            continue
        lo, hi = v.min(axis=0), v.max(axis=0)
        if np.any(lo > hi_v) or np.any(hi < lo_v):
            continue                                       # apart: adds as usual
        if np.all(lo <= corners.min(axis=0)) and np.all(hi >= corners.max(axis=0)):
            continue                                       # around the whole volume
        out.append(k)
        if warn and body.name not in volume._warned and not np.all(volume.contains(v)):
            volume._warned.add(body.name)
            warnings.warn(f"body {body.name!r} reaches out of volume {volume.name!r}'s box "
                          f"({volume.source_file or 'its grid'}): it replaces the voxels only "
                          "inside the box", VolumeOverlapWarning, stacklevel=3)
    return out


def mesh_intervals(bodies, which, origins, directions, t_max, *, axis=None):
    """Per ray, the stretches ``[t0, t1)`` inside any of the bodies ``which`` (their union):
    ``(start, t0, t1)`` as :func:`xray_viz.tracing.voxels.voxel_sums` takes them.

    From every hit of the NumPy reference engine (exact, watertight), each body's
    entries minus exits (its winding number) swept in order of ``t``: a stretch is inside
    where any of the bodies' counts is positive.
    """
    from xray_viz.bodies import Bodies
    from xray_viz.tracing.hits import trace_rays

    n = len(t_max)
    if not which:
        return np.zeros(n + 1, np.int64), np.zeros(0), np.zeros(0)
    if isinstance(bodies, Bodies) and list(which) == list(range(len(bodies))):
        sub = bodies                         # every body: its own set-up, kept on it
    elif isinstance(bodies, Bodies):
        sub = Bodies([bodies[k] for k in which], check=False,
                     reports=[bodies.reports[k] for k in which])
    else:
        sub = Bodies([bodies[k] for k in which])
    hits = trace_rays(sub, origins, directions, t_min=0.0, t_max=t_max, axis=axis)
    ray, t, body = hits.ray, hits.t, hits.body
    delta = np.where(hits.entering, 1, -1)
    k = len(ray)
    if k == 0:
        return np.zeros(n + 1, np.int64), np.zeros(0), np.zeros(0)
    # per (ray, body) running count; "inside any" = number of bodies with a positive count
    order = np.lexsort((t, body, ray))
    key = ray[order] * len(which) + body[order]
    d = delta[order]
    first = np.ones(k, bool)
    first[1:] = key[1:] != key[:-1]
    cs = np.cumsum(d)
    base = np.maximum.accumulate(np.where(first, np.arange(k), 0))
    before = np.concatenate([[0], cs])[base]
    count = cs - before                                     # after each hit, per body
    was = np.where(first, 0, np.concatenate([[0], count[:-1]]))
    change = (count > 0).astype(np.int64) - (was > 0).astype(np.int64)   # +1 in, -1 out
    # back in (ray, t) order: the number of bodies the ray is inside after each hit
    back = np.empty(k, np.int64)
    back[order] = np.arange(k)
    ch = change[back]                                       # hits are sorted by (ray, t)
    first_r = np.ones(k, bool)
    first_r[1:] = ray[1:] != ray[:-1]
    cs2 = np.cumsum(ch)
    base2 = np.maximum.accumulate(np.where(first_r, np.arange(k), 0))
    inside = cs2 - np.concatenate([[0], cs2])[base2]
    prev = np.where(first_r, 0, np.concatenate([[0], inside[:-1]]))
    opens = (inside > 0) & (prev <= 0)
    closes = (inside <= 0) & (prev > 0)
    t_open, r_open = t[opens], ray[opens]
    t_close, r_close = t[closes], ray[closes]
    # a ray still inside at its end (a body past the detector) closes at t_max
    still = np.zeros(n, np.int64)
    np.add.at(still, r_open, 1)
    np.add.at(still, r_close, -1)
    tail = np.flatnonzero(still > 0)
    t_close = np.concatenate([t_close, np.asarray(t_max, dtype=np.float64)[tail]])
    r_close = np.concatenate([r_close, tail])
    oc = np.argsort(r_close, kind="stable")
    t_close, r_close = t_close[oc], r_close[oc]
    start = np.zeros(n + 1, np.int64)
    np.add.at(start, r_open + 1, 1)
    start = np.cumsum(start)
    return start, t_open.astype(np.float64), t_close.astype(np.float64)


def volume_path_lengths(scene, *, supersample: int = 1, rows=None) -> np.ndarray:
    """The volumes' columns of the path lengths of detector rays: ``(rays, classes)``, the
    classes of ``scene.volumes`` in order, with the mesh bodies' stretches left out.

    Parameters
    ----------
    scene : Scene
        With ``volumes`` (and ``bodies``, ``acquisition``).
    supersample : int
    rows : (int, int), optional
        Image rows, as :func:`xray_viz.geometry.detector_rays`.
    """
    acq = scene.acquisition
    rays = acq.rays(supersample=supersample, rows=rows)
    cols = []
    for vol in scene.volumes:
        which = displacers(vol, scene.bodies, warn=False)
        iv = None
        if which:
            iv = mesh_intervals(scene.bodies, which, rays.origins, rays.directions, rays.t_max,
                                axis=acq.frame.forward)
        cols.append(vol.trace(rays.origins, rays.directions, rays.t_max, intervals=iv,
                              across=acq.frame.ho))
    if not cols:
        return np.zeros((len(rays), 0))
    return np.hstack(cols) if len(cols) > 1 else cols[0]


class VolumeProjector:
    """A :class:`~xray_viz.tracing.engines.Projector` of the mesh bodies with the voxel
    volumes' columns after theirs: each volume's classes, the meshes' stretches left out of
    the voxels (:func:`volume_path_lengths`). What :func:`xray_viz.render.scene_projector`
    gives for a scene with volumes; otherwise it answers as the mesh projector.

    Parameters
    ----------
    projector : Projector
        Of the scene's mesh bodies.
    volumes : sequence of VoxelVolume
    """

    #: Whole frames are not kept on the bodies (the voxels' columns are traced each time).
    keeps_results = False

    def __init__(self, projector, volumes):
        self.projector, self.volumes = projector, tuple(volumes)
        self.bodies = projector.bodies
        self.columns = len(projector.bodies) + sum(len(v.names) for v in self.volumes)

    def __getattr__(self, name):
        return getattr(self.projector, name)

    def _voxels(self, acquisition, supersample, rows):
        from types import SimpleNamespace

        view = SimpleNamespace(acquisition=acquisition, volumes=self.volumes, bodies=self.bodies)
        return volume_path_lengths(view, supersample=supersample, rows=rows)

    def path_lengths(self, acquisition, *, supersample: int = 1) -> np.ndarray:
        """``(rays, columns)``: the meshes' path lengths, then the volumes' classes'."""
        return np.hstack([self.projector.path_lengths(acquisition, supersample=supersample),
                          self._voxels(acquisition, supersample, None)])

    def windows(self, acquisition, *, supersample: int = 1, rows: int | None = None):
        """As :meth:`Projector.windows`, with the volumes' columns."""
        for r0, r1, L in self.projector.windows(acquisition, supersample=supersample,
                                                rows=rows):
            yield r0, r1, np.hstack([L, self._voxels(acquisition, supersample, (r0, r1))])

    def hits(self, acquisition, *, supersample: int = 1):
        """As :meth:`Projector.hits` (the meshes' hits), with the volumes' columns."""
        L, hits = self.projector.hits(acquisition, supersample=supersample)
        return np.hstack([L, self._voxels(acquisition, supersample, None)]), hits

    def __repr__(self) -> str:
        return f"VolumeProjector({self.projector!r}, {len(self.volumes)} volumes)"


def imaged_centre(scene):
    """The centre of the box around every body and voxel volume of a scene, or None when it
    has neither (what ``--angle`` and a scan's default orbit turn about)."""
    lows, highs = [], []
    if len(scene.bodies):
        box = scene.bodies.bounds
        lows.append(box[:, 0].min(axis=0))
        highs.append(box[:, 1].max(axis=0))
    for v in scene.volumes:
        lows.append(v.bounds[0])
        highs.append(v.bounds[1])
    if not lows:
        return None
    return (np.min(lows, axis=0) + np.max(highs, axis=0)) / 2


class _WithVolumes:
    """A scene as the physics sees it when it holds volumes: its bodies followed by each
    volume's classes (as materials), in the order of the path lengths' columns."""

    def __init__(self, scene):
        self._scene = scene
        self.bodies = tuple(scene.bodies) + tuple(m for v in scene.volumes for m in v.materials)

    def __getattr__(self, name):
        return getattr(self._scene, name)

    @property
    def body_names(self) -> list:
        return [b.name for b in self.bodies]

    @property
    def triangles(self) -> np.ndarray:
        """The meshes' triangles and the volumes' corners (for the object plane's box)."""
        parts = [np.asarray(self._scene.triangles).reshape(-1, 3, 3)]
        for v in self._scene.volumes:
            c = v.corners
            parts.append(np.stack([c[[0, 1, 2]], c[[3, 4, 5]], c[[6, 7, 7]]]))
        return np.concatenate(parts)


def with_volume_materials(scene):
    """The scene itself without volumes; else the physics' view of it (its bodies followed by
    every volume's classes, see :func:`volume_path_lengths`)."""
    if not scene.volumes:
        return scene
    return _WithVolumes(scene)
