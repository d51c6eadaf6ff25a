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
Unknown keys are an error, so that a typo is never silently ignored. Reading and writing the
files is :mod:`xray_viz.scene_file`'s job; this module is the model.

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from xray_viz._checks import is_number as _is_number
from xray_viz._checks import shown as _shown
from xray_viz._checks import vector3
from xray_viz.errors import SceneError
from xray_viz.physics.spectra import DEFAULT_ENERGY

__all__ = ["Source", "Detector", "Body", "Scene"]

#: Values of ``[detector] response``.
DETECTOR_RESPONSES = ("energy", "counting", "kerma")

#: Length units accepted by a body's ``units`` key, in millimetres.
LENGTH_UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3, "in": 25.4}

#: Largest coordinate (mm) of a source, a detector centre or a body's vertex: 1000 km. Rays
#: from that far keep their path lengths to 1e-7 mm (float64 rounds a distance d to 1e-16 d);
#: squared distances overflow float64 only beyond 1e154 mm.
COORDINATE_LIMIT = 1e9

#: The open range of a usable direction's largest coordinate: its square is an ordinary float64.
DIRECTION_LENGTH = (1e-150, 1e150)

#: Smallest and largest detector pitch (mm between neighbouring rays). The fast engine maps the
#: detector onto a fixed-point grid: projected positions are snapped to ``2**-22`` of a (sub-ray)
#: pitch and the grid spans ``2**35`` pitches each way (``FRAC_BITS`` and ``COORD_LIMIT`` of
#: :mod:`xray_viz.tracing._raster`); a triangle across the beam with a vertex beyond it cannot
#: be traced. At 1e-6 mm (1 nm) the grid spans +-34 m (over the supersampling factor), room for
#: any triangle; it shrinks with the pitch (+-34 mm at 1e-9 mm, 0.03 mm at 1e-12 mm, where the
#: sphere phantom's 2 mm facets no longer fit). At 1e6 mm (1 km) a snapped ray is placed only
#: to 0.12 mm (``2**-23`` pitch). Real detectors lie far inside (0.5 um to a few mm).
PITCH_RANGE = (1e-6, 1e6)

#: A pitch must be at least this fraction of the detector centre's distance from the origin
#: (its largest coordinate): float64 places points there to ``2**-52`` of that distance, so the
#: rays are then placed to ``2**-22`` of a pitch, as finely as the fast engine snaps them.
PITCH_MIN_RELATIVE = 2.0 ** -30

#: Smallest and largest body (the largest side of its bounding box in the scene, mm). The mesh
#: check and the engines multiply up to four lengths (volumes, determinants, the fast engine's
#: plane coefficients, with the detector pitch and the source distance), and float64 holds only
#: 1e-308 to 1e308 (1e-324 with lost precision): 1 pm to 1000 km keeps every such product many
#: orders of magnitude inside. (The sphere phantom scaled as a whole, pitch and distances too,
#: rendered wrong in the fast engine at 1e+-100, right in both engines at 1e+-60.)
BODY_SIZE_RANGE = (1e-9, 1e9)

#: A body must be at least this fraction of its distance from the origin across (its largest
#: coordinate): float64 then places its vertices to ``2**-22`` of its size.
BODY_MIN_RELATIVE = 2.0 ** -30


