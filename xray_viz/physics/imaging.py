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
"""

from __future__ import annotations

import math

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["body_mu", "log_transmission", "log_variance_transmission", "transmission",
           "pixel_log_mean", "pixel_log_transmission", "ray_weights", "detect", "detect_log",
           "flat_field", "detector_weights", "falloff_factor",
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
        from xray_viz.physics._air import air_mass_energy_absorption

        w = w * spectrum.energies * air_mass_energy_absorption(spectrum.energies)
    elif response != "counting":
        raise SceneError(f"detector response must be 'energy', 'counting' or 'kerma', got "
                         f"{response!r}")
    return w / w.sum()


def _beam(scene):
    """The detector's energy weights at the detector centre, for the signal and its variance.

    Each bin's photons (fluence ``phi_k``, summing to 1) score ``q_k`` each in the detector
    (``q = E / <E>`` energy-integrating, 1 counting; :func:`detector_weights` gives
    ``phi_k q_k``, so that an ideal detector's flat field reads 1 per photon) and are absorbed
    with probability ``eta_k`` (:func:`~xray_viz.physics.detector.absorption_efficiency`). The
    signal is ``sum_k u1_k T_k`` per incident photon and, a compound Poisson sum, its variance
    ``sum_k u2_k T_k``, with

        u1_k = phi_k q_k eta_k,        u2_k = phi_k q_k^2 eta_k.

    Returns
    -------
    spectrum : Spectrum
    keep : (n,) bool
        Bins with a non-zero weight.
    u1, u2 : (n,) float
    """
    from xray_viz.physics.detector import absorption_efficiency
    from xray_viz.physics.spectra import source_spectrum

    spectrum = source_spectrum(scene.source)
    dw = detector_weights(spectrum, _response(scene))
    eta = absorption_efficiency(getattr(scene.detector, "scintillator", None), spectrum.energies)
    keep = dw > 0
    u1 = dw * eta
    if not _counts_photons(scene):
        u2 = np.zeros_like(u1)
        u2[keep] = dw[keep] ** 2 / spectrum.weights[keep] * eta[keep]
    else:
        u2 = u1.copy()                     # q = 1: the variance is the mean
    return spectrum, keep, u1, u2


def _counts_photons(scene) -> bool:
    """Whether every detected photon scores the same (a counting detector or one energy), so
    that the signal is a plain photon count: its variance is its mean."""
    from xray_viz.physics.spectra import source_spectrum

    return _response(scene) == "counting" or len(source_spectrum(scene.source)) == 1


def _heel(scene, keep):
    """The heel effect's interpolation and its grid spectra over the bins ``keep`` as
    ``(interpolation, ratio (N, K))``, or None (``[source] heel`` off)."""
    from xray_viz.physics.heel import heel_interpolator, heel_side

    if heel_side(getattr(scene.source, "heel", None)) is None:
        return None
    interpolation = heel_interpolator(scene)
    return interpolation, np.ascontiguousarray(interpolation.ratio[:, keep])


def _row_range(scene, rows) -> tuple[int, int]:
    """``(start, stop)`` of a block of image rows (None: all of them)."""
    from xray_viz.geometry import row_range

    return row_range(rows, scene.detector.shape[1])


def _rays_per_pixel(scene, rows, n_rays) -> tuple[int, int]:
    """``(first pixel index, rays per pixel)`` of the rays of a block of rows."""
    start, stop = _row_range(scene, rows)
    w = scene.detector.shape[0]
    n_pixels = (stop - start) * w
    if n_rays % n_pixels:
        raise SceneError(f"{n_rays} rays do not cover image rows {start}:{stop} ({n_pixels} "
                         "pixels) in detector_rays order")
    return start * w, n_rays // n_pixels


def _log_sums(path_length, scene, *, rows=None, variance=False, out=None) -> list[np.ndarray]:
    """``ln(sum_k w_k T_k / sum_k w_k)`` per ray for the signal weights (and the variance's).

    One product ``L @ -mu`` per chunk of rays serves both sums; with the heel effect the
    weights of each chunk's rays are interpolated from SpekPy's grid. The products are
    :func:`numpy.einsum`'s own loops, not BLAS: each ray's sum is then the same whatever the
    number of rays of a call (a band, a chunk), and a skinny product (a few bodies) does not
    wait for BLAS threads, which on a loaded machine made them 10-15 times slower. ``out``
    (``(n_rays,)`` float) receives the signal's sum, the first array returned.
    """
    L = np.asarray(path_length, dtype=np.float64)
    spectrum, keep, u1, u2 = _beam(scene)
    mu = body_mu(scene, spectrum.energies[keep]) / MM_PER_CM          # (K, B) 1/mm
    moments = [u1[keep]] + ([u2[keep]] if variance else [])
    heel = _heel(scene, keep)
    if rows is not None or heel is not None:
        first_pixel, per_pixel = _rays_per_pixel(scene, rows, len(L))
    if out is None:
        out = np.empty(len(L))
    if len(mu) == 1 and heel is None:
        line = _line_integrals(L, mu[0], out=out)
        return [line] + ([line.copy()] if variance else [])
    # a bin's weight can underflow to 0 (u2 ~ phi^2 of a bin the filters all but remove): its
    # log is -inf, and exp(-inf) = 0 is exactly its share of the sums below
    with np.errstate(divide="ignore"):
        log_w = [np.log(u) - np.log(u.sum()) for u in moments]
    minus_mu_t = np.ascontiguousarray(-mu.T)                           # (B, K)
    out.fill(0.0)
    outs = [out] + [np.zeros(len(L)) for _ in moments[1:]]
    # a ray through no body transmits everything (its weights sum to 1): ln T = 0
    inside = _inside(L)
    if heel is not None:
        # a pixel's weights are u_k times a bilinear combination of the grid's spectra, so
        # its sum is the same combination of the grid spectra's sums (one small product)
        interpolation, ratio = heel
        levels = [ratio @ u for u in moments]                         # (N,) per grid spectrum
        # every inside ray's grid corners at once (elementwise: the same as chunk by chunk)
        all_corners, all_coef = interpolation.corners(first_pixel + inside // per_pixel)
    K = len(mu)
    chunk = max(16, CHUNK_BYTES // (8 * K))
    base_buf, work_buf = np.empty((chunk, K)), np.empty((chunk, K))
    for start in range(0, len(inside), chunk):
        idx = inside[start:start + chunk]
        part = L[idx]
        # bodies none of these rays crosses add exact zeros to every sum: left out
        crossed = np.flatnonzero(part.any(axis=0))
        factors = minus_mu_t
        if len(crossed) < part.shape[1]:
            part, factors = part[:, crossed], minus_mu_t[crossed]
        base = np.einsum("ij,jk->ik", part, factors, out=base_buf[:len(idx)])
        if heel is not None:
            corners = all_corners[start:start + chunk]
            coef = all_coef[start:start + chunk]
            # each ray's own spectrum ratio: its four grid spectra combined (rays, K)
            mix = np.einsum("nc,nck->nk", coef, ratio[corners])
        for m, dest in enumerate(outs):
            work = np.add(base, log_w[m], out=work_buf[:len(idx)])
            if heel is None:
                dest[idx] = _logsumexp_rows(work)
                continue
            top = work.max(axis=1)
            work -= top[:, None]
            np.exp(work, out=work)
            total = np.einsum("ik,ik->i", work, mix)
            level = (levels[m][corners] * coef).sum(axis=1) / moments[m].sum()
            dest[idx] = top + np.log(total / level)
    return outs


def _line_integrals(L, mu, *, out) -> np.ndarray:
    """``-sum_b mu_b L[:, b]`` per ray into ``out`` (one product for one body)."""
    if L.shape[1] == 1:
        return np.multiply(L[:, 0], -mu[0], out=out)
    if L.shape[1] == 0:
        out.fill(0.0)
        return out
    return np.einsum("ij,j->i", L, -mu, out=out)


def _inside(L) -> np.ndarray:
    """Indices of the rays with a non-zero path length in some body."""
    if not L.shape[1] or not len(L):
        return np.zeros(0, np.int64)
    if L.min() >= 0:                # a sum of non-negative numbers is 0 only if all are
        return np.flatnonzero(np.einsum("ij->i", L))
    return np.flatnonzero(np.any(L != 0, axis=1))


def _logsumexp_rows(work: np.ndarray) -> np.ndarray:
    """``ln sum_k exp(work[:, k])`` per row, the largest term factored out (overwrites work)."""
    top = work.max(axis=1)
    work -= top[:, None]
    np.exp(work, out=work)
    return top + np.log(work.sum(axis=1))


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
    return _log_sums(path_length, scene, rows=rows)[0]


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
    return _log_sums(path_length, scene, rows=rows, variance=True)[1]


def _needs_variance(scene) -> bool:
    """Whether the noise needs the variance sum: noise on, an energy-weighted polychromatic
    signal (for counting detectors and single energies the variance is the mean)."""
    return bool(getattr(scene.detector, "noise", False)) and not _counts_photons(scene)


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
    if variance is None:
        variance = _needs_variance(scene)
    return _pixel_log_transmission(path_length, scene, supersample=int(supersample), rows=rows,
                                   variance=variance)


def _pixel_log_transmission(path_length, scene, *, supersample, rows, variance, out_t=None,
                            out_v=None):
    """:func:`pixel_log_transmission`, written into ``out_t`` (and ``out_v``), ``(n_rows, W)``
    C-contiguous arrays, when given: one ray per pixel then needs no other image-sized array."""
    nn = supersample * supersample
    w = scene.detector.shape[0]
    direct = nn == 1 and out_t is not None and out_t.flags.c_contiguous
    sums = _log_sums(path_length, scene, rows=rows, variance=variance,
                     out=out_t.reshape(-1) if direct else None)
    if direct:
        if variance:
            np.copyto(out_v, sums[1].reshape(-1, w))
        return out_t, out_v
    log_t = pixel_log_mean(sums[0], nn).reshape(-1, w)
    log_v = pixel_log_mean(sums[1], nn).reshape(-1, w) if variance else None
    if out_t is None:
        return log_t, log_v
    np.copyto(out_t, log_t)
    if variance:
        np.copyto(out_v, log_v)
    return out_t, out_v


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
    start, stop = _row_range(scene, rows)
    w = scene.detector.shape[0]
    pixels = np.arange(start * w, stop * w)
    _, keep, u1, u2 = _beam(scene)
    u = (u2 if variance else u1)[keep]
    heel = _heel(scene, keep)
    if heel is None:
        out = np.broadcast_to(u / u.sum(), (len(pixels), len(u)))
    else:
        out = u * heel[0](pixels)[:, keep]
        out /= out.sum(axis=1, keepdims=True)
    return np.repeat(out, int(supersample) ** 2, axis=0)


def _levels(scene):
    """The unattenuated signal and variance per incident photon at each pixel, relative to
    an ideal detector at the centre: ``A = sum_k u1_k``, ``B = sum_k u2_k`` (heel included).

    Returns
    -------
    A, B : float or (H, W) float
    """
    _, keep, u1, u2 = _beam(scene)
    heel = _heel(scene, keep)
    if heel is None:
        return float(u1.sum()), float(u2.sum())
    interpolation, ratio = heel
    w, h = scene.detector.shape
    corners, coef = interpolation.corners(np.arange(w * h))
    A = ((ratio @ u1[keep])[corners] * coef).sum(axis=1)
    B = ((ratio @ u2[keep])[corners] * coef).sum(axis=1)
    return A.reshape(h, w), B.reshape(h, w)


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
    # one sub-ray per row, every pixel along the rows: NumPy's reductions along a short axis
    # (a pixel's 4-16 rays) are 3-5 times slower than these vectorised passes
    work = np.ascontiguousarray(a.reshape(-1, n_per_pixel).T)
    top = np.maximum.reduce(work, axis=0)
    with np.errstate(invalid="ignore"):                 # -inf - -inf: a pixel at -inf
        np.subtract(work, top, out=work)
    np.exp(work, out=work)
    rest = np.add.reduce(work, axis=0)
    del work
    rest /= n_per_pixel
    np.log(rest, out=rest)
    rest += top
    odd = ~np.isfinite(top)
    if odd.any():
        rest[odd] = top[odd]
    return rest


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
    w, h = scene.detector.shape
    if scene.source.kind == "parallel":
        return np.ones((h, w))
    acq = scene.acquisition
    frame = acq.frame
    r = acq.pixel_distances           # kept by the acquisition
    q = np.divide(frame.sid, r)
    if not frame.plain:               # tilted or offset: the pixels' own distances and angles
        q *= q
        q *= np.divide(frame.distance, r)
        return q
    cube = np.multiply(q, q)
    cube *= q
    return cube


def _apply_falloff(image, scene) -> None:
    """``image *= falloff_factor(scene)`` in place, without another image-sized array (a
    fresh one costs more in page faults than the arithmetic): divided by the pixels'
    distances (kept by the acquisition) and multiplied by the constants."""
    if scene.source.kind == "parallel":
        return
    frame = scene.acquisition.frame
    r = scene.acquisition.pixel_distances
    image /= r
    image /= r
    image /= r
    image *= frame.sid ** 2 * (frame.distance if not frame.plain else frame.sid)


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


def _focal_kernels(scene):
    sigmas = _blur_sigmas(scene)
    return None if sigmas is None else tuple(gaussian_kernel(s) for s in sigmas)


def _mtf_kernels(scene):
    """The detector blur's kernels along the rows and columns (:func:`~xray_viz.physics.
    detector.mtf_kernel`), or None without ``[detector] mtf``."""
    mtf = getattr(scene.detector, "mtf", None)
    if mtf is None:
        return None
    from xray_viz.physics.detector import mtf_kernel

    px, py = scene.detector.pitch
    return mtf_kernel(mtf, py)[0], mtf_kernel(mtf, px)[0]


def _convolve(image, kernels) -> np.ndarray:
    """Separable convolution, ``kernels[axis]`` along each axis, mirrored (half-sample
    symmetric) past the border, which keeps the total signal exactly."""
    from scipy.ndimage import convolve1d

    out = np.asarray(image, dtype=np.float64)
    for axis, k in enumerate(kernels):
        out = convolve1d(out, k, axis=axis, mode="reflect")
    return out


def _log_convolve(log_image, kernels) -> np.ndarray:
    """``ln`` of :func:`_convolve` of ``exp(log_image)`` (non-negative kernels), without
    underflow: each output pixel's sum is taken relative to the largest value under its
    kernel (log-sum-exp). Blurs directly when ``exp`` of every value is a normal float."""
    g = np.asarray(log_image, dtype=np.float64)
    if np.all(g > -700.0):
        return np.log(_convolve(np.exp(g), kernels))
    from scipy.ndimage import maximum_filter1d

    for axis, k in enumerate(kernels):
        r = len(k) // 2
        top = maximum_filter1d(g, size=len(k), axis=axis, mode="reflect")
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        padded = np.pad(g, pad, mode="symmetric")
        acc = np.zeros_like(g)
        n = g.shape[axis]
        for j, weight in enumerate(k[::-1]):
            if weight == 0:
                continue
            window = padded[j:j + n] if axis == 0 else padded[:, j:j + n]
            acc += weight * np.exp(window - top)
        g = top + np.log(acc)
    return g


def _blur(image, scene) -> np.ndarray:
    """Focal-spot blur: a separable discrete Gaussian of FWHM :func:`focal_spot_blur_mm`.

    The image is extended past its border by mirroring (half-sample symmetric), which keeps
    the total signal exactly, whatever the image.
    """
    kernels = _focal_kernels(scene)
    return image if kernels is None else _convolve(image, kernels)


def _log_blur(log_image, scene) -> np.ndarray:
    """``ln`` of :func:`_blur` of ``exp(log_image)``, without underflow.

    Each output pixel's sum is taken relative to the largest value under its kernel
    (log-sum-exp), so an image of transmissions far below float64's smallest number (a line
    integral of thousands) is blurred exactly. Same kernel and border rule as :func:`_blur`.
    """
    kernels = _focal_kernels(scene)
    g = np.asarray(log_image, dtype=np.float64)
    return g if kernels is None else _log_convolve(g, kernels)


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
    det = scene.detector
    w, h = det.shape
    i0 = float(getattr(det, "i0", 1.0) if i0 is None else i0)
    A, _ = _levels(scene)
    fall = falloff_factor(scene) if getattr(det, "falloff", False) else 1.0
    return float(getattr(det, "gain", 1.0)) * i0 * fall * np.broadcast_to(A, (h, w))


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
    return _detect_log(log_transmitted, scene, i0=i0, rng=rng, log_variance=log_variance)


#: Fewest values whose ``exp`` is shared out over threads (:func:`_exp`).
_PARALLEL_VALUES = 1 << 16


def _exp(x):
    """``np.exp(x)`` into a new array, the rows of a big image in one piece per thread
    (:mod:`xray_viz._threads`; NumPy's loop releases the GIL): the same numbers, 0.86 instead
    of 1.43 ms at 512 x 512 on two cores (scalar libm ``exp`` on an AVX2 processor)."""
    x = np.asarray(x)
    if x.ndim == 0 or x.size < _PARALLEL_VALUES or x.dtype != np.float64:
        return np.exp(x)
    from xray_viz import _threads

    k = min(_threads.count(), len(x))
    if k <= 1:
        return np.exp(x)
    out = np.empty_like(x)
    cut = [len(x) * j // k for j in range(k + 1)]
    _threads.run_pieces(lambda j: np.exp(x[cut[j]:cut[j + 1]], out=out[cut[j]:cut[j + 1]]), k)
    return out


def _detect_log(log_transmitted, scene, *, i0=None, rng=None, log_variance=None,
                overwrite=False):
    """:func:`detect_log`; with ``overwrite`` (a float64 array the caller no longer needs) a
    noise-free, unblurred line integral is written over ``log_transmitted``."""
    det = scene.detector
    log_t = np.asarray(log_transmitted, dtype=np.float64)
    i0 = float(getattr(det, "i0", 1.0) if i0 is None else i0)
    gain = float(getattr(det, "gain", 1.0))
    A, B = _levels(scene)
    mtf = _mtf_kernels(scene)
    noise = bool(getattr(det, "noise", False))
    falloff = bool(getattr(det, "falloff", False))
    if not noise and mtf is None and _blur_sigmas(scene) is None:
        # the common case, in place: 16 bytes per pixel besides log_t (big detectors); a
        # factor of exactly 1 is skipped (the same numbers, one pass less)
        signal = _exp(log_t)
        if gain * i0 != 1.0:
            signal *= gain * i0
        if falloff:
            _apply_falloff(signal, scene)
        if not (np.ndim(A) == 0 and A == 1.0):
            signal *= A
        if overwrite and log_t is log_transmitted:
            return signal, np.negative(log_t, out=log_t)
        return signal, -log_t
    incident = i0 * falloff_factor(scene) if falloff else np.full(log_t.shape, i0)
    flat = incident * A
    log_flat = np.log(flat)
    log_signal = _log_blur(log_flat + log_t, scene)
    if not noise:
        if mtf is not None:
            log_signal = _log_convolve(log_signal, mtf)
        return gain * np.exp(log_signal), log_flat - log_signal
    if rng is None:
        rng = np.random.default_rng(getattr(det, "seed", None))
    if _counts_photons(scene):
        # photon counts: variance = mean, c = 1 (the same numbers as c * Poisson(M / c))
        c = 1.0
        signal = _poisson(rng, np.exp(log_signal))
    else:
        log_v = log_t if log_variance is None else np.asarray(log_variance, dtype=np.float64)
        log_var = _log_blur(np.log(incident * B) + log_v, scene)
        log_c = log_var - log_signal                   # variance / mean, per pixel
        c = np.exp(log_c)
        signal = c * _poisson(rng, np.exp(log_signal - log_c))
    if mtf is not None:
        signal = _convolve(signal, mtf)
    sigma_e = float(getattr(det, "electronic_noise", 0.0) or 0.0)
    if sigma_e > 0:
        signal = signal + rng.normal(0.0, sigma_e, signal.shape)
    line_integral = log_flat - np.log(np.maximum(signal, 0.5 * c))
    return gain * signal, line_integral
