"""gVirtualXray (gVXR) JSON scene files: read them as scenes, or convert them to TOML.

gVXR's ``json2gvxr`` module sets up a simulation from a JSON file with a ``Source``, a
``Detector`` and ``Samples``; lengths carry their unit, ``[x, y, z, "mm"]``. This module turns
such a file into the dictionary that :func:`xray_viz.scene_file.scene_from_dict` takes (the TOML
scene format), so that ``xray-viz render scene.json`` renders it and
``xray-viz convert scene.json -o scene.toml`` writes the equivalent scene file.

What maps (gVXR -> xray-viz):

================================================  ==============================================
``Source.Position [x, y, z, unit]``                ``[source] position`` (mm)
``Source.Shape`` PointSource / Cone(Beam)          ``kind = "point"``; Parallel(Beam): ``"parallel"``
``Source.Shape ["FocalSpot", size, unit, n]``      ``[detector] focal_spot`` (mm; gVXR's uniform
                                                   spot taken as a Gaussian of that FWHM: a
                                                   warning says so)
``Source.Beam [{Energy, Unit, PhotonCount}]``      ``energy`` (keV) and ``[detector] I0``: one
                                                   energy only (a line spectrum: error)
``Source.Beam {kvp, tube angle, filter, mAs}``     ``spectrum = { kvp, anode_angle, filters }``,
                                                   ``mas`` (also "Peak kilo voltage", "Tube angle")
``Detector.Position``, ``UpVector``                ``[detector] center``, ``up``
``Detector.NumberOfPixels [W, H]``                 ``shape``
``Detector.Spacing [dx, dy, unit]`` / ``Size``     ``pitch`` (gVXR's pitch is size / pixels)
``Detector.Oversampling n``                        ``supersample``
``Detector.Scintillator {Material, Thickness}``    ``scintillator``
``Samples[].Label``, ``Path``, ``Unit``            ``[[body]] name``, ``mesh``, ``units``/``scale``
``Samples[].Material ["Element", "Fe" or 26]``     ``material = "Fe"`` (density: ``Density``, else
                                                   the element's)
``["Mixture", "Ti90Al6V4"]`` / ``[Z, w, ...]``     a mixture by mass fraction (needs ``Density``)
``["Compound", "H2O"]``                            ``material = "H2O"`` (needs ``Density``)
``["mu", value]``                                  ``mu`` (1/cm)
``["HU", n]``                                      the tissue class of ``round(n)`` and its
                                                   density (:func:`hu_material`); a
                                                   ``Density`` replaces the density
``Samples[].Cube [size, unit]``                    ``shape = { kind = "box" }`` (a cube)
``Cuboid`` / ``Parallelepiped [x, y, z, unit]``    ``shape = { kind = "box", size = [x, y, z] }``
``Cylinder [sectors, height, radius, unit]``       ``shape = { kind = "cylinder" }``, ``sections``
                                                   = sectors, axis along y (gVXR's); the
                                                   rotation that turns the z-axis shape onto y
                                                   comes first in ``rotation``
``Samples[].Transform``                            ``position``, ``rotation``, ``scale`` (the
                                                   transforms composed as gVXR's node matrix,
                                                   ``M = T1 @ T2 @ ...``)
================================================  ==============================================

No equivalent, an error (one line naming the key): a beam of several energies or from a text
file or GATE macro, a ``Step Wedge`` sample, ``MoveToCentre``, a ``SceneGraph``, the detector's
``Energy response`` and ``LSF``, a ``RightVector`` that would mirror the image, and a
``Transform`` that shears. Ignored: ``WindowSize``, ``File format version``, colours,
``Opacity``, ``Type`` (inner/outer: the innermost body wins anyway), the normal-flipping flags
(bodies are oriented outward on load). A ``Scan`` becomes the scene's ``[scan]`` orbit (as gVXR's
``json2gvxr`` scans: see ``_scan``), except one about a ``CenterOfRotation`` off the origin,
ignored with a warning.

Examples
--------
>>> import json, tempfile, pathlib, trimesh
>>> folder = pathlib.Path(tempfile.mkdtemp())
>>> _ = trimesh.creation.icosphere(radius=1.0).export(folder / "ball.stl")
>>> doc = {"Source": {"Position": [0, 0, 100, "cm"], "Shape": "PointSource",
...                   "Beam": [{"Energy": 60, "Unit": "keV", "PhotonCount": 1000}]},
...        "Detector": {"Position": [0, 0, -50, "cm"], "UpVector": [0, 1, 0],
...                     "NumberOfPixels": [64, 48], "Spacing": [0.5, 0.5, "mm"]},
...        "Samples": [{"Label": "ball", "Path": "ball.stl", "Unit": "cm",
...                     "Material": ["Element", "Al"]}]}
>>> scene = gvxr_to_dict(doc, base_dir=folder)
>>> scene["source"]["position"], scene["detector"]["shape"], scene["body"][0]["units"]
([0.0, 0.0, 1000.0], [64, 48], 'cm')
"""

