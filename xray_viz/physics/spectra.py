"""X-ray spectra: monochromatic beams, SpekPy tube spectra and user spectra from CSV files.

In a scene's ``[source]`` table give either ``energy`` (keV, monochromatic) or ``spectrum``:

``spectrum = { kvp = 80.0, anode_angle = 12.0, filters = { Al = 2.5 } }``
    A tungsten-anode tube spectrum computed by SpekPy (Poludniowski et al. 2021): ``kvp`` the
    tube potential (kV), ``anode_angle`` in degrees (default 12), ``filters`` a table of
    ``material = thickness in mm`` (SpekPy material names: element symbols, ``"Water, Liquid"``,
    ...; default none, i.e. no added filtration), ``bin`` the energy bin width in keV (default 1),
    ``anode`` ``"W"`` (default), ``"Mo"`` or ``"Rh"``; ``kvp`` from 10 to 500 kV for W, 10 to 50
    kV for Mo and Rh (:data:`KVP_RANGE`). The parameters (and filter names) are checked when the
    scene is loaded; the spectrum is computed when first used (SpekPy takes ~0.2 s per spectrum,
    plus ~0.7 s to import) and cached per parameter set.

    SpekPy computes the beam leaving the anode (its default physics and data); the filters are
    then applied here with xraylib's attenuation coefficients, the data set of the bodies and
    of :func:`~xray_viz.physics.dosimetry.hvl` (:mod:`~xray_viz.physics.materials`): an element
    symbol at xraylib's density of the solid element, a NIST compound name with xraylib's NIST
    composition and density, any other SpekPy material with the composition and density of its
    SpekPy material file. (SpekPy's own filtering interpolates coarse tables, and its NIST
    option the 20-30-40-50-60-80-100 keV grid of Hubbell and Seltzer log-log: its Al attenuation
    is 1.5-1.7 % high at 25 and 65-70 keV, a ~1 % error in a 70-80 kV HVL.)

    A tube always has inherent filtration (the glass or metal window, the oil and the housing:
    typically 2.5-3 mm Al equivalent for a diagnostic tube, the minimum total filtration IEC
    60601-1-3 requires above 70 kV, ~1 mm Be for mammography and low-energy tubes). A spectrum
    without any filter is unphysical, mostly very soft photons that no real beam contains, and
    warns (:class:`UnfilteredSpectrumWarning`).
``spectrum = { quality = "RQA5", anode_angle = 12.0 }``
    An IEC 61267:2005 standard radiation quality (:data:`IEC61267_QUALITIES`): the quality's
    tube voltage, an inherent Al filtration solved for the standard RQR first HVL at that anode
    angle, and for RQA the standard added Al filtration; ``bin`` as above. The HVL reached is in
    the spectrum's description and in :attr:`Spectrum.quality` (see :func:`quality_spectrum`).
``spectrum = { file = "spec.csv" }``
    Two columns, energy (keV) and relative fluence (photons in that bin), comma, semicolon or
    blank separated, UTF-8 (a byte-order mark is allowed). ``#`` comments and blank lines are
    allowed anywhere, and one header line before the data, none of whose fields is a number;
    any other non-numeric field is an error naming the file and line. The path is relative to
    the scene file. For a fluence *per keV* on a non-uniform grid, multiply by the bin widths
    first.

Every spectrum becomes a :class:`Spectrum`: bin energies and photon-fluence weights that sum to 1;
a SpekPy spectrum also knows its photons per mAs (:attr:`Spectrum.fluence_per_mas`).

Examples
--------
>>> s = Spectrum.monochromatic(60.0)
>>> s.energies.tolist(), s.weights.tolist()
([60.0], [1.0])
"""

from __future__ import annotations

import difflib
import json
import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from xray_viz.errors import SceneFileNotFoundError, SpectrumError

#: Photon energy (keV) of a source that gives neither ``energy`` nor ``spectrum``, and the
#: energy at which per-ray figures of a polychromatic source are shown when one is needed.
DEFAULT_ENERGY = 60.0

__all__ = ["Spectrum", "BeamQuality", "tube_spectrum", "quality_spectrum", "read_spectrum_csv",
           "read_columns", "spectrum_from_dict", "source_spectrum", "UnfilteredSpectrumWarning",
           "SPECTRUM_KEYS", "ANODES", "KVP_RANGE", "IEC61267_QUALITIES", "IEC61267_EDITION",
           "DEFAULT_ENERGY"]


class UnfilteredSpectrumWarning(UserWarning):
    """A tube spectrum without any filtration: unphysical (a real tube has >= 2.5 mm Al)."""

