"""Attenuation coefficients of materials, from xraylib (the NIST XCOM photon cross sections).

A material is one of

* a NIST compound as xraylib names it (``"Water, Liquid"``, ``"Bone, Cortical (ICRP)"``,
  ``"Tissue, Soft (ICRP)"``, ``"Adipose Tissue (ICRP)"``, ``"Air, Dry (near sea level)"``, ...;
  :func:`nist_compounds` lists all 180). They carry their own density, which an explicit
  ``density`` overrides;
* one of the ICRU-44 body tissues as NIST tabulates them (:data:`ICRU44_TISSUES`:
  ``"Tissue, Soft (ICRU-44)"``, ``"Bone, Cortical (ICRU-44)"``, ``"Adipose Tissue (ICRU-44)"``,
  ...), with their own density. These are the tissues radiography papers usually mean; xraylib's
  ``(ICRP)`` tissues have other compositions and densities (at 20 keV the ICRU-44 soft tissue
  has a 7.9 % higher mu/rho than "Tissue, Soft (ICRP)", and 1.06 instead of 1.00 g/cm^3;
  cortical bone 4.5 % higher, and 1.92 instead of 1.85 g/cm^3; measured in the tests);
* a chemical formula (``"H2O"``, ``"CaCO3"``, ``"Ca5(PO4)3OH"``) or an element symbol (``"Al"``),
  which need a ``density``;
* a mixture by mass fraction, a mapping ``{component: fraction}`` whose components are any of the
  above and whose fractions sum to 1 (within 1 %); it needs a ``density``. In a scene file::

      material = { "Water, Liquid" = 0.7, "Bone, Cortical (ICRP)" = 0.3 }
      density = 1.25

Names, formulas and symbols are case-sensitive, so that each material has one spelling; an
unknown name fails with the closest valid ones suggested, the right spelling first
(``"water, liquid"`` -> ``'Water, Liquid'``, ``"AL"`` -> ``'Al'``, ``"h2o"`` -> ``'H2O'``; see
:func:`suggest_materials`).

The mass attenuation coefficient is the *total* one with coherent (Rayleigh) scattering,
``mu/rho = sigma_photo + sigma_coherent + sigma_incoherent`` (xraylib ``CS_Total``/``CS_Total_CP``),
which is the "Total Attenuation with Coherent Scattering" column of NIST XCOM; e.g. water at
60 keV, 0.2059 cm^2/g. Mixtures follow the additivity rule ``mu/rho = sum_i w_i (mu/rho)_i``.

Examples
--------
>>> round(float(mass_attenuation("Water, Liquid", 60.0)[0]), 4)
0.2059
>>> round(float(linear_attenuation("Al", [60.0, 100.0], density=2.699)[1]), 3)
0.46
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from functools import lru_cache

import numpy as np

from xray_viz.errors import MaterialError

__all__ = ["ENERGY_RANGE", "mass_attenuation", "mass_scattering", "linear_attenuation",
           "material_density", "check_material", "nist_compounds", "material_key", "suggest_materials",
           "ICRU44_TISSUES"]

#: The body tissues of ICRU Report 44 (1989) as NIST tabulates them (Hubbell and Seltzer, NIST
#: X-Ray Mass Attenuation Coefficients, SRD 126, Table 2; the same compositions as ICRU Report 46
#: gives for these adult tissues): ``name: (density g/cm^3, ((element, mass fraction), ...))``.
#: Their mu/rho is the mass-weighted sum of xraylib's element cross sections, as for NIST's
#: Table 4 of the same names. The compositions agree with the PEGS4 (EGSnrc) copies SpekPy ships
#: as "... (ICRU)" material files (checked in the tests).
ICRU44_TISSUES = {
    "Adipose Tissue (ICRU-44)": (0.95, (("H", 0.114), ("C", 0.598), ("N", 0.007), ("O", 0.278),
                                        ("Na", 0.001), ("S", 0.001), ("Cl", 0.001))),
    "Blood, Whole (ICRU-44)": (1.06, (("H", 0.102), ("C", 0.110), ("N", 0.033), ("O", 0.745),
                                      ("Na", 0.001), ("P", 0.001), ("S", 0.002), ("Cl", 0.003),
                                      ("K", 0.002), ("Fe", 0.001))),
    "Bone, Cortical (ICRU-44)": (1.92, (("H", 0.034), ("C", 0.155), ("N", 0.042), ("O", 0.435),
                                        ("Na", 0.001), ("Mg", 0.002), ("P", 0.103), ("S", 0.003),
                                        ("Ca", 0.225))),
    "Brain, Grey/White Matter (ICRU-44)": (1.04, (("H", 0.107), ("C", 0.145), ("N", 0.022),
                                                  ("O", 0.712), ("Na", 0.002), ("P", 0.004),
                                                  ("S", 0.002), ("Cl", 0.003), ("K", 0.003))),
    "Breast Tissue (ICRU-44)": (1.02, (("H", 0.106), ("C", 0.332), ("N", 0.030), ("O", 0.527),
                                       ("Na", 0.001), ("P", 0.001), ("S", 0.002), ("Cl", 0.001))),
    "Eye Lens (ICRU-44)": (1.07, (("H", 0.096), ("C", 0.195), ("N", 0.057), ("O", 0.646),
                                  ("Na", 0.001), ("P", 0.001), ("S", 0.003), ("Cl", 0.001))),
    "Lung Tissue (ICRU-44)": (1.05, (("H", 0.103), ("C", 0.105), ("N", 0.031), ("O", 0.749),
                                     ("Na", 0.002), ("P", 0.002), ("S", 0.003), ("Cl", 0.003),
                                     ("K", 0.002))),
    "Muscle, Skeletal (ICRU-44)": (1.05, (("H", 0.102), ("C", 0.143), ("N", 0.034), ("O", 0.710),
                                          ("Na", 0.001), ("P", 0.002), ("S", 0.003), ("Cl", 0.001),
                                          ("K", 0.004))),
    "Ovary (ICRU-44)": (1.05, (("H", 0.105), ("C", 0.093), ("N", 0.024), ("O", 0.768),
                               ("Na", 0.002), ("P", 0.002), ("S", 0.002), ("Cl", 0.002),
                               ("K", 0.002))),
    "Testis (ICRU-44)": (1.04, (("H", 0.106), ("C", 0.099), ("N", 0.020), ("O", 0.766),
                                ("Na", 0.002), ("P", 0.001), ("S", 0.002), ("Cl", 0.002),
                                ("K", 0.002))),
    "Tissue, Soft (ICRU-44)": (1.06, (("H", 0.102), ("C", 0.143), ("N", 0.034), ("O", 0.708),
                                      ("Na", 0.002), ("P", 0.003), ("S", 0.003), ("Cl", 0.002),
                                      ("K", 0.003))),
}


def _xraylib():
    try:
        import xraylib
    except ImportError:  # pragma: no cover - xraylib is a dependency
        raise MaterialError("materials need xraylib: pip install xraylib") from None
    return xraylib


@lru_cache(maxsize=1)
def nist_compounds() -> tuple[str, ...]:
    """Names of the NIST compounds xraylib knows (``GetCompoundDataNISTList``)."""
    return tuple(_xraylib().GetCompoundDataNISTList())


def material_key(material):
    """A hashable, canonical form of a material: a string, or a sorted tuple of (name, fraction).

    Examples
    --------
    >>> material_key({"H2O": 0.5, "Al": 0.5})
    (('Al', 0.5), ('H2O', 0.5))
    """
    if isinstance(material, str):
        return material
    pairs = None
    if isinstance(material, Mapping):
        pairs = list(material.items())
    elif isinstance(material, tuple) and all(isinstance(p, tuple) and len(p) == 2
                                             for p in material):
        pairs = list(material)
    if pairs is not None:
        for name, frac in pairs:
            if not isinstance(name, str):
                raise MaterialError(f"mixture component names must be strings, got {name!r}")
            if isinstance(frac, (bool, np.bool_)) or not isinstance(
                    frac, (int, float, np.integer, np.floating)):
                raise MaterialError(f"mixture component {name!r} has mass fraction {frac!r}; "
                                    "fractions must be numbers")
        return tuple(sorted((k, float(v)) for k, v in pairs))
    raise MaterialError(f"material must be a name, a formula or a table of mass fractions, "
                        f"got {material!r}")


#: NIST compounds most often meant, suggested first among equally good matches.
COMMON_COMPOUNDS = ("Water, Liquid", "Tissue, Soft (ICRP)", "Bone, Cortical (ICRP)",
                    "Adipose Tissue (ICRP)", "Muscle, Skeletal", "Lung (ICRP)", "Blood (ICRP)",
                    "Brain (ICRP)", "Skin (ICRP)", "Air, Dry (near sea level)",
                    "Polymethyl Methacralate (Lucite, Perspex)", "Polyethylene",
                    "Tissue, Soft (ICRU-44)", "Bone, Cortical (ICRU-44)",
                    "Adipose Tissue (ICRU-44)", "Muscle, Skeletal (ICRU-44)")

#: Elements offered in a case-corrected formula of several elements: Z <= 56 and the heavy
#: elements of common detector, contrast and shielding compounds, no noble gases (so that
#: "fat" does not become 'FAt', nor "bone" 'BONe').
_FORMULA_ELEMENTS = frozenset(range(1, 57)) - {2, 10, 18, 36, 54} | {57, 58, 64, 71, 74, 78, 79,
                                                                     80, 81, 82, 83, 92}


@lru_cache(maxsize=1)
def _element_symbols() -> dict[str, tuple[str, int]]:
    """``{"al": ("Al", 13), ...}`` for Z = 1..92 (xraylib ``AtomicNumberToSymbol``)."""
    xrl = _xraylib()
    return {xrl.AtomicNumberToSymbol(z).lower(): (xrl.AtomicNumberToSymbol(z), z)
            for z in range(1, 93)}


def _formula_spellings(name: str, *, limit: int = 3) -> list[str]:
    """Chemical formulas that differ from ``name`` at most in letter case and that xraylib's
    ``CompoundParser`` accepts, lightest elements first (``"h2o"`` -> ``["H2O"]``,
    ``"AL"`` -> ``["Al"]``); at most ``limit``.

    Examples
    --------
    >>> _formula_spellings("caco3")
    ['CaCO3', 'CaCo3']
    """
    if not name or len(name) > 40 or not all(c.isalnum() or c in "()[]." for c in name):
        return []
    symbols = _element_symbols()
    found: list[tuple[tuple[str, ...], str]] = []

    def walk(i: int, text: str, used: tuple[str, ...]):
        if len(found) >= 64:
            return
        if i == len(name):
            found.append((used, text))
            return
        if not name[i].isalpha():
            walk(i + 1, text + name[i], used)
            return
        for n in (1, 2):
            sym = symbols.get(name[i:i + n].lower()) if name[i:i + n].isalpha() else None
            if sym and len(name[i:i + n]) == n:
                walk(i + n, text + sym[0], used + (sym[0],))

    walk(0, "", ())
    xrl = _xraylib()
    out = []
    for used, text in found:
        if not used:
            continue
        if len(set(used)) > 1 and any(symbols[u.lower()][1] not in _FORMULA_ELEMENTS
                                      for u in used):
            continue
        try:
            xrl.CompoundParser(text)
        except ValueError:
            continue
        out.append((sum(symbols[u.lower()][1] for u in set(used)), text))
    return [text for _, text in sorted(set(out))][:limit]


def _words(text: str) -> list[str]:
    return [w for w in "".join(c.lower() if c.isalnum() else " " for c in text).split()]


def suggest_materials(name: str, *, n: int = 3) -> list[str]:
    """Valid material names close to an unknown ``name``, best first.

    In order: the element symbol or formula with its letter case corrected (``"al"`` -> ``'Al'``,
    ``"h2o"`` -> ``'H2O'``); NIST compounds equal to ``name`` but for case and punctuation;
    NIST compounds that contain every word of ``name`` (common tissues first); then, only if
    none of those exist, difflib's closest NIST names.

    Examples
    --------
    >>> suggest_materials("water")
    ['Water, Liquid', 'Water Vapor']
    >>> suggest_materials("AL")
    ['Al']
    >>> suggest_materials("h2o")
    ['H2O']
    """
    names = nist_compounds() + tuple(ICRU44_TISSUES)
    key = name.strip()
    words = _words(key)
    out: list[str] = []
    compact = key.replace(" ", "")
    is_symbol = compact.lower() in _element_symbols()
    formula_like = any(c.isdigit() or c in "()[]" for c in compact)
    if is_symbol or formula_like:
        out += _formula_spellings(compact)
    exact = [c for c in names if _words(c) == words and words]
    rank = {c: i for i, c in enumerate(COMMON_COMPOUNDS)}
    containing = sorted(
        (c for c in names if c not in exact and words
         and all(any(cw.startswith(w) if len(w) >= 3 else cw == w for cw in _words(c))
                 for w in words)),
        key=lambda c: (rank.get(c, len(rank)), not _words(c)[0].startswith(words[0]), len(c), c))
    out += exact + containing
    if not (is_symbol or formula_like) and not exact and not containing:
        out += _formula_spellings(compact)
    if not out:
        lower = {c.lower(): c for c in names}
        out += [lower[c] for c in difflib.get_close_matches(key.lower(), list(lower), n=n,
                                                            cutoff=0.5)]
    seen = []
    for c in out:
        if c not in seen and c != name:
            seen.append(c)
    return seen[:n]


@lru_cache(maxsize=512)
def _resolve_name(name: str):
    """``("nist", name, density)`` or ``("formula", name, None)``; MaterialError if neither.

    Names are exact: a NIST compound spelled with other letter case, an element or formula
    with wrong case (``"AL"``, ``"h2o"``) is refused, with the right spelling suggested first.
    """
    xrl = _xraylib()
    if name in ICRU44_TISSUES:
        return ("icru44", name, ICRU44_TISSUES[name][0])
    if name in nist_compounds():
        return ("nist", name, float(xrl.GetCompoundDataNISTByName(name)["density"]))
    try:
        xrl.CompoundParser(name)
        return ("formula", name, None)
    except ValueError:
        pass
    close = suggest_materials(name)
    hint = (f"did you mean {', '.join(map(repr, close))}? " if close else "")
    raise MaterialError(
        f"unknown material {name!r}: {hint}use a NIST compound name (xray_viz.physics.materials."
        f"nist_compounds() lists them), an ICRU-44 tissue such as 'Tissue, Soft (ICRU-44)', a "
        f"chemical formula such as 'H2O' or an element such as 'Al'"
        " (names and symbols are case-sensitive)"
    )


def _check_mixture(key):
    if not key:
        raise MaterialError("a mixture needs at least one component")
    for name, frac in key:
        if not (np.isfinite(frac) and frac > 0):
            raise MaterialError(f"mixture component {name!r} has mass fraction {frac:g}; "
                                "fractions must be > 0")
        _resolve_name(name)
    total = sum(f for _, f in key)
    if abs(total - 1.0) > 0.01:
        raise MaterialError(f"mixture mass fractions sum to {total:g}; they must sum to 1")


def material_density(material) -> float | None:
    """The tabulated density (g/cm^3) of a NIST compound, or None for formulas and mixtures.

    Examples
    --------
    >>> material_density("Bone, Cortical (ICRP)")
    1.85
    >>> material_density("H2O") is None
    True
    """
    key = material_key(material)
    if isinstance(key, tuple):
        _check_mixture(key)
        return None
    kind, _, density = _resolve_name(key)
    return density


def check_material(material, *, density=None) -> float:
    """Validate a material and return the density (g/cm^3) that will be used.

    Raises
    ------
    MaterialError
        Unknown name (with the closest valid names suggested), bad mixture, or a formula,
        element or mixture without a density.

    Examples
    --------
    >>> check_material("Water, Liquid")
    1.0
    >>> check_material("CaCO3", density=2.71)
    2.71
    """
    if density is not None:
        density = float(density)
        if not (np.isfinite(density) and density > 0):
            raise MaterialError(f"material {material!r}: density must be > 0 g/cm3, got {density:g}")
        material_density(material)  # validates the name
        return density
    tabulated = material_density(material)
    if tabulated is None:
        what = "a mixture" if not isinstance(material, str) else "a chemical formula or element"
        example = "density = 1.0 for water"
        if isinstance(material, str):
            xrl = _xraylib()
            try:
                z = xrl.SymbolToAtomicNumber(material)
                example = f"density = {xrl.ElementDensity(z):g} for solid {material}"
            except ValueError:
                pass                       # a formula: no tabulated density to suggest
        raise MaterialError(f"material {material!r} is {what}: give its density in g/cm3 "
                            f"(e.g. {example})")
    return tabulated


#: Photon energies (keV) at which xraylib has the cross sections of every element Z = 1..98:
#: its photoelectric, Rayleigh and Compton tables are splines in ln E that refuse to
#: extrapolate ("Spline extrapolation is not allowed", xraylib >= 4.0); the scattering tables
#: run from 100 eV to 800 keV (measured with xraylib 4.3: 0.1 and 800 keV are accepted for
#: every Z, 0.09999 and 800.03 keV refused; tests/scene/test_validation.py checks it).
ENERGY_RANGE = (0.1, 800.0)


def _energies(energies_kev) -> np.ndarray:
    try:
        e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
    except (TypeError, ValueError, OverflowError):
        raise MaterialError(f"photon energies must be numbers in keV, "
                            f"got {energies_kev!r}"[:200]) from None
    if e.ndim != 1 or not np.all(np.isfinite(e)) or np.any(e <= 0):
        raise MaterialError(f"photon energies must be finite and > 0 keV, got {e.tolist()[:5]}")
    lo, hi = ENERGY_RANGE
    if e.min() < lo or e.max() > hi:
        out = e[(e < lo) | (e > hi)]
        raise MaterialError(
            f"photon energ{'y' if len(out) == 1 else 'ies'} {', '.join(f'{x:g}' for x in out[:3])}"
            f"{' ...' if len(out) > 3 else ''} keV outside {lo:g}-{hi:g} keV, the range of "
            f"xraylib's attenuation tables: use energies in that range for bodies of a material "
            f"(a body of constant mu takes any energy)")
    return e


@lru_cache(maxsize=1024)
def _mass_attenuation_cached(key, energies: tuple) -> np.ndarray:
    if isinstance(key, tuple):
        out = sum(frac * _mass_attenuation_cached(name, energies) for name, frac in key)
        out = out / sum(f for _, f in key)
    else:
        kind, name, _ = _resolve_name(key)
        if kind == "icru44":
            return _icru44_mass_attenuation(name, energies)
        cs = _xraylib().CS_Total_CP
        out = np.array([cs(name, e) for e in energies])
    out.setflags(write=False)
    return out


def _icru44_mass_attenuation(name: str, energies: tuple) -> np.ndarray:
    """mu/rho of an ICRU-44 tissue: its elements' xraylib cross sections by mass fraction."""
    elements = ICRU44_TISSUES[name][1]
    out = sum(w * _mass_attenuation_cached(sym, energies) for sym, w in elements)
    out = out / sum(w for _, w in elements)
    out.setflags(write=False)
    return out