from __future__ import annotations

import json
import math
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from xray_viz.errors import SceneError, SceneFileNotFoundError, excerpt
from xray_viz.poses import rotation

__all__ = ["gvxr_to_dict", "read_json", "not_toml", "to_toml", "GvxrWarning", "LENGTH_UNITS",
           "hu_material", "AIR_HU", "AIR"]

#: gVXR's length units, in mm.
LENGTH_UNITS = {
    "um": 1e-3, "micrometre": 1e-3, "micrometer": 1e-3, "micron": 1e-3,
    "mm": 1.0, "millimetre": 1.0, "millimeter": 1.0,
    "cm": 10.0, "centimetre": 10.0, "centimeter": 10.0,
    "dm": 100.0, "decimetre": 100.0, "decimeter": 100.0,
    "m": 1000.0, "metre": 1000.0, "meter": 1000.0,
    "dam": 1e4, "decametre": 1e4, "decameter": 1e4,
    "hm": 1e5, "hectometre": 1e5, "hectometer": 1e5,
    "km": 1e6, "kilometre": 1e6, "kilometer": 1e6,
}
#: gVXR's energy units, in keV.
ENERGY_UNITS = {"ev": 1e-3, "kev": 1.0, "mev": 1e3}
#: xray-viz's own body units (``[[body]] units``) for the gVXR names that have one.
_BODY_UNITS = {"um": "um", "mm": "mm", "cm": "cm", "m": "m", "micrometre": "um",
               "micrometer": "um", "millimetre": "mm", "millimeter": "mm", "centimetre": "cm",
               "centimeter": "cm", "metre": "m", "meter": "m"}

_TOP_KEYS = ("Source", "Detector", "Samples", "WindowSize", "Window size", "File format version",
             "Scan", "SceneGraph")
_SOURCE_KEYS = ("Position", "Shape", "Beam")
_DETECTOR_KEYS = ("Position", "UpVector", "RightVector", "NumberOfPixels", "Spacing", "Size",
                  "Oversampling", "Scintillator", "Energy response", "LSF")
_SAMPLE_KEYS = ("Label", "Path", "Unit", "Material", "Density", "Transform", "Type", "Opacity",
                "Colour", "Color", "flipNormal", "flipNormals", "flipNormalVectors",
                "invertNormal", "invertNormals", "invertNormalVectors", "Cube", "Cuboid",
                "Parallelepiped", "Cylinder")
_PRIMITIVES = ("Cube", "Cuboid", "Parallelepiped", "Cylinder")
#: Below this Hounsfield value a ``["HU", n]`` sample is air (the lowest class of the CT
#: tables, :data:`xray_viz.volume.HU_DENSITY`, starts here).
AIR_HU = -950
#: The material and density (g/cm3) of air (-1000 HU by the definition of the scale).
AIR = ("Air, Dry (near sea level)", 1.205e-3)


class GvxrWarning(UserWarning):
    """A gVXR setting taken approximately, or ignored (see the module docstring)."""


class _Ctx:
    def __init__(self, file):
        self.file = file

    def fail(self, where: str, msg: str, cls=SceneError):
        prefix = f"{self.file}: " if self.file else ""
        raise cls(f"{prefix}gVXR {where}: {msg}")


def _number(ctx, v, where) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        ctx.fail(where, f"must be a number, got {excerpt(json.dumps(v))}")
    return float(v)


def _length_unit(ctx, unit, where) -> float:
    if not isinstance(unit, str) or unit.lower() not in LENGTH_UNITS:
        ctx.fail(where, f"unknown length unit {excerpt(str(unit))}; use one of um, mm, cm, dm, m, "
                        "km")
    return LENGTH_UNITS[unit.lower()]


def _point(ctx, v, where, *, unit_required=True) -> list:
    """``[x, y, z, "unit"]`` -> [x, y, z] in mm (a missing unit: mm, as gVXR's default)."""
    if not isinstance(v, list) or len(v) not in (3, 4):
        ctx.fail(where, f"must be [x, y, z, \"unit\"], got {excerpt(json.dumps(v))}")
    scale = _length_unit(ctx, v[3], where) if len(v) == 4 else 1.0
    return [_number(ctx, x, where) * scale for x in v[:3]]


def _vector(ctx, v, where) -> list:
    if not isinstance(v, list) or len(v) != 3:
        ctx.fail(where, f"must be [x, y, z], got {excerpt(json.dumps(v))}")
    out = [_number(ctx, x, where) for x in v]
    if not any(out):
        ctx.fail(where, "must not be the zero vector")
    return out


_SCAN_KEYS = ("NumberOfProjections", "AngleStep", "FinalAngle", "StartAngle", "IncludeLastAngle",
              "CenterOfRotation", "CentreOfRotation", "Center of rotation", "Centre of rotation",
              "RotationAxis", "Rotation axis", "OutFolder", "GifPath", "Flat-Field Correction",
              "NumberOfWhiteImages")


