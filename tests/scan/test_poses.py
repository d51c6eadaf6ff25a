"""The rotations of poses (xray_viz.poses), written once: against scipy's Rotation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from xray_viz.poses import apply_rotations, rotation, rotations


@pytest.mark.parametrize("axis", [[0, 1, 0], [0, 0, 3.0], [1.0, -2.0, 0.5]])
def test_rotation_is_scipys_to_the_last_bits(axis):
    unit = np.asarray(axis, float) / np.linalg.norm(axis)
    degrees = np.linspace(-360.0, 360.0, 49)
    many = rotations(axis, degrees)
    for d, R in zip(degrees, many):
        want = Rotation.from_rotvec(np.radians(d) * unit).as_matrix()
        one = rotation(axis, float(d))
        assert np.abs(one - want).max() < 2e-15
        assert np.abs(R - want).max() < 2e-15
        np.testing.assert_allclose(one @ one.T, np.eye(3), atol=2e-15)
        assert np.linalg.det(one) == pytest.approx(1.0, abs=1e-14)
        assert np.abs(one @ unit - unit).max() < 1e-15               # the axis stays


def test_apply_rotations_is_the_matrix_product():
    rng = np.random.default_rng(5)
    rot = rotations([1.0, 2.0, 3.0], rng.uniform(-180, 180, 17))
    p = rng.normal(size=(17, 3))
    np.testing.assert_allclose(apply_rotations(rot, p), np.einsum("nij,nj->ni", rot, p),
                               rtol=0, atol=1e-14)
    # the same bits in any batch: no BLAS
    assert np.array_equal(apply_rotations(rot[3:4], p[3:4])[0], apply_rotations(rot, p)[3])


# --- conventions users bring ---------------------------------------------------------------

import xray_viz  # noqa: E402
from xray_viz.errors import SceneError  # noqa: E402
from xray_viz.poses import (  # noqa: E402
    carm_acquisition,
    carm_rotation,
    diffdrr_acquisition,
    diffdrr_rotation,
    euler_to_matrix,
    matrix_to_euler,
    matrix_to_quaternion,
    quaternion_to_matrix,
)


def _axis_turn(letter, angle):
    """The elementary rotation PyTorch3D's ``_axis_angle_rotation`` writes out (radians)."""
    c, s = np.cos(angle), np.sin(angle)
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[letter]


ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "XYX", "ZYZ"]


@pytest.mark.parametrize("order", ORDERS)
def test_euler_intrinsic_is_the_product_of_the_turns_and_extrinsic_its_reverse(order):
    a = np.radians([23.0, -41.0, 67.0])
    by_hand = _axis_turn(order[0], a[0]) @ _axis_turn(order[1], a[1]) @ _axis_turn(order[2], a[2])
    assert np.abs(euler_to_matrix(a, order, degrees=False) - by_hand).max() < 1e-14
    fixed = _axis_turn(order[2], a[2]) @ _axis_turn(order[1], a[1]) @ _axis_turn(order[0], a[0])
    assert np.abs(euler_to_matrix(np.degrees(a), order, intrinsic=False) - fixed).max() < 1e-14


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("intrinsic", [True, False])
def test_euler_round_trip(order, intrinsic):
    rng = np.random.default_rng(5)
    R = Rotation.random(20, random_state=rng).as_matrix()
    angles = matrix_to_euler(R, order, intrinsic=intrinsic)
    assert np.abs(euler_to_matrix(angles, order, intrinsic=intrinsic) - R).max() < 1e-12


def test_euler_order_is_checked():
    with pytest.raises(SceneError, match="Euler order 'ZZY'"):
        euler_to_matrix([0, 0, 0], "ZZY")


def test_quaternions_scalar_first_and_last():
    half = np.radians(50.0) / 2                 # 50 degrees about (1, 2, 2) / 3
    axis = np.array([1.0, 2.0, 2.0]) / 3
    wxyz = np.concatenate([[np.cos(half)], np.sin(half) * axis])
    R = rotation(axis, 50.0)
    assert np.abs(quaternion_to_matrix(wxyz, scalar_first=True) - R).max() < 1e-14
    assert np.abs(quaternion_to_matrix(np.roll(wxyz, -1)) - R).max() < 1e-14
    assert np.abs(matrix_to_quaternion(R, scalar_first=True) - wxyz).max() < 1e-14
    assert np.abs(matrix_to_quaternion(R) - np.roll(wxyz, -1)).max() < 1e-14
    # q and -q are the same rotation; the returned one has w >= 0
    assert matrix_to_quaternion(quaternion_to_matrix(-wxyz, scalar_first=True),
                                scalar_first=True)[0] > 0
    with pytest.raises(SceneError, match="quaternion"):
        quaternion_to_matrix([0, 0, 0, 0])


