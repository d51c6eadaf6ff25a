"""Scene files: the TOML contract and every kind of bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.errors import MeshError, SceneError, SceneFileNotFoundError
from helpers import write_scene

GOOD = """
[source]
position = [0.0, 0.0, 1000.0]
kind = "point"
energy = 60.0

[detector]
center = [0.0, 0.0, -500.0]
up = [0.0, 1.0, 0.0]
shape = [32, 24]
pitch = 2.0

[[body]]
name = "ball"
mesh = "ball.stl"
mu = 0.2
"""


@pytest.fixture
def ball():
    return trimesh.creation.icosphere(subdivisions=2, radius=20.0)


def test_good_scene_loads_with_the_documented_meaning(tmp_path, ball):
    scene = xray_viz.load_scene(write_scene(tmp_path, GOOD, {"ball.stl": ball}))
    assert scene.detector.shape == (32, 24)
    assert scene.detector.pitch == (2.0, 2.0)
    assert scene.detector.size == (62.0, 46.0)
    assert scene.source.kind == "point" and scene.source.energy == 60.0
    assert scene.bodies[0].name == "ball" and scene.bodies[0].mu == 0.2
    assert xray_viz.render(scene).intensity.shape == (24, 32)


def test_size_instead_of_pitch(tmp_path, ball):
    text = GOOD.replace("pitch = 2.0", "size = [62.0, 23.0]")
    scene = xray_viz.load_scene(write_scene(tmp_path, text, {"ball.stl": ball}))
    assert scene.detector.pitch == (2.0, 1.0)


def test_body_transforms(tmp_path, ball):
    text = GOOD.replace('mu = 0.2', 'mu = 0.2\nposition = [5.0, -3.0, 2.0]\nscale = 0.5\n'
                                    'rotation = [0.0, 0.0, 90.0]\nunits = "cm"')
    scene = xray_viz.load_scene(write_scene(tmp_path, text, {"ball.stl": ball}))
    v = scene.bodies[0].vertices
    np.testing.assert_allclose(v.mean(axis=0), [5.0, -3.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(v - [5, -3, 2], axis=1), 20.0 * 0.5 * 10, rtol=1e-6)  # STL: float32


BAD = [
    ("energy = 60.0", "energy = 60.0\nenrgy = 3", "unknown key 'enrgy' (did you mean 'energy'?)"),
    ("pitch = 2.0", "pitch = -1.0", "pitch must be > 0"),
    ("pitch = 2.0", "pitch = 0", "pitch must be > 0"),
    ("shape = [32, 24]", "shape = [0, 24]", "shape must be >= 1"),
    ("shape = [32, 24]", "shape = [32.5, 24]", "shape must be a list of 2 integers"),
    ("shape = [32, 24]", 'shape = "big"', "shape must be a list of 2 integers"),
    ("up = [0.0, 1.0, 0.0]", "up = [0.0, 0.0, 1.0]", "parallel to the beam"),
    ("up = [0.0, 1.0, 0.0]", "up = [0.0, 0.0, 0.0]", "up must be a non-zero vector"),
    ("position = [0.0, 0.0, 1000.0]", "position = [0.0, 1000.0]", "position must be a list of 3"),
    ("position = [0.0, 0.0, 1000.0]", "", "missing the required key 'position'"),
    ("position = [0.0, 0.0, 1000.0]", "position = [0.0, 0.0, 5.0]", "inside body 'ball'"),
    ('kind = "point"', 'kind = "cone"', "kind must be one of"),
    ("mu = 0.2", 'mu = "lots"', "mu must be a number"),
    ("mu = 0.2", "mu = -0.2", "mu must be >= 0"),
    ("mu = 0.2", "", "needs 'mu'"),
    ("pitch = 2.0", "pitch = 2.0\nsize = [3.0, 3.0]", "both 'pitch' and 'size'"),
    ("pitch = 2.0", "", "'pitch'"),
    ('mesh = "ball.stl"', 'mesh = "nope.stl"', "mesh file not found"),
    ("[detector]", "[detectr]", "unknown key 'detectr'"),
    ("energy = 60.0", "energy = -5.0", "energy must be > 0"),
    # the known keys listed are every key the table accepts, not only those the file uses
    ("mu = 0.2", "mu = 0.2\nrotaton = [0, 0, 90]",
     "unknown key 'rotaton' (did you mean 'rotation'?); known keys: density, material, mesh, mu, "
     "name, position, repair, rotation, scale, shape, units"),
    ("pitch = 2.0", "pitch = 2.0\npich = 2.0", "known keys: I0, center, electronic_noise, "
     "falloff, focal_spot, gain, grid, mtf, noise, offset, pitch, response, scintillator, seed, shape, "
     "size, supersample, u, up, v"),
]


@pytest.mark.parametrize("old,new,message", BAD)
def test_bad_scene_files_give_one_line_errors(tmp_path, ball, old, new, message):
    path = write_scene(tmp_path, GOOD.replace(old, new, 1), {"ball.stl": ball})
    with pytest.raises((SceneError, MeshError, SceneFileNotFoundError)) as info:
        xray_viz.load_scene(path)
    text = str(info.value)
    assert message in text
    assert "\n" not in text
    assert str(path) in text or "nope.stl" in text


def test_malformed_toml(tmp_path):
    path = write_scene(tmp_path, "[source\nposition = 1")
    with pytest.raises(SceneError, match="malformed TOML"):
        xray_viz.load_scene(path)


def test_missing_scene_file_names_the_phantoms(tmp_path):
    with pytest.raises(SceneFileNotFoundError, match="no such scene file.*sphere"):
        xray_viz.load_scene(tmp_path / "absent.toml")


@pytest.mark.parametrize("content,message", [
    ("solid x\nendsolid x\n", "empty"),
    ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("v inf 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("this is not a mesh", "empty"),
])
def test_bad_meshes_are_refused(tmp_path, content, message):
    suffix = ".stl" if content.startswith("solid") else ".obj"
    (tmp_path / f"m{suffix}").write_text(content)
    path = write_scene(tmp_path, GOOD.replace("ball.stl", f"m{suffix}"))
    with pytest.raises(MeshError, match=message):
        xray_viz.load_scene(path)


def test_duplicate_body_names(tmp_path, ball):
    text = GOOD + GOOD[GOOD.index("[[body]]"):]
    with pytest.raises(SceneError, match="unique"):
        xray_viz.load_scene(write_scene(tmp_path, text, {"ball.stl": ball}))


def test_parallel_source_plane_cutting_a_body_is_refused(tmp_path, ball):
    text = GOOD.replace('kind = "point"', 'kind = "parallel"').replace(
        "[0.0, 0.0, 1000.0]", "[0.0, 0.0, 10.0]")
    with pytest.raises(SceneError, match="crosses the plane of the parallel-beam source"):
        xray_viz.load_scene(write_scene(tmp_path, text, {"ball.stl": ball}))