#: Keys of a ``spectrum`` table and their meaning.
SPECTRUM_KEYS = {
    "kvp": "tube potential in kV (SpekPy tube spectrum)",
    "anode_angle": "anode angle in degrees (default 12)",
    "filters": "table of filter material = thickness in mm",
    "bin": "energy bin width in keV (default 1)",
    "anode": "anode material, 'W' (default), 'Mo' or 'Rh'",
    "file": "two-column CSV file (keV, relative fluence), relative to the scene file",
    "quality": "IEC 61267 radiation quality, 'RQR2'..'RQR10' or 'RQA2'..'RQA10'",
}

#: The edition of IEC 61267 whose radiation qualities :data:`IEC61267_QUALITIES` lists.
IEC61267_EDITION = "IEC 61267:2005 (2nd edition)"

#: IEC 61267:2005 standard radiation qualities (tungsten anode): ``name: (tube voltage kV,
#: added Al filtration mm beyond the RQR beam, first HVL mm Al)``. RQR: the beam emerging from
#: the tube assembly, whose total (inherent) filtration is chosen to give the HVL; RQA: the RQR
#: beam of the same voltage plus the added filtration (a patient-equivalent hardening).
#:
#: Sources and their confirmation: the RQR voltages and HVLs agree with the RRPPS (University
#: Hospitals Birmingham) list of the IEC 61267:2005 qualities it produces (HVLs given there to
#: 0.1 mm: 1.4, 1.8, 2.2, 2.6, 3.0, 3.5, 4.0, 5.0, 6.6) and, for RQR 3/5/7/9, with the values
#: the project's field notes quote. The RQA 3/5/7/9 added filtrations and HVLs (10/21/30/40 mm,
#: 3.8/6.8/9.2/11.6 mm) are as commonly quoted for the 2005 edition (the 1994 edition gave
#: 4.0/7.1/9.1/11.5); RQA 2/4/6/8/10 (4/16/26/34/45 mm, 2.2/5.4/8.2/10.1/13.3 mm) are from the
#: standard's table as recalled, NOT confirmed against an accessible copy of the standard.
IEC61267_QUALITIES = {
    "RQR2": (40.0, 0.0, 1.42), "RQR3": (50.0, 0.0, 1.78), "RQR4": (60.0, 0.0, 2.19),
    "RQR5": (70.0, 0.0, 2.58), "RQR6": (80.0, 0.0, 3.01), "RQR7": (90.0, 0.0, 3.48),
    "RQR8": (100.0, 0.0, 3.97), "RQR9": (120.0, 0.0, 5.00), "RQR10": (150.0, 0.0, 6.57),
    "RQA2": (40.0, 4.0, 2.2), "RQA3": (50.0, 10.0, 3.8), "RQA4": (60.0, 16.0, 5.4),
    "RQA5": (70.0, 21.0, 6.8), "RQA6": (80.0, 26.0, 8.2), "RQA7": (90.0, 30.0, 9.2),
    "RQA8": (100.0, 34.0, 10.1), "RQA9": (120.0, 40.0, 11.6), "RQA10": (150.0, 45.0, 13.3),
}


@dataclass(frozen=True)
class BeamQuality:
    """How a :func:`quality_spectrum` was made, and the HVL it reached.

    Attributes
    ----------
    name : str
        ``"RQR5"``, ``"RQA5"``, ...
    kvp : float
        Tube voltage (kV).
    anode_angle : float
        Degrees.
    inherent_al_mm : float
        The Al filtration solved for so that the RQR beam of this voltage has the standard HVL.
    added_al_mm : float
        The standard added filtration (0 for RQR).
    hvl_standard_mm : float
        The standard's first HVL (mm Al).
    hvl_mm : float
        The first HVL (mm Al, on air kerma) of this spectrum.
    edition : str
    """

    name: str
    kvp: float
    anode_angle: float
    inherent_al_mm: float
    added_al_mm: float
    hvl_standard_mm: float
    hvl_mm: float
    edition: str = IEC61267_EDITION

#: Anode (target) materials SpekPy models.
ANODES = ("W", "Mo", "Rh")


