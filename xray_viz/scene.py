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
from pathlib import Path
from typing import Any

import numpy as np

from xray_viz._toml import plain as _plain
from xray_viz.errors import SceneError, SceneFileNotFoundError, XrayVizError
from xray_viz.physics.spectra import DEFAULT_ENERGY

__all__ = ["Source", "Detector", "Body", "Scene", "load_scene", "scene_from_dict"]

#: Values of ``[detector] response``.
DETECTOR_RESPONSES = ("energy", "counting", "kerma")

#: Length units accepted by a body's ``units`` key, in millimetres.
LENGTH_UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3, "in": 25.4}

#: Largest coordinate (mm) of a source, a detector centre or a body's vertex: 1000 km. Rays
#: from that far keep their path lengths to 1e-7 mm (float64 rounds a distance d to 1e-16 d);
#: squared distances overflow float64 only beyond 1e154 mm.
COORDINATE_LIMIT = 1e9

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


def _shown(value) -> str:
    """A user's value quoted for a one-line message: short, escaped (see
    :func:`xray_viz.errors.excerpt`)."""
    from xray_viz.errors import excerpt

    if isinstance(value, (str, bytes)):
        return excerpt(value)
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 80 else f"{text[:80]}... ({len(text)} characters)"


def _is_number(value) -> bool:
    """A real number (Python or NumPy int or float), not a bool, string or complex."""
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, (bool, np.bool_)))


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
    ordinary float64 number."""
    if isinstance(value, (list, tuple)):
        ok = len(value) == 3 and all(_is_number(v) for v in value)
    else:
        ok = isinstance(value, np.ndarray) and value.dtype.kind in "iuf" and value.size == 3
    if not ok:
        raise SceneError(f"{name} must be 3 numbers (x, y, z in mm), got {_shown(value)}")
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(3)
    except OverflowError:                      # a Python int beyond float64
        arr = np.full(3, math.inf)
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{name} must be finite, got {np.asarray(value).tolist()}")
    big = float(np.max(np.abs(arr)))
    if position and big > COORDINATE_LIMIT:
        raise SceneError(f"{name} {arr.tolist()} is {big:g} mm from the origin: coordinates must "
                         f"be within {COORDINATE_LIMIT:g} mm (1000 km), where float64 still keeps "
                         f"path lengths to 1e-7 mm; check the units (mm)")
    if not position and big > 0 and not 1e-150 < big < 1e150:
        raise SceneError(f"{name} {arr.tolist()} has no usable length: give a direction of "
                         f"ordinary size, such as [0, 1, 0]")
    arr = arr + 0.0                            # -0.0 -> 0.0, and a copy the caller cannot change
    arr.setflags(write=False)
    return arr


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

    Build one with :func:`load_scene` (a TOML file or a bundled phantom name) or directly from
    a source, a detector and bodies. Bodies given as a sequence of :class:`Body` are checked
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

        check_heel(self)

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
        def placed(body, m):
            if body.source_file is None and getattr(body, "shape", None) is None:
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
        """The scene as a scene-file document (what :func:`scene_from_dict` reads).

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


def _path_text(path, base: Path | None) -> str:
    import os

    path = Path(path).resolve()
    if base is None:
        return str(path)
    try:
        return Path(os.path.relpath(path, Path(base).resolve())).as_posix()
    except ValueError:         # another drive: no relative path
        return str(path)


def _with_paths(table: dict, base: Path | None) -> dict:
    """A canonical table (spectrum, mtf) with its file paths written for ``base``."""
    return {k: (_path_text(v, base) if k in ("file", "lsf") and isinstance(v, (str, Path))
                else _plain(v)) for k, v in table.items()}


