"""The anti-scatter grid: a linear focused grid of lead strips in front of the detector.

A :class:`Grid` is a stack of thin absorbing strips (lead) of thickness ``d`` and height ``h``
separated by interspaces (aluminium) of width ``D``, ``N`` strips per cm (the *frequency*:
``D + d = 10 / N`` mm), grid ratio ``r = h / D``. The strips are parallel to the detector's
``v`` axis (up the image columns) and focused: their planes meet on a line parallel to ``v``
at ``focus_distance`` above the middle of the detector. A photon is described by the tangent
``t`` of its angle *across* the strips, measured from the local focused direction (its
lateral drift across the strips per unit depth, relative to the strips), and ``s``, the
tangent *along* them; its path through the grid's height is ``L = h sqrt(1 + t^2 + s^2)``.

**The transmission** (:meth:`Grid.transmission`) is the model of Day & Dance (G. J. Day and
D. R. Dance, "X-ray transmission formula for antiscatter grids", Phys. Med. Biol. 28 (1983)
1429-1433): the strips are locally parallel, the photons fall uniformly on one grid period
``P = D + d``, and each travels a straight line through strip and interspace material; the
transmission is the mean of ``exp(-mu_s l_s - mu_i l_i)`` over the entry point, ``l_s`` and
``l_i`` the lengths of the line in strip and interspace (``l_s + l_i = L``). Strip penetration
is included (a 1.3 mm high lead strip passes ``~3e-4`` at normal incidence at 100 keV and far
more for a photon crossing several thin strips obliquely). The lateral drift over the grid,
``p = h |t|``, and the strip fraction covered, ``c(x) / p`` for the entry point ``x``, are
piecewise linear in ``x`` with four kinks per period, so the mean is an exact sum of four
integrals of exponentials of linear functions (no quadrature). Not modelled: the covers, the
grid's own scatter (photons scattered in the interspace, largest for aluminium: Massera,
Bosmans, Rodriguez Perez and Marshall, "A combined analytical and Monte Carlo method for
detailed simulations of antiscatter grids in x-ray medical imaging: implementing scatter within
the grid", 2023), grid-line images (the mean over a period is what a moving grid or a pixel
several periods wide sees), lateral decentring and tilt of the grid.

**Defaults**: a common general-radiography grid, ratio 10, 60 lines/cm, 0.036 mm lead strips,
aluminium interspace, focused at 1000 mm. Ratios 8-12 at 40-80 lines/cm with focus distances
of 100-180 cm are the general-radiography grids of the textbooks (IAEA, *Diagnostic Radiology
Physics: A Handbook for Teachers and Students*, 2014, section 6.3.4; Bushberg et al., *The
Essential Physics of Medical Imaging*, 3rd ed., 2012, chapter 7); the strip thickness is
usually not marked on a grid (F. Ranallo, "Antiscatter grids - an essential component of
image quality", Gammex/RMI): 0.036 mm is a thin strip of a fine (60 lines/cm) grid, an
assumption to check against a grid's data sheet. With it the default grid's Tp is 0.70-0.72
at 60-120 kVp behind 20 cm of water (BENCHMARKS.md), as measured for a ratio-10 grid (70.6 %,
Altunbas et al., Med. Phys. 43(6) (2016), AAPM abstract WE-AB-207A-10).

**Figures of merit** (IEC 60627): the primary transmission ``Tp``, the scatter transmission
``Ts`` (for a stated angular distribution of the scatter: isotropic radiance over the half
space by default, whose photons cross the grid with the weight ``cos psi``), the total
transmission ``Tt = (Tp + SPR Ts) / (1 + SPR)`` for a scatter-to-primary ratio ``SPR`` in
front of the grid, the Bucky factor ``B = 1 / Tt``, the selectivity ``Tp / Ts`` and the
contrast improvement factor ``K = Tp / Tt`` (:meth:`Grid.figures_of_merit`).

Examples
--------
>>> grid = Grid()
>>> round(grid.interspace_width, 4), round(grid.strip_height, 4)       # mm
(0.1307, 1.3067)
>>> round(float(grid.primary_transmission(60.0)[0]), 3)
0.711
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["Grid", "GRID_KEYS", "GRID_DENSITIES"]

#: Keys of a scene file's ``[detector] grid`` table.
GRID_KEYS = ("ratio", "frequency", "strip_material", "strip_thickness", "strip_density",
             "interspace_material", "interspace_density", "focus_distance")

#: Densities (g/cm^3) used for the elements a grid is made of when none is given.
GRID_DENSITIES = {"Pb": 11.35, "W": 19.3, "Ta": 16.65, "Al": 2.699, "Cu": 8.96, "C": 1.7}


def _number(spec, key, default, *, positive=True):
    value = spec.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not (value > 0 if positive else value >= 0):
        raise SceneError(f"grid {key} must be a number > 0, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Grid:
    """A linear focused anti-scatter grid (see the module docstring for the model).

    Parameters
    ----------
    ratio : float
        Grid ratio ``h / D`` (strip height over interspace width), > 0. Default 10.
    frequency : float
        Strips per cm, > 0. Default 60.
    strip_material, interspace_material : str
        Materials of :mod:`xray_viz.physics.materials`. Default ``"Pb"`` and ``"Al"``.
    strip_thickness : float
        mm, > 0 and less than the period ``10 / frequency``. Default 0.036.
    strip_density, interspace_density : float or None
        g/cm^3; None: :data:`GRID_DENSITIES` for an element there, else the tabulated one.
    focus_distance : float
        mm from the grid to the line its strips converge on. Default 1000.

    Raises
    ------
    SceneError
        A value out of range or an unknown material.
    """

    ratio: float = 10.0
    frequency: float = 60.0
    strip_material: str = "Pb"
    strip_thickness: float = 0.036
    interspace_material: str = "Al"
    focus_distance: float = 1000.0
    strip_density: float | None = None
    interspace_density: float | None = None

    def __post_init__(self):
        spec = {k: getattr(self, k) for k in ("ratio", "frequency", "strip_thickness",
                                               "focus_distance")}
        for key in spec:
            object.__setattr__(self, key, _number(spec, key, None))
        if not self.strip_thickness < self.period:
            raise SceneError(f"grid strip_thickness {self.strip_thickness:g} mm must be less "
                             f"than the period 10 / frequency = {self.period:.4g} mm: lower "
                             "the thickness or the frequency (lines per cm)")
        from xray_viz.errors import MaterialError
        from xray_viz.physics.materials import check_material

        for key in ("strip", "interspace"):
            material = getattr(self, f"{key}_material")
            if not isinstance(material, str):
                raise SceneError(f"grid {key}_material must be a material name, formula or "
                                 f"element string, got {material!r}")
            density = getattr(self, f"{key}_density")
            if density is not None:
                density = _number({f"{key}_density": density}, f"{key}_density", None)
            elif material in GRID_DENSITIES:
                density = GRID_DENSITIES[material]
            try:
                density = check_material(material, density=density)
            except MaterialError as exc:
                raise SceneError(f"grid {key}_material: {exc}") from None
            object.__setattr__(self, f"{key}_density", float(density))

    @classmethod
    def of(cls, spec) -> Grid:
        """A grid from a scene file's table (a mapping of :data:`GRID_KEYS`), validated.

        Examples
        --------
        >>> Grid.of({"ratio": 12, "frequency": 40}).strip_height.__round__(3)
        2.568
        >>> Grid.of({"ratio": 0})
        Traceback (most recent call last):
        ...
        xray_viz.errors.SceneError: grid ratio must be a number > 0, got 0
        """
        if isinstance(spec, Grid):
            return spec
        if not isinstance(spec, Mapping):
            raise SceneError(f"grid must be a table such as {{ ratio = 10, frequency = 60 }}, "
                             f"got {spec!r}")
        unknown = sorted(set(spec) - set(GRID_KEYS))
        if unknown:
            raise SceneError(f"grid has unknown key(s) {', '.join(map(repr, unknown))}; the "
                             f"keys are {', '.join(GRID_KEYS)}")
        return cls(**dict(spec))

    def to_dict(self) -> dict:
        """The grid as a scene file's table (every key, densities included)."""
        return {key: getattr(self, key) for key in GRID_KEYS}

    # --- geometry ---------------------------------------------------------------------------

    @property
    def period(self) -> float:
        """mm from one strip to the next, ``10 / frequency``."""
        return 10.0 / self.frequency

    @property
    def interspace_width(self) -> float:
        """``D`` in mm: the period minus the strip thickness."""
        return self.period - self.strip_thickness

    @property
    def strip_height(self) -> float:
        """``h = ratio * D`` in mm."""
        return self.ratio * self.interspace_width

    def attenuation(self, energies_kev):
        """``(mu_strip, mu_interspace)`` in 1/mm at the energies, two arrays."""
        from xray_viz.physics.materials import linear_attenuation

        e = np.asarray(energies_kev, dtype=np.float64)
        flat = np.atleast_1d(e).reshape(-1)
        mus = linear_attenuation(self.strip_material, flat, density=self.strip_density) / 10.0
        mui = linear_attenuation(self.interspace_material, flat,
                                 density=self.interspace_density) / 10.0
        return np.asarray(mus).reshape(e.shape), np.asarray(mui).reshape(e.shape)

    # --- transmission -----------------------------------------------------------------------

    def transmission(self, energies_kev, tan_angle, *, tan_along=0.0) -> np.ndarray:
        """Transmission of a photon of energy E crossing the grid at an angle (NumPy
        broadcasting over the three arguments).

        Parameters
        ----------
        energies_kev : array_like
        tan_angle : array_like
            Tangent of the angle across the strips, from the local focused direction; the
            transmission is even in it.
        tan_along : array_like, optional
            Tangent along the strips (lengthens the path only).

        Returns
        -------
        ndarray
            The mean over one grid period (Day & Dance 1983), in (0, 1].
        """
        e, t, s = np.broadcast_arrays(np.asarray(energies_kev, dtype=np.float64),
                                      np.asarray(tan_angle, dtype=np.float64),
                                      np.asarray(tan_along, dtype=np.float64))
        mus, mui = self.attenuation(e)
        return period_mean(mus, mui, t, s, d=self.strip_thickness, period=self.period,
                           h=self.strip_height)

    def primary_transmission(self, energies_kev) -> np.ndarray:
        """The transmission along the focused direction (``tan_angle = 0``), per energy:
        ``D/P exp(-mu_i h) + d/P exp(-mu_s h)``.

        Examples
        --------
        >>> g = Grid()
        >>> bool(np.all(np.diff(g.primary_transmission([40.0, 60.0, 80.0])) > 0))
        True
        """
        e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
        return self.transmission(e, 0.0)

    def focused_tan(self, across_mm, tan_ray):
        """``tan_angle`` of a ray with tangent ``tan_ray`` across the strips (from the
        detector normal) hitting the grid ``across_mm`` from its middle: its drift relative to
        the strip there, whose tangent is ``across_mm / focus_distance``."""
        return np.asarray(tan_ray, dtype=np.float64) - np.asarray(across_mm) / self.focus_distance

    def spectrum_transmission(self, energies_kev, weights, tan_angle, tan_along=0.0
                              ) -> np.ndarray:
        """``sum_k w_k T(E_k, t, s) / sum_k w_k``: the transmission of a spectrum (weights
        ``weights`` at ``energies_kev``) at the tangents ``tan_angle`` across the strips and
        ``tan_along`` along them (broadcast together), the period's geometry computed once
        for all the energies.

        Examples
        --------
        >>> g = Grid()
        >>> one = g.spectrum_transmission([60.0], [1.0], [0.0, 0.05])
        >>> bool(np.allclose(one, g.transmission(60.0, [0.0, 0.05])))
        True
        """
        e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
        w = np.atleast_1d(np.asarray(weights, dtype=np.float64))
        mus, mui = self.attenuation(e)
        geometry = PeriodGeometry(tan_angle, tan_along, d=self.strip_thickness,
                                  period=self.period, h=self.strip_height)
        return sum(wk * geometry.mean(a, b) for wk, a, b in zip(w, mus, mui)) / w.sum()

    def pixel_tangents(self, acquisition) -> tuple[np.ndarray, np.ndarray]:
        """``(t, s)``, each (H, W): the tangents across the strips (from the strip where the
        ray arrives, :meth:`focused_tan`) and along them of each pixel's primary ray, from
        the source through the pixel's centre (along the beam for a parallel one)."""
        f = acquisition.frame
        (w, h), (pu, pv) = f.shape, f.pitch
        ho, ve, normal = (np.asarray(x, dtype=np.float64) for x in (f.ho, f.ve, f.normal))
        u = (np.arange(w) + 0.5 - 0.5 * w) * pu                   # across (ho), mm
        v = 0.5 * h * pv - (np.arange(h) + 0.5) * pv              # rows, top first
        if f.parallel:
            d = np.broadcast_to(np.asarray(f.forward, dtype=np.float64), (h, w, 3))
        else:
            d = (np.asarray(f.middle, dtype=np.float64) + u[None, :, None] * ho
                 + v[:, None, None] * ve) - np.asarray(f.source, dtype=np.float64)
        dn = np.abs(d @ normal)
        return self.focused_tan(u[None, :], (d @ ho) / dn), (d @ ve) / dn

    def off_focus(self, acquisition, energies_kev, weights, *, nodes=(65, 17)) -> np.ndarray:
        """(H, W): each pixel's primary transmission through the grid at its ray's angle
        (:meth:`pixel_tangents`) over the focused one, both weighted over the energies by
        ``weights`` (the detector's weights of the photons in front of the grid). 1 where
        the ray meets the strips edge on; below 1 where it does not, toward the edges of a
        detector whose source is off the grid's focus (the cut-off of a grid used at
        another distance, which the transport's photons show).

        Interpolated (bilinearly) in a table over ``nodes`` values of the two tangents (and
        ``t = 0``, the transmission's cusp).

        Examples
        --------
        >>> import xray_viz
        >>> scene = xray_viz.load_scene("sphere")          # source 1500 mm from the detector
        >>> c = Grid(focus_distance=1500.0).off_focus(scene.acquisition, [60.0], [1.0])
        >>> round(float(c.max()), 6)                       # focused at 1500 mm
        1.0
        >>> c = Grid(focus_distance=1000.0).off_focus(scene.acquisition, [60.0], [1.0])
        >>> bool(c[128, 128] > 0.99 and c[128, 0] < 0.9)   # cut off toward the edges
        True
        """
        from scipy.interpolate import RegularGridInterpolator

        e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
        wts = np.atleast_1d(np.asarray(weights, dtype=np.float64))
        t, s = self.pixel_tangents(acquisition)
        axes = []
        for x, n in zip((t, s), nodes):
            lo, hi = float(x.min()), float(x.max())
            if hi - lo < 1e-9:
                lo, hi, n = lo - 1e-6, hi + 1e-6, 2
            axes.append(np.linspace(lo, hi, n))
        if axes[0][0] < 0.0 < axes[0][-1]:
            axes[0] = np.union1d(axes[0], [0.0])
        table = self.spectrum_transmission(e, wts, axes[0][:, None], axes[1][None, :])
        focused = float(self.spectrum_transmission(e, wts, 0.0))
        level = RegularGridInterpolator(axes, table / focused)(
            np.stack([t.reshape(-1), s.reshape(-1)], axis=1))
        return level.reshape(t.shape)

    def scatter_transmission(self, energies_kev, *, nodes: int = 256) -> np.ndarray:
        """Transmission of scatter of isotropic radiance over the half space in front of the
        grid, per energy: the mean of ``T`` over directions weighted by ``cos psi`` (``psi``
        from the normal), by the midpoint rule in ``cos^2 psi`` (uniform for this weight) and
        in the azimuth, ``nodes`` of each.

        Examples
        --------
        >>> ts = Grid().scatter_transmission([60.0])
        >>> bool(0.05 < ts[0] < 0.3)
        True
        """
        e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
        w = (np.arange(nodes) + 0.5) / nodes                   # cos^2 psi
        phi = (np.arange(nodes) + 0.5) / nodes * (2.0 * math.pi)
        tan_psi = np.sqrt(1.0 - w) / np.sqrt(w)
        t = (tan_psi[:, None] * np.cos(phi)[None, :]).reshape(-1)
        s = (tan_psi[:, None] * np.sin(phi)[None, :]).reshape(-1)
        geometry = PeriodGeometry(t, s, d=self.strip_thickness, period=self.period,
                                  h=self.strip_height)
        mus, mui = self.attenuation(e)
        return np.array([geometry.mean(a, b).mean() for a, b in zip(mus, mui)])

    def figures_of_merit(self, energies_kev, weights=None, *, spr: float,
                         scatter_energies=None, scatter_weights=None) -> dict:
        """The IEC 60627 figures of merit for a spectrum (primary) and a scatter spectrum.

        Parameters
        ----------
        energies_kev, weights : array_like
            The primary beam at the grid as the detector weighs it (e.g. the fluence times
            the energy for an energy-integrating detector); default weights equal.
        spr : float
            Scatter-to-primary ratio (of the same weighted signal) in front of the grid.
        scatter_energies, scatter_weights : array_like, optional
            The scatter's spectrum; default the primary's (an approximation: Compton
            scattering lowers it a little). Its directions are isotropic over the half space
            (:meth:`scatter_transmission`).

        Returns
        -------
        dict
            ``Tp``, ``Ts``, ``Tt``, ``bucky_factor``, ``selectivity``,
            ``contrast_improvement``, ``spr_after`` (the SPR behind the grid).
        """
        e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
        w = np.ones_like(e) if weights is None else np.asarray(weights, dtype=np.float64)
        es = e if scatter_energies is None else np.atleast_1d(
            np.asarray(scatter_energies, dtype=np.float64))
        ws = (w if scatter_energies is None else np.ones_like(es)) if scatter_weights is None \
            else np.asarray(scatter_weights, dtype=np.float64)
        spr = float(spr)
        if not spr >= 0:
            raise ValueError(f"spr must be >= 0, got {spr}")
        tp = float(w @ self.primary_transmission(e) / w.sum())
        ts = float(ws @ self.scatter_transmission(es) / ws.sum())
        tt = (tp + spr * ts) / (1.0 + spr)
        return {"Tp": tp, "Ts": ts, "Tt": tt, "bucky_factor": 1.0 / tt, "selectivity": tp / ts,
                "contrast_improvement": tp / tt, "spr_after": spr * ts / tp}