def _is_integer(value) -> bool:
    """A Python or NumPy integer, not a bool (nor a float, even an integral one)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _real(value, name: str, *, positive=False, nonnegative=False, optional=False):
    """``value`` as a finite float, or SceneError naming ``name`` (refuses bools and strings)."""
    if value is None and optional:
        return None
    if not _is_number(value):
        raise SceneError(f"{name} must be a number, got {_shown(value)} ({type(value).__name__})")
    try:
        x = float(value)
    except OverflowError:                      # a Python int beyond float64
        x = math.inf
    if not math.isfinite(x):
        raise SceneError(f"{name} must be finite, got {_shown(value)}")
    if positive and not x > 0:
        raise SceneError(f"{name} must be > 0, got {x:g}")
    if nonnegative and not x >= 0:
        raise SceneError(f"{name} must be >= 0, got {x:g}")
    return x


def _flag(value, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise SceneError(f"{name} must be True or False, got {_shown(value)} "
                         f"({type(value).__name__})")
    return bool(value)


def _numbers(value, name: str, n: int) -> np.ndarray:
    """A number or ``n`` numbers as a finite (n,) float array, or SceneError naming ``name`` (no
    coercion of strings or bools; NumPy arrays of integers or floats are fine)."""
    if isinstance(value, (list, tuple)):
        ok = all(_is_number(v) for v in value)
    else:
        ok = _is_number(value) or (isinstance(value, np.ndarray) and value.dtype.kind in "iuf")
    size = np.size(value) if ok else 0
    if not ok or size not in (1, n):
        raise SceneError(f"{name} must be {'a number or ' if n > 1 else ''}{n} numbers, "
                         f"got {_shown(value)}")
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except OverflowError:                      # a Python int beyond float64
        arr = np.array([math.inf])
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{name} must be finite, got {_shown(value)}")
    return np.broadcast_to(arr, (n,)).copy() if arr.size == 1 else arr


def _vec3(value, *, name: str = "vector", position: bool = True) -> np.ndarray:
    """A finite 3-vector of numbers (read-only float64), or SceneError naming ``name``.

    A ``position`` (mm) must lie within :data:`COORDINATE_LIMIT` of the origin; a direction
    (``position=False``) must have a length between 1e-150 and 1e150, so that its square is an
    ordinary float64 number (``_checks.vector3`` with the scene's limits)."""
    if position:
        return vector3(value, name, strict=True, limit=COORDINATE_LIMIT)
    return vector3(value, name, strict=True, length=DIRECTION_LENGTH)


def check_pitch(pitch, center, *, what: str = "pitch") -> tuple[float, float]:
    """Validate a detector pitch (mm) for the detector centre ``center``; return it as a pair.

    A pitch must lie in :data:`PITCH_RANGE` (1e-6 to 1e6 mm) and be at least
    :data:`PITCH_MIN_RELATIVE` (``2**-30``) of the detector centre's largest coordinate.

    Raises
    ------
    SceneError
        Naming ``what`` (``"pitch"``, or a sentence about ``size``) and the limit.
    """
    px = tuple(float(p) for p in pitch)
    lo, hi = PITCH_RANGE
    for p in px:
        if not lo <= p <= hi:
            raise SceneError(
                f"[detector] {what} {p:g} mm: out of range, a pitch must be between {lo:g} and "
                f"{hi:g} mm (the fast engine's fixed-point grid snaps rays to 2**-22 of a pitch "
                f"and spans 2**35 pitches); check the units (mm)")
    far = float(np.max(np.abs(center)))
    floor = PITCH_MIN_RELATIVE * far
    if min(px) < floor:
        raise SceneError(
            f"[detector] {what} {min(px):g} mm: too fine for a detector centred {far:g} mm from "
            f"the origin: float64 places points there only to 2**-52 of that distance, so the "
            f"pitch must be >= 2**-30 of it ({floor:.3g} mm); use a coarser pitch or move the "
            f"scene nearer the origin")
    return px


def check_body_size(vertices, *, where: str, cause: str | None = None) -> None:
    """Validate a body's size in the scene (mm): finite, within :data:`BODY_SIZE_RANGE`, within
    :data:`COORDINATE_LIMIT` of the origin, and at least :data:`BODY_MIN_RELATIVE` of its
    distance from the origin across.

    ``where`` starts the message (``"body 'ball': "``), ``cause`` says what gave the mesh its
    place and size (``"scale 1e-200"``), if anything did. A mesh with no extent at all (a point)
    is left to the mesh check.

    Raises
    ------
    SceneError
    """
    v = np.asarray(vertices, dtype=np.float64)
    if not len(v):
        return
    lo, hi = BODY_SIZE_RANGE
    makes, puts = (f"{cause} makes the mesh", f"{cause} puts the mesh") if cause else \
        ("the mesh is", "the mesh is")
    if not np.all(np.isfinite(v)):
        what = f"{makes} overflow float64 (coordinates beyond 1.8e308 mm)" if cause else \
            "the mesh has non-finite vertices"
        raise SceneError(f"{where}{what}: a body must be between {lo:g} and {hi:g} mm across; "
                         f"check scale and units")
    with np.errstate(over="ignore", invalid="ignore"):
        size = float(np.max(np.ptp(v, axis=0)))
        far = float(np.max(np.abs(v)))
    if size > 0 and not lo <= size <= hi:
        raise SceneError(f"{where}{makes} {size:.3g} mm across: a body must be between {lo:g} "
                         f"and {hi:g} mm across (the engines multiply several lengths, which "
                         f"float64 holds only between 1e-308 and 1e308); check scale and units")
    if far > COORDINATE_LIMIT:
        raise SceneError(f"{where}{puts} {far:.3g} mm from the origin: coordinates must be "
                         f"within {COORDINATE_LIMIT:g} mm (1000 km); check position, scale and "
                         f"units")
    if size == 0:
        return
    if size < BODY_MIN_RELATIVE * far:
        raise SceneError(f"{where}{puts} ({size:.3g} mm across) {far:.3g} mm from the origin, "
                         f"where float64 places vertices only to {far * 2.0 ** -52:.2g} mm: a "
                         f"body must be at least 2**-30 of its distance from the origin across; "
                         f"move the scene nearer the origin")


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
        Photon energy in keV of a monochromatic beam (any energy > 0 for bodies of constant
        ``mu``; bodies of a ``material`` need 0.1 to 800 keV, the range of xraylib's tables).
    spectrum : dict, Spectrum or None
        Tube or CSV spectrum (see :mod:`xray_viz.physics.spectra`; the parser stores the
        validated table of :func:`~xray_viz.physics.spectra.spectrum_from_dict`); when set it
        replaces ``energy``.
    heel : bool or str
        The heel effect and off-axis spectra (:mod:`xray_viz.physics.heel`): true puts the anode
        at the top of the image, or name its side, ``"top"``, ``"bottom"``, ``"left"`` or
        ``"right"``; needs a point source and a tube spectrum.
    mas : float or None
        Tube current-time product (mAs) of a tube spectrum: the scene file then derives the
        detector's ``I0`` from it (:func:`~xray_viz.physics.dosimetry.photons_per_pixel`), and
        :func:`~xray_viz.physics.dosimetry.air_kerma` reports the exposure.

    Numbers must be numbers: a string (``energy="60"``) or a bool is refused, not converted.

    Raises
    ------
    SceneError
        On a value of the wrong type or out of range.
    """

    position: np.ndarray
    kind: str = "point"
    energy: float | None = DEFAULT_ENERGY
    spectrum: dict | None = None
    mas: float | None = None
    heel: bool | str = False

    def __post_init__(self):
        object.__setattr__(self, "position", _vec3(self.position, name="[source] position"))
        if not isinstance(self.kind, str) or self.kind not in ("point", "parallel"):
            raise SceneError(f"[source] kind must be 'point' or 'parallel', "
                             f"got {_shown(self.kind)}")
        energy = _real(self.energy, "[source] energy (keV)", positive=True, optional=True)
        object.__setattr__(self, "energy", energy)
        if self.spectrum is not None:
            from collections.abc import Mapping

            from xray_viz.physics.spectra import Spectrum

            if not isinstance(self.spectrum, (Mapping, Spectrum)):
                raise SceneError(f"[source] spectrum must be a table such as {{'kvp': 80.0}} or "
                                 f"a Spectrum, got {_shown(self.spectrum)}")
        mas = _real(self.mas, "[source] mas (mAs)", positive=True, optional=True)
        object.__setattr__(self, "mas", mas)
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
        Integers (Python or NumPy); a float, even ``256.0``, is refused.
    pitch : (float, float)
        Distance in mm between neighbouring rays along HO and VE. ``|HO| = (W - 1) * pitch[0]``.
        Between 1e-6 and 1e6 mm (:data:`PITCH_RANGE`: the fast engine's fixed-point grid snaps
        projected positions to ``2**-22`` of a pitch and spans ``2**35`` pitches, +-34 m at
        the smallest pitch, and places rays to 0.12 mm at the largest), and at
        least ``2**-30`` of the largest coordinate of ``center`` (:data:`PITCH_MIN_RELATIVE`:
        finer than that float64 cannot place the rays).
    response : {"energy", "counting", "kerma"}
        Energy-integrating (signal ~ sum fluence * E * transmission), photon counting, or air
        kerma (``fluence * E * (mu_en/rho)_air``, an ideal dosemeter).
    i0 : float
        Unattenuated photons per pixel (at the detector centre; with ``offset`` or ``u``/``v``,
        of a pixel at ``center`` facing the source). With noise off the image is just
        ``i0 * I / I0``; with noise on it sets the photon statistics.
    noise : bool
        Poisson noise.
    seed : int or None
        Seed of the noise (None: fresh randomness each render).
    falloff : bool
        Inverse-square and obliquity fall-off (``cos^3``) of a point source (on a tilted
        detector, the obliquity to its normal: :func:`~xray_viz.physics.imaging.falloff_factor`).
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
    offset : (float, float)
        ``[du, dv]`` mm (TOML ``offset``): the middle of the pixel grid sits at
        ``center + du * u + dv * v``, displaced within the detector plane; the beam axis (the
        principal ray) stays ``source -> center``. Default ``[0, 0]``.
    u, v : (3,) float or None
        A tilted detector's own axes (TOML ``u = [..]``, ``v = [..]``, both or neither): ``u``
        along the image rows (left to right, seen from the source), ``v`` up the columns. They
        are normalised and ``v`` is made exactly perpendicular to ``u`` (they must be
        perpendicular to 1e-9 already); ``up`` is then ``v`` (a scene file gives ``up`` or
        ``u``/``v``, not both). The detector plane passes through ``center`` with normal
        ``v x u`` (pointing away from the source, as ``unit(VE) x unit(HO)`` does); the
        source must face it, not along it (checked by
        :class:`~xray_viz.geometry.Acquisition`). None (the default): the thesis' untilted
        detector, ``u = unit(HO)``, ``v = unit(VE)``, across the beam.
    grid : Grid, dict or None
        An anti-scatter grid in front of the detector (:class:`~xray_viz.physics.grid.Grid`;
        a table of its keys, TOML ``grid = { ratio = 10, frequency = 60 }``, is validated into
        one); its strips run along ``v``. None (the default): no grid.

    The thesis' ``HO``, ``VE`` and ``FL`` (:func:`xray_viz.geometry.viewport`) name the
    untilted, unshifted detector; a tilted or offset detector's rays go from the source to its
    own pixel points (:attr:`xray_viz.geometry.DetectorFrame.middle`, ``u``, ``v``). A scene
    without ``offset``, ``u`` and ``v`` is exactly the untilted scene (the same images, bit
    for bit).

    Numbers must be numbers and flags bools: ``pitch=True``, ``i0="1e4"`` or ``noise="no"``
    are refused, not converted. See :mod:`xray_viz.physics` for what these model and what they
    do not.

    Raises
    ------
    SceneError
        On a value of the wrong type or out of range.
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
    offset: tuple[float, float] = (0.0, 0.0)
    u: np.ndarray | None = None
    v: np.ndarray | None = None
    grid: object = None

    def __post_init__(self):
        object.__setattr__(self, "center", _vec3(self.center, name="[detector] center"))
        object.__setattr__(self, "up", _vec3(self.up, name="[detector] up", position=False))
        self._check_tilt()
        shape = _shape(self.shape)
        pitch = _numbers(self.pitch, "[detector] pitch (mm)", 2)
        if not np.all(pitch > 0):
            raise SceneError(f"[detector] pitch must be > 0 mm, got {pitch.tolist()}")
        pitch = check_pitch(pitch, self.center)
        if not np.any(self.up):
            raise SceneError("[detector] up must be a non-zero vector")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "pitch", pitch)
        if not isinstance(self.response, str) or self.response not in DETECTOR_RESPONSES:
            raise SceneError(f"[detector] response must be 'energy', 'counting' or 'kerma', "
                             f"got {_shown(self.response)}")
        i0 = _real(self.i0, "[detector] I0 (photons per pixel)")
        if not i0 > 0:
            raise SceneError(f"[detector] I0 must be > 0 photons per pixel, got {i0:g}")
        noise = _flag(self.noise, "[detector] noise")
        if not _is_integer(self.supersample) or self.supersample < 1:
            raise SceneError(f"[detector] supersample must be an integer >= 1, "
                             f"got {_shown(self.supersample)}")
        focal_spot = _real(self.focal_spot, "[detector] focal_spot (mm)")
        if not focal_spot >= 0:
            raise SceneError(f"[detector] focal_spot must be >= 0 mm, got {focal_spot:g}")
        if self.seed is not None and (not _is_integer(self.seed) or self.seed < 0):
            raise SceneError(f"[detector] seed must be an integer >= 0, got {_shown(self.seed)}")
        object.__setattr__(self, "i0", i0)
        object.__setattr__(self, "supersample", int(self.supersample))
        object.__setattr__(self, "focal_spot", focal_spot)
        object.__setattr__(self, "seed", None if self.seed is None else int(self.seed))
        object.__setattr__(self, "noise", noise)
        object.__setattr__(self, "falloff", _flag(self.falloff, "[detector] falloff"))
        self._check_detector_physics()

    def _check_tilt(self):
        """Validate and canonicalise ``offset``, ``u`` and ``v`` (see the class docstring)."""
        offset = _numbers(self.offset, "[detector] offset (mm)", 2)
        if float(np.max(np.abs(offset))) > COORDINATE_LIMIT:
            raise SceneError(f"[detector] offset {offset.tolist()} mm is beyond "
                             f"{COORDINATE_LIMIT:g} mm (1000 km); check the units (mm)")
        object.__setattr__(self, "offset", tuple(float(x) + 0.0 for x in offset))
        if (self.u is None) != (self.v is None):
            given, missing = ("u", "v") if self.v is None else ("v", "u")
            raise SceneError(f"[detector] gives '{given}' without '{missing}': a tilted "
                             "detector needs both of its axes, u (along the rows) and v (up "
                             "the columns), or neither")
        if self.u is None:
            return
        axes = []
        for key in ("u", "v"):
            a = _vec3(getattr(self, key), name=f"[detector] {key}", position=False)
            if not np.any(a):
                raise SceneError(f"[detector] {key} must be a non-zero vector, got {a.tolist()}")
            axes.append(a / np.linalg.norm(a))
        u, v = axes
        dot = float(u @ v)
        if not abs(dot) <= 1e-9:
            raise SceneError(f"[detector] u {np.asarray(self.u).tolist()} and v "
                             f"{np.asarray(self.v).tolist()} must be perpendicular (u . v = "
                             f"{dot:.3g} after normalising): give the detector's own row and "
                             "column directions")
        v = v - dot * u
        v = v / np.linalg.norm(v)
        for key, a in (("u", u), ("v", v), ("up", v)):
            a = a + 0.0
            a.setflags(write=False)
            object.__setattr__(self, key, a)

    @property
    def tilted(self) -> bool:
        """The detector has its own axes ``u``, ``v`` (not necessarily at an angle)."""
        return self.u is not None

    @property
    def shifted(self) -> bool:
        """The detector has a non-zero ``offset``."""
        return self.offset != (0.0, 0.0)

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
            if self.grid is not None:
                from xray_viz.physics.grid import Grid

                object.__setattr__(self, "grid", Grid.of(self.grid))
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

        ``options`` are the other fields (``response``, ``i0``, ``noise``, ...). The pitch,
        ``size / (shape - 1)``, must meet the limits of :class:`Detector`.
        """
        shape = _shape(shape)
        size = _numbers(size, "[detector] size (mm)", 2)
        if np.any(size <= 0):
            raise SceneError(f"[detector] size must be > 0 mm, got {size.tolist()}")
        pitch = tuple(float(s / max(n - 1, 1)) for s, n in zip(size, shape))
        return cls(center=center, up=up, shape=shape, pitch=pitch, **options)


def _shape(value) -> tuple[int, int]:
    """``(W, H)`` from an integer or two integers (Python or NumPy), or SceneError."""
    if isinstance(value, np.ndarray):
        items = value.reshape(-1).tolist() if value.dtype.kind in "iu" else None
    elif isinstance(value, (list, tuple)):
        items = list(value)
    else:
        items = [value]
    if items is None or len(items) not in (1, 2) or not all(_is_integer(s) for s in items):
        raise SceneError(f"[detector] shape must be two integers [W, H] (pixels), got "
                         f"{_shown(value)}" + (" (a float: write it without the decimal point)"
                                         if items and any(isinstance(s, (float, np.floating))
                                                          for s in items) else ""))
    shape = tuple(int(s) for s in np.broadcast_to(np.array(items, dtype=object), (2,)))
    if any(s < 1 for s in shape):
        raise SceneError(f"[detector] shape must be >= 1 pixel each way, got {list(shape)}")
    return shape


def _check_body_values(where: str, mu, material, density):
    """The value rules of a body's material keys, shared by :class:`Body` and the scene-file
    reader (one validation path): ``(mu, density)`` as floats.

    Raises
    ------
    SceneError
        Neither or both of ``mu`` and ``material``, ``mu < 0``, ``density <= 0``, a density
        with ``mu``, a material that is neither a string nor a mapping.
    MaterialError
        An unknown material, a bad mixture, or a formula without a density.
    """
    if mu is None and material is None:
        raise SceneError(f"{where}needs 'mu' (linear attenuation coefficient, 1/cm) or "
                         "'material'")
    if mu is not None and material is not None:
        raise SceneError(f"{where}gives both 'mu' and 'material'; use one")
    mu = _real(mu, f"{where}mu (1/cm)", optional=True)
    if mu is not None and not mu >= 0:
        raise SceneError(f"{where}mu must be >= 0 (1/cm), got {mu:g}")
    density = _real(density, f"{where}density (g/cm3)", optional=True)
    if density is not None and not density > 0:
        raise SceneError(f"{where}density must be > 0 g/cm3, got {density:g}")
    if density is not None and mu is not None:
        raise SceneError(f"{where}gives 'density' with 'mu'; density goes with 'material'")
    if material is not None:
        from collections.abc import Mapping

        from xray_viz.errors import MaterialError
        from xray_viz.physics.materials import check_material

        if not isinstance(material, (str, Mapping)):
            raise SceneError(f"{where}material must be a name or formula string, or a mapping "
                             f"of mass fractions such as {{ H2O = 0.9, NaCl = 0.1 }}; got "
                             f"{_shown(material)}")
        try:
            check_material(material, density=density)
        except MaterialError as exc:
            raise MaterialError(f"{where}{exc}") from None
    return mu, density


@dataclass(frozen=True, eq=False)
class Body:
    """A closed triangle mesh filled with one material.

    Parameters
    ----------
    name : str
        Unique name of the body: not empty, no control characters (it appears in one-line
        messages).
    mesh : trimesh.Trimesh or pyvista.DataSet
        Closed, outward-oriented surface, in scene coordinates (mm), transforms applied. A
        pyvista dataset is replaced by its extracted, triangulated surface (a Trimesh).
        Between 1 pm and 1000 km across (:data:`BODY_SIZE_RANGE`) and at least ``2**-30`` of
        its distance from the origin (:data:`BODY_MIN_RELATIVE`), so that float64 holds it.
    mu : float or None
        Linear attenuation coefficient in 1/cm (energy independent: any photon energy).
    material : str, dict or None
        A NIST compound name, chemical formula or element, or a dict of mass fractions (see
        :mod:`xray_viz.physics.materials`); used instead of ``mu``. Its attenuation is
        tabulated from 0.1 to 800 keV (:data:`~xray_viz.physics.materials.ENERGY_RANGE`).
    density : float or None
        Density in g/cm^3 for ``material``.
    source_file : Path or None
        File the mesh was read from, for messages and :meth:`Scene.to_dict`.
    placement : dict or None
        How ``source_file``'s mesh was placed in the scene: the ``[[body]]`` keys
        ``position``, ``rotation``, ``scale``, ``units`` and ``repair`` as read from a scene
        file (None or ``{}``: the file's mesh as it is). :meth:`Scene.to_dict` writes them back.

    Raises
    ------
    SceneError
        A bad name, ``mu``, density or mesh size; both or neither of ``mu`` and ``material``.
    MaterialError
        An unknown material, a bad mixture, or a formula without a density.
    """

    name: str
    mesh: Any
    mu: float | None = None
    material: str | None = None
    density: float | None = None
    source_file: Path | None = None
    placement: dict | None = None
    shape: dict | None = None           # a primitive's table (xray_viz.meshes.primitives)

    def __post_init__(self):
        from xray_viz.meshes.io import as_trimesh

        object.__setattr__(self, "mesh", as_trimesh(self.mesh))  # pyvista: its surface
        check_name(self.name)
        where = f"body {self.name!r}: "
        mu, density = _check_body_values(where, self.mu, self.material, self.density)
        object.__setattr__(self, "mu", mu)
        object.__setattr__(self, "density", density)
        if not (hasattr(self.mesh, "vertices") and hasattr(self.mesh, "faces")):
            raise SceneError(f"{where}mesh must be a triangle mesh (trimesh.Trimesh), got "
                             f"{type(self.mesh).__name__}")
        vertices = np.asarray(self.mesh.vertices)
        if vertices.dtype.kind in "iuf" and np.all(np.isfinite(vertices)):
            check_body_size(vertices, where=where)   # non-finite: the mesh check's message

    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float vertex positions in mm."""
        return np.asarray(self.mesh.vertices, dtype=np.float64)

    @property
    def faces(self) -> np.ndarray:
        """(m, 3) int vertex indices of each triangle, counter-clockwise seen from outside."""
        return np.asarray(self.mesh.faces, dtype=np.int64)


#: Longest body name (characters): names appear in one-line messages and file metadata.
NAME_MAX = 256


def check_name(name) -> str:
    """A body name: a non-empty string of at most :data:`NAME_MAX` characters without control
    characters (it appears in one-line messages and file metadata), or SceneError."""
    import unicodedata

    if not isinstance(name, str) or not name.strip():
        raise SceneError(f"a body name must be a non-empty string, got {_shown(name)}")
    if any(unicodedata.category(c) in ("Cc", "Zl", "Zp") for c in name):
        raise SceneError(f"body name {_shown(name)} has a control character; use printable text")
    if len(name) > NAME_MAX:
        raise SceneError(f"body name {_shown(name)} is longer than {NAME_MAX} characters")
    return name


@dataclass(frozen=True, eq=False)
class Scene:
    """What is imaged and how: an :class:`~xray_viz.geometry.Acquisition` (a source and a
    detector) and :class:`~xray_viz.bodies.Bodies`.

    Build one with :func:`~xray_viz.scene_file.load_scene` (a TOML file or a bundled phantom
    name) or directly from a source, a detector and bodies. Bodies given as a sequence of
    :class:`Body` are checked
    (and repaired with a warning when needed) once, into a :class:`~xray_viz.bodies.Bodies`
    that keeps everything derived from the meshes; :meth:`replace` with another source or
    detector (``scene.replace(source=...)``, ``scene.replace(acquisition=...)``) keeps the same
    bodies, so none of that is paid again.

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> moved = scene.replace(source=dataclasses.replace(scene.source, position=[0, 0, 800]))
    >>> moved.bodies is scene.bodies
    True
    """

    source: Source
    detector: Detector
    bodies: tuple[Body, ...] = ()
    path: Path | None = None
    #: The scene file's ``[scan]`` orbit (:class:`xray_viz.orbit.Orbit`), if it has one.
    orbit: object = None
    #: The medium around the bodies, ``{"material": ..., "density": ...}`` (the scene file's
    #: ``[world]`` table; the photon transport, :func:`xray_viz.transport`); None: vacuum.
    world: dict | None = None
    #: Volumes traced as voxels (:class:`xray_viz.volume.VoxelVolume`: a ``[[ct]]`` or
    #: ``[[labels]]`` with ``trace = "voxels"``); the meshes in them replace their material.
    volumes: tuple = ()

    def __post_init__(self):
        from xray_viz.bodies import Bodies
        from xray_viz.geometry import Acquisition

        try:
            acquisition = Acquisition(source=self.source, detector=self.detector)
        except SceneError as exc:
            raise SceneError(f"{self._where()}{exc}") from None
        object.__setattr__(self, "acquisition", acquisition)
        if self.world is not None:
            object.__setattr__(self, "world", _check_world(self.world, self._where()))
        if not isinstance(self.bodies, Bodies):
            object.__setattr__(self, "bodies", Bodies(self.bodies, where=self._where()))
        self.bodies.check_source_outside(acquisition, where=self._where())
        if self.volumes:
            _check_volumes(self)
        from xray_viz.physics.heel import check_heel

        check_heel(acquisition)

    def _where(self) -> str:
        return f"{self.path}: " if self.path else ""

    def replace(self, **changes) -> "Scene":
        """Return a copy with fields replaced (``source=``, ``detector=``, ``acquisition=``,
        ``bodies=``, ``path=``).

        Bodies given as a sequence whose meshes are the very mesh objects of this scene's
        bodies (say, another material) share what was derived from the meshes
        (:meth:`xray_viz.bodies.Bodies.like`).
        """
        acquisition = changes.pop("acquisition", None)
        if acquisition is not None:
            if "source" in changes or "detector" in changes:
                raise TypeError("Scene.replace: give acquisition= or source=/detector=, not both")
            changes["source"], changes["detector"] = acquisition.source, acquisition.detector
        if "bodies" in changes:
            from xray_viz.bodies import Bodies

            changes["bodies"] = Bodies.like(changes["bodies"], self.bodies, where=self._where())
        return dataclasses.replace(self, **changes)

    def transform_bodies(self, matrix) -> "Scene":
        """Return a copy with every body moved by the same affine transform.

        An invertible map that keeps orientation (determinant > 0) keeps every body closed and
        outward and keeps which body lies inside which, so the mesh checks and the bodies'
        :attr:`precedence` carry over instead of being recomputed
        (:meth:`xray_viz.bodies.Bodies.transform`). To image the same bodies from another
        direction, turn the acquisition instead (``scene.replace(acquisition=
        scene.acquisition.rotated(...))``): that keeps every per-mesh set-up.

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
        from xray_viz.scene_file import _compose_placement

        def placed(body, m):
            if body.source_file is None and body.shape is None:
                return {}
            placement = _compose_placement(body.placement, m)
            # a shear has no scene-file keys: the mesh is no longer its file's (or shape's)
            return {"placement": placement} if placement is not None else \
                {"placement": None, "source_file": None, "shape": None}
        return dataclasses.replace(self, bodies=self.bodies.transform(matrix, changes=placed))

    @property
    def body_names(self) -> list[str]:
        """The bodies' names, in order."""
        return self.bodies.names

    def to_dict(self, *, base: str | Path | None = None) -> dict:
        """The scene as a scene-file document (what
        :func:`~xray_viz.scene_file.scene_from_dict` reads).

        Every key is written explicitly (defaults too). Each body refers to the mesh file it
        was read from (:attr:`Body.source_file`) with the keys that placed it
        (:attr:`Body.placement`), so the document loads into the same meshes, bit for bit,
        wherever it is saved; bodies moved by :meth:`transform_bodies` carry the composed
        placement (the same meshes to rounding).

        Parameters
        ----------
        base : path-like, optional
            Folder the document will be saved in: mesh and table paths are written relative
            to it. Default: absolute paths.

        Returns
        -------
        dict

        Raises
        ------
        SceneError
            A body built in Python without a mesh file, a spectrum given as a ``Spectrum``
            object, or a body moved by a transform that is not a rotation and scaling.

        Examples
        --------
        >>> import xray_viz
        >>> doc = xray_viz.load_scene("sphere").to_dict()
        >>> sorted(doc), doc["detector"]["shape"], doc["body"][0]["name"]
        (['body', 'detector', 'source'], [256, 256], 'ball')
        """
        from xray_viz.scene_file import _scene_document

        return _scene_document(self, base=None if base is None else Path(base))

    def to_toml(self, path: str | Path | None = None, *, base: str | Path | None = None) -> str:
        """The scene as the text of a scene file (:meth:`to_dict` written by tomlkit).

        Parameters
        ----------
        path : path-like, optional
            Also write the text to this file (through a temporary file beside it, renamed into
            place: never half-written), with mesh and table paths relative to its folder, so
            that the file and its meshes can be moved together.
        base : path-like, optional
            Folder the paths are written relative to (default: ``path``'s folder with a
            ``path``, else absolute paths: the text then loads from anywhere on this machine,
            as the scene embedded in an image's metadata must).

        Returns
        -------
        str

        Examples
        --------
        >>> import xray_viz
        >>> scene = xray_viz.load_scene("nested_spheres")
        >>> import tomllib
        >>> from xray_viz.scene_file import scene_from_dict
        >>> again = scene_from_dict(tomllib.loads(scene.to_toml()))
        >>> bool((xray_viz.render(again).intensity == xray_viz.render(scene).intensity).all())
        True
        """
        from xray_viz._toml import dumps

        if path is None:
            return dumps(self.to_dict(base=base))
        import os
        import tempfile

        path = Path(path)
        folder = path.parent if str(path.parent) else Path(".")
        text = dumps(self.to_dict(base=folder if base is None else base))
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        return text

    @property
    def triangles(self) -> np.ndarray:
        """(T, 3, 3) float: every triangle of every body, bodies in order
        (:attr:`xray_viz.bodies.Bodies.triangles`)."""
        return self.bodies.triangles

    @property
    def triangle_body(self) -> np.ndarray:
        """(T,) int: index of the body each triangle of :attr:`triangles` belongs to."""
        return self.bodies.triangle_body

    @property
    def triangle_offset(self) -> np.ndarray:
        """(n_bodies + 1,) int: body k owns triangles ``triangle_offset[k]:triangle_offset[k+1]``."""
        return self.bodies.triangle_offset

    @property
    def precedence(self) -> np.ndarray:
        """(n_bodies,) int rank: where bodies overlap, the highest rank gives the material.

        Innermost wins (a body inside another replaces its material), and where bodies only
        partly overlap the later-listed one wins. See :func:`xray_viz.attenuation.body_precedence`.
        """
        return self.bodies.precedence


def _check_world(world, where: str = "") -> dict:
    """The ``[world]`` medium: ``{"material": ..., "density": ...}`` checked (density from
    the material when it has one)."""
    from collections.abc import Mapping

    from xray_viz.errors import MaterialError
    from xray_viz.physics.materials import check_material

    if not isinstance(world, Mapping) or "material" not in world \
            or set(world) - {"material", "density"}:
        raise SceneError(f"{where}[world] takes 'material' (and 'density' in g/cm3), e.g. "
                         f"material = \"Air, Dry (near sea level)\"; got {_shown(world)}")
    material, density = world["material"], world.get("density")
    if not isinstance(material, (str, Mapping)):
        raise SceneError(f"{where}[world] material must be a name or a table of mass "
                         f"fractions, got {_shown(material)}")
    density = _real(density, "[world] density (g/cm3)", optional=True)
    try:
        density = check_material(material, density=density)
    except MaterialError as exc:
        raise MaterialError(f"{where}[world] {exc}") from None
    return {"material": material, "density": density}


def _check_volumes(scene) -> None:
    """Volumes are :class:`~xray_viz.volume.VoxelVolume`; every name (bodies, classes) unique;
    a mesh reaching out of a volume's box warned about once."""
    from xray_viz.volume import VoxelVolume, displacers

    volumes = tuple(scene.volumes)
    bad = [type(v).__name__ for v in volumes if not isinstance(v, VoxelVolume)]
    if bad:
        raise SceneError(f"{scene._where()}volumes must be VoxelVolume (xray_viz.volume), got "
                         f"{bad[0]}")
    object.__setattr__(scene, "volumes", volumes)
    names = list(scene.bodies.names) + [n for v in volumes for n in v.names]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SceneError(f"{scene._where()}body and volume class names must be unique, "
                         f"repeated: {dup}")
    for v in volumes:
        displacers(v, scene.bodies)


#: The names that moved to :mod:`xray_viz.scene_file` (reading and writing scene files), still
#: importable from here (``from xray_viz.scene import load_scene``); documented there.
_FILE_NAMES = frozenset({"load_scene", "scene_from_dict", "body_transform", "SOURCE_KEYS",
                         "DETECTOR_KEYS", "BODY_KEYS"})


def __getattr__(name):
    """The reader's names re-exported, imported on first use (:mod:`xray_viz.scene_file`
    imports this module, not the other way round at module level)."""
    if name in _FILE_NAMES:
        from xray_viz import scene_file

        return getattr(scene_file, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
