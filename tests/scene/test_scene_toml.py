"""Scene.to_dict / Scene.to_toml: the text of a scene file that loads into the same scene."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz import phantoms
from xray_viz.errors import SceneError
from xray_viz.scene import Body, Detector, Scene, Source, load_scene


def _same_images(a, b):
    ra, rb = xray_viz.render(a), xray_viz.render(b)
    assert np.array_equal(ra.intensity, rb.intensity)
    assert np.array_equal(ra.total_path_length, rb.total_path_length)


@pytest.mark.parametrize("name", phantoms.names())
def test_every_phantom_round_trips_bit_for_bit(name, tmp_path):
    scene = load_scene(name)
    elsewhere = tmp_path / "deep" / "folder"
    elsewhere.mkdir(parents=True)
    path = elsewhere / "copy.toml"
    path.write_text(scene.to_toml())                    # absolute paths: loads from anywhere
    again = load_scene(path)
    assert again.to_dict() == scene.to_dict()
    for a, b in zip(scene.bodies, again.bodies):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    small = dict(shape=(48, 40))

    def shrink(s):
        import dataclasses
        return s.replace(detector=dataclasses.replace(s.detector, **small))
    _same_images(shrink(scene), shrink(again))


def test_relative_paths_with_a_base_folder(tmp_path):
    scene = load_scene("nested_spheres")
    text = scene.to_toml(base=tmp_path)
    doc = tomllib.loads(text)
    assert all(not b["mesh"].startswith("/") for b in doc["body"])
    (tmp_path / "scene.toml").write_text(text)
    again = load_scene(tmp_path / "scene.toml")
    assert [b.source_file for b in again.bodies] == [b.source_file for b in scene.bodies]
    # the same text somewhere else does not find the meshes: the paths really are relative
    other = tmp_path / "other"
    other.mkdir()
    (other / "scene.toml").write_text(text)
    with pytest.raises(xray_viz.errors.SceneFileNotFoundError):
        load_scene(other / "scene.toml")


def test_placement_keys_are_written_back(tmp_path):
    mesh = trimesh.creation.box(extents=[2.0, 3.0, 4.0])
    mesh.export(tmp_path / "box.stl")
    (tmp_path / "s.toml").write_text(
        '[source]\nposition = [0.0, 0.0, 1000.0]\nenergy = 70.0\n'
        '[detector]\ncenter = [0.0, 0.0, -500.0]\nshape = [32, 24]\npitch = 2.0\n'
        '[[body]]\nname = "box"\nmesh = "box.stl"\nmu = 0.3\nunits = "cm"\n'
        'rotation = [10.0, 20.0, 30.0]\nposition = [5.0, -4.0, 3.0]\nscale = [1.0, 2.0, 1.5]\n')
    scene = load_scene(tmp_path / "s.toml")
    body = scene.to_dict()["body"][0]
    assert body["units"] == "cm" and body["rotation"] == [10.0, 20.0, 30.0]
    assert body["scale"] == [1.0, 2.0, 1.5] and body["position"] == [5.0, -4.0, 3.0]
    again = scene_from_text(scene.to_toml())
    assert np.array_equal(again.bodies[0].vertices, scene.bodies[0].vertices)
    _same_images(scene, again)


def scene_from_text(text):
    return xray_viz.scene.scene_from_dict(tomllib.loads(text))


def test_moved_bodies_carry_a_composed_placement(tmp_path):
    scene = load_scene("nested_spheres")
    turn = trimesh.transformations.rotation_matrix(np.radians(35.0), [0, 1, 0.5], [3, -2, 1])
    moved = scene.transform_bodies(turn)
    again = scene_from_text(moved.to_toml())
    for a, b in zip(moved.bodies, again.bodies):
        np.testing.assert_allclose(b.vertices, a.vertices, rtol=0, atol=1e-9)
    # a shear has no scene-file keys: refused in one line, not written wrong
    shear = np.eye(4)
    shear[0, 1] = 0.5
    sheared = scene.transform_bodies(shear)
    with pytest.raises(SceneError, match="no mesh file"):
        sheared.to_dict()


def test_what_a_scene_file_cannot_hold_is_refused():
    body = Body(name="ball", mesh=trimesh.creation.icosphere(radius=10.0), mu=0.2)
    scene = Scene(Source(position=[0, 0, 1000.0]), Detector(center=[0, 0, -500.0]), (body,))
    with pytest.raises(SceneError, match="export it"):
        scene.to_toml()
    from xray_viz.physics.spectra import Spectrum

    spectral = Scene(Source(position=[0, 0, 1000.0], energy=None,
                            spectrum=Spectrum.monochromatic(60.0)),
                     Detector(center=[0, 0, -500.0]))
    with pytest.raises(SceneError, match="Spectrum object"):
        spectral.to_dict()


def test_every_key_is_explicit_and_reads_back_the_same_values(tmp_path):
    scene = load_scene("frog")
    doc = scene.to_dict()
    again = scene_from_text(scene.to_toml())
    for key in ("center", "up"):
        assert np.array_equal(getattr(again.detector, key), getattr(scene.detector, key))
    for key in ("shape", "pitch", "response", "i0", "noise", "seed", "falloff", "supersample",
                "focal_spot", "mtf", "scintillator", "electronic_noise", "gain"):
        assert getattr(again.detector, key) == getattr(scene.detector, key), key
    assert again.source.energy == scene.source.energy and doc["source"]["kind"] == "point"
    assert [b.name for b in again.bodies] == [b.name for b in scene.bodies]
    assert [b.material for b in again.bodies] == [b.material for b in scene.bodies]


def test_spectra_exposure_and_detector_physics_round_trip(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    mesh.export(tmp_path / "ball.ply")
    (tmp_path / "spec.csv").write_text("energy_keV,fluence\n40,1.0\n50,2.0\n60,1.5\n")
    (tmp_path / "s.toml").write_text(
        '[source]\nposition = [0.0, 0.0, 1000.0]\nspectrum = { kvp = 80.0, filters = { Al = 2.5 } }\n'
        'mas = 2.0\nheel = "top"\n'
        '[detector]\ncenter = [0.0, 0.0, -500.0]\nshape = [24, 20]\npitch = 3.0\n'
        'response = "counting"\nnoise = true\nseed = 7\nsupersample = 2\nfocal_spot = 0.6\n'
        'mtf = { sigma = 0.4 }\nscintillator = { material = "CsI", thickness = 0.5 }\n'
        'electronic_noise = 2.0\ngain = 1.5\n'
        '[[body]]\nname = "ball"\nmesh = "ball.ply"\nmaterial = "Water, Liquid"\n')
    scene = load_scene(tmp_path / "s.toml")
    again = scene_from_text(scene.to_toml())
    assert again.detector.i0 == scene.detector.i0                    # from mas, both times
    assert again.source.spectrum == scene.source.spectrum and again.source.heel == "top"
    _same_images(scene, again)
    csv = tmp_path / "csv.toml"
    csv.write_text((tmp_path / "s.toml").read_text().replace(
        'spectrum = { kvp = 80.0, filters = { Al = 2.5 } }\nmas = 2.0\nheel = "top"\n',
        'spectrum = { file = "spec.csv" }\n').replace('noise = true', 'I0 = 1000.0\nnoise = true'))
    scene = load_scene(csv)
    text = scene.to_toml(base=tmp_path)
    assert 'file = "spec.csv"' in text
    (tmp_path / "again.toml").write_text(text)
    _same_images(scene, load_scene(tmp_path / "again.toml"))


def test_bodies_made_from_volumes_are_not_written_as_meshes(tmp_path):
    body = Body(name="bone", mesh=trimesh.creation.icosphere(radius=10.0), mu=0.5,
                source_file=tmp_path / "seg.nii.gz")
    scene = Scene(Source(position=[0, 0, 1000.0]), Detector(center=[0, 0, -500.0]), (body,))
    with pytest.raises(SceneError, match="seg.nii.gz, not a mesh file"):
        scene.to_toml()
