"""The detector: scintillator absorption and blur (MTF); the order of its noise and gain.

A scene's ``[detector]`` table may describe a real detector instead of the ideal counter::

    scintillator = { material = "CsI", thickness = 0.6, fill = 0.8 }   # mm; fill defaults to 1
    mtf = { sigma = 0.1 }            # mm: Gaussian blur in the detector plane (or fwhm = ...),
                                     # or a measured MTF / LSF table (see below)
    electronic_noise = 5.0           # photon-equivalents rms, added with noise = true
    gain = 1.0                       # detected units per photon-equivalent

Scintillator
    The fraction of the photons of energy ``E`` that interact in a converter of thickness ``t``,
    the absorption efficiency ``eta(E) = fill * (1 - exp(-mu(E) t))``
    (:func:`absorption_efficiency`), with ``mu`` from the same data as the bodies
    (:mod:`xray_viz.physics.materials`: xraylib, total attenuation with coherent scattering) and
    ``fill`` the packing / fill factor. ``material`` is any material the bodies accept; ``CsI``
    and ``Gd2O2S`` have default densities (:data:`SCINTILLATOR_DENSITIES`, g/cm^3), other
    formulas need ``density``. An energy-integrating detector's signal is then
    ``sum_k phi_k eta_k E_k T_k``, a counting detector's ``sum_k phi_k eta_k T_k``: the
    detector's own beam hardening. Each interacting photon is assumed to deposit its whole energy
    (no K-fluorescence or Compton escape).
MTF
    ``{ sigma = s }`` or ``{ fwhm = f }`` (mm): a Gaussian line spread function, MTF
    ``exp(-2 pi^2 s^2 f^2)``. ``{ file = "mtf.csv" }``: a table of frequency (cycles/mm) and
    MTF, the first row at 0 cycles/mm, reaching the detector's Nyquist frequency ``1 / (2 pitch)``.
    ``{ lsf = "lsf.csv" }``: a table of position (mm) and line spread function, sampled finer
    than the pitch; its MTF is its Fourier transform. A measured table is a *presampled* MTF,
    which includes the pixel aperture; ``presampled = true`` (the default for tables) divides
    the aperture's ``sinc(f * pitch)`` out again, since the rendering adds its own aperture
    (the pixel's supersampled rays). Paths are relative to the scene file; the tables are CSV
    files like spectra (two columns, ``#`` comments, one header line allowed).
    The blur acts on the image in the detector plane, after the focal-spot blur and after the
    quantum noise (light spread in the converter correlates the noise), as the discrete kernel
    of :func:`mtf_kernel`: non-negative, summing to 1, separable (the 1-D MTF along each axis),
    whose frequency response matches the MTF up to the Nyquist frequency as closely as a
    non-negative kernel on the pixel grid can (a linear programme, minimax). For a Gaussian of
    ``sigma >= 0.7`` pixel that is within 0.011 of the MTF (0.0013 at 1 pixel); a blur of
    0.3-0.6 pixel cannot be carried by the pixel grid better than ~0.06 (0.03 at 0.2 pixel;
    the kernel's own error is returned by :func:`mtf_kernel`).
Noise and gain
    The order of operations of :func:`~xray_viz.physics.imaging.detect_log`: mean signal
    (photon-equivalents) -> focal-spot blur -> quantum noise (compound Poisson, exact mean and
    variance per pixel) -> detector blur (MTF) -> electronic noise (Gaussian,
    ``electronic_noise`` photon-equivalents rms, independent per pixel) -> ``gain``.

Examples
--------
>>> s = scintillator_from_dict({"material": "CsI", "thickness": 0.6})
>>> s["density"], s["fill"]
(4.51, 1.0)
>>> round(float(absorption_efficiency(s, [30.0])[0]), 4)        # 0.6 mm CsI at 30 keV
0.9135
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path

import numpy as np

from xray_viz.errors import SceneError, SceneFileNotFoundError

__all__ = ["SCINTILLATOR_KEYS", "SCINTILLATOR_DENSITIES", "MTF_KEYS", "scintillator_from_dict",
           "absorption_efficiency", "mtf_from_dict", "detector_mtf", "mtf_kernel",
           "read_table_csv", "check_mtf_reaches_nyquist"]

#: Keys of a ``scintillator`` table.
SCINTILLATOR_KEYS = {
    "material": "converter material (any body material; CsI and Gd2O2S have default densities)",
    "thickness": "converter thickness in mm",
    "fill": "fill (packing) factor, 0 < fill <= 1 (default 1)",
    "density": "g/cm^3 (default: SCINTILLATOR_DENSITIES, or the NIST compound's own)",
}

#: Default densities (g/cm^3) of the common converters: caesium iodide and gadolinium
#: oxysulfide (Gadox), their bulk crystal densities.
SCINTILLATOR_DENSITIES = {"CsI": 4.51, "Gd2O2S": 7.32}

#: Keys of an ``mtf`` table.
MTF_KEYS = {
    "sigma": "mm, standard deviation of a Gaussian line spread function",
    "fwhm": "mm, full width at half maximum of a Gaussian line spread function",
    "file": "CSV table of frequency (cycles/mm) and MTF, relative to the scene file",
    "lsf": "CSV table of position (mm) and line spread function, relative to the scene file",
    "presampled": "the table includes the pixel aperture (default true for tables)",
}

_FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


def _fail(msg: str):
    raise SceneError(msg)


def _positive(spec, key, *, what, unit, default=None, maximum=None):
    value = spec.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value <= 0 or (maximum is not None and value > maximum):
        rng = f"> 0 and <= {maximum:g}" if maximum is not None else "> 0"
        _fail(f"{what} {key} must be a number {rng}{unit}, got {value!r}")
    return float(value)


def _unknown_keys(spec, known, what):
    unknown = sorted(set(spec) - set(known))
    if unknown:
        import difflib

        hints = []
        for key in unknown:
            close = difflib.get_close_matches(str(key), list(known), n=1)
            hints.append(f"'{key}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
        _fail(f"{what} has unknown key{'s' if len(unknown) > 1 else ''} {', '.join(hints)}; "
              f"known keys: {', '.join(known)}")


# --------------------------------------------------------------------------------------------
# scintillator


def scintillator_from_dict(spec) -> dict:
    """Validate a ``scintillator`` table and return its canonical form.

    Returns
    -------
    dict
        ``{"material", "thickness" (mm), "fill", "density" (g/cm^3)}``.

    Raises
    ------
    SceneError
        Unknown keys, a missing material or thickness, a thickness <= 0, a fill outside
        (0, 1], an unknown material or a formula without a density.

    Examples
    --------
    >>> scintillator_from_dict({"material": "Gd2O2S", "thickness": 0.2, "fill": 0.5})["density"]
    7.32
    >>> scintillator_from_dict({"material": "CsI", "thickness": 0})
    Traceback (most recent call last):
    ...
    xray_viz.errors.SceneError: scintillator thickness must be a number > 0 mm, got 0
    """
    if not isinstance(spec, Mapping):
        _fail(f"scintillator must be a table such as {{ material = \"CsI\", thickness = 0.6 }}, "
              f"got {spec!r}")
    _unknown_keys(spec, SCINTILLATOR_KEYS, "scintillator")
    if "material" not in spec:
        _fail("scintillator needs 'material' (e.g. \"CsI\" or \"Gd2O2S\")")
    if "thickness" not in spec:
        _fail("scintillator needs 'thickness' (mm, e.g. 0.6 for CsI)")
    material = spec["material"]
    if not isinstance(material, (str, Mapping)):
        _fail(f"scintillator material must be a name or formula string, got {material!r}")
    thickness = _positive(spec, "thickness", what="scintillator", unit=" mm")
    fill = _positive(spec, "fill", what="scintillator", unit="", default=1.0, maximum=1.0)
    density = spec.get("density")
    if density is not None:
        density = _positive(spec, "density", what="scintillator", unit=" g/cm3")
    elif isinstance(material, str) and material in SCINTILLATOR_DENSITIES:
        density = SCINTILLATOR_DENSITIES[material]
    from xray_viz.errors import MaterialError
    from xray_viz.physics.materials import check_material, material_key

    try:
        density = check_material(material, density=density)
    except MaterialError as exc:
        _fail(f"scintillator: {exc}")
    if not isinstance(material, str):
        material = dict(material_key(material))
    return {"material": material, "thickness": thickness, "fill": fill, "density": density}


def absorption_efficiency(scintillator, energies_kev) -> np.ndarray:
    """Fraction of the photons of each energy absorbed: ``fill * (1 - exp(-mu(E) t))``.

    Parameters
    ----------
    scintillator : dict or None
        A canonical table from :func:`scintillator_from_dict`; None is the ideal detector
        (efficiency 1 at every energy).
    energies_kev : (n,) float

    Returns
    -------
    (n,) float
        In (0, fill].

    Examples
    --------
    >>> absorption_efficiency(None, [20.0, 60.0]).tolist()
    [1.0, 1.0]
    """
    e = np.atleast_1d(np.asarray(energies_kev, dtype=np.float64))
    if scintillator is None:
        return np.ones_like(e)
    from xray_viz.physics.materials import linear_attenuation

    mu = linear_attenuation(scintillator["material"], e, density=scintillator["density"])
    return scintillator["fill"] * -np.expm1(-mu * scintillator["thickness"] / 10.0)


# --------------------------------------------------------------------------------------------
# tables


@lru_cache(maxsize=64)
def _read_table_cached(path: str, mtime_ns: int, size: int) -> np.ndarray:
    from xray_viz.physics.spectra import read_columns

    data = read_columns(path, error=SceneError, name="table",
                        columns="two numeric columns")
    if len(data) < 2:
        _fail(f"{path}: needs at least two rows of two numbers")
    if not np.all(np.isfinite(data)):
        _fail(f"{path}: values must be finite")
    if np.any(np.diff(data[:, 0]) <= 0):
        _fail(f"{path}: the first column must be strictly increasing")
    data.setflags(write=False)
    return data


def read_table_csv(path) -> np.ndarray:
    """Read a two-column numeric CSV table (cached until the file changes).

    Same format as a spectrum file: comma, semicolon or blank separated, ``#`` comments, one
    header line allowed before the data; the first column strictly increasing.

    Returns
    -------
    (n, 2) float
        Read-only.

    Raises
    ------
    SceneFileNotFoundError
        The file does not exist.
    SceneError
        Anything else wrong with it, naming the file and line.
    """
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise SceneFileNotFoundError(f"{path}: file not found") from None
    except OSError as exc:
        _fail(f"{path}: cannot read: {exc.strerror}")
    if path.is_dir():
        _fail(f"{path}: is a directory, not a CSV table")
    return _read_table_cached(str(path.resolve()), st.st_mtime_ns, st.st_size)


# --------------------------------------------------------------------------------------------
# MTF


def mtf_from_dict(spec, *, base_dir=None) -> dict:
    """Validate an ``mtf`` table and return its canonical form.

    Returns
    -------
    dict
        ``{"sigma": mm}`` for a Gaussian (``fwhm`` converted), or ``{"file": absolute path,
        "kind": "mtf" or "lsf", "presampled": bool}`` for a table (read and checked).

    Raises
    ------
    SceneError, SceneFileNotFoundError

    Examples
    --------
    >>> round(mtf_from_dict({"fwhm": 0.2355})["sigma"], 4)
    0.1
    """
    if not isinstance(spec, Mapping):
        _fail(f"mtf must be a table such as {{ sigma = 0.1 }} (mm) or {{ file = \"mtf.csv\" }}, "
              f"got {spec!r}")
    if set(spec) == {"file", "kind", "presampled"} and spec["kind"] in ("mtf", "lsf"):
        # the canonical form of a table (this function's result): check it again
        spec = {("file" if spec["kind"] == "mtf" else "lsf"): spec["file"],
                "presampled": spec["presampled"]}
    _unknown_keys(spec, MTF_KEYS, "mtf")
    given = [k for k in ("sigma", "fwhm", "file", "lsf") if k in spec]
    if len(given) != 1:
        _fail("mtf needs exactly one of 'sigma' or 'fwhm' (mm, Gaussian), 'file' (MTF table) or "
              f"'lsf' (LSF table); got {', '.join(map(repr, given)) or 'none'}")
    key = given[0]
    if key in ("sigma", "fwhm"):
        if "presampled" in spec:
            _fail("mtf presampled goes with a 'file' or 'lsf' table, not a Gaussian")
        value = _positive(spec, key, what="mtf", unit=" mm")
        return {"sigma": value if key == "sigma" else value / _FWHM_PER_SIGMA}
    presampled = spec.get("presampled", True)
    if not isinstance(presampled, bool):
        _fail(f"mtf presampled must be true or false, got {presampled!r}")
    name = spec[key]
    if not isinstance(name, (str, os.PathLike)):
        _fail(f"mtf {key} must be a path string, got {name!r}")
    path = Path(name)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    kind = "mtf" if key == "file" else "lsf"
    data = read_table_csv(path)
    if kind == "mtf":
        if data[0, 0] != 0:
            _fail(f"{path}: the MTF table must start at 0 cycles/mm (got {data[0, 0]:g}); "
                  "MTF(0) normalises it")
        if data[0, 1] <= 0 or np.any(data[:, 1] < 0):
            _fail(f"{path}: MTF values must be >= 0 and MTF(0) > 0")
    else:
        area = np.trapezoid(data[:, 1], data[:, 0])
        if not area > 0:
            _fail(f"{path}: the line spread function must have a positive area, got {area:g}")
    return {"file": str(path.resolve()), "kind": kind, "presampled": presampled}


def _lsf_mtf(data: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``|integral LSF(x) exp(-2 pi i f x) dx| / integral LSF dx`` by the trapezoid rule."""
    x, y = data[:, 0], data[:, 1]
    phase = 2 * np.pi * f[:, None] * x[None, :]
    re = np.trapezoid(y[None, :] * np.cos(phase), x, axis=1)
    im = np.trapezoid(y[None, :] * np.sin(phase), x, axis=1)
    return np.hypot(re, im) / np.trapezoid(y, x)