def _scan(ctx, scan, up, file) -> dict | None:
    """A gVXR ``Scan`` as a ``[scan]`` table, or None (a centre of rotation off the origin:
    ignored, with a warning).

    As gVXR's ``json2gvxr`` (gVXR 2.1) scans: it passes ``NumberOfProjections`` (else
    ``int((FinalAngle - StartAngle) / AngleStep)``, plus one with ``IncludeLastAngle``),
    ``StartAngle``, ``IncludeLastAngle`` and ``FinalAngle`` to ``computeCTAcquisition``, whose
    projection ``k`` turns the samples by ``StartAngle + k * step`` about the rotation axis
    (``RotationAxis``, else ``Detector UpVector``; right-handed, as OpenGL's rotations), the
    step ``(FinalAngle - StartAngle) / (NumberOfProjections - 1)`` with ``IncludeLastAngle``,
    else ``/ NumberOfProjections`` (a given ``AngleStep`` only counts the projections). The
    source and detector turn the other way, which is the ``[scan]`` orbit about ``-axis``.
    ``NumberOfProjections`` and ``AngleStep`` without ``FinalAngle`` (which json2gvxr cannot
    pass on) step by ``AngleStep``. The flat-field keys are for gVXR's images only.
    """
    _keys(ctx, scan, _SCAN_KEYS, "Scan")

    def number(key, default=None):
        if key not in scan:
            return default
        return _number(ctx, scan[key], f"Scan {key}")

    nop, step = number("NumberOfProjections"), number("AngleStep")
    final, start = number("FinalAngle"), number("StartAngle", 0.0)
    last = scan.get("IncludeLastAngle", False)
    if not isinstance(last, bool):
        ctx.fail("Scan IncludeLastAngle", f"must be true or false, got {excerpt(json.dumps(last))}")
    if nop is not None and (nop != int(nop) or nop < 1):
        ctx.fail("Scan NumberOfProjections", f"must be a whole number >= 1, got {nop:g}")
    if final is None:
        if nop is None or step is None:
            ctx.fail("Scan", "needs FinalAngle and NumberOfProjections or AngleStep (or both of "
                             "these)")
        count = int(nop)
    else:
        if nop is None:
            if step is None:
                ctx.fail("Scan", "needs FinalAngle and NumberOfProjections or AngleStep (or "
                                 "both of these)")
            if step == 0:
                ctx.fail("Scan AngleStep", "must not be 0")
            nop = int((final - start) / step) + int(last)
        count = int(nop)
        if last and count < 2:
            ctx.fail("Scan", f"gives {count} projection with IncludeLastAngle; it needs at "
                             "least two (the first and the last angle)")
        step = (final - start) / (count - int(last)) if count > int(last) else 0.0
    if count < 1 or step == 0:
        ctx.fail("Scan", f"gives {count} projections {step:g} degrees apart; it needs at least "
                         "one projection and a step other than 0")
    names = [k for k in _SCAN_KEYS[5:9] if k in scan]
    key = names[0] if names else "CenterOfRotation"
    centre = _point(ctx, scan.get(key, [0, 0, 0, "mm"]), f"Scan {key}")
    if any(c != 0 for c in centre):
        warnings.warn(f"{file}: " * bool(file) + f"gVXR Scan {key} {centre} mm ignored, and the "
                      "scan with it (gVXR moves the source and detector by it during the scan "
                      "only): the scene is the radiograph without it", GvxrWarning, stacklevel=4)
        return None
    turn = next((k for k in ("RotationAxis", "Rotation axis") if k in scan), None)
    if turn is not None:
        up = _vector(ctx, scan[turn], f"Scan {turn}")
    axis = [-float(x) for x in up] if step > 0 else [float(x) for x in up]
    first = start if step > 0 else -start             # the same turns about the axis used
    table = {"orbit": "circular", "projections": count, "arc": _clean(count * abs(step)),
             "axis": [_clean(x) + 0.0 for x in axis], "center": [0.0, 0.0, 0.0]}
    if first != 0:
        table["start"] = _clean(first) + 0.0
    return table


def _keys(ctx, table, allowed, where):
    if not isinstance(table, Mapping):
        ctx.fail(where, f"must be a JSON object, got {type(table).__name__}")
    unknown = [k for k in table if k not in allowed]
    if unknown:
        ctx.fail(where, f"unknown key{'s' * (len(unknown) > 1)} "
                        f"{', '.join(excerpt(k) for k in unknown)}; known: {', '.join(allowed)}")


def _symbol(ctx, z, where) -> str:
    from xray_viz.physics.materials import _xraylib

    xrl = _xraylib()
    if isinstance(z, bool):
        ctx.fail(where, f"not an element: {z!r}")
    if isinstance(z, (int, float)) and float(z).is_integer() and 1 <= int(z) <= 103:
        return xrl.AtomicNumberToSymbol(int(z))
    if isinstance(z, str):
        try:
            xrl.SymbolToAtomicNumber(z)
            return z
        except Exception:
            pass
    ctx.fail(where, f"unknown element {excerpt(str(z))}; give a symbol (\"Fe\") or Z (26)")