def _strip_cover(y, d, period):
    """Length of ``[0, y]`` lying in strips ``[k P, k P + d)`` (y >= 0)."""
    k = np.floor(y / period)
    return k * d + np.minimum(y - k * period, d)


def _phi(z):
    """``(1 - exp(-z)) / z``, 1 at 0, accurate for small z."""
    z = np.asarray(z, dtype=np.float64)
    small = np.abs(z) < 1e-8
    safe = np.where(small, 1.0, z)
    return np.where(small, 1.0 - 0.5 * z, -np.expm1(-safe) / safe)


def period_mean(mu_strip, mu_inter, tan_angle, tan_along, *, d, period, h):
    """The Day & Dance mean transmission over one period (arrays broadcast; 1/mm and mm).

    A line entering at ``x`` (from a strip's edge) drifts ``p = h |t|`` across; the strip
    length it covers, ``c(x) = S(x + p) - S(x)`` with ``S`` the strip length in ``[0, y]``,
    is piecewise linear between ``0, d, -p mod P, d - p mod P``: the mean of
    ``exp(-L (mu_i + (mu_s - mu_i) c(x) / p))`` is then a sum of exact integrals. For
    ``p = 0``: ``D/P exp(-mu_i h) + d/P exp(-mu_s h)``.
    """
    mus, mui, t, s = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in
                                           (mu_strip, mu_inter, tan_angle, tan_along)))
    return PeriodGeometry(t, s, d=d, period=period, h=h).mean(mus, mui)


