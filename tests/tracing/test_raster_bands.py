"""The banded raster of the fast engine (one kernel for one body by bands and for several
bodies): the winner of a stretch of ray, found from a bit mask of the bodies' ranks, is the
one of the reference rule, and the look-at-each-body fallback (more than 64 ranked bodies)
gives the same path lengths bit for bit."""

import dataclasses

import numpy as np
import pytest

import xray_viz
from xray_viz.tracing import _raster as R, _raster_calls as RC
from xray_viz.tracing import fast
from xray_viz.tracing.reference import numpy_path_lengths


def test_lowest_bit_of_every_single_bit_and_of_mixed_masks():
    for b in range(64):
        one = np.uint64(1) << np.uint64(b)
        assert R._lowest_bit(one) == b
        assert R._lowest_bit(one | (np.uint64(1) << np.uint64(63))) == b


@pytest.mark.parametrize("precedence", [[3, 1, 1, -1, 5], [0, 0, 0], [2, 7, 7, 0, 1, 9]])
def test_ranks_order_bodies_as_the_highest_precedence_then_lowest_index_rule(precedence):
    rank, by_rank = RC.body_ranks(precedence)
    inside_sets = [[0, 1, 2], [1, 2], [3], [0, 3, 4], list(range(len(precedence)))]
    for inside in inside_sets:
        inside = [q for q in inside if q < len(precedence)]
        best, win = -1, -1                       # the rule of the reference sweep
        for q in inside:
            if precedence[q] > best:
                best, win = precedence[q], q
        ranked = [rank[q] for q in inside if rank[q] >= 0]
        got = by_rank[min(ranked)] if ranked else -1
        assert got == win, (precedence, inside)


def test_fallback_for_many_bodies_is_bit_identical_and_agrees_with_numpy(monkeypatch):
    scene = xray_viz.load_scene("nested_spheres")
    det = scene.detector
    small = scene.replace(detector=dataclasses.replace(
        det, shape=(48, 40), pitch=(det.pitch[0] * det.shape[0] / 48,
                                    det.pitch[1] * det.shape[1] / 40)))
    fast_L = fast.trace_once(small)
    ranks = RC.body_ranks

    def padded(precedence):                      # by_rank longer than 65: the loop path
        rank, by_rank = ranks(precedence)
        return rank, np.concatenate([by_rank, np.zeros(70, np.int64)])

    monkeypatch.setattr(RC, "body_ranks", padded)
    np.testing.assert_array_equal(fast.trace_once(small), fast_L)
    ref = numpy_path_lengths(small)[0]
    assert np.abs(fast_L - ref).max() < 1e-9 * max(1.0, ref.max())
    assert (fast_L > 0).sum() > 100
