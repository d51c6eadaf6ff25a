"""Image formation: from path lengths to detected intensities and line integrals.

For photons of energy E, Beer-Lambert's law gives the fraction transmitted along a ray

    T(E) = exp(-sum_b mu_b(E) * L_b)

where ``L_b`` is the effective path length (mm) of the ray in body b's material and ``mu_b`` its
linear attenuation coefficient (1/cm; hence the factor 1/10). A spectrum of photon-fluence
weights ``phi_k`` at energies ``E_k`` is detected as

    counting detector:           T = sum_k phi_k eta_k T(E_k) / sum_k phi_k eta_k
    energy-integrating detector: T = sum_k phi_k eta_k E_k T(E_k) / sum_k phi_k eta_k E_k

with ``eta_k`` the scintillator's absorption efficiency (1 for an ideal detector;
:mod:`xray_viz.physics.detector`) and, with the heel effect, ``phi_k`` the spectrum towards each
pixel (:mod:`xray_viz.physics.heel`). :func:`log_transmission` computes ``ln T`` in the log
domain; one matrix product over (rays x bodies) per chunk of rays gives every energy bin at
once, so the geometry is traced once whatever the number of bins. The variance of an
energy-integrating detector's signal is one more such sum, with weights ``phi_k eta_k E_k^2``
(:func:`log_variance_transmission`). The detector then reads ``I = gain * I0 * F * A * T``
(:func:`detect_log`), with ``F`` the optional inverse-square and obliquity fall-off and ``A``
the unattenuated beam's detected fraction (:func:`flat_field`), blurred by the focal spot and
the detector's MTF and, if asked, with quantum and electronic noise. The *line integral* is the
flat-field corrected ``-ln(I / flat_field)``; for a polychromatic beam it is no longer
proportional to path length (beam hardening).

The functions here take a scene and are adapters of the pipeline's values, which hold the
computations: :class:`~xray_viz.physics.beam.Beam` (spectrum, detector weights and attenuation,
built once per source and bodies) and :class:`~xray_viz.physics.detector_model.DetectorModel`
(built once per detector); a renderer or a scan builds those once and reuses them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from xray_viz.physics import detector_model as _dm
from xray_viz.physics.beam import (  # noqa: F401  (the helpers re-exported for their tests)
    MM_PER_CM, Beam, _inside, _line_integrals, body_mu as _body_mu, detector_weights,
    pixel_log_mean)
from xray_viz.physics.detector_model import (  # noqa: F401  (the helpers re-exported)
    DetectorModel, _convolve, _log_convolve, gaussian_kernel)

__all__ = ["body_mu", "log_transmission", "log_variance_transmission", "transmission",
           "pixel_log_mean", "pixel_log_transmission", "ray_weights", "detect", "detect_log",
           "flat_field", "detector_weights", "falloff_factor",
           "source_object_distance", "source_detector_distance", "magnification",
           "focal_spot_blur_mm", "gaussian_kernel", "MM_PER_CM"]


def _beam_of(scene) -> Beam:
    """The scene's :class:`~xray_viz.physics.beam.Beam` at its acquisition."""
    return Beam.of(scene.source, scene.bodies, scene.detector,
                   world=scene.world).at(scene.acquisition)


def _model(scene, i0=None) -> DetectorModel:
    """The scene's :class:`~xray_viz.physics.detector_model.DetectorModel` (``i0``: another
    I0)."""
    model = DetectorModel.of(scene.detector)
    return model if i0 is None else dataclasses.replace(model, i0=float(i0))


def body_mu(scene, energies_kev) -> np.ndarray:
    """Linear attenuation coefficients of every body at the given energies, in 1/cm.

    A body with a constant ``mu`` has it at every energy; a body with a ``material`` gets
    ``mu(E)`` from :func:`xray_viz.physics.materials.linear_attenuation`.

    Returns
    -------
    (n_energies, n_bodies) float

    Examples
    --------
    >>> import xray_viz
    >>> body_mu(xray_viz.load_scene("sphere"), [40.0, 60.0]).tolist()
    [[0.2], [0.2]]
    """
    return _body_mu(scene.bodies, energies_kev)