def _checked(material, energies_kev):
    """``(key, energies)`` of a material known to xraylib (a mixture's fractions checked)
    and its energies as an array: what the cached coefficients are looked up by."""
    key = material_key(material)
    if isinstance(key, tuple):
        _check_mixture(key)
    else:
        _resolve_name(key)
    return key, _energies(energies_kev)


def mass_attenuation(material, energies_kev) -> np.ndarray:
    """Mass attenuation coefficient ``mu/rho`` in cm^2/g (total, with coherent scattering).

    Parameters
    ----------
    material : str or mapping of str to float
        NIST compound name, chemical formula, element symbol, or mass-fraction mixture.
    energies_kev : float or (n,) float
        Photon energies in keV.

    Returns
    -------
    (n,) float
        Read-only; cached per material and energy grid.

    Examples
    --------
    >>> round(float(mass_attenuation("Al", 100.0)[0]), 4)
    0.1704
    """
    key, e = _checked(material, energies_kev)
    return _mass_attenuation_cached(key, tuple(e.tolist()))


#: Polar angles (midpoints) of the cone integral of :func:`mass_scattering`, per radian of
#: the cone's half-angle.
_CONE_STEPS = 240


@lru_cache(maxsize=1024)
def _mass_scattering_cached(key, energies: tuple, cone, process=None) -> np.ndarray:
    if isinstance(key, tuple):
        out = sum(frac * _mass_scattering_cached(name, energies, cone, process)
                  for name, frac in key)
        out = out / sum(f for _, f in key)
    else:
        kind, name, _ = _resolve_name(key)
        xrl = _xraylib()
        whole = {None: (xrl.CS_Compt_CP, xrl.CS_Rayl_CP), "coherent": (xrl.CS_Rayl_CP,),
                 "incoherent": (xrl.CS_Compt_CP,)}[process]
        parts = {None: (xrl.DCS_Compt_CP, xrl.DCS_Rayl_CP), "coherent": (xrl.DCS_Rayl_CP,),
                 "incoherent": (xrl.DCS_Compt_CP,)}[process]
        if kind == "icru44":
            elements = ICRU44_TISSUES[name][1]
            out = sum(w * _mass_scattering_cached(sym, energies, cone, process)
                      for sym, w in elements)
            out = out / sum(w for _, w in elements)
        elif cone is None:
            out = np.array([sum(f(name, e) for f in whole) for e in energies])
        else:
            # the differential cross sections integrated over the cone (midpoint rule)
            n = max(16, int(np.ceil(_CONE_STEPS * cone)))
            theta = (np.arange(n) + 0.5) * (cone / n)
            solid = 2.0 * np.pi * np.sin(theta) * (cone / n)
            out = np.array([sum(w * sum(f(name, e, t) for f in parts)
                                for t, w in zip(theta.tolist(), solid.tolist()))
                            for e in energies])
    out.setflags(write=False)
    return out


