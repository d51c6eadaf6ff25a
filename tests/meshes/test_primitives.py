"""Primitive bodies in scene files: ``[[body]] shape = { kind = ..., ... }`` (box, sphere,
cylinder, cone), traced like mesh files, written back by ``to_toml``."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.scene import scene_from_dict

HEAD = {"source": {"position": [0.0, 0.0, 1000.0], "energy": 60.0},
        "detector": {"center": [0.0, 0.0, -500.0], "up": [0.0, 1.0, 0.0], "shape": [64, 64],
                     "pitch": 0.5}}


def scene_of(*bodies):
    return scene_from_dict({**HEAD, "body": list(bodies)})


@pytest.mark.parametrize("shape, chord", [
    ({"kind": "box", "size": [30.0, 20.0, 12.5]}, 12.5),
    ({"kind": "cylinder", "radius": 6.0, "height": 17.0}, 17.0),     # along z: the beam
])
def test_a_primitive_traces_its_exact_chord(shape, chord):
    scene = scene_of({"name": "p", "shape": shape, "mu": 0.4})
    li = xray_viz.render(scene).line_integral
    # the four central pixels' rays are within 0.25 mm of the axis: chord / cos ~ chord
    np.testing.assert_allclose(li[31:33, 31:33], 0.4 * chord / 10, rtol=1e-6)
    assert li[0, 0] == 0.0


def test_a_sphere_and_a_cone_are_closed_and_placed():
    scene = scene_of({"name": "s", "shape": {"kind": "sphere", "radius": 5.0}, "mu": 0.2,
                      "position": [0.0, 8.0, 0.0]},
                     {"name": "c", "shape": {"kind": "cone", "radius": 4.0, "height": 9.0},
                      "mu": 0.2, "rotation": [90.0, 0.0, 0.0]})
    s, c = scene.bodies
    assert s.mesh.is_watertight and c.mesh.is_watertight
    assert s.mesh.volume == pytest.approx(4 / 3 * np.pi * 125, rel=0.01)   # icosphere
    np.testing.assert_allclose(s.mesh.bounds.mean(axis=0), [0.0, 8.0, 0.0], atol=1e-9)
    # the cone's axis turned from z to -y (90 degrees about x): its height along y
    np.testing.assert_allclose(np.ptp(c.mesh.bounds, axis=0)[1], 9.0, atol=1e-9)


def test_primitives_round_trip_through_to_toml(tmp_path):
    scene = scene_of({"name": "b", "shape": {"kind": "box", "size": [10.0, 10.0, 10.0]},
                      "material": "Al", "density": 2.699, "position": [3.0, 0.0, 0.0]},
                     {"name": "c", "shape": {"kind": "cylinder", "radius": 2.0, "height": 8.0,
                                             "sections": 16}, "mu": 0.3})
    text = scene.to_toml(tmp_path / "prim.toml")
    assert tomllib.loads(text)["body"][1]["shape"] == {"kind": "cylinder", "radius": 2.0,
                                                      "height": 8.0, "sections": 16}
    again = xray_viz.load_scene(tmp_path / "prim.toml")
    assert np.array_equal(xray_viz.render(again).intensity, xray_viz.render(scene).intensity)


@pytest.mark.parametrize("body, expect", [
    ({"name": "x", "shape": {"kind": "box", "size": [1.0, 1.0, 1.0]}, "mesh": "a.stl",
      "mu": 0.1}, "gives both 'mesh' and 'shape'"),
    ({"name": "x", "shape": {"kind": "torus", "radius": 1.0}, "mu": 0.1},
     "shape kind must be one of box, sphere, cylinder, cone"),
    ({"name": "x", "shape": {"kind": "sphere", "radius": -1.0}, "mu": 0.1},
     "shape 'sphere' radius must be a number > 0"),
    ({"name": "x", "shape": {"kind": "cylinder", "radius": 1.0}, "mu": 0.1},
     "shape 'cylinder' needs 'height'"),
    ({"name": "x", "shape": {"kind": "box", "size": [1.0, 1.0, 1.0], "colour": "red"},
      "mu": 0.1}, "unknown key 'colour'"),
])
def test_a_bad_shape_is_one_line_naming_the_key(body, expect):
    with pytest.raises(SceneError, match=expect) as info:
        scene_of(body)
    assert "\n" not in str(info.value) and "[[body]]" in str(info.value)


def test_a_moved_primitive_writes_its_new_placement():
    scene = scene_of({"name": "b", "shape": {"kind": "box", "size": [10.0, 10.0, 10.0]},
                      "mu": 0.3, "position": [3.0, 0.0, 0.0]})
    moved = scene.transform_bodies(np.array([[1, 0, 0, 5.0], [0, 1, 0, 0], [0, 0, 1, 0],
                                             [0, 0, 0, 1]]))
    again = scene_from_dict(tomllib.loads(moved.to_toml()))
    np.testing.assert_allclose(again.bodies[0].mesh.bounds, moved.bodies[0].mesh.bounds,
                               atol=1e-9)
    np.testing.assert_allclose(again.bodies[0].mesh.bounds.mean(axis=0), [8.0, 0.0, 0.0],
                               atol=1e-9)
