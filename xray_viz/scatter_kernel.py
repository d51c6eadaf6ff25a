"""A fast scatter model: scatter kernel superposition calibrated on the transport.

The scatter a detector pixel receives is the sum, over the pixels of the irradiated field, of
each pixel's *scatter source* spread by a kernel, as in the scatter kernel superposition of
Ohnesorge, Flohr and Klingenbeck-Regn (Med Phys 26:13, 1999) and of Sun and Star-Lack (Phys Med
Biol 55:6695, 2010)::

    S(x) = sum_x' T(x') A(tau(x')) K(x - x'; tau(x'), gap)

in the units of the flat field (those of ``exp(log_transmission)`` and of
``Transport.images[k] / flat_signal(scene)``), with

- ``T`` the primary transmission of the pixel (``exp(log_transmission)``) and ``tau`` its
  water-equivalent thickness (mm): the thickness of water whose transmission, weighed by this
  scene's spectrum and detector (:class:`~xray_viz.physics.beam.Beam`), is ``T``;
- with each pixel's path lengths per body (``scatter(..., path_lengths=)``, which
  ``render(scatter="kernel")`` passes), the amplitude is read instead at the pixel's
  *scatter-equivalent* water thickness ``tau_s = sum_b L_b mu_s,b / mu_s,water``: the water
  that scatters as much toward the detector, while ``T`` stays the transmission as traced and
  ``tau`` (the kernel's spread) its water-equivalent thickness. ``mu_s`` is the incoherent
  plus coherent part of the attenuation of each body's material at ``E`` (xraylib's
  ``DCS_Compt + DCS_Rayl``), counting only the photons scattered within the cone the detector
  subtends from the bodies' exit side (:meth:`KernelModel.cone`, :meth:`KernelModel.
  scattering_coefficients`). A body of high Z absorbs more by the photoelectric effect and
  scatters less per unit of attenuation than water (20 mm of cortical bone attenuates like
  about 55 mm of water at 90 kVp but scatters like about 37 mm), and more of its scatter is
  coherent, which is forward-peaked: far from a small detector, most of the scatter detected
  is coherent (about 90 % of it for the aluminium step wedge 490 mm above its detector), and
  aluminium then scatters toward the detector 4.7 times as much as water per mm, not the 2.6
  times of the whole cross sections. This is the material-dependent amplitude of Sun and
  Star-Lack's kernels in a simple form with no new parameter (the water fit read at another
  thickness; single-scatter acceptance, the multiple scatter taken to follow it). A voxel
  volume's classes are read the same way (``volumes=``: their materials after the bodies');
- ``A(tau, E)`` the scatter-to-primary ratio of an infinite slab of that thickness (the
  amplitude factor), ``ln A = a0 + a1 ln(tau / 100 mm) + a2 (tau / 100 mm - 1)
  + a3 ln(E / 50 keV) + a4 (tau / 100 mm) ln(E / 50 keV)``: Sun and Star-Lack's
  ``c T^alpha (ln 1/T)^beta`` written in the water-equivalent thickness, the spectrum entering
  by ``E``, the mean energy of the source's photons after 100 mm of water;
- a body narrower than the field keeps less than the slab of its thickness: a pixel ``d`` mm
  from the edge of the bodies' shadow sends a share ``b_edge exp(-d / (c_edge tau +
  l_edge))`` of its incoherent scatter out by the body's sides instead (from the body's
  middle, evenly per solid angle: most of it lands beyond a small field). The slab fit's
  amplitude includes the scatter that the material beyond the irradiated field sends back
  into it (the calibration's slabs are wider than the field); a body narrower than the field
  has none, and what it sends sideways leaves it. The coherent share (water's within the
  cone, or each pixel's from its path lengths: :meth:`KernelModel.path_weights`) is left
  out: forward and single, it does not go sideways (most of what the aluminium step wedge
  sends to its detector 490 mm below). Fitted on water cylinders, spheres and blocks
  narrower than the field with the slab parameters held (``benchmarks/
  calibrate_scatter_kernel.py``, stage 2), the reach bounded at ``tau + 100`` mm (a body
  covering all of the field but a corner is nearly a slab);
- ``K`` the scatter's spread, two components (Sun and Star-Lack's two-component kernel form):
  a forward-peaked one and a broad one (``fraction`` of the scatter). Each is the footprint
  on the detector of photons leaving a *virtual source* ``h_i = gap + s_i tau M`` mm above it
  with intensity ``cos^n_i`` of their angle per unit solid angle,
  ``(n + 1) h^(n+1) / (2 pi (r^2 + h^2)^((n+3)/2))`` per unit area
  (:meth:`KernelModel.gap_kernel`): the scatter leaves the body as if from a point inside it,
  ``s_i tau`` above its exit side (magnified to the detector plane, ``M`` the
  source-to-detector over the source-to-exit distance), then crosses the air ``gap``
  between the bodies' exit side and the detector, so that the spread in the body and across
  the gap add, and the photons far out arrive obliquely (what an anti-scatter grid weighs).
  The ``gap`` of each group of thickness is the mean, over its scatter source, of the air
  gaps below the bodies' exit side (:meth:`KernelModel.exit_heights`: a frog's or a
  cylinder's exit side rises toward the edges of its shadow, 75-125 mm above the detector
  for the frog; the lowest point alone made the frog's scatter too concentrated, 16 % high).

Behind an anti-scatter grid (``[detector] grid``) each kernel is weighed by the grid's
transmission at the angle its photons arrive at across the strips, measured from the strip
where they arrive (the grid is focused: kernels at :data:`GRID_NODES` positions along ``u``),
for the scatter's spectrum (:meth:`KernelModel.scatter_transmission`: the source's, hardened
by ``grid_hardening`` times the group's thickness, scattered once within the cone the
detector subtends, Compton-shifted); the angles as from ``grid_depth`` mm into the body at
most (``depth / (1 + depth / grid_depth)``: most of the scatter from deep in a thick body is
scattered again near its exit side and arrives more obliquely than from the kernel's
source). Both fitted on water slabs and a cylinder behind the default grid (stage 3). The
scatter is then relative to each pixel's flat field behind the grid, off-focus cut-off
included (:meth:`~xray_viz.physics.grid.Grid.off_focus`, as the renderer's primary).

The sum is evaluated by FFT on a coarse grid (at most :data:`COARSE` cells along a side) for a
few groups of thickness (:data:`GROUPS`, each with its own kernel) and interpolated back to the
pixels. The parameters are fitted by least squares on the transport's scatter images of water
slabs (the amplitude and the kernels), then of water bodies narrower than the field (the edge
term), then of water behind the default grid (the grid's angles and spectrum)
(``benchmarks/calibrate_scatter_kernel.py``), and stored in
``xray_viz/data/scatter_kernel.json`` with the ranges of the fit: a scene outside them (its
spectrum's energy, a water-equivalent thickness, the field size or the air gap) gets a
:class:`~xray_viz.errors.ScatterModelWarning` naming the quantity and its value.

Examples
--------
>>> import numpy as np, xray_viz
>>> scene = xray_viz.load_scene("nested_spheres")
>>> model = KernelModel.of(scene)
>>> log_t = -xray_viz.render(scene).line_integral
>>> s = model.scatter(log_t, scene.acquisition, scene.bodies)
>>> s.shape, bool(np.all(s >= 0)), bool(s.max() < 1)
((256, 256), True, True)
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xray_viz.errors import SceneError, ScatterModelWarning

__all__ = ["KernelModel", "KernelParameters", "load_parameters", "PARAMETERS_FILE",
           "PARAMETER_NAMES", "RANGE_NAMES", "COARSE", "GROUPS", "TOLERANCE", "TAU_MIN",
           "EXIT_CELLS", "GRID_NODES", "GRID_ANGLES", "GRID_TAU_STEP"]

#: The calibration shipped with the package.
PARAMETERS_FILE = Path(__file__).parent / "data" / "scatter_kernel.json"

#: The fitted parameters, in the order of :attr:`KernelParameters.values`.
PARAMETER_NAMES = ("a0", "a1", "a2", "a3", "a4", "fraction", "s1", "s2", "n1",
                   "n2", "b_edge", "c_edge", "l_edge", "grid_depth", "grid_hardening")

#: The ranges of the fit: ``[low, high]`` each.
RANGE_NAMES = ("energy_kev", "thickness_mm", "field_mm", "gap_mm")

#: The model's stated error: the relative error of its scatter (and SPR) over blocks of a
#: few mm against the transport, inside the fitted ranges, for water, bone layers in water,
#: the bundled phantoms (the limb, the nested spheres, the aluminium step wedge, the frog's
#: 15 tissues; given the path lengths per body) and water behind a grid (BENCHMARKS.md,
#: "Scatter kernel model": medians of 2.3-6.3 % on the cases it was not fitted on, 5.3-8.8 %
#: behind a grid). A large body close to the detector is 13-18 % low beside it (see there).
TOLERANCE = 0.10

#: Cells of the coarse grid along the detector's longer side, at most.
COARSE = 64

#: Upper edges (mm of water) of the groups of thickness that share a kernel.
GROUPS = (20.0, 45.0, 75.0, 110.0, 150.0, 200.0, 260.0, 330.0, np.inf)

#: Water-equivalent thickness (mm) below which a pixel sends no scatter and lies outside
#: the bodies' shadow (the edge term's): a spectrum's weights sum to 1 only to rounding, so
#: the unattenuated pixels invert to a few 1e-15 mm, not 0.
TAU_MIN = 0.05

#: Step of the look-up table in ``ln(1 / T)``.
LOOKUP_STEP = 5e-4

#: The kernels' heights above the detector are rounded to multiples of this (mm), so that
#: the views of a scan share their kernels (:meth:`KernelModel._spread`).
HEIGHT_STEP = 0.5

#: Positions along the detector's ``u`` axis at which a focused grid's kernels are taken
#: (the scatter's sources shared linearly between neighbours).
GRID_NODES = 5

#: Angles in (-pi/2, pi/2) of the table of the grid's scatter transmission.
GRID_ANGLES = 2001

#: Steps (mm of water) of the thicknesses that harden the scatter's spectrum for a grid's
#: transmission (:meth:`KernelModel.scatter_transmission`).
GRID_TAU_STEP = 10.0

#: Cells along a side of the map of the bodies' exit heights, at most
#: (:meth:`KernelModel.exit_heights`: each group's mean air gap).
EXIT_CELLS = 32

#: Surface points projected at a time (:meth:`KernelModel.exit_heights`).
POINTS_CHUNK = 16384

#: Kernels kept on a model at most (emptied when full).
SPREADS_KEPT = 256

#: Water-equivalent thicknesses tabulated for the inversion of the transmission (mm).
_TAU = np.concatenate([np.linspace(0.0, 50.0, 501), np.linspace(50.5, 1000.0, 1900)])


@dataclass(frozen=True)
class KernelParameters:
    """A calibration of the kernel model.

    Attributes
    ----------
    values : dict of str to float
        :data:`PARAMETER_NAMES`.
    ranges : dict of str to (float, float)
        :data:`RANGE_NAMES`: what the fit covered.
    meta : dict
        Date, commit, histories, cases, residuals of the fit (free form).
    """

    values: dict
    ranges: dict
    meta: dict

    def to_dict(self) -> dict:
        """The JSON document :func:`load_parameters` reads."""
        return {"parameters": {k: float(self.values[k]) for k in PARAMETER_NAMES},
                "ranges": {k: [float(v) for v in self.ranges[k]] for k in RANGE_NAMES},
                "meta": self.meta}


def load_parameters(path=None) -> KernelParameters:
    """Read a calibration file (default :data:`PARAMETERS_FILE`).

    Raises
    ------
    SceneError
        The file is missing, not JSON, or lacks a parameter or range (one line naming it).
    """
    path = Path(PARAMETERS_FILE if path is None else path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"scatter kernel calibration {path} not found: regenerate it with "
                         "benchmarks/calibrate_scatter_kernel.py") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SceneError(f"scatter kernel calibration {path} is not readable JSON "
                         f"({type(exc).__name__}): regenerate it with "
                         "benchmarks/calibrate_scatter_kernel.py") from None
    if not isinstance(doc, dict):
        raise SceneError(f"scatter kernel calibration {path}: expected a JSON object")
    values, ranges = {}, {}
    params = doc.get("parameters")
    for name in PARAMETER_NAMES:
        v = params.get(name) if isinstance(params, dict) else None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SceneError(f"scatter kernel calibration {path}: parameters.{name} must be a "
                             f"finite number, got {v!r}")
        values[name] = float(v)
    rng = doc.get("ranges")
    for name in RANGE_NAMES:
        v = rng.get(name) if isinstance(rng, dict) else None
        ok = (isinstance(v, list) and len(v) == 2
              and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                      and math.isfinite(x) for x in v) and v[0] <= v[1])
        if not ok:
            raise SceneError(f"scatter kernel calibration {path}: ranges.{name} must be "
                             f"[low, high] numbers, got {v!r}")
        ranges[name] = (float(v[0]), float(v[1]))
    if values["a1"] <= 0 or not 0 <= values["fraction"] <= 1 or not 0 <= values["b_edge"] <= 1:
        raise SceneError(f"scatter kernel calibration {path}: needs a1 > 0 and fraction and "
                         f"b_edge in [0, 1], got a1 = {values['a1']}, fraction = "
                         f"{values['fraction']}, b_edge = {values['b_edge']}")
    if values["l_edge"] <= 0:
        raise SceneError(f"scatter kernel calibration {path}: needs l_edge > 0 (mm), got "
                         f"l_edge = {values['l_edge']}")
    meta = doc.get("meta", {})
    return KernelParameters(values, ranges, meta if isinstance(meta, dict) else {})


def _warn(message):
    warnings.warn(message, ScatterModelWarning, stacklevel=3)


class KernelModel:
    """The scatter kernel superposition model of one scene's beam (spectrum and detector).

    Build it with :meth:`of`; :meth:`scatter` gives the scatter image of an acquisition.

    Attributes
    ----------
    parameters : KernelParameters
    energy_kev : float
        Mean energy of the source's photons after 100 mm of water (the spectrum's variable).
    """

    def __init__(self, tau, log_t_water, energy_kev, parameters, *, grid=None,
                 grid_primary=1.0, grid_spectrum=None):
        self._tau, self._minus_log_t = tau, -log_t_water
        self.energy_kev = float(energy_kev)
        self.parameters = parameters
        self.grid, self.grid_primary = grid, float(grid_primary)
        self.grid_spectrum = grid_spectrum
        self._grid_tables = {}                  # scatter_transmission's, by key
        self._spreads = (parameters, {})     # the kernels' spectra (_spread)
        self._table, self._table_params = None, None    # the look-up table (_lookup)

    @classmethod
    def of(cls, scene, *, parameters=None) -> KernelModel:
        """The model of ``scene``'s source and detector (its bodies come with each call).

        Parameters
        ----------
        scene : Scene
        parameters : KernelParameters, optional
            Default :func:`load_parameters`.

        Raises
        ------
        SceneError
            No detector, or the calibration file is malformed (:func:`load_parameters`).

        Warns
        -----
        ScatterModelWarning
            The spectrum's energy outside the fitted range, a detector response other than
            ``"energy"``.

        Notes
        -----
        A detector ``grid`` (:class:`~xray_viz.physics.grid.Grid`: ``transmission(energies,
        tan_angle)``, ``primary_transmission(energies)``) weighs each component's spread
        across the air gap by the grid's transmission at the angle a photon arrives at (the
        offset across the strips, along the detector's ``u`` axis, over the gap; at
        :attr:`energy_kev`), and divides the scatter by the grid's primary transmission:
        the scatter relative to the flat field behind the grid. Derived from the kernel's
        angular model, not fitted on the transport's grid scoring.
        """
        from xray_viz.physics.beam import Beam, MM_PER_CM
        from xray_viz.physics.materials import linear_attenuation

        det = getattr(scene, "detector", None)
        if det is None:
            raise SceneError("the scatter kernel needs the scene's detector (its response "
                             "weighs the spectrum): add a [detector] table")
        if parameters is None:
            parameters = load_parameters()
        beam = Beam.of(scene.source, (), det)
        e = beam.spectrum.energies[beam.keep]
        u1 = beam.u1[beam.keep]
        mu = np.asarray(linear_attenuation("Water, Liquid", e), float) / MM_PER_CM   # 1/mm
        with np.errstate(divide="ignore"):
            log_w = np.log(u1) - np.log(u1.sum())
        work = log_w[None, :] - _TAU[:, None] * mu[None, :]
        top = work.max(axis=1)
        log_t_water = top + np.log(np.exp(work - top[:, None]).sum(axis=1))
        phi = beam.spectrum.weights[beam.keep] * np.exp(-100.0 * mu)
        energy = float(phi @ e / phi.sum())
        lo, hi = parameters.ranges["energy_kev"]
        if not lo <= energy <= hi:
            _warn(f"scatter kernel: the spectrum's mean energy after 100 mm of water, "
                  f"{energy:.1f} keV, is outside the fitted {lo:g}-{hi:g} keV")
        response = det.response
        if response != "energy":
            _warn(f"scatter kernel: fitted for an energy-integrating detector, the scene's "
                  f"response is {response!r}")
        grid = det.grid
        grid_primary, grid_spectrum = 1.0, None
        if grid is not None:
            # the primary's transmission through the grid as the detector without it weighs
            # the beam: the flat field behind the grid over the one without
            from dataclasses import replace

            bare = Beam.of(scene.source, (), replace(det, grid=None))
            w0 = bare.u1[bare.keep]
            grid_primary = float(w0 @ np.asarray(grid.primary_transmission(e), float)
                                 / w0.sum())
            # the scatter's spectrum: the source's after the bodies' water, as detected
            grid_spectrum = (e, w0, mu)
        return cls(_TAU, log_t_water, energy, parameters, grid=grid,
                   grid_primary=grid_primary, grid_spectrum=grid_spectrum)

    def water_thickness(self, log_transmission) -> np.ndarray:
        """Water-equivalent thickness (mm) of each transmission ``ln T``: the water of the
        same spectrum-weighted transmission.

        Examples
        --------
        >>> import xray_viz
        >>> model = KernelModel.of(xray_viz.load_scene("sphere"))      # 60 keV
        >>> mu = 0.020588                                              # water, 1/mm, about
        >>> round(float(model.water_thickness(-mu * 100.0)), 0)
        100.0
        """
        return np.interp(-np.asarray(log_transmission, float), self._minus_log_t, self._tau)

    def _lookup(self):
        """``(tau, T A(tau), group)`` on the uniform grid of ``ln(1 / T)``, step
        :data:`LOOKUP_STEP`, up to the water table's end (cached per parameters)."""
        if self._table_params is not self.parameters:
            grid = np.arange(0.0, self._minus_log_t[-1] + LOOKUP_STEP, LOOKUP_STEP)
            tau = np.interp(grid, self._minus_log_t, self._tau)
            q = np.exp(-grid) * self.amplitude(tau)
            q[tau < TAU_MIN] = 0.0
            group = np.searchsorted(np.asarray(GROUPS), tau, side="left")
            self._table, self._table_params = (tau, q, group), self.parameters
        return self._table

    def amplitude(self, tau) -> np.ndarray:
        """The scatter-to-primary ratio of an infinite water slab ``tau`` mm thick."""
        p = self.parameters.values
        t = np.asarray(tau, float) / 100.0
        le = math.log(self.energy_kev / 50.0)
        with np.errstate(divide="ignore"):
            ln_a = (p["a0"] + p["a1"] * np.log(t) + p["a2"] * (t - 1.0) + p["a3"] * le
                    + p["a4"] * t * le)
        return np.exp(ln_a)

    def gap_kernel(self, gap, shape, cells, n, across=0.0, angle=None,
                   table=None) -> np.ndarray | None:
        """A component's kernel on the coarse grid (FFT order, each cell's share):
        ``(n + 1) h^(n+1) / (2 pi (r^2 + h^2)^((n+3)/2))`` per unit area, the footprint at
        the detector of photons leaving a point ``h = gap`` mm above it with intensity
        ``cos^n`` of their angle per unit solid angle (times the grid's transmission at
        their angle, with a grid, for photons leaving from ``across`` mm along ``u`` from
        the detector's middle, as if from ``angle`` mm above the detector, default ``h``:
        :meth:`_footprint`); None for ``h`` below a quarter of a cell (all in the cell
        below it at this resolution)."""
        (ny, nx), (cy, cx) = shape, cells
        if gap < 0.25 * min(cy, cx):
            return None
        ky = np.arange(ny)
        ky = np.where(ky > ny // 2, ky - ny, ky) * cy
        kx = np.arange(nx)
        kx = np.where(kx > nx // 2, kx - nx, kx) * cx
        angle = gap if angle is None else angle
        out = self._footprint(ky[:, None], kx[None, :], gap, n, across, angle,
                              table) * (cy * cx)
        # the cells near the origin, where it changes within a cell: 9 x 9 points each
        m = min(3, ny // 2 - 1, nx // 2 - 1)
        sub = (np.arange(9) - 4.0) / 9.0
        idx = np.arange(-m, m + 1)
        y = ((idx[:, None] + sub[None, :]) * cy).reshape(-1)
        x = ((idx[:, None] + sub[None, :]) * cx).reshape(-1)
        core = self._footprint(y[:, None], x[None, :], gap, n, across, angle, table)
        core = core.reshape(2 * m + 1, 9, 2 * m + 1, 9).mean(axis=(1, 3)) * (cy * cx)
        out[np.ix_(idx % ny, idx % nx)] = core
        return out

    def _spread(self, components, shape, cells, across=0.0, table=None) -> np.ndarray:
        """``rfft2`` of a kernel: the sum of ``components``, ``(share, step, n, angle)``
        each, a :meth:`gap_kernel` at ``step`` times :data:`HEIGHT_STEP` mm (its photons'
        angles through a grid as if from ``angle`` times that); kept on the model for the
        next calls with the same components, coarse grid, cells, ``across`` and grid table
        ``table`` (:meth:`scatter_transmission`; a scan's views share most of them)."""
        key = (components, shape, cells, across, table)
        cache = self._spreads
        if cache[0] is not self.parameters:
            cache = self._spreads = (self.parameters, {})
        hit = cache[1].get(key)
        if hit is None:
            kern = np.zeros(shape)
            for share, step, n, angle in components:
                spread = self.gap_kernel(step * HEIGHT_STEP, shape, cells, n, across,
                                         angle * HEIGHT_STEP, table)
                if spread is None:
                    kern[0, 0] += share * self.grid_factor(n, across, table)
                else:
                    kern += share * spread
            hit = np.fft.rfft2(kern)
            if len(cache[1]) >= SPREADS_KEPT:
                cache[1].clear()
            cache[1][key] = hit
        return hit

    def _grid_nodes(self, w, k, pu, cw):
        """``[(across, weights)]``: with a grid, :data:`GRID_NODES` positions along ``u``
        (mm from the detector's middle) over the coarse grid's ``cw`` columns and each
        column's share of each (linear between neighbours): the strips lean toward the
        focus, so a photon's angle across them depends on where it arrives. Without a
        grid, ``[(0.0, None)]``."""
        if self.grid is None or cw < 2:
            return [(0.0, None)]
        u = ((np.arange(cw) + 0.5) * k - 0.5 * w) * pu          # the columns' centres
        nodes = np.linspace(u[0], u[-1], min(GRID_NODES, cw))
        step = nodes[1] - nodes[0]
        return [(round(float(c), 6), np.maximum(0.0, 1.0 - np.abs(u - c) / step))
                for c in nodes]

    @staticmethod
    def _edge_distance(inside, cells):
        """mm from each cell's centre to the edge of the bodies' shadow (half a cell short of
        the nearest cell outside it: the same at any cell size; the field's own edge is not
        one); None when the shadow covers the field."""
        if inside.all():
            return None
        from scipy.ndimage import distance_transform_edt

        d = distance_transform_edt(inside, sampling=cells)
        return np.maximum(d - 0.5 * min(cells), 0.0)

    def _footprint(self, y, x, gap, n, across=0.0, angle=None, table=None):
        """The per-area density of :meth:`gap_kernel` at offsets ``y``, ``x`` (mm), times
        the grid's transmission at ``tan = x / angle - (across + x) / focus_distance``
        across the strips (``angle`` default ``gap``; the angle from the strip where the
        photon arrives, ``across + x`` mm from the detector's middle along ``u``: the grid
        is focused)."""
        h2 = gap * gap
        # (n + 1) h^(n+1) / (2 pi (r^2 + h^2)^((n+3)/2)), without overflow for a large n
        dens = (n + 1.0) / (2.0 * math.pi * h2) * (h2 / (y * y + x * x + h2)) ** (
            (n + 3.0) / 2.0)
        if self.grid is not None:                  # across the strips: along u
            tan = x / (gap if angle is None else angle) - (across + x) / self.grid.focus_distance
            dens = dens * self.scatter_transmission(tan, table)
        return dens

    def _angle_depth(self, depth):
        """How far (mm) above the bodies' exit side a kernel's photons seem to come from,
        for their angles through a grid: its source's ``depth``, but no deeper than a few
        of ``grid_depth`` (``depth / (1 + depth / grid_depth)``): most of the scatter from
        deep in a thick body is scattered again on its way out, the last time near the
        exit side, and arrives more obliquely than from the kernel's source. ``depth``
        without a grid (where the angles do not matter)."""
        if self.grid is None:
            return depth
        return depth / (1.0 + depth / self.parameters.values["grid_depth"])

    def scatter_transmission(self, tan_angle, table=None) -> np.ndarray:
        """The grid's transmission of the scatter at the tangents ``tan_angle`` across its
        strips (from the local focused direction), weighted over the scatter's energies:
        the source's photons as the detector weighs them, hardened by ``grid_hardening``
        times the group's water-equivalent thickness, scattered once within the cone the
        detector subtends (:meth:`cone`), water's coherent share of them at their own
        energy, the rest Compton-shifted (Klein-Nishina); interpolated in the table
        ``table`` (the key :meth:`scatter` made it under: :data:`GRID_ANGLES` angles and 0).
        1 without a grid."""
        if self.grid is None:
            return np.ones(np.shape(tan_angle))
        theta, values = self._grid_tables[table]
        return np.interp(np.arctan(tan_angle), theta, values)

    def _grid_table_for(self, cone, coherent, tau):
        """The key of :meth:`scatter_transmission`'s table for this cone, coherent share and
        water thickness ``tau`` (mm, in steps of :data:`GRID_TAU_STEP`: the scatter's
        spectrum is the source's hardened by it), made and kept on the model on first use."""
        step = int(round(tau / GRID_TAU_STEP))
        key = (round(cone, 6), step)
        if key not in self._grid_tables:
            e, w0, mu = self.grid_spectrum
            e, w = _compton_shifted(e, w0 * np.exp(-step * GRID_TAU_STEP * mu), cone,
                                    coherent)
            theta = np.union1d(np.linspace(-0.5 * math.pi, 0.5 * math.pi, GRID_ANGLES)[1:-1],
                               [0.0])
            self._grid_tables[key] = (theta,
                                      self.grid.spectrum_transmission(e, w, np.tan(theta)))
        return key

    def grid_factor(self, n, across=0.0, table=None) -> float:
        """The grid's mean transmission of scatter leaving with intensity ``cos^n`` of its
        angle per unit solid angle (the no-gap limit of :meth:`gap_kernel`, ``across`` mm
        along ``u`` from the detector's middle); 1 without a grid."""
        if self.grid is None:
            return 1.0
        theta = (np.arange(400) + 0.5) * (0.5 * math.pi / 400)
        phi = (np.arange(64) + 0.5) * (2.0 * math.pi / 64)
        w = np.cos(theta) ** n * np.sin(theta)
        tan_u = (np.tan(theta)[:, None] * np.cos(phi)[None, :]
                 - across / self.grid.focus_distance)
        t = self.scatter_transmission(tan_u, table)
        return float((w[:, None] * t).sum() / (w.sum() * len(phi)))

    @staticmethod
    def geometry(acquisition, bodies, volumes=()) -> tuple[float, float]:
        """``(gap, magnification)``: the air gap (mm) between the bodies' side nearest the
        detector (and the voxel volumes' non-empty voxels', every few mm) and the
        detector plane, and the source-to-detector distance over the source-to-exit
        distance (1 for a parallel beam)."""
        f = acquisition.frame
        parts = [_volume_points(v, 4.0) for v in volumes]
        if len(bodies):
            parts.append(bodies.cached(("scatter_kernel", "points"),
                                       lambda: np.vstack([np.asarray(b.mesh.vertices, float)
                                                          for b in bodies]), limit=1)
                         if hasattr(bodies, "cached") else
                         np.vstack([np.asarray(b.mesh.vertices, float) for b in bodies]))
        pts = np.vstack(parts) if parts else np.zeros((0, 3))
        if not len(pts):
            return 0.0, 1.0
        normal = np.asarray(f.normal, float)
        # above the detector plane (einsum's own loop: no BLAS threads to wait for)
        gap = max(0.0, float(np.asarray(f.middle, float) @ normal
                             - np.einsum("ij,j->i", pts, normal).max()))
        if f.parallel:
            return gap, 1.0
        d = float(f.distance)
        return gap, d / max(d - gap, 1e-9)

    @staticmethod
    def exit_heights(acquisition, bodies, cells, k, volumes=()) -> np.ndarray:
        """``(ch, cw)`` float: mm above the detector plane of the bodies' side nearest it
        (their exit side) over each cell of ``k x k`` pixels of ``acquisition``; NaN where no
        body's surface projects.

        The lowest of the bodies' surface points that project into the cell: their
        vertices, and points on a lattice over each triangle whose projection spans more
        than a cell (at most a cell apart), projected from the source (along the beam
        for a parallel one). A slab's is its exit face's everywhere; a cylinder's or a
        frog's rises toward the edges of its shadow, where the air gap the scatter crosses
        is longer than the global one (:meth:`geometry`).

        Examples
        --------
        >>> import xray_viz
        >>> scene = xray_viz.load_scene("sphere")     # r 40 mm, centre 500 mm up
        >>> h = KernelModel.exit_heights(scene.acquisition, scene.bodies, (8, 8), 32)
        >>> round(float(np.nanmin(h)), 0), bool(np.isnan(h[0, 0]))
        (460.0, True)
        """
        f = acquisition.frame
        ch, cw = cells
        out = np.full(ch * cw, np.nan)
        meshes = [b.mesh for b in bodies if getattr(b, "mesh", None) is not None]
        if not meshes and not volumes:
            return out.reshape(ch, cw)
        normal, middle = np.asarray(f.normal, float), np.asarray(f.middle, float)
        pu, pv = (float(x) for x in f.pitch)
        verts = [v.corners for v in volumes]
        if meshes:
            verts.append(bodies.cached(("scatter_kernel", "points"), lambda: np.vstack(
                [np.asarray(m.vertices, float) for m in meshes]), limit=1)
                if hasattr(bodies, "cached") else
                np.vstack([np.asarray(m.vertices, float) for m in meshes]))
        top = max(float(np.max(np.einsum("ij,j->i", x, -normal))) for x in verts) + float(
            middle @ normal)                                    # the highest point
        stretch = 1.0 if f.parallel else float(f.distance) / max(float(f.distance) - top,
                                                                 1e-9)
        # points at most a cell apart once projected, so that a cell a surface crosses
        # holds some of its points (in quarter octaves of mm: a scan's views share them)
        spacing = 2.0 ** (math.floor(4.0 * math.log2(k * min(pu, pv) / stretch)) / 4.0)
        pts = [_volume_points(v, spacing) for v in volumes]
        if meshes:
            pts.append(bodies.cached(("scatter_kernel", "surface", spacing),
                                     lambda: _surface_points(meshes, spacing), limit=2)
                       if hasattr(bodies, "cached") else _surface_points(meshes, spacing))
        pts = pts[0] if len(pts) == 1 else np.vstack(pts)
        axes = np.stack([np.asarray(f.ho, float), np.asarray(f.ve, float), normal], axis=1)
        w, h = f.shape
        out[:] = np.inf
        for lo in range(0, len(pts), POINTS_CHUNK):          # bounded temporaries
            if f.parallel:
                # along the beam onto the plane: (u, v) of the point, shifted
                rel = (pts[lo:lo + POINTS_CHUNK] - middle) @ axes
                fwd = np.asarray(f.forward, float) @ axes
                height = -rel[:, 2]
                u = rel[:, 0] + height / fwd[2] * fwd[0]
                v = rel[:, 1] + height / fwd[2] * fwd[1]
            else:
                # from the source through the point onto the plane
                rel = (pts[lo:lo + POINTS_CHUNK] - np.asarray(f.source, float)) @ axes
                base = (np.asarray(f.source, float) - middle) @ axes
                scale = float(f.distance) / rel[:, 2]
                height = float(f.distance) - rel[:, 2]
                u = base[0] + rel[:, 0] * scale
                v = base[1] + rel[:, 1] * scale
            col = u / pu + 0.5 * w                                # from the left edge
            row = 0.5 * h - v / pv                                # from the top edge
            ok = (col >= 0) & (col < w) & (row >= 0) & (row < h) & (height > -1e-9)
            index = (row[ok] // k).astype(np.intp) * cw + (col[ok] // k).astype(np.intp)
            np.minimum.at(out, index, height[ok])
        out[np.isinf(out)] = np.nan
        return out.reshape(ch, cw)

    def scattering_coefficients(self, bodies, *, cone=None, process=None) -> np.ndarray:
        """Each body's scattering coefficient over water's at :attr:`energy_kev`:
        ``(mu_incoherent + mu_coherent)`` of its material over that of liquid water (a body
        of constant ``mu`` scatters as water of the same attenuation); with ``cone``
        (radians), of the photons scattered within that angle only
        (:func:`~xray_viz.physics.materials.mass_scattering`); with ``process``
        (``"coherent"`` or ``"incoherent"``), that part of it (over water's whole).

        Examples
        --------
        >>> import xray_viz
        >>> scene = xray_viz.load_scene("step_wedge")                   # aluminium, 60 keV
        >>> model = KernelModel.of(scene)
        >>> [round(float(c), 2) for c in model.scattering_coefficients(scene.bodies)]
        [2.57]
        """
        from xray_viz.physics.materials import (check_material, linear_attenuation,
                                                mass_scattering)

        e = self.energy_kev
        water = (float(mass_scattering("Water, Liquid", e, cone=cone)[0])
                 * check_material("Water, Liquid"))
        share = 1.0 if process is None else (
            float(mass_scattering("Water, Liquid", e, cone=cone, process=process)[0])
            * check_material("Water, Liquid") / water)
        mu_water = float(linear_attenuation("Water, Liquid", e)[0])
        out = np.empty(len(bodies))
        for b, body in enumerate(bodies):
            if body.material is None:
                out[b] = float(body.mu) / mu_water * share
            else:
                rho = check_material(body.material, density=body.density)
                out[b] = float(mass_scattering(body.material, e, cone=cone,
                                               process=process)[0]) * rho / water
        return out

    def path_weights(self, acquisition, bodies, *, materials=None, volumes=()) -> np.ndarray:
        """``(n_materials, 2)``: each body's mm of path in mm of water that scatter as much
        toward the detector (:meth:`scattering_coefficients` within the :meth:`cone` of this
        acquisition), and the coherent part of it. ``materials``: the path lengths' columns
        (default ``bodies``; with voxel ``volumes``, the bodies then the volumes' classes,
        :func:`xray_viz.volume.with_volume_materials`).

        Examples
        --------
        >>> import xray_viz
        >>> scene = xray_viz.load_scene("step_wedge")          # 490 mm above its detector
        >>> w = KernelModel.of(scene).path_weights(scene.acquisition, scene.bodies)
        >>> w.shape, bool(w[0, 1] > 0.5 * w[0, 0])             # mostly coherent, aluminium
        ((1, 2), True)
        """
        gap, _ = self.geometry(acquisition, bodies, volumes)
        cone = self.cone(acquisition, gap)
        materials = bodies if materials is None else materials
        return np.stack([self.scattering_coefficients(materials, cone=cone),
                         self.scattering_coefficients(materials, cone=cone,
                                                      process="coherent")], axis=1)

    def _water_coherent(self, cone) -> float:
        """The coherent share of water's scattering within the cone (radians)."""
        from xray_viz.physics.materials import mass_scattering

        return float(mass_scattering("Water, Liquid", self.energy_kev, cone=cone,
                                     process="coherent")[0]
                     / mass_scattering("Water, Liquid", self.energy_kev, cone=cone)[0])

    @staticmethod
    def cone(acquisition, gap) -> float:
        """Half-angle (radians) of the cone the detector subtends from the bodies' exit side:
        ``atan(r / gap)``, ``r`` the radius of the disc of the detector's area (pi / 2 with
        no gap). Rounded to a quarter of a degree (the cross sections are cached per cone).
        """
        w, h = acquisition.detector.shape
        pu, pv = (float(x) for x in acquisition.frame.pitch)
        r = math.sqrt(w * h * pu * pv / math.pi)
        step = math.radians(0.25)
        return max(step, round(math.atan2(r, gap) / step) * step)

    def scatter(self, log_transmission, acquisition, bodies, *,
                path_lengths=None, scattering=None, coherent_share=None,
                volumes=()) -> np.ndarray:
        """The scatter reaching each pixel, relative to the flat field.

        Parameters
        ----------
        log_transmission : (H, W) float
            The noise-free primary ``ln(P / flat)`` of each pixel of ``acquisition``.
        acquisition : Acquisition
        bodies : Bodies or sequence of Body
            For the air gap between their exit side and the detector (and, with
            ``path_lengths``, their materials).
        path_lengths : (H, W, n_bodies) float, optional
            Each pixel's path length (mm) through each body (``Radiograph.path_length``).
            With them the amplitude is read at the pixel's *scatter-equivalent* water
            thickness (the water of the same incoherent + coherent line integral,
            :meth:`scattering_coefficients`) instead of the water-equivalent thickness of
            its transmission: a body of high Z absorbs more and scatters less per unit of
            attenuation than water. Without them, every body is taken for water.
        coherent_share : float, optional
            With ``scattering`` of shape (H, W): the coherent part's share of it at every
            pixel (one material's), instead of water's.
        volumes : sequence of VoxelVolume, optional
            The scene's voxel volumes (``Scene.volumes``): their non-empty voxels are
            bodies' exit sides too (the air gaps).
        scattering : (H, W, 2) or (H, W) float, optional
            The same thickness already summed, ``path_lengths @ w`` with ``w`` the
            :meth:`path_weights` of this acquisition (what the renderer accumulates while
            it traces, without the (H, W, n_bodies) array): the whole and its coherent
            part (the whole only: water's coherent share); not with ``path_lengths``.

        Returns
        -------
        (H, W) float
            Non-negative; zeros where nothing attenuates.

        Warns
        -----
        ScatterModelWarning
            A water-equivalent thickness, the field or the air gap outside the fitted range.
        """
        log_t = np.asarray(log_transmission, dtype=np.float64)
        h, w = log_t.shape
        scat = None
        if path_lengths is not None:
            lengths = np.asarray(path_lengths, dtype=np.float64)
            materials = tuple(bodies) + tuple(m for v in volumes for m in v.materials)
            n = len(materials)
            if lengths.shape != (h, w, n):
                raise SceneError(f"scatter kernel: path_lengths of shape {lengths.shape} for "
                                 f"a {h} x {w} image of {n} bodies and voxel classes: pass "
                                 f"Radiograph.path_length, ({h}, {w}, {n})")
            weights = self.path_weights(acquisition, bodies, materials=materials,
                                        volumes=volumes)
            # column by column: einsum's own loop for one vector is many times its loop
            # for two
            scat = np.stack([np.einsum("ijk,k->ij", lengths, weights[:, c])
                             for c in range(weights.shape[1])], axis=-1)
        elif scattering is not None:
            scat = np.asarray(scattering, dtype=np.float64)
            if scat.shape not in ((h, w), (h, w, 2)):
                raise SceneError(f"scatter kernel: scattering of shape {scat.shape} for a "
                                 f"{h} x {w} image: pass ({h}, {w}, 2) mm of water")
        coherent = None
        if scat is not None and scat.ndim == 3:
            scat, coherent = scat[..., 0], scat[..., 1]
        f = acquisition.frame
        pu, pv = (float(x) for x in f.pitch)
        ranges = self.parameters.ranges
        x = np.negative(log_t.reshape(-1))                  # ln(1 / T) per pixel
        top = float(self.water_thickness(-x.max())) if x.size else 0.0
        if top < TAU_MIN:                            # nothing attenuates: no scatter
            return np.zeros((h, w))
        gap, mag = self.geometry(acquisition, bodies, volumes)
        field = max(w * pu, h * pv)
        for name, value, unit in (("thickness_mm", top, "water-equivalent thickness"),
                                  ("field_mm", field, "field side at the detector"),
                                  ("gap_mm", gap, "air gap")):
            lo, hi = ranges[name]
            if value > hi * 1.0001:
                _warn(f"scatter kernel: the {unit} {value:.0f} mm is beyond the fitted "
                      f"{lo:g}-{hi:g} mm")
        # the coarse grid: k x k pixels per cell, at most COARSE cells along a side
        k = max(1, -(-max(h, w) // COARSE))
        ch, cw = -(-h // k), -(-w // k)
        n_cells = ch * cw
        # ln(1 / T) averaged over pre x pre pixels first (at least 2 x 2 of them per cell):
        # the source varies little within half a cell, and the rest costs 1 / pre^2
        pre = next(p for p in (4, 2, 1) if k % p == 0 and k // p >= 2 or p == 1)
        if pre > 1:
            hb, wb = -(-h // pre), -(-w // pre)
            x = np.negative(_pooled(log_t, pre, hb, wb))
            if scat is not None:
                scat = _pooled(scat, pre, hb, wb)
            if coherent is not None:
                coherent = _pooled(coherent, pre, hb, wb)
        else:
            hb, wb = h, w
        kb = k // pre
        # tau, the scatter source T A(tau) and the group by look-up on a fine uniform table
        # of ln(1 / T) (its step, LOOKUP_STEP, moves T by 0.05 % at most)
        tab_tau, tab_q, tab_group = self._lookup()
        i = np.multiply(x, 1.0 / LOOKUP_STEP)
        i += 0.5
        np.clip(i, 0, len(tab_tau) - 1, out=i)
        i = i.astype(np.intp)
        tau, q, group = tab_tau[i], tab_q[i], tab_group[i]
        if scat is not None:
            if scat.ndim > 1:
                scat = scat.reshape(-1)
            # the amplitude at the scatter-equivalent thickness, the transmission as it is
            with np.errstate(divide="ignore"):
                q = np.exp(-x) * self.amplitude(scat)
            q[(scat <= 0) | (tau < TAU_MIN)] = 0.0
        # the coherent share of each pixel's scatter (water's where the materials are not
        # given): single and forward, it has no share in what the edge term takes off
        if coherent is None:
            share = (self._water_coherent(self.cone(acquisition, gap))
                     if coherent_share is None else float(coherent_share))
            q_coh = q * share
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                q_coh = q * np.where(scat > 0, coherent.reshape(-1) / scat, 0.0)
        cell = ((np.arange(hb) // kb)[:, None] * cw + (np.arange(wb) // kb)[None, :]).reshape(-1)
        index = group * n_cells + cell
        n_groups = len(GROUPS)
        sums = np.bincount(index, weights=q, minlength=n_groups * n_cells)
        moments = np.bincount(index, weights=q * tau, minlength=n_groups * n_cells)
        sums_coh = np.bincount(index, weights=q_coh, minlength=n_groups * n_cells)
        sums = sums.reshape(n_groups, ch, cw) / (kb * kb)   # mean source per cell (zeros
        moments = moments.reshape(n_groups, ch, cw) / (kb * kb)  # past the image's edge)
        sums_coh = sums_coh.reshape(n_groups, ch, cw) / (kb * kb)
        # near the edge of a body's shadow the scatter sent sideways leaves the body: the
        # source falls by 1 - b exp(-d / (c tau)) at d mm from the nearest cell outside it
        edge = self._edge_distance(sums.sum(axis=0) > 0, (k * pv, k * pu))
        ny, nx = 2 * ch, 2 * cw                     # zero padded: the field ends at its edge
        total = np.zeros((ny, nx // 2 + 1), complex)
        p = self.parameters.values
        coarse = np.zeros((ny, nx))
        cells = (k * pv, k * pu)
        # each group's air gap: the mean over its source of the cells' exit heights (the
        # global gap where no surface point projects), taken on cells of at most
        # EXIT_CELLS a side
        m = -(-max(ch, cw) // EXIT_CELLS)
        lift = self.exit_heights(acquisition, bodies, (-(-ch // m), -(-cw // m)), k * m,
                                 volumes)
        lift = np.repeat(np.repeat(lift, m, axis=0), m, axis=1)[:ch, :cw]
        lift = np.where(np.isfinite(lift), np.maximum(lift, gap), gap)
        nodes = self._grid_nodes(w, k, pu, cw)
        if self.grid is not None:
            cone = self.cone(acquisition, gap)
            coherent = self._water_coherent(cone)
        sides = []
        for g in range(n_groups):
            weight = float(sums[g].sum())
            if weight <= 0:
                continue
            tau_g = float(moments[g].sum()) / weight
            gap_g = float((sums[g] * lift).sum()) / weight
            mag = 1.0 if f.parallel else float(f.distance) / max(float(f.distance) - gap_g,
                                                                 1e-9)
            source = sums[g]
            # the scatter's spectrum through a grid: hardened by half the body (the photons
            # cross about half of it before they scatter, at the source's energies)
            table = None if self.grid is None else self._grid_table_for(
                cone, coherent, p["grid_hardening"] * tau_g)
            side = None
            if edge is not None:
                # near the edge of the shadow, a share of the incoherent scatter leaves by
                # the body's sides: from its middle, evenly per solid angle
                side = (sums[g] - sums_coh[g]) * (p["b_edge"] * np.exp(
                    -edge / (p["c_edge"] * tau_g + p["l_edge"])))
                source = source - side
            # each component's height, and the height its photons' angles through a grid
            # are taken from (the depth in the body scaled by grid_depth; the same without
            # a grid)
            parts = [(source, tuple(
                (share, _height_step(gap_g + sk * tau_g * mag), n,
                 _height_step(gap_g + self._angle_depth(sk * tau_g * mag)))
                for share, sk, n in ((1.0 - p["fraction"], p["s1"], p["n1"]),
                                     (p["fraction"], p["s2"], p["n2"]))))]
            if side is not None:
                # one side emission for all groups (one transform): from the middle of the
                # bodies, weighted over the groups by what each sends out
                share = float(side.sum())
                sides.append((side, share, gap_g + 0.5 * tau_g * mag, 0.5 * tau_g * mag,
                              tau_g))
            self._convolve(total, coarse, parts, nodes, cells, table)
        if sides:
            weight = sum(x[1] for x in sides)
            if weight > 0:
                mean = [sum(x[1] * x[i] for x in sides) / weight for i in (2, 3, 4)]
                table = None if self.grid is None else self._grid_table_for(
                    cone, coherent, p["grid_hardening"] * mean[2])
                source = sum(x[0] for x in sides)
                self._convolve(total, coarse, [(source, ((
                    1.0, _height_step(mean[0]), 0.0,
                    _height_step(mean[0] - mean[1] + self._angle_depth(mean[1]))),))],
                    nodes, cells, table)
        if self.grid is not None:
            total /= self.grid_primary
        s = np.fft.irfft2(total, s=(ny, nx))[:ch, :cw]
        np.maximum(s, 0.0, out=s)                   # FFT round-off below zero
        if k == 1:
            return self._per_flat(np.ascontiguousarray(s), acquisition)
        # bilinear interpolation from the cells' centres to the pixels', axis by axis
        lo, t = _linear(h, k, ch)
        rows = s[lo] * (1.0 - t)[:, None]
        rows += s[np.minimum(lo + 1, ch - 1)] * t[:, None]
        lo, t = _linear(w, k, cw)
        out = rows[:, lo] * (1.0 - t)
        out += rows[:, np.minimum(lo + 1, cw - 1)] * t
        return self._per_flat(np.maximum(out, 0.0, out=out), acquisition)

    def _convolve(self, total, coarse, parts, nodes, cells, table):
        """``total += rfft2(source) * spread`` for each ``(source, components)`` of ``parts``
        (:meth:`_spread`), with a grid once per position along ``u`` (:meth:`_grid_nodes`),
        the source shared between them."""
        ch, cw = parts[0][0].shape
        for src, components in parts:
            for across, share in nodes:
                coarse[:ch, :cw] = src if share is None else src * share
                total += np.fft.rfft2(coarse) * self._spread(components, coarse.shape, cells,
                                                             across, table)

    def _per_flat(self, s, acquisition):
        """``s`` (relative to the focused flat field) relative to each pixel's flat field:
        with a grid, over its off-focus cut-off (:meth:`~xray_viz.physics.grid.Grid.
        off_focus`, as :meth:`~xray_viz.physics.beam.Beam.at` puts it in the flat field)."""
        if self.grid is None:
            return s
        s /= self.grid.off_focus(acquisition, *self.grid_spectrum[:2])
        return s


def _compton_shifted(energies, weights, cone, coherent, *, angles=32, bins=48):
    """``(energies, weights)``: a spectrum scattered once within ``cone`` (radians), a share
    ``coherent`` of it at its own energies, the rest over the angles with the Klein-Nishina
    cross section's weights (times ``sin theta``) at the Compton-shifted energies;
    rebinned onto ``bins`` energies."""
    e = np.asarray(energies, dtype=np.float64)[:, None]
    theta = (np.arange(angles) + 0.5) * (cone / angles)
    ratio = 1.0 / (1.0 + e / 511.0 * (1.0 - np.cos(theta))[None, :])       # E' / E
    kn = ratio ** 2 * (ratio + 1.0 / ratio - np.sin(theta) ** 2) * np.sin(theta)
    w0 = np.asarray(weights, dtype=np.float64)
    w = (1.0 - coherent) * w0[:, None] * kn / kn.sum(axis=1, keepdims=True)
    shifted = np.concatenate([(e * ratio).reshape(-1), e[:, 0]])
    wall = np.concatenate([w.reshape(-1), coherent * w0])
    edges = np.linspace(shifted.min(), shifted.max() + 1e-9, bins + 1)
    where = np.digitize(shifted, edges) - 1
    total = np.bincount(where, weights=wall, minlength=bins)
    mean = np.bincount(where, weights=wall * shifted, minlength=bins)
    keep = total > 0
    return mean[keep] / total[keep], total[keep]


def _height_step(height):
    """A kernel's height (mm) in multiples of :data:`HEIGHT_STEP` (:meth:`KernelModel._spread`'s
    key: the views of a scan share their kernels)."""
    return int(round(height / HEIGHT_STEP))


def _pooled(a, pre, hb, wb):
    """``(hb * wb,)``: the means of ``a`` over ``pre x pre`` pixels (edges repeated)."""
    h, w = a.shape
    pad = a if (h % pre, w % pre) == (0, 0) else np.pad(
        a, ((0, hb * pre - h), (0, wb * pre - w)), mode="edge")
    acc = np.zeros((hb, wb))
    for i in range(pre):                          # strided views: no reshaped copy
        for j in range(pre):
            acc += pad[i::pre, j::pre]
    acc *= 1.0 / (pre * pre)
    return acc.reshape(-1)


def _volume_points(volume, spacing):
    """(n, 3) float: the centres of a voxel volume's non-empty voxels (scene mm), every
    ``s``-th along each axis, ``s`` the most voxels within ``spacing`` mm (at least 1)."""
    a = np.asarray(volume.affine, dtype=np.float64)
    size = np.linalg.norm(a[:3, :3], axis=0)                   # mm per voxel along i, j, k
    stride = tuple(max(1, int(spacing // s)) for s in size)
    sub = np.asarray(volume.classes)[::stride[0], ::stride[1], ::stride[2]]
    idx = np.argwhere(sub > 0) * np.asarray(stride)
    return idx @ a[:3, :3].T + a[:3, 3]


def _surface_points(meshes, spacing):
    """(n, 3) float: the meshes' vertices and, on each triangle with an edge longer than
    ``spacing`` mm, points at most ``spacing`` apart (rows from the vertex opposite its
    shortest edge, the apex, to that edge, so that a sliver gets few); one of them per cube
    of ``spacing / 2`` mm."""
    verts = [np.asarray(m.vertices, float) for m in meshes]
    out = [np.vstack(verts)]
    tris = np.concatenate([v[np.asarray(m.faces)] for v, m in zip(verts, meshes)])
    # edge i is opposite vertex i
    edges = np.stack([np.linalg.norm(tris[:, (i + 2) % 3] - tris[:, (i + 1) % 3], axis=1)
                      for i in range(3)], axis=1)
    big = edges.max(axis=1) > spacing
    if big.any():
        tris, edges = tris[big], edges[big]
        apex = edges.argmin(axis=1)
        t = np.arange(len(tris))
        a, b, c = (tris[t, (apex + i) % 3] for i in range(3))
        n_s = np.minimum(np.ceil(np.maximum(np.linalg.norm(b - a, axis=1),
                                            np.linalg.norm(c - a, axis=1)) / spacing), 512)
        n_r = np.minimum(np.maximum(np.ceil(edges[t, apex] / spacing), 1), 512)
        for ns, nr in np.unique(np.stack([n_s, n_r], axis=1), axis=0):
            sel = (n_s == ns) & (n_r == nr)
            s_ = np.arange(1, int(ns) + 1) / ns
            r_ = np.arange(int(nr) + 1) / nr
            s_, r_ = (x.reshape(-1) for x in np.meshgrid(s_, r_, indexing="ij"))
            w = np.stack([1.0 - s_, s_ * (1.0 - r_), s_ * r_], axis=1)     # (q, 3)
            corners = np.stack([a[sel], b[sel], c[sel]], axis=1)           # (t, 3, 3)
            out.append(np.einsum("qk,tkd->tqd", w, corners).reshape(-1, 3))
    # one point per cube of half the spacing: a fine mesh's vertices thinned (each cell's
    # lowest point then within half the spacing of the surface's)
    pts = np.vstack(out)
    _, first = np.unique(np.floor(pts * (2.0 / spacing)).astype(np.int64), axis=0,
                         return_index=True)
    return pts[np.sort(first)]


def _linear(n, k, m):
    """``(lo, t)``: pixel ``i`` of ``n`` is ``(1 - t) cell[lo] + t cell[lo + 1]`` of ``m``
    cells of ``k`` pixels (values at the cells' centres, held at the ends)."""
    pos = np.clip((np.arange(n) + 0.5) / k - 0.5, 0.0, m - 1.0)
    lo = np.minimum(np.floor(pos).astype(np.intp), max(m - 2, 0))
    return lo, pos - lo