@dataclass(frozen=True, eq=False)
class Spectrum:
    """A discrete photon spectrum.

    Attributes
    ----------
    energies : (n,) float
        Bin energies in keV, increasing.
    weights : (n,) float
        Fraction of the photons in each bin (photon fluence), summing to 1.
    kvp : float or None
        Tube potential of a tube spectrum; the energy of a monochromatic beam.
    description : str
    fluence_per_mas : float or None
        Photons per mm^2 per mAs at 1 m from the focal spot (all bins, after the filters), for
        a SpekPy tube spectrum (SpekPy's ``get_flu()`` per mAs at its 100 cm reference distance,
        / 100); None for CSV and monochromatic spectra, which carry no absolute output.
    quality : BeamQuality or None
        For an IEC 61267 preset (:func:`quality_spectrum`): its filtration and the HVL reached.
    """

    energies: np.ndarray
    weights: np.ndarray
    kvp: float | None = None
    description: str = ""
    fluence_per_mas: float | None = None
    quality: BeamQuality | None = None

    def __post_init__(self):
        e = np.atleast_1d(np.asarray(self.energies, dtype=np.float64)).copy()
        w = np.atleast_1d(np.asarray(self.weights, dtype=np.float64)).copy()
        if e.ndim != 1 or e.shape != w.shape or len(e) == 0:
            raise SpectrumError(f"spectrum needs matching non-empty energies and weights, got "
                                f"shapes {e.shape} and {w.shape}")
        if not (np.all(np.isfinite(e)) and np.all(e > 0)):
            raise SpectrumError("spectrum energies must be finite and > 0 keV")
        if np.any(np.diff(e) <= 0):
            raise SpectrumError("spectrum energies must be strictly increasing")
        if not (np.all(np.isfinite(w)) and np.all(w >= 0)) or w.sum() <= 0:
            raise SpectrumError("spectrum fluences must be finite, >= 0 and not all zero")
        w = w / w.sum()
        if self.fluence_per_mas is not None:
            f = self.fluence_per_mas
            if isinstance(f, bool) or not (math.isfinite(f) and f > 0):
                raise SpectrumError(f"spectrum fluence_per_mas must be > 0 photons/mm^2/mAs, "
                                    f"got {f!r}")
            object.__setattr__(self, "fluence_per_mas", float(f))
        for a in (e, w):
            a.setflags(write=False)
        object.__setattr__(self, "energies", e)
        object.__setattr__(self, "weights", w)

    def __len__(self) -> int:
        return len(self.energies)

    @classmethod
    def monochromatic(cls, energy: float) -> "Spectrum":
        """A single energy (keV)."""
        return cls(np.array([float(energy)]), np.array([1.0]), kvp=float(energy),
                   description=f"monochromatic {float(energy):g} keV")

    @property
    def mean_energy(self) -> float:
        """Fluence-weighted mean energy in keV."""
        return float(self.weights @ self.energies)

    @property
    def swank_factor(self) -> float:
        """``<E>^2 / <E^2>``: the efficiency loss of energy weighting (1 for a single energy).

        An energy-integrating detector's signal has relative variance ``1 / (N * swank)`` for
        ``N`` photons (compound Poisson statistics).
        """
        return float(self.mean_energy ** 2 / (self.weights @ self.energies ** 2))

    @property
    def max_energy(self) -> float:
        """Energy (keV) of the highest bin."""
        return float(self.energies[-1])


def _spekpy():
    try:
        import spekpy
    except ImportError:  # pragma: no cover - spekpy is a dependency
        raise SpectrumError("tube spectra need SpekPy: pip install spekpy") from None
    return spekpy


@lru_cache(maxsize=1)
def _spekpy_materials() -> frozenset[str] | None:
    """Names SpekPy accepts as filter materials, or None if SpekPy is not installed.

    SpekPy looks a filter up as ``NAME.comp`` in its ``data/matl_usr`` then ``data/matl_def``
    directories (element symbols and NIST-like compound names). The directories are listed
    without importing SpekPy (~0.7 s), so scene files are checked quickly at load time.
    """
    import importlib.util

    try:
        spec = importlib.util.find_spec("spekpy")
    except (ImportError, ValueError):  # pragma: no cover
        spec = None
    if spec is None or not spec.submodule_search_locations:
        return None
    root = Path(list(spec.submodule_search_locations)[0]) / "data"
    names = set()
    for sub in ("matl_usr", "matl_def"):
        try:
            names.update(p.name[:-5] for p in (root / sub).iterdir() if p.name.endswith(".comp"))
        except OSError:
            continue
    return frozenset(names) or None


def _filter_hint(material: str, known) -> str:
    """``"did you mean 'Al'? "``: a case-insensitive match first, then a name one letter
    shorter (``'Alu'`` -> ``'Al'``) or starting with the given one, then difflib's closest."""
    known = sorted(known)
    m = material.strip().lower()
    close = [k for k in known if k.lower() == m]
    close += sorted((k for k in known if k not in close
                     and ((m.startswith(k.lower()) and len(m) - len(k) == 1 and len(k) >= 2)
                          or (k.lower().startswith(m) and len(m) >= 3))),
                    key=lambda k: (abs(len(k) - len(m)), k))
    close += [c for c in difflib.get_close_matches(material, known, n=3) if c not in close]
    return f"did you mean {', '.join(map(repr, close[:3]))}? " if close else ""


