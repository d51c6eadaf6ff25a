"""The load-time mesh checks' edge facts (one sort of the edges) and volume agree exactly with
trimesh's own answers (group_rows, is_watertight, is_winding_consistent, the components of
face_adjacency, mass_properties' volume), an independent implementation."""

import numpy as np
import pytest
import trimesh

from xray_viz.meshes import repair as R


def _cases():
    box = trimesh.creation.box(extents=[2, 3, 4])
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    flipped = box.faces.copy()
    flipped[0] = flipped[0][::-1]
    bad_winding = trimesh.Trimesh(box.vertices, flipped, process=False)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=5)
    two = trimesh.util.concatenate([box, ball.copy().apply_translation([20, 0, 0])])
    # a non-manifold edge: two boxes sharing one edge (used by four faces)
    other = box.copy().apply_translation([2, 3, 0])
    pinched = trimesh.util.concatenate([box, other])
    pinched.merge_vertices()
    return {"box": box, "open": open_box, "winding": bad_winding, "ball": ball, "two": two,
            "pinched": pinched}


@pytest.mark.parametrize("name", list(_cases()))
def test_edge_facts_and_volume_equal_trimesh(name):
    m = _cases()[name]
    m = trimesh.Trimesh(m.vertices, m.faces, process=False)
    f = np.asarray(m.faces, np.int64)
    boundary, watertight, winding, labels, n = R._edge_facts(f, len(m.vertices))
    edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    assert boundary == len(trimesh.grouping.group_rows(edges, require_count=1))
    assert watertight == bool(m.is_watertight)
    assert winding == bool(m.is_winding_consistent)
    ref = trimesh.graph.connected_component_labels(m.face_adjacency, node_count=len(f))
    assert n == int(ref.max()) + 1
    np.testing.assert_array_equal(labels, ref)
    assert R._volume(np.asarray(m.vertices, float), f) == float(m.volume)


def test_the_cases_cover_each_answer():
    facts = {k: R._edge_facts(np.asarray(m.faces, np.int64), len(m.vertices))
             for k, m in _cases().items()}
    assert facts["open"][0] > 0 and not facts["open"][1]
    assert facts["box"][1] and facts["box"][2] and not facts["winding"][2]
    assert facts["two"][4] == 2


@pytest.mark.parametrize("name", list(_cases()) + ["soup", "noisy", "collapsed"])
def test_compiled_edge_facts_equal_the_numpy_ones(name, monkeypatch):
    """The compiled edge facts (:mod:`xray_viz.meshes._check_kernels`) are the NumPy ones
    (checked against trimesh above), labels included, also on a soup with repeated corners
    and non-manifold edges."""
    from xray_viz.meshes import _check_kernels as K

    rng = np.random.default_rng(7)
    if name == "soup":
        f, nv = rng.integers(0, 40, size=(300, 3)), 40
    elif name == "collapsed":
        # a closed box and two faces with a repeated corner: their edge from vertex 8 to
        # itself is used twice, and ends where it starts whichever use comes first
        box = trimesh.creation.box()
        f = np.vstack([box.faces, [[8, 8, 9], [8, 8, 10]]])
        nv = 11
    elif name == "noisy":
        ball = trimesh.creation.icosphere(subdivisions=3)
        f = ball.faces[rng.permutation(len(ball.faces))[:1200]]
        nv = len(ball.vertices)
    else:
        m = _cases()[name]
        f, nv = np.asarray(m.faces, np.int64), len(m.vertices)
    compiled = K.edge_facts(f, nv)
    monkeypatch.setattr(K, "is_ready", lambda: False)
    numpy = R._edge_facts(np.asarray(f, np.int64), nv)
    assert compiled[:3] == numpy[:3] and compiled[4] == numpy[4]
    np.testing.assert_array_equal(compiled[3], numpy[3])
    if name == "collapsed":
        assert compiled[2]            # the winding is consistent


@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_volume_is_trimesh_s_float(seed, monkeypatch):
    """The compiled volume (one pass, ``np.sum`` of the same terms) is the NumPy spelling's
    float and trimesh's, bit for bit: on noisy and shifted spheres of 1280-81920 faces, where
    a fused multiply-add or another summation order would change the last bits."""
    from xray_viz.meshes import _check_kernels as K

    K.compile_kernels()
    rng = np.random.default_rng(seed)
    ball = trimesh.creation.icosphere(subdivisions=3 + seed, radius=10.0 * (seed + 1))
    v = ball.vertices * rng.uniform(0.5, 2.0, 3) + rng.normal(scale=0.05,
                                                              size=ball.vertices.shape)
    v += rng.uniform(-100, 100, 3)
    m = trimesh.Trimesh(v, ball.faces, process=False)
    f = np.asarray(m.faces, np.int64)
    compiled = R._volume(v, f)
    assert compiled == K.volume(v, f) == float(m.volume)
    monkeypatch.setattr(K, "is_ready", lambda: False)
    assert R._volume(v, f) == compiled
