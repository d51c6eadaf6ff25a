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
