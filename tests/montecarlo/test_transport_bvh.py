"""The transport's BVH (xray_viz.montecarlo.geometry.build_bvh): built level by level, every
triangle in exactly one leaf, every box around what it holds, and the transport's numbers
independent of the tree (the same bits with leaves of one or of four triangles)."""

from __future__ import annotations

import numpy as np
import trimesh

import xray_viz
from xray_viz.montecarlo import geometry as G
from xray_viz.scene import Body, Detector, Scene, Source


def _check(bvh, tri):
    n = len(tri)
    leaf = bvh.child[:, 0] < 0
    assert len(bvh.lo) == 2 * np.count_nonzero(leaf) - 1          # a full binary tree
    assert np.all(bvh.count[~leaf] == 0) and np.all(bvh.count[leaf] >= 1)
    held = np.concatenate([np.arange(s, s + c) for s, c in
                           zip(bvh.start[leaf], bvh.count[leaf])])
    assert np.array_equal(np.sort(held), np.arange(n))           # each triangle once
    for k in np.flatnonzero(leaf):
        sl = slice(bvh.start[k], bvh.start[k] + bvh.count[k])
        for v in (bvh.v0, bvh.v1, bvh.v2):
            assert np.all(v[sl] >= bvh.lo[k]) and np.all(v[sl] <= bvh.hi[k])
    inner = np.flatnonzero(~leaf)
    for side in (0, 1):
        c = bvh.child[inner, side]
        assert np.all(bvh.lo[c] >= bvh.lo[inner]) and np.all(bvh.hi[c] <= bvh.hi[inner])
    # the triangles are the input's, reordered
    key = np.sort(np.hstack([bvh.v0, bvh.v1, bvh.v2]).round(12), axis=0)
    assert np.array_equal(key, np.sort(tri.reshape(n, 9).round(12), axis=0))


def test_every_triangle_in_one_leaf_inside_every_box(monkeypatch):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    tri = np.asarray(mesh.triangles)
    for leaf in (1, 3):
        monkeypatch.setattr(G, "LEAF_SIZE", leaf)
        bvh = G.build_bvh(tri, np.zeros(len(tri), int))
        _check(bvh, tri)
        assert bvh.count.max() <= leaf
    one = G.build_bvh(tri[:1], np.zeros(1, int))
    assert one.child.tolist() == [[-1, -1]] and one.count.tolist() == [1]


def test_the_numbers_do_not_depend_on_the_tree(monkeypatch):
    ball = trimesh.creation.icosphere(subdivisions=2, radius=30)
    slab = trimesh.creation.box(extents=[120, 120, 80])
    scene = Scene(source=Source(position=[0, 0, 600], energy=60.0),
                  detector=Detector(center=[0, 0, -400], shape=(8, 8), pitch=(15.0, 15.0)),
                  bodies=(Body(name="bone", mesh=ball, material="Bone, Cortical (ICRP)"),
                          Body(name="water", mesh=slab, material="Water, Liquid")))
    from xray_viz.transport import prepare

    results, nodes = [], []
    for leaf in (1, 4):
        monkeypatch.setattr(G, "LEAF_SIZE", leaf)
        fresh = scene.replace(bodies=[Body(name=b.name, mesh=b.mesh.copy(), material=b.material)
                                      for b in scene.bodies])          # its own BVH
        results.append(xray_viz.transport(fresh, 5000, seed=9))
        nodes.append(len(prepare(fresh, 1)["bvh"].lo))
    assert nodes[0] > 2 * nodes[1]                                  # two other trees
    a, b = results
    assert a.energy == b.energy and a.balance == b.balance
    assert all((a.images[k] == b.images[k]).all() for k in a.images)