def _scene_document(scene: "Scene", *, base: Path | None) -> dict:
    src, det = scene.source, scene.detector
    source = {"position": src.position.tolist(), "kind": src.kind}
    if src.spectrum is not None:
        from collections.abc import Mapping

        if not isinstance(src.spectrum, Mapping):
            raise SceneError("[source] spectrum is a Spectrum object built in Python: a scene "
                             "file needs it as a table (such as { kvp = 80.0 }) or a CSV file "
                             "({ file = \"spectrum.csv\" })")
        source["spectrum"] = _with_paths(dict(src.spectrum), base)
    else:
        source["energy"] = src.energy
    if src.mas is not None:
        source["mas"] = src.mas
    source["heel"] = src.heel
    detector = {"center": det.center.tolist()}
    if det.tilted:
        detector.update(u=det.u.tolist(), v=det.v.tolist())
    else:
        detector["up"] = det.up.tolist()
    if det.shifted:
        detector["offset"] = list(det.offset)
    detector.update(shape=list(det.shape), pitch=list(det.pitch), response=det.response)
    if src.mas is None:
        detector["I0"] = det.i0
    detector.update(noise=det.noise, falloff=det.falloff, supersample=det.supersample,
                    focal_spot=det.focal_spot)
    if det.seed is not None:
        detector["seed"] = det.seed
    if det.scintillator is not None:
        detector["scintillator"] = _plain(dict(det.scintillator))
    if det.mtf is not None:
        detector["mtf"] = _with_paths(dict(det.mtf), base)
    detector.update(electronic_noise=det.electronic_noise, gain=det.gain)
    bodies = []
    for body in scene.bodies:
        if body.shape is not None:                           # a primitive: its table
            entry = {"name": body.name, "shape": _plain(dict(body.shape))}
        else:
            if body.source_file is None:
                raise SceneError(f"body {body.name!r} has no mesh file (its mesh was built in "
                                 "Python): export it (body.mesh.export('NAME.ply')) and give the "
                                 "Body source_file= that file, to write the scene")
            from xray_viz.meshes.io import MESH_SUFFIXES, split_node

            mesh_file = str(split_node(body.source_file)[0])      # model.glb#NODE: the file
            if not mesh_file.lower().endswith(MESH_SUFFIXES):
                raise SceneError(f"body {body.name!r} was made from {Path(mesh_file).name}, not "
                                 "a mesh file: write its meshes with `xray-viz mesh FILE -o "
                                 "FOLDER` and refer to them, to write the scene")
            entry = {"name": body.name, "mesh": _path_text(body.source_file, base)}
        if body.mu is not None:
            entry["mu"] = body.mu
        else:
            entry["material"] = _plain(body.material)
            if body.density is not None:
                entry["density"] = body.density
        entry.update(_plain(dict(body.placement or {})))
        bodies.append(entry)
    doc = {"source": source, "detector": detector}
    if bodies:
        doc["body"] = bodies
    if getattr(scene, "world", None) is not None:       # the transport's medium
        doc["world"] = {"material": scene.world["material"],
                        "density": float(scene.world["density"])}
    for vol in getattr(scene, "volumes", ()):       # voxel volumes: their [[ct]] / [[labels]]
        if vol.table is None or vol.source_file is None:
            raise SceneError(f"voxel volume {vol.name!r} was built in Python, not read from a "
                             "[[ct]] or [[labels]] table: save it as NIfTI and refer to it, to "
                             "write the scene")
        kind, table = vol.table
        entry = _plain(dict(table))
        entry.update(file=_path_text(vol.source_file, base), trace="voxels")
        doc.setdefault(kind, []).append(entry)
    return doc