def _pytorch3d_quaternion_to_matrix(q):
    """DiffDRR's ``quaternion_to_matrix`` (PyTorch3D's), real part first, written out."""
    r, i, j, k = q
    two_s = 2.0 / (q @ q)
    return np.array([[1 - two_s * (j * j + k * k), two_s * (i * j - k * r), two_s * (i * k + j * r)],
                     [two_s * (i * j + k * r), 1 - two_s * (i * i + k * k), two_s * (j * k - i * r)],
                     [two_s * (i * k - j * r), two_s * (j * k + i * r), 1 - two_s * (i * i + j * j)]])


def test_diffdrr_parametrisations_agree_with_its_formulas():
    rng = np.random.default_rng(11)
    for _ in range(5):
        a = rng.uniform(-np.pi, np.pi, 3)
        R = diffdrr_rotation(a, parameterization="euler_angles", convention="ZXY")
        assert np.abs(R - _axis_turn("Z", a[0]) @ _axis_turn("X", a[1]) @ _axis_turn("Y", a[2])
                      ).max() < 1e-14
        q = rng.normal(size=4) * 3                       # DiffDRR normalises (two_s)
        assert np.abs(diffdrr_rotation(q, parameterization="quaternion")
                      - _pytorch3d_quaternion_to_matrix(q)).max() < 1e-13
        rv = rng.normal(size=3)
        assert np.abs(diffdrr_rotation(rv, parameterization="axis_angle")
                      - rotation(rv, np.degrees(np.linalg.norm(rv)))).max() < 1e-14
        assert np.abs(diffdrr_rotation(R[:2].ravel(), parameterization="rotation_6d") - R
                      ).max() < 1e-14
        assert np.array_equal(diffdrr_rotation(R, parameterization="matrix"), R)
    with pytest.raises(SceneError, match="convention"):
        diffdrr_rotation([0, 0, 0], parameterization="euler_angles")
    with pytest.raises(SceneError, match="se3_exp_map"):
        diffdrr_rotation([0] * 3, parameterization="se3_exp_map")


def _triu(A):
    """DiffDRR's 10-vector of a symmetric 4x4 matrix: ``A[triu_indices(4, 4)]``, row by row."""
    return np.array([A[i, j] for i in range(4) for j in range(i, 4)])


def test_diffdrr_10d_and_adjugate_parametrisations_agree_with_its_formulas():
    """``rotation_10d`` (the eigenvector of least eigenvalue of the symmetric matrix, DiffDRR's
    ``rotation_10d_to_quaternion``) and ``quaternion_adjugate`` (its row of largest norm):
    DiffDRR's own encodings of a quaternion (``-q q^T`` and ``q q^T``) give back its matrix;
    any 10-vector gives the matrix of its eigenvector, computed here by NumPy's eigh."""
    rng = np.random.default_rng(12)
    for _ in range(5):
        q = rng.normal(size=4)
        R = _pytorch3d_quaternion_to_matrix(q)
        assert np.abs(diffdrr_rotation(_triu(-np.outer(q, q)), parameterization="rotation_10d")
                      - R).max() < 1e-12
        adj = _triu(np.outer(q, q))
        assert np.abs(diffdrr_rotation(adj, parameterization="quaternion_adjugate") - R
                      ).max() < 1e-12
        v = rng.normal(size=10)
        A = np.zeros((4, 4))
        A[np.triu_indices(4)] = v
        A = A + np.triu(A, 1).T
        assert np.array_equal(_triu(A), v)
        w, vectors = np.linalg.eigh(A)
        assert np.abs(diffdrr_rotation(v, parameterization="rotation_10d")
                      - _pytorch3d_quaternion_to_matrix(vectors[:, np.argmin(w)])).max() < 1e-12
        row = A[np.argmax(np.linalg.norm(A, axis=0))]
        assert np.abs(diffdrr_rotation(v, parameterization="quaternion_adjugate")
                      - _pytorch3d_quaternion_to_matrix(row)).max() < 1e-12
    with pytest.raises(SceneError, match="rotation_10d rotation must be 10 finite numbers"):
        diffdrr_rotation([1.0] * 9, parameterization="rotation_10d")


