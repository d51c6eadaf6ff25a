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
``spectrum = { file = "spec.csv" }``
    Two columns, energy (keV) and relative fluence (photons in that bin), comma, semicolon or
    blank separated, UTF-8 (a byte-order mark is allowed). ``#`` comments and blank lines are
    allowed anywhere, and one header line before the data, none of whose fields is a number;
    any other non-numeric field is an error naming the file and line. The path is relative to
    the scene file. For a fluence *per keV* on a non-uniform grid, multiply by the bin widths
    first.

Every spectrum becomes a :class:`Spectrum`: bin energies and photon-fluence weights that sum to 1.

Examples
--------
>>> s = Spectrum.monochromatic(60.0)
>>> s.energies.tolist(), s.weights.tolist()
([60.0], [1.0])
"""

from __future__ import annotations

import difflib
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from xray_viz.errors import SceneFileNotFoundError, SpectrumError, excerpt

__all__ = ["Spectrum", "tube_spectrum", "read_spectrum_csv", "spectrum_from_dict",
           "source_spectrum", "SPECTRUM_KEYS", "ANODES", "KVP_RANGE"]

#: Keys of a ``spectrum`` table and their meaning.
SPECTRUM_KEYS = {
    "kvp": "tube potential in kV (SpekPy tube spectrum)",
    "anode_angle": "anode angle in degrees (default 12)",
    "filters": "table of filter material = thickness in mm",
    "bin": "energy bin width in keV (default 1)",
    "anode": "anode material, 'W' (default), 'Mo' or 'Rh'",
    "file": "two-column CSV file (keV, relative fluence), relative to the scene file",
}

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
    """

    energies: np.ndarray
    weights: np.ndarray
    kvp: float | None = None
    description: str = ""

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


@lru_cache(maxsize=64)
def _tube_spectrum_cached(kvp, anode_angle, filters, bin_width, anode) -> Spectrum:
    sp = _spekpy()
    try:
        s = sp.Spek(kvp=kvp, th=anode_angle, dk=bin_width, targ=anode)
    except Exception as exc:
        raise SpectrumError(f"SpekPy cannot model kvp = {kvp:g} with anode {anode!r} and "
                            f"anode_angle = {anode_angle:g}: {exc}") from None
    for material, mm in filters:
        try:
            s.filter(material, mm)
        except Exception:
            raise _unknown_filter(material, _spekpy_materials() or ()) from None
    k, fluence = s.get_spectrum()
    keep = fluence > 0
    if not np.any(keep):
        raise SpectrumError(f"the filters {dict(filters)} absorb the whole {kvp:g} kV spectrum")
    desc = f"{kvp:g} kV {anode} anode {anode_angle:g} deg" + "".join(
        f", {mm:g} mm {m}" for m, mm in filters)
    return Spectrum(np.asarray(k)[keep], np.asarray(fluence)[keep], kvp=float(kvp),
                    description=desc)


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
        Bins of zero fluence are dropped.

    Examples
    --------
    >>> s = tube_spectrum(80.0, filters={"Al": 2.5})       # doctest: +SKIP
    >>> round(s.mean_energy, 1)                            # doctest: +SKIP
    42.9
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


@lru_cache(maxsize=64)
def _read_csv_cached(path: str, mtime_ns: int, size: int) -> Spectrum:
    rows = []
    header_seen = False
    try:
        # utf-8-sig: a byte-order mark (as spreadsheet programs write) is not part of line 1
        with open(path, encoding="utf-8-sig") as fh:
            lines = fh.readlines()
    except UnicodeDecodeError as exc:
        raise SpectrumError(f"{path}: not a UTF-8 text file (byte {exc.start}); a spectrum is a "
                            "two-column CSV text file: keV, relative fluence") from None
    except OSError as exc:
        raise SpectrumError(f"{path}: cannot read the spectrum file: {exc.strerror}") from None
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
                   else "expected two numbers: keV, relative fluence")
            # the file may be anything a scene names: quote a short escaped excerpt only
            raise SpectrumError(f"{path}: line {lineno}: {excerpt(bad[0])} is not a number "
                                f"({why})")
        if len(parts) != 2:
            raise SpectrumError(f"{path}: line {lineno}: expected two columns (keV, fluence), "
                                f"got {len(parts)}")
        rows.append([float(p) for p in parts])
    if not rows:
        raise SpectrumError(f"{path}: no spectrum rows (two columns: keV, relative fluence)")
    data = np.asarray(rows)
    try:
        return Spectrum(data[:, 0], data[:, 1], kvp=float(data[-1, 0]),
                        description=f"from {os.path.basename(path)}")
    except SpectrumError as exc:
        raise SpectrumError(f"{path}: {exc}") from None


def read_spectrum_csv(path) -> Spectrum:
    """Read a two-column CSV spectrum (keV, relative fluence per bin); cached until the file changes.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "s.csv"
    >>> _ = p.write_text("keV,fluence\\n50,1\\n70,3\\n")
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
        in), or ``{"file": absolute path}`` for a CSV spectrum (the file is read and checked).

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
    :func:`~xray_viz.scene.load_scene` stays fast. The one error left to that point is a
    filtration that absorbs the whole spectrum.

    Examples
    --------
    >>> spectrum_from_dict({"kvp": 80})["anode_angle"]
    12.0
    """
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
    if "kvp" not in spec:
        raise SpectrumError("spectrum needs 'kvp' (tube potential, kV) or 'file' (a CSV spectrum)")
    kvp = _number(spec, "kvp", None, minimum=0.0)
    angle = _number(spec, "anode_angle", 12.0, minimum=0.0)
    if angle >= 90:
        raise SpectrumError(f"spectrum anode_angle must be between 0 and 90 degrees, got {angle:g}")
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
        return _mono_cached(float(source.energy if source.energy is not None else 60.0))
    if isinstance(spec, Spectrum):
        return spec
    d = spectrum_from_dict(spec)
    if "file" in d:
        return read_spectrum_csv(d["file"])
    return _tube_spectrum_cached(d["kvp"], d["anode_angle"], tuple(d["filters"].items()),
                                 d["bin"], d["anode"])


@lru_cache(maxsize=64)
def _mono_cached(energy: float) -> Spectrum:
    return Spectrum.monochromatic(energy)