class PeriodGeometry:
    """The energy-independent part of :func:`period_mean` at the points ``(t, s)``: the
    kinks and strip fractions, computed once; :meth:`mean` evaluates the period mean at any
    attenuations."""

    def __init__(self, t, s, *, d, period, h):
        t, s = np.broadcast_arrays(np.asarray(t, dtype=np.float64),
                                   np.asarray(s, dtype=np.float64))
        P = float(period)
        p = h * np.abs(t)
        straight = p <= 1e-12 * P
        p_safe = np.where(straight, 1.0, p)
        kinks = np.stack([np.zeros_like(p), np.full_like(p, d), np.mod(-p, P),
                          np.mod(d - p, P), np.full_like(p, P)], axis=-1)
        kinks.sort(axis=-1)
        c = _strip_cover(kinks + p[..., None], d, P) - _strip_cover(kinks, d, P)
        frac = np.clip(c / p_safe[..., None], 0.0, 1.0)      # strip fraction of the path
        self.length = h * np.sqrt(1.0 + t * t + s * s)
        self.straight, self.width = straight, np.diff(kinks, axis=-1)
        self.f0, self.f1 = frac[..., :-1], frac[..., 1:]
        self.d, self.period = float(d), P

    def mean(self, mu_strip, mu_inter) -> np.ndarray:
        """The period mean at these attenuations (1/mm; broadcast with the points)."""
        mus = np.asarray(mu_strip, dtype=np.float64)
        mui = np.asarray(mu_inter, dtype=np.float64)
        L, P, d = self.length, self.period, self.d
        base = np.exp(-mui * L)
        k = ((mus - mui) * L)[..., None]                     # exponent per unit fraction
        f0, f1 = self.f0, self.f1
        # the integral of exp(-k f) along a linear f, from its smaller exponent (no overflow)
        low = np.where(k >= 0, np.minimum(f0, f1), np.maximum(f0, f1))
        part = self.width * np.exp(-k * low) * _phi(np.abs(k) * np.abs(f1 - f0))
        mean = part.sum(axis=-1) / P
        straight_mean = ((P - d) + d * np.exp(-(mus - mui) * L)) / P
        return base * np.where(self.straight, straight_mean, mean)