def detector_mtf(mtf, frequencies, *, pitch=None) -> np.ndarray:
    """The detector blur's MTF (without the pixel aperture) at frequencies in cycles/mm.

    Parameters
    ----------
    mtf : dict
        Canonical table of :func:`mtf_from_dict`.
    frequencies : (n,) float
        Cycles/mm, >= 0.
    pitch : float, optional
        mm. For a ``presampled`` table, the aperture ``|sinc(f * pitch)|`` is divided out.

    Returns
    -------
    (n,) float

    Examples
    --------
    >>> round(float(detector_mtf({"sigma": 0.1}, [1.0])[0]), 6)      # exp(-2 pi^2 0.01)
    0.820869
    """
    f = np.abs(np.atleast_1d(np.asarray(frequencies, dtype=np.float64)))
    if "sigma" in mtf:
        return np.exp(-2.0 * np.pi ** 2 * mtf["sigma"] ** 2 * f ** 2)
    data = read_table_csv(mtf["file"])
    if mtf["kind"] == "mtf":
        out = np.interp(f, data[:, 0], data[:, 1]) / data[0, 1]
    else:
        out = _lsf_mtf(data, f)
    if mtf.get("presampled") and pitch is not None:
        out = out / np.abs(np.sinc(f * pitch))
    return out


