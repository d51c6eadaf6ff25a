"""The rotations of poses (xray_viz.poses), written once: against scipy's Rotation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from xray_viz.poses import apply_rotations, rotation, rotations


@pytest.mark.parametrize("axis", [[0, 1, 0], [0, 0, 3.0], [1.0, -2.0, 0.5]])
def test_rotation_is_scipys_to_the_last_bits(axis):
    unit = np.asarray(axis, float) / np.linalg.norm(axis)
    degrees = np.linspace(-360.0, 360.0, 49)
    many = rotations(axis, degrees)
    for d, R in zip(degrees, many):
        want = Rotation.from_rotvec(np.radians(d) * unit).as_matrix()
        one = rotation(axis, float(d))
        assert np.abs(one - want).max() < 2e-15
        assert np.abs(R - want).max() < 2e-15
        np.testing.assert_allclose(one @ one.T, np.eye(3), atol=2e-15)
        assert np.linalg.det(one) == pytest.approx(1.0, abs=1e-14)
        assert np.abs(one @ unit - unit).max() < 1e-15               # the axis stays


def test_apply_rotations_is_the_matrix_product():
    rng = np.random.default_rng(5)
    rot = rotations([1.0, 2.0, 3.0], rng.uniform(-180, 180, 17))
    p = rng.normal(size=(17, 3))
    np.testing.assert_allclose(apply_rotations(rot, p), np.einsum("nij,nj->ni", rot, p),
                               rtol=0, atol=1e-14)
    # the same bits in any batch: no BLAS
    assert np.array_equal(apply_rotations(rot[3:4], p[3:4])[0], apply_rotations(rot, p)[3])
