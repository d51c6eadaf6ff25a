"""The main job: render a scene's radiograph.

The pipeline's stages are values, each built once and reused (``ARCHITECTURE.md``):

    bodies -> Projector -> path lengths -> Beam -> DetectorModel -> image

a :class:`~xray_viz.tracing.engines.Projector` (bodies and an engine) gives the path lengths
of an :class:`~xray_viz.geometry.Acquisition`; a :class:`~xray_viz.physics.beam.Beam` (source
spectrum and the bodies' attenuation) turns them into ``ln(I / I0)``; a
:class:`~xray_viz.physics.detector_model.DetectorModel` reads that as the image. :func:`render`
builds the three values from a scene; :func:`xray_viz.scan` builds them once for every
projection.

Memory
------
A render works in *bands* of detector rows: the engine gives the path lengths of one band's
rays through every body, ``(rays in band, n_bodies)``, which become ``ln(I / I0)`` per ray
(:func:`~xray_viz.physics.imaging.log_transmission`), averaged over each pixel's rays
(:func:`~xray_viz.physics.imaging.pixel_log_mean`) into the band's rows of an ``(H, W)``
log-transmission image and an ``(H, W)`` total-path-length image. The detector model
(:func:`~xray_viz.physics.imaging.detect_log`: focal-spot blur, noise) then runs once on the
whole image. A band holds about :data:`BAND_BYTES` of path lengths (``rays x bodies x 8``
bytes; at least one pixel row), so peak memory is O(output + meshes), not O(pixels x bodies):
about 48 bytes per pixel for the images and the detector model's temporaries (more with a
focal spot, fall-off or noise; see :func:`memory_needed`), plus the meshes, plus a few bands.
A job whose output cannot fit in the memory this machine has available is refused before any
work (:func:`check_memory`).

Per-body path lengths ``(H, W, n_bodies)`` are computed only when asked for:
``render(scene, path_lengths=True)``, or on first access of :attr:`Radiograph.path_length`
(a second trace).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from xray_viz.errors import SceneError
from xray_viz.geometry import check_supersample
from xray_viz.tracing.engines import ENGINES, Projector
from xray_viz.tracing.hits import Hits

__all__ = ["Radiograph", "render", "stages", "scene_projector", "image", "ENGINES", "QUANTITIES", "BAND_BYTES", "memory_needed",
           "check_memory", "available_memory", "SCATTER_MODES", "ScatterSource",
           "SCATTER_QUANTITIES"]

#: The values of ``render(..., scatter=)`` (and ``xray-viz render --scatter``, where None is
#: ``none``).
SCATTER_MODES = (None, "mc", "kernel")

#: Names accepted by ``--quantity`` and :meth:`Radiograph.quantity`.
QUANTITIES = ("intensity", "line-integral", "path-length")

#: The views of a radiograph rendered with scatter (:meth:`Radiograph.quantity`): the
#: detected total (the intensity), its noise-free primary and scatter parts, and their ratio.
SCATTER_QUANTITIES = ("total", "primary", "scatter", "spr")

#: Bytes of path lengths (``rays x bodies x 8``) that one band of a render holds at most (but
#: always at least one pixel row): the band size of :func:`render`.
BAND_BYTES = 64 << 20

#: Bytes of path lengths per call of :func:`~xray_viz.physics.imaging.log_transmission` (whole
#: image rows, at least one, in blocks counted from the top row whatever the bands: see
#: :class:`_LogBlocks`).
LOG_BLOCK_BYTES = 16 << 20



@dataclass(frozen=True, eq=False)
class Radiograph:
    """A rendered radiograph.

    Arrays are in image orientation: shape ``(H, W)``, row 0 at the top of the detector
    (v = 1), column 0 at its left (u = 0), as seen from the source.

    Attributes
    ----------
    intensity : (H, W) float
        Detected intensity, ``I0 exp(-line_integral)`` for a monochromatic beam.
    line_integral : (H, W) float
        ``sum_b mu_b L_b`` (dimensionless), ``-ln(I / I0)``.
    total_path_length : (H, W) float
        Millimetres of each pixel's rays inside any body (the mean over its supersampled rays).
    body_names : list of str
    timing : dict
        Seconds spent in ``trace`` (rays, hits, path lengths), ``image`` and ``total``.
    engine : str
    scene : Scene
    hits : Hits or None
        Every hit of every ray, when asked for with ``keep_hits=True`` (numpy engine).
    supersample : int
        Rays per pixel along each axis.
    lod : LevelOfDetail or None
        What ``render(..., max_error=...)`` chose per body (:mod:`xray_viz.lod`); None
        without ``max_error``. :attr:`scene` is then the scene with the reduced meshes.
    primary : (H, W) float or None
        With ``render(..., scatter="mc" | "kernel")``: the noise-free mean primary signal, in
        the units of :attr:`intensity` (the flat field ``gain I0 F A`` times the
        transmission; before the focal-spot blur and the MTF). None without scatter.
    scatter : (H, W) float or None
        With ``scatter=``: the noise-free mean scatter signal in the units of
        :attr:`intensity` (the flat field times the scatter relative to it), >= 0; the
        detected :attr:`intensity` reads ``primary + scatter`` (through the blur and the
        noise) and :attr:`line_integral` is the total's, ``-ln((P + S) / flat)``. None
        without scatter (the image is then the primary alone, bit for bit as before).
    scatter_details : dict or None
        With ``scatter=``: ``mode`` (``"mc"`` or ``"kernel"``); for ``"mc"`` also
        ``histories``, ``seed``, ``error``, the (H, W) standard error of :attr:`scatter`
        (the three scattered images' errors added in quadrature, through the smoothing if
        any), and with ``scatter_smoothing`` ``smoothing_mm``.
    """

    intensity: np.ndarray
    line_integral: np.ndarray
    total_path_length: np.ndarray
    body_names: list
    timing: dict
    engine: str
    scene: object = field(repr=False, default=None)
    hits: Hits | None = field(repr=False, default=None)
    supersample: int = 1
    _path_length: np.ndarray | None = field(repr=False, default=None)
    lod: object = field(repr=False, default=None)
    primary: np.ndarray | None = field(repr=False, default=None)
    scatter: np.ndarray | None = field(repr=False, default=None)
    scatter_details: dict | None = field(repr=False, default=None)

    @property
    def spr(self) -> np.ndarray | None:
        """(H, W) the scatter-to-primary ratio ``scatter / primary`` (noise-free), or None
        without scatter; ``inf`` where the primary underflows to 0 under some scatter, 0
        where both are 0."""
        if self.scatter is None:
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = self.scatter / self.primary
        ratio[(self.scatter == 0) & (self.primary == 0)] = 0.0
        return ratio

    @property
    def scope(self) -> str:
        """What the image includes, for anyone who uses it as data: the primary radiation
        alone, or with the scatter of the model asked for
        (:func:`xray_viz.physics.dosimetry.scatter_scope`)."""
        from xray_viz.physics.dosimetry import scatter_scope

        mode = None if self.scatter_details is None else self.scatter_details["mode"]
        return scatter_scope(mode)

    @property
    def air_kerma(self):
        """The exposure's incident air kerma (:class:`~xray_viz.physics.dosimetry.AirKerma`)
        when the scene's source gives ``mas``; None otherwise."""
        if self.scene is None or self.scene.source.mas is None:
            return None
        from xray_viz.physics.dosimetry import air_kerma

        return air_kerma(self.scene)

    @property
    def path_length(self) -> np.ndarray:
        """(H, W, n_bodies) float: millimetres of each pixel's rays in each body's material
        (innermost / later body wins; the mean over a pixel's supersampled rays).

        Filled by ``render(..., path_lengths=True)``; otherwise computed on first access by
        tracing the scene again with the same engine and supersampling (the cost of the trace
        part of :attr:`timing`, and ``8 x n_bodies`` bytes per pixel), then kept.

        Raises
        ------
        SceneError
            If the ``(H, W, n_bodies)`` array cannot fit in the memory available.
        """
        if self._path_length is None:
            if self.scene is None:
                raise SceneError("this Radiograph has no scene to trace its path lengths from")
            n = self.supersample
            check_memory(self.scene, supersample=n, engine=self.engine, path_lengths=True,
                         images=False)
            w, h = self.scene.detector.shape
            out = np.empty((h, w, len(self.body_names)))
            _band_loop(scene_projector(self.scene, self.engine), self.scene.acquisition, n,
                       per_body=out)
            object.__setattr__(self, "_path_length", out)
        return self._path_length

    def quantity(self, name: str) -> np.ndarray:
        """The (H, W) image of ``"intensity"``, ``"line-integral"`` or ``"path-length"``; of a
        radiograph rendered with scatter also ``"total"`` (the intensity: what the detector
        read), ``"primary"``, ``"scatter"`` and ``"spr"`` (:data:`SCATTER_QUANTITIES`)."""
        if name in ("intensity", "total"):
            if name == "total" and self.scatter is None:
                self._refuse_scatter_view(name)
            return self.intensity
        if name in SCATTER_QUANTITIES:
            if self.scatter is None:
                self._refuse_scatter_view(name)
            return self.spr if name == "spr" else getattr(self, name)
        if name in ("line-integral", "line_integral"):
            return self.line_integral
        if name in ("path-length", "path_length"):
            return self.total_path_length
        raise SceneError(f"unknown quantity {name!r}; choose one of {', '.join(QUANTITIES)}"
                         + (f", {', '.join(SCATTER_QUANTITIES)}" if self.scatter is not None
                            else ""))

    @staticmethod
    def _refuse_scatter_view(name):
        raise SceneError(f"quantity {name!r} needs a radiograph rendered with scatter: "
                         "render(scene, scatter='mc', histories=...) or scatter='kernel'")

    def display(self, quantity: str = "intensity") -> np.ndarray:
        """The (H, W) image as shown by :meth:`plot` and in a notebook, 0 (black) to 1
        (white), attenuation bright: ``quantity`` windowed to its finite values, an
        intensity inverted (as the PNG that ``xray-viz render`` writes shows it); a
        non-finite pixel is drawn at the window's attenuating end.

        Examples
        --------
        >>> import xray_viz
        >>> shown = xray_viz.render(xray_viz.load_scene("sphere")).display()
        >>> round(float(shown[0, 0]), 6), round(float(shown[128, 128]), 6)  # open beam, ball
        (0.0, 1.0)
        """
        a = np.asarray(self.quantity(quantity), dtype=np.float64)
        finite = np.isfinite(a)
        lo, hi = (a[finite].min(), a[finite].max()) if finite.any() else (0.0, 0.0)
        scaled = (np.where(finite, a, hi) - lo) / (hi - lo) if hi > lo else np.zeros_like(a)
        if quantity in ("intensity", "total", "primary"):
            scaled = 1.0 - scaled
            scaled[~finite] = 1.0
        return np.clip(scaled, 0.0, 1.0)

    def plot(self, quantity: str = "intensity", *, ax=None, colorbar: bool = True):
        """Draw the radiograph with matplotlib, attenuation bright, axes in mm on the detector.

        Parameters
        ----------
        quantity : {"intensity", "line-integral", "path-length"}
            Or, rendered with scatter, ``"total"``, ``"primary"``, ``"scatter"``, ``"spr"``.
        ax : matplotlib.axes.Axes, optional
            Where to draw (default: a new figure's axes).
        colorbar : bool
            A colour bar in the quantity's own values.

        Returns
        -------
        matplotlib.image.AxesImage
            Its data is the quantity itself (``get_array()``); intensity uses the reversed grey
            map, so that attenuation is bright as on a film viewer.
        """
        if ax is None:
            import matplotlib.pyplot as plt

            _, ax = plt.subplots()
        a = self.quantity(quantity)
        h, w = a.shape
        extent = None
        if self.scene is not None:
            pu, pv = np.broadcast_to(np.asarray(self.scene.detector.pitch, dtype=float), (2,))
            extent = (-w * pu / 2, w * pu / 2, -h * pv / 2, h * pv / 2)
            ax.set_xlabel("u (mm)")
            ax.set_ylabel("v (mm)")
        cmap = ("gray_r" if quantity in ("intensity", "total", "primary")
                else "viridis" if quantity in ("scatter", "spr") else "gray")
        shown = ax.imshow(a, cmap=cmap, extent=extent, interpolation="nearest")
        ax.set_title(f"{quantity} ({w} x {h}, engine {self.engine})")
        if colorbar:
            ax.figure.colorbar(shown, ax=ax,
                               label={"intensity": "I / I0", "line-integral": "sum mu L",
                                      "line_integral": "sum mu L", "total": "I / I0",
                                      "primary": "I / I0", "scatter": "I / I0",
                                      "spr": "scatter / primary"}.get(quantity, "mm"))
        return shown

    def _repr_png_(self) -> bytes:
        """An 8-bit PNG of :meth:`display` (Jupyter shows it as the cell's output)."""
        import io

        from PIL import Image

        buffer = io.BytesIO()
        Image.fromarray(np.round(self.display() * 255).astype(np.uint8)).save(buffer, "PNG")
        return buffer.getvalue()


