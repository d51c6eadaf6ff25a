"""The scene model: an X-ray source, a detector (the thesis' viewport) and bodies.

One model is shared by the command line, the Python API, the viewer and the tests. A scene is
described in a TOML file::

    [source]
    position = [0.0, 0.0, 1000.0]   # mm; the thesis' r0
    kind = "point"                  # or "parallel"
    energy = 60.0                   # keV

    [detector]
    center = [0.0, 0.0, -500.0]     # mm
    up = [0.0, 1.0, 0.0]
    shape = [512, 384]              # [W, H] pixels
    pitch = 0.25                    # mm between neighbouring rays (or size = [|HO|, |VE|])

    [[body]]
    name = "ball"
    mesh = "ball.stl"               # relative to the scene file
    mu = 0.2                        # 1/cm

Geometry is in millimetres, linear attenuation coefficients in 1/cm, energies in keV.
Unknown keys are an error, so that a typo is never silently ignored.

Examples
--------
>>> import xray_viz
>>> scene = xray_viz.load_scene("sphere")          # a bundled phantom, or a path to a .toml
>>> scene.detector.shape
(256, 256)
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from xray_viz.errors import SceneError, SceneFileNotFoundError, XrayVizError

__all__ = ["Source", "Detector", "Body", "Scene", "load_scene", "scene_from_dict"]

#: Values of ``[detector] response``.
DETECTOR_RESPONSES = ("energy", "counting")

#: Length units accepted by a body's ``units`` key, in millimetres.
LENGTH_UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3, "in": 25.4}


def _vec3(value, *, name: str = "vector") -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{name} must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Source:
    """The X-ray source: the thesis' camera position r0.

    Parameters
    ----------
    position : (3,) float
        Focal spot position in mm (``r0``).
    kind : {"point", "parallel"}
        A point source (cone beam, rays fan out from ``position``) or a parallel beam (every ray
        along ``position -> detector centre``, one ray per pixel).
    energy : float or None
        Photon energy in keV of a monochromatic beam.
    spectrum : dict, Spectrum or None
        Tube or CSV spectrum (see :mod:`xray_viz.physics.spectra`; the parser stores the
        validated table of :func:`~xray_viz.physics.spectra.spectrum_from_dict`); when set it
        replaces ``energy``.
    heel : bool or str
        The heel effect and off-axis spectra (:mod:`xray_viz.physics.heel`): true puts the anode
        at the top of the image, or name its side, ``"top"``, ``"bottom"``, ``"left"`` or
        ``"right"``; needs a point source and a tube spectrum.
    """

    position: np.ndarray
    kind: str = "point"
    energy: float | None = 60.0
    spectrum: dict | None = None
    heel: bool | str = False

    def __post_init__(self):
        object.__setattr__(self, "position", _vec3(self.position, name="source position"))
        if self.kind not in ("point", "parallel"):
            raise SceneError(f"[source] kind must be 'point' or 'parallel', got {self.kind!r}")
        if self.energy is not None and not (math.isfinite(self.energy) and self.energy > 0):
            raise SceneError(f"[source] energy must be > 0 keV, got {self.energy}")
        from xray_viz.physics.heel import heel_side

        heel_side(self.heel)


@dataclass(frozen=True)
class Detector:
    """The detector: the thesis' viewport, a W x H grid of rays.

    Parameters
    ----------
    center : (3,) float
        Centre of the viewport in mm. ``FL = r0 - center``.
    up : (3,) float
        Approximate up direction; ``VE`` is the part of it orthogonal to the beam.
    shape : (int, int)
        ``(W, H)``: W rays along ``HO`` (image columns), H rays along ``VE`` (image rows).
    pitch : (float, float)
        Distance in mm between neighbouring rays along HO and VE. ``|HO| = (W - 1) * pitch[0]``.
    response : {"energy", "counting"}
        Energy-integrating (signal ~ sum fluence * E * transmission) or photon counting.
    i0 : float
        Unattenuated photons per pixel (at the detector centre). With noise off the image is just
        ``i0 * I / I0``; with noise on it sets the photon statistics.
    noise : bool
        Poisson noise.
    seed : int or None
        Seed of the noise (None: fresh randomness each render).
    falloff : bool
        Inverse-square and obliquity fall-off (``cos^3``) of a point source.
    supersample : int
        ``n x n`` rays per pixel, averaged in intensity.
    focal_spot : float
        Focal spot size in mm (FWHM of a Gaussian); 0 for an ideal point.
    scintillator : dict or None
        The converter's absorption, ``{"material", "thickness" (mm), "fill", "density"}``
        (:func:`~xray_viz.physics.detector.scintillator_from_dict`); None: an ideal detector.
    mtf : dict or None
        The detector blur, ``{"sigma": mm}`` or a table (:func:`~xray_viz.physics.detector.
        mtf_from_dict`); None: no blur.
    electronic_noise : float
        Additive Gaussian noise, photon-equivalents rms (needs ``noise``).
    gain : float
        Detected units per photon-equivalent.

    See :mod:`xray_viz.physics` for what these model and what they do not.
    """

    center: np.ndarray
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    shape: tuple[int, int] = (256, 256)
    pitch: tuple[float, float] = (1.0, 1.0)
    response: str = "energy"
    i0: float = 1.0
    noise: bool = False
    seed: int | None = None
    falloff: bool = False
    supersample: int = 1
    focal_spot: float = 0.0
    scintillator: dict | None = None
    mtf: dict | None = None
    electronic_noise: float = 0.0
    gain: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "center", _vec3(self.center, name="detector center"))
        object.__setattr__(self, "up", _vec3(self.up, name="detector up"))
        shape = tuple(int(s) for s in np.broadcast_to(self.shape, (2,)))
        if any(s < 1 for s in shape):
            raise SceneError(f"[detector] shape must be >= 1 pixel each way, got {list(shape)}")
        pitch = tuple(float(p) for p in np.broadcast_to(np.asarray(self.pitch, float), (2,)))
        if not all(math.isfinite(p) and p > 0 for p in pitch):
            raise SceneError(f"[detector] pitch must be > 0 mm, got {list(pitch)}")
        if np.linalg.norm(self.up) == 0:
            raise SceneError("[detector] up must be a non-zero vector")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "pitch", pitch)
        if self.response not in DETECTOR_RESPONSES:
            raise SceneError(f"[detector] response must be 'energy' or 'counting', "
                             f"got {self.response!r}")
        if not (math.isfinite(self.i0) and self.i0 > 0):
            raise SceneError(f"[detector] I0 must be > 0 photons per pixel, got {self.i0}")
        if isinstance(self.supersample, bool) or int(self.supersample) != self.supersample \
                or self.supersample < 1:
            raise SceneError(f"[detector] supersample must be an integer >= 1, "
                             f"got {self.supersample!r}")
        if not (math.isfinite(self.focal_spot) and self.focal_spot >= 0):
            raise SceneError(f"[detector] focal_spot must be >= 0 mm, got {self.focal_spot}")
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int)
                                      or self.seed < 0):
            raise SceneError(f"[detector] seed must be an integer >= 0, got {self.seed!r}")
        object.__setattr__(self, "i0", float(self.i0))
        object.__setattr__(self, "supersample", int(self.supersample))
        object.__setattr__(self, "focal_spot", float(self.focal_spot))
        object.__setattr__(self, "noise", bool(self.noise))
        object.__setattr__(self, "falloff", bool(self.falloff))
        self._check_detector_physics()

    def _check_detector_physics(self):
        """Validate and canonicalise ``scintillator``, ``mtf``, ``electronic_noise``, ``gain``."""
        from xray_viz.physics import detector as phys

        try:
            if self.scintillator is not None:
                object.__setattr__(self, "scintillator",
                                   phys.scintillator_from_dict(self.scintillator))
            if self.mtf is not None:
                mtf = phys.mtf_from_dict(self.mtf)
                phys.check_mtf_reaches_nyquist(mtf, self.pitch)
                object.__setattr__(self, "mtf", mtf)
        except SceneError as exc:
            raise SceneError(f"[detector] {exc}") from None
        if self.mtf is not None and "sigma" in self.mtf:
            extent = max(self.shape[0] * self.pitch[0], self.shape[1] * self.pitch[1])
            if not 2.0 * math.sqrt(2.0 * math.log(2.0)) * self.mtf["sigma"] <= extent:   # FWHM
                raise SceneError(f"[detector] mtf sigma = {self.mtf['sigma']:g} mm blurs more "
                                 f"than the detector's {extent:.3g} mm: give it in mm (a "
                                 "converter's light spread is ~0.05-0.3 mm)")
        for key, low in (("electronic_noise", None), ("gain", 0.0)):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or (value <= low if low is not None else value < 0):
                raise SceneError(f"[detector] {key} must be a number "
                                 f"{'> 0' if low is not None else '>= 0'}, got {value!r}")
            object.__setattr__(self, key, float(value))
        if self.electronic_noise > 0 and not self.noise:
            raise SceneError(f"[detector] electronic_noise = {self.electronic_noise:g} needs "
                             "noise = true (electronic noise is part of the noise model)")

    @property
    def size(self) -> tuple[float, float]:
        """``(|HO|, |VE|)`` in mm: the distance between the first and last rays."""
        (w, h), (px, py) = self.shape, self.pitch
        return (max(w - 1, 0) * px, max(h - 1, 0) * py)

    @classmethod
    def from_size(cls, center, up, shape, size, **options) -> "Detector":
        """Make a detector from its size ``[|HO|, |VE|]`` in mm instead of its pitch.

        ``options`` are the other fields (``response``, ``i0``, ``noise``, ...).
        """
        shape = tuple(int(s) for s in np.broadcast_to(shape, (2,)))
        size = np.broadcast_to(np.asarray(size, float), (2,))
        if not np.all(np.isfinite(size)) or np.any(size <= 0):
            raise SceneError(f"[detector] size must be > 0 mm, got {size.tolist()}")
        pitch = tuple(float(s / max(n - 1, 1)) for s, n in zip(size, shape))
        return cls(center=center, up=up, shape=shape, pitch=pitch, **options)


@dataclass(frozen=True, eq=False)
class Body:
    """A closed triangle mesh filled with one material.

    Parameters
    ----------
    name : str
        Unique name of the body.
    mesh : trimesh.Trimesh
        Closed, outward-oriented surface, in scene coordinates (mm), transforms applied.
    mu : float or None
        Linear attenuation coefficient in 1/cm (energy independent).
    material : str, dict or None
        A NIST compound name, chemical formula or element, or a dict of mass fractions (see
        :mod:`xray_viz.physics.materials`); used instead of ``mu`` when set.
    density : float or None
        Density in g/cm^3 for ``material``.
    source_file : Path or None
        File the mesh was read from, for messages.
    """

    name: str
    mesh: Any
    mu: float | None = None
    material: str | None = None
    density: float | None = None
    source_file: Path | None = None

    def __post_init__(self):
        if self.mu is None and self.material is None:
            raise SceneError(f"body {self.name!r}: give 'mu' (1/cm) or 'material'")
        if self.mu is not None and not (math.isfinite(self.mu) and self.mu >= 0):
            raise SceneError(f"body {self.name!r}: mu must be >= 0 (1/cm), got {self.mu}")

    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float vertex positions in mm."""
        return np.asarray(self.mesh.vertices, dtype=np.float64)

    @property
    def faces(self) -> np.ndarray:
        """(m, 3) int vertex indices of each triangle, counter-clockwise seen from outside."""
        return np.asarray(self.mesh.faces, dtype=np.int64)


