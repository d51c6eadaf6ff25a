"""Physics: materials, spectra and the detector, from path lengths to a radiograph.

* :mod:`~xray_viz.physics.materials` - ``mu(E)`` of NIST compounds, the ICRU-44 body tissues,
  formulas, elements and mass-fraction mixtures from xraylib (NIST XCOM total attenuation with
  coherent scattering).
* :mod:`~xray_viz.physics.spectra` - monochromatic beams, SpekPy tube spectra (filtered with
  xraylib's data), the IEC 61267:2005 radiation qualities (RQR, RQA), CSV spectra.
* :mod:`~xray_viz.physics.dosimetry` - air kerma (NIST mu_en/rho of air), half-value layers
  (:func:`hvl`), photons per pixel from the tube current-time product, entrance air kerma
  (:func:`air_kerma`).
* :mod:`~xray_viz.physics.beam` - :class:`~xray_viz.physics.beam.Beam`, built once per source
  and bodies: the spectrum as the detector weighs it and every body's attenuation at its bins;
  ``beam.log_transmission(L)``, Beer-Lambert over the spectrum in the log domain.
* :mod:`~xray_viz.physics.detector_model` -
  :class:`~xray_viz.physics.detector_model.DetectorModel`, built once per detector:
  ``model.read(log_t, ...)`` with I0, gain, inverse-square/obliquity fall-off, focal-spot blur,
  quantum and electronic noise, the MTF; line integrals.
* :mod:`~xray_viz.physics.imaging` - the same on a scene (adapters of the two values):
  Beer-Lambert over the spectrum, detector response (energy-integrating or counting), fall-off,
  focal-spot blur, noise, line integrals.
* :mod:`~xray_viz.physics.detector` - the scintillator's absorption efficiency, the detector
  blur (MTF), the order of noise and gain.
* :mod:`~xray_viz.physics.grid` - the anti-scatter grid (:class:`~xray_viz.physics.grid.Grid`):
  transmission by energy and angle (Day & Dance 1983), IEC 60627 figures of merit.
* :mod:`~xray_viz.physics.heel` - the heel effect: SpekPy's off-axis spectra across the field.

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
                            # (times gain and the scintillator's absorbed fraction)
    noise = false           # quantum noise (and electronic noise, if given) ...
    seed = 1                # ... reproducible with a seed (fresh randomness without one)
    falloff = false         # inverse square and obliquity, cos^3(theta), for a point source
    supersample = 1         # n x n rays per pixel, averaged in intensity (anti-aliasing)
    focal_spot = 0.0        # mm; Gaussian focal spot of this FWHM
    scintillator = { material = "CsI", thickness = 0.6, fill = 0.8 }   # mm; fill default 1;
                            # "Gd2O2S" too; density = ... g/cm3 (CsI 4.51, Gd2O2S 7.32 default)
    mtf = { sigma = 0.1 }   # mm, Gaussian detector blur; or fwhm = ...; or a measured table,
                            # { file = "mtf.csv" } (cycles/mm, MTF) or { lsf = "lsf.csv" }
                            # (mm, LSF), presampled = true (default: includes the pixel aperture)
    electronic_noise = 0.0  # photon-equivalents rms, Gaussian, per pixel; needs noise = true
    gain = 1.0              # detected units per photon-equivalent (scales the intensity)
    grid = { ratio = 10, frequency = 60 }   # an anti-scatter grid (lines per cm), with
                            # strip_material = "Pb", strip_thickness = 0.036 (mm),
                            # interspace_material = "Al", focus_distance = 1000.0 (mm) and
                            # strip_density / interspace_density (g/cm3) by default
                            # (:mod:`~xray_viz.physics.grid`); none by default

and in ``[source]``::

    heel = false            # true: the heel effect, anode at the top of the image; or the
                            # anode's side, "top", "bottom", "left", "right"; needs a SpekPy
                            # spectrum = { kvp = ... } and a point source

What is modelled
----------------
Narrow-beam (primary) attenuation along straight rays, ``exp(-sum_b mu_b(E) L_b)``, summed over
the spectrum's energy bins with fluence (counting) or fluence x energy (energy-integrating)
weights, which reproduces beam hardening. An ideal detector absorbs every photon (quantum
efficiency 1 at all energies); with ``scintillator`` the converter absorbs the fraction
``eta(E) = fill * (1 - exp(-mu(E) t))`` of the photons (the same xraylib data as the bodies),
which hardens the detected beam a little more: behind 20 cm of water at 80 kVp (W anode, 12
degrees) a 0.6 mm CsI converter raises the line integral by 1.38 % (energy-integrating; 1.28 %
counting) without added filtration, and by 1.07 % (0.95 %) with 2.5 mm Al; the fill factor
scales the signal, not the line integral. Point-source fall-off ``cos^3(theta)`` (inverse
square times obliquity) relative to the detector centre, evaluated at pixel centres.
Focal-spot unsharpness as one Gaussian kernel of FWHM ``focal_spot * (SID - SOD) / SOD`` for
the object plane through the centre of the bodies' bounding box
(:func:`~xray_viz.physics.imaging.source_object_distance`); a discrete Gaussian whose variance
is exact also for blurs far below a pixel (:func:`~xray_viz.physics.imaging.gaussian_kernel`).
The detector blur (``mtf``), separate from and after the focal spot's, in the detector plane:
a non-negative kernel on the pixel grid fitted to the MTF up to the Nyquist frequency (exact to
0.0013 for a Gaussian of 1 pixel sigma, 0.011 at 0.7, ~0.06 at 0.3-0.6, 0.03 at 0.2, where the
pixel grid cannot carry the Gaussian; :func:`~xray_viz.physics.detector.mtf_kernel`); the pixel
aperture comes from the supersampled rays (``supersample``), so the presampled MTF measured
from a slanted edge is the blur's MTF times the aperture's sinc.
Quantum noise: Poisson counts for a counting detector; an energy-integrating detector's
compound Poisson signal with the exact mean and variance of each pixel's *transmitted*
spectrum (the variance is a second log-domain sum with weights ``phi eta E^2``; behind 20 cm of
water at 80 kVp, 2.5 mm Al, the unattenuated beam's Swank factor would give a variance 18 %
too low). Then the detector blur, electronic noise (Gaussian, per pixel) and the gain, in this
order (:mod:`~xray_viz.physics.detector`).
The heel effect and off-axis spectra (``heel``): SpekPy's spectrum towards each pixel,
interpolated from a 13 x 5 grid of directions (within 0.07 % of SpekPy's detected intensity
over a 30 x 30 cm field at 1 m; :mod:`~xray_viz.physics.heel`), including the filters' oblique
paths; the anode side is darker and harder.

Dosimetry (:mod:`~xray_viz.physics.dosimetry`): an air-kerma detector response, fluence x energy x
(mu_en/rho)_air with NIST's mu_en/rho of dry air; first and second half-value layers on air kerma
(:func:`hvl`); photons per pixel from the tube's output per mAs (SpekPy), by the inverse square
law, and the incident air kerma (free in air) at the nearest body surface and at the detector
(:func:`air_kerma`). One attenuation data set, xraylib's, serves the bodies, the tube filters and
the half-value layers; only the anode's self-absorption is SpekPy's own. A ``[world]`` medium
attenuates each ray along its path outside the bodies (:class:`~xray_viz.physics.beam.Beam`'s
``world``: the ray's length from the source to its pixel minus its paths in the bodies).

Photon transport (:func:`xray_viz.transport`, a separate Monte Carlo on the same meshes, voxel
volumes and xraylib data): photoelectric absorption, incoherent scattering (Klein-Nishina x the incoherent
scattering function S, free-electron energies: no Doppler broadening) and coherent scattering
(Thomson x F^2) in the bodies and the ``[world]`` medium, cut-off 1 keV; energy per body, dose
with ``mas``, and the detector image split into primary, single incoherent, single coherent
and multiple. Not in it: **fluorescence** (the photoelectric energy, K and L shells included,
is deposited where the photon was absorbed), secondary electrons (deposited on the spot: valid
to ~150 keV), polarisation, and the detector model (the images are the energy reaching the
detector plane).

What is NOT modelled
--------------------
* Scattered radiation in an image rendered without ``scatter=``: scattered photons are then
  removed from the beam (they are part of ``mu``) but not detected (:data:`SCATTER_SCOPE`;
  BENCHMARKS.md, "Scatter in the images": at 80 kVp without a grid, 1-40 % of the primary
  for the bundled phantoms, 0.24 of it behind 2 cm of water and 3.2 times it behind 20 cm,
  in a 30 x 30 cm field). ``render(scene, scatter="mc")`` adds the photon transport's
  scatter, ``scatter="kernel"`` the kernel model's.
* The heel effect for a CSV or monochromatic spectrum (it needs SpekPy's tube model), and
  the heel effect's own dependence on the focal spot's size and shape.
* Depth-dependent focal-spot blur (one kernel for the object plane, not per body depth), the
  focal spot's real shape, and extra-focal radiation.
* Detector physics beyond absorption, blur, electronic noise and gain: the converter's
  obliquity (every ray crosses its thickness as at normal incidence), depth-dependent light
  spread, the Swank noise of the light yield (each absorbed photon scores its whole energy),
  K-fluorescence and Compton escape, a blur of ~0.2-0.7 pixel exactly (see above), anisotropic
  or non-separable blur, noise aliasing from the pixel aperture, dark current, lag, gain
  non-uniformity, pile-up and energy thresholds of counting detectors.
* Air attenuation between source and detector (unless a body of air is in the scene), refraction
  and phase contrast, polarisation, and secondary electrons.
* Patient dose: only the incident air kerma is reported (no backscatter factor, no organ or
  effective dose).
"""

from xray_viz.physics.dosimetry import SCATTER_SCOPE, air_kerma, hvl, scatter_scope

__all__ = ["beam", "detector", "detector_model", "dosimetry", "heel", "imaging", "materials",
           "spectra", "hvl",
           "air_kerma", "SCATTER_SCOPE", "scatter_scope"]