def _compose_placement(placement, matrix):
    """The placement keys of a body's file mesh moved by ``matrix`` as well: a rotation matrix,
    a scale per axis and a position; None when ``matrix`` shears the mesh (no such keys)."""
    p = dict(placement or {})
    rotation = p.get("rotation")
    if rotation is not None:
        rotation = np.asarray(rotation, dtype=np.float64)
    m = np.asarray(matrix, dtype=np.float64) @ body_transform(
        position=p.get("position"), rotation=rotation, scale=p.get("scale"),
        units=p.get("units", "mm"))
    scale = np.linalg.norm(m[:3, :3], axis=0)
    r = m[:3, :3] / scale
    if not (np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
        return None
    out = {"position": m[:3, 3].tolist(), "rotation": r.tolist(), "scale": scale.tolist()}
    if "repair" in p:
        out["repair"] = p["repair"]
    return out


# --------------------------------------------------------------------------------------------
# TOML parsing and validation

#: Every key each table of a scene file accepts (an unknown key is an error that lists these).
SOURCE_KEYS = ("position", "kind", "energy", "spectrum", "mas", "heel")
DETECTOR_KEYS = ("center", "up", "shape", "pitch", "size", "response", "I0", "noise", "seed",
                 "falloff", "supersample", "focal_spot", "scintillator", "mtf",
                 "electronic_noise", "gain", "offset", "u", "v")
BODY_KEYS = ("name", "mesh", "shape", "mu", "material", "density", "position", "rotation",
             "scale", "units", "repair")


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
            self.fail(f"{key} must be a number, got {_shown(value)}")
        try:
            value = float(value)
        except OverflowError:                  # an integer beyond float64
            value = math.inf
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
            self.fail(f"{key} must be a string, got {_shown(value)}")
        if choices is not None and value not in choices:
            self.fail(f"{key} must be one of {', '.join(map(repr, choices))}; got {_shown(value)}")
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
            self.fail(f"{key} must be a list of {n} {kind}, got {_shown(value)}")
        if integer and any(abs(v) >= 2**63 for v in value):
            self.fail(f"{key} must be integers below 2**63, got {_shown(value)}")
        try:
            arr = np.asarray(value, dtype=np.int64 if integer else np.float64)
        except OverflowError:                  # an integer beyond float64
            self.fail(f"{key} must be finite, got {_shown(value)}")
        if not np.all(np.isfinite(arr)):
            self.fail(f"{key} must be finite, got {_shown(value)}")
        if positive and np.any(arr <= 0):
            self.fail(f"{key} must be > 0, got {_shown(value)}")
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

    Raises
    ------
    SceneError
        Unknown ``units``, a ``scale`` that is not one or three numbers > 0, a ``position``
        that is not three finite numbers, or a ``rotation`` that is neither three finite
        angles nor a 3 x 3 rotation matrix.

    Examples
    --------
    >>> body_transform(position=[1, 2, 3])[:3, 3].tolist()
    [1.0, 2.0, 3.0]
    """
    if not isinstance(units, str) or units not in LENGTH_UNITS:
        raise SceneError(f"units must be one of {', '.join(map(repr, LENGTH_UNITS))}; "
                         f"got {units!r}")
    m = np.eye(4)
    s = np.ones(3) * LENGTH_UNITS[units]
    if scale is not None:
        factor = _numbers(scale, "scale", 3)
        if not np.all(factor > 0):
            raise SceneError(f"scale must be > 0 (a negative one would mirror the mesh "
                             f"inside out), got {np.asarray(scale).tolist()}")
        s = s * factor
    if rotation is None:
        r = np.eye(3)
    else:
        rot = np.asarray(rotation)
        if rot.shape == (3, 3) and rot.dtype.kind in "iuf" and np.all(np.isfinite(rot)):
            r = _rotation_matrix(rot)
        else:
            r = _rotation_matrix(_numbers(rotation, "rotation (degrees)", 3)
                                 if rot.shape == (3,) else
                                 _numbers(rotation, "rotation (3 angles or a 3 x 3 matrix)", 3))
    m[:3, :3] = r @ np.diag(s)
    if position is not None:
        m[:3, 3] = _vec3(position, name="position")
    return m


def _transform_cause(scale, units, position) -> str:
    """What made a body its size in the scene, for messages: ``"scale 1e-200"``, ..."""
    parts = []
    if scale is not None:
        sc = np.asarray(scale, dtype=np.float64)
        parts.append(f"scale {sc[0]:g}" if np.all(sc == sc[0]) else f"scale {sc.tolist()}")
    if units != "mm":
        parts.append(f"units {units!r}")
    if position is not None:
        parts.append(f"position {np.asarray(position, dtype=np.float64).tolist()}")
    return " with ".join(parts) if parts else "the mesh file's coordinates"


def _distinct_rows(v: np.ndarray) -> int:
    """How many distinct rows (vertices) ``v`` has, exactly (``-0.0 == 0.0``)."""
    if len(v) < 2:
        return len(v)
    v = np.ascontiguousarray(v + 0.0)
    order = np.lexsort(v.T[::-1])
    s = v[order]
    return 1 + int(np.count_nonzero(np.any(s[1:] != s[:-1], axis=1)))


def _place_mesh(mesh, transform, *, where: str, cause: str):
    """The mesh moved by ``transform`` (mm), refusing a result float64 cannot hold: a size out of
    :data:`BODY_SIZE_RANGE`, too small for its distance from the origin, or vertices that the
    transform merged. The mesh itself when ``transform`` is the identity."""
    v0 = np.asarray(mesh.vertices, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        v = v0 @ transform[:3, :3].T + transform[:3, 3]
    check_body_size(v, where=where, cause=cause)
    if np.array_equal(v, v0):
        return mesh
    if len(v) and np.ptp(v, axis=0).max() > 0:
        before, after = _distinct_rows(v0), _distinct_rows(v)
        if after < before:
            raise SceneError(f"{where}{cause} merges {before - after} of the mesh's {before} "
                             f"vertices (they round to the same float64 point): the mesh would "
                             f"collapse; use a larger scale or move it nearer the origin")
    m3 = transform[:3, :3]
    gram = m3.T @ m3
    if not np.allclose(gram, gram[0, 0] * np.eye(3), rtol=1e-9, atol=0):
        # a scale of different factors per axis can flatten a good mesh to zero volume
        from xray_viz.meshes.repair import _is_flat

        volume = float(mesh.volume)
        if not _is_flat(v0, volume) and _is_flat(v, volume * float(np.linalg.det(m3))):
            dims = " x ".join(f"{d:.3g}" for d in np.ptp(v, axis=0))
            raise SceneError(f"{where}{cause} flattens the mesh to {dims} mm, zero volume to "
                             f"rounding: scale the axes by similar factors")
    mesh = mesh.copy()
    mesh.apply_transform(transform)
    return mesh


def _boolean(t: _Table, key: str, default: bool = False) -> bool:
    value = t.raw(key, default=default)
    if not isinstance(value, bool):
        t.fail(f"{key} must be true or false, got {_shown(value)}")
    return value


def _integer(t: _Table, key: str, *, minimum: int, default=None):
    value = t.raw(key, default=default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        t.fail(f"{key} must be an integer >= {minimum}, got {_shown(value)}")
    return value


def _parse_body(t: _Table, base_dir: Path, index: int):
    """``(body, report)``: one ``[[body]]`` table's body, its mesh checked (and repaired if
    allowed), and the mesh's :class:`~xray_viz.meshes.repair.MeshReport`."""
    from xray_viz.meshes.io import load_mesh, split_node

    t.expect(BODY_KEYS)
    name = t.string("name", default=f"body{index}")
    try:
        check_name(name)
    except SceneError as exc:
        t.fail(f"name: {exc}")
    label = f"(name {name!r})"
    shape = None
    if t.has("shape"):                   # a primitive instead of a mesh file
        from xray_viz.meshes.primitives import check_shape

        if t.has("mesh"):
            t.fail(f"{label} gives both 'mesh' and 'shape'; use one")
        try:
            shape = check_shape(t.raw("shape"))
        except SceneError as exc:
            t.fail(f"{label} {exc}")
        mesh_name = None
    else:
        mesh_name = t.string("mesh", required=True)
        if not mesh_name.strip():
            t.fail(f"{label} mesh must name a mesh file, got {mesh_name!r}")
    mu = t.number("mu")                                  # types here, values in Body's rules
    material = t.raw("material")
    density = t.number("density")
    from xray_viz.errors import MaterialError

    try:
        mu, density = _check_body_values("", mu, material, density)
    except MaterialError as exc:
        t.fail(f"{label}: {exc}")
    except SceneError as exc:
        t.fail(str(exc))
    position = t.vector("position", 3)
    rotation = None
    if t.has("rotation"):
        raw = t.data["rotation"]
        if isinstance(raw, list) and raw and all(isinstance(r, list) for r in raw):
            t.used.add("rotation")
            ok = len(raw) == 3 and all(len(r) == 3 and all(_is_number(x) for x in r) for r in raw)
            rot = np.asarray(raw, dtype=float) if ok else None
            if rot is None or not np.all(np.isfinite(rot)) \
                    or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
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
    where = f"{t.file}: " if t.file else ""
    if shape is not None:
        from xray_viz.meshes.primitives import shape_mesh

        path = None
        mesh = shape_mesh(shape)
    else:
        path = (base_dir / mesh_name) if not Path(mesh_name).is_absolute() else Path(mesh_name)
        if not Path(mesh_name).is_absolute():    # model.glb#NODE: the node's name kept as is
            mesh_file, node = split_node(path)
            path = mesh_file.resolve() if node is None else Path(f"{mesh_file.resolve()}#{node}")
        try:
            mesh = load_mesh(path)
        except XrayVizError as exc:
            raise type(exc)(f"{where}body {name!r}: {exc}") from None
    try:
        transform = body_transform(position=position, rotation=rotation, scale=scale, units=units)
    except SceneError as exc:
        t.fail(f"{label} {exc}")
    mesh = _place_mesh(mesh, transform, where=f"{where}{t.where} {label} ",
                       cause=_transform_cause(scale if t.has("scale") else None, units, position))
    from xray_viz.meshes.repair import MeshRepairWarning, ensure_traceable

    try:
        mesh, changes, report = ensure_traceable(mesh, name=name, repair=repair,
                                                 return_report=True)
    except XrayVizError as exc:
        raise type(exc)(f"{where}{path.name if path else shape['kind']}: {exc}") from None
    if changes:
        import warnings

        warnings.warn(f"{where}body {name!r} ({path.name if path else shape['kind']}): mesh "
                      f"repaired: {'; '.join(changes)}", MeshRepairWarning, stacklevel=2)
    placement = {k: t.data[k] for k in ("position", "rotation", "scale", "units", "repair")
                 if k in t.data}
    return Body(name=name, mesh=mesh, mu=mu, material=material, density=density,
                source_file=path, placement=placement, shape=shape), report