@dataclass(frozen=True, eq=False)
class Scene:
    """A source, a detector and bodies.

    Build one with :func:`load_scene` (a TOML file or a bundled phantom name) or directly.
    Derived data (the concatenated triangle soup) is computed once and cached; use
    :meth:`replace` to make a changed copy.

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> moved = scene.replace(source=dataclasses.replace(scene.source, position=[0, 0, 800]))
    """

    source: Source
    detector: Detector
    bodies: tuple[Body, ...] = ()
    path: Path | None = None

    def __post_init__(self):
        object.__setattr__(self, "bodies", tuple(self.bodies))
        names = [b.name for b in self.bodies]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise SceneError(f"{self._where()}body names must be unique, repeated: {dup}")
        from xray_viz.geometry import beam_direction

        forward = beam_direction(self.source.position, self.detector.center)
        up = self.detector.up / np.linalg.norm(self.detector.up)
        if np.linalg.norm(np.cross(forward, up)) < 1e-9:
            raise SceneError(
                f"{self._where()}[detector] up {self.detector.up.tolist()} is parallel to the beam "
                "(source -> detector centre); choose an up vector across the beam"
            )
        object.__setattr__(self, "bodies", tuple(_traceable(b, self._where()) for b in self.bodies))
        from xray_viz.attenuation import check_source_outside

        check_source_outside(self)
        from xray_viz.physics.heel import check_heel

        check_heel(self)

    def _where(self) -> str:
        return f"{self.path}: " if self.path else ""

    def replace(self, **changes) -> "Scene":
        """Return a copy with fields replaced (``source=``, ``detector=``, ``bodies=``)."""
        return dataclasses.replace(self, **changes)

    def transform_bodies(self, matrix) -> "Scene":
        """Return a copy with every body moved by the same affine transform.

        An invertible map that keeps orientation (determinant > 0) keeps every body closed and
        outward and keeps which body lies inside which, so the mesh checks and the bodies'
        :attr:`precedence` carry over instead of being recomputed (the viewer's rotation
        slider re-renders the frog without testing its 16 bodies for nesting again).

        Parameters
        ----------
        matrix : (4, 4) array_like
            Homogeneous transform applied to the mesh vertices (mm); last row ``[0, 0, 0, 1]``.

        Returns
        -------
        Scene

        Raises
        ------
        SceneError
            If ``matrix`` is not a finite 4 x 4 affine transform with a positive determinant.

        Examples
        --------
        >>> import numpy as np, xray_viz
        >>> scene = xray_viz.load_scene("nested_spheres")
        >>> shifted = scene.transform_bodies(np.array([[1, 0, 0, 5.0], [0, 1, 0, 0],
        ...                                            [0, 0, 1, 0], [0, 0, 0, 1]]))
        >>> float(shifted.bodies[0].vertices[:, 0].mean() - scene.bodies[0].vertices[:, 0].mean())
        5.0
        """
        from xray_viz.meshes.repair import check_mesh, remember_check

        m = np.asarray(matrix, dtype=float)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)) or not np.allclose(m[3], [0, 0, 0, 1]):
            raise SceneError(f"transform_bodies: need a finite 4 x 4 affine matrix with last row "
                             f"[0, 0, 0, 1], got shape {m.shape}")
        det = float(np.linalg.det(m[:3, :3]))
        if not det > 0:
            raise SceneError(f"transform_bodies: the matrix must keep orientation (determinant "
                             f"> 0), got {det:.6g}; a mirror image would turn meshes inside out")
        bodies = []
        for body in self.bodies:
            mesh = body.mesh.copy()
            mesh.apply_transform(m)
            report = check_mesh(body.mesh)
            remember_check(mesh, dataclasses.replace(report, volume=report.volume * det))
            bodies.append(dataclasses.replace(body, mesh=mesh))
        from xray_viz.attenuation import remember_precedence

        remember_precedence(bodies, self.precedence)
        return self.replace(bodies=tuple(bodies))

    @property
    def body_names(self) -> list[str]:
        return [b.name for b in self.bodies]

    @cached_property
    def triangles(self) -> np.ndarray:
        """(T, 3, 3) float: every triangle of every body, bodies in order."""
        if not self.bodies:
            return np.zeros((0, 3, 3))
        tris = np.concatenate([b.vertices[b.faces] for b in self.bodies])
        tris.setflags(write=False)
        return tris

    @cached_property
    def triangle_body(self) -> np.ndarray:
        """(T,) int: index of the body each triangle of :attr:`triangles` belongs to."""
        counts = [len(b.faces) for b in self.bodies]
        return np.repeat(np.arange(len(self.bodies)), counts)

    @cached_property
    def triangle_offset(self) -> np.ndarray:
        """(n_bodies + 1,) int: body k owns triangles ``triangle_offset[k]:triangle_offset[k+1]``."""
        return np.concatenate([[0], np.cumsum([len(b.faces) for b in self.bodies])]).astype(np.int64)

    @cached_property
    def precedence(self) -> np.ndarray:
        """(n_bodies,) int rank: where bodies overlap, the highest rank gives the material.

        Innermost wins (a body inside another replaces its material), and where bodies only
        partly overlap the later-listed one wins. See :func:`xray_viz.attenuation.body_precedence`.
        """
        from xray_viz.attenuation import body_precedence

        return body_precedence(self)


