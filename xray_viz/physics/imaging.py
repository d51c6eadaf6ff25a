"""Image formation: from path lengths to detected intensities and line integrals.

For photons of energy E, Beer-Lambert's law gives the fraction transmitted along a ray

    T(E) = exp(-sum_b mu_b(E) * L_b)

where ``L_b`` is the effective path length (mm) of the ray in body b's material and ``mu_b`` its
linear attenuation coefficient (1/cm; hence the factor 1/10). A spectrum of photon-fluence
weights ``phi_k`` at energies ``E_k`` is detected as

    counting detector:           T = sum_k phi_k T(E_k)
    energy-integrating detector: T = sum_k phi_k E_k T(E_k) / sum_k phi_k E_k

(:func:`transmission`; one matrix product over (rays x bodies) per chunk of rays gives every
energy bin at once, so the geometry is traced once whatever the number of bins). The detector
then reads ``I = I0 * F * T`` (:func:`detect`), with ``F`` the optional inverse-square and
obliquity fall-off, blurred by the focal spot and, if asked, with Poisson noise. The *line
integral* is the flat-field corrected ``-ln(I / (I0 F))``; for a polychromatic beam it is no
longer proportional to path length (beam hardening).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["body_mu", "log_transmission", "transmission", "pixel_log_mean", "detect", "detect_log", "detector_weights", "falloff_factor",
           "source_object_distance", "source_detector_distance", "magnification",
           "focal_spot_blur_mm", "gaussian_kernel", "MM_PER_CM"]

MM_PER_CM = 10.0

#: Bytes of the (rays x energy bins) work array of one chunk in :func:`transmission`: small
#: enough to stay in the CPU's L2 cache between the product, the exp and the weighted sum
#: (1 MiB: ~870 rays at 150 bins; 32 MiB chunks were 2-3 times slower).
CHUNK_BYTES = 2**20


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
    energies = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
    mu = np.empty((len(energies), len(scene.bodies)))
    for b, body in enumerate(scene.bodies):
        if body.mu is not None:
            mu[:, b] = body.mu
        else:
            from xray_viz.physics.materials import linear_attenuation

            mu[:, b] = linear_attenuation(body.material, energies, density=body.density)
    return mu


def _response(scene) -> str:
    return getattr(scene.detector, "response", "energy")


def detector_weights(spectrum, response: str = "energy") -> np.ndarray:
    """Weight of each energy bin in the detector signal, summing to 1.

    ``"counting"``: the photon fluence ``phi_k``; ``"energy"``: ``phi_k E_k / sum phi E``;
    ``"kerma"``: air kerma, ``phi_k E_k (mu_en/rho)_air(E_k)`` (:mod:`~xray_viz.physics.dosimetry`).

    Examples
    --------
    >>> from xray_viz.physics.spectra import Spectrum
    >>> detector_weights(Spectrum([20.0, 60.0], [1.0, 1.0]), "energy").tolist()
    [0.25, 0.75]
    """
    w = np.asarray(spectrum.weights, dtype=np.float64)
    if response == "energy":
        w = w * spectrum.energies
    elif response == "kerma":
        from xray_viz.physics.dosimetry import air_mass_energy_absorption

        w = w * spectrum.energies * air_mass_energy_absorption(spectrum.energies)
    elif response != "counting":
        raise ValueError(f"detector response must be 'energy', 'counting' or 'kerma', got "
                         f"{response!r}")
    return w / w.sum()


def log_transmission(path_length, scene) -> np.ndarray:
    """Natural log of the detected fraction of the beam along each ray, ``ln(I / I0)``.

    Computed in the log domain, so it stays finite however thick or dense the bodies are
    (``exp(-745)`` already underflows to 0 in float64): a monochromatic beam gives the line
    integral directly, ``-sum_b mu_b L_b``; a spectrum gives
    ``ln sum_k w_k exp(-sum_b mu_b(E_k) L_b)`` by the log-sum-exp rule (the largest term is
    factored out before the exponentials), with ``w_k`` the detector weights
    (:func:`detector_weights`).

    Parameters
    ----------
    path_length : (n_rays, n_bodies) float
        Millimetres of each ray in each body's material.
    scene : Scene
        Gives the bodies' materials, the source spectrum and the detector response.

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
    from xray_viz.physics.spectra import source_spectrum

    L = np.asarray(path_length, dtype=np.float64)
    spectrum = source_spectrum(scene.source)
    mu = body_mu(scene, spectrum.energies) / MM_PER_CM          # (K, B) 1/mm
    if len(spectrum) == 1:
        return -(L @ mu[0])
    weights = detector_weights(spectrum, _response(scene))
    keep = weights > 0
    log_w = np.log(weights[keep])
    minus_mu_t = np.ascontiguousarray(-mu[keep].T)              # (B, K)
    out = np.zeros(len(L))
    inside = np.flatnonzero(np.any(L != 0, axis=1)) if L.shape[1] else np.zeros(0, np.int64)
    chunk = max(16, CHUNK_BYTES // (8 * int(keep.sum())))
    for start in range(0, len(inside), chunk):
        rows = inside[start:start + chunk]
        work = L[rows] @ minus_mu_t                             # (rows, K): -sum_b mu_b L_b
        work += log_w
        top = work.max(axis=1)
        work -= top[:, None]
        np.exp(work, out=work)
        out[rows] = top + np.log(work.sum(axis=1))
    return out


def transmission(path_length, scene) -> np.ndarray:
    """Detected fraction of the beam along each ray, ``I / I0`` (see the module docstring).

    ``exp`` of :func:`log_transmission`; it underflows to 0 behind more than ~745 attenuation
    lengths, where :func:`log_transmission` stays exact.

    Parameters
    ----------
    path_length : (n_rays, n_bodies) float
        Millimetres of each ray in each body's material.
    scene : Scene
        Gives the bodies' materials, the source spectrum and the detector response.

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
    return np.exp(log_transmission(path_length, scene))


def pixel_log_mean(log_values, n_per_pixel: int) -> np.ndarray:
    """``ln`` of the mean of ``exp(log_values)`` over consecutive groups of ``n_per_pixel``.

    Averages the transmissions of each pixel's ``n x n`` supersampled rays in the log domain
    (log-sum-exp), so that the mean of underflowing transmissions is still exact.

    Parameters
    ----------
    log_values : (n_pixels * n_per_pixel,) float
    n_per_pixel : int

    Returns
    -------
    (n_pixels,) float

    Examples
    --------
    >>> import numpy as np
    >>> pixel_log_mean(np.log([1.0, 3.0, 2000.0, 2000.0]), 2).round(6).tolist()
    [0.693147, 7.600902]
    >>> float(pixel_log_mean(np.array([-2000.0, -2001.0]), 2)[0])     # no underflow
    -2000.3798854930417
    """
    a = np.asarray(log_values, dtype=np.float64)
    if n_per_pixel == 1:
        return a
    a = a.reshape(-1, n_per_pixel)
    top = a.max(axis=1)
    with np.errstate(invalid="ignore"):
        rest = np.exp(a - top[:, None]).sum(axis=1)
    return np.where(np.isfinite(top), top + np.log(rest / n_per_pixel), top)


# --------------------------------------------------------------------------------------------
# geometry of the source and detector


def source_detector_distance(scene) -> float:
    """SID in mm: from the source to the detector plane, along the beam axis."""
    return float(np.linalg.norm(np.asarray(scene.source.position) - scene.detector.center))


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
    from xray_viz.geometry import beam_direction

    r0 = np.asarray(scene.source.position, dtype=np.float64)
    sid = source_detector_distance(scene)
    if not scene.bodies:
        return sid
    tris = scene.triangles.reshape(-1, 3)
    centre = (tris.min(axis=0) + tris.max(axis=0)) / 2
    sod = float((centre - r0) @ beam_direction(r0, scene.detector.center))
    return sod if 0 < sod else sid


def magnification(scene) -> float:
    """Geometric magnification ``SID / SOD`` of the object plane (1 for a parallel beam)."""
    if scene.source.kind == "parallel":
        return 1.0
    return source_detector_distance(scene) / source_object_distance(scene)


def focal_spot_blur_mm(scene) -> float:
    """Width (FWHM, mm at the detector) of the focal-spot penumbra of the object plane.

    ``focal_spot * (SID - SOD) / SOD = focal_spot * (M - 1)``, the geometric unsharpness of an
    edge in the object plane; 0 for a parallel beam or no focal spot.
    """
    f = float(getattr(scene.detector, "focal_spot", 0.0) or 0.0)
    if f <= 0 or scene.source.kind == "parallel":
        return 0.0
    return f * abs(magnification(scene) - 1.0)


def falloff_factor(scene) -> np.ndarray:
    """(H, W) inverse-square and obliquity fall-off of a point source, 1 at the detector centre.

    The photons per pixel fall as ``1 / r^2`` (distance source -> pixel) times ``cos(theta)``
    (the pixel seen obliquely), so with ``r = SID / cos(theta)`` the factor is ``cos^3(theta)``.
    1 everywhere for a parallel beam.

    Examples
    --------
    >>> import xray_viz
    >>> f = falloff_factor(xray_viz.load_scene("sphere"))
    >>> float(f.max()) <= 1.0
    True
    """
    from xray_viz.geometry import pixel_coordinates, viewport

    w, h = scene.detector.shape
    if scene.source.kind == "parallel":
        return np.ones((h, w))
    vp = viewport(scene.source.position, scene.detector)
    u, v = pixel_coordinates(vp.shape)
    r = np.linalg.norm(vp.point(u, v) - vp.r0, axis=-1)
    return (np.linalg.norm(vp.FL) / r) ** 3


def gaussian_kernel(sigma: float) -> np.ndarray:
    """The discrete Gaussian kernel of variance ``sigma**2`` (pixels), summing to 1.

    ``T(n) = exp(-t) I_n(t)`` with ``t = sigma**2`` and ``I_n`` the modified Bessel function
    (Lindeberg's discrete analogue of the Gaussian): its variance is exactly ``sigma**2`` for any
    ``sigma``, also far below a pixel, where a sampled Gaussian is only ``[1]`` (a blur of 0.05
    pixel would do nothing) or has far too small a variance. For ``sigma`` of a few pixels it
    equals the sampled Gaussian. Truncated at ``4 sigma + 2`` pixels and
    renormalised.

    Examples
    --------
    >>> k = gaussian_kernel(0.1)
    >>> len(k), round(float(k.sum()), 12), round(float(k @ (np.arange(7) - 3.0) ** 2), 6)
    (7, 1.0, 0.01)
    """
    from scipy.special import ive

    t = float(sigma) ** 2
    radius = int(math.ceil(4.0 * float(sigma))) + 2
    k = ive(np.arange(-radius, radius + 1), t)
    return k / k.sum()


def _blur_sigmas(scene) -> tuple[float, float] | None:
    """The focal-spot blur's standard deviations ``(rows, columns)`` in pixels, or None.

    Raises
    ------
    SceneError
        If the blur is wider than the detector itself (a focal spot given in the wrong unit):
        it would make a uniform grey image and a kernel larger than the image.
    """
    fwhm = focal_spot_blur_mm(scene)
    if fwhm <= 0:
        return None
    sigma_mm = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    px, py = scene.detector.pitch
    w, h = scene.detector.shape
    extent = max(w * px, h * py)
    if not fwhm <= extent:
        from xray_viz.errors import SceneError

        raise SceneError(
            f"[detector] focal_spot = {scene.detector.focal_spot:g} mm blurs the image by "
            f"{fwhm:.3g} mm (FWHM at the detector), more than the detector's {extent:.3g} mm: "
            "a real focal spot is 0.1-2 mm across; give focal_spot in mm, or 0 for an ideal point")
    return sigma_mm / py, sigma_mm / px


def _blur(image, scene) -> np.ndarray:
    """Focal-spot blur: a separable discrete Gaussian of FWHM :func:`focal_spot_blur_mm`.

    The image is extended past its border by mirroring (half-sample symmetric), which keeps
    the total signal exactly, whatever the image.
    """
    sigmas = _blur_sigmas(scene)
    if sigmas is None:
        return image
    from scipy.ndimage import convolve1d

    out = np.asarray(image, dtype=np.float64)
    for axis, sigma in enumerate(sigmas):
        out = convolve1d(out, gaussian_kernel(sigma), axis=axis, mode="reflect")
    return out


def _log_blur(log_image, scene) -> np.ndarray:
    """``ln`` of :func:`_blur` of ``exp(log_image)``, without underflow.

    Each output pixel's sum is taken relative to the largest value under its kernel
    (log-sum-exp), so an image of transmissions far below float64's smallest number (a line
    integral of thousands) is blurred exactly. Same kernel and border rule as :func:`_blur`.
    """
    sigmas = _blur_sigmas(scene)
    g = np.asarray(log_image, dtype=np.float64)
    if sigmas is None:
        return g
    if np.all(g > -700.0):                 # exp(g) is a normal float: blur it directly
        return np.log(_blur(np.exp(g), scene))
    from scipy.ndimage import maximum_filter1d

    for axis, sigma in enumerate(sigmas):
        k = gaussian_kernel(sigma)
        r = len(k) // 2
        top = maximum_filter1d(g, size=len(k), axis=axis, mode="reflect")
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        padded = np.pad(g, pad, mode="symmetric")
        acc = np.zeros_like(g)
        n = g.shape[axis]
        for j, weight in enumerate(k[::-1]):
            window = padded[j:j + n] if axis == 0 else padded[:, j:j + n]
            acc += weight * np.exp(window - top)
        g = top + np.log(acc)
    return g


def _poisson(rng, lam) -> np.ndarray:
    """Poisson samples of means ``lam``; above 1e12 photons the normal limit
    ``N(lam, lam)`` (numpy's Poisson sampler refuses means beyond ~9e18; the normal limit's
    relative skewness there is below 1e-6)."""
    lam = np.asarray(lam, dtype=np.float64)
    big = lam > 1e12
    if not big.any():
        return rng.poisson(lam).astype(np.float64)
    out = np.empty_like(lam)
    out[~big] = rng.poisson(lam[~big])
    out[big] = np.maximum(np.round(rng.normal(lam[big], np.sqrt(lam[big]))), 0.0)
    return out


def detect(transmitted, scene, *, i0: float | None = None, rng=None):
    """The detector's reading of the transmitted beam.

    Parameters
    ----------
    transmitted : (H, W) float
        ``I / I0`` per pixel, from :func:`transmission` averaged over each pixel's rays.
    scene : Scene
        ``scene.detector`` gives ``i0``, ``falloff``, ``focal_spot``, ``noise`` and ``seed``.
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


def detect_log(log_transmitted, scene, *, i0: float | None = None, rng=None):
    """The detector's reading of the transmitted beam, given ``ln(I / I0)`` per pixel.

    Parameters
    ----------
    log_transmitted : (H, W) float
        ``ln(I / I0)`` per pixel (:func:`log_transmission` averaged over each pixel's rays by
        :func:`pixel_log_mean`).
    scene : Scene
        ``scene.detector`` gives ``i0``, ``falloff``, ``focal_spot``, ``noise`` and ``seed``.
    i0 : float, optional
        Unattenuated photons per pixel at the detector centre; default ``scene.detector.i0``.
    rng : numpy.random.Generator, optional
        Random numbers for the noise; default ``numpy.random.default_rng(scene.detector.seed)``.

    Returns
    -------
    intensity : (H, W) float
        ``I0 * F * T`` (photons, or photon-equivalents of mean energy for an
        energy-integrating detector), blurred by the focal spot, with Poisson noise if asked.
        It underflows to 0 behind more than ~745 attenuation lengths.
    line_integral : (H, W) float
        ``-ln(intensity / (I0 * F))``, computed from ``log_transmitted`` directly (and
        through the blur in the log domain), so it is finite for any finite path length.
        With noise, pixels that received no photon count as half a photon so the line
        integral stays finite.

    Notes
    -----
    Noise: a counting detector gets ``Poisson(I)``. An energy-integrating detector's signal is a
    compound Poisson sum of photon energies; it is modelled as ``Poisson(s I) / s`` with ``s`` the
    Swank factor ``<E>^2 / <E^2>`` of the *unattenuated* spectrum, which gives the exact mean and
    variance of a flat field (and of any pixel to the extent hardening leaves ``s`` unchanged).
    Means above 1e12 photons are sampled from the normal limit of the Poisson distribution.

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> intensity, li = detect_log(np.full((2, 2), -2000.0), xray_viz.load_scene("sphere"))
    >>> li.tolist(), intensity.tolist()
    ([[2000.0, 2000.0], [2000.0, 2000.0]], [[0.0, 0.0], [0.0, 0.0]])
    """
    det = scene.detector
    log_t = np.asarray(log_transmitted, dtype=np.float64)
    i0 = float(getattr(det, "i0", 1.0) if i0 is None else i0)
    flat = i0 * falloff_factor(scene) if getattr(det, "falloff", False) else np.full(
        log_t.shape, i0)
    if _blur_sigmas(scene) is None:
        signal = flat * np.exp(log_t)
        line_integral = -log_t
    else:
        log_flat = np.log(flat)
        log_signal = _log_blur(log_flat + log_t, scene)
        signal = np.exp(log_signal)
        line_integral = log_flat - log_signal
    if not getattr(det, "noise", False):
        return signal, line_integral
    from xray_viz.physics.spectra import source_spectrum

    if rng is None:
        rng = np.random.default_rng(getattr(det, "seed", None))
    spectrum = source_spectrum(scene.source)
    s = spectrum.swank_factor if _response(scene) == "energy" else 1.0
    signal = _poisson(rng, signal * s) / s
    line_integral = -np.log(np.maximum(signal, 0.5 / s) / flat)
    return signal, line_integral
