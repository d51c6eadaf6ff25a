"""Physics: materials, spectra and the detector, from path lengths to a radiograph.

* :mod:`~xray_viz.physics.materials` - ``mu(E)`` of NIST compounds, the ICRU-44 body tissues,
  formulas, elements and mass-fraction mixtures from xraylib (NIST XCOM total attenuation with
  coherent scattering).
* :mod:`~xray_viz.physics.spectra` - monochromatic beams, SpekPy tube spectra (filtered with
  xraylib's data), the IEC 61267:2005 radiation qualities (RQR, RQA), CSV spectra.
* :mod:`~xray_viz.physics.dosimetry` - air kerma (NIST mu_en/rho of air), half-value layers
  (:func:`hvl`), photons per pixel from the tube current-time product, entrance air kerma
  (:func:`air_kerma`).
* :mod:`~xray_viz.physics.imaging` - Beer-Lambert over the spectrum, detector response
  (energy-integrating or counting), inverse-square/obliquity fall-off, focal-spot blur, Poisson
  noise, line integrals.

The ``[source]`` keys of the physics (beside ``position`` and ``kind``)::

    energy = 60.0           # keV, a monochromatic beam; or
    spectrum = { kvp = 80.0, filters = { Al = 2.5 } }     # a SpekPy tube spectrum; or
    spectrum = { quality = "RQA5", anode_angle = 12.0 }   # an IEC 61267:2005 quality; or
    spectrum = { file = "spectrum.csv" }                  # keV, relative fluence
    mas = 2.0               # tube current-time product (mAs), with a tube spectrum and a
                            # point source: I0 follows from SpekPy's output per mAs, and
                            # falloff defaults to true (inverse square to every pixel)

The ``[detector]`` keys of a scene file::

    response = "energy"     # or "counting", or "kerma" (air kerma: fluence x E x mu_en/rho air)
    I0 = 1.0                # unattenuated photons per pixel (at the detector centre); required
                            # with noise unless [source] gives mas (then I0 is not allowed);
                            # with noise off the image is simply I0 * I/I0
    noise = false           # Poisson noise ...
    seed = 1                # ... reproducible with a seed (fresh randomness without one)
    falloff = false         # inverse square and obliquity, cos^3(theta), for a point source
    supersample = 1         # n x n rays per pixel, averaged in intensity (anti-aliasing)
    focal_spot = 0.0        # mm; Gaussian focal spot of this FWHM

What is modelled
----------------
Narrow-beam (primary) attenuation along straight rays, ``exp(-sum_b mu_b(E) L_b)``, summed over
the spectrum's energy bins with fluence (counting) or fluence x energy (energy-integrating)
weights, which reproduces beam hardening. An ideal detector absorbs every photon (quantum
efficiency 1 at all energies). Point-source fall-off ``cos^3(theta)`` (inverse square times
obliquity) relative to the detector centre, evaluated at pixel centres. Focal-spot unsharpness as
one Gaussian kernel of FWHM ``focal_spot * (SID - SOD) / SOD`` for the object plane through the
centre of the bodies' bounding box (:func:`~xray_viz.physics.imaging.source_object_distance`);
a discrete Gaussian whose variance is exact also for blurs far below a pixel
(:func:`~xray_viz.physics.imaging.gaussian_kernel`).
Quantum noise: Poisson counts; for energy-integrating detectors via the Swank factor.

Dosimetry (:mod:`~xray_viz.physics.dosimetry`): an air-kerma detector response, fluence x energy x
(mu_en/rho)_air with NIST's mu_en/rho of dry air; first and second half-value layers on air kerma
(:func:`hvl`); photons per pixel from the tube's output per mAs (SpekPy), by the inverse square
law, and the incident air kerma (free in air) at the nearest body surface and at the detector
(:func:`air_kerma`). One attenuation data set, xraylib's, serves the bodies, the tube filters and
the half-value layers; only the anode's self-absorption is SpekPy's own.

What is NOT modelled
--------------------
* Scattered radiation (Compton and Rayleigh photons reaching the detector), anti-scatter grids.
  Scattered photons are removed from the beam (they are part of ``mu``) but never detected
  (:data:`SCATTER_NOT_MODELLED`; BENCHMARKS.md, "Scatter not modelled", estimates how much
  signal that is: at 80 kVp without a grid, 1-40 % of the primary for the bundled phantoms,
  0.24 of it behind 2 cm of water and 3.2 times it behind 20 cm, in a 30 x 30 cm field).
* The heel effect and off-axis spectral changes of the tube (SpekPy gives the central-axis
  spectrum); the anode angle changes the spectrum only through self-filtration.
* Depth-dependent focal-spot blur (one kernel for the object plane, not per body depth), the
  focal spot's real shape, and extra-focal radiation.
* Detector physics: energy-dependent absorption efficiency, the converter layer's thickness and
  obliquity, light spread or charge sharing (MTF), electronic noise, dark current, gain and
  lag, K-fluorescence escape, pile-up and energy thresholds of counting detectors.
* Air attenuation between source and detector (unless a body of air is in the scene), refraction
  and phase contrast, polarisation, and secondary electrons.
* Patient dose: only the incident air kerma is reported (no backscatter factor, no organ or
  effective dose).
"""

from xray_viz.physics.dosimetry import SCATTER_NOT_MODELLED, air_kerma, hvl

__all__ = ["dosimetry", "imaging", "materials", "spectra", "hvl", "air_kerma",
           "SCATTER_NOT_MODELLED"]
