"""Reconstruction of a projection stack (issue 14): FDK (circular cone beam) and FBP (parallel
beam) through RTK (``itk-rtk``, the ``ct`` extra), on the CPU; RTK's iterative SART and
conjugate gradient (few-view scans; also helical orbits, which RTK's circular geometry holds as
per-view source and detector offsets along the axis); mbirjax's MBIR (``method="mbirjax"``,
the ``ct-mbir`` extra: JAX on the CPU, circular and helical cone beam, see
:func:`mbirjax_geometry`). ASTRA (no 3D CPU path: a 3D call without CUDA kills the process)
and TIGRE (CUDA only) are refused in one line without being imported.

The stack and its geometry are those of :func:`xray_viz.scan` (the layout of CT-LAYOUT.md):
``projections`` ``(n, H, W)`` line integrals (``-ln(I/I0)``, dimensionless), row 0 at the top of
the detector (the +v side), column 0 at its left (the -u side seen from the source); a
``geometry`` dict with, per projection, the source, the detector centre and the detector's unit
``u`` (columns, left to right) and ``v`` (bottom to top) vectors in mm.

How xray_viz's geometry maps onto RTK's (IEC 61217; the gantry turns about RTK's y axis through
the isocentre at RTK's origin; a projection image's index ``(i, j)`` lies at
``detector origin + i pu u + j pv v``):

* an RTK frame: y along the rotation ``axis``, origin at ``center`` (:func:`rtk_frame`); a
  world point ``p`` is at ``R (p - center)`` there;
* each pose (source, detector centre, ``u``, ``v``) is given to RTK in that frame
  (``AddProjection(source, detector, row vector u, column vector v)``: RTK finds the gantry,
  out-of-plane and in-plane angles and the offsets itself), the detector's origin at its centre
  and the projection image's origin at ``(-(W-1)/2 pu, -(H-1)/2 pv)``;
* **one row flip**: RTK's row index ``j`` runs along ``v`` (bottom to top), xray_viz's rows top
  down, so RTK's projection ``k`` is ``projections[k, ::-1, :]``;
* a parallel beam: the same decomposition with the source at its start point, then the
  projection re-added with ``SourceToDetectorDistance = 0`` (RTK's parallel geometry);
* the volume: a grid along the world axes (x, y, z), given to RTK with direction ``R`` and
  origin ``R (origin - center)``, so the array comes back as ``(z, y, x)`` of the world;
* units: RTK returns 1/mm (line integrals over mm); xray_viz's mu is in 1/cm (x 10).

RTK's own files, for RTK's command-line tools: :func:`write_rtk_geometry` (RTK's
``ThreeDCircularProjectionGeometry`` XML, RTK's writer) and :func:`write_rtk_projections` (the
stack as one ``.mha`` in RTK's image convention);
``xray-viz reconstruct scan.zarr --rtk-geometry geometry.xml --rtk-projections proj.mha``
writes both (``-o`` is then optional), and ``rtkfdk -g geometry.xml -p . -r proj.mha -o
volume.mha`` reconstructs the scan in RTK's frame (``--like`` an image on our grid gives our
volume, ``tests/reconstruct/test_reconstruct_rtk_files.py``).

``tests/reconstruct/test_reconstruct.py`` proves the mapping against RTK's own analytic projections of an
off-centre ellipsoid (``RayEllipsoidIntersectionImageFilter``) and the render of the same
ellipsoid's mesh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xray_viz.errors import OutputError, XrayVizError

__all__ = ["Volume", "reconstruct", "ITERATIVE", "reconstruct_file", "rtk_geometry", "rtk_frame",
           "rtk_matrices", "write_rtk_geometry", "read_rtk_geometry", "write_rtk_projections",
           "read_line_integrals",
           "write_volume", "add_reconstruct_parser", "reconstruct_command", "METHODS"]

#: Reconstruction methods: name -> (beam it needs, what it is).
METHODS = {
    "fdk": ("cone", "Feldkamp-Davis-Kress filtered back-projection (RTK), circular cone beam"),
    "fbp": ("parallel", "filtered back-projection (RTK's FDK with a parallel geometry)"),
}

#: Iterative methods (RTK, CPU, any beam and orbit RTK's geometry holds): name ->
#: (default iterations, what it is).
ITERATIVE = {
    "sart": (10, "SART (RTK's SARTConeBeamReconstructionFilter): one projection per update, "
                 "relaxation 0.3, mu >= 0 enforced"),
    "cg": (20, "conjugate gradient on the unweighted least-squares problem (RTK's "
               "ConjugateGradientConeBeamReconstructionFilter)"),
}
METHODS.update({k: ("any", v[1]) for k, v in ITERATIVE.items()})
METHODS["mbirjax"] = ("cone", "MBIR (mbirjax, JAX on the CPU; the ct-mbir extra): circular or "
                              "helical cone beam, untilted flat detector")

#: Other back-ends users ask for, and why they are refused here (one line each).
REFUSED_BACKENDS = {
    "astra": "ASTRA's PyPI/conda builds have no 3D CPU path (a 3D call without CUDA kills the "
             "process); use method='fdk' (RTK, CPU), or ASTRA itself on a CUDA machine",
    "tigre": "TIGRE needs CUDA (pip install git+https://github.com/CERN/TIGRE on a machine with "
             "an NVIDIA GPU and the CUDA toolkit); use method='fdk' (RTK, CPU)",
}


class ReconstructionError(XrayVizError, ValueError):
    """A projection stack or its geometry that cannot be reconstructed as asked."""


@dataclass(frozen=True)
class Volume:
    """A reconstructed volume: ``mu[z, y, x]`` (1/cm, float32) on a grid along the world axes.

    Attributes
    ----------
    mu : (nz, ny, nx) float32
        Linear attenuation coefficient, 1/cm.
    origin : (3,) float
        World position (mm, x y z) of voxel ``[0, 0, 0]``'s centre.
    spacing : (3,) float
        Voxel size (mm) along x, y, z.
    direction : (3, 3) float
        Columns: the world directions of the x, y, z index axes (the identity: the grid is
        along the world axes).
    method : str
    """

    mu: np.ndarray
    origin: np.ndarray
    spacing: np.ndarray
    direction: np.ndarray
    method: str

    @property
    def affine(self) -> np.ndarray:
        """(4, 4): world mm (x, y, z) of voxel index ``(i, j, k)`` = ``mu[k, j, i]``."""
        a = np.eye(4)
        a[:3, :3] = self.direction * self.spacing[None, :]
        a[:3, 3] = self.origin
        return a

    def centers(self, axis: int) -> np.ndarray:
        """World coordinate (mm) of the voxel centres along world axis 0 (x), 1 (y) or 2 (z)."""
        n = self.mu.shape[2 - axis]
        return self.origin[axis] + self.spacing[axis] * np.arange(n)


def _rtk():
    """``(itk, itk.RTK)``; ITK's SWIG modules' load-time DeprecationWarning (Python's, about
    SWIG's ``swigvarlink``) is silenced: turned into an error inside SWIG's initialisation it
    crashes the interpreter."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            import itk
            from itk import RTK as rtk
            for name in ("ThreeDCircularProjectionGeometry", "ConstantImageSource",
                         "FDKConeBeamReconstructionFilter", "ParkerShortScanImageFilter",
                         "DisplacedDetectorForOffsetFieldOfViewImageFilter"):
                getattr(rtk, name)                     # load the lazy modules here
            itk.image_from_array, itk.Matrix, itk.imwrite, itk.imread
            itk.PyCommand, itk.ProgressEvent, itk.IterationEvent     # progress observers
    except ImportError as exc:      # pragma: no cover - the ct extra is installed in tests
        raise ReconstructionError(
            f"reconstruction needs RTK (itk-rtk), which is not installed ({exc}); "
            "pip install 'xray_viz[ct]'") from None
    return itk, rtk


def _unit(v, what):
    from xray_viz._checks import vector3

    return vector3(v, f"geometry {what}", unit=True, error=ReconstructionError)


def rtk_frame(geometry) -> tuple[np.ndarray, np.ndarray]:
    """``(R, center)``: the RTK frame of a scan's geometry; a world point ``p`` is at
    ``R @ (p - center)`` in RTK's fixed coordinates.

    RTK's y is the rotation ``axis``; its z is the world axis least aligned with the rotation
    axis (x before y before z on ties), made perpendicular to it; x completes a right-handed
    frame. For an axis along a world axis, ``R`` is a signed permutation.

    Examples
    --------
    >>> R, c = rtk_frame({"axis": [0, 0, 1], "center": [0, 0, 0]})
    >>> (R + 0.0).tolist()            # RTK (x, y, z) = world (y, z, x)
    [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]
    """
    ey = _unit(geometry.get("axis", (0.0, 0.0, 1.0)), "axis")
    from xray_viz._checks import vector3
    from xray_viz.poses import rtk_axes

    center = vector3(geometry.get("center", (0.0, 0.0, 0.0)), "geometry center", units=" (mm)",
                     error=ReconstructionError)
    return rtk_axes(ey), center


def _poses(geometry):
    poses = geometry.get("poses")
    if not poses:
        raise ReconstructionError("geometry has no 'poses' (source, detector_center, u, v per "
                                  "projection); write the scan with xray_viz.scan")
    out = []
    for k, p in enumerate(poses):
        try:
            out.append({key: np.asarray(p[key], np.float64).reshape(3)
                        for key in ("source", "detector_center", "u", "v")})
        except (KeyError, ValueError, TypeError) as exc:
            raise ReconstructionError(f"geometry poses[{k}] is not 4 points/vectors of 3 numbers "
                                      f"(source, detector_center, u, v): {exc}") from None
    return out


def _detector(geometry):
    try:
        det = geometry["detector"]
        w, h = (int(v) for v in det["shape"])
        pu, pv = (float(v) for v in det["pitch_mm"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ReconstructionError("geometry 'detector' needs shape [W, H] and pitch_mm [pu, pv] "
                                  f"({exc})") from None
    return (w, h), (pu, pv)


def rtk_geometry(geometry):
    """RTK's ``ThreeDCircularProjectionGeometry`` of a scan (in the frame :func:`rtk_frame`).

    Returns
    -------
    rtk.ThreeDCircularProjectionGeometry
        One projection per pose; the detector's origin at its centre (the projection images'
        origin is ``(-(W-1)/2 pu, -(H-1)/2 pv)``). A parallel beam has
        ``SourceToDetectorDistance = 0``.
    """
    _, rtk = _rtk()
    R, center = rtk_frame(geometry)
    parallel = geometry.get("beam", "cone") == "parallel"
    cone = rtk.ThreeDCircularProjectionGeometry.New()
    from xray_viz.poses import rtk_rows

    rows = rtk_rows(_poses(geometry), R, center, parallel=parallel, error=ReconstructionError)
    for k, (s, d, u, v) in enumerate(rows):
        ok = cone.AddProjection([float(x) for x in s], [float(x) for x in d],
                                [float(x) for x in u], [float(x) for x in v])
        if not ok:
            raise ReconstructionError(f"geometry poses[{k}]: RTK cannot describe this source and "
                                      "detector as a circular-orbit projection")
    if not parallel:
        return cone
    out = rtk.ThreeDCircularProjectionGeometry.New()
    deg = 180.0 / math.pi
    sid = cone.GetSourceToIsocenterDistances()
    for k in range(len(sid)):
        out.AddProjection(float(sid[k]), 0.0, cone.GetGantryAngles()[k] * deg,
                          cone.GetProjectionOffsetsX()[k], cone.GetProjectionOffsetsY()[k],
                          cone.GetOutOfPlaneAngles()[k] * deg, cone.GetInPlaneAngles()[k] * deg,
                          cone.GetSourceOffsetsX()[k], cone.GetSourceOffsetsY()[k])
    return out


def _projection_image(p, geometry):
    """The stack as RTK's projection image: rows flipped once, origin and spacing of the
    detector in RTK's projection coordinates (mm, centred)."""
    itk, _ = _rtk()
    (w, h), (pu, pv) = _detector(geometry)
    image = itk.image_from_array(np.ascontiguousarray(p[:, ::-1, :]))   # the one row flip
    image.SetSpacing([pu, pv, 1.0])
    image.SetOrigin([-(w - 1) / 2 * pu, -(h - 1) / 2 * pv, 0.0])
    return image


def rtk_matrices(rgeo) -> np.ndarray:
    """``(n, 3, 4)`` float64: the projection matrices of an RTK geometry (RTK's ``GetMatrix``;
    from RTK's fixed coordinates to the projection image's physical coordinates, mm).

    Examples
    --------
    >>> from xray_viz.reconstruct import _rtk
    >>> g = _rtk()[1].ThreeDCircularProjectionGeometry.New()
    >>> g.AddProjection(1000.0, 1300.0, 0.0)
    >>> rtk_matrices(g)[0].tolist()
    [[-1300.0, 0.0, 0.0, 0.0], [0.0, -1300.0, 0.0, 0.0], [0.0, 0.0, 1.0, -1000.0]]
    """
    n = len(rgeo.GetGantryAngles())
    out = np.empty((n, 3, 4))
    for k in range(n):
        m = rgeo.GetMatrix(k)
        out[k] = [[m(i, j) for j in range(4)] for i in range(3)]
    return out


def write_rtk_geometry(geometry, path) -> Path:
    """Write a scan's geometry as RTK's ``ThreeDCircularProjectionGeometry`` XML file (RTK's
    own ``ThreeDCircularProjectionGeometryXMLFileWriter``), for ``rtkfdk --geometry`` and the
    other RTK command-line tools.

    The geometry is :func:`rtk_geometry`'s, in the frame :func:`rtk_frame` (RTK's y along the
    rotation axis, its origin at the scan's ``center``); RTK's tools also need the projections
    in RTK's image convention: :func:`write_rtk_projections`. The file is written beside the
    target, read back with RTK's reader (same projection matrices to 1e-9 relative: the XML holds
    15 significant digits), then renamed.

    Parameters
    ----------
    geometry : dict
        The scan's geometry (CT-LAYOUT.md).
    path : str or Path
        The ``.xml`` file.

    Returns
    -------
    Path
    """
    from xray_viz.output import atomic_write, check_target

    if not str(path).lower().endswith(".xml"):
        raise OutputError(f"{path}: RTK's geometry file is XML; end the name with .xml")
    check_target(path)
    _, rtk = _rtk()
    rgeo = rtk_geometry(geometry)
    want = rtk_matrices(rgeo)

    def write(tmp):
        w = rtk.ThreeDCircularProjectionGeometryXMLFileWriter.New()
        w.SetObject(rgeo)
        w.SetFilename(str(tmp))
        w.WriteFile()

    def verify(tmp):
        back = rtk_matrices(read_rtk_geometry(tmp))
        scale = np.abs(want).max(axis=(1, 2), keepdims=True)
        if back.shape != want.shape or not np.all(np.abs(back - want) <= 1e-9 * scale):
            raise OutputError(f"{path}: the RTK geometry read back differs")

    atomic_write(path, write, verify=verify)
    return Path(path)


def read_rtk_geometry(path):
    """Read an RTK ``ThreeDCircularProjectionGeometry`` XML file (RTK's own reader).

    Returns
    -------
    rtk.ThreeDCircularProjectionGeometry

    Raises
    ------
    ReconstructionError
        A missing file, or one that holds no projection (RTK's reader reads any other XML as
        an empty geometry).
    """
    _, rtk = _rtk()
    if not Path(path).is_file():
        raise ReconstructionError(f"{path}: no such RTK geometry file")
    reader = rtk.ThreeDCircularProjectionGeometryXMLFileReader.New()
    reader.SetFilename(str(path))
    try:
        reader.GenerateOutputInformation()
    except RuntimeError as exc:
        said = [ln for ln in str(exc).splitlines() if ln.strip()]
        raise ReconstructionError(f"{path}: RTK cannot read this geometry file "
                                  f"({said[-1] if said else type(exc).__name__})") from None
    rgeo = reader.GetOutputObject()
    if not len(rgeo.GetGantryAngles()):
        raise ReconstructionError(f"{path}: not an RTK geometry file (no <Projection> in a "
                                  "<RTKThreeDCircularGeometry>)")
    return rgeo


def write_rtk_projections(projections, geometry, path) -> Path:
    """Write a stack as RTK's command-line tools read projections: one 3D image (``.mha``,
    ``.mhd``, ``.nrrd``) of ``W x H x n`` float32 line integrals, rows flipped once (RTK's row
    index runs along ``v``, bottom to top), spacing ``(pu, pv, 1)`` and origin
    ``(-(W-1)/2 pu, -(H-1)/2 pv, 0)`` mm: with :func:`write_rtk_geometry`'s file,
    ``rtkfdk -g geometry.xml -p FOLDER -r NAME.mha -o volume.mha`` reconstructs the scan
    (``tests/reconstruct/test_reconstruct_rtk_files.py`` runs it).

    Returns
    -------
    Path
    """
    from xray_viz.output import atomic_write, check_target

    name = str(path).lower()
    if not name.endswith((".mha", ".mhd", ".nrrd")):
        raise OutputError(f"{path}: RTK's projections are written as an ITK image; end the "
                          "name with .mha, .mhd or .nrrd")
    check_target(path)
    itk, _ = _rtk()
    p = np.asarray(projections, dtype=np.float32)
    (w, h), _ = _detector(geometry)
    n = len(_poses(geometry))
    if p.shape != (n, h, w):
        raise ReconstructionError(f"projections have shape {p.shape}; the geometry says "
                                  f"(n, H, W) = {(n, h, w)}")
    image = _projection_image(p, geometry)

    def write(tmp):
        itk.imwrite(image, str(tmp), compression=True)

    def verify(tmp):
        back = itk.imread(str(tmp))
        if tuple(back.GetLargestPossibleRegion().GetSize()) != (w, h, n):
            raise OutputError(f"{path}: the projections read back differ")

    atomic_write(path, write, verify=verify)
    return Path(path)


def _rows_across_axis(p, geometry):
    """The stack and geometry with the detector's rows (``u``) across the rotation axis.

    Any axis that crosses the beam can be scanned (README); RTK's FDK weighting (its offset
    detector and short-scan filters) only knows a detector whose ``u`` runs across the axis and
    ``v`` along it. When the scan's ``u`` lies along the axis (an orbit about the detector's
    own x, e.g. ``--axis 1 0 0`` for a source on z), the same pixels are presented turned by
    90 degrees in the detector plane: ``u' = v``, ``v' = -u`` (same normal), the stack
    transposed accordingly - the same rays, described the way RTK expects. An axis along the
    beam (every view the same) is refused here, in one line, before RTK.
    """
    axis = _unit(geometry.get("axis", (0.0, 0.0, 1.0)), "axis")
    poses = _poses(geometry)
    rays = [q["detector_center"] - q["source"] for q in poses]
    if all(np.linalg.norm(r) > 0 and abs(r @ axis) > 0.999 * np.linalg.norm(r) for r in rays):
        raise ReconstructionError(f"the orbit's axis {axis.round(6).tolist()} runs along the beam "
                                  "(a source turning about the beam axis sees the same view "
                                  "every time): the orbit's axis must cross the beam")
    if not all(abs(q["u"] @ axis) > abs(q["v"] @ axis) for q in poses):
        return p, geometry
    (w, h), (pu, pv) = _detector(geometry)
    turned = dict(geometry)
    turned["poses"] = [{**pose, "u": np.asarray(q["v"]).tolist(),
                        "v": (-np.asarray(q["u"])).tolist()}
                       for pose, q in zip(geometry["poses"], poses)]
    turned["detector"] = {**geometry["detector"], "shape": [h, w], "pitch_mm": [pv, pu]}
    turned.pop("projection_matrices", None)
    # stored row r of the old stack is RTK row H-1-r; the new RTK image is the old one
    # transposed, then its rows flipped; stored again with the one flip of _projection_image
    return np.ascontiguousarray(p[:, ::-1, :].transpose(0, 2, 1)), turned


def _default_grid(geometry, voxel, shape):
    """Voxel size (mm) and shape (nx, ny, nz) of the volume, and its origin in world mm."""
    (w, h), (pu, pv) = _detector(geometry)
    R, center = rtk_frame(geometry)
    mag = 1.0
    if geometry.get("beam", "cone") != "parallel":
        sid, sod = geometry.get("sid_mm"), geometry.get("sod_mm")
        if sid and sod:
            mag = float(sod) / float(sid)
    if voxel is None:
        voxel = min(pu, pv) * mag
    voxel = np.broadcast_to(np.asarray(voxel, np.float64), (3,)).copy()
    if not np.all(np.isfinite(voxel)) or not np.all(voxel > 0):
        raise ReconstructionError(f"voxel must be a positive size in mm (one or three), got "
                                  f"{np.asarray(voxel).tolist()}")
    if shape is None:       # the detector seen at the isocentre: transaxial W, axial H
        fov_t, fov_a = w * pu * mag, h * pv * mag
        ax = np.abs(R[1])                  # the world axes' share of the rotation axis
        extent = fov_t * (1 - ax) + fov_a * ax
        shape = np.maximum(1, np.ceil(extent / voxel)).astype(int)
    shape = np.asarray(shape).reshape(-1)
    if shape.shape != (3,) or not np.all(shape >= 1) or not np.all(shape == np.round(shape)):
        raise ReconstructionError(f"shape must be three whole numbers >= 1 (X Y Z), got "
                                  f"{shape.tolist()}")
    shape = shape.astype(int)
    origin = center - (shape - 1) / 2 * voxel
    return voxel, shape, origin


def reconstruct(projections, geometry, *, voxel=None, shape=None, method: str = "fdk",
                hann: float = 0.0, iterations: int | None = None,
                relaxation: float | None = None) -> Volume:
    """Reconstruct a projection stack with RTK: FDK (circular cone beam), FBP (parallel), or
    an iterative method (SART, conjugate gradient) for few-view and helical scans.

    Parameters
    ----------
    projections : (n, H, W) array
        Line integrals ``-ln(I/I0)`` (xray_viz images: row 0 at the top of the detector).
    geometry : dict
        The scan's geometry (CT-LAYOUT.md): ``beam``, ``axis``, ``center``, ``poses``,
        ``detector`` (and ``sid_mm``/``sod_mm`` for the default voxel).
    voxel : float or (3,) float, optional
        Voxel size in mm; default the detector pitch at the isocentre.
    shape : (3,) int, optional
        ``(nx, ny, nz)`` voxels; default the detector's field of view at the isocentre.
    method : {"fdk", "fbp", "sart", "cg"}
        ``"fdk"`` for a cone beam, ``"fbp"`` for a parallel beam; the iterative ones
        (:data:`ITERATIVE`; RTK's Joseph projectors, either beam) fit few-view scans better
        than FDK (BENCHMARKS.md, "CT reconstruction"), at ``iterations`` times a forward and
        a back projection. ``"astra"`` and ``"tigre"`` are refused with the reason.
    hann : float
        RTK's Hann cut frequency in ]0, 1] (0: the plain ramp filter); FDK/FBP only.
    iterations : int, optional
        Iterative methods: SART passes over all projections, CG steps (default:
        :data:`ITERATIVE`'s). Unregularised CG fits noise and few-view gaps as it goes on
        (semi-convergence): keep it short.
    relaxation : float, optional
        SART's relaxation ``lambda`` (default 0.3).

    Returns
    -------
    Volume
        ``mu[z, y, x]`` float32 in 1/cm on a grid along the world axes, centred on ``center``.

    Raises
    ------
    ReconstructionError
        (a ``ValueError``) for a method that does not fit the beam, a helical orbit, a stack
        that does not match the geometry, or a refused back-end.

    Examples
    --------
    >>> reconstruct(np.zeros((1, 2, 2)), {"beam": "cone"}, method="tigre")
    Traceback (most recent call last):
    ...
    xray_viz.reconstruct.ReconstructionError: TIGRE needs CUDA (...
    """
    if method in REFUSED_BACKENDS:
        raise ReconstructionError(REFUSED_BACKENDS[method])
    if method not in METHODS:
        raise ReconstructionError(f"unknown method {method!r}; choose one of "
                                  f"{', '.join(METHODS)}")
    beam = geometry.get("beam", "cone")
    if beam not in ("cone", "parallel"):
        raise ReconstructionError(f"geometry beam {beam!r}: expected 'cone' or 'parallel'")
    if METHODS[method][0] not in (beam, "any"):
        other = "fdk" if beam == "cone" else "fbp"
        raise ReconstructionError(f"method {method!r} is for a {METHODS[method][0]} beam; this "
                                  f"scan is {beam} beam: use method={other!r}")
    orbit = geometry.get("orbit", "circular")
    helical = orbit == "helical" or float(geometry.get("pitch_mm_per_turn", 0.0) or 0.0) != 0.0
    if helical and method not in ITERATIVE and method != "mbirjax":
        raise ReconstructionError(f"method {method!r} (filtered back-projection) is for a "
                                  "circular orbit; a helical orbit reconstructs with an "
                                  "iterative method: method='sart', 'cg' or 'mbirjax'")
    if iterations is not None and not (float(iterations) == int(iterations) >= 1):
        raise ReconstructionError(f"iterations must be a whole number >= 1, got {iterations!r}")
    p = np.asarray(projections, dtype=np.float32)
    (w, h), (pu, pv) = _detector(geometry)
    n = len(_poses(geometry))
    if p.shape != (n, h, w):
        raise ReconstructionError(f"projections have shape {p.shape}; the geometry says "
                                  f"(n, H, W) = {(n, h, w)}")
    if not np.all(np.isfinite(p)):
        raise ReconstructionError("projections hold non-finite values (NaN or inf); "
                                  "reconstruct line integrals of a finished scan")
    p, geometry = _rows_across_axis(p, geometry)
    if method == "mbirjax":                  # no RTK needed
        voxel, shape, origin = _default_grid(geometry, voxel, shape)
        mu = _mbirjax(p, geometry, voxel, shape, origin, 15 if iterations is None else iterations)
        return Volume(mu=(mu * 10.0).astype(np.float32), origin=origin, spacing=voxel,
                      direction=np.eye(3), method=method)
    itk, rtk = _rtk()
    R, center = rtk_frame(geometry)
    voxel, shape, origin = _default_grid(geometry, voxel, shape)
    rgeo = rtk_geometry(geometry)

    image = _projection_image(p, geometry)
    ImageType = itk.Image[itk.F, 3]

    vol = rtk.ConstantImageSource[ImageType].New()
    vol.SetOrigin([float(x) for x in R @ (origin - center)])
    vol.SetSpacing([float(x) for x in voxel])
    vol.SetSize([int(x) for x in shape])
    direction = itk.Matrix[itk.D, 3, 3](itk.GetVnlMatrixFromArray(np.ascontiguousarray(R)))
    vol.SetDirection(direction)
    vol.SetConstant(0.0)

    if method in ITERATIVE:
        out = _iterative(method, vol.GetOutput(), image, rgeo, iterations=iterations,
                         relaxation=relaxation, volume_shape=shape)
        mu = itk.array_from_image(out).astype(np.float32) * np.float32(10.0)    # 1/cm
        return Volume(mu=mu, origin=origin, spacing=voxel, direction=np.eye(3), method=method)

    weighted = image
    if beam == "cone":
        ddf = rtk.DisplacedDetectorForOffsetFieldOfViewImageFilter[ImageType].New()
        ddf.SetInput(image)
        ddf.SetGeometry(rgeo)
        pssf = rtk.ParkerShortScanImageFilter[ImageType].New()
        pssf.SetInput(ddf.GetOutput())
        pssf.SetGeometry(rgeo)
        pssf.InPlaceOff()
        weighted = pssf.GetOutput()
    fdk = rtk.FDKConeBeamReconstructionFilter[ImageType].New()
    fdk.SetInput(0, vol.GetOutput())
    fdk.SetInput(1, weighted)
    fdk.SetGeometry(rgeo)
    fdk.GetRampFilter().SetTruncationCorrection(0.0)
    fdk.GetRampFilter().SetHannCutFrequency(float(hann))
    _update(fdk, shape, desc=f"reconstructing ({method})")
    mu = itk.array_from_image(fdk.GetOutput()).astype(np.float32) * np.float32(10.0)  # 1/cm
    return Volume(mu=mu, origin=origin, spacing=voxel, direction=np.eye(3), method=method)


def mbirjax_geometry(geometry) -> dict:
    """The scan's geometry as mbirjax's ``ConeBeamModel`` wants it (cone beam, flat detector,
    circular or helical orbit about ``axis``; ALU = mm).

    mbirjax's object frame: its z along the rotation ``axis`` through ``center``; its y
    (``e_y``) is :func:`rtk_frame`'s z, its x ``e_y x axis``. At view angle ``theta`` the
    source is at ``SID (sin theta e_x + cos theta e_y) + shift axis`` (mbirjax turns the object
    by ``theta``, source fixed on +y; ``helical_z_shifts`` move it along z) and the detector's
    channels run along ``cos theta e_x - sin theta e_y``, its rows along +z. Each pose is
    decomposed so; the detector must be untilted (its ``u``/``v`` those directions up to sign:
    a reversed one is a flipped image axis) and SID/SDD the same for every view.

    Returns
    -------
    dict
        ``angles`` (rad), ``helical_z_shifts`` (mm), ``source_iso_dist``,
        ``source_detector_dist``, ``det_channel_offset``, ``det_row_offset`` (mm),
        ``flip_rows``, ``flip_channels`` (bool), ``frame`` ((3, 3): rows e_x, e_y, axis).
    """
    R, center = rtk_frame(geometry)
    a, ey = R[1], R[2]
    ex = np.cross(ey, a)
    (w, h), (pu, pv) = _detector(geometry)
    out = {k: [] for k in ("angles", "helical_z_shifts", "sid", "sdd", "oc", "or", "su", "sv")}
    for k, p in enumerate(_poses(geometry)):
        s = p["source"] - center
        theta = math.atan2(s @ ex, s @ ey)
        radial = math.sin(theta) * ex + math.cos(theta) * ey
        chan = math.cos(theta) * ex - math.sin(theta) * ey
        su, sv = float(p["u"] @ chan), float(p["v"] @ a)
        if abs(abs(su) - 1) > 1e-6 or abs(abs(sv) - 1) > 1e-6 or abs(s @ chan) > 1e-6 * (
                1 + np.linalg.norm(s)):
            raise ReconstructionError(
                f"geometry poses[{k}]: mbirjax needs the source on a circle about the axis and "
                "an untilted detector (u across the axis, v along it); use method='sart' or "
                "'cg' (RTK) for this orbit")
        d = p["detector_center"] - center
        sid = float(s @ radial)
        sdd = float((s - d) @ radial)
        # where the central ray (source -> axis) meets the detector, in detector mm from its
        # centre along mbirjax's (channel, row) directions
        out["oc"].append(-float((d - (s - sdd * radial)) @ chan))
        out["or"].append(-float((d - (s - sdd * radial)) @ a))
        out["angles"].append(theta)
        out["helical_z_shifts"].append(float(s @ a))
        for key, val in (("sid", sid), ("sdd", sdd), ("su", su), ("sv", sv)):
            out[key].append(val)
    for key in ("sid", "sdd", "oc", "or", "su", "sv"):
        v = np.asarray(out[key])
        if np.ptp(v) > 1e-6 * max(1.0, np.abs(v).max()):
            raise ReconstructionError(f"geometry: mbirjax needs one {key} for every view "
                                      f"(got {v.min():g} .. {v.max():g}); use method='sart' "
                                      "or 'cg' (RTK) for this orbit")
    return {"angles": np.unwrap(out["angles"]), "helical_z_shifts": np.asarray(
                out["helical_z_shifts"]),
            "source_iso_dist": out["sid"][0], "source_detector_dist": out["sdd"][0],
            "det_channel_offset": out["oc"][0], "det_row_offset": out["or"][0],
            "flip_channels": out["su"][0] < 0, "flip_rows": out["sv"][0] > 0,
            "frame": np.array([ex, ey, a])}


def _mbirjax(p, geometry, voxel, shape, origin, iterations):
    """mbirjax's MBIR reconstruction (:func:`mbirjax_geometry`), resampled (trilinear) onto
    the world grid ``origin + index * voxel``: ``mu[z, y, x]`` in 1/mm."""
    try:
        import warnings

        import matplotlib

        backend = matplotlib.get_backend()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import mbirjax as mj               # its viewer switches matplotlib to TkAgg
        if matplotlib.get_backend() != backend:
            matplotlib.use(backend)
    except ImportError as exc:
        raise ReconstructionError(f"method 'mbirjax' needs mbirjax, which is not installed "
                                  f"({exc}); pip install 'xray_viz[ct-mbir]'") from None
    from scipy.ndimage import map_coordinates

    g = mbirjax_geometry(geometry)
    (w, h), (pu, pv) = _detector(geometry)
    sino = p[:, ::-1, :] if g["flip_rows"] else p
    sino = sino[:, :, ::-1] if g["flip_channels"] else sino
    delta = float(np.min(voxel))
    F, center = g["frame"], np.asarray(geometry.get("center", (0, 0, 0)), np.float64)
    # the world grid's corners in mbirjax's frame: its box, centred on the axis
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    pts = origin + (corners * (shape - 1)) * voxel - center
    half = np.abs(pts @ F.T).max(axis=0)
    n = (np.ceil(2 * half / delta).astype(int) + 3) | 1     # odd: a voxel on the axis
    model = mj.ConeBeamModel(sino.shape, g["angles"],
                             source_detector_dist=g["source_detector_dist"],
                             source_iso_dist=g["source_iso_dist"],
                             helical_z_shifts=g["helical_z_shifts"])
    model.set_params(delta_det_channel=pu, delta_det_row=pv,
                     det_channel_offset=g["det_channel_offset"],
                     det_row_offset=g["det_row_offset"], delta_voxel=delta,
                     recon_shape=(int(n[1]), int(n[0]), int(n[2])), verbose=0,
                     recon_slice_offset=0.0)   # mbirjax centres a helix's recon on its travel
    import io
    from contextlib import redirect_stdout

    np.random.seed(0)                          # mbirjax draws its partitions from NumPy's RNG
    with redirect_stdout(io.StringIO()):
        recon, _ = model.recon(np.ascontiguousarray(sino, dtype=np.float32),
                               max_iterations=int(iterations), logfile_path=None,
                               print_logs=False)
    recon = np.asarray(recon, np.float64)       # (rows: e_y, cols: e_x, slices: axis)
    # world voxel centres -> mbirjax (row, col, slice) indices
    zz, yy, xx = np.meshgrid(*(origin[i] + voxel[i] * np.arange(shape[i]) for i in (2, 1, 0)),
                             indexing="ij")
    q = np.stack([xx, yy, zz], -1) - center
    fx, fy, fz = (q @ F[i] for i in range(3))
    idx = [fy / delta + (n[1] - 1) / 2, fx / delta + (n[0] - 1) / 2, fz / delta + (n[2] - 1) / 2]
    return map_coordinates(recon, idx, order=1, mode="constant", cval=0.0)


def _update(f, volume_shape=None, *, iterations=None, desc="reconstructing"):
    """``f.Update()``; RTK's refusal is one line, with a hint only where its cause is known:
    an image it cannot allocate (the volume's size, given ``volume_shape``), a detector it
    cannot weight (FDK: use an iterative method). An axis along the beam is refused before
    RTK (:func:`_rows_across_axis`).

    The work runs as a :func:`xray_viz.progress.task` (a bar on the command line's stderr):
    ``iterations`` steps counted on RTK's ``IterationEvent`` for an iterative filter (SART,
    CG), else per cent of the filter's own ``GetProgress()`` on ITK's ``ProgressEvent``
    (FDK reports it as it filters and back-projects). The observers are attached only when
    the bars are on (:func:`xray_viz.progress.is_enabled`) and only read: the volume is the
    same with or without them."""
    from xray_viz import progress

    itk, _ = _rtk()
    total, unit = (int(iterations), "iteration") if iterations is not None else (100, "%")
    try:
        with progress.task(desc, total=total, unit=unit) as t:
            if iterations is not None:
                event, step = itk.IterationEvent(), (lambda: t.advance())
            else:
                event, step = itk.ProgressEvent(), (
                    lambda: t.update_to(max(t.n, min(100, int(f.GetProgress() * 100.0)))))
            tag = f.AddObserver(event, step) if progress.is_enabled() else None
            try:
                f.Update()
                if tag is not None and iterations is None:
                    t.update_to(100)     # done: ITK's last ProgressEvent may read 0.99...
            finally:
                if tag is not None:
                    f.RemoveObserver(tag)
    except RuntimeError as exc:
        said = [ln for ln in str(exc).splitlines() if "ERROR" in ln] or str(exc).splitlines()
        text = said[-1].split("):", 1)[-1].strip() if said else type(exc).__name__
        hint = ""
        if "allocate" in text.lower():
            if volume_shape is not None:
                n = int(np.prod(np.asarray(volume_shape, dtype=np.float64)))
                size = f"{n * 4 / 2**30:.3g} GiB" if n * 4 < 2**70 else "more than any memory"
                hint = (f": the {' x '.join(str(int(x)) for x in volume_shape)} voxel volume "
                        f"alone is {size} of float32; give a smaller --shape or a larger "
                        "--voxel (default: the detector's field of view)")
            else:
                hint = ": not enough memory for RTK's images"
        elif "detector rotation" in text.lower():
            hint = (": FDK's weighting needs the detector's rows across the rotation axis; "
                    "reconstruct this scan with method 'sart' or 'cg'")
        raise ReconstructionError(f"RTK cannot reconstruct this scan ({text}){hint}") from None


def _iterative(method, volume, image, rgeo, *, iterations, relaxation, volume_shape=None):
    """RTK's iterative reconstruction (Joseph forward and back projectors, CPU) of ``image``
    (RTK's projections) onto the grid of ``volume`` (a zero image): the output image, 1/mm."""
    itk, rtk = _rtk()
    ImageType = itk.Image[itk.F, 3]
    n_iter = int(iterations if iterations is not None else ITERATIVE[method][0])
    if method == "sart":
        f = rtk.SARTConeBeamReconstructionFilter[ImageType, ImageType].New()
        f.SetLambda(float(relaxation if relaxation is not None else 0.3))
        f.SetEnforcePositivity(True)
        f.SetNumberOfProjectionsPerSubset(1)            # SART: one projection per update
    elif method == "cg":
        f = rtk.ConjugateGradientConeBeamReconstructionFilter[ImageType].New()
        ones = rtk.ConstantImageSource[ImageType].New()  # unweighted least squares
        ones.SetInformationFromImage(image)
        ones.SetConstant(1.0)
        ones.Update()
        f.SetInput(2, ones.GetOutput())
    f.SetNumberOfIterations(n_iter)
    f.SetInput(0, volume)
    f.SetInput(1, image)
    f.SetGeometry(rgeo)
    _update(f, volume_shape, iterations=n_iter, desc=f"reconstructing ({method})")
    return f.GetOutput()


def rtk_forward_project(values, affine, geometry) -> np.ndarray:
    """RTK's Joseph forward projection (CPU) of a voxel grid onto a scan's detector: the line
    integrals ``sum of value x step`` (mm x value) of every pixel's ray, in xray_viz's image
    order, for comparing with :mod:`xray_viz.tracing.voxels` (issue 40).

    Joseph's projector samples the grid where each ray crosses the planes of voxel centres
    across its main direction, interpolating bilinearly within them (P. M. Joseph, IEEE TMI
    1 (1982) 192): not the exact chords, and it integrates between the first and last planes
    of voxel centres (half a voxel less at each face); agreement is to within that
    interpolation of the values.

    Parameters
    ----------
    values : (I, J, K) array
        Voxel values, indexed (i, j, k).
    affine : (4, 4)
        Voxel index -> world mm (any rotation: RTK honours the image's direction).
    geometry : dict
        :func:`xray_viz.scan.scan_geometry`'s (a circular or helical orbit).

    Returns
    -------
    (n, H, W) float32
    """
    itk, rtk = _rtk()
    R, center = rtk_frame(geometry)
    a = np.asarray(affine, np.float64)
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    vol = itk.image_from_array(np.ascontiguousarray(
        np.asarray(values, np.float32).transpose(2, 1, 0)))
    vol.SetSpacing([float(x) for x in spacing])
    vol.SetOrigin([float(x) for x in R @ (a[:3, 3] - center)])
    direction = R @ (a[:3, :3] / spacing)
    vol.SetDirection(itk.matrix_from_array(np.ascontiguousarray(direction)))
    (w, h), _ = _detector(geometry)
    n = len(_poses(geometry))
    proj = _projection_image(np.zeros((n, h, w), np.float32), geometry)
    ImageType = itk.Image[itk.F, 3]
    f = rtk.JosephForwardProjectionImageFilter[ImageType, ImageType].New()
    f.SetInput(0, proj)
    f.SetInput(1, vol)
    f.SetGeometry(rtk_geometry(geometry))
    _update(f, desc="forward projecting")
    return np.asarray(itk.array_from_image(f.GetOutput()))[:, ::-1, :].copy()


# --------------------------------------------------------------------------------------------
# Files: the scan store in, the volume out

VOLUME_FORMATS = {
    ".nii.gz": "NIfTI-1, gzipped (nibabel): affine in mm, RAS+ = xray_viz's world x, y, z",
    ".nii": "NIfTI-1 (nibabel): affine in mm, RAS+ = xray_viz's world x, y, z",
    ".mha": "MetaImage (ITK): origin, spacing, direction in mm (ITK's LPS reading of x, y, z)",
    ".nrrd": "NRRD (ITK): origin, spacing, direction in mm",
}


def _suffix(path) -> str:
    name = Path(path).name.lower()
    for s in VOLUME_FORMATS:
        if name.endswith(s):
            return s
    raise OutputError(f"{path}: unknown volume format; end the name with one of "
                      f"{', '.join(VOLUME_FORMATS)}")


def reconstruct_file(path, *, voxel=None, shape=None, method: str = "fdk",
                     **options) -> Volume:
    """Reconstruct the Zarr store of a scan (CT-LAYOUT.md; :func:`xray_viz.scan`).

    Reads ``projections`` and the group attribute ``xray_viz`` (``quantity``, ``geometry``);
    an ``intensity`` stack is turned into line integrals with its ``flat`` field (else the
    physics' ``I0``). Read by :func:`xray_viz.scan.read_zarr`, which refuses in one line a
    missing store, a folder that is not one, and one whose ``done`` record misses projections.

    Parameters
    ----------
    path : str or Path
        The ``.zarr`` folder.
    voxel, shape, method, **options
        As for :func:`reconstruct` (``hann``, ``iterations``, ``relaxation``).

    Returns
    -------
    Volume
    """
    p, geometry = read_line_integrals(path)
    return reconstruct(p, geometry, voxel=voxel, shape=shape, method=method, **options)


def read_line_integrals(path) -> tuple[np.ndarray, dict]:
    """``(projections, geometry)`` of a scan's Zarr store: float32 line integrals (an
    ``intensity`` stack is turned into them with its ``flat``/``dark`` fields, else the
    physics' ``I0``) and the geometry dict (CT-LAYOUT.md).
    """
    from xray_viz.scan import read_zarr

    stack = read_zarr(path)                  # one line for a missing or unfinished store
    p, geometry, quantity = stack.projections.astype(np.float32), stack.geometry, stack.quantity
    if quantity == "intensity":
        if stack.flat is not None:
            flat = stack.flat
            dark = stack.dark if stack.dark is not None else 0.0
        else:
            i0 = stack.physics.get("I0")
            if not i0:
                raise ReconstructionError(f"{path}: an intensity stack without a 'flat' array "
                                          "or physics I0 cannot be turned into line integrals")
            flat, dark = float(i0), 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            p = -np.log(np.clip((p - dark) / (flat - dark), 1e-30, None)).astype(np.float32)
    elif quantity not in ("line-integral", "line_integral"):
        raise ReconstructionError(f"{path}: quantity {quantity!r} cannot be reconstructed; "
                                  "expected 'line-integral' or 'intensity'")
    return p, geometry


def write_volume(volume: Volume, path) -> Path:
    """Write a volume: ``.nii.gz``/``.nii`` (nibabel) or ``.mha``/``.nrrd`` (ITK), safely
    (written beside the target, read back, then renamed).

    NIfTI: the affine maps voxel ``(i, j, k)`` (x, y, z index) to xray_viz's world mm, taken as
    NIfTI's RAS+ (x to the Right, y Anterior, z Superior; qform and sform code 1, "scanner");
    the data array is ``mu`` transposed to ``(x, y, z)``, float32, 1/cm. ITK formats carry the
    same origin, spacing and direction (ITK reads them as LPS; the numbers are xray_viz's).
    """
    from xray_viz.output import atomic_write, check_target

    suffix = _suffix(path)
    check_target(path)
    xyz = np.ascontiguousarray(np.transpose(volume.mu, (2, 1, 0)), dtype=np.float32)

    if suffix in (".nii.gz", ".nii"):
        import gzip

        import nibabel as nib

        img = nib.Nifti1Image(xyz, volume.affine)
        img.header.set_xyzt_units("mm")
        img.header["descrip"] = b"xray_viz mu 1/cm"
        img.set_qform(volume.affine, code=1)
        img.set_sform(volume.affine, code=1)
        data = img.to_bytes()
        if suffix == ".nii.gz":
            data = gzip.compress(data, compresslevel=6)

        def write(tmp):
            Path(tmp).write_bytes(data)

        def verify(tmp):
            back = nib.Nifti1Image.from_bytes(gzip.decompress(Path(tmp).read_bytes())
                                              if suffix == ".nii.gz" else Path(tmp).read_bytes())
            if not (np.allclose(back.affine, volume.affine) and back.shape == xyz.shape):
                raise OutputError("the NIfTI file read back differs")
    else:
        itk, _ = _rtk()

        def write(tmp):
            img = itk.image_from_array(np.ascontiguousarray(volume.mu, dtype=np.float32))
            img.SetOrigin([float(x) for x in volume.origin])
            img.SetSpacing([float(x) for x in volume.spacing])
            img.SetDirection(itk.GetMatrixFromArray(np.ascontiguousarray(volume.direction)))
            itk.imwrite(img, str(tmp), compression=True)

        def verify(tmp):
            back = itk.imread(str(tmp))
            if tuple(back.GetLargestPossibleRegion().GetSize()) != tuple(xyz.shape):
                raise OutputError("the volume file read back differs")
    atomic_write(path, write, verify=verify)
    return Path(path)


# --------------------------------------------------------------------------------------------
# The command line: `xray-viz reconstruct scan.zarr -o volume.nii.gz`

def add_reconstruct_parser(subparsers) -> None:
    """Register ``xray-viz reconstruct`` on the CLI's sub-parsers."""
    p = subparsers.add_parser(
        "reconstruct", help="reconstruct a scan (Zarr store) into a volume (RTK: FDK/FBP, SART, "
                            "CG)",
        description="Reconstruct the projection stack of `xray-viz scan` (a Zarr store) with "
                    "RTK on the CPU: FDK for a circular cone-beam orbit, FBP for a parallel "
                    "beam, SART or conjugate gradient (--method sart|cg --iterations N) for "
                    "few-view or helical scans; or mbirjax (--method mbirjax, the ct-mbir "
                    "extra). --rtk-geometry/--rtk-projections write RTK's own files for its "
                    "command-line tools (rtkfdk -g XML -p DIR -r NAME.mha). The volume (mu "
                    "in 1/cm, float32, on a grid along the scene's x, y, z axes) is written by OUT's suffix: "
                    + "; ".join(f"{k} = {v}" for k, v in VOLUME_FORMATS.items()) + ".")
    p.add_argument("store", metavar="SCAN", help="the scan's .zarr store")
    p.add_argument("-o", "--output", default=None, metavar="OUT",
                   help="the volume: .nii.gz, .nii, .mha or .nrrd (optional with --rtk-geometry "
                        "or --rtk-projections: then only those files are written)")
    p.add_argument("--voxel", type=float, default=None, metavar="MM",
                   help="voxel size in mm (default: the detector pitch at the rotation axis)")
    p.add_argument("--shape", type=int, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="voxels along x, y, z (default: the detector's field of view)")
    p.add_argument("--method", default=None, choices=sorted(METHODS),
                   help="fdk (cone beam) or fbp (parallel beam), or iterative: sart, cg "
                        "(RTK), mbirjax (MBIR, cone beam; few-view or helical scans); default: "
                        "fdk/fbp by the scan's beam")
    p.add_argument("--hann", type=float, default=0.0, metavar="F",
                   help="Hann window cut frequency in ]0, 1] against noise (default 0: none)")
    p.add_argument("--iterations", type=int, default=None, metavar="N",
                   help="iterative methods: passes / steps (default "
                        + ", ".join(f"{k} {v[0]}" for k, v in ITERATIVE.items())
                        + ", mbirjax 15)")
    p.add_argument("--rtk-geometry", default=None, metavar="XML",
                   help="also write the scan's geometry as RTK's "
                        "ThreeDCircularProjectionGeometry XML file (rtkfdk --geometry XML)")
    p.add_argument("--rtk-projections", default=None, metavar="MHA",
                   help="also write the projections as RTK's tools read them (.mha/.mhd/.nrrd: "
                        "rows flipped, centred origin): rtkfdk -g XML -p DIR -r NAME.mha")
    p.set_defaults(func=reconstruct_command)


def reconstruct_command(args) -> int:
    """``xray-viz reconstruct``: read, reconstruct, write (nothing is written on bad input)."""
    from xray_viz.output import check_target

    if not (args.output or args.rtk_geometry or args.rtk_projections):
        raise ReconstructionError("nothing to write: give -o VOLUME (.nii.gz, .nii, .mha, "
                                  ".nrrd), --rtk-geometry FILE.xml or --rtk-projections FILE.mha")
    if args.output:
        _suffix(args.output)                  # bad output names fail before the work
        check_target(args.output)
    if args.rtk_geometry and not args.rtk_geometry.lower().endswith(".xml"):
        raise OutputError(f"{args.rtk_geometry}: RTK's geometry file is XML; end the name "
                          "with .xml")
    if args.rtk_projections and not args.rtk_projections.lower().endswith(
            (".mha", ".mhd", ".nrrd")):
        raise OutputError(f"{args.rtk_projections}: RTK's projections are an ITK image; end "
                          "the name with .mha, .mhd or .nrrd")
    for extra in (args.rtk_geometry, args.rtk_projections):
        if extra:
            check_target(extra)
    method = args.method
    if method is None:
        method = "fdk"
        try:
            import zarr

            g = dict(zarr.open_group(str(args.store), mode="r").attrs)["xray_viz"]["geometry"]
            method = "fbp" if g.get("beam") == "parallel" else "fdk"
        except Exception:                     # reconstruct_file reports what is wrong
            pass
    projections, geometry = read_line_integrals(args.store)
    volume = None
    if args.output:                    # the work first: nothing is written if it fails
        volume = reconstruct(projections, geometry, voxel=args.voxel,
                             shape=tuple(args.shape) if args.shape else None,
                             method=method, hann=args.hann, iterations=args.iterations)
    else:
        rtk_geometry(geometry)         # refuses a geometry RTK cannot hold before writing
    if args.rtk_geometry:
        print(f"{write_rtk_geometry(geometry, args.rtk_geometry)}: RTK geometry, "
              f"{len(geometry['poses'])} projections")
    if args.rtk_projections:
        print(f"{write_rtk_projections(projections, geometry, args.rtk_projections)}: RTK "
              "projections (line integrals)")
    if volume is None:
        return 0
    out = write_volume(volume, args.output)
    nz, ny, nx = volume.mu.shape
    print(f"{out}: {nx} x {ny} x {nz} voxels of {', '.join(f'{s:g}' for s in volume.spacing)} "
          f"mm, mu {float(volume.mu.min()):.4g} .. {float(volume.mu.max()):.4g} /cm "
          f"({method})")
    return 0