def test_diffdrr_se3_log_map_is_the_exponential_of_the_twist():
    """``se3_log_map`` (rotation, translation): the pose is SE(3)'s exponential of the twist
    ``[[hat(rotation), translation], [0, 0]]`` (PyTorch3D's ``se3_exp_map``, translation
    first), computed here by SciPy's matrix exponential."""
    from scipy.linalg import expm

    like = xray_viz.load_scene("sphere").acquisition
    geo = dict(sdd=1000.0, height=4, delx=1.0)
    for omega, t in (([0.3, -1.2, 0.7], [15.0, -40.0, -600.0]), ([0.0, 0.0, 0.0], [1, 2, -500]),
                     ([1e-9, 0.0, -2e-9], [0.0, 30.0, -550.0])):
        wx, wy, wz = omega
        twist = np.zeros((4, 4))
        twist[:3, :3] = [[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]]
        twist[:3, 3] = t
        pose = expm(twist)
        acq = diffdrr_acquisition(omega, t, like=like, parameterization="se3_log_map", **geo)
        assert np.abs(acq.source.position - pose[:3, 3]).max() < 1e-9
        assert np.abs(acq.detector.center - (pose[:3, :3] @ [0, 0, 1000.0] + pose[:3, 3])
                      ).max() < 1e-9
        assert np.abs(diffdrr_rotation(omega, parameterization="se3_log_map") - pose[:3, :3]
                      ).max() < 1e-12


