"""gVirtualXray JSON scenes: loaded directly, converted to TOML, and one-line errors for what
has no equivalent (xray_viz.meshes.gvxr)."""

from __future__ import annotations

import json
import re
import tomllib

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import xray_viz
from xray_viz import cli
from xray_viz.errors import SceneError
from xray_viz.meshes import gvxr as G
from helpers import doctest_examples


def write_meshes(folder):
    folder.mkdir(exist_ok=True)
    trimesh.creation.icosphere(subdivisions=3, radius=2.0).export(folder / "ball.stl")
    trimesh.creation.box(extents=[30.0, 20.0, 10.0]).export(folder / "plate.stl")


def gvxr_doc(**changes):
    doc = {
        "WindowSize": [500, 500],
        "Source": {"Position": [0, 0, 100, "cm"], "Shape": "PointSource",
                   "Beam": [{"Energy": 60, "Unit": "keV", "PhotonCount": 1000}]},
        "Detector": {"Position": [0, 0, -20, "cm"], "UpVector": [0, 1, 0],
                     "NumberOfPixels": [64, 48], "Spacing": [0.5, 0.5, "mm"]},
        "Samples": [
            {"Label": "plate", "Path": "meshes/plate.stl", "Unit": "mm",
             "Material": ["Element", "Al"]},
            {"Label": "ball", "Path": "meshes/ball.stl", "Unit": "cm",
             "Material": ["Mixture", "Ti90Al6V4"], "Density": 4.43,
             "Transform": [["Translation", 5, 0, 0, "mm"], ["Rotation", 90, 0, 0, 1]]},
            {"Label": "water", "Path": "meshes/ball.stl", "Unit": "mm",
             "Material": ["Compound", "H2O"], "Density": 1.0,
             "Transform": [["Scaling", 1.0, 2.0, 1.0], ["Translation", 0, 0, 20, "mm"]]},
        ],
    }
    for key, value in changes.items():
        section, _, sub = key.partition("__")
        if sub:
            doc[section][sub] = value
        else:
            doc[section] = value
    return doc


def write_json(tmp_path, doc, name="scene.json"):
    write_meshes(tmp_path / "meshes")
    p = tmp_path / name
    p.write_text(json.dumps(doc, indent=2))
    return p


def test_json_scene_loads_with_units_materials_and_transforms(tmp_path):
    scene = xray_viz.load_scene(write_json(tmp_path, gvxr_doc()))
    assert scene.source.position.tolist() == [0.0, 0.0, 1000.0]     # cm -> mm
    assert scene.detector.center.tolist() == [0.0, 0.0, -200.0]
    assert scene.detector.shape == (64, 48) and scene.detector.pitch == (0.5, 0.5)
    assert scene.source.energy == 60.0 and scene.detector.i0 == 1000.0
    plate, ball, water = scene.bodies
    assert plate.material == "Al" and plate.density == pytest.approx(2.699, rel=1e-3)
    assert ball.material == pytest.approx({"Ti": 0.9, "Al": 0.06, "V": 0.04})
    assert (water.material, water.density) == ("H2O", 1.0)
    # gVXR's node matrix: each transform right-multiplies, so the last one acts first on
    # the vertices (rotate about z, then translate); the unit scales the mesh file itself
    raw = trimesh.load(tmp_path / "meshes" / "ball.stl")
    r = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()
    expected = (raw.vertices * 10.0) @ r.T + [5.0, 0, 0]
    assert np.allclose(np.sort(ball.vertices, axis=0), np.sort(expected, axis=0), atol=1e-9)
    # scaling then translation listed: the translation acts first, then the scaling
    expected = (raw.vertices + [0, 0, 20.0]) * [1.0, 2.0, 1.0]
    assert np.allclose(np.sort(water.vertices, axis=0), np.sort(expected, axis=0), atol=1e-9)