def _unknown_filter(material: str, known) -> SpectrumError:
    return SpectrumError(f"spectrum has an unknown filter material {material!r}: "
                         f"{_filter_hint(material, known)}"
                         "use an element symbol such as 'Al' or 'Cu', or a SpekPy material name "
                         "such as 'Water, Liquid'")


#: Tube potentials (kV) SpekPy models for each anode (its default physics model, "casim").
KVP_RANGE = {"W": (10.0, 500.0), "Mo": (10.0, 50.0), "Rh": (10.0, 50.0)}


@lru_cache(maxsize=32)
def _spekpy_beam(kvp, anode_angle, bin_width, anode):
    """SpekPy's unfiltered beam: (energies keV, photons per mm^2 per bin per mAs at 1 m).

    SpekPy's default physics ("casim") and its default attenuation data for the anode's
    self-absorption, with which the model was validated; ``get_spectrum(diff=False)`` is in
    photons per cm^2 per bin at z = 100 cm for 1 mAs.
    """
    sp = _spekpy()
    try:
        s = sp.Spek(kvp=kvp, th=anode_angle, dk=bin_width, targ=anode, z=100.0, mas=1.0)
        k, fluence = s.get_spectrum(diff=False)
    except Exception as exc:
        raise SpectrumError(f"SpekPy cannot model kvp = {kvp:g} with anode {anode!r} and "
                            f"anode_angle = {anode_angle:g}: {exc}") from None
    k = np.asarray(k, dtype=np.float64).copy()
    fluence = np.asarray(fluence, dtype=np.float64) / 100.0        # per cm^2 -> per mm^2
    for a in (k, fluence):
        a.setflags(write=False)
    return k, fluence


@lru_cache(maxsize=128)
def _filter_definition(material: str):
    """``(xraylib material, density g/cm^3)`` of a filter named as SpekPy names materials.

    An element symbol: the element at xraylib's density of the solid; a NIST compound name
    xraylib knows: that compound; any other SpekPy material: the mass fractions and density of
    its SpekPy material file, as a mixture of elements.
    """
    from xray_viz.physics import materials

    if material in materials.nist_compounds():
        return material, materials.material_density(material)
    xrl = materials._xraylib()
    try:
        z = xrl.SymbolToAtomicNumber(material)
    except ValueError:
        z = 0
    if z > 0:
        return material, float(xrl.ElementDensity(z))
    path = _spekpy_material_file(material)
    if path is None:
        raise _unknown_filter(material, _spekpy_materials() or ())
    comp = json.loads(path.read_text())["composition"]
    mixture = tuple((xrl.AtomicNumberToSymbol(int(zz)), float(w)) for zz, w in comp["elements"])
    total = sum(w for _, w in mixture)
    return tuple((sym, w / total) for sym, w in mixture), float(comp["density"])


def _spekpy_material_file(material: str) -> Path | None:
    import importlib.util

    try:
        spec = importlib.util.find_spec("spekpy")
    except (ImportError, ValueError):  # pragma: no cover
        return None
    if spec is None or not spec.submodule_search_locations:  # pragma: no cover
        return None
    root = Path(list(spec.submodule_search_locations)[0]) / "data"
    for sub in ("matl_usr", "matl_def"):
        path = root / sub / f"{material}.comp"
        if path.is_file():
            return path
    return None


def filter_attenuation(material: str, energies_kev) -> np.ndarray:
    """Linear attenuation (1/mm) of a tube filter, with xraylib's cross sections.

    Parameters
    ----------
    material : str
        A filter name as in ``filters``: element symbol, NIST compound or SpekPy material.
    energies_kev : (n,) float

    Returns
    -------
    (n,) float

    Examples
    --------
    >>> from xray_viz.physics.materials import linear_attenuation
    >>> bool(filter_attenuation("Al", [60.0])[0] * 10 == linear_attenuation("Al", [60.0],
    ...                                                                     density=2.6989)[0])
    True
    """
    from xray_viz.physics.materials import linear_attenuation

    definition, density = _filter_definition(material)
    return linear_attenuation(definition if isinstance(definition, str) else dict(definition),
                              energies_kev, density=density) / 10.0


def _filtered(k, fluence, filters):
    """Fluence behind ``filters`` ((material, mm) pairs), attenuated with xraylib."""
    out = np.array(fluence, dtype=np.float64)
    positive = out > 0
    for material, mm in filters:
        mu = filter_attenuation(material, k[positive])
        out[positive] *= np.exp(-mu * mm)
    return out


