"""Beer-Lambert image formation: from path lengths to line integrals and intensities.

For a monochromatic beam of energy E, Beer-Lambert's law gives the intensity behind the object

    I = I0 * exp(-sum_b mu_b(E) * L_b)

where ``L_b`` is the effective path length (mm) of the ray in body b's material and ``mu_b`` its
linear attenuation coefficient (1/cm; hence the factor 1/10 below). The *line integral* is the
exponent, ``-ln(I / I0)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["body_mu", "transmission", "detect"]

MM_PER_CM = 10.0


def body_mu(scene, energies_kev) -> np.ndarray:
    """Linear attenuation coefficients of every body at the given energies, in 1/cm.

    Returns
    -------
    (n_energies, n_bodies) float
    """
    energies = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
    mu = np.empty((len(energies), len(scene.bodies)))
    for b, body in enumerate(scene.bodies):
        if body.mu is not None:
            mu[:, b] = body.mu
        else:
            from xray_viz.physics.materials import linear_attenuation

            mu[:, b] = linear_attenuation(body.material, energies, density=body.density)
    return mu


def transmission(path_length, scene) -> np.ndarray:
    """Fraction of the beam transmitted along each ray, ``I / I0 = exp(-sum_b mu_b L_b)``.

    Parameters
    ----------
    path_length : (n_rays, n_bodies) float
        Millimetres of each ray in each body's material.
    scene : Scene
        Gives the bodies' materials and the source energy.

    Returns
    -------
    (n_rays,) float

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> scene = xray_viz.load_scene("sphere")          # mu = 0.2 /cm
    >>> float(transmission(np.array([[50.0]]), scene)[0]) == float(np.exp(-1.0))
    True
    """
    energy = scene.source.energy if scene.source.energy is not None else 60.0
    mu = body_mu(scene, [energy])[0]
    return np.exp(-(np.asarray(path_length) @ (mu / MM_PER_CM)))


def detect(transmitted, scene, *, i0: float = 1.0):
    """The detector's reading of the transmitted beam.

    Parameters
    ----------
    transmitted : (H, W) float
        ``I / I0`` per pixel.
    scene : Scene
    i0 : float
        Unattenuated intensity.

    Returns
    -------
    intensity : (H, W) float
        ``I0 * transmitted``.
    line_integral : (H, W) float
        ``-ln(I / I0)``.
    """
    transmitted = np.asarray(transmitted, dtype=np.float64)
    with np.errstate(divide="ignore"):
        line_integral = -np.log(transmitted)
    return i0 * transmitted, line_integral