def _element_density(symbol: str) -> float:
    from xray_viz.physics.materials import _xraylib

    xrl = _xraylib()
    return float(xrl.ElementDensity(xrl.SymbolToAtomicNumber(symbol)))


def _material(ctx, sample, where) -> dict:
    """A sample's Material (and Density) -> {mu} or {material, density}."""
    if "Material" not in sample:
        ctx.fail(where, "has no 'Material' (such as [\"Element\", \"Al\"])")
    m = sample["Material"]
    w = f"{where} Material"
    if not isinstance(m, list) or len(m) != 2 or not isinstance(m[0], str):
        ctx.fail(w, f"must be [kind, value] such as [\"Element\", \"Al\"], got "
                    f"{excerpt(json.dumps(m))}")
    kind, value = m[0].upper(), m[1]
    density = None
    if "Density" in sample:
        density = _number(ctx, sample["Density"], f"{where} Density")
        if not density > 0:
            ctx.fail(f"{where} Density", f"must be > 0 g/cm3, got {density:g}")
    if kind == "MU":
        mu = _number(ctx, value, w)
        if density is not None:
            ctx.fail(w, "gives a Density with a linear attenuation coefficient (mu)")
        return {"mu": mu}
    if kind == "HU":            # gvxr.setHounsfieldValue(label, round(n)), then any Density
        hu = _number(ctx, value, w)
        out = hu_material(hu)
        if density is not None:
            out["density"] = density
        return out
    if kind == "ELEMENT":
        symbol = _symbol(ctx, value, w)
        return {"material": symbol,
                "density": density if density is not None else _element_density(symbol)}
    if kind == "COMPOUND":
        if not isinstance(value, str) or not value:
            ctx.fail(w, "a compound is a formula such as \"H2O\", got "
                        f"{excerpt(json.dumps(value))}")
        if density is None:
            ctx.fail(where, f"the compound {value!r} needs a 'Density' (g/cm3)")
        return {"material": value, "density": density}
    if kind == "MIXTURE":
        fractions = {}
        if isinstance(value, str):
            parts = re.findall(r"([A-Z][a-z]?)(\d+(?:\.\d+)?)", value)
            if not parts or "".join(a + b for a, b in parts) != value.replace(" ", ""):
                ctx.fail(w, f"cannot read the mixture {excerpt(value)}; write it as element "
                            "symbols and mass percentages, e.g. \"Ti90Al6V4\"")
            pairs = [(a, float(b)) for a, b in parts]
        elif isinstance(value, list) and value and len(value) % 2 == 0:
            pairs = [(_symbol(ctx, z, w), _number(ctx, f, w)) for z, f in
                     zip(value[0::2], value[1::2])]
        else:
            ctx.fail(w, f"a mixture is \"Ti90Al6V4\" or [Z1, w1, Z2, w2, ...], got "
                        f"{excerpt(json.dumps(value))}")
        total = sum(f for _, f in pairs)
        if not total > 0 or any(f < 0 for _, f in pairs):
            ctx.fail(w, "the mass fractions must be >= 0 and not all 0")
        for s, f in pairs:
            fractions[s] = fractions.get(s, 0.0) + f / total
        if density is None:
            ctx.fail(where, "a mixture needs a 'Density' (g/cm3)")
        return {"material": fractions, "density": density}
    ctx.fail(w, f"unknown material kind {excerpt(m[0])}; use Element, Mixture, Compound, HU "
                "or mu")


def hu_material(hu: float) -> dict:
    """A Hounsfield value's ``{"material", "density"}``, as a gVXR ``["HU", n]`` sample.

    gVXR rounds ``n`` to a whole number and looks it up in Schneider, Bortfeld and Schlegel's
    (2000) tissue tables; here the rounded value falls in one of the tissue classes that CT
    volumes traced as voxels use (:data:`xray_viz.volume.HU_DENSITY`: lung, adipose, soft
    tissue, cancellous and cortical bone, from Schneider's HU ranges) and takes that class's
    material at the density of its HU-density line (``1 + HU / 1000`` below 120 HU, Schneider's
    ``1.017 + 0.592e-3 HU`` above): the same density as gVXR's, a coarser composition. Below
    :data:`AIR_HU` the sample is air (:data:`AIR`).

    Examples
    --------
    >>> hu_material(40.4)
    {'material': 'Tissue, Soft (ICRP)', 'density': 1.04}
    >>> hu_material(1200)
    {'material': 'Bone, Cortical (ICRP)', 'density': 1.7274}
    >>> hu_material(-1000)["material"]
    'Air, Dry (near sea level)'
    """
    from xray_viz.volume import HU_DENSITY

    n = int(round(float(hu)))
    if n < AIR_HU:
        return {"material": AIR[0], "density": AIR[1]}
    for _name, low, high, material, (a, b) in HU_DENSITY:
        if low <= n < high:
            return {"material": material, "density": _clean(a + b * n)}
    raise AssertionError(f"HU_DENSITY leaves {n} HU out")     # pragma: no cover - it spans all


