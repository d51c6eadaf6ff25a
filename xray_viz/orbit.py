"""CT orbits: sequences of :class:`~xray_viz.geometry.Acquisition` around fixed bodies.

An :class:`Orbit` turns the acquisition of a scene into the acquisitions of a scan:

* ``"circular"``: ``acquisition.rotated(theta_k, axis=, center=)`` with
  ``theta_k = start + k * arc / n`` (a full scan is ``arc = 360``, a short scan
  ``180 + fan angle``);
* ``"helical"``: the same, also moved by ``pitch * theta_k / 360`` mm along the axis;
* ``"poses"``: an explicit source position, detector centre (the middle of the pixel grid)
  and detector ``u``/``v`` per projection (like ASTRA's ``cone_vec``); ``u``, ``v`` other than
  the frame that :class:`~xray_viz.geometry.Acquisition` derives from the source and the
  centre are a tilted detector (:class:`~xray_viz.scene.Detector` ``u``, ``v``). A parallel
  beam's pose has its source on the ray through the detector centre.
* ``"poses"`` drawn at random (:class:`RandomPoses`, ``[scan] poses = { random = N, seed = 7,
  ... }``): a training set of DRRs, each projection's pose a function of ``(seed, k)`` only,
  so the same on every worker in any batch order.

Lives below :mod:`xray_viz.scene` (which reads the ``[scan]`` table with
:func:`orbit_from_dict`); :mod:`xray_viz.scan` renders and writes.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xray_viz._checks import vector3
from xray_viz.errors import SceneError
from xray_viz.geometry import Acquisition
from xray_viz.poses import (  # noqa: F401  (check_pose, POSE_TOLERANCE: importable here as before)
    POSE_TOLERANCE,
    apply_rotations as _apply,
    check_pose,
    pose_acquisition,
    rotations as _rotations,
)

__all__ = ["Orbit", "ORBITS", "SCAN_KEYS", "orbit_from_dict", "pose_acquisition", "check_pose",
           "read_poses", "RandomPoses", "RANDOM_KEYS"]

ORBITS = ("circular", "helical", "poses")
#: Keys of the ``[scan]`` table of a scene file.
SCAN_KEYS = ("orbit", "projections", "arc", "axis", "center", "pitch", "poses", "start")

#: How far (unit vectors) a pose's u/v may be from the derived detector frame.


def _vector(value, name, where) -> np.ndarray:
    return vector3(value, f"{where}{name}")


@dataclass(frozen=True, eq=False)
class Orbit:
    """Where the source and detector go during a scan.

    Parameters
    ----------
    kind : {"circular", "helical", "poses"}
    projections : int
        Number of projections (for ``"poses"``: the number of poses).
    arc : float
        Degrees covered by the ``projections`` angles ``start + k * arc / projections``.
    axis, center : (3,) float
        The rotation axis (direction) through ``center`` (mm).
    pitch : float
        Helical: mm travelled along ``axis`` per 360 degrees (0 for a circular orbit).
    start : float
        Angle (degrees) of the first projection.
    poses : tuple of dict, optional
        ``{"source", "detector_center", "u", "v"}`` per projection (``"poses"`` orbits).
    random : RandomPoses or dict, optional
        Poses drawn at random about ``axis`` through ``center`` (a ``"poses"`` orbit without
        ``poses``; ``projections`` is ``random.count``).

    Examples
    --------
    >>> import xray_viz
    >>> orbit = Orbit("circular", projections=4, axis=[0, 1, 0])
    >>> orbit.angles().tolist()
    [0.0, 90.0, 180.0, 270.0]
    >>> acqs = list(orbit.acquisitions(xray_viz.load_scene("sphere").acquisition))
    >>> (acqs[1].frame.source.round(9) + 0.0).tolist()
    [1000.0, 0.0, 0.0]
    """

    kind: str = "circular"
    projections: int = 360
    arc: float = 360.0
    axis: np.ndarray = dataclasses.field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    center: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    pitch: float = 0.0
    start: float = 0.0
    poses: tuple | None = None
    random: "RandomPoses | None" = None

    def __post_init__(self):
        if self.kind not in ORBITS:
            raise SceneError(f"[scan] orbit must be one of {', '.join(ORBITS)}, "
                             f"got {self.kind!r}")
        n = self.projections
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise SceneError(f"[scan] projections must be a whole number >= 1, got {n!r}")
        object.__setattr__(self, "projections", int(n))
        for key in ("arc", "pitch", "start"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) \
                    or not math.isfinite(v):
                raise SceneError(f"[scan] {key} must be a finite number, got {v!r}")
            object.__setattr__(self, key, float(v))
        if not self.arc > 0:
            raise SceneError(f"[scan] arc must be > 0 degrees, got {self.arc:g}")
        axis = _vector(self.axis, "axis", "[scan] ")
        if not np.linalg.norm(axis) > 0:
            raise SceneError("[scan] axis must not be [0, 0, 0]")
        object.__setattr__(self, "axis", axis / np.linalg.norm(axis))
        object.__setattr__(self, "center", _vector(self.center, "center", "[scan] "))
        if self.kind == "circular" and self.pitch != 0:
            raise SceneError(f"[scan] pitch = {self.pitch:g} needs orbit = \"helical\"")
        if self.kind == "helical" and self.pitch == 0:
            raise SceneError("[scan] orbit = \"helical\" needs pitch (mm per turn, not 0): "
                             "without it the orbit is a circle; say orbit = \"circular\"")
        if self.random is not None:
            rnd = self.random if isinstance(self.random, RandomPoses) \
                else RandomPoses.from_dict(self.random)
            if self.kind != "poses" or self.poses is not None:
                raise SceneError("[scan] random poses are an orbit of their own: no orbit "
                                 "= \"circular\"/\"helical\" and no explicit poses with them")
            object.__setattr__(self, "random", rnd)
            object.__setattr__(self, "projections", rnd.count)
        elif self.kind == "poses":
            if not self.poses:
                raise SceneError("[scan] a poses orbit needs poses (a JSON file of poses)")
            object.__setattr__(self, "poses", tuple(self.poses))
            object.__setattr__(self, "projections", len(self.poses))
        elif self.poses is not None:
            raise SceneError("[scan] poses are given only with orbit = \"poses\"")

    def angles(self) -> np.ndarray | None:
        """(n,) float: the gantry angle of each projection in degrees (None for poses)."""
        if self.kind == "poses":
            return None
        return self.start + self.arc * np.arange(self.projections) / self.projections

    def acquisition(self, base: Acquisition, k: int) -> Acquisition:
        """Projection ``k``'s acquisition: ``base`` moved along the orbit."""
        if self.random is not None:
            return self.random.acquisition(base, k, axis=self.axis, center=self.center)
        if self.kind == "poses":
            return pose_acquisition(base, self.poses[k], where=f"pose {k}: ")
        angle = float(self.angles()[k])
        acq = base.rotated(angle, axis=self.axis, center=self.center)
        if self.pitch:
            shift = self.pitch * angle / 360.0 * self.axis
            acq = Acquisition(
                source=dataclasses.replace(acq.source, position=acq.source.position + shift),
                detector=dataclasses.replace(acq.detector,
                                             center=acq.detector.center + shift))
        return acq

    def pose_arrays(self, base: Acquisition) -> tuple:
        """``(source, detector_center, up)``, each ``(n, 3)``, of a circular or helical orbit,
        built over all projections at once (:meth:`acquisition` one by one: the same poses
        to rounding): a million poses in about a second.

        Examples
        --------
        >>> import xray_viz
        >>> base = xray_viz.load_scene("sphere").acquisition
        >>> src, det, up = Orbit(projections=4, axis=[0, 1, 0]).pose_arrays(base)
        >>> (src[1].round(9) + 0.0).tolist()
        [1000.0, 0.0, 0.0]
        """
        if self.kind == "poses":
            raise SceneError("pose_arrays of a circular or helical orbit only")
        angles = self.angles()
        rot = _rotations(self.axis, angles)
        n = len(angles)
        c = self.center

        def turn(p):
            return _apply(rot, np.broadcast_to(np.asarray(p, np.float64), (n, 3)))

        src = c + turn(base.source.position - c)
        det = c + turn(base.detector.center - c)
        up = turn(base.detector.up)
        if self.pitch:
            shift = (self.pitch * angles / 360.0)[:, None] * self.axis
            src, det = src + shift, det + shift
        return src, det, up

    def acquisitions(self, base: Acquisition):
        """Yield the acquisition of every projection in order (a generator)."""
        for k in range(self.projections):
            yield self.acquisition(base, k)

    def to_dict(self) -> dict:
        """The orbit as a ``[scan]`` table (poses inline)."""
        out = {"orbit": self.kind, "projections": self.projections}
        if self.random is not None:
            out.update(poses=self.random.to_dict(), axis=self.axis.tolist(),
                       center=self.center.tolist())
            return out
        if self.kind == "poses":
            out["poses"] = [dict(p) for p in self.poses]
            return out
        out.update(arc=self.arc, axis=self.axis.tolist(), center=self.center.tolist(),
                   pitch=self.pitch, start=self.start)
        return out