def _band_rows(projector, acquisition, n) -> int:
    """Image rows per band: ``rows x W x n^2`` rays of path lengths fill :data:`BAND_BYTES`
    (with the engine's working memory per ray), at least one row."""
    w = acquisition.detector.shape[0]
    per_ray = 8 * max(1, projector.columns) + projector.ray_bytes
    return max(1, BAND_BYTES // (w * n * n * per_ray))


def _windows(projector, acquisition, n, keep_hits=False):
    """``(r0, r1, L, hits)`` for consecutive windows of image rows covering the detector."""
    h = acquisition.detector.shape[1]
    rows = _band_rows(projector, acquisition, n)
    if keep_hits:                      # the hits of every ray, with global ray numbers
        L, hits = projector.hits(acquisition, supersample=n)
        yield 0, h, L, hits
        return
    if rows >= h and projector.keeps_results:
        # It fits in one band: the whole frame, through the results the engine keeps.
        yield 0, h, projector.path_lengths(acquisition, supersample=n), None
        return
    for r0, r1, L in projector.windows(acquisition, supersample=n, rows=rows):
        yield r0, r1, L, None


class _LogBlocks:
    """ln(I / I0) per pixel, computed by fixed blocks of image rows whatever the bands.

    :func:`~xray_viz.physics.imaging.log_transmission` multiplies path lengths by the bodies'
    attenuation through BLAS, whose rounding depends on how many rays a call holds (its
    threads and unrolled loops split them differently), so the same ray could differ in the
    last bit between bands of different sizes. Every call therefore holds one block of
    :data:`LOG_BLOCK_BYTES` of whole image rows, counted from row 0 whatever the bands are: a
    band's rows that do not fill their block wait in a buffer of one block for the next band.
    The image is then the same bit for bit for any band size.
    """

    def __init__(self, beam, n, log_t, log_v=None):
        w, h = beam.shape
        self.beam, self.nn, self.w, self.h, self.out = beam, n * n, w, h, log_t
        self.n, self.out_v = n, log_v
        nb = max(1, beam.mu.shape[1])
        self.rows = max(1, min(h, LOG_BLOCK_BYTES // (w * self.nn * nb * 8)))
        self.per_row = w * self.nn
        self.carry = None               # rows [c0, c0 + filled) of the block starting at c0
        self.c0 = self.filled = 0

    def _block(self, r0, L):
        """Write the log-transmission image rows of the block starting at row ``r0``."""
        r1 = r0 + len(L) // self.per_row
        self.beam.pixel_log_transmission(
            L, supersample=self.n, rows=(r0, r1), variance=self.out_v is not None,
            out_t=self.out[r0:r1], out_v=None if self.out_v is None else self.out_v[r0:r1])

    def add(self, r0, r1, L):
        """The path lengths ``L`` of image rows ``r0 .. r1 - 1`` (bands come in row order)."""
        R, per_row = self.rows, self.per_row
        r = r0
        while r < r1:
            b0 = (r // R) * R                       # the block holding row r
            b1 = min(self.h, b0 + R)
            take = min(r1, b1)
            part = L[(r - r0) * per_row:(take - r0) * per_row]
            if r == b0 and take == b1:              # the whole block is in this band
                self._block(b0, part)
            else:                                   # a piece: gather it
                if self.carry is None:
                    self.carry = np.empty((R * per_row, L.shape[1]))
                if r == b0:
                    self.c0, self.filled = b0, 0
                assert self.c0 == b0 and self.filled == (r - b0) * per_row
                self.carry[self.filled:self.filled + len(part)] = part
                self.filled += len(part)
                if take == b1:
                    self._block(b0, self.carry[:self.filled])
            r = take


def _band_loop(projector, acquisition, n, *, beam=None, log_t=None, log_v=None, total=None,
               per_body=None, keep_hits=False, progress=None, weighted=None):
    """Trace the projector's bodies at the acquisition band by band into the (H, W) images
    given (any may be None; ``log_t`` and ``log_v`` need the ``beam`` at the acquisition;
    ``weighted = (w, out)``: ``out`` (H, W, k) receives each pixel's mean ``L @ w``, ``w``
    (n_bodies, k)).

    ``progress(rows_done, rows)`` is called after each band (default:
    :func:`xray_viz.progress.rows`, the command line's progress bar; a no-op elsewhere).
    Returns the seconds spent tracing and in the per-band image work, and the hits (or None).
    """
    if progress is None:
        from xray_viz.progress import rows as progress
    w, h = acquisition.detector.shape
    nb = projector.columns
    nn = n * n
    t_trace = t_image = 0.0
    hits = None
    blocks = _LogBlocks(beam, n, log_t, log_v) if log_t is not None else None
    t0 = time.perf_counter()
    for r0, r1, L, band_hits in _windows(projector, acquisition, n, keep_hits):
        t1 = time.perf_counter()
        t_trace += t1 - t0
        sums = None
        if total is not None and nn == 1:
            # each ray's total, which also tells whether its path lengths are finite
            sums = _row_sums(L, out=total[r0:r1].reshape(-1))
        if not _valid(L, sums):
            L = _checked(L, projector, acquisition, r0)   # raises, or reads rounding -0 as 0
            if sums is not None:
                _row_sums(L, out=sums)
        hits = band_hits if band_hits is not None else hits
        if blocks is not None:
            # ln(I / I0) of every ray, averaged (in I) over each pixel's n x n rays, in the
            # log domain.
            blocks.add(r0, r1, L)
        if weighted is not None:
            for c in range(weighted[0].shape[1]):
                # no BLAS threads to wait for; one einsum per column (its loop for one
                # vector is several times faster than for two)
                lw = np.einsum("ij,j->i", L, weighted[0][:, c])
                weighted[1][r0:r1, :, c] = (lw if nn == 1 else lw.reshape(-1, nn).mean(axis=1)
                                            ).reshape(r1 - r0, w)
            del lw
        if (total is not None and nn > 1) or per_body is not None:
            # (pixels, bodies): the mean over each pixel's rays (one ray: the same numbers).
            mean = L if nn == 1 else L.reshape((r1 - r0) * w, nn, nb).mean(axis=1)
            if total is not None and nn > 1:
                total[r0:r1] = mean.sum(axis=1).reshape(r1 - r0, w)
            if per_body is not None:
                per_body[r0:r1] = mean.reshape(r1 - r0, w, nb)
            del mean
        del L
        progress(r1, h)
        t0 = time.perf_counter()
        t_image += t0 - t1
    return t_trace, t_image, hits


def _row_sums(L, *, out) -> np.ndarray:
    """Each ray's path length in any body, ``L.sum(axis=1)``, into ``out`` (no temporary):
    a copy for one body. Several bodies keep NumPy's own reduction (its pairwise order), so
    that the total path length is bit for bit ``Radiograph.path_length.sum(axis=2)``;
    :func:`numpy.einsum` would be 3 times faster but round differently."""
    if L.shape[1] == 1:
        np.copyto(out, L[:, 0])
        return out
    with np.errstate(invalid="ignore", over="ignore"):    # bad values: _checked's message
        return np.add.reduce(L, axis=1, out=out)


#: Path lengths down to this fraction of the source-detector distance below zero are rounding
#: (a ray grazing a silhouette: entry and exit depths equal to the last bits) and read as 0.
NEGATIVE_TOLERANCE = 1e-9


def _valid(L, sums=None) -> bool:
    """Whether every path length is finite and non-negative: ``L.min() >= 0`` (NaN if any is
    NaN) and the largest finite, read from the rays' sums when given (a sum of non-negative
    numbers is infinite only if one of them is: one pass over ``L`` instead of two)."""
    if not L.size:
        return True
    if not float(L.min()) >= 0.0:
        return False
    return bool(np.isfinite(float((L if sums is None else sums).max())))


def _checked(L, projector, acquisition, r0):
    """The band's path lengths, after checking the invariants every engine must keep: finite
    and non-negative (a negative one would give I > I0). Rounding-level negatives are read as
    0; anything else raises :class:`~xray_viz.errors.EngineError` instead of writing a wrong
    image."""
    if _valid(L):
        return L
    from xray_viz.errors import EngineError

    sid = float(np.linalg.norm(acquisition.source.position - acquisition.detector.center))
    bad = ~np.isfinite(L) | (L < -NEGATIVE_TOLERANCE * sid)
    if bad.any():
        ray, body = np.argwhere(bad)[0]
        w = acquisition.detector.shape[0]
        raise EngineError(
            f"internal error: engine {projector.name!r} gave path length {L[ray, body]!r} mm "
            f"for body {projector.bodies[int(body)].name!r} on image row "
            f"{r0 + int(ray) // w}; the image is not written. Please report it with the scene; "
            f"engine {projector.fallback!r} may trace it meanwhile")
    if not L.flags.writeable:
        L = L.copy()
    np.maximum(L, 0.0, out=L)
    return L


def _check_transmission(log_t):
    """No pixel may transmit more than the open beam (I <= I0): mu >= 0 and L >= 0 make every
    energy bin's ``exp(-sum mu L) <= 1``."""
    if not log_t.size:
        return
    top, low = float(log_t.max()), float(log_t.min())       # NaN if any is NaN
    if not (top <= 1e-9 and np.isfinite(low)):
        from xray_viz.errors import EngineError

        raise EngineError(f"internal error: a pixel's transmission ln(I/I0) = {top!r} (> 0, or "
                          "not finite); the image is not written. Please report it with the "
                          "scene")


# ------------------------------------------------------------------------------------------
# memory


def available_memory() -> int | None:
    """Bytes of memory this process may still take, or None where that is not known: the
    least of the machine's ``MemAvailable``, the process's ``RLIMIT_AS`` / ``RLIMIT_DATA``
    and its control group's limit (``xray_viz._memory.available_memory``)."""
    from xray_viz._memory import available_memory as limit

    return limit()


def _mesh_bytes(scene) -> int:
    """What the engines allocate per mesh (copies in spatial order, projections, per-triangle
    set-up), about 100 bytes per vertex and 320 per face."""
    total = 0
    for body in scene.bodies:
        total += 100 * len(body.vertices) + 320 * len(body.faces)
    return total


def _image_bytes_per_pixel(scene) -> int:
    """Bytes per pixel that a render allocates for its (H, W) images, at the peak.

    The log-transmission and total-path-length images (8 + 8), the intensity and line
    integral (8 + 8) and the detector model's temporaries (the flat field and one exponential,
    8 + 8); a focal-spot blur adds about 40 (log-domain blur), the fall-off of a point source
    about 80 (the pixels' positions), noise about 40. The output file's array (a float32 TIFF
    and its copy, or a 16-bit PNG's scaling, at most 24) is made after the log-transmission
    image and the temporaries are freed, so it fits under that peak.
    """
    from xray_viz.physics.detector_model import DetectorModel

    model = DetectorModel.of(scene.detector)
    per = 48
    if model.blur_sigmas(scene.acquisition, scene.bodies) is not None:
        per += 40
    if model.falloff and scene.source.kind != "parallel":
        per += 80
    if model.noise:
        per += 40
    return per


def _scatter_bytes_per_pixel(scatter, *, grid=False) -> int:
    """Bytes per pixel that the scatter of a render or of a scan's projection allocates, at
    the peak (0 without scatter).

    Every mode: the scatter image ``s`` (8), and what :func:`render` keeps in its
    :class:`Radiograph` (``primary`` and ``scatter``, 8 + 8) with the flat field they are made
    from (8). ``"kernel"``: the path lengths weighted by material the tracer sums for the
    model, with their coherent part (16), and the model's per-pixel work on the whole image
    at the most, without pre-averaging (the image's ``ln(1 / T)``, its look-up index, the
    thickness, source and group gathered, the cell and group indices, the source times the
    thickness, the interpolated output, the coherent share's source and its two
    temporaries: 12 arrays of 8, 96); with a ``grid``, the off-focus cut-off it divides by
    and its interpolation's points, weights and indices (64). ``"mc"``: the transport's
    tallies (a sum and its square per pixel for each of its 4 images, 64) held by the run's
    total, a group's and one batch per thread, its means and errors (128), the scatter's
    variance and error (16).
    """
    if scatter in (None, "none"):
        return 0
    per = 8 + 24
    if scatter == "kernel":
        return per + 16 + 96 + (64 if grid else 0)
    from xray_viz import _threads

    return per + (2 + max(1, _threads.count())) * 64 + 128 + 16


def memory_needed(scene, *, supersample: int | None = None, engine: str = "fast",
                  path_lengths: bool = False, images: bool = True,
                  keep_hits: bool = False, scatter: str | None = None) -> dict:
    """Estimated peak memory of :func:`render` (bytes), by part.

    Parameters
    ----------
    scene : Scene
    supersample : int, optional
        Default: the scene's.
    engine : str
    path_lengths : bool
        Count the per-body path lengths ``(H, W, n_bodies)`` (8 bytes each).
    images : bool
        Count the output images (see :func:`_image_bytes_per_pixel`).
    keep_hits : bool
        The whole detector is traced at once (its path lengths; the hits are not counted).
    scatter : {None, "mc", "kernel"}
        Count the scatter's images and temporaries (:func:`render`'s ``scatter``; a scan's
        projection allocates the same).

    Returns
    -------
    dict
        ``images`` (the (H, W) images and the detector model's temporaries), ``path_lengths``
        (a column per body and per voxel volume's class), ``bands`` (a few bands of path
        lengths), ``meshes``, ``volumes`` (what tracing the voxel volumes allocates: each
        volume's copy in the detector's axis order; the grids themselves are already loaded),
        ``scatter`` (the scatter's images and its model's or Monte Carlo's per-pixel
        temporaries; 0 without scatter) and ``total``.

    Examples
    --------
    >>> import xray_viz
    >>> need = memory_needed(xray_viz.load_scene("sphere"))
    >>> need["images"] == 256 * 256 * 48
    True
    """
    n = check_supersample(scene.detector.supersample if supersample is None else supersample)
    w, h = scene.detector.shape
    pixels = w * h
    volumes = tuple(scene.volumes)
    nb = len(scene.bodies) + sum(len(v.names) for v in volumes)   # the path lengths' columns
    projector = Projector(scene.bodies, engine)
    rows = h if keep_hits else min(h, _band_rows(projector, scene.acquisition, n))
    per_ray = 8 * max(1, nb) + (projector.hits_ray_bytes if keep_hits else projector.ray_bytes)
    if volumes:     # the voxel traversal's rays: directions and ends (24 + 8 bytes a ray)
        per_ray += 32
    need = {
        "images": pixels * _image_bytes_per_pixel(scene) if images else 0,
        "path_lengths": pixels * nb * 8 if path_lengths else 0,
        # A band's path lengths, their per-pixel means and the per-ray log-transmissions.
        "bands": 3 * rows * w * n * n * per_ray,
        "meshes": _mesh_bytes(scene),
        "volumes": sum(v.layout_bytes(scene.acquisition.frame.ho) for v in volumes),
        "scatter": pixels * _scatter_bytes_per_pixel(
            scatter, grid=scene.detector.grid is not None),
    }
    need["total"] = sum(need.values())
    return need


def _gib(nbytes: float) -> str:
    from xray_viz._memory import format_bytes

    return format_bytes(nbytes)


def check_memory(scene, *, supersample: int | None = None, engine: str = "fast",
                 path_lengths: bool = False, images: bool = True,
                 keep_hits: bool = False, scatter: str | None = None) -> None:
    """Refuse, in one line, a job whose output cannot fit in the memory available.

    Compares :func:`memory_needed` with :func:`available_memory` (the machine's
    ``MemAvailable``, the process's ``RLIMIT_AS`` and its cgroup's limit, the least of them;
    no check where none is known).

    Raises
    ------
    SceneError
        Saying how much the job needs and how much is available, and what to change.
    """
    available = available_memory()
    if available is None:
        return
    need = memory_needed(scene, supersample=supersample, engine=engine,
                         path_lengths=path_lengths, images=images, keep_hits=keep_hits,
                         scatter=scatter)
    if need["total"] <= available:
        return
    from xray_viz._memory import describe

    w, h = scene.detector.shape
    nb = len(scene.bodies)
    volumes = tuple(scene.volumes)
    if need["volumes"] and need["volumes"] >= max(need["images"], need["path_lengths"]):
        names = ", ".join(repr(str(v.source_file.name if v.source_file else v.name))
                          for v in volumes)
        raise SceneError(
            f"the voxel volume{'s' * (len(volumes) > 1)} {names} need about "
            f"{_gib(need['volumes'])} more to be traced (a copy of the grid in the detector's "
            f"axis order; {_gib(need['total'])} in all, {describe(available)}): crop or "
            "downsample the CT, or turn the detector so that its rows run along the grid's "
            "last axis")
    nb += sum(len(v.names) for v in volumes)
    what = [name for name, key in (("the output images", "images"),
                                   (f"the path lengths of {nb} bod{'y' if nb == 1 else 'ies'}",
                                    "path_lengths"),
                                   (f"the scatter ({scatter})", "scatter")) if need[key]]
    fix = "use a smaller shape"
    if need["path_lengths"] and need["path_lengths"] >= need["images"]:
        fix += (", or do without the per-body path lengths (path_lengths=False; "
                "Radiograph.total_path_length has their sum)")
    raise SceneError(
        f"[detector] shape {w} x {h} needs about {_gib(need['total'])} for "
        f"{' and '.join(what) or 'the job'} ({describe(available)}): {fix}")


# ------------------------------------------------------------------------------------------


def render(scene, *, engine: str = "fast", supersample: int | None = None,
           keep_hits: bool = False, path_lengths: bool = False,
           max_error: float | None = None, scatter: str | None = None,
           histories: int | None = None, scatter_smoothing: float | None = None,
           progress=None) -> Radiograph:
    """Render the radiograph of a scene.

    Parameters
    ----------
    scene : Scene
        From :func:`xray_viz.load_scene`.
    engine : str
        ``"fast"`` (default): the watertight fixed-point footprint rasteriser of
        :mod:`xray_viz.tracing.fast` (numba). ``"numpy"``: the pure-NumPy reference engine
        (watertight Moller-Trumbore on culled ray-triangle pairs).
    supersample : int, optional
        ``n`` traces ``n x n`` rays per pixel and averages their intensities (anti-aliasing).
        Defaults to the scene's ``[detector] supersample`` (1 unless set). A Python or NumPy
        integer; floats, strings and booleans are refused.
    keep_hits : bool
        Keep every hit of every ray in :attr:`Radiograph.hits` (numpy engine). The whole
        detector is then traced at once (memory O(rays x bodies + hits)).
    path_lengths : bool
        Also fill :attr:`Radiograph.path_length`, ``(H, W, n_bodies)`` (``8 x n_bodies``
        bytes per pixel). Without it that array is computed on first access (a second trace).
    max_error : float, optional
        Level of detail: trace each body at the coarsest pymeshlab decimation that keeps every
        pixel's line integral ``-ln(I/I0)`` within ``max_error`` (dimensionless, ~ the relative
        error of the intensity) of the full-resolution render at the same supersampling
        (:mod:`xray_viz.lod`: a measured estimate, with the budget shared by overlapping
        bodies; the pixel-scale sampling error is not part of it). The choice is in
        :attr:`Radiograph.lod`. None (default): the meshes as they are.
    scatter : {None, "mc", "kernel"}
        Scattered radiation in the image (:class:`ScatterSource`). None (default): the
        primary alone, today's images bit for bit. ``"mc"``: the photon Monte Carlo of
        :func:`xray_viz.transport` on the scene's meshes (``histories`` photons, seeded with
        the detector's ``seed``, 0 where it has none); ``"kernel"``: the fast scatter model
        ``xray_viz.scatter_kernel.KernelModel``, its amplitude from each pixel's path lengths
        through the bodies' materials. The detector reads primary plus scatter
        (:meth:`~xray_viz.physics.detector_model.DetectorModel.read`); the parts are in
        :attr:`Radiograph.primary`, :attr:`Radiograph.scatter` and :attr:`Radiograph.spr`.
    histories : int, optional
        Photons the Monte Carlo emits into the field (``scatter="mc"`` only, required there;
        the scatter's relative error falls as ``1 / sqrt(histories)``).
    scatter_smoothing : float, optional
        ``scatter="mc"`` only: smooth the Monte Carlo's scatter with a Gaussian of this
        standard deviation (mm at the detector; its standard error goes along), for a
        coarse Monte Carlo whose pixels receive few scattered photons. Scatter varies on the
        scale of centimetres; a blur far below that changes its mean little. None (default):
        the Monte Carlo's pixels as they are.
    progress : callable, optional
        ``progress(done, total)`` during the Monte Carlo (histories).

    Returns
    -------
    Radiograph

    Raises
    ------
    SceneError
        For an unknown engine, a supersampling that is not a whole number >= 1, or a job whose
        output cannot fit in the memory available (:func:`check_memory`); an unknown
        ``scatter``, ``scatter="mc"`` without ``histories`` (or histories not > 0), histories
        without ``scatter="mc"``.

    Notes
    -----
    Rendered by bands of detector rows (see the module docstring): peak memory is about
    :func:`memory_needed`, O(output + meshes).

    Examples
    --------
    >>> import xray_viz
    >>> image = xray_viz.render(xray_viz.load_scene("sphere"))
    >>> image.intensity.shape
    (256, 256)
    >>> round(float(image.total_path_length.max()), 1)      # the diameter, 80 mm
    80.0
    """
    projector = scene_projector(scene, engine)           # an unknown engine is refused here
    n = check_supersample(scene.detector.supersample if supersample is None else supersample)
    source = ScatterSource.of(scene, scatter, histories=histories, progress=progress,
                              smoothing=scatter_smoothing)
    lod = None
    if max_error is not None:
        from xray_viz.lod import level_of_detail

        scene, lod = level_of_detail(scene, max_error, supersample=n)
        projector = scene_projector(scene, engine)
    beam, model = stages(scene)
    model.blur_sigmas(scene.acquisition, scene.bodies)   # a focal spot wider than the detector
    check_memory(scene, supersample=n, engine=engine, path_lengths=path_lengths,
                 keep_hits=keep_hits, scatter=None if source is None else source.mode)
    parts = {}
    intensity, line_integral, total, per_body, hits, timing = _image(
        projector, beam, model, scene.acquisition, n, seed=scene.detector.seed,
        path_lengths=path_lengths, keep_hits=keep_hits, scatter=source,
        scatter_seed=None if source is None else source.seed(scene.detector.seed),
        parts=parts)
    return Radiograph(
        intensity=intensity,
        line_integral=line_integral,
        total_path_length=total,
        body_names=_names(scene),
        timing=timing,
        engine=engine,
        scene=scene,
        hits=hits,
        supersample=n,
        _path_length=per_body,
        lod=lod,
        primary=parts.get("primary"),
        scatter=parts.get("scatter"),
        scatter_details=parts.get("details"),
    )


def scene_projector(scene, engine: str = "fast"):
    """The :class:`~xray_viz.tracing.engines.Projector` of a scene's bodies, or with voxel
    volumes (``scene.volumes``) a ``xray_viz.volume.VolumeProjector``: the volumes'
    classes as columns after the bodies' (:func:`_names`).

    Examples
    --------
    >>> import xray_viz
    >>> scene_projector(xray_viz.load_scene("sphere"), "numpy")
    Projector(1 bodies, engine='numpy')
    """
    projector = Projector(scene.bodies, engine)
    if not scene.volumes:
        return projector
    from xray_viz.volume import VolumeProjector

    return VolumeProjector(projector, scene.volumes)


def _names(scene) -> list:
    """The names of the path lengths' columns: the bodies', then the voxel volumes' classes."""
    return list(scene.body_names) + [n for v in scene.volumes for n in v.names]


def stages(scene):
    """The physics stages of a scene, built once: ``(beam, detector_model)``.

    The :class:`~xray_viz.physics.beam.Beam` of the scene's source through its bodies as its
    detector weighs them (not yet at a pose: :meth:`~xray_viz.physics.beam.Beam.at`), and the
    :class:`~xray_viz.physics.detector_model.DetectorModel` of its detector. With a
    :class:`~xray_viz.tracing.engines.Projector` of the bodies they make any acquisition's
    image (:func:`image`), as :func:`render` and :func:`xray_viz.scan` do.

    Examples
    --------
    >>> import xray_viz
    >>> beam, model = stages(xray_viz.load_scene("sphere"))
    >>> beam.spectrum.description, model.i0
    ('monochromatic 60 keV', 1.0)
    """
    from xray_viz.physics.beam import Beam
    from xray_viz.physics.detector_model import DetectorModel

    bodies = scene.bodies
    if scene.volumes:              # the voxel volumes' classes: columns after the bodies'
        from xray_viz.volume import with_volume_materials

        bodies = with_volume_materials(scene).bodies
    return (Beam.of(scene.source, bodies, scene.detector, world=scene.world),
            DetectorModel.of(scene.detector))


def image(projector, beam, model, acquisition, *, supersample: int = 1, seed=None,
          scatter=None, scatter_seed=None):
    """The detected image of one acquisition: ``(intensity, line_integral)``, ``(H, W)``.

    ``model.read(beam.log_transmission(projector.path_lengths(acquisition)), seed=seed)``,
    band by band as :func:`render` (the same numbers bit for bit), for a caller that keeps the
    stages (:func:`stages`) over many acquisitions, e.g. a scan's projections.

    Parameters
    ----------
    projector : Projector
    beam : Beam
    model : DetectorModel
    acquisition : Acquisition
    supersample : int
    seed : int, optional
        The noise's seed.
    scatter : ScatterSource, optional
        Scatter added to the primary (:meth:`ScatterSource.of`, built once); None: the
        primary alone.
    scatter_seed : int, optional
        The Monte Carlo's seed (``scatter`` of mode ``"mc"``).

    Examples
    --------
    >>> import xray_viz
    >>> from xray_viz.tracing.engines import Projector
    >>> scene = xray_viz.load_scene("sphere")
    >>> intensity, li = image(Projector(scene.bodies), *stages(scene), scene.acquisition)
    >>> bool((intensity == xray_viz.render(scene).intensity).all())
    True
    """
    n = check_supersample(supersample)
    intensity, line_integral, *_ = _image(projector, beam, model, acquisition, n, seed=seed,
                                          scatter=scatter, scatter_seed=scatter_seed)
    return intensity, line_integral


def _image(projector, beam, model, acquisition, n, *, seed, path_lengths=False,
           keep_hits=False, scatter=None, scatter_seed=None, parts=None):
    """:func:`image`, with the total and per-body path lengths, the hits and the timing;
    with ``scatter``, ``parts`` (a dict) receives ``primary``, ``scatter`` and ``details``
    (see :class:`Radiograph`)."""
    beam = beam.at(acquisition)
    w, h = acquisition.detector.shape
    t0 = time.perf_counter()
    log_t = np.empty((h, w))
    # the variance's sum of an energy-integrating detector's noise (see detect_log)
    log_v = np.empty((h, w)) if model.needs_variance(beam) else None
    total = np.empty((h, w))
    # the kernel model reads each pixel's path lengths per body weighted by their materials'
    # scattering (mm of water), summed band by band
    weights = scattering = coherent = None
    if (scatter is not None and scatter.mode == "kernel"
            and projector.columns == len(scatter.materials)):
        weights = scatter.kernel.path_weights(acquisition, projector.bodies,
                                              materials=scatter.materials,
                                              volumes=scatter.scene.volumes)
        # one material's share of coherent scattering (one body, or bodies of one
        # material): the model takes it as a number, not a second sum per ray
        nonzero = weights[:, 0] > 0
        shares = weights[nonzero, 1] / weights[nonzero, 0]
        coherent = float(shares[0]) if len(shares) and np.ptp(shares) == 0.0 else None
        if coherent is not None:
            weights = weights[:, :1]
        scattering = np.empty((h, w, weights.shape[1]))
    per_body = np.empty((h, w, projector.columns)) if path_lengths else None
    t_trace, t_bands, hits = _band_loop(projector, acquisition, n, beam=beam, log_t=log_t,
                                        log_v=log_v, total=total, per_body=per_body,
                                        keep_hits=keep_hits,
                                        weighted=None if weights is None else (weights,
                                                                               scattering))
    t1 = time.perf_counter()
    _check_transmission(log_t)
    if scattering is not None and coherent is not None:
        scattering = (scattering[..., 0], coherent)
    s = None
    if scatter is not None:
        s, details = scatter(log_t, acquisition, projector.bodies, seed=scatter_seed,
                             scattering=scattering)
        if parts is not None:
            flat = model.flat_field(beam=beam, acquisition=acquisition)
            parts["primary"] = flat * np.exp(log_t)
            parts["scatter"] = flat * s
            if "error" in details:
                details["error"] = flat * details["error"]
            parts["details"] = details
    # log_t is not used again: the line integral is written over it
    intensity, line_integral = model.read(log_t, beam=beam, acquisition=acquisition,
                                          bodies=projector.bodies, seed=seed,
                                          log_variance=log_v, overwrite=True, scatter=s)
    del log_t, log_v
    t2 = time.perf_counter()
    timing = {"trace": t_trace, "image": t_bands + (t2 - t1), "total": t2 - t0}
    return intensity, line_integral, total, per_body, hits, timing


# ------------------------------------------------------------------------------------------
# scatter


class ScatterSource:
    """Where a render's scatter comes from, built once per scene (a scan's projections share
    it): ``source(log_t, acquisition, bodies, seed=)`` gives ``(s, details)``, ``s`` the
    (H, W) mean scatter reading relative to the flat field (the units of ``exp(log_t)``, the
    primary's transmission) at that acquisition.

    ``"mc"``: ``(incoherent + coherent + multiple) / flat_signal`` of
    :func:`xray_viz.transport` of the scene at the acquisition (its seed given per call);
    ``"kernel"``: ``KernelModel.of(scene).scatter(log_t, acquisition, bodies,
    scattering=)`` of ``xray_viz.scatter_kernel``, built here once (the render passes each
    pixel's path lengths per body weighted by the model's ``path_weights``, summed while it
    traces, when its projector has one column per body: the model's amplitude then sees
    the materials).

    Examples
    --------
    >>> import xray_viz
    >>> ScatterSource.of(xray_viz.load_scene("sphere"), None) is None
    True
    """

    def __init__(self, scene, mode, histories=None, progress=None, smoothing=None):
        self.scene, self.mode, self.histories, self.progress = scene, mode, histories, progress
        #: The Gaussian blur (standard deviation, mm at the detector) of the Monte Carlo's
        #: scatter, or None.
        self.smoothing = smoothing
        self.kernel = None
        #: The path lengths' columns as the physics sees them: the bodies, then the voxel
        #: volumes' classes (the kernel model's materials).
        self.materials = tuple(scene.bodies)
        if mode == "kernel":
            from xray_viz.scatter_kernel import KernelModel
            from xray_viz.volume import with_volume_materials

            # kept on the bodies per source and detector: the renders of a loop over poses
            # share its kernels (KernelModel._spread)
            key = ("scatter_kernel", "model", repr(scene.source), repr(scene.detector))
            self.kernel = scene.bodies.cached(key, lambda: KernelModel.of(scene), limit=2)
            self.materials = tuple(with_volume_materials(scene).bodies)

    @classmethod
    def of(cls, scene, scatter, *, histories=None, progress=None, smoothing=None):
        """The source of ``render(scene, scatter=, histories=, scatter_smoothing=)``, or None
        for ``scatter=None`` (the options checked by :meth:`options` and
        :meth:`check_smoothing`)."""
        mode, n = cls.options(scene, scatter, histories)
        smoothing = cls.check_smoothing(mode, smoothing)
        return None if mode is None else cls(scene, mode, n, progress, smoothing)

    @staticmethod
    def check_smoothing(mode, smoothing):
        """``smoothing`` (mm) as a float, or None; only with ``mode == "mc"``.

        Raises
        ------
        SceneError
            Not a finite number >= 0, or given without the Monte Carlo.
        """
        if smoothing is None:
            return None
        if mode != "mc":
            raise SceneError(f"scatter smoothing ({smoothing!r} mm) is for scatter='mc' only: "
                             "leave it out or ask for scatter='mc'")
        try:
            value = float(smoothing)
        except (TypeError, ValueError):
            value = float("nan")
        if isinstance(smoothing, bool) or not (value >= 0 and np.isfinite(value)):
            raise SceneError(f"scatter smoothing must be a number of mm >= 0 (the Gaussian's "
                             f"standard deviation at the detector, e.g. 5), got {smoothing!r}")
        return value or None

    @staticmethod
    def options(scene, scatter, histories):
        """``(mode, histories)`` checked: ``mode`` None (also for ``"none"``), ``"mc"`` or
        ``"kernel"``; ``histories`` an int for ``"mc"``, else None.

        Raises
        ------
        SceneError
            An unknown ``scatter``; ``"mc"`` without ``histories``, or with histories that are
            not a whole number > 0; ``histories`` without ``"mc"``.
        """
        if scatter is not None and not isinstance(scatter, str):
            raise SceneError(f"scatter must be None, 'mc' or 'kernel', got {scatter!r}")
        if scatter == "none":
            scatter = None
        if scatter not in SCATTER_MODES:
            raise SceneError(f"unknown scatter {scatter!r}: choose none (the primary alone), "
                             "mc (the photon Monte Carlo, with histories) or kernel (the fast "
                             "scatter model)")
        if scatter != "mc":
            if histories is not None:
                raise SceneError(f"histories = {histories!r} is for scatter='mc' (the Monte "
                                 f"Carlo) only, not scatter={scatter!r}: leave it out or ask "
                                 "for scatter='mc'")
            return scatter, None
        if histories is None:
            raise SceneError("scatter='mc' needs histories, the photons the Monte Carlo "
                             "emits, e.g. histories=1000000 (the scatter's relative error "
                             "falls as 1/sqrt(histories))")
        from xray_viz.transport import _check_histories

        n = _check_histories(histories)
        return "mc", n

    @staticmethod
    def seed(detector_seed):
        """The Monte Carlo's seed for a detector's noise seed: the same, or 0 for None."""
        return 0 if detector_seed is None else int(detector_seed)

    def __call__(self, log_t, acquisition, bodies, *, seed=None, scattering=None):
        """``(s, details)`` at ``acquisition``: see the class. ``scattering`` ((H, W, 2) mm of
        water, or ``((H, W), coherent share)`` for one material; optional): each pixel's path
        lengths weighted by ``self.kernel.path_weights``;
        the kernel model's amplitude then sees the bodies' materials (``KernelModel.scatter``'s
        option of that name)."""
        if self.mode == "kernel":
            share = None
            if isinstance(scattering, tuple):             # one material's coherent share
                scattering, share = scattering
            s = np.asarray(self.kernel.scatter(log_t, acquisition, bodies,
                                               scattering=scattering, coherent_share=share,
                                               volumes=self.scene.volumes), dtype=np.float64)
            return s, {"mode": "kernel"}
        from xray_viz.transport import flat_signal, transport

        scene = self.scene
        if acquisition is not scene.acquisition:
            scene = scene.replace(acquisition=acquisition)
        seed = 0 if seed is None else int(seed)
        result = transport(scene, self.histories, seed=seed, progress=self.progress)
        flat = flat_signal(scene)
        keys = ("incoherent", "coherent", "multiple")
        s = sum(result.images[k] for k in keys) / flat
        variance = sum(result.image_errors[k] ** 2 for k in keys) / flat ** 2
        details = {"mode": "mc", "histories": result.histories, "seed": seed}
        if self.smoothing:
            from xray_viz.physics.detector_model import _convolve, gaussian_kernel

            px, py = acquisition.detector.pitch
            kernels = (gaussian_kernel(self.smoothing / py), gaussian_kernel(self.smoothing / px))
            s = np.maximum(_convolve(s, kernels), 0.0)
            # the mean of independent pixels weighted by k: variance weighted by k^2
            variance = _convolve(variance, tuple(k * k for k in kernels))
            details["smoothing_mm"] = self.smoothing
        details["error"] = np.sqrt(np.maximum(variance, 0.0))
        return s, details


#: What one Monte Carlo run covers, per command (the help texts' and errors' word).
_SCATTER_PER = {"render": "the image", "projection": "each projection",
                "view": "each render of the view"}


def add_scatter_arguments(parser, *, per: str) -> None:
    """``--scatter {none,mc,kernel}``, ``--histories N`` and ``--scatter-smoothing MM``, as
    ``xray-viz render``, ``scan`` and ``show`` take them; ``per`` names what one Monte Carlo
    run covers (``"render"``, ``"projection"`` or ``"view"``). Checked by
    :func:`scatter_arguments`."""
    what = _SCATTER_PER[per]
    parser.add_argument(
        "--scatter", choices=("none", "mc", "kernel"), default="none",
        help=f"scattered radiation in {what}: none (default: the primary beam alone, "
             "scattered photons removed but not detected), mc (the photon Monte Carlo on the "
             "scene's bodies, with --histories; slow, its error falls as 1/sqrt(histories)) "
             "or kernel (the fast scatter kernel model, calibrated on the Monte Carlo). The "
             "detector reads primary plus scatter"
             + ("; every slider move renders again (mc is slow), and the radiograph can be "
                "shown as the total, its primary, its scatter or the scatter-to-primary ratio "
                "(key k, or --radiograph); the key a puts the anti-scatter grid in front of the "
                "detector or takes it away (the scene's [detector] grid, else the default one)"
                if per == "view" else ""))
    parser.add_argument(
        "--histories", type=int, default=None, metavar="N",
        help=f"photons the Monte Carlo emits for {what} with --scatter mc (required there; "
             "e.g. 1000000 for a 256 x 256 detector), seeded from the detector's seed (0 "
             "without one)")
    parser.add_argument(
        "--scatter-smoothing", type=float, default=None, metavar="MM",
        help="with --scatter mc: smooth the Monte Carlo's scatter with a Gaussian of MM mm "
             "(standard deviation at the detector; scatter varies over centimetres), for few "
             "histories per pixel. Default: no smoothing")


def scatter_arguments(args) -> tuple[str | None, int | None, float | None]:
    """``(scatter, histories, smoothing)`` of :func:`add_scatter_arguments`'s options:
    ``scatter`` None for ``none``.

    Raises
    ------
    SceneError
        One line: ``--scatter mc`` without ``--histories``, histories <= 0, ``--histories`` or
        ``--scatter-smoothing`` without ``--scatter mc``, a smoothing < 0 or not finite.
    """
    mode = args.scatter
    scatter = None if mode == "none" else mode
    histories, smoothing = args.histories, args.scatter_smoothing
    if histories is not None and histories <= 0:
        raise SceneError(f"--histories must be > 0 (the photons the Monte Carlo emits, e.g. "
                           f"1000000), got {histories}")
    if scatter == "mc" and histories is None:
        raise SceneError("--scatter mc needs --histories N, the photons the Monte Carlo "
                           "emits (e.g. --histories 1000000; the scatter's error falls as "
                           "1/sqrt(N))")
    for name, value in (("--histories", histories), ("--scatter-smoothing", smoothing)):
        if scatter != "mc" and value is not None:
            raise SceneError(f"{name} is for --scatter mc only (got --scatter "
                               f"{mode}): leave it out or add --scatter mc")
    if smoothing is not None and not 0 <= smoothing < float("inf"):
        raise SceneError(f"--scatter-smoothing must be a number of mm >= 0 (e.g. 5), got "
                           f"{smoothing}")
    return scatter, histories, smoothing