def test_tube_beam_and_detector_size(tmp_path):
    doc = gvxr_doc(Source__Beam={"kvp": 80, "tube angle": 10, "mAs": 2.0,
                                 "filter": [["Al", 2.5], [29, 100, "um"]]},
                   Source__Shape="ParallelBeam",
                   Detector__Size=[32.0, 24.0, "mm"], Detector__Oversampling=2)
    del doc["Detector"]["Spacing"]
    d = G.gvxr_to_dict(doc, base_dir=tmp_path)
    assert d["source"]["spectrum"] == {"kvp": 80.0, "anode_angle": 10.0,
                                       "filters": {"Al": 2.5, "Cu": 0.1}}
    assert d["source"]["mas"] == 2.0 and d["source"]["kind"] == "parallel"
    assert d["detector"]["pitch"] == 0.5                 # gVXR: size / pixels
    assert d["detector"]["supersample"] == 2


def test_render_json_equals_render_of_the_converted_toml(tmp_path, capsys):
    src = write_json(tmp_path, gvxr_doc())
    (tmp_path / "out").mkdir()
    dst = tmp_path / "out" / "scene.toml"
    assert cli.main(["convert", str(src), "-o", str(dst)]) == 0
    assert "wrote" in capsys.readouterr().out
    text = dst.read_text()
    doc = tomllib.loads(text)
    assert doc["body"][0]["mesh"] == "../meshes/plate.stl"   # relative to OUT's folder
    a = xray_viz.render(xray_viz.load_scene(src), engine="numpy")
    b = xray_viz.render(xray_viz.load_scene(dst), engine="numpy")
    assert np.array_equal(a.intensity, b.intensity)
    assert a.intensity.min() < 0.9 * a.intensity.max()        # the bodies are in the image
    # and the CLI renders the JSON directly
    assert cli.main(["render", str(src), "-o", str(tmp_path / "img.npy")]) == 0
    assert np.allclose(np.load(tmp_path / "img.npy"), a.intensity, rtol=1e-6)  # fast engine


def test_json_where_toml_is_expected_is_named(tmp_path, capsys):
    p = write_json(tmp_path, gvxr_doc(), name="scene.toml")
    with pytest.raises(SceneError, match=r"is a JSON file \(a gVirtualXray scene\), not TOML"):
        xray_viz.load_scene(p)
    rc = cli.main(["render", str(p), "-o", str(tmp_path / "x.npy")])
    err = capsys.readouterr().err
    assert rc == 2 and "malformed TOML" not in err and "xray-viz convert" in err
    q = tmp_path / "other.toml"
    q.write_text('{"a": 1}')
    with pytest.raises(SceneError, match="is a JSON file, not TOML"):
        xray_viz.load_scene(q)


def test_focal_spot_and_scan_warn(tmp_path):
    doc = gvxr_doc(Source__Shape=["FocalSpot", 0.4, "mm", 5],
                   Scan={"NumberOfProjections": 10, "FinalAngle": 360})
    with pytest.warns(G.GvxrWarning) as record:
        d = G.gvxr_to_dict(doc)
    assert d["detector"]["focal_spot"] == 0.4
    messages = " | ".join(str(w.message) for w in record)
    assert "Gaussian" in messages and "Scan" not in messages        # the Scan is a scan now
    assert d["scan"]["projections"] == 10


