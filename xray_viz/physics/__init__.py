"""Physics: materials, spectra and the detector, from path lengths to a radiograph.

* :mod:`~xray_viz.physics.materials` - ``mu(E)`` of NIST compounds, formulas, elements and
  mass-fraction mixtures from xraylib (NIST XCOM total attenuation with coherent scattering).
* :mod:`~xray_viz.physics.spectra` - monochromatic beams, SpekPy tube spectra, CSV spectra.
* :mod:`~xray_viz.physics.imaging` - Beer-Lambert over the spectrum, detector response
  (energy-integrating or counting), inverse-square/obliquity fall-off, focal-spot blur, Poisson
  noise, line integrals.

The ``[detector]`` keys of a scene file::

    response = "energy"     # or "counting"
    I0 = 1.0                # unattenuated photons per pixel (at the detector centre); required
                            # with noise; with noise off the image is simply I0 * I/I0
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

What is NOT modelled
--------------------
* Scattered radiation (Compton and Rayleigh photons reaching the detector), anti-scatter grids.
  Scattered photons are removed from the beam (they are part of ``mu``) but never detected.
* The heel effect and off-axis spectral changes of the tube (SpekPy gives the central-axis
  spectrum); the anode angle changes the spectrum only through self-filtration.
* Depth-dependent focal-spot blur (one kernel for the object plane, not per body depth), the
  focal spot's real shape, and extra-focal radiation.
* Detector physics: energy-dependent absorption efficiency, the converter layer's thickness and
  obliquity, light spread or charge sharing (MTF), electronic noise, dark current, gain and
  lag, K-fluorescence escape, pile-up and energy thresholds of counting detectors.
* Air attenuation between source and detector (unless a body of air is in the scene), refraction
  and phase contrast, polarisation, and secondary electrons.
* Patient dose.
"""

__all__ = ["imaging", "materials", "spectra"]