def _transform(ctx, transforms, where) -> np.ndarray:
    """gVXR's node transforms, composed as its node matrix: each one right-multiplies."""
    m = np.eye(4)
    if not isinstance(transforms, list):
        ctx.fail(where, "must be a list such as [[\"Rotation\", 90, 0, 1, 0], "
                        "[\"Translation\", 10, 0, 0, \"mm\"]]")
    for k, t in enumerate(transforms, start=1):
        w = f"{where} #{k}"
        if not isinstance(t, list) or not t or not isinstance(t[0], str):
            ctx.fail(w, f"must be [\"Rotation\" | \"Translation\" | \"Scaling\", ...], got "
                        f"{excerpt(json.dumps(t))}")
        kind = t[0].lower()
        step = np.eye(4)
        if kind == "rotation" and len(t) == 5:
            angle = _number(ctx, t[1], w)
            step[:3, :3] = rotation(_vector(ctx, t[2:5], w), angle)
        elif kind == "translation" and len(t) == 5:
            step[:3, 3] = _point(ctx, t[1:5], w)
        elif kind == "scaling" and len(t) == 4:
            s = [_number(ctx, x, w) for x in t[1:4]]
            if not all(x > 0 for x in s):
                ctx.fail(w, f"a scaling must be > 0 (a negative one mirrors the mesh inside out), "
                            f"got {s}")
            step[:3, :3] = np.diag(s)
        else:
            ctx.fail(w, f"not a transform: {excerpt(json.dumps(t))} (Rotation angle x y z, "
                        "Translation x y z unit, Scaling x y z)")
        m = m @ step
    return m


def _clean(x: float) -> float:
    r = round(x, 9)
    return 0.0 if r == 0 else r


def _placement(ctx, m: np.ndarray, where) -> dict:
    """A 4x4 matrix -> ``position``, ``rotation`` (degrees about x, y, z) and ``scale``."""
    from scipy.spatial.transform import Rotation

    a = m[:3, :3]
    scale = np.linalg.norm(a, axis=0)
    r = a / scale
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
        ctx.fail(where, "a scaling between rotations shears the mesh, which has no equivalent "
                        "in xray-viz (scale, then rotate, then translate); scale first")
    out = {}
    if np.any(m[:3, 3] != 0):
        out["position"] = [_clean(x) for x in m[:3, 3]]
    if not np.allclose(r, np.eye(3), atol=1e-12):
        out["rotation"] = [_clean(x) for x in Rotation.from_matrix(r).as_euler("xyz",
                                                                                degrees=True)]
    if not np.allclose(scale, 1.0, atol=1e-12):
        out["scale"] = [_clean(x) for x in scale]
    return out


def _beam(ctx, beam, source: dict, detector: dict):
    where = "Source Beam"
    if isinstance(beam, list):
        if not beam:
            ctx.fail(where, "is empty")
        lines = []
        for k, b in enumerate(beam, start=1):
            w = f"{where} #{k}"
            _keys(ctx, b, ("Energy", "Unit", "PhotonCount"), w)
            unit = str(b.get("Unit", "keV")).lower()
            if unit not in ENERGY_UNITS:
                ctx.fail(w, f"unknown energy unit {excerpt(str(b.get('Unit')))}; use eV, keV "
                            "or MeV")
            if "Energy" not in b:
                ctx.fail(w, "has no 'Energy'")
            lines.append((_number(ctx, b["Energy"], w) * ENERGY_UNITS[unit],
                          _number(ctx, b.get("PhotonCount", 1), w)))
        energies = sorted({e for e, _ in lines})
        if len(energies) > 1:
            ctx.fail(where, f"a spectrum of {len(energies)} lines ({energies[0]:g} to "
                            f"{energies[-1]:g} keV) has no equivalent in a scene file; give one "
                            "energy, or a tube {\"kvp\": ...}, or write the spectrum as a CSV "
                            "file (energy_keV, weight) for [source] spectrum = { file = ... }")
        source["energy"] = _clean(energies[0])
        count = sum(c for _, c in lines)
        if not count > 0:
            ctx.fail(where, "PhotonCount must be > 0")
        if count != 1:
            detector["I0"] = float(count)
        return
    if not isinstance(beam, Mapping):
        ctx.fail(where, f"must be a list of energies or a tube object, got "
                        f"{type(beam).__name__}")
    for key in ("TextFile", "GateMacro"):
        if key in beam:
            ctx.fail(f"{where} {key}", "a spectrum read from a gVXR text file has no "
                                       "equivalent; write it as a CSV file (energy_keV, weight) "
                                       "for [source] spectrum = { file = ... }")
    aliases = {"kvp": "kvp", "peak kilo voltage": "kvp", "tube angle": "angle", "mas": "mas",
               "filter": "filter", "filters": "filter", "unit": "unit"}
    got = {}
    for k, v in beam.items():
        if k.lower() not in aliases:
            ctx.fail(where, f"unknown key {excerpt(k)}; known: kvp, tube angle, filter, mAs")
        got[aliases[k.lower()]] = v
    if "kvp" not in got:
        ctx.fail(where, "needs 'kvp' (tube voltage in kV) or a list of energies")
    spectrum = {"kvp": _number(ctx, got["kvp"], f"{where} kvp")}
    if "angle" in got:
        spectrum["anode_angle"] = _number(ctx, got["angle"], f"{where} tube angle")
    filters = {}
    for k, f in enumerate(got.get("filter") or [], start=1):
        w = f"{where} filter #{k}"
        if not isinstance(f, list) or len(f) not in (2, 3):
            ctx.fail(w, f"must be [material, thickness(, unit)], got {excerpt(json.dumps(f))}")
        symbol = _symbol(ctx, f[0], w)
        mm = _number(ctx, f[1], w) * (_length_unit(ctx, f[2], w) if len(f) == 3 else 1.0)
        filters[symbol] = filters.get(symbol, 0.0) + mm
    if filters:
        spectrum["filters"] = filters
    source["spectrum"] = spectrum
    if got.get("mas") is not None:
        source["mas"] = _number(ctx, got["mas"], f"{where} mAs")