def mass_scattering(material, energies_kev, *, cone=None, process=None) -> np.ndarray:
    """The scattering part of :func:`mass_attenuation`: incoherent plus coherent ``mu/rho``
    in cm^2/g (xraylib ``CS_Compt_CP + CS_Rayl_CP``), without the photoelectric absorption.

    Parameters
    ----------
    material : str or mapping of str to float
        See :func:`mass_attenuation`.
    energies_kev : float or (n,) float
        Photon energies in keV.
    cone : float, optional
        Only the photons scattered by less than this angle (radians, in (0, pi]): the
        differential cross sections (``DCS_Compt_CP + DCS_Rayl_CP``) integrated over the
        cone. Coherent scattering is forward-peaked, so a narrow cone weighs it more.
    process : {None, "coherent", "incoherent"}, optional
        One of the two processes only (default both).

    Returns
    -------
    (n,) float
        Read-only; cached per material and energy grid.

    Examples
    --------
    >>> round(float(mass_scattering("Water, Liquid", 60.0)[0]), 4)
    0.1909
    >>> round(float(mass_scattering("Al", 60.0)[0] / mass_attenuation("Al", 60.0)[0]), 3)
    0.656
    >>> whole = mass_scattering("Water, Liquid", 60.0, cone=np.pi)[0]    # the same, about
    >>> bool(abs(whole / mass_scattering("Water, Liquid", 60.0)[0] - 1) < 0.1)
    True
    >>> round(float(mass_scattering("Al", 60.0, cone=0.2, process="coherent")[0]
    ...             / mass_scattering("Al", 60.0, cone=0.2)[0]), 2)     # forward: coherent
    0.92
    """
    key, e = _checked(material, energies_kev)
    if process not in (None, "coherent", "incoherent"):
        raise MaterialError(f"scattering process {process!r}: choose 'coherent', "
                            "'incoherent' or None (both)")
    if cone is not None:
        cone = float(cone)
        if not 0.0 < cone <= np.pi:
            raise MaterialError(f"scattering cone {cone!r} rad outside (0, pi]: give the "
                                "cone's half-angle in radians")
    return _mass_scattering_cached(key, tuple(e.tolist()), cone, process)


def linear_attenuation(material, energies_kev, *, density=None) -> np.ndarray:
    """Linear attenuation coefficient ``mu`` in 1/cm: ``mu/rho * density``.

    Parameters
    ----------
    material : str or mapping of str to float
        See :func:`mass_attenuation`.
    energies_kev : float or (n,) float
        Photon energies in keV.
    density : float, optional
        g/cm^3. Required for formulas, elements and mixtures; overrides a NIST compound's own.

    Returns
    -------
    (n,) float

    Examples
    --------
    >>> round(float(linear_attenuation("Water, Liquid", 60.0)[0]), 4)
    0.2059
    >>> linear_attenuation("H2O", 60.0)
    Traceback (most recent call last):
    ...
    xray_viz.errors.MaterialError: material 'H2O' is a chemical formula or element: give its density in g/cm3 (e.g. density = 1.0 for water)
    """
    rho = check_material(material, density=density)
    return mass_attenuation(material, energies_kev) * rho
