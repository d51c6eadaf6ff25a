"""Hostile values become one-line errors naming the key and the limit, never a traceback or a
silently wrong image (issue 12): through the command line (exit status 2, one line on stderr)
and through the API (SceneError / MaterialError, both ValueErrors)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.cli import main
from xray_viz.errors import MaterialError, SceneError, XrayVizError
from xray_viz.scene import (BODY_SIZE_RANGE, COORDINATE_LIMIT, PITCH_RANGE, Body, Detector,
                            Scene, Source, scene_from_dict)
from xray_viz.tracing import trace_rays
from helpers import write_scene

BALL = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
BALL_SIZE = float(np.ptp(BALL.vertices, axis=0).max())      # the largest side of its box


def scene_text(source="energy = 60.0", detector="pitch = 4.0", body="mu = 0.2") -> str:
    """A small scene file: the ball at the origin, a 16 x 16 detector, 1500 mm from the source."""
    if "position" not in source:
        source = "position = [0.0, 0.0, 1000.0]\n" + source
    if "center" not in detector:
        detector = "center = [0.0, 0.0, -500.0]\n" + detector
    if "name" not in body:
        body = 'name = "ball"\n' + body
    if "mesh" not in body:
        body = 'mesh = "ball.stl"\n' + body
    return (f"[source]\n{source}\n\n[detector]\nshape = [16, 16]\n{detector}\n\n"
            f"[[body]]\n{body}\n")


def cli_error(tmp_path, capsys, text, *, files=None) -> str:
    """Render the scene ``text`` through the CLI; assert it fails in one line; return the line."""
    path = write_scene(tmp_path, text, {"ball.stl": BALL, **(files or {})})
    out = tmp_path / "out.npy"
    rc = main(["render", str(path), "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("xray-viz: error: ") and "Traceback" not in err
    assert not out.exists()
    return lines[0]


def cli_render(tmp_path, capsys, text, *, engine="fast", files=None) -> np.ndarray:
    """Render the scene ``text`` through the CLI; assert it succeeds; return the image."""
    path = write_scene(tmp_path, text, {"ball.stl": BALL, **(files or {})})
    out = tmp_path / "out.npy"
    rc = main(["render", str(path), "-o", str(out), "--engine", engine])
    err = capsys.readouterr().err
    assert rc == 0 and "Traceback" not in err and "error" not in err, err
    return np.load(out)


# ------------------------------------------------------------------------------------------
# 1. body scale: the mesh's size in the scene must be one float64 engines can hold


@pytest.mark.parametrize("scale", [1e-200, 1e-12, 1e12, 1e100])
def test_absurd_body_scales_name_the_key_and_the_size(tmp_path, capsys, scale):
    msg = cli_error(tmp_path, capsys, scene_text(body=f"mu = 0.2\nscale = {scale!r}"))
    lo, hi = BODY_SIZE_RANGE
    assert f"[[body]] #1 (name 'ball') scale {scale:g} makes the mesh " \
           f"{BALL_SIZE * scale:.3g} mm across" in msg, msg
    assert f"between {lo:g} and {hi:g} mm across" in msg and "scale and units" in msg


def test_a_scale_that_overflows_float64_says_so(tmp_path, capsys):
    msg = cli_error(tmp_path, capsys, scene_text(body="mu = 0.2\nscale = 1e307"))
    assert "(name 'ball') scale 1e+307 makes the mesh overflow float64" in msg, msg


def test_a_scale_that_flattens_the_mesh_says_so_not_that_repair_failed(tmp_path, capsys):
    msg = cli_error(tmp_path, capsys, scene_text(body="mu = 0.2\nscale = [1.0, 1.0, 1e-12]"))
    assert "scale [1.0, 1.0, 1e-12] flattens the mesh" in msg and "repair" not in msg, msg


def test_a_body_too_small_for_its_distance_from_the_origin(tmp_path, capsys):
    # 0.04 mm across, 1e8 mm out: float64 would place its vertices to 1.5e-8 mm only
    msg = cli_error(tmp_path, capsys, scene_text(
        body="mu = 0.2\nscale = 1e-3\nposition = [0.0, 100000000.0, 0.0]"))
    assert "scale 0.001 with position [0.0, 100000000.0, 0.0] puts the mesh" in msg, msg
    assert "2**-30 of its distance from the origin" in msg


def test_a_body_beyond_the_coordinate_limit(tmp_path, capsys):
    msg = cli_error(tmp_path, capsys, scene_text(body="mu = 0.2\nposition = [0.0, 2e9, 0.0]"))
    assert "[[body]] #1 (name 'ball') position [0.0, 2000000000.0, 0.0]" in msg
    assert f"within {COORDINATE_LIMIT:g} mm" in msg


def test_vertices_merged_by_the_transform_are_refused():
    from xray_viz.scene_file import _place_mesh, body_transform

    # two vertices one ulp apart at x = 20: distinct, but not once moved 1000 mm out
    v = np.array([[20.0, 0, 0], [np.nextafter(20.0, 30.0), 0, 0], [0, 20.0, 0], [0, 0, 20.0]])
    mesh = trimesh.Trimesh(v, [[0, 2, 3], [1, 3, 2]], process=False)
    assert len(np.unique(v, axis=0)) == 4
    with pytest.raises(SceneError, match="merges 1 of the mesh's 4 vertices"):
        _place_mesh(mesh, body_transform(position=[1000.0, 0, 0]), where="", cause="position")


def test_the_body_size_limits_hold_for_the_api_too():
    with pytest.raises(SceneError, match="body 'b': the mesh is 4.*e-199 mm across"):
        Body("b", BALL.copy().apply_scale(1e-200), mu=0.2)
    with pytest.raises(SceneError, match="2\\*\\*-30 of its distance"):
        Body("b", BALL.copy().apply_scale(1e-3).apply_translation([0, 0, 1e8]), mu=0.2)


def scaled_sphere_scene(s: float, *, pitch_factor=5.0) -> dict:
    """The whole set-up scaled by ``s``: the ball (40 mm) 12 pixels across on 16 x 16."""
    return {"source": {"position": [0.0, 0.0, 1000.0 * s]},
            "detector": {"center": [0.0, 0.0, -500.0 * s], "shape": [16, 16],
                         "pitch": pitch_factor * s},
            "body": [{"name": "ball", "mesh": "ball.stl", "mu": 0.2, "scale": s}]}


def test_sane_scales_render_the_same_picture_in_both_engines(tmp_path):
    """Scale invariance: the whole scene scaled by s has path lengths s times the unscaled
    ones, in both engines, from pitch 1e-6 mm (s = 2e-7) to 1e6 mm (s = 2e5), the limits."""
    BALL.export(tmp_path / "ball.stl")
    ref = None
    for s in (2e-7, 1e-3, 0.37, 1.0, 1e3, 2e5):
        scene = scene_from_dict(scaled_sphere_scene(s), base_dir=tmp_path)
        assert scene.detector.pitch[0] == pytest.approx(5 * s)
        for engine in ("fast", "numpy"):
            L = xray_viz.render(scene, engine=engine).total_path_length / s
            if ref is None:
                ref = L
                assert ref.max() > 30 and np.count_nonzero(ref) > 60   # the ball is seen
            np.testing.assert_allclose(L, ref, rtol=1e-7, atol=1e-9 * ref.max(),
                                       err_msg=f"scale {s}, {engine} engine")


# ------------------------------------------------------------------------------------------
# 2. detector pitch: what the fast engine's fixed-point grid can represent


def test_the_pitch_limits_are_those_of_the_fixed_point_grid():
    from xray_viz.scene import PITCH_MIN_RELATIVE
    from xray_viz.tracing import _raster

    # the docstrings' "snapped to 2**-22 of a pitch, 2**35 pitches each way"
    assert _raster.FRAC_BITS == 22 and _raster.COORD_LIMIT == 2.0 ** 35
    lo, hi = PITCH_RANGE
    assert lo * _raster.COORD_LIMIT == pytest.approx(34359.7, rel=1e-5)  # +-34 m of grid
    assert hi * 2.0 ** -(_raster.FRAC_BITS + 1) < 0.12                  # rays to 0.12 mm
    # the relative floor puts rays to 2**-22 of a pitch: 2**-52 of the distance
    assert PITCH_MIN_RELATIVE * 2.0 ** -_raster.FRAC_BITS == 2.0 ** -52


@pytest.mark.parametrize("detector, shown", [
    ("pitch = 1e-300", "pitch 1e-300 mm: out of range"),
    ("pitch = 1e300", "pitch 1e+300 mm: out of range"),
    ("pitch = 9e-7", "pitch 9e-07 mm: out of range"),
    ("pitch = [1.0, 2e6]", "pitch 2e+06 mm: out of range"),
    ("size = [1e-300, 1e-300]", "size [1e-300, 1e-300] over shape [16, 16] gives a pitch of "
                                "6.66667e-302 mm: out of range"),
])
def test_absurd_pitches_are_refused_with_the_limit(tmp_path, capsys, detector, shown):
    msg = cli_error(tmp_path, capsys, scene_text(detector=detector))
    assert shown in msg and "between 1e-06 and 1e+06 mm" in msg and "fixed-point grid" in msg, msg


def test_a_pitch_too_fine_for_the_detectors_distance_from_the_origin(tmp_path, capsys):
    msg = cli_error(tmp_path, capsys, scene_text(
        source="position = [0.0, 0.0, 100001000.0]\nenergy = 60.0",
        detector="center = [0.0, 0.0, 100000000.0]\npitch = 0.01"))
    # 2**-30 * 1e8 mm = 0.093 mm
    assert "pitch 0.01 mm: too fine for a detector centred 1e+08 mm from the origin" in msg, msg
    assert "(0.0931 mm)" in msg


def test_the_api_detector_checks_the_pitch_too():
    with pytest.raises(SceneError, match="pitch 1e-300 mm: out of range"):
        Detector(center=[0, 0, -500], pitch=1e-300)
    with pytest.raises(SceneError, match="out of range"):
        Detector.from_size([0, 0, -500], [0, 1, 0], (16, 16), 1e300)
    for p in PITCH_RANGE:                                 # the limits themselves are fine
        assert Detector(center=[0, 0, -500], pitch=p).pitch == (p, p)


# ------------------------------------------------------------------------------------------
# 3. energies: material bodies need xraylib's tabulated range, constant mu any energy


def test_xraylibs_tables_span_exactly_the_stated_range():
    """The range in the messages is xraylib's own: every element Z = 1..98 has its total cross
    section at 0.1 and 800 keV and refuses to extrapolate just outside."""
    import xraylib

    from xray_viz.physics.materials import ENERGY_RANGE

    lo, hi = ENERGY_RANGE
    for z in range(1, 99):
        assert xraylib.CS_Total(z, lo) > 0 and xraylib.CS_Total(z, hi) > 0
        for e in (lo * 0.999, hi * 1.001):
            with pytest.raises(ValueError, match="extrapolation"):
                xraylib.CS_Total(z, e)


@pytest.mark.parametrize("energy", [0.0001, 0.09, 801.0, 5000.0])
def test_energies_outside_the_material_data_say_the_range(tmp_path, capsys, energy):
    msg = cli_error(tmp_path, capsys, scene_text(source=f"energy = {energy!r}",
                                                 body='material = "Water, Liquid"'))
    assert f"[source] energy {energy:g} keV is outside 0.1-800 keV" in msg, msg
    assert "body 'ball' (material 'Water, Liquid')" in msg and "constant mu" in msg


@pytest.mark.parametrize("rows, span", [("0.05,1\n50,2\n100,1\n", "0.05-100"),
                                        ("50,1\n900,1\n", "50-900")])
def test_a_csv_spectrum_reaching_outside_the_material_data(tmp_path, capsys, rows, span):
    (tmp_path / "spec.csv").write_text("keV,fluence\n" + rows)
    msg = cli_error(tmp_path, capsys, scene_text(source='spectrum = { file = "spec.csv" }',
                                                 body='material = "Water, Liquid"'))
    assert f"spectrum file spec.csv spans {span} keV, outside 0.1-800 keV" in msg, msg


def test_constant_mu_bodies_take_any_positive_energy(tmp_path, capsys):
    """mu does not depend on the energy: the same image at 60 keV, 1e-4 keV and 1e9 keV, and
    from a spectrum reaching past the material tables."""
    ref = cli_render(tmp_path, capsys, scene_text())
    assert ref.min() < 0.5                                 # the ball is in the image
    for energy in (0.0001, 5000.0, 1e9, 1e-300):
        np.testing.assert_array_equal(
            cli_render(tmp_path, capsys, scene_text(source=f"energy = {energy!r}")), ref)
    (tmp_path / "spec.csv").write_text("keV,fluence\n0.05,1\n900,1\n")
    np.testing.assert_allclose(cli_render(tmp_path, capsys, scene_text(
        source='spectrum = { file = "spec.csv" }')), ref, rtol=1e-12)


def test_the_api_refuses_out_of_range_energies_in_one_line():
    from xray_viz.physics.materials import linear_attenuation

    with pytest.raises(MaterialError, match="5000 keV outside 0.1-800 keV"):
        linear_attenuation("Water, Liquid", [60.0, 5000.0])
    sphere = xray_viz.load_scene("sphere")
    water = Body("ball", sphere.bodies[0].mesh, material="Water, Liquid")
    scene = sphere.replace(source=dataclasses.replace(sphere.source, energy=0.05),
                           bodies=(water,))
    with pytest.raises(MaterialError, match="0.05 keV outside 0.1-800 keV") as info:
        xray_viz.render(scene)
    assert "\n" not in str(info.value)
    # the limits themselves are tabulated
    np.testing.assert_array_less(0, linear_attenuation("Water, Liquid", [0.1, 800.0]))


# ------------------------------------------------------------------------------------------
# 5. API values are refused, not coerced


MESH = BALL


@pytest.mark.parametrize("make, match", [
    (lambda: Source([0, 0, 1000], energy="60"), "energy .* must be a number, got '60'"),
    (lambda: Source([0, 0, 1000], energy=True), "energy .* must be a number, got True"),
    (lambda: Source(["0", "0", "1000"]), "position must be 3 numbers"),
    (lambda: Source([True, 0, 1000]), "position must be 3 numbers"),
    (lambda: Source([0, 0]), "position must be 3 numbers"),
    (lambda: Source([0, 0, np.nan]), "position must be finite"),
    (lambda: Source([0, 0, 1000], kind=["point"]), "kind must be"),
    (lambda: Source([0, 0, 1000], spectrum=80), "spectrum must be a table"),
    (lambda: Detector([0, 0, -500], pitch=True), "pitch .* must be a number or 2 numbers"),
    (lambda: Detector([0, 0, -500], pitch="0.5"), "pitch .* must be a number or 2 numbers"),
    (lambda: Detector([0, 0, -500], i0="1e4"), "I0 .* must be a number, got '1e4'"),
    (lambda: Detector([0, 0, -500], shape=(256.5, 256)), "shape must be two integers"),
    (lambda: Detector([0, 0, -500], shape=(256.0, 256)), "shape must be two integers"),
    (lambda: Detector([0, 0, -500], shape=(True, 256)), "shape must be two integers"),
    (lambda: Detector([0, 0, -500], shape=np.array([256.0, 256.0])), "shape must be two"),
    (lambda: Detector([0, 0, -500], shape=(256, 256, 3)), "shape must be two integers"),
    (lambda: Detector([0, 0, -500], noise="no"), "noise must be True or False"),
    (lambda: Detector([0, 0, -500], falloff=1), "falloff must be True or False"),
    (lambda: Detector([0, 0, -500], supersample=2.0), "supersample must be an integer"),
    (lambda: Detector([0, 0, -500], seed="7"), "seed must be an integer"),
    (lambda: Detector([0, 0, -500], focal_spot="0.1"), "focal_spot .* must be a number"),
    (lambda: Detector([0, 0, -500], up=[1e-300, 0, 0]), "up .* has no usable length"),
    (lambda: Body("b", MESH, mu="0.2"), "mu .* must be a number, got '0.2'"),
    (lambda: Body("b", MESH, mu=True), "mu .* must be a number, got True"),
    (lambda: Body("b", MESH, mu=0.2, material="Water, Liquid"), "both 'mu' and 'material'"),
    (lambda: Body("b", MESH, mu=0.2, density=1.0), "'density' with 'mu'"),
    (lambda: Body("b", MESH, material="H2O", density="1"), "density .* must be a number"),
    (lambda: Body("b", MESH, material=["H2O"], density=1.0), "material must be a name"),
    (lambda: Body("", MESH, mu=0.2), "non-empty string"),
    (lambda: Body(None, MESH, mu=0.2), "non-empty string"),
    (lambda: Body("a\nb", MESH, mu=0.2), "control character"),
    (lambda: Body("b", None, mu=0.2), "must be a triangle mesh"),
])
def test_bad_api_values_are_refused_not_coerced(make, match):
    with pytest.raises(SceneError, match=match) as info:
        make()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("make, match", [
    (lambda: Body("b", MESH, material="Watr"), "body 'b': unknown material 'Watr'"),
    (lambda: Body("b", MESH, material="H2O"), "give its density"),
    (lambda: Body("b", MESH, material={"H2O": "0.5", "Al": 0.5}, density=1.0),
     "mass fraction '0.5'; fractions must be numbers"),
])
def test_bad_materials_are_refused_when_the_body_is_made(make, match):
    with pytest.raises(MaterialError, match=match):
        make()


def test_numpy_numbers_are_still_accepted():
    det = Detector(np.array([0, 0, -500], np.int32), up=np.array([0.0, 1.0, 0.0], np.float32),
                   shape=(np.int32(8), np.int64(4)), pitch=np.float32(0.5), i0=np.float64(10),
                   seed=np.int64(3), supersample=np.int16(2), noise=np.bool_(False),
                   focal_spot=np.int64(0))
    assert det.shape == (8, 4) and type(det.shape[0]) is int
    assert det.pitch == (0.5, 0.5) and det.i0 == 10.0 and det.seed == 3 and det.supersample == 2
    assert Detector([0, 0, -500], shape=np.array([8, 4])).shape == (8, 4)
    assert Detector([0, 0, -500], shape=8).shape == (8, 8)
    src = Source(position=(0, 0, 1000), energy=np.int64(60))
    assert src.energy == 60.0 and src.position.dtype == np.float64
    assert Body("b", MESH, mu=np.float32(0.25)).mu == 0.25
    assert Body("b", MESH, material={"H2O": np.float64(0.5), "Al": 0.5}, density=1.0).density == 1


# trace_rays: shapes, broadcasting, finite and non-zero


def test_trace_rays_refuses_malformed_rays():
    scene = xray_viz.load_scene("sphere")
    o = [0.0, 0.0, 1000.0]
    bad = [
        ((o, [0, 1]), "directions must have shape \\(n, 3\\) or \\(3,\\), got \\(2,\\)"),
        ((o, np.zeros((2, 4))), "directions must have shape"),
        ((np.zeros((2, 2, 3)), [0, 0, -1]), "origins must have shape"),
        ((o, [[0, 0, -1], [0, 0, 0]]), "row 1 is \\[0.0, 0.0, 0.0\\] \\(zero"),
        ((o, [[0, 0, -1e-200]]), "a length whose square float64 cannot hold"),
        ((o, [[0, np.inf, -1]]), "directions must be finite: row 0"),
        (([np.nan, 0, 1000], [0, 0, -1]), "origins must be finite"),
        ((o, [["0", "0", "-1"]]), "must be an \\(n, 3\\) or \\(3,\\) array of numbers"),
        ((o, [[True, False, True]]), "array of numbers"),
        ((o, [[0, 0, -1j]]), "array of numbers"),
        ((np.zeros((2, 3)), np.ones((3, 3))), "same number of rows"),
    ]
    for args, match in bad:
        with pytest.raises(SceneError, match=match):
            trace_rays(scene, *args)
    with pytest.raises(SceneError, match="t_max must not be NaN"):
        trace_rays(scene, o, [0, 0, -1], t_max=np.nan)
    with pytest.raises(SceneError, match="one number per ray"):
        trace_rays(scene, o, [[0, 0, -1]] * 3, t_min=[0.0, 1.0])
    with pytest.raises(SceneError, match="axis must be one non-zero"):
        trace_rays(scene, o, [0, 0, -1], axis=[0, 0, 0])


def test_trace_rays_broadcasts_one_origin_or_one_direction():
    scene = xray_viz.load_scene("sphere")
    o = np.array([0.0, 0.0, 1000.0])
    d = np.array([[0.0, 0.0, -1.0], [0.01, 0.0, -1.0], [0.0, 0.02, -1.0]])
    full = trace_rays(scene, np.tile(o, (3, 1)), d)
    one_origin = trace_rays(scene, o, d)
    for field in ("ray", "t", "point", "triangle", "body", "entering"):
        np.testing.assert_array_equal(getattr(one_origin, field), getattr(full, field))
    # parallel rays: many origins, one direction
    origins = np.array([[0.0, 0.0, 1000.0], [10.0, 0.0, 1000.0], [0.0, 100.0, 1000.0]])
    par = trace_rays(scene, origins, [0.0, 0.0, -1.0])
    each = [trace_rays(scene, origins[k], [[0.0, 0.0, -1.0]]) for k in range(3)]
    assert [len(par.for_ray(k)) for k in range(3)] == [len(h) for h in each] == [2, 2, 0]
    for k in range(2):
        np.testing.assert_array_equal(par.for_ray(k).t, each[k].t)
    # the ball's radius 40: the axis ray crosses 80 mm of it (to the mesh's facets)
    assert each[0].t[1] - each[0].t[0] == pytest.approx(80.0, rel=2e-3)
    assert len(trace_rays(scene, o, np.zeros((0, 3)))) == 0


# ------------------------------------------------------------------------------------------
# hostile values through the command line


@pytest.mark.parametrize("part, value, shown", [
    ("source", "position = [nan, 0.0, 1000.0]\nenergy = 60.0", "[source] position must be finite"),
    ("source", "position = [0.0, 0.0, inf]\nenergy = 60.0", "[source] position must be finite"),
    ("source", "position = [0.0, 0.0, 1e300]\nenergy = 60.0", "coordinates must be within 1e+09"),
    ("detector", "pitch = nan", "pitch must be finite"),
    ("detector", "pitch = -0.0", "pitch must be > 0"),
    ("detector", "pitch = " + "1" * 400, "pitch must be finite"),
    ("detector", "pitch = 4.0\nup = [0.0, -inf, 0.0]", "[detector] up must be finite"),
    ("detector", "pitch = 4.0\nup = [1e-300, 0.0, 0.0]", "up [1e-300, 0.0, 0.0] has no usable"),
    ("detector", "pitch = 4.0\nfocal_spot = 1e300", "focal_spot"),
    ("detector", 'pitch = 4.0\nresponse = "' + "x" * 5000 + '"', "... (5000 characters)"),
    ("source", "energy = -0.0", "[source] energy must be > 0"),
    ("source", "energy = " + "1" * 400, "energy must be finite"),
    ("body", 'name = ""\nmu = 0.2', "non-empty string"),
    ("body", 'name = "a\\nb"\nmu = 0.2', "control character"),
    ("body", 'name = "' + "n" * 300 + '"\nmu = 0.2', "longer than 256 characters"),
    ("body", 'mu = 0.2\nmesh = " "', "mesh must name a mesh file"),
    ("body", 'material = ""', "unknown material ''"),
    ("body", 'material = { H2O = "0.5", Al = 0.5 }\ndensity = 1.0', "fractions must be numbers"),
    ("body", 'material = "H2O"\ndensity = true', "density must be a number"),
    ("body", 'mu = 0.2\nunits = ""', "units must be one of"),
])
def test_hostile_values_through_the_command_line(tmp_path, capsys, part, value, shown):
    text = scene_text(**{part: value})
    msg = cli_error(tmp_path, capsys, text)
    assert shown in msg, msg


def test_shapes_beyond_int64_are_one_line_errors(tmp_path, capsys):
    text = scene_text().replace("shape = [16, 16]", "shape = [" + "9" * 30 + ", 16]")
    assert "shape must be integers below 2**63" in cli_error(tmp_path, capsys, text)


def test_hostile_but_valid_values_render(tmp_path, capsys):
    """A unicode name, a density of 1e-300 (nothing attenuates), I0 = 1e300 with and without
    noise, mu = -0.0 and a huge integer energy for a constant-mu body all render, with the
    expected values."""
    ref = cli_render(tmp_path, capsys, scene_text())
    img = cli_render(tmp_path, capsys, scene_text(body='name = "Knochen ü 骨 🦴"\nmu = 0.2'))
    np.testing.assert_array_equal(img, ref)
    img = cli_render(tmp_path, capsys, scene_text(body='material = "H2O"\ndensity = 1e-300'))
    np.testing.assert_allclose(img, 1.0, rtol=1e-12)
    img = cli_render(tmp_path, capsys, scene_text(detector="pitch = 4.0\nI0 = 1e300"))
    np.testing.assert_allclose(img, 1e300 * ref, rtol=1e-12)
    img = cli_render(tmp_path, capsys, scene_text(source="energy = " + "1" * 60))
    np.testing.assert_array_equal(img, ref)
    img = cli_render(tmp_path, capsys, scene_text(body="mu = -0.0"))
    np.testing.assert_array_equal(img, 1.0)
    img = cli_render(tmp_path, capsys, scene_text(detector="pitch = 4.0\nI0 = 1e300\n"
                                                           "noise = true\nseed = 1"))
    np.testing.assert_allclose(img, 1e300 * ref, rtol=1e-9)   # noise: 1e-150 relative


def test_no_bad_value_reaches_the_user_as_a_traceback():
    """Every error above is an XrayVizError (the CLI's one-line errors) and a ValueError."""
    for exc in (SceneError, MaterialError):
        assert issubclass(exc, XrayVizError) and issubclass(exc, ValueError)


def test_scene_checks_still_run_after_the_dataclass_checks():
    sphere = xray_viz.load_scene("sphere")
    with pytest.raises(SceneError, match="inside body"):
        Scene(Source([0, 0, 0]), sphere.detector, sphere.bodies)


# ------------------------------------------------------------------------------------------
# 4. the viewer: mixtures and Spectrum sources


def test_show_of_a_phantom_with_mixture_materials(tmp_path, capsys):
    """``xray-viz show shepp_logan`` crashed on the iodine-blood mixtures' legend label."""
    pytest.importorskip("pyvista")
    from PIL import Image

    from xray_viz.viz.scene_view import material_label

    out = tmp_path / "shepp.png"
    rc = main(["show", "shepp_logan", "--screenshot", str(out), "--resolution", "32",
               "--size", "1000", "500"])
    captured = capsys.readouterr()
    assert rc == 0 and "Traceback" not in captured.err, captured.err
    with Image.open(out) as im:
        assert im.size == (1000, 500)
        pixels = np.asarray(im.convert("L"))
    assert pixels.std() > 10                                # a picture, not a blank window
    labels = {material_label(b) for b in xray_viz.load_scene("shepp_logan").bodies}
    assert "99% Blood (ICRP) + 1% I, 1.07 g/cm3" in labels
    assert "99.5% Blood (ICRP) + 0.5% I, 1.065 g/cm3" in labels
    assert "Bone, Cortical (ICRP)" in labels


def test_viewer_of_a_source_with_a_spectrum_object(tmp_path):
    pytest.importorskip("pyvista")
    from xray_viz.physics.spectra import Spectrum
    from xray_viz.viz import Viewer

    sphere = xray_viz.load_scene("sphere")
    water = Body("ball", sphere.bodies[0].mesh, material="Water, Liquid")
    spectrum = Spectrum(np.array([40.0, 60.0, 80.0]), np.array([1.0, 2.0, 1.0]))
    scene = sphere.replace(source=Source(sphere.source.position, spectrum=spectrum),
                           bodies=(water,))
    vw = Viewer(scene, resolution=32, off_screen=True, window_size=(1000, 500))
    try:
        # the preview is the API's radiograph of the same (smaller) scene
        np.testing.assert_allclose(vw.radiograph.intensity,
                                   xray_viz.render(vw.scene).intensity, rtol=1e-12)
        assert vw.radiograph.intensity.min() < 0.5
        # no energy or kVp control for a fixed spectrum; the status names it
        assert "energy" not in vw.sliders and "kvp" not in vw.sliders
        assert "spectrum, mean 60 keV" in vw.view.status
        with pytest.raises(ValueError, match="has a spectrum"):
            vw.set_energy(70.0)
        prof = vw.pick_pixel(16, 16)
        assert 40.0 < prof.energy < 80.0                    # the effective energy
        vw.set_source_distance(1200.0)
        assert vw.scene.source.spectrum is spectrum
        assert vw.screenshot(tmp_path / "spectrum.png").stat().st_size > 10_000
    finally:
        vw.close()