def gvxr_to_dict(doc, *, base_dir=".", file=None) -> dict:
    """A parsed gVXR JSON document -> the dictionary :func:`~xray_viz.scene_file.scene_from_dict`
    takes (mesh paths relative to ``base_dir``, as in the JSON file).

    Parameters
    ----------
    doc : dict
        The JSON document.
    base_dir : path-like
        Folder of the JSON file (mesh paths are relative to it).
    file : Path, optional
        Named in messages.

    Returns
    -------
    dict
        ``{"source": {...}, "detector": {...}, "body": [...]}``.

    Raises
    ------
    SceneError
        A key with no equivalent, or a malformed value (one line naming the key).

    Warns
    -----
    GvxrWarning
        A focal spot taken as a Gaussian; a ``Scan`` about a centre off the origin ignored.
    """
    ctx = _Ctx(file)
    _keys(ctx, doc, _TOP_KEYS, "scene")
    if "SceneGraph" in doc:
        ctx.fail("SceneGraph", "a gVXR scene graph file has no equivalent; list the meshes in "
                               "'Samples'")
    for key in ("Source", "Detector"):
        if key not in doc:
            ctx.fail("scene", f"has no '{key}'")

    src_doc = doc["Source"]
    _keys(ctx, src_doc, _SOURCE_KEYS, "Source")
    source: dict = {}
    detector: dict = {}
    if "Position" not in src_doc:
        ctx.fail("Source", "has no 'Position'")
    source["position"] = _point(ctx, src_doc["Position"], "Source Position")
    shape = src_doc.get("Shape", "PointSource")
    if isinstance(shape, str) and shape.upper() in ("PARALLELBEAM", "PARALLEL"):
        source["kind"] = "parallel"
    elif isinstance(shape, str) and shape.upper() in ("POINTSOURCE", "POINT", "CONE", "CONEBEAM"):
        source["kind"] = "point"
    elif isinstance(shape, list) and len(shape) == 4 and str(shape[0]).upper() == "FOCALSPOT":
        source["kind"] = "point"
        size = _number(ctx, shape[1], "Source Shape") * _length_unit(ctx, shape[2],
                                                                     "Source Shape")
        detector["focal_spot"] = _clean(size)
        warnings.warn(f"{file}: " * bool(file) + f"gVXR Source Shape FocalSpot of {size:g} mm: "
                      "taken as a Gaussian focal spot of that FWHM", GvxrWarning, stacklevel=3)
    else:
        ctx.fail("Source Shape", f"unknown shape {excerpt(json.dumps(shape))}; use PointSource, "
                                 "ParallelBeam or [\"FocalSpot\", size, unit, n]")
    if "Beam" not in src_doc:
        ctx.fail("Source", "has no 'Beam' (the energies or the tube)")
    _beam(ctx, src_doc["Beam"], source, detector)

    det_doc = doc["Detector"]
    _keys(ctx, det_doc, _DETECTOR_KEYS, "Detector")
    for key in ("Energy response", "LSF"):
        if key in det_doc:
            ctx.fail(f"Detector {key}", "has no equivalent in xray-viz (see [detector] response, "
                                        "scintillator and mtf); remove it")
    for key in ("Position", "UpVector", "NumberOfPixels"):
        if key not in det_doc:
            ctx.fail("Detector", f"has no '{key}'")
    detector["center"] = _point(ctx, det_doc["Position"], "Detector Position")
    detector["up"] = _vector(ctx, det_doc["UpVector"], "Detector UpVector")
    n = det_doc["NumberOfPixels"]
    if (not isinstance(n, list) or len(n) != 2
            or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in n)):
        ctx.fail("Detector NumberOfPixels", f"must be [columns, rows], got "
                                            f"{excerpt(json.dumps(n))}")
    detector["shape"] = list(n)
    if ("Spacing" in det_doc) == ("Size" in det_doc):
        ctx.fail("Detector", "needs one of 'Spacing' ([dx, dy, unit]) or 'Size'")
    key = "Spacing" if "Spacing" in det_doc else "Size"
    v = det_doc[key]
    if not isinstance(v, list) or len(v) != 3:
        ctx.fail(f"Detector {key}", f"must be [x, y, \"unit\"], got {excerpt(json.dumps(v))}")
    unit = _length_unit(ctx, v[2], f"Detector {key}")
    xy = [_number(ctx, x, f"Detector {key}") * unit for x in v[:2]]
    if key == "Size":
        xy = [xy[0] / n[0], xy[1] / n[1]]
    detector["pitch"] = [_clean(x) for x in xy] if xy[0] != xy[1] else _clean(xy[0])
    if "Oversampling" in det_doc:
        o = det_doc["Oversampling"]
        if isinstance(o, bool) or not isinstance(o, int) or o < 1:
            ctx.fail("Detector Oversampling", f"must be a whole number >= 1, got {o!r}")
        detector["supersample"] = o
    if "Scintillator" in det_doc:
        sc = det_doc["Scintillator"]
        _keys(ctx, sc, ("Material", "Thickness", "Unit"), "Detector Scintillator")
        if "Material" not in sc or "Thickness" not in sc:
            ctx.fail("Detector Scintillator", "needs 'Material' and 'Thickness'")
        thickness = _number(ctx, sc["Thickness"], "Detector Scintillator Thickness") * \
            _length_unit(ctx, sc.get("Unit", "mm"), "Detector Scintillator Unit")
        name = str(sc["Material"])
        detector["scintillator"] = {"material": name.split()[0], "thickness": _clean(thickness)}
    if "RightVector" in det_doc:
        from xray_viz.geometry import detector_axes

        right = np.asarray(_vector(ctx, det_doc["RightVector"], "Detector RightVector"))
        _, ho, _ = detector_axes(source["position"], detector["center"], detector["up"])
        if np.dot(right / np.linalg.norm(right), ho) < 1 - 1e-6:
            ctx.fail("Detector RightVector", f"{right.tolist()} is not xray-viz's image x axis "
                                             f"(beam x up = {[_clean(x) for x in ho]}): the image "
                                             "would be mirrored or turned; no equivalent")

    bodies = []
    samples = doc.get("Samples", [])
    if not isinstance(samples, list):
        ctx.fail("Samples", "must be a list of objects")
    for k, sample in enumerate(samples, start=1):
        where = f"Samples #{k}"
        if isinstance(sample, str):
            ctx.fail(where, f"{excerpt(sample)} has no equivalent (xray-viz does not move "
                            "the samples); place them with a Transform instead")
        _keys(ctx, sample, _SAMPLE_KEYS, where)
        label = sample.get("Label", f"sample{k}")
        if not isinstance(label, str) or not label.strip():
            ctx.fail(where, f"Label must be a non-empty string, got {label!r}")
        where = f"Samples #{k} ({label!r})"
        primitives = [p for p in _PRIMITIVES if p in sample]
        if len(primitives) > 1 or (primitives and "Path" in sample):
            ctx.fail(where, f"gives {' and '.join(primitives + ['Path'] * ('Path' in sample))}: "
                            "give one shape (a primitive or a mesh file's Path)")
        turn = np.eye(4)            # a primitive's own orientation, before the Transform
        if primitives:
            body = {"name": label, "shape": _primitive(ctx, primitives[0], sample[primitives[0]],
                                                       f"{where} {primitives[0]}")}
            if primitives[0] == "Cylinder":       # gVXR's axis is y, the shape's z
                turn[:3, :3] = rotation([1.0, 0.0, 0.0], -90.0)
        elif "Path" not in sample or not isinstance(sample["Path"], str):
            ctx.fail(where, "has no 'Path' (the mesh file) nor a primitive (Cube, Cuboid, "
                            "Cylinder)")
        else:
            body = {"name": label, "mesh": sample["Path"]}
        unit = "mm" if primitives else sample.get("Unit", "mm")   # a primitive's own unit
        factor = _length_unit(ctx, unit, f"{where} Unit")
        body.update(_material(ctx, sample, where))
        m = _transform(ctx, sample["Transform"], f"{where} Transform") \
            if "Transform" in sample else np.eye(4)
        placement = _placement(ctx, m @ turn, f"{where} Transform")
        if unit.lower() in _BODY_UNITS:
            if _BODY_UNITS[unit.lower()] != "mm":
                body["units"] = _BODY_UNITS[unit.lower()]
        else:
            placement["scale"] = [_clean(x * factor) for x in placement.get("scale", [1, 1, 1])]
        body.update(placement)
        bodies.append(body)
    out = {"source": source, "detector": detector, "body": bodies}
    if "Scan" in doc:
        scan = _scan(ctx, doc["Scan"], detector["up"], file)
        if scan is not None:
            out["scan"] = scan
    return out


