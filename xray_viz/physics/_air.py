"""Dry air's mass energy-absorption coefficient (NIST) and half-value layers on air kerma.

The data every kerma figure rests on, below both :mod:`~xray_viz.physics.spectra` (the IEC
61267 qualities are tuned to a half-value layer) and :mod:`~xray_viz.physics.dosimetry`, which
documents and exports these names.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from xray_viz.errors import SpectrumError

#: Joules per keV (exact, SI 2019).
KEV_TO_JOULE = 1.602176634e-16

#: Argon K-shell edge in dry air, keV (the table gives mu_en just below and just above it).
AIR_K_EDGE_KEV = 3.2029

#: NIST mass energy-absorption coefficients of dry air (near sea level), Hubbell and Seltzer,
#: NIST SRD 126, Table 4: (photon energy in MeV, mu_en/rho in cm^2/g). The Ar K edge appears
#: twice, below then above it.
MUEN_AIR_NIST = (
    (1.00000e-03, 3.599e+03), (1.50000e-03, 1.188e+03), (2.00000e-03, 5.262e+02),
    (3.00000e-03, 1.614e+02), (3.20290e-03, 1.330e+02), (3.20290e-03, 1.460e+02),
    (4.00000e-03, 7.636e+01), (5.00000e-03, 3.931e+01), (6.00000e-03, 2.270e+01),
    (8.00000e-03, 9.446e+00), (1.00000e-02, 4.742e+00), (1.50000e-02, 1.334e+00),
    (2.00000e-02, 5.389e-01), (3.00000e-02, 1.537e-01), (4.00000e-02, 6.833e-02),
    (5.00000e-02, 4.098e-02), (6.00000e-02, 3.041e-02), (8.00000e-02, 2.407e-02),
    (1.00000e-01, 2.325e-02), (1.50000e-01, 2.496e-02), (2.00000e-01, 2.672e-02),
    (3.00000e-01, 2.872e-02), (4.00000e-01, 2.949e-02), (5.00000e-01, 2.966e-02),
    (6.00000e-01, 2.953e-02), (8.00000e-01, 2.882e-02), (1.00000e+00, 2.789e-02),
    (1.25000e+00, 2.666e-02), (1.50000e+00, 2.547e-02), (2.00000e+00, 2.345e-02),
    (3.00000e+00, 2.057e-02), (4.00000e+00, 1.870e-02), (5.00000e+00, 1.740e-02),
    (6.00000e+00, 1.647e-02), (8.00000e+00, 1.525e-02), (1.00000e+01, 1.450e-02),
    (1.50000e+01, 1.353e-02), (2.00000e+01, 1.311e-02),
)


def _kev(mev) -> np.ndarray:
    """MeV -> keV, rounded to the table's digits (3.20290e-03 MeV is 3.2029 keV, exactly)."""
    return np.round(np.asarray(mev, dtype=np.float64) * 1000.0, 9)


@lru_cache(maxsize=1)
def _muen_splines():
    """The two cubic splines in (ln E, ln mu_en): below and above the Ar K edge."""
    from scipy.interpolate import CubicSpline

    table = np.asarray(MUEN_AIR_NIST, dtype=np.float64)
    e_kev, muen = _kev(table[:, 0]), table[:, 1]
    edge = int(np.flatnonzero(np.diff(e_kev) == 0)[0])          # last node below the edge
    below = CubicSpline(np.log(e_kev[:edge + 1]), np.log(muen[:edge + 1]))
    above = CubicSpline(np.log(e_kev[edge + 1:]), np.log(muen[edge + 1:]))
    return below, above, float(e_kev[0]), float(e_kev[-1])


def air_mass_energy_absorption(energies_kev) -> np.ndarray:
    """``(mu_en/rho)`` of dry air in cm^2/g, from NIST's table (see the module docstring).

    Parameters
    ----------
    energies_kev : float or (n,) float
        Photon energies, 1 keV to 20 MeV. At exactly the Ar K edge the value above it is given.

    Returns
    -------
    (n,) float
        Equal to the table at its energies; a cubic spline in log-log between them.

    Raises
    ------
    SpectrumError
        Energies outside the table's 1 keV - 20 MeV.

    Examples
    --------
    >>> air_mass_energy_absorption([20.0, 100.0]).tolist()
    [0.5389, 0.02325]
    """
    e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
    below, above, lo, hi = _muen_splines()
    if e.ndim != 1 or not np.all(np.isfinite(e)) or np.any(e < lo) or np.any(e > hi):
        bad = e[~((e >= lo) & (e <= hi))] if e.ndim == 1 else e.ravel()
        raise SpectrumError(f"air kerma needs photon energies from {lo:g} keV to {hi:g} keV "
                            f"(NIST's mu_en/rho table of air), got {bad.tolist()[:3]} keV")
    out = np.empty_like(e)
    low = e < AIR_K_EDGE_KEV
    out[low] = np.exp(below(np.log(e[low])))
    out[~low] = np.exp(above(np.log(e[~low])))
    # the spline passes through the nodes up to rounding: return the table's values there
    node_e, node_v = _muen_nodes()
    i = np.clip(np.searchsorted(node_e, e), 0, len(node_e) - 1)
    at_node = node_e[i] == e
    out[at_node] = node_v[i[at_node]]
    return out


@lru_cache(maxsize=1)
def _muen_nodes():
    """The table's energies (keV, each once; the value above the K edge) and values."""
    table = np.asarray(MUEN_AIR_NIST, dtype=np.float64)
    e, v = _kev(table[:, 0]), table[:, 1]
    keep = np.append(e[1:] != e[:-1], True)                     # the later of a repeated energy
    return e[keep], v[keep]


def _attenuation_to_half(kerma_w, mu_per_mm, fraction: float) -> float:
    """Thickness (mm) at which ``sum_k w_k exp(-mu_k t) / sum_k w_k`` equals ``fraction``."""
    from scipy.optimize import brentq

    w = np.asarray(kerma_w, dtype=np.float64)
    mu = np.asarray(mu_per_mm, dtype=np.float64)
    keep = w > 0
    w, mu = w[keep] / w[keep].sum(), mu[keep]
    log_w, target = np.log(w), math.log(fraction)

    def f(t):                                           # log of the transmitted fraction
        a = log_w - mu * t
        top = a.max()
        return top + math.log(np.exp(a - top).sum()) - target

    hi = -target / max(float(mu.min()), 1e-300)          # f(hi) <= 0: the softest weight fits
    hi = min(hi, 1e9)
    while f(hi) > 0:                                    # pragma: no cover - mu.min() bounds it
        hi *= 2.0
    return float(brentq(f, 0.0, hi, xtol=1e-13 * max(hi, 1.0), rtol=1e-14, maxiter=500))


def _half_value_layers(energies_kev, fluence, mu_per_mm, muen=None):
    """``(hvl1, hvl2)`` in mm for given attenuation (1/mm) and mu_en/rho of air (cm^2/g)."""
    e = np.asarray(energies_kev, dtype=np.float64)
    muen = air_mass_energy_absorption(e) if muen is None else np.asarray(muen, dtype=np.float64)
    w = np.asarray(fluence, dtype=np.float64) * e * muen
    h1 = _attenuation_to_half(w, mu_per_mm, 0.5)
    q = _attenuation_to_half(w, mu_per_mm, 0.25)
    return h1, q - h1


# Documented and exported by xray_viz.physics.dosimetry (as numpy's ``set_module`` does).
air_mass_energy_absorption.__module__ = "xray_viz.physics.dosimetry"