def log_transmission(path_length, scene, *, rows=None) -> np.ndarray:
    """Natural log of the detected fraction of the beam along each ray, ``ln(I / I0)``.

    Computed in the log domain, so it stays finite however thick or dense the bodies are
    (``exp(-745)`` already underflows to 0 in float64): a monochromatic beam gives the line
    integral directly, ``-sum_b mu_b L_b``; a spectrum gives
    ``ln sum_k w_k exp(-sum_b mu_b(E_k) L_b)`` by the log-sum-exp rule (the largest term is
    factored out before the exponentials), with ``w_k`` the detector weights
    (:func:`detector_weights`) times the scintillator's absorption efficiency, normalised to
    sum to 1. With the heel effect (``[source] heel``) each ray has its pixel's weights
    (:func:`ray_weights`).

    Parameters
    ----------
    path_length : (n_rays, n_bodies) float
        Millimetres of each ray in each body's material.
    scene : Scene
        Gives the bodies' materials, the source spectrum and the detector response.
    rows : slice, range or (start, stop), optional
        The block of image rows the rays belong to, in
        :func:`~xray_viz.geometry.detector_rays` order (``n`` consecutive sub-rays per pixel),
        so that a renderer can work in bands of rows; default: the whole detector. Only the
        heel effect needs it.

    Returns
    -------
    (n_rays,) float
        ``<= 0`` for non-negative path lengths; finite for finite ones.

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> scene = xray_viz.load_scene("sphere")          # mu = 0.2 /cm
    >>> log_transmission(np.array([[50.0], [1e5]]), scene).tolist()   # 1e5 mm: exp underflows
    [-1.0, -2000.0]
    """
    return _beam_of(scene).log_transmission(path_length, rows=rows)


def log_variance_transmission(path_length, scene, *, rows=None) -> np.ndarray:
    """``ln`` of the transmitted fraction of the signal's variance along each ray.

    An energy-integrating detector's signal is a compound Poisson sum of the absorbed photons'
    energies: its variance is ``N0 sum_k phi_k q_k^2 eta_k T_k`` (weights ``phi E^2`` for an
    ideal detector), which hardening changes differently from the mean. This is
    ``ln(sum_k u2_k T_k / sum_k u2_k)`` in the log domain, the companion of
    :func:`log_transmission` (which has ``u1_k = phi_k q_k eta_k``); for a counting detector
    or a single energy the two are equal.

    Parameters
    ----------
    path_length : (n_rays, n_bodies) float
    scene : Scene
    rows : optional
        As for :func:`log_transmission`.

    Returns
    -------
    (n_rays,) float

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> log_variance_transmission(np.array([[50.0]]), xray_viz.load_scene("sphere")).tolist()
    [-1.0]
    """
    return _beam_of(scene).log_sums(path_length, rows=rows, variance=True)[1]


def pixel_log_transmission(path_length, scene, *, supersample: int = 1, rows=None,
                           variance: bool | None = None):
    """Per-pixel ``ln(I / I0)`` (and the variance's) from the rays of a block of image rows.

    :func:`log_transmission` of every ray, averaged over each pixel's ``supersample**2`` rays by
    :func:`pixel_log_mean`; with ``variance`` the same for :func:`log_variance_transmission`,
    from the same product over (rays x bodies). This is what a renderer hands to
    :func:`detect_log`.

    Parameters
    ----------
    path_length : (n_rays, n_bodies) float
        In :func:`~xray_viz.geometry.detector_rays` order for the rows.
    scene : Scene
    supersample : int
        Rays per pixel along each axis.
    rows : slice, range or (start, stop), optional
        The image rows the rays cover (default: all).
    variance : bool, optional
        Also the variance's sum; default: when the scene's noise needs it (noise on, an
        energy-integrating detector, a spectrum).

    Returns
    -------
    log_t : (n_rows, W) float
    log_v : (n_rows, W) float or None

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> log_t, log_v = pixel_log_transmission(np.zeros((256 * 256, 1)), scene)
    >>> log_t.shape, bool(log_t.max() == 0), log_v is None
    ((256, 256), True, True)
    """
    beam = _beam_of(scene)
    if variance is None:
        variance = _model(scene).needs_variance(beam)
    return beam.pixel_log_transmission(path_length, supersample=int(supersample), rows=rows,
                                       variance=variance)


def ray_weights(scene, rows=None, *, supersample: int = 1, variance: bool = False) -> np.ndarray:
    """The energy weights of each ray of a block of image rows, each row summing to 1.

    The signal's weights ``u1_k = phi_k q_k eta_k`` (or the variance's, ``u2_k``; see
    :func:`log_variance_transmission`) over the bins of the scene's spectrum with a non-zero
    weight, normalised per ray; with the heel effect each pixel has its own spectrum
    (:mod:`xray_viz.physics.heel`), the same for all of its sub-rays. ``log_transmission`` of
    a ray is ``ln sum_k w_k exp(-sum_b mu_b(E_k) L_b)`` with these weights.

    Parameters
    ----------
    scene : Scene
    rows : slice, range or (start, stop), optional
        Image rows (default: all).
    supersample : int
        Rays per pixel along each axis (``supersample**2`` consecutive rays per pixel).
    variance : bool

    Returns
    -------
    (n_rays, K) float

    Examples
    --------
    >>> import xray_viz
    >>> ray_weights(xray_viz.load_scene("sphere"), rows=(0, 1)).shape      # 256 rays, 1 bin
    (256, 1)
    """
    return _beam_of(scene).ray_weights(rows, supersample=supersample, variance=variance)


