"""The beam: a source's spectrum as a detector weighs it, through the bodies' materials.

A :class:`Beam` is built once per source and bodies (:meth:`Beam.of`): the spectrum's bins,
each bin's weight in the detector's signal and in its variance (the detector's response and
scintillator, :func:`detector_weights`), and every body's linear attenuation coefficient at
every bin. :meth:`Beam.at` binds it to an :class:`~xray_viz.geometry.Acquisition` (the heel
effect gives each pixel its own spectrum; without it the beam is the same at every pose).
:meth:`Beam.log_transmission` then turns the path lengths of the engines
(:class:`~xray_viz.tracing.engines.Projector`) into ``ln(I / I0)`` per ray, the image before
the detector (:class:`~xray_viz.physics.detector_model.DetectorModel`)::

    image = detector_model.read(beam.log_transmission(L), ...)

The formulas are in :mod:`xray_viz.physics.imaging`, whose scene functions are adapters of
these values.

Examples
--------
>>> import numpy as np, xray_viz
>>> scene = xray_viz.load_scene("sphere")                  # mu = 0.2 /cm, 60 keV
>>> beam = Beam.of(scene.source, scene.bodies, scene.detector)
>>> beam.log_transmission(np.array([[50.0], [100.0]])).tolist()
[-1.0, -2.0]
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["Beam", "body_mu", "detector_weights", "pixel_log_mean", "MM_PER_CM"]

MM_PER_CM = 10.0

#: Bytes of the (rays x energy bins) work array of one chunk of :meth:`Beam.log_transmission`:
#: small enough to stay in the CPU's L2 cache between the product, the exp and the weighted sum.
CHUNK_BYTES = 2**20


def body_mu(bodies, energies_kev) -> np.ndarray:
    """Linear attenuation coefficients of every body at the given energies, in 1/cm.

    A body with a constant ``mu`` has it at every energy; a body with a ``material`` gets
    ``mu(E)`` from :func:`xray_viz.physics.materials.linear_attenuation`.

    Parameters
    ----------
    bodies : Bodies or sequence of Body
    energies_kev : array_like

    Returns
    -------
    (n_energies, n_bodies) float
    """
    energies = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
    mu = np.empty((len(energies), len(bodies)))
    for b, body in enumerate(bodies):
        if body.mu is not None:
            mu[:, b] = body.mu
        else:
            from xray_viz.physics.materials import linear_attenuation

            mu[:, b] = linear_attenuation(body.material, energies, density=body.density)
    return mu


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


@dataclass(frozen=True, eq=False)
class Beam:
    """A source's spectrum as a detector weighs it, and the bodies' attenuation at its bins.

    Each bin's photons (fluence ``phi_k``, summing to 1) score ``q_k`` each in the detector
    (``q = E / <E>`` energy-integrating, 1 counting; :func:`detector_weights` gives
    ``phi_k q_k``, so that an ideal detector's flat field reads 1 per photon) and are absorbed
    with probability ``eta_k`` (:func:`~xray_viz.physics.detector.absorption_efficiency`,
    times the anti-scatter grid's primary transmission at the bin,
    :meth:`~xray_viz.physics.grid.Grid.primary_transmission`, with ``[detector] grid``). The
    signal is ``sum_k u1_k T_k`` per incident photon and, a compound Poisson sum, its variance
    ``sum_k u2_k T_k``, with ``u1_k = phi_k q_k eta_k`` and ``u2_k = phi_k q_k^2 eta_k``.

    Build one with :meth:`of`; :meth:`at` binds it to an acquisition (the heel effect).

    Attributes
    ----------
    spectrum : Spectrum
    keep : (n,) bool
        Bins with a non-zero weight.
    u1, u2 : (n,) float
    mu : (K, n_bodies) float
        Each body's linear attenuation (1/mm) at the ``K`` bins of ``keep``.
    counts_photons : bool
        Every detected photon scores the same (a counting detector or one energy): the
        variance of the signal is its mean.
    shape : (int, int)
        The detector's ``(W, H)``, for rays given by image rows.
    heel : (HeelInterpolation, (N, K) float) or None
        The heel effect's interpolation and its grid spectra over the bins ``keep``, set by
        :meth:`at` when the source has ``heel`` on.
    world : (K,) float or None
        The world medium's linear attenuation (1/mm) at the bins ``keep`` (``[world]``,
        :meth:`of`'s ``world``); None: vacuum. Each ray's path through the world is its length
        from the source (a parallel beam: the plane through the source across the beam) to
        its detector point minus its path lengths in the bodies: one more term of every sum.
    acquisition : Acquisition or None
        The pose :meth:`at` bound, for the rays' lengths when there is a world medium.
    grid : Grid or None
        The detector's anti-scatter grid (``u1`` and ``u2`` include its focused
        transmission).
    off_focus : ((H, W) float, (H, W) float) or None
        Set by :meth:`at` with a grid: each pixel's primary transmission at its ray's angle
        over the focused one, for the signal's and the variance's weights
        (:meth:`~xray_viz.physics.grid.Grid.off_focus`): 1 where the source is at the grid's
        focus, lower toward the edges where it is not (:meth:`levels` multiplies them in).
    """

    spectrum: object
    keep: np.ndarray
    u1: np.ndarray
    u2: np.ndarray
    mu: np.ndarray
    counts_photons: bool
    shape: tuple
    heel: tuple | None = None
    world: np.ndarray | None = None
    acquisition: object = None
    grid: object = None
    off_focus: tuple | None = None

    @classmethod
    def of(cls, source, bodies, detector, *, world=None) -> Beam:
        """The beam of ``source`` through ``bodies`` as ``detector`` weighs it (its
        ``response``, ``scintillator`` and ``grid``), at no pose yet (see :meth:`at`).

        The grid's transmission in ``u1`` and ``u2`` is its focused one, ``Tp(E)``; :meth:`at`
        adds each pixel's off-focus cut-off (the strips lean toward the grid's focus, above
        the detector's middle: a source at another distance sees them cut its rays off
        toward the edges, as the transport's photons are).

        ``world``: the scene's ``[world]`` medium (``{"material": ..., "density": ...}``, as
        :class:`~xray_viz.scene.Scene` checks it), attenuating each ray along its path outside
        the bodies; None (the default) is vacuum."""
        from xray_viz.physics.detector import absorption_efficiency
        from xray_viz.physics.spectra import source_spectrum

        spectrum = source_spectrum(source)
        dw = detector_weights(spectrum, detector.response)
        eta = absorption_efficiency(detector.scintillator, spectrum.energies)
        grid = detector.grid
        if grid is not None:
            # the grid passes each bin's primary photons with its focused transmission: a
            # thinning, so the signal's and the variance's weights both take the factor
            eta = eta * grid.primary_transmission(spectrum.energies)
        keep = dw > 0
        u1 = dw * eta
        counts = detector.response == "counting" or len(spectrum) == 1
        if not counts:
            u2 = np.zeros_like(u1)
            u2[keep] = dw[keep] ** 2 / spectrum.weights[keep] * eta[keep]
        else:
            u2 = u1.copy()                     # q = 1: the variance is the mean
        mu = body_mu(bodies, spectrum.energies[keep]) / MM_PER_CM          # (K, B) 1/mm
        mu_world = None
        if world is not None:
            from xray_viz.physics.materials import linear_attenuation

            mu_world = np.asarray(linear_attenuation(
                world["material"], spectrum.energies[keep], density=world.get("density")),
                dtype=np.float64).reshape(-1) / MM_PER_CM
        return cls(spectrum, keep, u1, u2, mu, counts, tuple(detector.shape), world=mu_world,
                   grid=grid)

    def at(self, acquisition) -> Beam:
        """This beam at an :class:`~xray_viz.geometry.Acquisition`: with the heel effect
        (``[source] heel``) each pixel's weights from SpekPy's grid; otherwise the same beam."""
        from xray_viz.physics.heel import HeelInterpolation, heel_side

        if self.world is not None:
            self = replace(self, acquisition=acquisition, shape=tuple(acquisition.detector.shape))
        if self.grid is not None:
            self = replace(self, off_focus=self._off_focus(acquisition),
                           shape=tuple(acquisition.detector.shape))
        if heel_side(acquisition.source.heel) is None:
            return self if self.heel is None else replace(self, heel=None)
        interpolation = HeelInterpolation(acquisition)
        return replace(self, heel=(interpolation,
                                   np.ascontiguousarray(interpolation.ratio[:, self.keep])),
                       shape=tuple(acquisition.detector.shape))

    def _off_focus(self, acquisition):
        """:attr:`off_focus` at ``acquisition``: the grid's, weighted by ``u1`` and ``u2``
        without the grid's focused transmission."""
        e = self.spectrum.energies[self.keep]
        focused = np.asarray(self.grid.primary_transmission(e), dtype=np.float64)
        return tuple(self.grid.off_focus(acquisition, e, u[self.keep] / focused)
                     for u in (self.u1, self.u2))

    # ----------------------------------------------------------------------------------------

    def _rays_per_pixel(self, rows, n_rays) -> tuple[int, int]:
        """``(first pixel index, rays per pixel)`` of the rays of a block of rows."""
        from xray_viz.geometry import row_range

        w, h = self.shape
        start, stop = row_range(rows, h)
        n_pixels = (stop - start) * w
        if n_rays % n_pixels:
            raise SceneError(f"{n_rays} rays do not cover image rows {start}:{stop} ({n_pixels} "
                             "pixels) in detector_rays order")
        return start * w, n_rays // n_pixels

    def log_sums(self, path_length, *, rows=None, variance=False, out=None) -> list:
        """``ln(sum_k w_k T_k / sum_k w_k)`` per ray for the signal weights (and the variance's).

        One product ``L @ -mu`` per chunk of rays serves both sums; with the heel effect the
        weights of each chunk's rays are interpolated from SpekPy's grid. The products are
        :func:`numpy.einsum`'s own loops, not BLAS: each ray's sum is then the same whatever
        the number of rays of a call (a band, a chunk), and a skinny product (a few bodies)
        does not wait for BLAS threads. ``out`` (``(n_rays,)`` float) receives the signal's
        sum, the first array returned.
        """
        L = np.asarray(path_length, dtype=np.float64)
        keep, u1, u2, mu, heel = self.keep, self.u1, self.u2, self.mu, self.heel
        moments = [u1[keep]] + ([u2[keep]] if variance else [])
        if self.world is not None:          # the world medium: one more column, one more body
            L = np.column_stack([L, self.world_path(L, rows=rows)])
            mu = np.column_stack([mu, self.world])
        if rows is not None or heel is not None:
            first_pixel, per_pixel = self._rays_per_pixel(rows, len(L))
        if out is None:
            out = np.empty(len(L))
        if len(mu) == 1 and heel is None:
            line = _line_integrals(L, mu[0], out=out)
            return [line] + ([line.copy()] if variance else [])
        # a bin's weight can underflow to 0 (u2 ~ phi^2 of a bin the filters all but remove):
        # its log is -inf, and exp(-inf) = 0 is exactly its share of the sums below
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
            levels = [ratio @ u for u in moments]                     # (N,) per grid spectrum
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

    def world_path(self, path_length, *, rows=None) -> np.ndarray:
        """Millimetres of each ray in the world medium: its length from the source (a parallel
        beam: from the plane through the source across the beam) to its detector point
        (:func:`~xray_viz.geometry.detector_rays`' ``t_max``) minus its path lengths in the
        bodies (the columns of ``path_length``: each stretch counted once, for the body that
        wins it), at least 0.

        Parameters
        ----------
        path_length : (n_rays, n_bodies) float
        rows : slice, range or (start, stop), optional
            As :meth:`log_transmission`.

        Returns
        -------
        (n_rays,) float

        Raises
        ------
        SceneError
            No pose bound (:meth:`at`).
        """
        from xray_viz.geometry import detector_rays

        if self.acquisition is None:
            raise SceneError("a beam through a [world] medium needs its pose for the rays' "
                             "lengths: call Beam.at(acquisition) first")
        L = np.asarray(path_length, dtype=np.float64)
        _, per_pixel = self._rays_per_pixel(rows, len(L))
        n = int(round(per_pixel ** 0.5))
        t_max = detector_rays(self.acquisition, supersample=n, rows=rows).t_max
        inside = L.sum(axis=1) if L.shape[1] else 0.0
        return np.maximum(np.broadcast_to(t_max, (len(L),)) - inside, 0.0)

    def log_transmission(self, path_length, *, rows=None) -> np.ndarray:
        """``ln(I / I0)`` along each ray (:func:`xray_viz.physics.imaging.log_transmission`).

        Parameters
        ----------
        path_length : (n_rays, n_bodies) float
            Millimetres of each ray in each body's material.
        rows : slice, range or (start, stop), optional
            The block of image rows the rays belong to (``n`` consecutive sub-rays per pixel,
            :func:`~xray_viz.geometry.detector_rays` order); default the whole detector. Only
            the heel effect needs it.

        Returns
        -------
        (n_rays,) float
        """
        return self.log_sums(path_length, rows=rows)[0]

    def pixel_log_transmission(self, path_length, *, supersample: int = 1, rows=None,
                               variance: bool = False, out_t=None, out_v=None):
        """Per-pixel ``ln(I / I0)`` (and the variance's, with ``variance``) of the rays of a
        block of image rows, each pixel's ``supersample**2`` rays averaged by
        :func:`pixel_log_mean`: ``(log_t, log_v or None)``, each ``(n_rows, W)``; written into
        ``out_t`` (and ``out_v``), C-contiguous arrays, when given (one ray per pixel then needs
        no other image-sized array)."""
        nn = supersample * supersample
        w = self.shape[0]
        direct = nn == 1 and out_t is not None and out_t.flags.c_contiguous
        sums = self.log_sums(path_length, rows=rows, variance=variance,
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

    def ray_weights(self, rows=None, *, supersample: int = 1, variance: bool = False):
        """``(n_rays, K)``: the energy weights of each ray of a block of image rows, each row
        summing to 1 (:func:`xray_viz.physics.imaging.ray_weights`)."""
        from xray_viz.geometry import row_range

        w, h = self.shape
        start, stop = row_range(rows, h)
        pixels = np.arange(start * w, stop * w)
        u = (self.u2 if variance else self.u1)[self.keep]
        if self.heel is None:
            out = np.broadcast_to(u / u.sum(), (len(pixels), len(u)))
        else:
            out = u * self.heel[0](pixels)[:, self.keep]
            out /= out.sum(axis=1, keepdims=True)
        return np.repeat(out, int(supersample) ** 2, axis=0)

    def levels(self):
        """The unattenuated signal and variance per incident photon at each pixel, relative
        to an ideal detector at the centre: ``A = sum_k u1_k``, ``B = sum_k u2_k`` (heel
        and a grid's :attr:`off_focus` included): two floats, or two ``(H, W)`` arrays with
        the heel effect or a grid."""
        u1, u2, keep = self.u1, self.u2, self.keep
        if self.heel is None:
            A, B = float(u1.sum()), float(u2.sum())
        else:
            interpolation, ratio = self.heel
            w, h = self.shape
            corners, coef = interpolation.corners(np.arange(w * h))
            A = ((ratio @ u1[keep])[corners] * coef).sum(axis=1).reshape(h, w)
            B = ((ratio @ u2[keep])[corners] * coef).sum(axis=1).reshape(h, w)
        if self.off_focus is not None:
            A, B = A * self.off_focus[0], B * self.off_focus[1]
        return A, B