def check_mtf_reaches_nyquist(mtf, pitch) -> None:
    """Refuse a table that does not describe the MTF up to the Nyquist frequency.

    An MTF table must reach ``1 / (2 pitch)`` cycles/mm; an LSF table must be sampled finer
    than the pitch (so that its own Nyquist frequency is higher).

    Raises
    ------
    SceneError
    """
    if mtf is None or "sigma" in mtf:
        return
    data = read_table_csv(mtf["file"])
    p = min(pitch)
    nyquist = 0.5 / p
    if mtf["kind"] == "mtf" and data[-1, 0] < nyquist * (1 - 1e-9):
        _fail(f"{mtf['file']}: the MTF table ends at {data[-1, 0]:g} cycles/mm, below the "
              f"detector's Nyquist frequency {nyquist:g} cycles/mm (pitch {p:g} mm): extend it")
    if mtf["kind"] == "lsf":
        dx = float(np.max(np.diff(data[:, 0])))
        if dx >= p:
            _fail(f"{mtf['file']}: the LSF is sampled every {dx:g} mm, not finer than the "
                  f"detector pitch {p:g} mm: give a finer (oversampled) LSF")


def _mtf_key(mtf):
    if "sigma" in mtf:
        return ("sigma", float(mtf["sigma"]))
    st = os.stat(mtf["file"])
    return ("table", mtf["file"], mtf["kind"], bool(mtf.get("presampled")), st.st_mtime_ns,
            st.st_size)


