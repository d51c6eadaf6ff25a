"""Dosimetry: air kerma, half-value layers, photons per mAs and entrance air kerma.

Air kerma
---------
The air kerma of a photon fluence ``Phi_k`` (photons per area) at energies ``E_k`` is

    K = sum_k Phi_k E_k (mu_en / rho)_air(E_k)

with ``(mu_en/rho)_air`` the mass energy-absorption coefficient of dry air
(:func:`air_mass_energy_absorption`). Its values are NIST's: Hubbell J. H. and Seltzer S. M.,
*Tables of X-Ray Mass Attenuation Coefficients and Mass Energy-Absorption Coefficients from 1 keV
to 20 MeV for Elements Z = 1 to 92 and 48 Additional Substances of Dosimetric Interest*, NIST
Standard Reference Database 126 (NISTIR 5632, 1995, updated 2004), Table 4, "Air, Dry (near sea
level)" (:data:`MUEN_AIR_NIST`). xraylib's own energy-absorption coefficients (``CS_Energy_CP``)
are not used: for air they are 34 % low at 20 keV, 18 % at 15 keV, 9 % at 50 keV and 11 % high
at 1 MeV (measured in the tests; xraylib issues #176, #255). Between the tabulated energies the
table is interpolated by a cubic spline in ``log E``-``log mu_en`` on each side of argon's K edge
(3.2029 keV): linear log-log interpolation, as SpekPy does, bulges by up to 3-4 % between the
coarse nodes around the minimum of ``mu_en`` (35 and 70 keV), where the spline stays within a
fraction of a per cent of the fine-grid PENELOPE table SpekPy ships (checked in the tests).

Half-value layers
-----------------
:func:`hvl` gives the first and second half-value layers and the homogeneity coefficient of a
spectrum, defined on air kerma (as the IEC standards and every dosimetry protocol define them;
HVLs of the energy fluence or of the photon count are 1.3-1.9 times larger for RQR beams), with
the attenuation coefficients of :mod:`~xray_viz.physics.materials` (xraylib), the data set the
bodies and the tube filters use.

Dose and photon numbers
-----------------------
A SpekPy tube spectrum carries its absolute output: photons per mm^2 per mAs at 1 m from the
focal spot (:attr:`~xray_viz.physics.spectra.Spectrum.fluence_per_mas`). With ``[source] mas``
the unattenuated photons per pixel follow from it by the inverse square law and the pixel area
(:func:`photons_per_pixel`), and :func:`air_kerma` reports the incident air kerma (free in air,
no backscatter) at the body surface nearest to the focal spot and at the detector.

What an image includes
----------------------
:data:`SCATTER_SCOPE` (:func:`scatter_scope`): a render is the primary radiation alone unless
scatter is asked for (``render(scene, scatter="mc" | "kernel")``); see BENCHMARKS.md,
"Scatter in the images".

Examples
--------
>>> float(air_mass_energy_absorption(60.0)[0])        # NIST Table 4, dry air, 60 keV
0.03041
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from xray_viz.errors import SpectrumError
from xray_viz.physics._air import (AIR_K_EDGE_KEV, KEV_TO_JOULE, MUEN_AIR_NIST,  # noqa: F401
                                   _half_value_layers, air_mass_energy_absorption)

__all__ = ["MUEN_AIR_NIST", "AIR_K_EDGE_KEV", "KEV_TO_JOULE", "SCATTER_SCOPE", "scatter_scope",
           "air_mass_energy_absorption", "kerma_weights", "air_kerma_per_mas",
           "HalfValueLayers", "hvl", "photons_per_pixel", "centre_pixel_photons", "AirKerma",
           "air_kerma"]

#: What an image includes, by its ``scatter`` mode (None, ``"mc"``, ``"kernel"``), for result
#: metadata (``Radiograph.scope``, the files' descriptions) and documentation.
SCATTER_SCOPE = {
    None: ("primary radiation only: scattered photons (Compton and Rayleigh) are removed from "
           "the beam but not detected (render with scatter='mc' or 'kernel' to add them); at "
           "80 kVp without a grid scatter adds 1-40 % of the primary signal for the bundled "
           "phantoms and about 3 times the primary behind 20 cm of water in a 30 x 30 cm "
           "field (see BENCHMARKS.md, 'Scatter in the images')"),
    "mc": ("primary plus scatter from the photon Monte Carlo (xray_viz.transport) on the "
           "scene's meshes: photoelectric absorption, incoherent (Klein-Nishina x S) and "
           "coherent (Thomson x F^2) scattering, single and multiple, to a 1 keV cut-off, "
           "no fluorescence; its statistical error falls as 1/sqrt(histories) (see "
           "BENCHMARKS.md, 'Scatter in the images')"),
    "kernel": ("primary plus scatter from the scatter kernel model "
               "(xray_viz.scatter_kernel), calibrated on the photon Monte Carlo; its error "
               "against the Monte Carlo is in BENCHMARKS.md, 'Scatter kernel model'"),
}


def scatter_scope(mode=None) -> str:
    """What an image rendered with ``scatter=mode`` includes (:data:`SCATTER_SCOPE`).

    Examples
    --------
    >>> scatter_scope(None).startswith("primary radiation only")
    True
    """
    if mode == "none":
        mode = None
    return SCATTER_SCOPE[mode]

def kerma_weights(spectrum) -> np.ndarray:
    """Air-kerma weight of each bin, ``phi_k E_k (mu_en/rho)_air(E_k)``, normalised to sum 1.

    Examples
    --------
    >>> from xray_viz.physics.spectra import Spectrum
    >>> w = kerma_weights(Spectrum([20.0, 60.0], [1.0, 1.0]))
    >>> round(float(w[0]), 4)                     # 20 * 0.5389 / (20 * 0.5389 + 60 * 0.03041)
    0.8552
    """
    e = np.asarray(spectrum.energies, dtype=np.float64)
    w = np.asarray(spectrum.weights, dtype=np.float64) * e * air_mass_energy_absorption(e)
    return w / w.sum()


def _kerma_uGy(energies_kev, fluence_per_mm2, muen=None) -> float:
    """Air kerma in uGy of a fluence spectrum given in photons per mm^2 per bin."""
    e = np.asarray(energies_kev, dtype=np.float64)
    muen = air_mass_energy_absorption(e) if muen is None else np.asarray(muen, dtype=np.float64)
    # photons/mm^2 -> /cm^2 (x 100); keV -> J; cm^2/g -> cm^2/kg (x 1000); Gy -> uGy (x 1e6)
    return float(np.sum(np.asarray(fluence_per_mm2) * 100.0 * e * KEV_TO_JOULE * muen * 1e3)
                 * 1e6)


def _absolute_spectrum(spectrum):
    """``spectrum`` as a :class:`Spectrum` that knows its photons per mAs, or SpectrumError."""
    from xray_viz.physics.spectra import Spectrum, source_spectrum

    if not isinstance(spectrum, Spectrum):
        spectrum = source_spectrum(_AsSource(spectrum))
    if spectrum.fluence_per_mas is None:
        raise SpectrumError(f"the spectrum ({spectrum.description or 'user spectrum'}) has no "
                            "absolute output: photons per mAs come from SpekPy tube spectra "
                            "(spectrum = { kvp = ... } or { quality = ... }); give [detector] "
                            "I0 instead")
    return spectrum


@dataclass(frozen=True)
class _AsSource:
    spectrum: object
    energy: float | None = None


def air_kerma_per_mas(spectrum, *, distance_mm: float = 1000.0) -> float:
    """Incident air kerma in uGy per mAs at ``distance_mm`` from the focal spot.

    ``fluence_per_mas * (1000 / distance)^2`` photons per mm^2 with the spectrum's weights,
    weighted by ``E (mu_en/rho)_air``; free in air (no backscatter, no air attenuation).

    Parameters
    ----------
    spectrum : Spectrum or spectrum table
        A SpekPy tube spectrum (or a table such as ``{"kvp": 80, "filters": {"Al": 2.5}}``).
    distance_mm : float

    Returns
    -------
    float
    """
    s = _absolute_spectrum(spectrum)
    if not (math.isfinite(distance_mm) and distance_mm > 0):
        raise SpectrumError(f"distance must be > 0 mm, got {distance_mm!r}")
    fluence = s.weights * s.fluence_per_mas * (1000.0 / distance_mm) ** 2
    return _kerma_uGy(s.energies, fluence)


# --------------------------------------------------------------------------------------------
# half-value layers


@dataclass(frozen=True)
class HalfValueLayers:
    """First and second half-value layers of a spectrum, on air kerma.

    Attributes
    ----------
    hvl1 : float
        mm of ``material`` that halve the air kerma.
    hvl2 : float
        mm more that halve it again (``QVL - HVL1``).
    homogeneity : float
        ``hvl1 / hvl2`` (1 for a monochromatic beam, < 1 for a beam that hardens).
    material : str
    density : float
        g/cm^3 used.
    """

    hvl1: float
    hvl2: float
    homogeneity: float
    material: str
    density: float


def hvl(spectrum, material="Al", *, density: float | None = None) -> HalfValueLayers:
    """First and second half-value layers and the homogeneity coefficient, on air kerma.

    Parameters
    ----------
    spectrum : Spectrum or spectrum table
        Any :class:`~xray_viz.physics.spectra.Spectrum`, or a table such as
        ``{"kvp": 80, "filters": {"Al": 2.5}}`` or ``{"quality": "RQR5"}``.
    material : str or mapping, default "Al"
        Any material of :mod:`~xray_viz.physics.materials`.
    density : float, optional
        g/cm^3; default the tabulated density: a NIST compound's own, or xraylib's density of
        the solid element for an element symbol (Al: 2.699, NIST's value).

    Returns
    -------
    HalfValueLayers

    Notes
    -----
    Narrow-beam geometry: ``K(t) = sum_k phi_k E_k (mu_en/rho)_air(E_k) exp(-mu(E_k) t)``;
    ``HVL1`` solves ``K(HVL1) = K(0) / 2`` and ``HVL1 + HVL2`` solves ``K = K(0) / 4`` (Brent's
    method to 1e-13 relative). The attenuation is xraylib's (:mod:`~xray_viz.physics.materials`),
    the same data as the bodies' and the tube filters'.

    Examples
    --------
    >>> from xray_viz.physics.spectra import Spectrum
    >>> h = hvl(Spectrum.monochromatic(60.0))       # ln 2 / mu of Al at 60 keV
    >>> round(h.hvl1, 3), round(h.homogeneity, 12)
    (9.245, 1.0)
    """
    from xray_viz.physics.materials import check_material, linear_attenuation
    from xray_viz.physics.spectra import Spectrum, source_spectrum

    s = spectrum if isinstance(spectrum, Spectrum) else source_spectrum(_AsSource(spectrum))
    rho = _default_density(material) if density is None else float(density)
    rho = check_material(material, density=rho)
    mu = linear_attenuation(material, s.energies, density=rho) / 10.0        # 1/mm
    h1, h2 = _half_value_layers(s.energies, s.weights, mu)
    name = material if isinstance(material, str) else str(dict(material))
    return HalfValueLayers(hvl1=h1, hvl2=h2, homogeneity=h1 / h2, material=name, density=rho)


def _default_density(material) -> float | None:
    """A NIST compound's density, or the solid element's (xraylib ``ElementDensity``)."""
    from xray_viz.physics.materials import material_density

    rho = material_density(material)
    if rho is None and isinstance(material, str):
        import xraylib

        try:
            rho = float(xraylib.ElementDensity(xraylib.SymbolToAtomicNumber(material)))
        except ValueError:
            rho = None
    return rho


# --------------------------------------------------------------------------------------------
# photons per pixel and air kerma of a scene


def photons_per_pixel(spectrum, mas: float, *, distance_mm: float, pixel_area_mm2: float) -> float:
    """Unattenuated photons on one pixel of ``pixel_area_mm2`` facing the focal spot.

    ``fluence_per_mas * mas * (1000 / distance)^2 * pixel_area``: the tube output per mAs at
    1 m (SpekPy's reference distance), the inverse square law and the pixel area. Off-axis
    pixels also see the obliquity ``cos(theta)``; the scene's ``falloff`` applies both, as
    ``cos^3(theta)``, relative to the detector centre.

    Examples
    --------
    >>> from xray_viz.physics.spectra import Spectrum
    >>> s = Spectrum([50.0], [1.0], fluence_per_mas=2.0e4)     # photons/mm^2/mAs at 1 m
    >>> photons_per_pixel(s, 10.0, distance_mm=2000.0, pixel_area_mm2=0.25)
    12500.0
    """
    s = _absolute_spectrum(spectrum)
    for name, value in (("mas", mas), ("distance", distance_mm), ("pixel area", pixel_area_mm2)):
        if isinstance(value, bool) or not (math.isfinite(value) and value > 0):
            raise SpectrumError(f"{name} must be > 0, got {value!r}")
    return float(s.fluence_per_mas * mas * (1000.0 / distance_mm) ** 2 * pixel_area_mm2)


def centre_pixel_photons(spectrum, mas: float, *, kind: str, source, center, pitch) -> float:
    """The ``I0`` of a detector for ``mas``: unattenuated photons on its centre pixel.

    :func:`photons_per_pixel` at the source-detector distance with the pixel area
    ``pitch[0] * pitch[1]``; the scene file sets ``[detector] I0`` to it when ``[source]``
    gives ``mas`` (and turns ``falloff`` on unless told otherwise, so that every other pixel
    gets its inverse square and obliquity).

    Parameters
    ----------
    spectrum : Spectrum, spectrum table or None
        A SpekPy tube spectrum (None, a monochromatic beam, has no tube output).
    mas : float
    kind : {"point", "parallel"}
    source, center : (3,) float
        Focal spot and detector centre (mm).
    pitch : (2,) float
        mm.

    Raises
    ------
    SpectrumError
        A parallel beam, no tube spectrum, or a CSV spectrum (no absolute output).
    """
    if kind != "point":
        raise SpectrumError("mas needs a point source (kind = \"point\"): the tube output per "
                            "mAs falls off with distance from a focal spot")
    if spectrum is None:
        raise SpectrumError("mas needs a tube spectrum, spectrum = { kvp = ..., filters = ... } "
                            "or { quality = \"RQA5\" }: a monochromatic energy has no tube "
                            "output per mAs; give [detector] I0 instead")
    sid = float(np.linalg.norm(np.asarray(source, float) - np.asarray(center, float)))
    px, py = (float(p) for p in np.broadcast_to(np.asarray(pitch, float), (2,)))
    return photons_per_pixel(spectrum, mas, distance_mm=sid, pixel_area_mm2=px * py)


@dataclass(frozen=True)
class AirKerma:
    """Incident air kerma of a scene's exposure (free in air: no backscatter, no air).

    Attributes
    ----------
    entrance_uGy : float or None
        At the point of the bodies' surfaces nearest to the focal spot (None without bodies).
    detector_uGy : float
        At the detector centre, without the bodies (the unattenuated beam).
    entrance_distance_mm, detector_distance_mm : float or None, float
        Distances from the focal spot.
    mas : float
    per_mas_at_1m_uGy : float
        The tube's output, uGy per mAs at 1 m.
    """

    entrance_uGy: float | None
    detector_uGy: float
    entrance_distance_mm: float | None
    detector_distance_mm: float
    mas: float
    per_mas_at_1m_uGy: float


def _closest_distance(points_source, tris) -> float:
    """Smallest distance from a point to a set of (T, 3, 3) triangles (Ericson's regions)."""
    p = np.asarray(points_source, dtype=np.float64)
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        q = a + ab * v[:, None] + ac * w[:, None]                       # inside the face
        t_ab = np.clip(d1 / (d1 - d3), 0, 1)
        t_ac = np.clip(d2 / (d2 - d6), 0, 1)
        t_bc = np.clip((d4 - d3) / ((d4 - d3) + (d5 - d6)), 0, 1)
    q = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], a + ab * t_ab[:, None], q)
    q = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], a + ac * t_ac[:, None], q)
    q = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[:, None],
                 b + (c - b) * t_bc[:, None], q)
    q = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, q)
    q = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, q)
    q = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, q)
    return float(np.sqrt(np.min(np.einsum("ij,ij->i", p - q, p - q))))