def _make_spectrum(k, fluence, *, kvp, description, quality=None) -> Spectrum:
    keep = fluence > 0
    if not np.any(keep):
        raise SpectrumError(f"the filtration ({description}) absorbs the whole {kvp:g} kV "
                            "spectrum")
    return Spectrum(k[keep], fluence[keep], kvp=float(kvp), description=description,
                    fluence_per_mas=float(fluence[keep].sum()), quality=quality)


@lru_cache(maxsize=64)
def _tube_spectrum_cached(kvp, anode_angle, filters, bin_width, anode) -> Spectrum:
    for material, _ in filters:
        _filter_definition(material)                   # unknown names fail before SpekPy runs
    k, fluence = _spekpy_beam(kvp, anode_angle, bin_width, anode)
    desc = f"{kvp:g} kV {anode} anode {anode_angle:g} deg" + "".join(
        f", {mm:g} mm {m}" for m, mm in filters)
    return _make_spectrum(k, _filtered(k, fluence, filters), kvp=kvp, description=desc)


def _first_hvl_al(k, fluence) -> float:
    from xray_viz.physics._air import _half_value_layers

    return _half_value_layers(k, fluence, filter_attenuation("Al", k))[0]


@lru_cache(maxsize=64)
def _quality_spectrum_cached(name, anode_angle, bin_width) -> Spectrum:
    from scipy.optimize import brentq

    kvp, added, target = IEC61267_QUALITIES[name]
    rqr = "RQR" + name[3:]
    rqr_hvl = IEC61267_QUALITIES[rqr][2]
    k, fluence = _spekpy_beam(kvp, anode_angle, bin_width, "W")
    positive = fluence > 0
    k, fluence = k[positive], fluence[positive]
    mu_al = filter_attenuation("Al", k)

    def rqr_error(mm):
        return _first_hvl_al(k, fluence * np.exp(-mu_al * mm)) - rqr_hvl

    if rqr_error(0.0) >= 0:
        raise SpectrumError(f"quality {name}: the unfiltered {kvp:g} kV beam at anode_angle = "
                            f"{anode_angle:g} deg already has an HVL above the {rqr} value "
                            f"{rqr_hvl:g} mm Al; no inherent filtration gives it")
    hi = 1.0
    while rqr_error(hi) < 0:
        hi *= 2.0
        if hi > 1000:                                  # pragma: no cover - HVL grows with mm
            raise SpectrumError(f"quality {name}: cannot reach the {rqr} HVL")
    inherent = float(brentq(rqr_error, 0.0, hi, xtol=1e-10, rtol=1e-12))
    filtered = fluence * np.exp(-mu_al * (inherent + added))
    reached = _first_hvl_al(k, filtered)
    quality = BeamQuality(name=name, kvp=kvp, anode_angle=anode_angle, inherent_al_mm=inherent,
                          added_al_mm=added, hvl_standard_mm=target, hvl_mm=reached)
    desc = (f"{name} ({IEC61267_EDITION}): {kvp:g} kV W anode {anode_angle:g} deg, "
            f"{inherent:.3f} mm Al inherent (for the {rqr} HVL {rqr_hvl:g} mm Al)"
            + (f" + {added:g} mm Al added" if added else "")
            + f"; HVL {reached:.3f} mm Al (standard {target:g})")
    return _make_spectrum(k, filtered, kvp=kvp, description=desc, quality=quality)


def quality_spectrum(name: str, *, anode_angle: float = 12.0, bin_width: float = 1.0) -> Spectrum:
    """An IEC 61267:2005 standard radiation quality as a tube spectrum (cached).

    Parameters
    ----------
    name : str
        ``"RQR2"`` ... ``"RQR10"``, ``"RQA2"`` ... ``"RQA10"`` (:data:`IEC61267_QUALITIES`).
    anode_angle : float
        Degrees; the inherent filtration that gives the standard HVL depends on it.
    bin_width : float
        keV.

    Returns
    -------
    Spectrum
        ``quality`` holds the inherent filtration found and the HVL reached.

    Notes
    -----
    The tube voltage is the quality's. The inherent Al filtration is solved (Brent's method)
    so that the RQR beam of that voltage has the standard RQR first HVL on air kerma
    (:func:`~xray_viz.physics.dosimetry.hvl`); an RQA quality then adds its standard Al
    filtration, and its HVL is whatever that gives (the standard asks to adjust the voltage
    slightly instead until the RQA HVL is met; here the voltage stays nominal and the HVL
    reached is reported). Filters and HVLs use xraylib's Al at 2.699 g/cm^3.

    Examples
    --------
    >>> s = quality_spectrum("RQA5")
    >>> round(s.quality.hvl_mm, 1), s.kvp
    (6.7, 70.0)
    """
    d = spectrum_from_dict({"quality": name, "anode_angle": anode_angle, "bin": bin_width})
    return _quality_spectrum_cached(d["quality"], d["anode_angle"], d["bin"])