def mtf_kernel(mtf, pitch: float) -> tuple[np.ndarray, float]:
    """The detector blur as a discrete kernel along one axis of the pixel grid.

    The non-negative symmetric kernel ``k`` (summing to 1) whose frequency response
    ``K(nu) = k_0 + 2 sum_m k_m cos(2 pi m nu)`` (``nu`` in cycles per pixel) is closest to
    the MTF on ``[0, 1/2]`` in the maximum norm (a linear programme, scipy's HiGHS). A
    non-negative kernel keeps intensities non-negative and can be applied in the log domain.
    Cached per MTF and pitch.

    Parameters
    ----------
    mtf : dict
        Canonical table of :func:`mtf_from_dict`.
    pitch : float
        mm between pixel centres along the axis.

    Returns
    -------
    kernel : (2 R + 1,) float
    max_error : float
        ``max |K(nu) - MTF(nu / pitch)|`` up to the Nyquist frequency.

    Examples
    --------
    >>> k, err = mtf_kernel({"sigma": 0.1}, 0.1)                    # 1 pixel
    >>> round(float(k.sum()), 12), bool(np.all(k >= 0)), err < 0.002
    (1.0, True, True)
    """
    return _mtf_kernel_cached(_mtf_key(mtf), float(pitch))


@lru_cache(maxsize=64)
def _mtf_kernel_cached(key, pitch: float):
    if key[0] == "sigma":
        mtf = {"sigma": key[1]}
    else:
        mtf = {"file": key[1], "kind": key[2], "presampled": key[3]}
    # support: 4 sigma of the Gaussian with the same half-value frequency, plus 3 pixels
    fine = np.linspace(0.0, 0.5 / pitch, 513)
    below = np.flatnonzero(detector_mtf(mtf, fine, pitch=pitch) <= 0.5)
    sigma_px = 0.5
    if below.size and fine[below[0]] > 0:
        sigma_px = math.sqrt(math.log(2.0) / (2 * math.pi ** 2)) / fine[below[0]] / pitch
    radius = int(min(128, math.ceil(4 * sigma_px) + 3))
    nu = np.linspace(0.0, 0.5, max(257, 8 * (radius + 1)))
    target = detector_mtf(mtf, nu / pitch, pitch=pitch)
    m = np.arange(radius + 1)
    mult = np.where(m == 0, 1.0, 2.0)
    basis = mult[None, :] * np.cos(2 * np.pi * nu[:, None] * m[None, :])
    n = radius + 1
    from scipy.optimize import linprog

    ones = np.ones((len(nu), 1))
    res = linprog(np.r_[np.zeros(n), 1.0],
                  A_ub=np.block([[basis, -ones], [-basis, -ones]]),
                  b_ub=np.r_[target, -target],
                  A_eq=np.r_[mult, 0.0][None, :], b_eq=[1.0],
                  bounds=[(0, None)] * (n + 1), method="highs")
    if not res.success:  # pragma: no cover - always feasible (the identity kernel)
        raise RuntimeError(f"mtf_kernel: linear programme failed: {res.message}")
    half = np.maximum(res.x[:n], 0.0)
    half[half < 1e-13] = 0.0
    half = half[:int(np.flatnonzero(half)[-1]) + 1]
    half /= half[0] + 2 * half[1:].sum()
    err = float(np.max(np.abs(basis[:, :len(half)] @ half - target)))
    kernel = np.r_[half[:0:-1], half]
    kernel.setflags(write=False)
    return kernel, err