def air_kerma(scene) -> AirKerma:
    """Incident air kerma at the bodies' nearest surface and at the detector, for ``mas``.

    A public adapter (``xray_viz.physics.air_kerma(scene)`` in the README) over the scene's
    acquisition and bodies.

    Parameters
    ----------
    scene : Scene
        A point source with ``mas`` and a SpekPy tube spectrum.

    Returns
    -------
    AirKerma

    Raises
    ------
    SpectrumError
        Without ``mas``, for a parallel beam, or a spectrum without absolute output.

    Notes
    -----
    ``K(d) = K_1m * mas * (1000 / d)^2`` with ``K_1m`` from :func:`air_kerma_per_mas`; ``d`` is
    the distance from the focal spot to the nearest point of any body's surface (exact over the
    triangles), and the source-detector distance along the beam axis. No backscatter factor (an
    entrance *surface* air kerma would be 1.2-1.5 times larger), no heel effect, no attenuation
    by air.
    """
    return _air_kerma(scene.acquisition, scene.bodies)


def _air_kerma(acquisition, bodies) -> AirKerma:
    """:func:`air_kerma` of bodies at an acquisition."""
    from xray_viz.physics.spectra import source_spectrum

    src = acquisition.source
    mas = src.mas
    if mas is None:
        raise SpectrumError("air kerma needs [source] mas (the tube current-time product, mAs)")
    if src.kind == "parallel":
        raise SpectrumError("air kerma needs a point source: a parallel beam has no focal spot "
                            "to fall off from")
    spectrum = source_spectrum(src)
    per_1m = air_kerma_per_mas(spectrum)
    sid = acquisition.frame.sid
    entrance_d = None
    if len(bodies):
        entrance_d = _closest_distance(src.position, bodies.triangles)
    k = lambda d: per_1m * mas * (1000.0 / d) ** 2                      # noqa: E731
    return AirKerma(entrance_uGy=None if entrance_d is None else k(entrance_d),
                    detector_uGy=k(sid), entrance_distance_mm=entrance_d,
                    detector_distance_mm=sid, mas=float(mas), per_mas_at_1m_uGy=per_1m)