def tube_spectrum(kvp: float, *, anode_angle: float = 12.0, filters=None, bin_width: float = 1.0,
                  anode: str = "W") -> Spectrum:
    """A tube spectrum from SpekPy (cached per parameter set).

    Parameters
    ----------
    kvp : float
        Tube potential in kV.
    anode_angle : float
        Anode (target) angle in degrees.
    filters : mapping of str to float, optional
        Filter material -> thickness in mm, applied in order.
    bin_width : float
        Energy bin width in keV.
    anode : {"W", "Mo", "Rh"}

    Returns
    -------
    Spectrum
        Bins of zero fluence are dropped; ``fluence_per_mas`` is the tube output after the
        filters.

    Warns
    -----
    UnfilteredSpectrumWarning
        Without filters.

    Examples
    --------
    >>> s = tube_spectrum(80.0, filters={"Al": 2.5})
    >>> round(s.mean_energy, 1)
    43.0
    """
    d = spectrum_from_dict({"kvp": kvp, "anode_angle": anode_angle, "filters": filters or {},
                            "bin": bin_width, "anode": anode})
    return _tube_spectrum_cached(d["kvp"], d["anode_angle"], tuple(d["filters"].items()),
                                 d["bin"], d["anode"])


def _csv_fields(text: str) -> list[str]:
    text = text.replace(";", ",")
    return [p.strip() for p in text.split(",")] if "," in text else text.split()


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def read_columns(path, *, error=SpectrumError, name="spectrum file",
                 columns="keV, relative fluence") -> np.ndarray:
    """The rows of a two-column numeric CSV text file: the one reader of spectrum files and of
    the detector's MTF/LSF tables.

    Comma, semicolon or blank separated, UTF-8 (a byte-order mark allowed), ``#`` comments and
    blank lines anywhere, one header line before the data none of whose fields is a number.
    Errors name the file, line and field, never quoting the file's text (it may be any
    file a scene names).

    Parameters
    ----------
    path : str or Path
    error : type
        The exception class raised (an :class:`~xray_viz.errors.XrayVizError` subclass).
    name, columns : str
        How messages name the file and its two columns.

    Returns
    -------
    (n, 2) float
        ``n >= 0`` rows, in file order.
    """
    from xray_viz._files import require_regular

    require_regular(path, error, name)
    try:
        # utf-8-sig: a byte-order mark (as spreadsheet programs write) is not part of line 1
        with open(path, encoding="utf-8-sig") as fh:
            lines = fh.readlines()
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a UTF-8 text file (byte {exc.start}); a {name} is a "
                    f"two-column CSV text file: {columns}") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {name}: {exc.strerror}") from None
    rows = []
    header_seen = False
    for lineno, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = _csv_fields(text)
        bad = [p for p in parts if not _is_number(p)]
        if bad:
            # one header line is allowed, before the data, and only if no field is a number
            if not rows and not header_seen and len(bad) == len(parts):
                header_seen = True
                continue
            why = ("only one header line is allowed, before the data" if len(bad) == len(parts)
                   else f"expected two numbers: {columns}")
            # the file may be anything a scene (or an image's embedded scene) names: say where,
            # never what (a line of someone's private file is not quoted back)
            field = parts.index(bad[0]) + 1
            raise error(f"{path}: line {lineno}, field {field} of {len(parts)} is not a number "
                        f"({why})")
        if len(parts) != 2:
            raise error(f"{path}: line {lineno}: expected two columns ({columns}), "
                        f"got {len(parts)}")
        rows.append([float(p) for p in parts])
    return np.asarray(rows, dtype=np.float64).reshape(-1, 2)


@lru_cache(maxsize=64)
def _read_csv_cached(path: str, mtime_ns: int, size: int) -> Spectrum:
    data = read_columns(path)
    if not len(data):
        raise SpectrumError(f"{path}: no spectrum rows (two columns: keV, relative fluence)")
    try:
        return Spectrum(data[:, 0], data[:, 1], kvp=float(data[-1, 0]),
                        description=f"from {os.path.basename(path)}")
    except SpectrumError as exc:
        raise SpectrumError(f"{path}: {exc}") from None


