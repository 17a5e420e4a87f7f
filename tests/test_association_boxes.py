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


def test_few_pairs_in_python_floats_are_the_whole_array_forms_to_the_bit() -> None:
    """A pair with one detection and one track takes the distances to segments and the points
    in boxes one at a time in Python floats: the same numbers, bit for bit, as the whole-array
    pass, degenerate segments, edges and non-finite points included."""
    from stereod.tracking import association as a

    rng = np.random.default_rng(11)
    for trial in range(400):
        n, m = int(rng.integers(0, 3)), int(rng.integers(0, 3))
        points = rng.uniform(-50.0, 350.0, (n, 2))
        start = rng.uniform(0.0, 300.0, (m, 2))
        end = start if trial % 5 == 0 else start + rng.normal(0.0, 40.0, (m, 2))
        boxes = np.column_stack([rng.integers(0, 300, (m, 2)), rng.integers(0, 60, (m, 2))]).astype(
            np.int32
        )
        if n and m and trial % 7 == 0:
            points[0] = boxes[0, :2] + boxes[0, 2:]  # on the far corner: inclusive
        if n and trial % 11 == 0:
            points[0, 1] = np.nan
        few = a._to_segments_few(points, start, end)
        want = a._to_segments(np.repeat(points, 5, axis=0), start, end)[::5]  # > SMALL_PAIRS
        assert few.shape == (n, m) and few.dtype == np.float64
        assert np.array_equal(few, want, equal_nan=True)
        for grow in (0.0, 0.25):
            got = a._insides_few(points, boxes, grow)
            whole = a._insides(np.repeat(points, 5, axis=0), boxes, grow)[:, ::5]
            assert got.shape == (m, n) and got.dtype == bool
            assert np.array_equal(got, whole)
    assert a.SMALL_PAIRS < 5  # the whole-array forms above are not the few-pair ones