def _traceable(body: Body, where: str = "") -> Body:
    """The body itself when its mesh is closed and outward; else repaired, with a warning."""
    from xray_viz.meshes.repair import MeshRepairWarning, check_mesh, ensure_traceable

    if check_mesh(body.mesh).traceable:
        return body
    try:
        mesh, changes = ensure_traceable(body.mesh, name=body.name)
    except XrayVizError as exc:
        raise type(exc)(f"{where}{exc}") from None
    import warnings

    warnings.warn(f"{where}body {body.name!r}: mesh repaired: {'; '.join(changes)}",
                  MeshRepairWarning, stacklevel=3)
    return dataclasses.replace(body, mesh=mesh)


# --------------------------------------------------------------------------------------------
# TOML parsing and validation

#: Every key each table of a scene file accepts (an unknown key is an error that lists these).
SOURCE_KEYS = ("position", "kind", "energy", "spectrum", "heel")
DETECTOR_KEYS = ("center", "up", "shape", "pitch", "size", "response", "I0", "noise", "seed",
                 "falloff", "supersample", "focal_spot", "scintillator", "mtf",
                 "electronic_noise", "gain")
BODY_KEYS = ("name", "mesh", "mu", "material", "density", "position", "rotation", "scale",
             "units", "repair")


class _Table:
    """Typed access to one TOML table that remembers which keys were read."""

    def __init__(self, data, where: str, file: Path | None):
        self.where = where
        self.file = file
        if not isinstance(data, dict):
            self.fail(f"must be a table, got {type(data).__name__}")
        self.data = data
        self.used: set[str] = set()

    def fail(self, msg: str):
        prefix = f"{self.file}: " if self.file else ""
        raise SceneError(f"{prefix}{self.where} {msg}")

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key, *, required=False, default=None):
        self.used.add(key)
        if key not in self.data:
            if required:
                self.fail(f"is missing the required key '{key}'")
            return default
        return self.data[key]

    def number(self, key, *, required=False, default=None, positive=False, nonnegative=False):
        value = self.raw(key, required=required, default=default)
        if value is None or key not in self.data:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(f"{key} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            self.fail(f"{key} must be finite, got {value}")
        if positive and value <= 0:
            self.fail(f"{key} must be > 0, got {value:g}")
        if nonnegative and value < 0:
            self.fail(f"{key} must be >= 0, got {value:g}")
        return value

    def string(self, key, *, required=False, default=None, choices=None):
        value = self.raw(key, required=required, default=default)
        if key not in self.data:
            return value
        if not isinstance(value, str):
            self.fail(f"{key} must be a string, got {value!r}")
        if choices is not None and value not in choices:
            self.fail(f"{key} must be one of {', '.join(map(repr, choices))}; got {value!r}")
        return value

    def vector(self, key, n, *, required=False, default=None, positive=False, integer=False):
        value = self.raw(key, required=required, default=default)
        if key not in self.data:
            return value
        ok = isinstance(value, list) and len(value) == n and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        )
        if integer:
            ok = ok and all(isinstance(v, int) for v in value)
        if not ok:
            kind = "integers" if integer else "numbers"
            self.fail(f"{key} must be a list of {n} {kind}, got {value!r}")
        arr = np.asarray(value, dtype=np.int64 if integer else np.float64)
        if not np.all(np.isfinite(arr)):
            self.fail(f"{key} must be finite, got {value!r}")
        if positive and np.any(arr <= 0):
            self.fail(f"{key} must be > 0, got {value!r}")
        return arr

    def scalar_or_vector(self, key, n, *, default=None, positive=False):
        if key in self.data and isinstance(self.data[key], list):
            return self.vector(key, n, positive=positive)
        value = self.number(key, default=default, positive=positive)
        return None if value is None else np.full(n, value)

    def table(self, key, *, required=False):
        value = self.raw(key, required=required, default=None)
        if value is None:
            return None
        return _Table(value, f"{self.where[:-1]}.{key}]" if self.where.endswith("]") else key,
                      self.file)

    def expect(self, keys):
        """Fail now on keys outside ``keys`` (a typo is reported before the key it misspelt)."""
        self.used.update(keys)
        self.done()
        self.used.difference_update(keys)

    def done(self):
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            import difflib

            hints = []
            for key in unknown:
                close = difflib.get_close_matches(key, sorted(self.used), n=1)
                hints.append(f"'{key}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
            self.fail(f"has unknown key{'s' if len(unknown) > 1 else ''} {', '.join(hints)}; "
                      f"known keys: {', '.join(sorted(self.used))}")


def _rotation_matrix(rotation) -> np.ndarray:
    """3x3 rotation from Euler angles in degrees about x, then y, then z (fixed axes)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    if rotation.shape == (3, 3):
        return rotation
    ax, ay, az = np.radians(rotation)
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def body_transform(*, position=None, rotation=None, scale=None, units="mm") -> np.ndarray:
    """4x4 matrix taking mesh coordinates to scene millimetres.

    The mesh is scaled (``units`` then ``scale``), then rotated (degrees about x, y, z in
    that order, fixed axes, or a 3x3 matrix), then translated to ``position``.

    Examples
    --------
    >>> body_transform(position=[1, 2, 3])[:3, 3].tolist()
    [1.0, 2.0, 3.0]
    """
    m = np.eye(4)
    s = np.ones(3) * LENGTH_UNITS[units]
    if scale is not None:
        s = s * np.broadcast_to(np.asarray(scale, float), (3,))
    r = np.eye(3) if rotation is None else _rotation_matrix(rotation)
    m[:3, :3] = r @ np.diag(s)
    if position is not None:
        m[:3, 3] = position
    return m


def _boolean(t: _Table, key: str, default: bool = False) -> bool:
    value = t.raw(key, default=default)
    if not isinstance(value, bool):
        t.fail(f"{key} must be true or false, got {value!r}")
    return value


def _integer(t: _Table, key: str, *, minimum: int, default=None):
    value = t.raw(key, default=default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        t.fail(f"{key} must be an integer >= {minimum}, got {value!r}")
    return value


def _parse_body(t: _Table, base_dir: Path, index: int) -> Body:
    from xray_viz.meshes.io import load_mesh

    t.expect(BODY_KEYS)
    name = t.string("name", default=f"body{index}")
    mesh_name = t.string("mesh", required=True)
    mu = t.number("mu", nonnegative=True)
    material = t.raw("material")
    if material is not None and not isinstance(material, (str, dict)):
        t.fail(f"material must be a name or formula string, or a table of mass fractions such as "
               f"{{ H2O = 0.9, NaCl = 0.1 }}; got {material!r}")
    density = t.number("density", positive=True)
    if mu is not None and material is not None:
        t.fail("gives both 'mu' and 'material'; use one")
    if mu is None and material is None:
        t.fail("needs 'mu' (linear attenuation coefficient, 1/cm) or 'material'")
    if mu is not None and density is not None:
        t.fail("gives 'density' with 'mu'; density goes with 'material'")
    if material is not None:
        from xray_viz.errors import MaterialError
        from xray_viz.physics.materials import check_material

        try:
            check_material(material, density=density)
        except MaterialError as exc:
            t.fail(f"(name {name!r}): {exc}")
    position = t.vector("position", 3)
    rotation = None
    if t.has("rotation"):
        raw = t.data["rotation"]
        if isinstance(raw, list) and raw and all(isinstance(r, list) for r in raw):
            t.used.add("rotation")
            rot = np.asarray(raw, dtype=float) if all(len(r) == 3 for r in raw) else None
            if rot is None or rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) \
                    or np.linalg.det(rot) < 0:
                t.fail(f"rotation must be 3 angles in degrees or a 3x3 rotation matrix, got {raw!r}")
            rotation = rot
        else:
            rotation = t.vector("rotation", 3)
    scale = t.scalar_or_vector("scale", 3, positive=True)
    units = t.string("units", default="mm", choices=tuple(LENGTH_UNITS))
    repair = t.raw("repair", default=True)
    if not isinstance(repair, bool):
        t.fail(f"repair must be true or false, got {repair!r}")
    t.done()
    path = (base_dir / mesh_name).resolve() if not Path(mesh_name).is_absolute() else Path(mesh_name)
    where = f"{t.file}: " if t.file else ""
    try:
        mesh = load_mesh(path)
    except XrayVizError as exc:
        raise type(exc)(f"{where}body {name!r}: {exc}") from None
    transform = body_transform(position=position, rotation=rotation, scale=scale, units=units)
    if not np.allclose(transform, np.eye(4)):
        mesh = mesh.copy()
        mesh.apply_transform(transform)
    from xray_viz.meshes.repair import MeshRepairWarning, ensure_traceable

    try:
        mesh, changes = ensure_traceable(mesh, name=name, repair=repair)
    except XrayVizError as exc:
        raise type(exc)(f"{where}{path.name}: {exc}") from None
    if changes:
        import warnings

        warnings.warn(f"{where}body {name!r} ({path.name}): mesh repaired: {'; '.join(changes)}",
                      MeshRepairWarning, stacklevel=2)
    return Body(name=name, mesh=mesh, mu=mu, material=material, density=density, source_file=path)


def scene_from_dict(doc: dict, *, base_dir: str | Path = ".", file: Path | None = None) -> Scene:
    """Build a :class:`Scene` from a parsed TOML document.

    Parameters
    ----------
    doc : dict
        The parsed document with ``source``, ``detector`` and ``body`` entries.
    base_dir : path-like
        Directory that mesh paths are relative to.
    file : Path, optional
        The file the document came from, named in error messages.
    """
    base_dir = Path(base_dir)
    top = _Table(doc, "scene", file)
    top.expect(("source", "detector", "body"))
    src = top.table("source", required=True)
    src.where = "[source]"
    src.expect(SOURCE_KEYS)
    position = src.vector("position", 3, required=True)
    kind = src.string("kind", default="point", choices=("point", "parallel"))
    spectrum = src.raw("spectrum")
    energy = src.number("energy", default=None if spectrum is not None else 60.0, positive=True)
    if spectrum is not None and src.has("energy"):
        src.fail("gives both 'energy' and 'spectrum'; use one")
    heel = src.raw("heel", default=False)
    if not isinstance(heel, (bool, str)):
        src.fail(f"heel must be true, false or the anode's side of the image, got {heel!r}")
    src.done()
    if spectrum is not None:
        from xray_viz.errors import SpectrumError
        from xray_viz.physics.spectra import spectrum_from_dict

        try:
            spectrum = spectrum_from_dict(spectrum, base_dir=base_dir)
        except SceneFileNotFoundError as exc:
            raise SceneFileNotFoundError(f"{src.file}: [source] {exc}" if src.file
                                         else f"[source] {exc}") from None
        except SpectrumError as exc:
            src.fail(str(exc))

    det = top.table("detector", required=True)
    det.where = "[detector]"
    det.expect(DETECTOR_KEYS)
    center = det.vector("center", 3, required=True)
    up = det.vector("up", 3, default=np.array([0.0, 1.0, 0.0]))
    shape = det.vector("shape", 2, required=True, integer=True)
    if np.any(shape < 1):
        det.fail(f"shape must be >= 1 pixel each way, got {shape.tolist()}")
    if det.has("pitch") and det.has("size"):
        det.fail("gives both 'pitch' and 'size'; use one")
    if not det.has("pitch") and not det.has("size"):
        det.fail("is missing the required key 'pitch' (mm between rays) or 'size' ([|HO|, |VE|] mm)")
    if np.linalg.norm(up) == 0:
        det.fail("up must be a non-zero vector")
    if det.has("size"):
        size = det.vector("size", 2, positive=True)
        pitch = size / np.maximum(shape - 1, 1)
    else:
        pitch = det.scalar_or_vector("pitch", 2, positive=True)
    options = {
        "response": det.string("response", default="energy", choices=DETECTOR_RESPONSES),
        "noise": _boolean(det, "noise"),
        "falloff": _boolean(det, "falloff"),
        "seed": _integer(det, "seed", minimum=0),
        "supersample": _integer(det, "supersample", minimum=1, default=1),
        "focal_spot": det.number("focal_spot", default=0.0, nonnegative=True),
        "electronic_noise": det.number("electronic_noise", default=0.0, nonnegative=True),
        "gain": det.number("gain", default=1.0, positive=True),
    }
    from xray_viz.physics import detector as phys

    for key, parse in (("scintillator", phys.scintillator_from_dict),
                       ("mtf", lambda raw: phys.mtf_from_dict(raw, base_dir=base_dir))):
        try:
            options[key] = None if not det.has(key) else parse(det.raw(key))
        except SceneFileNotFoundError as exc:
            raise SceneFileNotFoundError(f"{det.file}: [detector] {key}: {exc}" if det.file
                                         else f"[detector] {key}: {exc}") from None
        except SceneError as exc:
            det.fail(str(exc))
    if options["noise"] and not det.has("I0"):
        det.fail("sets noise = true without 'I0': give the unattenuated photons per pixel, "
                 "e.g. I0 = 10000.0")
    options["i0"] = det.number("I0", default=1.0, positive=True)
    det.done()

    raw_bodies = top.raw("body", default=[])
    if not isinstance(raw_bodies, list):
        top.fail("'body' must be an array of tables: write [[body]]")
    top.done()
    bodies = []
    for k, raw in enumerate(raw_bodies):
        bt = _Table(raw, f"[[body]] #{k + 1}", file)
        bodies.append(_parse_body(bt, base_dir, k))
    try:
        scene = Scene(
            source=Source(position=position, kind=kind, energy=energy, spectrum=spectrum,
                          heel=heel),
            detector=Detector(center=center, up=up, shape=tuple(shape), pitch=tuple(pitch),
                              **options),
            bodies=tuple(bodies),
            path=file,
        )
    except SceneError as exc:
        msg = str(exc)
        if file and not msg.startswith(str(file)):
            msg = f"{file}: {msg}"
        raise SceneError(msg) from None
    return scene


def load_scene(path: str | Path) -> Scene:
    """Load a scene from a TOML file, or a bundled phantom by name.

    Parameters
    ----------
    path : str or Path
        A ``.toml`` scene file, or the name of a bundled phantom (see ``xray-viz phantoms``).
        An existing file is read; otherwise a bare name (no suffix, no folder) is a phantom's
        name, even when a folder of that name exists (``./frog`` names the folder).

    Returns
    -------
    Scene

    Raises
    ------
    SceneFileNotFoundError
        If the file does not exist and no phantom has that name.
    SceneError
        If the file is not valid TOML or not a valid scene (unknown or missing keys, wrong types,
        bad values, ``up`` parallel to the beam, the source inside a body).

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> [body.name for body in scene.bodies]
    ['ball']
    """
    p = Path(path)
    if not p.is_file():
        # a bare name (no suffix, no folder) that is not a file is a phantom's name, even when
        # the working directory has a folder of that name (a phantom's mesh folder, say)
        from xray_viz import phantoms

        bare = not p.suffix and "/" not in str(path) and "\\" not in str(path)
        resolved = phantoms.scene_path(str(path)) if bare else None
        if resolved is not None:
            p = resolved
        elif p.is_dir():
            raise SceneError(f"{p}: is a directory, not a scene file")
        elif not p.exists():
            names = ", ".join(phantoms.names())
            raise SceneFileNotFoundError(
                f"{path}: no such scene file, and no bundled phantom of that name "
                f"(phantoms: {names})"
            )
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise SceneError(f"{p}: not a text (UTF-8) TOML file") from None
    except OSError as exc:
        raise SceneError(f"{p}: cannot read: {exc.strerror}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{p}: malformed TOML: {exc}") from None
    return scene_from_dict(doc, base_dir=p.parent, file=p)
