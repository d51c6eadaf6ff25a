"""What the viewer draws, as plain arrays: chosen pixels, their rays, hits and mu(t) profiles.

Nothing here imports PyVista, so every number the 3D view shows can be tested without a render
window. Every hit comes from :func:`xray_viz.tracing.trace_rays`: the viewer never intersects
rays with triangles itself.

Pixels are named by the thesis' indices ``(i, j)``: ``i`` counts columns from the left
(``u_i = i / (W - 1)``) and ``j`` counts rows from the *bottom* (``v_j = j / (H - 1)``), so
pixel ``(i, j)`` is ray ``k = (H - 1 - j) * W + i`` of :func:`~xray_viz.geometry.detector_rays`
and ``image[H - 1 - j, i]`` of a :class:`~xray_viz.render.Radiograph`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from xray_viz.errors import SceneError
from xray_viz.geometry import detector_rays
from xray_viz.tracing import Hits, trace_rays

__all__ = [
    "RaySelection",
    "AttenuationProfile",
    "pixel_ray_index",
    "select_pixels",
    "trace_selection",
    "inside_segments",
    "attenuation_profile",
    "effective_energy",
]


def pixel_ray_index(shape, i, j) -> np.ndarray:
    """Index in image order of the ray of pixel ``(i, j)``.

    Parameters
    ----------
    shape : (int, int)
        Detector ``(W, H)``.
    i, j : int or array of int
        Column from the left and row from the bottom (thesis Eq. 1.3-1.4).

    Returns
    -------
    int array
        ``(H - 1 - j) * W + i``.

    Examples
    --------
    >>> int(pixel_ray_index((4, 3), 0, 0))         # bottom-left pixel: last image row
    8
    """
    w, h = shape
    i = np.asarray(i, dtype=np.int64)
    j = np.asarray(j, dtype=np.int64)
    if np.any((i < 0) | (i >= w) | (j < 0) | (j >= h)):
        raise SceneError(f"pixel (i, j) outside a {w} x {h} detector: i={i}, j={j}")
    return (h - 1 - j) * w + i


def _even_indices(n: int, count: int) -> np.ndarray:
    count = max(1, min(int(count), n))
    if count == 1:
        return np.array([(n - 1) // 2])
    return np.unique(np.round(np.linspace(0, n - 1, count)).astype(np.int64))


def select_pixels(shape, rays) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(i, j)`` chosen by a ray specification.

    Parameters
    ----------
    shape : (int, int)
        Detector ``(W, H)``.
    rays : str, int, sequence of (i, j) or None
        ``"every K"`` (or the int ``K``): every K-th column of every K-th row, starting at
        pixel (0, 0); ``"grid N"``: an N x N grid spread evenly over the detector, corners
        included; ``"row J"`` / ``"column I"``: every pixel of row ``j = J`` (counted from the
        bottom) or column ``i = I``; ``"center"``; ``"none"`` or None; or explicit pixels
        ``[(i, j), ...]``.

    Returns
    -------
    i, j : (n,) int

    Examples
    --------
    >>> i, j = select_pixels((5, 3), "row 2")
    >>> i.tolist(), j.tolist()
    ([0, 1, 2, 3, 4], [2, 2, 2, 2, 2])
    >>> select_pixels((256, 256), "grid 3")[0].tolist()
    [0, 0, 0, 128, 128, 128, 255, 255, 255]
    """
    w, h = (int(s) for s in shape)
    empty = np.zeros(0, np.int64)
    if rays is None:
        return empty, empty
    if isinstance(rays, (int, np.integer)) and not isinstance(rays, bool):
        rays = f"every {int(rays)}"
    if isinstance(rays, str):
        spec = rays.strip().lower()
        if spec == "none":
            return empty, empty
        if spec == "center":
            return np.array([(w - 1) // 2]), np.array([(h - 1) // 2])
        m = re.fullmatch(r"(every|grid|row|column)\s+(\d+)", spec)
        if not m:
            raise SceneError(f"rays must be 'every K', 'grid N', 'row J', 'column I', 'center', "
                             f"'none' or a list of (i, j) pixels; got {rays!r}")
        what, n = m.group(1), int(m.group(2))
        if what == "every":
            if n < 1:
                raise SceneError(f"rays 'every K' needs K >= 1, got {n}")
            ii, jj = np.meshgrid(np.arange(0, w, n), np.arange(0, h, n), indexing="ij")
        elif what == "grid":
            if n < 1:
                raise SceneError(f"rays 'grid N' needs N >= 1, got {n}")
            ii, jj = np.meshgrid(_even_indices(w, n), _even_indices(h, n), indexing="ij")
        elif what == "row":
            if n >= h:
                raise SceneError(f"row {n} outside a detector {h} pixels high")
            ii, jj = np.arange(w), np.full(w, n)
        else:
            if n >= w:
                raise SceneError(f"column {n} outside a detector {w} pixels wide")
            ii, jj = np.full(h, n), np.arange(h)
        return ii.ravel().astype(np.int64), jj.ravel().astype(np.int64)
    pix = np.asarray(rays, dtype=np.int64).reshape(-1, 2)
    pixel_ray_index((w, h), pix[:, 0], pix[:, 1])          # validates the range
    return pix[:, 0].copy(), pix[:, 1].copy()


@dataclass(frozen=True)
class RaySelection:
    """A few detector rays and every hit along them.

    Attributes
    ----------
    i, j : (n,) int
        The pixels (column from the left, row from the bottom).
    index : (n,) int
        The rays' indices in image order (into :func:`~xray_viz.geometry.detector_rays`).
    origins, directions : (n, 3) float
        As in :func:`~xray_viz.geometry.detector_rays` (unit directions, t in mm).
    t_max : (n,) float
        Where each ray meets the detector.
    hits : Hits
        From :func:`~xray_viz.tracing.trace_rays`; ``hits.ray`` indexes this selection.
    """

    i: np.ndarray
    j: np.ndarray
    index: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    t_max: np.ndarray
    hits: Hits

    def __len__(self) -> int:
        return len(self.i)

    @property
    def ends(self) -> np.ndarray:
        """(n, 3) float: where each ray meets the detector (its pixel position)."""
        return self.origins + self.t_max[:, None] * self.directions


def trace_selection(scene, rays) -> RaySelection:
    """Choose pixels (see :func:`select_pixels`) and trace their rays through the scene.

    Examples
    --------
    >>> import xray_viz
    >>> sel = trace_selection(xray_viz.load_scene("sphere"), "center")
    >>> sel.hits.entering.tolist()
    [True, False]
    """
    i, j = select_pixels(scene.detector.shape, rays)
    all_rays = detector_rays(scene)
    k = pixel_ray_index(scene.detector.shape, i, j)
    origins = all_rays.origins[k]
    directions = all_rays.directions[k]
    t_max = all_rays.t_max[k]
    # No culling axis hint: a few rays need none (and main's binned culling at cec552b lost
    # the hits of some single rays with it).
    hits = trace_rays(scene, origins, directions, t_min=0.0, t_max=t_max)
    return RaySelection(i=i, j=j, index=k, origins=origins, directions=directions, t_max=t_max,
                        hits=hits)


def inside_segments(hits: Hits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pieces of the rays that lie inside at least one body.

    A piece runs from one hit to the next hit of the same ray while the ray is inside a body
    (entries minus exits of that body so far positive: the renderer's sweep,
    :func:`xray_viz.attenuation.stretch_materials`). Its end points *are* hit points.

    Returns
    -------
    starts, ends : (m, 3) float
    ray : (m,) int

    Examples
    --------
    >>> import xray_viz
    >>> hits = trace_selection(xray_viz.load_scene("sphere"), "center").hits
    >>> starts, ends, ray = inside_segments(hits)
    >>> float(round(np.linalg.norm(ends - starts), 1))   # ~ the diameter, mm (pixel 127, 127)
    80.0
    """
    from xray_viz.attenuation import stretch_materials

    if len(hits) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
    winner = stretch_materials(hits.ray, hits.body, hits.entering,
                               precedence=np.arange(int(hits.body.max()) + 1))
    same_ray = hits.ray[1:] == hits.ray[:-1]
    idx = np.flatnonzero(same_ray & (winner[:-1] >= 0))
    return hits.point[idx], hits.point[idx + 1], hits.ray[idx]


@dataclass(frozen=True)
class AttenuationProfile:
    """mu along one ray: a step function of t.

    Attributes
    ----------
    t : (m + 1,) float
        Segment boundaries in mm along the ray: 0, every hit, ``t_max``.
    mu : (m,) float
        Linear attenuation coefficient (1/cm) on each segment ``[t[k], t[k+1]]``.
    body : (m,) int
        The body whose material fills the segment, -1 for air (vacuum).
    line_integral : float
        ``sum mu dt`` (dimensionless; dt in cm).
    energy : float
        keV at which ``mu`` was evaluated.
    """

    t: np.ndarray
    mu: np.ndarray
    body: np.ndarray
    line_integral: float
    energy: float

    def steps(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, y)`` arrays that draw the step function as a polyline."""
        x = np.repeat(self.t, 2)[1:-1]
        y = np.repeat(self.mu, 2)
        return x, y


def attenuation_profile(scene, hits: Hits, t_max: float, *, energy=None) -> AttenuationProfile:
    """mu(t) along one ray from its hits, and the line integral it gives.

    Where bodies overlap, the material is that of the body of highest ``scene.precedence``
    among those the ray is inside (the same rule as the renderer).

    Parameters
    ----------
    scene : Scene
    hits : Hits
        The hits of a single ray, in order of t (e.g. ``Hits.for_ray(k)``).
    t_max : float
        Where the ray meets the detector.
    energy : float, optional
        keV; default the source energy (60 keV when the source has a spectrum).

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> sel = trace_selection(scene, "center")
    >>> prof = attenuation_profile(scene, sel.hits, float(sel.t_max[0]))
    >>> prof.mu.tolist(), round(prof.line_integral, 3)          # ~8 cm at 0.2 /cm
    ([0.0, 0.2, 0.0], 1.6)
    """
    from xray_viz.physics.imaging import MM_PER_CM, body_mu

    if energy is None:
        from xray_viz.physics.spectra import DEFAULT_ENERGY

        energy = scene.source.energy if scene.source.energy is not None else DEFAULT_ENERGY
    mu_b = body_mu(scene, [energy])[0] if scene.bodies else np.zeros(0)
    from xray_viz.attenuation import stretch_materials

    prec = np.asarray(scene.precedence) if scene.bodies else np.zeros(0, np.int64)
    after = stretch_materials(np.zeros(len(hits), np.int64), hits.body, hits.entering,
                              precedence=prec)
    t = np.concatenate([[0.0], np.asarray(hits.t, dtype=np.float64), [float(t_max)]])
    body = np.concatenate([[-1], after]).astype(np.int64)
    mu = np.where(body >= 0, mu_b[np.maximum(body, 0)] if len(mu_b) else 0.0, 0.0)
    line_integral = float(np.sum(mu * np.diff(t)) / MM_PER_CM)
    return AttenuationProfile(t=t, mu=mu, body=body, line_integral=line_integral,
                              energy=float(energy))


def effective_energy(scene, profile: AttenuationProfile, line_integral: float, *,
                     energies) -> float | None:
    """The single photon energy (keV) at which ``profile``'s ray has ``line_integral``.

    A polychromatic image holds ``-ln(I / I0)`` of the whole spectrum, not the line integral
    at any one energy; the ray's *effective energy* is the energy a monochromatic beam would
    need to give the same value along the same path (lower than the spectrum's mean where the
    soft photons are absorbed, higher behind thick bone: beam hardening).

    Parameters
    ----------
    scene : Scene
    profile : AttenuationProfile
        The ray's path through the bodies (at any energy: only ``t`` and ``body`` are used).
    line_integral : float
        The image's value, e.g. ``Radiograph.line_integral[H - 1 - j, i]``.
    energies : (float, float)
        The range of keV searched, e.g. the spectrum's lowest and highest bins.

    Returns
    -------
    float or None
        None when no energy in the range gives ``line_integral``: the ray misses every body,
        or its bodies have a constant ``mu``.

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("nested_spheres")
    >>> sel = trace_selection(scene, "center")
    >>> prof = attenuation_profile(scene, sel.hits, float(sel.t_max[0]), energy=50.0)
    >>> e = effective_energy(scene, prof, prof.line_integral, energies=(20.0, 80.0))
    >>> round(e, 3)
    50.0
    """
    from xray_viz.physics.imaging import MM_PER_CM, body_mu

    inside = profile.body >= 0
    if not inside.any() or not np.isfinite(line_integral):
        return None
    lengths = np.bincount(profile.body[inside], weights=np.diff(profile.t)[inside],
                          minlength=len(scene.bodies))

    def excess(e):
        return body_mu(scene, np.atleast_1d(e)) @ lengths / MM_PER_CM - line_integral

    lo, hi = (float(e) for e in energies)
    grid = np.linspace(lo, hi, 129)
    d = excess(grid)
    if np.ptp(d) < 1e-12 * max(abs(line_integral), 1.0):
        return None                               # mu does not change with energy
    change = np.flatnonzero((d[:-1] == 0) | (np.sign(d[:-1]) != np.sign(d[1:])))
    if not len(change):
        return None
    k = change[-1]                                # the highest energy that fits (K-edges)
    if d[k] == 0:
        return float(grid[k])
    from scipy.optimize import brentq

    return float(brentq(lambda e: float(excess(e)[0]), grid[k], grid[k + 1], xtol=1e-12))
