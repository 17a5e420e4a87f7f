"""The association's whole-array box tests agree with the one-box forms they batch."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.tracking.association import _inside, _insides, _iou, _ious


@pytest.mark.parametrize("grow", [0.0, 0.25])
def test_points_in_boxes_match_the_one_point_test(grow: float) -> None:
    rng = np.random.default_rng(3)
    boxes = np.column_stack(
        [rng.integers(0, 300, 12), rng.integers(0, 220, 12), rng.integers(1, 40, (12, 2))]
    ).astype(np.int32)
    # points on the boxes' edges as well as anywhere: the comparisons are inclusive
    corners = boxes[:4, :2] + boxes[:4, 2:] * np.array(
        [[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]
    )
    points = np.vstack([rng.uniform(-5, 325, (30, 2)), corners.astype(np.float64)])
    got = _insides(points, boxes, grow)
    want = np.array([[_inside(p, b, grow) for p in points] for b in boxes])
    assert got.shape == (len(boxes), len(points))
    assert np.array_equal(got, want)


def test_box_overlaps_match_the_one_pair_form() -> None:
    rng = np.random.default_rng(4)
    a = np.column_stack([rng.uniform(0, 60, (5, 2)), rng.uniform(1, 30, (5, 2))])
    b = np.column_stack([rng.uniform(0, 60, (7, 2)), rng.uniform(1, 30, (7, 2))])
    want = np.array([[_iou(p, q) for q in b] for p in a])
    assert np.allclose(_ious(a, b), want, rtol=1e-12, atol=0.0)