def _check_material_energies(src: _Table, energy, spectrum, bodies) -> None:
    """Fail when a body of a ``material`` meets photon energies outside the tabulated range of
    the material data (bodies of constant ``mu`` take any energy)."""
    from xray_viz.physics.materials import ENERGY_RANGE

    named = [b for b in bodies if b.material is not None]
    if not named:
        return
    lo, hi = ENERGY_RANGE
    first = named[0]
    who = (f"body {first.name!r} (material {first.material!r})"
           + (f" and {len(named) - 1} more" if len(named) > 1 else ""))
    why = (f"outside {lo:g}-{hi:g} keV, the range of xraylib's attenuation tables that {who} "
           f"needs")
    if spectrum is None:
        e = DEFAULT_ENERGY if energy is None else energy
        if not lo <= e <= hi:
            src.fail(f"energy {e:g} keV is {why}; use an energy in that range, or give such "
                     f"bodies a constant mu (1/cm)")
    elif "file" in spectrum:
        from xray_viz.physics.spectra import read_spectrum_csv

        spec = read_spectrum_csv(spectrum["file"])
        e0, e1 = float(spec.energies[0]), float(spec.energies[-1])
        if e0 < lo or e1 > hi:
            src.fail(f"spectrum file {Path(spectrum['file']).name} spans {e0:g}-{e1:g} keV, "
                     f"{why}; remove its rows outside that range")


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
    top.expect(("source", "detector", "body", "labels", "ct", "scan", "world"))
    world = top.raw("world")                           # the transport's medium; None: vacuum
    src = top.table("source", required=True)
    src.where = "[source]"
    src.expect(SOURCE_KEYS)
    position = src.vector("position", 3, required=True)
    kind = src.string("kind", default="point", choices=("point", "parallel"))
    spectrum = src.raw("spectrum")
    energy = src.number("energy", default=None if spectrum is not None else DEFAULT_ENERGY,
                        positive=True)
    if spectrum is not None and src.has("energy"):
        src.fail("gives both 'energy' and 'spectrum'; use one")
    mas = src.number("mas", positive=True)
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
    if det.has("up") and (det.has("u") or det.has("v")):
        det.fail("gives 'up' and the tilted detector's axes 'u'/'v': use one (with u and v, "
                 "up is v)")
    tilt = {"offset": det.vector("offset", 2, default=(0.0, 0.0)),
            "u": det.vector("u", 3), "v": det.vector("v", 3)}
    shape = det.vector("shape", 2, required=True, integer=True)
    if det.has("pitch") and det.has("size"):
        det.fail("gives both 'pitch' and 'size'; use one")
    if not det.has("pitch") and not det.has("size"):
        det.fail("is missing the required key 'pitch' (mm between rays) or 'size' ([|HO|, |VE|] mm)")
    if det.has("size"):
        size = det.vector("size", 2, positive=True)
        pitch = size / np.maximum(shape - 1, 1)
        what = f"size {size.tolist()} over shape {shape.tolist()} gives a pitch of"
    else:
        pitch = det.scalar_or_vector("pitch", 2, positive=True)
        what = "pitch"
    try:
        check_pitch(pitch, center, what=what)
    except SceneError as exc:
        raise SceneError(f"{det.file}: {exc}" if det.file else str(exc)) from None
    options = {
        "response": det.string("response", default="energy", choices=DETECTOR_RESPONSES),
        "noise": _boolean(det, "noise"),
        "falloff": _boolean(det, "falloff", default=mas is not None),
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
    if options["noise"] and not det.has("I0") and mas is None:
        det.fail("sets noise = true without 'I0': give the unattenuated photons per pixel, "
                 "e.g. I0 = 10000.0, or [source] mas")
    if mas is not None and det.has("I0"):
        det.fail("gives 'I0' and [source] gives 'mas': use one (with mas, I0 follows from the "
                 "tube output)")
    options["i0"] = det.number("I0", default=1.0, positive=True)
    if mas is not None:
        from xray_viz.errors import SpectrumError
        from xray_viz.physics.dosimetry import centre_pixel_photons

        try:
            options["i0"] = centre_pixel_photons(spectrum, mas, kind=kind, source=position,
                                                 center=center, pitch=pitch)
        except SpectrumError as exc:
            src.fail(str(exc))
    det.done()
    # the value rules are the dataclasses' own: a bad value is reported before any mesh loads
    try:
        source = Source(position=position, kind=kind, energy=energy, spectrum=spectrum, mas=mas,
                        heel=heel)
        detector = Detector(center=center, up=up, shape=tuple(shape.tolist()),
                            pitch=tuple(pitch), **options, **tilt)
    except SceneError as exc:
        raise SceneError(f"{file}: {exc}" if file else str(exc)) from None

    orbit = top.raw("scan")
    if orbit is not None:
        from xray_viz.orbit import orbit_from_dict

        orbit = orbit_from_dict(orbit, base_dir=base_dir, file=file)
    raw_bodies = top.raw("body", default=[])
    if not isinstance(raw_bodies, list):
        top.fail("'body' must be an array of tables: write [[body]]")
    volumes = {key: top.raw(key) for key in ("labels", "ct")}
    top.done()
    from xray_viz.meshes.io import expand_nodes

    raw_bodies = expand_nodes(raw_bodies, base_dir, file=file)  # glTF nodes: a body each
    parsed = []
    for k, raw in enumerate(raw_bodies):
        bt = _Table(raw, f"[[body]] #{k + 1}", file)
        parsed.append(_parse_body(bt, base_dir, k))
    if any(v is not None for v in volumes.values()):  # label maps and CTs: bodies after [[body]]
        from xray_viz.meshes.volumes import volume_bodies

        from xray_viz.volume import VoxelVolume

        made = volume_bodies(volumes, base_dir=base_dir, file=file, body=Body)
        voxels = tuple(b for b in made if isinstance(b, VoxelVolume))   # trace = "voxels"
        parsed.extend((b, None) for b in made if not isinstance(b, VoxelVolume))
    else:
        voxels = ()
    bodies = [b for b, _ in parsed]
    _check_material_energies(src, energy, spectrum, bodies)
    from xray_viz.bodies import Bodies

    try:
        bodies = Bodies(bodies, where=f"{file}: " if file else "",
                        reports=[r for _, r in parsed])
        scene = Scene(source=source, detector=detector, bodies=bodies, path=file,
                      orbit=orbit, world=world, volumes=voxels)
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
        A ``.toml`` scene file, or the name of a bundled phantom (see ``xray-viz phantoms``),
        or a mesh file alone (STL, OBJ, PLY, ...: framed with a stated material, see
        :mod:`xray_viz.starter`).
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
        else:                                   # a named pipe would block the read for ever
            from xray_viz._files import require_regular

            require_regular(p, SceneError, "scene file")
    from xray_viz.starter import framed_document, is_mesh_file

    if is_mesh_file(p):              # a mesh alone: framed, with a stated material (logged)
        return scene_from_dict(framed_document(p), base_dir=p.parent, file=p)
    if p.suffix.lower() == ".json":  # a gVirtualXray scene
        from xray_viz.meshes.gvxr import gvxr_to_dict, read_json

        return scene_from_dict(gvxr_to_dict(read_json(p), base_dir=p.parent, file=p),
                               base_dir=p.parent, file=p)
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise SceneError(f"{p}: not a text (UTF-8) TOML file") from None
    except OSError as exc:
        raise SceneError(f"{p}: cannot read: {exc.strerror}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        from xray_viz.meshes.gvxr import not_toml

        raise SceneError(not_toml(p, text) or f"{p}: malformed TOML: {exc}") from None
    except RecursionError:
        raise SceneError(f"{p}: nested too deeply (arrays or tables thousands of levels inside each other): not a scene file") from None
    return scene_from_dict(doc, base_dir=p.parent, file=p)