def _primitive(ctx, kind, value, where) -> dict:
    """A gVXR primitive sample's shape table (mm): ``Cube [size, unit]``, ``Cuboid`` or
    ``Parallelepiped [x, y, z, unit]`` (``gvxr.makeCuboid``), ``Cylinder [sectors, height,
    radius, unit]`` (``gvxr.makeCylinder``), each centred on the origin."""
    forms = {"Cube": "[size, \"unit\"]", "Cuboid": "[x, y, z, \"unit\"]",
             "Parallelepiped": "[x, y, z, \"unit\"]",
             "Cylinder": "[sectors, height, radius, \"unit\"]"}
    n = {"Cube": 2, "Cuboid": 4, "Parallelepiped": 4, "Cylinder": 4}[kind]
    if not isinstance(value, list) or len(value) != n or not isinstance(value[-1], str):
        ctx.fail(where, f"must be {forms[kind]}, got {excerpt(json.dumps(value))}")
    factor = _length_unit(ctx, value[-1], where)
    numbers = value[1:-1] if kind == "Cylinder" else value[:-1]
    lengths = [_number(ctx, x, where) * factor for x in numbers]
    if not all(x > 0 for x in lengths):
        ctx.fail(where, f"lengths must be > 0, got {', '.join(f'{x:g}' for x in lengths)} mm")
    if kind == "Cube":
        return {"kind": "box", "size": [_clean(lengths[0])] * 3}
    if kind in ("Cuboid", "Parallelepiped"):
        return {"kind": "box", "size": [_clean(x) for x in lengths]}
    sectors = value[0]
    if isinstance(sectors, bool) or not isinstance(sectors, (int, float)) \
            or not float(sectors).is_integer() or not 3 <= sectors <= 4096:
        ctx.fail(where, f"the number of sectors must be a whole number from 3 to 4096, got "
                        f"{excerpt(json.dumps(sectors))}")
    height, radius = lengths
    return {"kind": "cylinder", "radius": _clean(radius), "height": _clean(height),
            "sections": int(sectors)}