def transmission(path_length, scene, *, rows=None) -> np.ndarray:
    """Detected fraction of the beam along each ray, ``I / I0`` (see the module docstring).

    ``exp`` of :func:`log_transmission`; it underflows to 0 behind more than ~745 attenuation
    lengths, where :func:`log_transmission` stays exact.

    Parameters
    ----------
    path_length : (n_rays, n_bodies) float
        Millimetres of each ray in each body's material.
    scene : Scene
        Gives the bodies' materials, the source spectrum and the detector response.
    rows : optional
        As for :func:`log_transmission`.

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
    return np.exp(log_transmission(path_length, scene, rows=rows))


# --------------------------------------------------------------------------------------------
# geometry of the source and detector


def source_detector_distance(scene) -> float:
    """SID in mm: from the source to the detector plane, along the beam axis
    (:attr:`xray_viz.geometry.DetectorFrame.sid`)."""
    return scene.acquisition.frame.sid


def source_object_distance(scene) -> float:
    """SOD in mm: from the source to the *object plane*, along the beam axis.

    The object plane is perpendicular to the beam and passes through the centre of the
    bounding box of all bodies (the detector plane if there are none). It is the plane where
    :func:`magnification` and :func:`focal_spot_blur_mm` are evaluated and where the DICOM
    ``PixelSpacing`` is calibrated (``DistanceSourceToPatient``).

    Examples
    --------
    >>> import xray_viz
    >>> source_object_distance(xray_viz.load_scene("sphere"))      # ball at the origin
    1000.0
    """
    return _dm.source_object_distance(scene.acquisition, scene.bodies)


def magnification(scene) -> float:
    """Geometric magnification ``SID / SOD`` of the object plane (1 for a parallel beam)."""
    return _dm.magnification(scene.acquisition, scene.bodies)


def focal_spot_blur_mm(scene) -> float:
    """Width (FWHM, mm at the detector) of the focal-spot penumbra of the object plane.

    ``focal_spot * (SID - SOD) / SOD = focal_spot * (M - 1)``, the geometric unsharpness of an
    edge in the object plane; 0 for a parallel beam or no focal spot.
    """
    return _model(scene).focal_spot_blur_mm(scene.acquisition, scene.bodies)


def falloff_factor(scene) -> np.ndarray:
    """(H, W) inverse-square and obliquity fall-off of a point source, 1 at the detector centre.

    The photons per pixel fall as ``1 / r^2`` (distance source -> pixel) times ``cos(theta)``
    (the pixel seen obliquely), so with ``r = SID / cos(theta)`` the factor is ``cos^3(theta)``.
    1 everywhere for a parallel beam. On a tilted or offset detector the factor is
    ``(SID / r)^2 cos(theta)`` with ``theta`` the angle between the pixel's ray and the
    detector's normal, ``cos(theta) = D / r`` (``D`` the distance from the source to the
    detector plane, :attr:`~xray_viz.geometry.DetectorFrame.distance`): ``I0`` stays the
    photons of a pixel at ``center`` (on the beam axis, SID from the source) facing the source,
    so the factor is ``cos`` of the tilt there and exceeds 1 on pixels nearer the source than
    SID. (Untilted, ``D = SID`` and this is ``cos^3(theta)``.)

    Examples
    --------
    >>> import xray_viz
    >>> f = falloff_factor(xray_viz.load_scene("sphere"))
    >>> float(f.max()) <= 1.0
    True
    """
    return _dm.falloff_factor(scene.acquisition)


def detect(transmitted, scene, *, i0: float | None = None, rng=None):
    """The detector's reading of the transmitted beam.

    Parameters
    ----------
    transmitted : (H, W) float
        ``I / I0`` per pixel, from :func:`transmission` averaged over each pixel's rays.
    scene : Scene
        ``scene.detector`` gives ``i0``, ``falloff``, ``focal_spot``, ``noise``, ``seed`` and
        the detector model (see :func:`detect_log`).
    i0 : float, optional
        Unattenuated photons per pixel at the detector centre; default ``scene.detector.i0``.
    rng : numpy.random.Generator, optional
        Random numbers for the noise; default ``numpy.random.default_rng(scene.detector.seed)``.

    Returns
    -------
    intensity, line_integral : (H, W) float
        See :func:`detect_log`, which this calls with ``ln(transmitted)``.

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> intensity, li = detect(np.full((2, 2), np.exp(-1.0)), xray_viz.load_scene("sphere"))
    >>> np.allclose(li, 1.0)
    True
    """
    with np.errstate(divide="ignore"):
        log_t = np.log(np.asarray(transmitted, dtype=np.float64))
    return detect_log(log_t, scene, i0=i0, rng=rng)


def flat_field(scene, *, i0: float | None = None) -> np.ndarray:
    """(H, W) the noise-free reading without any body, in detected units.

    ``gain * I0 * F * A``: ``F`` the fall-off (if on), ``A`` the unattenuated beam's detected
    fraction relative to an ideal detector at the centre (the scintillator's absorption and the
    heel effect; 1 for an ideal detector and a uniform beam). The line integral is
    ``-ln(intensity / flat_field)``.

    Examples
    --------
    >>> import xray_viz
    >>> float(flat_field(xray_viz.load_scene("sphere")).max())
    1.0
    """
    model = _model(scene, i0)
    return model.flat_field(beam=_beam_of(scene), acquisition=scene.acquisition)


def detect_log(log_transmitted, scene, *, i0: float | None = None, rng=None,
               log_variance=None):
    """The detector's reading of the transmitted beam, given ``ln(I / I0)`` per pixel.

    Parameters
    ----------
    log_transmitted : (H, W) float
        ``ln(I / I0)`` per pixel (:func:`pixel_log_transmission`, or :func:`log_transmission`
        averaged over each pixel's rays by :func:`pixel_log_mean`).
    scene : Scene
        ``scene.detector`` gives ``i0``, ``falloff``, ``focal_spot``, ``noise``, ``seed``,
        ``scintillator``, ``mtf``, ``electronic_noise`` and ``gain``.
    i0 : float, optional
        Unattenuated photons per pixel at the detector centre; default ``scene.detector.i0``.
    rng : numpy.random.Generator, optional
        Random numbers for the noise; default ``numpy.random.default_rng(scene.detector.seed)``.
    log_variance : (H, W) float, optional
        The variance's transmitted fraction, ``ln`` (:func:`pixel_log_transmission`); without
        it the noise assumes the unattenuated beam's variance-to-mean ratio everywhere (exact
        for a counting detector and a single energy, not behind thick bodies otherwise).

    Returns
    -------
    intensity : (H, W) float
        In detected units: ``gain`` times the signal in photon-equivalents, ``I0 * F * A * T``
        without noise (``A``: :func:`flat_field`'s detected fraction; an energy-integrating
        detector's photon-equivalent is a photon of the unattenuated beam's mean energy). It
        underflows to 0 behind more than ~745 attenuation lengths.
    line_integral : (H, W) float
        ``-ln(intensity / flat_field)``, computed from ``log_transmitted`` directly (and
        through the blurs in the log domain), so it is finite for any finite path length.
        With noise, pixels read as less than half a photon count as half a photon, so the
        line integral stays finite.

    Notes
    -----
    Order of operations (:mod:`xray_viz.physics.detector`): mean signal -> focal-spot blur ->
    quantum noise -> detector blur (MTF) -> electronic noise -> gain.

    Quantum noise: the signal is a compound Poisson sum of the absorbed photons' scores
    (energies for an energy-integrating detector); per pixel, with mean ``M`` and variance
    ``V = I0 F sum_k u2_k T_k`` (the transmitted spectrum's own second moment, from
    ``log_variance``), it is sampled as ``c * Poisson(M / c)``, ``c = V / M``: the exact mean
    and variance (``c`` is the inverse Swank factor ``<E^2> / <E>^2`` of the transmitted
    spectrum, relative to the unattenuated mean energy). A counting detector has ``c = 1``:
    plain Poisson counts. Means above 1e12 photons are sampled from the normal limit. The
    focal-spot blur acts on the mean and the variance alike (it redistributes photons); the
    detector blur acts on the noisy signal (light spread correlates the noise). Electronic
    noise is ``Normal(0, electronic_noise)`` photon-equivalents per pixel.

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> intensity, li = detect_log(np.full((2, 2), -2000.0), xray_viz.load_scene("sphere"))
    >>> li.tolist(), intensity.tolist()
    ([[2000.0, 2000.0], [2000.0, 2000.0]], [[0.0, 0.0], [0.0, 0.0]])
    """
    return _model(scene, i0).read(log_transmitted, beam=_beam_of(scene),
                                  acquisition=scene.acquisition, bodies=scene.bodies,
                                  seed=scene.detector.seed, rng=rng, log_variance=log_variance)