def _diffdrr_rays(R, t, *, sdd, height, width, delx, dely, x0, y0, reorient,
                  reverse_x_axis=False):
    """DiffDRR's ``Detector._initialize_carm`` + calibration + ``forward`` (source, targets in
    its image order), reimplemented from its source."""
    h_off = 1.0 if height % 2 else 0.5
    w_off = 1.0 if width % 2 else 0.5
    tt = -(np.arange(-height // 2, height // 2) + h_off)
    s = -(np.arange(-width // 2, width // 2) + w_off)
    if not reverse_x_axis:
        s = -s
    coefs = np.array([(a, b) for a in tt for b in s])           # cartesian_prod(t, s)
    basis = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    target = coefs @ basis + [0.0, 0.0, 1.0]
    calibration = np.array([[delx, 0, 0, x0], [0, dely, 0, y0], [0, 0, sdd, 0], [0, 0, 0, 1]])
    extrinsic = np.eye(4)
    extrinsic[:3, :3], extrinsic[:3, 3] = R, t
    pose = extrinsic @ reorient                                # reorient.compose(extrinsic)
    homog = np.c_[target, np.ones(len(target))] @ calibration.T
    target = homog @ pose.T
    return pose[:3, 3], target[:, :3].reshape(height, width, 3)


@pytest.mark.parametrize("reverse_x_axis", [False, True])
def test_diffdrr_pose_gives_its_source_and_pixels(reverse_x_axis):
    like = xray_viz.load_scene("sphere").acquisition
    reorient = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # its "AP"
    cases = [([0.0, 0.0, 0.0], [0.0, 0.0, -500.0], "euler_angles", "ZXY", np.eye(4)),
             ([0.3, -0.4, 1.1], [20.0, 850.0, -30.0], "euler_angles", "ZXY", reorient),
             ([0.9, 0.1, -0.3, 0.2], [5.0, -7.0, 600.0], "quaternion", None, reorient),
             ([0.2, 1.3, -0.5], [-40.0, 10.0, 700.0], "axis_angle", None, np.eye(4))]
    for rot, t, param, conv, reo in cases:
        geo = dict(sdd=1020.0, height=5, width=7, delx=1.5, dely=2.0, x0=3.0, y0=-4.5)
        acq = diffdrr_acquisition(rot, t, like=like, parameterization=param, convention=conv,
                                  reorient=reo, **geo)
        R = diffdrr_rotation(rot, parameterization=param, convention=conv)
        src, targets = _diffdrr_rays(R, np.array(t), reorient=reo,
                                     reverse_x_axis=reverse_x_axis, **geo)
        assert np.abs(acq.source.position - src).max() < 1e-9
        ends = acq.rays().ends.reshape(5, 7, 3)                # xray_viz's image order
        mine = ends if reverse_x_axis else ends[:, ::-1]       # its columns run the other way
        assert np.abs(mine - targets).max() < 1e-9


def test_carm_cardinal_views_against_the_hand_derived_geometry():
    """LPS axes: x left, y posterior, z superior; source sod before the isocentre, detector
    sid - sod beyond it, up the head end turned with the arm."""
    like = xray_viz.load_scene("sphere").acquisition
    iso = np.array([10.0, -20.0, 30.0])
    c30, s30 = np.cos(np.radians(30)), np.sin(np.radians(30))
    views = {  # (lao, cranial): (unit source -> detector, detector up)
        (0.0, 0.0): ([0, -1, 0], [0, 0, 1]),            # AP: beam posterior -> anterior
        (90.0, 0.0): ([1, 0, 0], [0, 0, 1]),            # LAO 90: left lateral
        (-90.0, 0.0): ([-1, 0, 0], [0, 0, 1]),          # RAO 90: right lateral
        (0.0, 30.0): ([0, -c30, s30], [0, s30, c30]),   # cranial 30: detector towards the head
        (0.0, -30.0): ([0, -c30, -s30], [0, -s30, c30]),  # caudal 30
        (30.0, 0.0): ([s30, -c30, 0], [0, 0, 1]),       # LAO 30
    }
    for convention in ("dicom", "deepdrr"):
        for (lao, cra), (beam, up) in views.items():
            acq = carm_acquisition(like, lao=lao, cranial=cra, sid=1000.0, sod=700.0,
                                   isocenter=iso, convention=convention)
            beam, up = np.array(beam, float), np.array(up, float)
            assert np.abs(acq.source.position - (iso - 700.0 * beam)).max() < 1e-9
            assert np.abs(acq.detector.center - (iso + 300.0 * beam)).max() < 1e-9
            assert np.abs(acq.frame.forward - beam).max() < 1e-12
            assert np.abs(acq.frame.ve / np.linalg.norm(acq.frame.ve) - up).max() < 1e-12
            # at AP the image's columns run towards the patient's right (seen from the source)
            if (lao, cra) == (0.0, 0.0):
                assert np.abs(acq.frame.ho / np.linalg.norm(acq.frame.ho) - [-1, 0, 0]
                              ).max() < 1e-12


def test_carm_conventions_differ_only_when_both_angles_are_set():
    """DICOM: the cranial turn about the rolled arm; DeepDRR: about the fixed left-right axis
    (its MobileCArm's ``from_euler("xy", [alpha, beta])``, alpha RAO+, beta caudal+)."""
    lao, cra = np.radians(40.0), np.radians(25.0)
    dicom = carm_rotation(40.0, 25.0) @ [0, -1, 0]
    assert np.abs(dicom - [np.sin(lao) * np.cos(cra), -np.cos(lao) * np.cos(cra), np.sin(cra)]
                  ).max() < 1e-14
    deep = carm_rotation(40.0, 25.0, convention="deepdrr") @ [0, -1, 0]
    # DeepDRR by hand: principal ray Ry(beta) Rx(alpha) z in its device frame (x inferior,
    # y left, z anterior), alpha = -lao, beta = -cranial
    a, b = -lao, -cra
    ray = _axis_turn("Y", b) @ _axis_turn("X", a) @ [0, 0, 1]
    lps = ray[0] * np.array([0, 0, -1]) + ray[1] * np.array([1, 0, 0]) + ray[2] * np.array(
        [0, -1, 0])
    assert np.abs(deep - lps).max() < 1e-14
    assert np.abs(deep - dicom).max() > 0.05


def test_carm_bad_input_names_the_value():
    like = xray_viz.load_scene("sphere").acquisition
    with pytest.raises(SceneError, match="0 < sod < sid"):
        carm_acquisition(like, sid=500.0, sod=700.0)
    with pytest.raises(SceneError, match="C-arm lao"):
        carm_acquisition(like, lao=float("nan"), sid=1000.0, sod=700.0)
    with pytest.raises(SceneError, match="convention 'siemens'"):
        carm_acquisition(like, sid=1000.0, sod=700.0, convention="siemens")


def test_a_scan_builds_each_acquisition_once_for_its_images_and_its_geometry(monkeypatch):
    """Issue 37: the poses are computed once and shared with the geometry export."""
    import dataclasses

    from xray_viz.geometry import Acquisition
    from xray_viz.scan import Orbit, Projections, scan_geometry

    scene = xray_viz.load_scene("sphere")
    small = scene.replace(detector=dataclasses.replace(scene.detector, shape=(16, 12),
                                                       pitch=(16.0, 16.0)))
    orbit = Orbit(projections=5, axis=[0, 1, 0])
    reference = xray_viz.scan(small, orbit)                 # before counting
    built = []
    original = Acquisition.__post_init__

    def counting(self):
        built.append(self)
        original(self)

    monkeypatch.setattr(Acquisition, "__post_init__", counting)
    s = xray_viz.scan(small, orbit)
    # one per projection, and at most one for the whole orbit's pose arrays (before: 5 + 5 + 1)
    assert 5 <= len(built) <= 6
    np.testing.assert_array_equal(s.projections, reference.projections)
    # the geometry read from the kept acquisitions is the one built on its own
    monkeypatch.setattr(Acquisition, "__post_init__", original)
    project = Projections(small, orbit, keep=True)
    assert scan_geometry(small, orbit, acquisitions=project.acquisitions) == \
        scan_geometry(small, orbit)


# --- CIL ---------------------------------------------------------------------------------

def _cil_to_astra(cil):
    """CIL's own map of a circular AcquisitionGeometry to ASTRA ``cone_vec`` /
    ``parallel3d_vec`` rows (``cil.plugins.astra.utilities.convert_geometry_to_astra_vec_3D``,
    reimplemented from its source): the frame aligned so that the rotation axis is z through
    the origin (``align_reference_frame('cil')``), ``row = pixel_size[0] direction_x``,
    ``col = pixel_size[1] direction_y`` (negated for a ``right`` / ``top`` origin), and
    each system turned by ``-angle`` about z. Returns the rows and the frame ``(M, origin)``."""
    sysargs, panel = cil["system"], cil["panel"]
    z = np.asarray(sysargs["rotation_axis_direction"], float)
    z /= np.linalg.norm(z)
    ref = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    M = np.array([x, np.cross(z, x), z])                  # rows: the aligned frame's axes
    o = np.asarray(sysargs["rotation_axis_position"], float)
    row = panel["pixel_size"][0] * M @ sysargs["detector_direction_x"]
    col = panel["pixel_size"][1] * M @ sysargs["detector_direction_y"]
    if "right" in panel["origin"]:
        row = -row
    if "top" in panel["origin"]:
        col = -col
    det = M @ (np.asarray(sysargs["detector_position"], float) - o)
    src = M @ sysargs["ray_direction"] if "ray_direction" in sysargs \
        else M @ (np.asarray(sysargs["source_position"], float) - o)
    out = []
    for theta in cil["angles"]["angles"]:
        t = np.radians(-theta)
        Rz = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
        out.append(np.concatenate([Rz @ src, Rz @ det, Rz @ row, Rz @ col]))
    return np.array(out), M, o


@pytest.mark.parametrize("beam", ["cone", "parallel"])
def test_cil_geometry_is_our_astra_geometry_through_cils_own_conversion(beam):
    import dataclasses

    from xray_viz.poses import astra_vectors, cil_geometry
    from xray_viz.scan import Orbit, scan_geometry

    scene = xray_viz.load_scene("sphere")
    det = dataclasses.replace(scene.detector, shape=(40, 30), pitch=(2.0, 3.0),
                              offset=(7.0, -5.0))
    src = dataclasses.replace(scene.source, kind="parallel") if beam == "parallel" \
        else scene.source
    scene = scene.replace(detector=det, source=src)
    orbit = Orbit(projections=7, axis=[0.2, 1.0, 0.1], center=[3.0, -4.0, 5.0], start=30.0,
                  arc=250.0)
    g = scan_geometry(scene, orbit)
    cil = cil_geometry(g)
    assert cil["create"] == ("create_Cone3D" if beam == "cone" else "create_Parallel3D")
    assert cil["dimension_labels"] == ["angle", "vertical", "horizontal"]
    theirs, M, o = _cil_to_astra(cil)
    ours = astra_vectors(g)
    # ours in CIL's aligned frame: positions moved by -o, everything turned by M
    ours_aligned = np.concatenate(
        [(ours[:, :3] - (0 if beam == "parallel" else o)) @ M.T, (ours[:, 3:6] - o) @ M.T,
         ours[:, 6:9] @ M.T, ours[:, 9:] @ M.T], axis=1)
    assert np.abs(theirs - ours_aligned).max() < 1e-9


def test_cil_geometry_refuses_what_is_not_one_system_turned():
    from xray_viz.poses import cil_geometry
    from xray_viz.scan import orbit_from_dict, scan_geometry

    scene = xray_viz.load_scene("sphere")
    helical = scan_geometry(scene, orbit_from_dict({"orbit": "helical", "projections": 4,
                                                    "axis": [0, 1, 0], "pitch": 20.0}))
    with pytest.raises(SceneError, match="pose 1 is not the first pose turned"):
        cil_geometry(helical)
    random = scan_geometry(scene, orbit_from_dict({"axis": [0, 1, 0],
                                                   "poses": {"random": 3, "seed": 1}}))
    with pytest.raises(SceneError, match="astra_vectors"):
        cil_geometry(random)


def test_cil_acquisition_geometry_names_how_to_get_cil():
    from xray_viz.poses import cil_acquisition_geometry
    from xray_viz.scan import Orbit, scan_geometry

    try:
        import cil  # noqa: F401
    except ModuleNotFoundError:
        g = scan_geometry(xray_viz.load_scene("sphere"), Orbit(projections=2, axis=[0, 1, 0]))
        with pytest.raises(ModuleNotFoundError, match="conda-forge"):
            cil_acquisition_geometry(g)
    else:
        g = scan_geometry(xray_viz.load_scene("sphere"), Orbit(projections=2, axis=[0, 1, 0]))
        ag = cil_acquisition_geometry(g)
        assert ag.config.panel.num_pixels.tolist() == [256, 256]


def test_rtk_rows_are_the_poses_in_rtks_frame():
    from xray_viz.poses import rtk_axes, rtk_rows

    rng = np.random.default_rng(3)
    for axis in rng.normal(size=(5, 3)):
        R = rtk_axes(axis)
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-14 and np.linalg.det(R) > 0
        assert np.abs(R[1] - axis / np.linalg.norm(axis)).max() < 1e-14     # y: the axis
    pose = {"source": [0.0, 0.0, 1000.0], "detector_center": [0.0, 0.0, -500.0],
            "u": [1.0, 0.0, 0.0], "v": [0.0, 1.0, 0.0]}
    R, c = rtk_axes([0, 1, 0]), np.array([1.0, 2.0, 3.0])
    (s, d, u, v), = rtk_rows([pose], R, c, parallel=False)
    assert np.abs(R.T @ s + c - pose["source"]).max() < 1e-12
    assert np.abs(R.T @ d + c - pose["detector_center"]).max() < 1e-12
    assert np.abs(R.T @ u - pose["u"]).max() < 1e-15 and np.abs(R.T @ v - pose["v"]).max() < 1e-15
    # a parallel beam's source goes onto the detector's normal; oblique rays are refused
    (s, d, u, v), = rtk_rows([pose], R, c, parallel=True)
    assert np.abs(np.cross(s - d, np.cross(u, v))).max() < 1e-9
    oblique = {**pose, "source": [300.0, 0.0, 1000.0]}
    with pytest.raises(SceneError, match="poses\\[0\\].*oblique"):
        rtk_rows([oblique], R, c, parallel=True)


def test_carm_in_a_scene_whose_axes_are_not_lps():
    """A RAS scene (x right, y anterior, z superior): world_from_patient = diag(-1, -1, 1)."""
    like = xray_viz.load_scene("sphere").acquisition
    ras = np.diag([-1.0, -1.0, 1.0])
    ap = carm_acquisition(like, sid=1000.0, sod=700.0, world_from_patient=ras)
    assert np.abs(ap.source.position - [0.0, -700.0, 0.0]).max() < 1e-9    # posterior: -y
    lat = carm_acquisition(like, lao=90.0, sid=1000.0, sod=700.0, world_from_patient=ras)
    assert np.abs(lat.detector.center - [-300.0, 0.0, 0.0]).max() < 1e-9   # the left: -x
    with pytest.raises(SceneError, match="rotation matrix"):
        carm_acquisition(like, sid=1000.0, sod=700.0, world_from_patient=np.diag([1, 1, -1]))
