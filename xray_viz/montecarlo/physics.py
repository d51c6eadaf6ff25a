"""Photon interaction data and samplers of the transport: tables from xraylib, numba samplers.

Per material (one entry per body, plus the world medium as entry 0) on a grid uniform in
``ln E`` from the cut-off (1 keV) to just above the highest source energy, the linear
attenuation coefficients (1/mm) of

* photoelectric absorption (``CS_Photo``): the photon ends, its energy is deposited on the spot
  (no fluorescence: :mod:`xray_viz.physics` says so in its scope);
* incoherent scattering (``CS_Compt``): Klein-Nishina times the incoherent scattering function
  ``S(x, Z)`` (``SF_Compt``), the free-electron energy ``E' = E / (1 + k (1 - cos))`` (no
  Doppler broadening), ``E - E'`` deposited on the spot;
* coherent scattering (``CS_Rayl``): Thomson times the atomic form factor squared
  ``F(x, Z)^2`` (``FF_Rayl``), no energy lost.

A compound's coefficient is the mass-fraction sum over its elements (what xraylib's
``CS_*_CP`` and the project's :func:`xray_viz.physics.materials.mass_attenuation` do), so the
three add up to the attenuation the primary engines use. ``x = sin(theta / 2) / lambda`` in
1/Angstrom, xraylib's momentum transfer (``HC_KEV_ANGSTROM``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

import xray_viz.tracing._numba_cache  # noqa: F401  (the kernels' one disk cache)

from xray_viz.errors import MaterialError
from xray_viz.montecarlo.rng import uniform

# The numba kernels (``mu_lookup``, ``sample_incoherent``, ``sample_coherent``) are documented
# where they are defined; the API reference lists the Python side.
__all__ = ["MaterialTables", "composition", "tables", "CUTOFF_KEV", "HC_KEV_ANGSTROM",
           "ELECTRON_REST_KEV"]

#: Photons below this energy (keV) are absorbed where they are.
CUTOFF_KEV = 1.0
#: h c in keV Angstrom (xraylib's ``KEV2ANGST``): ``x = E / hc * sin(theta / 2)``.
HC_KEV_ANGSTROM = 12.398419843320026
#: m_e c^2 in keV.
ELECTRON_REST_KEV = 510.99895
#: Points of the energy grid and of the momentum-transfer grid.
N_ENERGY = 2048
N_X = 8192


def composition(material) -> dict[int, float]:
    """Elements ``{Z: mass fraction}`` (summing to 1) of a material as the bodies name it.

    Parameters
    ----------
    material : str or mapping
        A NIST compound, an ICRU-44 tissue, a formula or element, or a mixture of those by
        mass fraction (:mod:`xray_viz.physics.materials`).

    Examples
    --------
    >>> {z: round(w, 4) for z, w in composition("H2O").items()}
    {1: 0.1121, 8: 0.8879}
    """
    import xraylib

    from xray_viz.physics.materials import ICRU44_TISSUES, material_key, nist_compounds

    key = material_key(material)
    out: dict[int, float] = {}
    if isinstance(key, tuple):
        total = sum(f for _, f in key)
        for name, frac in key:
            for z, w in composition(name).items():
                out[z] = out.get(z, 0.0) + w * frac / total
        return out
    if key in ICRU44_TISSUES:
        pairs = ICRU44_TISSUES[key][1]
        total = sum(w for _, w in pairs)
        return {xraylib.SymbolToAtomicNumber(s): w / total for s, w in pairs}
    if key in nist_compounds():
        data = xraylib.GetCompoundDataNISTByName(key)
    else:
        try:
            data = xraylib.CompoundParser(key)
        except ValueError:
            raise MaterialError(f"unknown material {key!r}") from None
    for z, w in zip(data["Elements"], data["massFractions"]):
        out[int(z)] = out.get(int(z), 0.0) + float(w)
    return out


@dataclass(frozen=True, eq=False)
class MaterialTables:
    """The interaction tables of a list of materials, as the transport kernel reads them.

    Attributes
    ----------
    ln_e0, d_ln_e : float
        The energy grid: ``E_i = exp(ln_e0 + i d_ln_e)`` keV.
    mu : (M, 3, N_ENERGY) float
        Photoelectric, incoherent, coherent linear attenuation, 1/mm (0 for vacuum).
    x_max, dx : float
        The momentum-transfer grid ``x_j = j dx``, 1/Angstrom, up to ``x_max``.
    sf : (M, N_X) float
        ``S_eff(x) / S_eff(inf)``: the incoherent scattering function of the material, per
        electron, between 0 and 1.
    ff2_cum : (M, N_X) float
        ``G(x_j) = integral_0^{x_j^2} F_eff^2 d(x^2)``: the cumulative coherent form factor.
    names : tuple of str
    densities : (M,) float
        g/cm3.
    """

    ln_e0: float
    d_ln_e: float
    mu: np.ndarray
    x_max: float
    dx: float
    sf: np.ndarray
    ff2_cum: np.ndarray
    names: tuple
    densities: np.ndarray

    def energies(self) -> np.ndarray:
        """(N_ENERGY,) keV of the grid."""
        return np.exp(self.ln_e0 + self.d_ln_e * np.arange(self.mu.shape[2]))


def _element_tables(z: int, energies: np.ndarray, x: np.ndarray):
    import xraylib

    photo = np.array([xraylib.CS_Photo(z, e) for e in energies])
    compt = np.array([xraylib.CS_Compt(z, e) for e in energies])
    rayl = np.array([xraylib.CS_Rayl(z, e) for e in energies])
    # xraylib's S(x, Z) starts at x = 1e-3 for most Z; below it S grows as x^2
    x0 = 1e-3
    s0 = xraylib.SF_Compt(z, x0)
    sf = np.array([xraylib.SF_Compt(z, xi) if xi >= x0 else s0 * (xi / x0) ** 2 for xi in x])
    ff = np.array([xraylib.FF_Rayl(z, xi) for xi in x])
    return photo, compt, rayl, sf, ff


def tables(materials, *, e_max: float, e_min: float = CUTOFF_KEV) -> MaterialTables:
    """Build the tables of ``materials``: a sequence of ``(name, material, density)``, where
    ``material`` None is vacuum.

    Parameters
    ----------
    materials : sequence of (str, str or mapping or None, float)
    e_max : float
        Highest photon energy (keV) the transport will meet.
    e_min : float
        Lowest (the cut-off).

    Examples
    --------
    >>> t = tables([("water", "Water, Liquid", 1.0)], e_max=100.0)
    >>> mu = mu_lookup(t.mu[0], t.ln_e0, t.d_ln_e, 60.0)
    >>> round(10 * (mu[0] + mu[1] + mu[2]), 4)        # 1/cm, as linear_attenuation gives
    0.2059
    """
    import xraylib

    hi = max(float(e_max) * 1.001, e_min * 2.0)
    ln_e0 = math.log(e_min)
    d_ln_e = (math.log(hi) - ln_e0) / (N_ENERGY - 1)
    energies = np.exp(ln_e0 + d_ln_e * np.arange(N_ENERGY))
    energies[-1] = min(energies[-1], 800.0)
    x_max = hi / HC_KEV_ANGSTROM * 1.0001
    dx = x_max / (N_X - 1)
    x = dx * np.arange(N_X)
    m = len(materials)
    mu = np.zeros((m, 3, N_ENERGY))
    sf = np.zeros((m, N_X))
    cum = np.zeros((m, N_X))
    cache = {}
    for k, (_, material, density) in enumerate(materials):
        if material is None:
            sf[k] = 1.0
            cum[k] = np.arange(N_X, dtype=float)
            continue
        s_eff = np.zeros(N_X)
        f2_eff = np.zeros(N_X)
        z_over_a = 0.0
        for z, w in composition(material).items():
            if z not in cache:
                cache[z] = _element_tables(z, energies, x)
            photo, compt, rayl, s, f = cache[z]
            # cm2/g * g/cm3 = 1/cm; / 10: 1/mm
            mu[k, 0] += w * photo * density / 10.0
            mu[k, 1] += w * compt * density / 10.0
            mu[k, 2] += w * rayl * density / 10.0
            a = xraylib.AtomicWeight(z)
            s_eff += w / a * s
            f2_eff += w / a * f * f
            z_over_a += w * z / a
        sf[k] = np.clip(s_eff / z_over_a, 0.0, 1.0)
        u = x * x
        cum[k, 1:] = np.cumsum(0.5 * (f2_eff[1:] + f2_eff[:-1]) * np.diff(u))
    for a in (mu, sf, cum):
        a.setflags(write=False)
    return MaterialTables(ln_e0=ln_e0, d_ln_e=d_ln_e, mu=mu, x_max=x_max, dx=dx, sf=sf,
                          ff2_cum=cum, names=tuple(n for n, _, _ in materials),
                          densities=np.array([d if mat is not None else 0.0
                                              for _, mat, d in materials], float))


# --- the samplers (numba) ------------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def mu_lookup(mu, ln_e0, d_ln_e, energy):
    """The three coefficients ``(photo, incoherent, coherent)`` of one material at ``E``,
    linear in ``ln E`` between grid points (``mu``: (3, N) of ``MaterialTables.mu``)."""
    f = (math.log(energy) - ln_e0) / d_ln_e
    n = mu.shape[1]
    i = int(f)
    if i < 0:
        i = 0
        f = 0.0
    if i > n - 2:
        i = n - 2
        f = float(n - 1)
    w = f - i
    return (mu[0, i] + w * (mu[0, i + 1] - mu[0, i]), mu[1, i] + w * (mu[1, i + 1] - mu[1, i]),
            mu[2, i] + w * (mu[2, i + 1] - mu[2, i]))


@numba.njit(cache=True, nogil=True)
def _interp_uniform(table, dx, x):
    f = x / dx
    i = int(f)
    if i >= table.shape[0] - 1:
        return table[table.shape[0] - 1]
    w = f - i
    return table[i] + w * (table[i + 1] - table[i])


@numba.njit(cache=True, nogil=True)
def sample_incoherent(energy, sf, dx, state):
    """``(cos theta, E')``: Klein-Nishina (Butcher and Messel's sampling, as Geant4's
    ``G4KleinNishinaCompton``) times ``S(x) / Z`` by rejection (``state``: the
    random stream, ``rng.uniform``)."""
    k = energy / ELECTRON_REST_KEV
    eps0 = 1.0 / (1.0 + 2.0 * k)
    eps0sq = eps0 * eps0
    alpha1 = -math.log(eps0)
    alpha2 = alpha1 + 0.5 * (1.0 - eps0sq)
    kx = energy / HC_KEV_ANGSTROM
    while True:
        if alpha1 > alpha2 * uniform(state):
            eps = math.exp(-alpha1 * uniform(state))
            epssq = eps * eps
        else:
            epssq = eps0sq + (1.0 - eps0sq) * uniform(state)
            eps = math.sqrt(epssq)
        onecost = (1.0 - eps) / (eps * k)
        sint2 = onecost * (2.0 - onecost)
        greject = 1.0 - eps * sint2 / (1.0 + epssq)
        if greject < uniform(state):
            continue
        # binding: accept with S(x) / Z, x = E / hc sin(theta / 2)
        x = kx * math.sqrt(0.5 * onecost)
        if uniform(state) <= _interp_uniform(sf, dx, x):
            return 1.0 - onecost, energy * eps


@numba.njit(cache=True, nogil=True)
def sample_coherent(energy, cum, dx, state):
    """cos theta of coherent scattering: ``x^2`` from ``F^2`` (inverse of its cumulative up
    to ``x_max(E)``), accepted with Thomson's ``(1 + cos^2) / 2``."""
    kx = energy / HC_KEV_ANGSTROM
    u_max = kx * kx
    g_max = _interp_uniform(cum, dx, kx)
    n = cum.shape[0]
    while True:
        target = uniform(state) * g_max
        lo = 0
        hi = min(int(kx / dx) + 1, n - 1)
        while hi - lo > 1:                       # cum[lo] <= target < cum[hi]
            mid = (lo + hi) >> 1
            if cum[mid] <= target:
                lo = mid
            else:
                hi = mid
        u0 = (lo * dx) ** 2
        u1 = (hi * dx) ** 2
        g0 = cum[lo]
        g1 = cum[hi]
        u = u0 + (u1 - u0) * ((target - g0) / (g1 - g0) if g1 > g0 else 0.5)
        if u > u_max:
            u = u_max
        cost = 1.0 - 2.0 * u / u_max
        if 2.0 * uniform(state) <= 1.0 + cost * cost:
            return cost