@pytest.mark.parametrize("change, expect", [
    (dict(Samples=[{"Label": "c", "Cylinder": [2, 10, 2, "mm"],
                    "Material": ["Element", "Fe"]}]),
     r"Samples #1 \('c'\) Cylinder: the number of sectors must be a whole number from 3"),
    (dict(Samples=[{"Label": "c", "Cuboid": [10, 0, 2, "mm"], "Material": ["Element", "Fe"]}]),
     r"Samples #1 \('c'\) Cuboid: lengths must be > 0, got 10, 0, 2 mm"),
    (dict(Samples=[{"Label": "c", "Cuboid": [10, 2, "mm"], "Material": ["Element", "Fe"]}]),
     r"Cuboid: must be \[x, y, z, \"unit\"\]"),
    (dict(Samples=[{"Label": "c", "Cube": [1, "cm"], "Path": "meshes/ball.stl",
                    "Material": ["Element", "Fe"]}]),
     r"gives Cube and Path: give one shape"),
    (dict(Samples=[{"Label": "b", "Path": "meshes/ball.stl", "Material": ["HU", "bone"]}]),
     r"Samples #1 \('b'\) Material"),
    (dict(Samples=[{"Label": "w", "Step Wedge": {}, "Material": ["Element", "Al"]}]),
     r"unknown key 'Step Wedge'"),
    (dict(Source__Beam=[{"Energy": 40, "Unit": "keV", "PhotonCount": 1},
                        {"Energy": 60, "Unit": "keV", "PhotonCount": 1}]),
     r"Source Beam: a spectrum of 2 lines \(40 to 60 keV\) has no equivalent"),
    (dict(Source__Beam={"TextFile": "spectrum.txt", "Unit": "keV"}),
     r"Source Beam TextFile: a spectrum read from a gVXR text file has no equivalent"),
    (dict(Detector__LSF=[0.1, 0.8, 0.1]), r"Detector LSF: has no equivalent"),
    (dict(Samples=["MoveToCentre"]), r"Samples #1: 'MoveToCentre' has no equivalent"),
    (dict(Detector__RightVector=[-1, 0, 0]), r"Detector RightVector: \[-1.0, 0.0, 0.0\] is not"),
    (dict(Samples=[{"Label": "s", "Path": "meshes/ball.stl", "Material": ["Element", "Fe"],
                    "Transform": [["Rotation", 30, 0, 0, 1], ["Scaling", 1, 2, 1],
                                  ["Rotation", 30, 0, 0, 1]]}]),
     r"Transform: a scaling between rotations shears the mesh"),
    (dict(Source__Colour=[1, 0, 0]), r"Source: unknown key 'Colour'"),
    (dict(Detector__Spacing=[0.5, 0.5, "furlong"]), r"unknown length unit 'furlong'"),
    (dict(Samples=[{"Label": "m", "Path": "meshes/ball.stl", "Material": ["Mixture", "Ti90"]}]),
     r"a mixture needs a 'Density'"),
    (dict(SceneGraph={"Path": "x.dae", "Unit": "mm"}), r"SceneGraph: a gVXR scene graph"),
])
def test_no_equivalent_is_one_line(tmp_path, capsys, change, expect):
    p = write_json(tmp_path, gvxr_doc(**change))
    out = tmp_path / "out.npy"
    rc = cli.main(["render", str(p), "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith("xray-viz: error: "), err
    assert str(p) in err and re.search(expect, err), err
    assert not out.exists()
    rc = cli.main(["convert", str(p), "-o", str(tmp_path / "s.toml")])
    assert rc == 2 and not (tmp_path / "s.toml").exists()
    capsys.readouterr()


def test_malformed_json_is_one_line(tmp_path, capsys):
    p = tmp_path / "bad.json"
    p.write_text('{"Source": {"Position": [0, 0, 1, "m"],,}')
    rc = cli.main(["render", str(p), "-o", str(tmp_path / "o.npy")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "malformed JSON" in err and "line 1" in err


def test_convert_refuses_a_non_toml_output_and_keeps_a_previous_file(tmp_path, capsys):
    src = write_json(tmp_path, gvxr_doc())
    assert cli.main(["convert", str(src), "-o", str(tmp_path / "s.json")]) == 2
    assert "name it .toml" in capsys.readouterr().err
    dst = tmp_path / "s.toml"
    dst.write_text("previous")
    bad = write_json(tmp_path, gvxr_doc(Detector__LSF=[1]), name="bad.json")
    assert cli.main(["convert", str(bad), "-o", str(dst)]) == 2
    assert dst.read_text() == "previous"


def test_to_toml_round_trips_through_tomllib():
    doc = {"source": {"position": [0.0, -1.5, 1e3], "spectrum": {"kvp": 80.0,
                                                               "filters": {"Al": 2.5}}},
           "detector": {"shape": [4, 3], "pitch": [0.1, 0.2], "noise": False},
           "body": [{"name": 'odd "name" é', "mesh": "a b/c.stl",
                     "material": {"Blood (ICRP)": 0.99, "I": 0.01}, "density": 1.07}]}
    assert tomllib.loads(G.to_toml(doc, header="a\nb")) == doc


def test_docstring_examples():
    assert doctest_examples(G) > 0           # pytest runs them (--doctest-modules), once


# --------------------------------------------------------------------------------------------
# other mesh inputs: pyvista and trimesh objects, glTF/GLB scenes of several nodes


def _scene_with(bodies):
    from xray_viz.scene import Detector, Scene, Source

    return Scene(source=Source(position=[0, 0, 500.0], kind="parallel"),
                 detector=Detector(center=[0, 0, -100.0], up=[0, 1, 0], shape=(48, 48),
                                   pitch=0.5),
                 bodies=bodies)


def test_body_accepts_pyvista_datasets_and_trimesh():
    import pyvista as pv

    from xray_viz.scene import Body

    tri = trimesh.creation.icosphere(subdivisions=3, radius=8.0)
    poly = pv.PolyData.from_regular_faces(tri.vertices, tri.faces)
    a = Body(name="a", mesh=tri, mu=0.2)
    b = Body(name="b", mesh=poly, mu=0.2)
    assert isinstance(b.mesh, trimesh.Trimesh) and b.mesh.is_watertight
    ia = xray_viz.render(_scene_with([a]), engine="numpy").quantity("path-length")
    ib = xray_viz.render(_scene_with([b]), engine="numpy").quantity("path-length")
    assert np.allclose(ia, ib, atol=1e-9) and ia.max() > 15
    # any dataset: its outer surface (a 10 mm voxel block; an unstructured grid of it)
    grid = pv.ImageData(dimensions=(11, 11, 11), spacing=(1.0, 1.0, 1.0), origin=(-5, -5, -5))
    for dataset in (grid, grid.cast_to_unstructured_grid()):
        body = Body(name="block", mesh=dataset, mu=0.1)
        assert body.mesh.is_watertight and body.mesh.volume == pytest.approx(1000.0)
        image = xray_viz.render(_scene_with([body]), engine="numpy").quantity("path-length")
        assert image.max() == pytest.approx(10.0)


def write_glb(path):
    s = trimesh.Scene()
    s.add_geometry(trimesh.creation.box(extents=[4, 4, 4]), node_name="cube",
                   transform=trimesh.transformations.translation_matrix([10, 0, 0]))
    s.add_geometry(trimesh.creation.icosphere(radius=3.0), node_name="ball")
    s.add_geometry(trimesh.creation.icosphere(radius=1.0), node_name="pearl",
                   transform=trimesh.transformations.translation_matrix([0, 10, 0]))
    s.export(path)


GLB_SCENE = """
[source]
position = [0.0, 0.0, 500.0]
kind = "parallel"
[detector]
center = [0.0, 0.0, -100.0]
shape = [16, 16]
pitch = 2.0
[[body]]
mesh = "model.glb"
mu = 0.1
{extra}
"""


def test_glb_of_several_nodes_loads_as_several_bodies(tmp_path):
    write_glb(tmp_path / "model.glb")
    (tmp_path / "s.toml").write_text(GLB_SCENE.format(extra=""))
    scene = xray_viz.load_scene(tmp_path / "s.toml")
    assert [b.name for b in scene.bodies] == ["model/ball", "model/cube", "model/pearl"]
    ball, cube, pearl = scene.bodies
    assert np.allclose(cube.mesh.bounds, [[8, -2, -2], [12, 2, 2]])   # its node's transform
    assert np.allclose(pearl.mesh.centroid, [0, 10, 0], atol=0.05)
    # merge = true: one body of all of them; a named node: that one only
    (tmp_path / "s.toml").write_text(GLB_SCENE.format(extra='name = "all"\nmerge = true'))
    (merged,) = xray_viz.load_scene(tmp_path / "s.toml").bodies
    assert merged.name == "all" and len(merged.faces) == sum(len(b.faces) for b in scene.bodies)
    (tmp_path / "s.toml").write_text(GLB_SCENE.format(extra="").replace(
        'mesh = "model.glb"', 'mesh = "model.glb#cube"'))
    (only,) = xray_viz.load_scene(tmp_path / "s.toml").bodies
    assert np.allclose(only.mesh.bounds, cube.mesh.bounds)


def test_glb_errors_are_one_line(tmp_path, capsys):
    write_glb(tmp_path / "model.glb")
    for extra, mesh, expect in [
        ('merge = "yes"', "model.glb", r"\[\[body\]\] #1 merge must be true or false"),
        ("", "model.glb#nope", r"has no mesh node 'nope'; its nodes: ball, cube, pearl"),
    ]:
        (tmp_path / "s.toml").write_text(GLB_SCENE.format(extra=extra).replace(
            'mesh = "model.glb"', f'mesh = "{mesh}"'))
        rc = cli.main(["render", str(tmp_path / "s.toml"), "-o", str(tmp_path / "o.npy")])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and re.search(expect, err), err


# -- a gVXR Scan becomes the scene's orbit ------------------------------------------------------

@pytest.mark.parametrize("scan, angles", [
    ({"NumberOfProjections": 4, "FinalAngle": 360}, [0, 90, 180, 270]),
    # the count is the total; IncludeLastAngle makes the step (360 - 0) / (4 - 1)
    ({"NumberOfProjections": 4, "FinalAngle": 360, "IncludeLastAngle": True}, [0, 120, 240, 360]),
    ({"AngleStep": 45, "FinalAngle": 180, "StartAngle": 0}, [0, 45, 90, 135]),
    ({"AngleStep": 45, "FinalAngle": 180, "IncludeLastAngle": True}, [0, 45, 90, 135, 180]),
    # AngleStep counts the projections (int(100 / 30) = 3); computeCTAcquisition steps 100 / 3
    ({"AngleStep": 30, "FinalAngle": 100}, [0, 100 / 3, 200 / 3]),
    ({"AngleStep": 10, "NumberOfProjections": 3, "FinalAngle": 90}, [0, 30, 60]),
    ({"AngleStep": 30, "NumberOfProjections": 3}, [0, 30, 60]),   # no FinalAngle: AngleStep
    ({"NumberOfProjections": 3, "FinalAngle": 90, "StartAngle": 30}, [30, 50, 70]),
    ({"NumberOfProjections": 4, "FinalAngle": -360, "StartAngle": 10}, [10, -82.5, -175, -267.5]),
    ({"NumberOfProjections": 3, "FinalAngle": 90, "RotationAxis": [1, 0, 0]}, [0, 30, 60]),
    ({"NumberOfProjections": 2, "FinalAngle": 90, "Rotation axis": [0, 0, -2],
      "Flat-Field Correction": True, "NumberOfWhiteImages": 4}, [0, 45]),
])
def test_a_gvxr_scan_becomes_the_orbit_json2gvxr_makes(tmp_path, scan, angles):
    """json2gvxr (gVXR 2.1) hands the Scan to computeCTAcquisition, whose projection k turns
    the samples by StartAngle + k * step about the rotation axis (RotationAxis, else the
    detector's up vector) through the origin, right-handed: in the samples' frame the source
    and detector turn the other way, computed here with scipy's rotations."""
    from xray_viz.scene import scene_from_dict

    up = np.array([0.0, 0.6, 0.8])
    doc = gvxr_doc(Scan=scan, Detector__UpVector=up.tolist())
    axis = scan.get("RotationAxis", scan.get("Rotation axis", up))
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    write_meshes(tmp_path / "meshes")
    d = G.gvxr_to_dict(doc, base_dir=tmp_path)
    scene = scene_from_dict(d, base_dir=tmp_path)
    acquisitions = list(scene.orbit.acquisitions(scene.acquisition))
    assert len(acquisitions) == len(angles)
    source = np.array(scene.source.position, float)
    centre = np.array(scene.detector.center, float)
    for acq, angle in zip(acquisitions, angles):
        turn = Rotation.from_rotvec(-np.radians(angle) * axis)      # the samples' +angle
        np.testing.assert_allclose(acq.frame.source, turn.apply(source), atol=1e-9)
        np.testing.assert_allclose(acq.frame.center, turn.apply(centre), atol=1e-9)


def test_a_gvxr_scan_about_another_centre_is_ignored_with_a_warning(tmp_path):
    doc = gvxr_doc(Scan={"NumberOfProjections": 4, "FinalAngle": 360,
                         "CenterOfRotation": [0, 0, 5, "mm"]})
    with pytest.warns(G.GvxrWarning, match="CenterOfRotation"):
        d = G.gvxr_to_dict(doc)
    assert "scan" not in d


@pytest.mark.parametrize("scan, expect", [
    ({"FinalAngle": 360}, r"Scan: needs FinalAngle and NumberOfProjections or AngleStep"),
    ({"NumberOfProjections": 4, "FinalAngle": 360, "Turns": 2}, r"Scan.*Turns"),
    ({"NumberOfProjections": 2.5, "FinalAngle": 360}, r"NumberOfProjections: must be a whole"),
    ({"NumberOfProjections": 1, "FinalAngle": 360, "IncludeLastAngle": True},
     r"1 projection with IncludeLastAngle; it needs at least two"),
    ({"AngleStep": 30}, r"Scan: needs FinalAngle and NumberOfProjections or AngleStep"),
    ({"AngleStep": 30, "FinalAngle": 20}, r"gives 0 projections"),
    ({"NumberOfProjections": 4, "FinalAngle": 0}, r"a step other than 0"),
    ({"NumberOfProjections": 4, "FinalAngle": 90, "RotationAxis": [0, 0, 0]},
     r"Scan RotationAxis"),
])
def test_a_bad_gvxr_scan_is_one_line(scan, expect):
    with pytest.raises(SceneError, match=expect):
        G.gvxr_to_dict(gvxr_doc(Scan=scan))


def test_a_gvxr_cube_is_a_box_body(tmp_path):
    """gvxr.makeCube(label, size, unit) is a cube of that edge centred on the origin, placed by
    the sample's Transform: a box shape, traced with its exact chord."""
    doc = gvxr_doc(Samples=[{"Label": "c", "Cube": [2, "cm"], "Material": ["mu", 0.5],
                             "Transform": [["Translation", 0, 0, 5, "mm"]]}])
    d = G.gvxr_to_dict(doc)
    assert d["body"] == [{"name": "c", "shape": {"kind": "box", "size": [20.0, 20.0, 20.0]},
                          "mu": 0.5, "position": [0.0, 0.0, 5.0]}]
    p = write_json(tmp_path, doc)
    li = xray_viz.render(xray_viz.load_scene(p)).line_integral
    np.testing.assert_allclose(li[23:25, 31:33], 0.5 * 2.0, rtol=1e-6)   # 20 mm of mu 0.5/cm
    out = tmp_path / "cube.toml"
    assert cli.main(["convert", str(p), "-o", str(out)]) == 0
    assert tomllib.loads(out.read_text())["body"][0]["shape"]["kind"] == "box"


def test_gvxr_cuboid_and_cylinder_are_shape_bodies(tmp_path):
    """gvxr.makeCuboid(label, x, y, z, unit) and gvxr.makeCylinder(label, sectors, height,
    radius, unit), centred on the origin, the cylinder's axis along y: box and cylinder shapes
    with the same extents, placed by the sample's Transform (which acts after the cylinder's own
    turn), and rendered with their exact chords."""
    doc = gvxr_doc(
        Detector__NumberOfPixels=[100, 100], Detector__Spacing=[1.0, 1.0, "mm"],
        Samples=[
            {"Label": "slab", "Cuboid": [1, 2, 3, "cm"], "Material": ["mu", 0.5],
             "Transform": [["Translation", -25, 0, 0, "mm"]]},
            {"Label": "rod", "Cylinder": [256, 4, 1, "cm"], "Material": ["mu", 0.5],
             "Transform": [["Translation", 20, 0, 0, "mm"]]},
            {"Label": "bar", "Parallelepiped": [2, 2, 2, "mm"], "Material": ["mu", 0.5],
             "Transform": [["Translation", 0, 30, 0, "mm"]]},
            {"Label": "pin", "Cylinder": [64, 10, 1, "mm"], "Material": ["mu", 0.5],
             "Transform": [["Translation", 0, -30, 0, "mm"], ["Rotation", 90, 0, 0, 1],
                           ["Scaling", 1, 2, 1]]},
        ])
    d = G.gvxr_to_dict(doc)
    slab, rod, bar, pin = d["body"]
    assert slab["shape"] == {"kind": "box", "size": [10.0, 20.0, 30.0]}
    assert bar["shape"] == {"kind": "box", "size": [2.0, 2.0, 2.0]}
    assert rod["shape"] == {"kind": "cylinder", "radius": 10.0, "height": 40.0, "sections": 256}
    scene = xray_viz.load_scene(write_json(tmp_path, doc))
    bounds = {b.name: np.asarray(b.mesh.bounds) for b in scene.bodies}
    np.testing.assert_allclose(bounds["slab"], [[-30, -10, -15], [-20, 10, 15]], atol=1e-9)
    # the rod stands along y, 40 mm long, 20 mm across in x and z (a 256-gon: within 0.1 %)
    np.testing.assert_allclose(bounds["rod"][:, 1], [-20.0, 20.0], atol=1e-9)
    np.testing.assert_allclose(bounds["rod"][:, [0, 2]], [[10, -10], [30, 10]], rtol=1e-3)
    # the pin: scaled 2x along y (its axis: 20 mm long), turned about z onto x, then moved
    np.testing.assert_allclose(bounds["pin"][:, 0], [-10.0, 10.0], atol=1e-9)
    np.testing.assert_allclose(bounds["pin"][:, 1], [-31.0, -29.0], rtol=1e-2)
    li = xray_viz.render(scene).line_integral
    # the rays from the source at z = 1000 mm to the pixels 1200 mm away: through the slab
    # 30 mm of mu 0.5/cm along z, times the ray's obliquity; through the rod near its axis
    # about its diameter (a 256-gon: 2 r cos(pi/256) to 2 r, times the obliquity)
    x = (np.arange(100) - 49.5) * 1.0                       # pixel centres on the detector, mm
    col = lambda mm: int(np.argmin(abs(x / 1.2 - mm)))       # noqa: E731  (at z = 0)
    row = 50
    oblique = lambda c: np.linalg.norm([x[c], x[row], 1200.0]) / 1200.0   # noqa: E731
    c = col(-25.0)
    assert li[row, c] == pytest.approx(0.5 * 3.0 * oblique(c), rel=1e-9)
    c = col(20.0)
    assert 0.99 * 0.5 * 2.0 * np.cos(np.pi / 256) <= li[row, c] <= 0.5 * 2.0 * oblique(c)
    assert li[row, col(0.0)] == 0.0 and li[col(0.0), col(0.0)] == 0.0       # between them
    out = tmp_path / "shapes.toml"
    assert cli.main(["convert", str(tmp_path / "scene.json"), "-o", str(out)]) == 0
    np.testing.assert_array_equal(xray_viz.render(xray_viz.load_scene(out)).line_integral, li)


def test_gvxr_hounsfield_material_takes_the_ct_tables(tmp_path):
    """["HU", n]: gVXR rounds n and looks it up in Schneider et al.'s tables; here the CT
    voxels' classes and density lines (1 + HU/1000 below 120 HU, Schneider's bone line above),
    a Density replacing the density as gVXR's setDensity does after setHounsfieldValue. The
    render equals xraylib's mass attenuation coefficient times that density times the path."""
    import xraylib

    assert G.hu_material(0) == {"material": "Adipose Tissue (ICRP)", "density": 1.0}
    assert G.hu_material(18.4)["material"] == "Adipose Tissue (ICRP)"       # rounds to 18
    assert G.hu_material(18.6) == {"material": "Tissue, Soft (ICRP)", "density": 1.019}
    assert G.hu_material(-740) == {"material": "Lung (ICRP)", "density": 0.26}
    assert G.hu_material(600) == {"material": "Bone, Cortical (ICRP)",
                                  "density": pytest.approx(1.017 + 0.592e-3 * 600)}
    assert G.hu_material(-1000)["material"] == "Air, Dry (near sea level)"
    doc = gvxr_doc(Samples=[
        {"Label": "bone", "Cuboid": [10, 10, 10, "mm"], "Material": ["HU", 1200.2]},
        {"Label": "dense", "Cuboid": [4, 4, 4, "mm"], "Material": ["HU", 1200], "Density": 1.9,
         "Transform": [["Translation", 0, 0, 30, "mm"]]}])
    bone, dense = G.gvxr_to_dict(doc)["body"]
    assert bone["material"] == dense["material"] == "Bone, Cortical (ICRP)"
    assert bone["density"] == pytest.approx(1.017 + 0.592e-3 * 1200) and dense["density"] == 1.9
    dense_free = gvxr_doc(Samples=[doc["Samples"][0]])
    li = xray_viz.render(xray_viz.load_scene(write_json(tmp_path, dense_free))).line_integral
    mu = xraylib.CS_Total_CP("Bone, Cortical (ICRP)", 60.0) * bone["density"]      # 1/cm
    assert li[23:25, 31:33] == pytest.approx(mu * 1.0, rel=1e-6)                  # 10 mm