def read_json(path):
    """Parse a JSON file; a syntax error is one line naming the file, line and column."""
    from xray_viz._files import require_regular

    path = Path(path)
    require_regular(path, SceneError, "gVXR scene file")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a text (UTF-8) JSON file") from None
    except FileNotFoundError:
        raise SceneFileNotFoundError(f"{path}: no such scene file") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise SceneError(f"{path}: malformed JSON: {exc.msg} (line {exc.lineno}, column "
                         f"{exc.colno})") from None
    except RecursionError:
        raise SceneError(f"{path}: nested too deeply (arrays or tables thousands of levels inside each other): not a gVXR scene") from None


def not_toml(path, text: str) -> str | None:
    """The message for a JSON file given where TOML was expected, or None if it is not JSON.

    Examples
    --------
    >>> not_toml("scene.toml", '{"Source": {}, "Detector": {}}')  # doctest: +ELLIPSIS
    'scene.toml: is a JSON file (a gVirtualXray scene), not TOML: ...'
    >>> not_toml("scene.toml", "[source]") is None
    True
    """
    stripped = text.lstrip("\ufeff \t\r\n")
    if not stripped.startswith(("{", "[")):
        return None
    try:
        doc = json.loads(stripped)
    except (json.JSONDecodeError, RecursionError):
        return None
    what = "a gVirtualXray scene" if isinstance(doc, dict) and "Source" in doc else "JSON"
    return (f"{path}: is a JSON file ({what}), not TOML: rename it to .json to load it as a "
            f"gVXR scene, or convert it with `xray-viz convert {path} -o scene.toml`"
            if what != "JSON" else
            f"{path}: is a JSON file, not TOML: a scene file is TOML ([source], [detector], "
            "[[body]]), or a gVirtualXray .json scene")


# --------------------------------------------------------------------------------------------
# TOML writing and `xray-viz convert`


def to_toml(doc: Mapping, *, header: str = "") -> str:
    """A scene dictionary (as :func:`gvxr_to_dict` returns) as TOML text (tomlkit), after
    ``header`` as comment lines.

    Examples
    --------
    >>> print(to_toml({"source": {"position": [0.0, 0.0, 1.0]}, "body": [{"name": "a"}]}))
    [source]
    position = [0.0, 0.0, 1.0]
    <BLANKLINE>
    [[body]]
    name = "a"
    <BLANKLINE>
    """
    from xray_viz._toml import dumps

    return dumps(doc, header=header)