def read_spectrum_csv(path) -> Spectrum:
    r"""Read a two-column CSV spectrum (keV, relative fluence per bin); cached until the file changes.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "s.csv"
    >>> _ = p.write_text("keV,fluence\n50,1\n70,3\n")
    >>> read_spectrum_csv(p).weights.tolist()
    [0.25, 0.75]
    """
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise SceneFileNotFoundError(f"{path}: spectrum file not found") from None
    except OSError as exc:
        raise SpectrumError(f"{path}: cannot read the spectrum file: {exc.strerror}") from None
    if path.is_dir():
        raise SpectrumError(f"{path}: is a directory, not a spectrum CSV file")
    return _read_csv_cached(str(path.resolve()), st.st_mtime_ns, st.st_size)


def _number(d, key, default, *, minimum=0.0, strict=True):
    value = d.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (value <= minimum if strict else value < minimum):
        op = ">" if strict else ">="
        raise SpectrumError(f"spectrum {key} must be a number {op} {minimum:g}, got {value!r}")
    return float(value)


def spectrum_from_dict(spec, *, base_dir=None) -> dict:
    """Validate a ``spectrum`` table and return its canonical form.

    Returns
    -------
    dict
        ``{"kvp", "anode_angle", "filters", "bin", "anode"}`` for a tube spectrum (defaults filled
        in), ``{"quality", "anode_angle", "bin"}`` for an IEC 61267 quality, or
        ``{"file": absolute path}`` for a CSV spectrum (the file is read and checked).

    Warns
    -----
    UnfilteredSpectrumWarning
        A tube spectrum without any filter (or only 0 mm ones): see the module docstring.

    Raises
    ------
    SpectrumError
        Unknown keys, wrong types or values: a ``kvp`` outside the range SpekPy models for the
        anode (:data:`KVP_RANGE`), an ``anode_angle`` outside 0-90 degrees, a filter material
        SpekPy does not know (checked against its material files, without computing the
        spectrum), a malformed CSV file.
    SceneFileNotFoundError
        The CSV file does not exist.

    Notes
    -----
    A tube spectrum is only computed (~0.2 s, plus ~0.7 s to import SpekPy) when first used,
    by :func:`source_spectrum`; validating it here costs microseconds, so
    :func:`~xray_viz.scene_file.load_scene` stays fast. The one error left to that point is a
    filtration that absorbs the whole spectrum.

    Examples
    --------
    >>> spectrum_from_dict({"kvp": 80, "filters": {"Al": 2.5}})["anode_angle"]
    12.0
    >>> spectrum_from_dict({"quality": "RQA5"})
    {'quality': 'RQA5', 'anode_angle': 12.0, 'bin': 1.0}
    """
    d = _validated(spec, base_dir=base_dir)
    if "kvp" in d and not d["filters"]:
        warnings.warn(f"spectrum {{ kvp = {d['kvp']:g} }} has no filtration: a real tube always "
                      "has its inherent filtration (typically 2.5 mm Al equivalent for a "
                      "diagnostic tube); add e.g. filters = { Al = 2.5 }, or use a standard "
                      "beam such as quality = \"RQR5\"", UnfilteredSpectrumWarning,
                      stacklevel=2)
    return d