#: Keys of a ``[scan] poses = { random = N, ... }`` table (:class:`RandomPoses`).
RANDOM_KEYS = ("random", "seed", "angle", "tilt", "roll", "sod", "sid", "shift")
#: The spawn key of the pose stream (the noise stream, ``scan.projection_seed``, is another).
POSE_STREAM = 0x706F7365


def _range(value, key, *, positive=False):
    where = f"[scan] poses.{key}"
    try:
        lo, hi = value
        ok = not any(isinstance(x, bool) for x in value) and \
            math.isfinite(float(lo)) and math.isfinite(float(hi)) and float(lo) <= float(hi)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise SceneError(f"{where} must be [low, high], two finite numbers with low <= high, "
                         f"got {value!r}")
    lo, hi = float(lo), float(hi)
    if positive and not lo > 0:
        raise SceneError(f"{where} must be > 0 mm, got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class RandomPoses:
    """Poses drawn at random, for training sets of DRRs: ``[scan] poses = { random = N, ... }``.

    Projection ``k``'s pose is a function of ``(seed, k)`` only (NumPy's ``SeedSequence(seed,
    spawn_key=(POSE_STREAM, k))``): the same in any order, batching or worker. Starting from
    the scene's acquisition, in this order:

    1. ``sod``, ``sid`` (mm, ``[low, high]``, default: the scene's own): the source slides
       along the beam axis to ``sod`` mm before the rotation centre (its foot on the beam
       axis) and the detector centre to ``sid`` mm from the source, facing it;
    2. ``roll`` (degrees): source and detector turned about the beam axis (the object's
       in-plane rotation);
    3. ``tilt`` (degrees): turned about ``beam x axis`` through ``center`` (a cranio-caudal
       tilt for a vertical ``axis``);
    4. ``angle`` (degrees, default ``[0, 360]``): turned about the ``[scan]`` ``axis`` through
       ``center`` (the gantry angle);
    5. ``shift`` (mm, ``[sx, sy, sz]``, default 0): source and detector moved together by a
       uniform draw in ``[-s, s]`` per scene axis (the object shifted by the opposite).

    Each value is uniform in its range; every projection draws the same eight numbers
    whichever keys are given, so fixing a range changes no other draw.

    Examples
    --------
    >>> import xray_viz
    >>> r = RandomPoses(count=3, seed=7, tilt=(-10.0, 10.0))
    >>> acq = xray_viz.load_scene("sphere").acquisition
    >>> a = r.acquisition(acq, 1, axis=[0, 1, 0], center=[0, 0, 0])
    >>> b = RandomPoses(count=500, seed=7, tilt=(-10.0, 10.0)).acquisition(
    ...     acq, 1, axis=[0, 1, 0], center=[0, 0, 0])
    >>> bool((a.frame.source == b.frame.source).all())     # (seed, k) only: not the count
    True
    """

    count: int
    seed: int = 0
    angle: tuple = (0.0, 360.0)
    tilt: tuple = (0.0, 0.0)
    roll: tuple = (0.0, 0.0)
    sod: tuple | None = None
    sid: tuple | None = None
    shift: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        n = self.count
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise SceneError(f"[scan] poses.random must be a whole number >= 1 (how many "
                             f"poses), got {n!r}")
        object.__setattr__(self, "count", int(n))
        s = self.seed
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise SceneError(f"[scan] poses.seed must be a whole number >= 0, got {s!r}")
        object.__setattr__(self, "seed", int(s))
        for key in ("angle", "tilt", "roll"):
            object.__setattr__(self, key, _range(getattr(self, key), key))
        for key in ("sod", "sid"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, _range(getattr(self, key), key, positive=True))
        if self.sod is not None and self.sid is not None and not self.sid[0] > self.sod[1]:
            raise SceneError(f"[scan] poses.sid {list(self.sid)} must lie beyond poses.sod "
                             f"{list(self.sod)} (low sid > high sod): the detector behind the "
                             "rotation centre")
        shift = self.shift
        try:
            ok = len(shift) == 3 and not any(isinstance(x, bool) for x in shift) and \
                all(math.isfinite(float(x)) and float(x) >= 0 for x in shift)
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise SceneError(f"[scan] poses.shift must be 3 numbers >= 0 (mm, the largest "
                             f"move along x, y, z), got {shift!r}")
        object.__setattr__(self, "shift", tuple(float(x) for x in shift))

    @classmethod
    def from_dict(cls, table) -> "RandomPoses":
        """From the ``poses = { random = N, ... }`` table (:data:`RANDOM_KEYS`)."""
        if not isinstance(table, dict) or "random" not in table:
            raise SceneError(f"[scan] random poses are a table with random = N, got {table!r}")
        unknown = sorted(set(table) - set(RANDOM_KEYS))
        if unknown:
            raise SceneError(f"[scan] poses: unknown key(s) {unknown}; known: "
                             f"{', '.join(RANDOM_KEYS)}")
        kwargs = {k: table[k] for k in RANDOM_KEYS[1:] if k in table}
        return cls(count=table["random"], **kwargs)

    def to_dict(self) -> dict:
        """The ``poses`` table (JSON/TOML-serialisable; inverse of :meth:`from_dict`)."""
        out = {"random": self.count, "seed": self.seed, "angle": list(self.angle),
               "tilt": list(self.tilt), "roll": list(self.roll), "shift": list(self.shift)}
        for key in ("sod", "sid"):
            if getattr(self, key) is not None:
                out[key] = list(getattr(self, key))
        return out

    def draws(self, k: int) -> np.ndarray:
        """The eight uniform numbers in [0, 1) of projection ``k`` (its own stream)."""
        seq = np.random.SeedSequence(self.seed, spawn_key=(POSE_STREAM, int(k)))
        return np.random.default_rng(seq).random(8)

    def draws_many(self, ks) -> np.ndarray:
        """``(len(ks), 8)``: :meth:`draws` of every ``k`` (NumPy's own generators, one per
        projection: ~25 us each, 2.4 s for 100,000 poses).

        Examples
        --------
        >>> r = RandomPoses(count=10, seed=7)
        >>> bool((r.draws_many([3, 0, 9])[0] == r.draws(3)).all())
        True
        """
        ks = np.asarray(ks, np.int64).reshape(-1)
        out = np.empty((ks.size, 8), np.float64)
        for i, k in enumerate(ks.tolist()):
            out[i] = self.draws(k)
        return out

    def pose_arrays(self, base: Acquisition, ks=None, *, axis, center) -> tuple:
        """``(source, detector_center, up)``, each ``(len(ks), 3)``: the poses of projections
        ``ks`` (default all), built over all ``k`` at once; row ``i`` depends on
        ``(seed, ks[i])`` only (element-wise arithmetic: the same bits in any batch).

        Raises
        ------
        IndexError
            A ``k`` outside ``0 <= k < count``.
        SceneError
            A tilt about an axis along the beam.
        """
        ks = np.arange(self.count) if ks is None else np.asarray(ks, np.int64).reshape(-1)
        if ks.size and not (ks.min() >= 0 and ks.max() < self.count):
            bad = int(ks[(ks < 0) | (ks >= self.count)][0])
            raise IndexError(f"pose {bad} of {self.count}")
        u = self.draws_many(ks)

        def pick(rng, x):
            return rng[0] + x * (rng[1] - rng[0])

        axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
        center = np.asarray(center, np.float64)
        f = base.frame
        foot = f.source + ((center - f.source) @ f.forward) * f.forward   # centre on the beam
        n = len(ks)
        sod = np.full(n, float(np.linalg.norm(foot - f.source))) if self.sod is None \
            else pick(self.sod, u[:, 0])
        sid = np.full(n, f.sid) if self.sid is None else pick(self.sid, u[:, 1])
        # points relative to `center`, directions: composed rotations, one pose at the end
        fc = foot - center
        src = fc - sod[:, None] * f.forward
        det = fc + (sid - sod)[:, None] * f.forward
        up = np.broadcast_to(np.asarray(base.detector.up, np.float64), (n, 3))
        rot = _rotations(f.forward, pick(self.roll, u[:, 2]))           # about the beam axis
        src, det, up = fc + _apply(rot, src - fc), fc + _apply(rot, det - fc), _apply(rot, up)
        tilt = pick(self.tilt, u[:, 3])
        if np.any(tilt != 0):
            across = np.cross(f.forward, axis)
            if not np.linalg.norm(across) > 1e-9:
                raise SceneError("[scan] poses.tilt needs an axis across the beam, got axis "
                                 f"{axis.tolist()} along it")
            rot = _rotations(across, tilt)
            src, det, up = _apply(rot, src), _apply(rot, det), _apply(rot, up)
        rot = _rotations(axis, pick(self.angle, u[:, 4]))
        move = center + (2 * u[:, 5:8] - 1) * np.asarray(self.shift)
        return _apply(rot, src) + move, _apply(rot, det) + move, _apply(rot, up)

    def acquisition(self, base: Acquisition, k: int, *, axis, center) -> Acquisition:
        """Projection ``k``'s acquisition (see the class; :meth:`pose_arrays` of ``[k]``)."""
        if not 0 <= k < self.count:
            raise IndexError(f"pose {k} of {self.count}")
        src, det, up = (a[0] for a in self.pose_arrays(base, [k], axis=axis, center=center))
        return Acquisition(
            source=dataclasses.replace(base.source, position=src),
            detector=dataclasses.replace(base.detector, center=det, up=up))


def read_poses(path) -> tuple:
    """The poses of a JSON file: a list of ``{"source", "detector_center", "u", "v"}`` or a
    scan's geometry document (a table with ``"poses"``)."""
    from xray_viz._files import require_regular

    path = Path(path)
    require_regular(path, SceneError, "poses file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"[scan] poses file {path} not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SceneError(f"[scan] poses file {path} is not readable JSON: {exc}") from None
    except RecursionError:
        raise SceneError(f"[scan] poses file {path} is nested too deeply (arrays or tables thousands of levels inside each other)") from None
    if isinstance(doc, dict) and "poses" in doc:
        doc = doc["poses"]
    if not isinstance(doc, list) or not doc:
        raise SceneError(f"[scan] poses file {path} must hold a non-empty list of poses")
    return tuple(doc)


def orbit_from_dict(table, *, base_dir=".", file=None) -> Orbit:
    """The :class:`Orbit` of a ``[scan]`` table (a poses file relative to ``base_dir``).

    Raises
    ------
    SceneError
        One line naming the file, the key and the value.

    Examples
    --------
    >>> orbit_from_dict({"orbit": "helical", "projections": 8, "pitch": 10.0}).pitch
    10.0
    """
    where = f"{file}: " if file else ""
    try:
        if not isinstance(table, dict):
            raise SceneError(f"[scan] must be a table, got {table!r}")
        unknown = sorted(set(table) - set(SCAN_KEYS))
        if unknown:
            raise SceneError(f"[scan] unknown key(s) {unknown}; known: {', '.join(SCAN_KEYS)}")
        kwargs = {k: table[k] for k in ("projections", "arc", "axis", "center", "pitch",
                                        "start") if k in table}
        poses = table.get("poses")
        kind = table.get("orbit", "poses" if poses is not None else "circular")
        if kind == "poses":                  # each pose says where source and detector are
            for key in ("arc", "pitch", "start"):
                if key in table:
                    raise SceneError(f"[scan] {key} = {table[key]!r} does not apply to a poses "
                                     "orbit (each pose places the source and detector); "
                                     f"remove it, or use orbit = \"circular\"/\"helical\"")
        if poses is not None:
            if kind != "poses":
                raise SceneError(f"[scan] poses are given, so orbit must be \"poses\" "
                                 f"(or left out), got {kind!r}")
            if isinstance(poses, dict):
                random = RandomPoses.from_dict(poses)
                if "projections" in kwargs and kwargs["projections"] != random.count:
                    raise SceneError(f"[scan] projections = {kwargs['projections']!r} but "
                                     f"poses.random = {random.count}")
                kwargs.pop("projections", None)
                return Orbit("poses", random=random, **kwargs)
            if isinstance(poses, str):
                poses = read_poses(Path(base_dir) / poses)
            elif not isinstance(poses, list):
                raise SceneError(f"[scan] poses must be a JSON file name, a list or a table "
                                 f"{{ random = N, seed = ... }}, got {poses!r}")
            if "projections" in kwargs and kwargs["projections"] != len(poses):
                raise SceneError(f"[scan] projections = {kwargs['projections']!r} but the "
                                 f"poses give {len(poses)}")
            kwargs["projections"] = len(poses)
            for k, p in enumerate(poses):
                check_pose(p, where=f"[scan] pose {k}: ")
        return Orbit(kind, poses=poses, **kwargs)
    except SceneError as exc:
        raise SceneError(f"{where}{exc}") from None
