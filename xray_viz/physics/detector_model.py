"""The detector model: how a detector reads the beam that reaches it.

A :class:`DetectorModel` is built once per detector (:meth:`DetectorModel.of`): ``I0``,
``gain``, quantum and electronic noise, the fall-off of a point source, the focal-spot blur and
the detector's own blur (MTF kernels). :meth:`DetectorModel.read` turns ``ln(I / I0)`` per
pixel (:meth:`~xray_viz.physics.beam.Beam.pixel_log_transmission`) into the detected image
and its flat-field corrected line integral, at an :class:`~xray_viz.geometry.Acquisition`
(the fall-off and the focal-spot blur depend on the pose, the latter also on where the bodies
are). The order of operations is that of :mod:`xray_viz.physics.detector`: mean signal ->
focal-spot blur -> quantum noise -> detector blur (MTF) -> electronic noise -> gain. The
scene functions of :mod:`xray_viz.physics.imaging` (``detect_log``, ``flat_field``...) are
adapters of these.

Examples
--------
>>> import numpy as np, xray_viz
>>> from xray_viz.physics.beam import Beam
>>> scene = xray_viz.load_scene("sphere")
>>> beam = Beam.of(scene.source, scene.bodies, scene.detector)
>>> model = DetectorModel.of(scene.detector)
>>> intensity, li = model.read(np.full((2, 2), -1.0), beam=beam,
...                            acquisition=scene.acquisition, bodies=scene.bodies)
>>> li.tolist() == [[1.0, 1.0], [1.0, 1.0]], bool(np.allclose(intensity, np.exp(-1.0)))
(True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["DetectorModel", "gaussian_kernel", "source_object_distance", "magnification",
           "falloff_factor"]


def source_object_distance(acquisition, bodies) -> float:
    """SOD in mm: from the source to the *object plane* (perpendicular to the beam, through
    the centre of the bodies' bounding box; the detector plane if there are none), along the
    beam axis (:func:`xray_viz.physics.imaging.source_object_distance`)."""
    from xray_viz.geometry import beam_direction

    r0 = np.asarray(acquisition.source.position, dtype=np.float64)
    sid = acquisition.frame.sid
    if not len(bodies):
        return sid
    tris = bodies.triangles.reshape(-1, 3)
    centre = (tris.min(axis=0) + tris.max(axis=0)) / 2
    sod = float((centre - r0) @ beam_direction(r0, acquisition.detector.center))
    return sod if 0 < sod else sid


def magnification(acquisition, bodies) -> float:
    """Geometric magnification ``SID / SOD`` of the object plane (1 for a parallel beam)."""
    if acquisition.source.kind == "parallel":
        return 1.0
    return acquisition.frame.sid / source_object_distance(acquisition, bodies)


def falloff_factor(acquisition) -> np.ndarray:
    """(H, W) inverse-square and obliquity fall-off of a point source, 1 at the detector
    centre (:func:`xray_viz.physics.imaging.falloff_factor`)."""
    w, h = acquisition.detector.shape
    if acquisition.source.kind == "parallel":
        return np.ones((h, w))
    frame = acquisition.frame
    r = acquisition.pixel_distances           # kept by the acquisition
    q = np.divide(frame.sid, r)
    if not frame.plain:               # tilted or offset: the pixels' own distances and angles
        q *= q
        q *= np.divide(frame.distance, r)
        return q
    cube = np.multiply(q, q)
    cube *= q
    return cube


def _apply_falloff(image, acquisition) -> None:
    """``image *= falloff_factor(acquisition)`` in place, without another image-sized array (a
    fresh one costs more in page faults than the arithmetic): divided by the pixels'
    distances (kept by the acquisition) and multiplied by the constants."""
    if acquisition.source.kind == "parallel":
        return
    frame = acquisition.frame
    r = acquisition.pixel_distances
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


@dataclass(frozen=True, eq=False)
class DetectorModel:
    """A detector's reading of the beam: its constants, built once (:meth:`of`).

    Attributes
    ----------
    shape : (int, int)
        ``(W, H)`` pixels.
    pitch : (float, float)
        mm.
    i0 : float
        Unattenuated photons per pixel at the detector centre.
    gain : float
        Detected units per photon-equivalent.
    noise : bool
        Quantum noise (and electronic noise, ``electronic_noise`` photon-equivalents rms).
    electronic_noise : float
    falloff : bool
        Inverse-square and obliquity fall-off of a point source.
    focal_spot : float
        mm (0: an ideal point).
    mtf_kernels : (ndarray, ndarray) or None
        The detector blur's kernels along the rows and the columns
        (:func:`~xray_viz.physics.detector.mtf_kernel`); None without ``[detector] mtf``.
    """

    shape: tuple
    pitch: tuple
    i0: float
    gain: float
    noise: bool
    electronic_noise: float
    falloff: bool
    focal_spot: float
    mtf_kernels: tuple | None

    @classmethod
    def of(cls, detector) -> DetectorModel:
        """The model of a :class:`~xray_viz.scene.Detector`."""
        px, py = detector.pitch
        mtf = None
        if detector.mtf is not None:
            from xray_viz.physics.detector import mtf_kernel

            mtf = (mtf_kernel(detector.mtf, py)[0], mtf_kernel(detector.mtf, px)[0])
        return cls(tuple(detector.shape), (px, py), float(detector.i0), float(detector.gain),
                   bool(detector.noise), float(detector.electronic_noise or 0.0),
                   bool(detector.falloff), float(detector.focal_spot), mtf)

    def focal_spot_blur_mm(self, acquisition, bodies) -> float:
        """Width (FWHM, mm at the detector) of the focal-spot penumbra of the object plane,
        ``focal_spot * |M - 1|``; 0 for a parallel beam or no focal spot."""
        f = self.focal_spot
        if f <= 0 or acquisition.source.kind == "parallel":
            return 0.0
        return f * abs(magnification(acquisition, bodies) - 1.0)

    def blur_sigmas(self, acquisition, bodies) -> tuple[float, float] | None:
        """The focal-spot blur's standard deviations ``(rows, columns)`` in pixels, or None.

        Raises
        ------
        SceneError
            If the blur is wider than the detector itself (a focal spot given in the wrong
            unit): it would make a uniform grey image and a kernel larger than the image.
        """
        fwhm = self.focal_spot_blur_mm(acquisition, bodies)
        if fwhm <= 0:
            return None
        sigma_mm = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
        px, py = self.pitch
        w, h = self.shape
        extent = max(w * px, h * py)
        if not fwhm <= extent:
            raise SceneError(
                f"[detector] focal_spot = {self.focal_spot:g} mm blurs the image by "
                f"{fwhm:.3g} mm (FWHM at the detector), more than the detector's {extent:.3g} "
                "mm: a real focal spot is 0.1-2 mm across; give focal_spot in mm, or 0 for an "
                "ideal point")
        return sigma_mm / py, sigma_mm / px

    def focal_kernels(self, acquisition, bodies):
        """The focal-spot blur's kernels along the rows and columns, or None."""
        sigmas = self.blur_sigmas(acquisition, bodies)
        return None if sigmas is None else tuple(gaussian_kernel(s) for s in sigmas)

    def needs_variance(self, beam) -> bool:
        """Whether the noise needs the variance's sum: noise on, an energy-weighted
        polychromatic signal (for counting detectors and single energies it is the mean)."""
        return self.noise and not beam.counts_photons

    def flat_field(self, *, beam, acquisition) -> np.ndarray:
        """(H, W) the noise-free reading without any body, ``gain * I0 * F * A``
        (:func:`xray_viz.physics.imaging.flat_field`); ``beam`` at ``acquisition``."""
        w, h = self.shape
        A, _ = beam.levels()
        fall = falloff_factor(acquisition) if self.falloff else 1.0
        return self.gain * self.i0 * fall * np.broadcast_to(A, (h, w))

    def read(self, log_transmission, *, beam, acquisition, bodies, seed=None, rng=None,
             log_variance=None, overwrite=False, scatter=None):
        """The detector's reading of ``ln(I / I0)`` per pixel.

        With ``scatter`` (the scattered radiation's mean reading relative to the flat field,
        the units of ``exp(log_transmission)``) the detector reads the total, primary plus
        scatter: its log transmission ``ln(exp(log_transmission) + scatter)`` goes through
        the focal-spot blur, the quantum noise, the MTF and the electronic noise as the
        primary alone does, and the line integral is the total's (scatter lowers the
        contrast). The scatter's noise variance is taken with the unattenuated beam's
        variance-to-mean ratio (``ln(exp(log_variance) + scatter)``): exact for a counting
        detector; for an energy-integrating detector it overstates the variance of the
        scattered photons a little (they have lost energy).

        Parameters
        ----------
        log_transmission : (H, W) float
            From :meth:`~xray_viz.physics.beam.Beam.pixel_log_transmission`.
        beam : Beam
            At ``acquisition`` (:meth:`~xray_viz.physics.beam.Beam.at`).
        acquisition : Acquisition
            The pose (fall-off, focal-spot blur).
        bodies : Bodies
            Where the object plane of the focal-spot blur is.
        seed : int, optional
            The noise's seed (``numpy.random.default_rng(seed)``); None: fresh entropy.
        rng : numpy.random.Generator, optional
            Instead of ``seed``.
        log_variance : (H, W) float, optional
            The variance's transmitted fraction, ``ln`` (with noise on an energy-integrating
            detector); without it the unattenuated beam's variance-to-mean ratio is assumed.
        overwrite : bool
            ``log_transmission`` (a float64 array the caller no longer needs) may receive a
            noise-free, unblurred line integral.
        scatter : (H, W) float, optional
            The mean scatter reading relative to the flat field (>= 0), added to the
            primary's before the focal-spot blur. None: the primary alone (the same numbers
            as without it, bit for bit).

        Returns
        -------
        intensity, line_integral : (H, W) float
            See :func:`xray_viz.physics.imaging.detect_log`.
        """
        log_t = np.asarray(log_transmission, dtype=np.float64)
        if scatter is not None:
            s = np.asarray(scatter, dtype=np.float64)
            if s.shape != log_t.shape or not np.all(np.isfinite(s) & (s >= 0)):
                raise SceneError(f"the scatter image must be finite, >= 0 and of shape "
                                 f"{log_t.shape}, got shape {s.shape}")
            if log_variance is not None:
                log_variance = np.log(np.exp(np.asarray(log_variance, dtype=np.float64)) + s)
            log_t = np.log(np.exp(log_t) + s)          # the total's, a new array
        i0, gain = self.i0, self.gain
        A, B = beam.levels()
        mtf = self.mtf_kernels
        focal = self.focal_kernels(acquisition, bodies)
        if not self.noise and mtf is None and focal is None:
            # the common case, in place: 16 bytes per pixel besides log_t (big detectors); a
            # factor of exactly 1 is skipped (the same numbers, one pass less)
            signal = _exp(log_t)
            if gain * i0 != 1.0:
                signal *= gain * i0
            if self.falloff:
                _apply_falloff(signal, acquisition)
            if not (np.ndim(A) == 0 and A == 1.0):
                signal *= A
            if overwrite and log_t is log_transmission:
                return signal, np.negative(log_t, out=log_t)
            return signal, -log_t
        incident = i0 * falloff_factor(acquisition) if self.falloff else np.full(log_t.shape, i0)
        flat = incident * A
        log_flat = np.log(flat)
        log_signal = _log_blurred(log_flat + log_t, focal)
        if not self.noise:
            if mtf is not None:
                log_signal = _log_convolve(log_signal, mtf)
            return gain * np.exp(log_signal), log_flat - log_signal
        if rng is None:
            rng = np.random.default_rng(seed)
        if beam.counts_photons:
            # photon counts: variance = mean, c = 1 (the same numbers as c * Poisson(M / c))
            c = 1.0
            signal = _poisson(rng, np.exp(log_signal))
        else:
            log_v = log_t if log_variance is None else np.asarray(log_variance, dtype=np.float64)
            log_var = _log_blurred(np.log(incident * B) + log_v, focal)
            log_c = log_var - log_signal                   # variance / mean, per pixel
            c = np.exp(log_c)
            signal = c * _poisson(rng, np.exp(log_signal - log_c))
        if mtf is not None:
            signal = _convolve(signal, mtf)
        if self.electronic_noise > 0:
            signal = signal + rng.normal(0.0, self.electronic_noise, signal.shape)
        line_integral = log_flat - np.log(np.maximum(signal, 0.5 * c))
        return gain * signal, line_integral


def _log_blurred(log_image, kernels) -> np.ndarray:
    """``ln`` of the blur (``kernels``, or none) of ``exp(log_image)``, without underflow."""
    g = np.asarray(log_image, dtype=np.float64)
    return g if kernels is None else _log_convolve(g, kernels)