def _validated(spec, *, base_dir=None) -> dict:
    """:func:`spectrum_from_dict` without its warning (for tables validated before)."""
    if not isinstance(spec, Mapping):
        raise SpectrumError(f"spectrum must be a table such as {{ kvp = 80.0 }} or "
                            f"{{ file = \"spec.csv\" }}, got {spec!r}")
    unknown = sorted(set(spec) - set(SPECTRUM_KEYS))
    if unknown:
        hints = []
        for key in unknown:
            close = difflib.get_close_matches(key, list(SPECTRUM_KEYS), n=1)
            hints.append(f"'{key}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
        raise SpectrumError(f"spectrum has unknown key{'s' if len(unknown) > 1 else ''} "
                            f"{', '.join(hints)}; known keys: {', '.join(SPECTRUM_KEYS)}")
    if "file" in spec:
        extra = sorted(set(spec) - {"file"})
        if extra:
            raise SpectrumError(f"spectrum gives 'file' with {', '.join(extra)}; a CSV spectrum "
                                "takes only 'file'")
        if not isinstance(spec["file"], (str, os.PathLike)):
            raise SpectrumError(f"spectrum file must be a path string, got {spec['file']!r}")
        path = Path(spec["file"])
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        read_spectrum_csv(path)
        return {"file": str(path.resolve())}
    if "quality" in spec:
        return _validated_quality(spec)
    if "kvp" not in spec:
        raise SpectrumError("spectrum needs 'kvp' (tube potential, kV), 'quality' (an IEC 61267 "
                            "radiation quality such as 'RQA5') or 'file' (a CSV spectrum)")
    kvp = _number(spec, "kvp", None, minimum=0.0)
    angle = _anode_angle(spec)
    bin_width = _number(spec, "bin", 1.0, minimum=0.0)
    if bin_width >= kvp:
        raise SpectrumError(f"spectrum bin ({bin_width:g} keV) must be smaller than kvp ({kvp:g})")
    anode = spec.get("anode", "W")
    if anode not in ANODES:
        raise SpectrumError(f"spectrum anode must be one of {', '.join(map(repr, ANODES))}, "
                            f"got {anode!r}")
    lo, hi = KVP_RANGE[anode]
    if not lo <= kvp <= hi:
        raise SpectrumError(f"spectrum kvp = {kvp:g} is outside the {lo:g}-{hi:g} kV that SpekPy "
                            f"models for the {anode} anode")
    filters = spec.get("filters", {})
    if not isinstance(filters, Mapping):
        raise SpectrumError(f"spectrum filters must be a table such as {{ Al = 2.5 }} (mm), "
                            f"got {filters!r}")
    clean = {}
    known = _spekpy_materials()
    for material, mm in filters.items():
        if isinstance(mm, bool) or not isinstance(mm, (int, float)) or not math.isfinite(mm) \
                or mm < 0:
            raise SpectrumError(f"spectrum filter {material} must be a thickness >= 0 mm, got {mm!r}")
        if known is not None and str(material) not in known:
            raise _unknown_filter(str(material), known)
        if mm > 0:
            clean[str(material)] = float(mm)
    return {"kvp": kvp, "anode_angle": angle, "filters": clean, "bin": bin_width, "anode": anode}


def _anode_angle(spec) -> float:
    angle = _number(spec, "anode_angle", 12.0, minimum=0.0)
    if angle >= 90:
        raise SpectrumError(f"spectrum anode_angle must be between 0 and 90 degrees, got {angle:g}")
    return angle


def _validated_quality(spec) -> dict:
    extra = sorted(set(spec) - {"quality", "anode_angle", "bin"})
    if extra:
        raise SpectrumError(f"spectrum gives 'quality' with {', '.join(map(repr, extra))}; an IEC "
                            "61267 quality sets the voltage and the filtration itself and takes "
                            "only 'anode_angle' and 'bin'")
    name = spec["quality"]
    if not isinstance(name, str) or name.replace(" ", "").upper() not in IEC61267_QUALITIES:
        close = difflib.get_close_matches(str(name).replace(" ", "").upper(),
                                          list(IEC61267_QUALITIES), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise SpectrumError(f"spectrum quality {name!r} is not an IEC 61267 radiation quality: "
                            f"{hint}use one of RQR2..RQR10, RQA2..RQA10")
    angle = _anode_angle(spec)
    bin_width = _number(spec, "bin", 1.0, minimum=0.0)
    name = name.replace(" ", "").upper()
    kvp = IEC61267_QUALITIES[name][0]
    if bin_width >= kvp:
        raise SpectrumError(f"spectrum bin ({bin_width:g} keV) must be smaller than the "
                            f"{kvp:g} kV of {name}")
    return {"quality": name, "anode_angle": angle, "bin": bin_width}


def source_spectrum(source) -> Spectrum:
    """The :class:`Spectrum` of a :class:`~xray_viz.scene.Source` (cached).

    ``source.spectrum`` may be a :class:`Spectrum`, a (validated or raw) spectrum table, or None
    for a monochromatic beam of ``source.energy`` keV (60 keV if that is None too).

    Examples
    --------
    >>> import xray_viz
    >>> source_spectrum(xray_viz.load_scene("sphere").source).description
    'monochromatic 60 keV'
    """
    spec = source.spectrum
    if spec is None:
        return _mono_cached(float(source.energy if source.energy is not None else DEFAULT_ENERGY))
    if isinstance(spec, Spectrum):
        return spec
    d = _validated(spec)
    if "file" in d:
        return read_spectrum_csv(d["file"])
    if "quality" in d:
        return _quality_spectrum_cached(d["quality"], d["anode_angle"], d["bin"])
    return _tube_spectrum_cached(d["kvp"], d["anode_angle"], tuple(d["filters"].items()),
                                 d["bin"], d["anode"])


@lru_cache(maxsize=64)
def _mono_cached(energy: float) -> Spectrum:
    return Spectrum.monochromatic(energy)
