"""The 3-vector check (xray_viz._checks), written once: each caller's name and error class."""

from __future__ import annotations

import numpy as np
import pytest

import xray_viz
from xray_viz._checks import vector3
from xray_viz.errors import SceneError
from xray_viz.orbit import Orbit, check_pose
from xray_viz.reconstruct import ReconstructionError, rtk_frame

BAD = [[0, 1], [0, 1, 2, 3], [0, np.nan, 1], [0, np.inf, 1], [0, True, 1], "abc", None,
       np.array([True, False, True]), [0, 1e400, 0]]


@pytest.mark.parametrize("value", BAD)
def test_a_bad_vector_is_refused_naming_it(value):
    with pytest.raises(SceneError, match=r"^\[scan\] axis must be 3 finite numbers; got "):
        vector3(value, "[scan] axis")


def test_a_good_vector_and_a_direction():
    assert vector3((1, 2, 3), "x").tolist() == [1.0, 2.0, 3.0]
    assert vector3(np.array([0, 0, 2]), "x", unit=True).tolist() == [0.0, 0.0, 1.0]
    assert vector3([0, 0, 0], "x").tolist() == [0.0, 0.0, 0.0]           # a point may be 0
    with pytest.raises(ValueError, match="^d must be 3 finite numbers, not all 0; got"):
        vector3([0, 0, 0], "d", direction=True, error=ValueError)


def test_each_caller_names_its_value():
    with pytest.raises(SceneError, match=r"^\[scan\] center must be 3 finite numbers; got"):
        Orbit(projections=2, axis=[0, 1, 0], center=[0, True, 0])
    acq = xray_viz.load_scene("sphere").acquisition
    with pytest.raises(SceneError, match="^rotation axis must be 3 finite numbers, not all 0"):
        acq.rotated(10.0, axis=[0, 0, 0])
    pose = {"source": [0, 0, 1000], "detector_center": [0, 0, "x"], "u": [1, 0, 0],
            "v": [0, 1, 0]}
    with pytest.raises(SceneError, match="^pose 3: detector_center must be 3 finite numbers"):
        check_pose(pose, where="pose 3: ")
    with pytest.raises(ReconstructionError, match="^geometry axis must be 3 finite numbers, "
                                                  "not all 0; got"):
        rtk_frame({"axis": [0, 0, 0]})
    with pytest.raises(ReconstructionError,
                       match=r"^geometry center must be 3 finite numbers \(mm\); got"):
        rtk_frame({"axis": [0, 0, 1], "center": [0, np.nan, 0]})


def test_the_scenes_rule_is_the_same_check_with_its_limits():
    """scene._vec3 is vector3(strict=True) with the scene's limits: the limits are parameters
    (another limit moves the boundary), the result a read-only copy without -0.0."""
    from xray_viz.scene import COORDINATE_LIMIT, DIRECTION_LENGTH, Detector, Source

    v = vector3([-0.0, 1, 2], "p", strict=True, limit=COORDINATE_LIMIT)
    assert v.tolist() == [0.0, 1.0, 2.0] and not np.signbit(v).any() and not v.flags.writeable
    assert vector3([10.0, 0, 0], "p", strict=True, limit=10.0).tolist() == [10.0, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"^p \[10.5, 0.0, 0.0\] is 10.5 mm from the origin: "
                                         r"coordinates must be within 10 mm \(1e-05 km\)"):
        vector3([10.5, 0, 0], "p", strict=True, limit=10.0, error=ValueError)
    with pytest.raises(SceneError, match=r"must be within 1e\+09 mm \(1000 km\)"):
        Source([0, 0, 2 * COORDINATE_LIMIT])
    for bad in ([1e-3, 0, 0], [1e3, 0, 0]):
        with pytest.raises(SceneError, match="^d .* has no usable length"):
            vector3(bad, "d", strict=True, length=(1e-2, 1e2))
    assert vector3([0, 0, 0], "d", strict=True, length=DIRECTION_LENGTH).tolist() == [0, 0, 0]
    with pytest.raises(SceneError, match="^up .* has no usable length"):
        vector3([DIRECTION_LENGTH[1], 0, 0], "up", strict=True, length=DIRECTION_LENGTH)
    # the strict rule refuses what the loose one takes (a string of digits), in its own words
    assert vector3(np.array([1, 2, 3], np.int64), "p").tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(SceneError, match=r"^p must be 3 numbers \(x, y, z in mm\), got "):
        vector3((1, 2, np.int64(3) + 0j), "p", strict=True)
    with pytest.raises(SceneError, match=r"^p must be finite, got \[0.0, 0.0, nan\]"):
        vector3([0.0, 0.0, np.nan], "p", strict=True)
    with pytest.raises(SceneError, match=r"^\[detector\] up must be finite"):
        Detector([0, 0, -500], up=[0, np.inf, 0])
    with pytest.raises(TypeError, match="strict takes no direction"):
        vector3([0, 0, 1], "d", strict=True, direction=True)
