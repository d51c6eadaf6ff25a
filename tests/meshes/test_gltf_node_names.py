"""glTF node names with ``/`` (``Armature/Bone``, as Blender writes them) or ``#`` (issue 42):
``FILE#NODE`` is split on the first ``#`` after an existing glTF/GLB file, so these were
"mesh file not found" and now load, in a ``[[body]]`` table, by expansion of a whole model
(one body per node) and when a scene is written back to TOML."""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

NODES = {"Armature/Bone": [0.0, 0.0, 0.0], "part#2": [30.0, 0.0, 0.0],
         "a/b#c/d": [-30.0, 0.0, 0.0]}


@pytest.fixture
def rig(tmp_path):
    folder = tmp_path / "models #1"                    # a '#' in a folder's name too
    folder.mkdir()
    s = trimesh.Scene()
    for node, at in NODES.items():
        s.add_geometry(trimesh.creation.box(extents=[10, 10, 10]), node_name=node,
                       transform=trimesh.transformations.translation_matrix(at))
    path = folder / "rig.glb"
    s.export(path)
    return path


def test_load_mesh_node_with_slash_and_hash(rig):
    from xray_viz.meshes.io import load_mesh, scene_nodes

    assert sorted(scene_nodes(rig)) == sorted(NODES)
    for node, at in NODES.items():
        mesh = load_mesh(f"{rig}#{node}")
        np.testing.assert_allclose(mesh.bounds.mean(axis=0), at, atol=1e-9)


def test_scene_bodies_from_nodes(rig, tmp_path):
    from xray_viz.scene import load_scene

    head = ('[source]\nposition = [0.0, 0.0, 1000.0]\nenergy = 60.0\n[detector]\n'
            'center = [0.0, 0.0, -500.0]\nshape = [16, 16]\npitch = [8.0, 8.0]\n')
    one = tmp_path / "one.toml"
    rel = rig.relative_to(tmp_path).as_posix()
    one.write_text(head + f'[[body]]\nname = "bone"\nmesh = "{rel}#Armature/Bone"\nmu = 0.2\n')
    scene = load_scene(one)
    np.testing.assert_allclose(scene.bodies[0].mesh.bounds.mean(axis=0), [0, 0, 0], atol=1e-9)
    every = tmp_path / "every.toml"
    every.write_text(head + f'[[body]]\nname = "rig"\nmesh = "{rel}"\nmu = 0.2\n')
    scene = load_scene(every)
    assert sorted(b.name for b in scene.bodies) == sorted(f"rig/{n}" for n in NODES)
    for body in scene.bodies:
        node = body.name.removeprefix("rig/")
        np.testing.assert_allclose(body.mesh.bounds.mean(axis=0), NODES[node], atol=1e-9)
    again = tmp_path / "again.toml"                   # written back and read again
    again.write_text(scene.to_toml(base=tmp_path))
    assert sorted(b.name for b in load_scene(again).bodies) == sorted(b.name for b in
                                                                     scene.bodies)


def test_missing_node_still_named(rig):
    from xray_viz.errors import MeshError
    from xray_viz.meshes.io import load_mesh

    with pytest.raises(MeshError, match="has no mesh node 'Armature/Nope'"):
        load_mesh(f"{rig}#Armature/Nope")
