"""The whole-array box tests agree with the one-box forms they batch, and boxes that are one
object's re-segmented are told from others."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.tracking.boxes import inside, insides, iou, ious


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
    got = insides(points, boxes, grow)
    want = np.array([[inside(p, b, grow) for p in points] for b in boxes])
    assert got.shape == (len(boxes), len(points))
    assert np.array_equal(got, want)


def test_box_overlaps_match_the_one_pair_form() -> None:
    rng = np.random.default_rng(4)
    a = np.column_stack([rng.uniform(0, 60, (5, 2)), rng.uniform(1, 30, (5, 2))])
    b = np.column_stack([rng.uniform(0, 60, (7, 2)), rng.uniform(1, 30, (7, 2))])
    want = np.array([[iou(p, q) for q in b] for p in a])
    assert np.allclose(ious(a, b), want, rtol=1e-12, atol=0.0)


def test_few_pairs_in_python_floats_are_the_whole_array_forms_to_the_bit() -> None:
    """A pair with one detection and one track takes the distances to segments and the points
    in boxes one at a time in Python floats: the same numbers, bit for bit, as the whole-array
    pass, degenerate segments, edges and non-finite points included."""
    from stereod.tracking import boxes as a

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
        few = a.to_segments_few(points, start, end)
        want = a.to_segments(np.repeat(points, 5, axis=0), start, end)[::5]  # > SMALL_PAIRS
        assert few.shape == (n, m) and few.dtype == np.float64
        assert np.array_equal(few, want, equal_nan=True)
        for grow in (0.0, 0.25):
            got = a.insides_few(points, boxes, grow)
            whole = a.insides(np.repeat(points, 5, axis=0), boxes, grow)[:, ::5]
            assert got.shape == (m, n) and got.dtype == bool
            assert np.array_equal(got, whole)
    assert a.SMALL_PAIRS < 5  # the whole-array forms above are not the few-pair ones


def test_recut_boxes_hold_one_another_and_share_an_end() -> None:
    """A ball's box (40 x 40 px) and the box of the ball with its long shadow beside it (140 x
    42) are one object's, re-segmented: one holds the other and they share the ball's side.
    A small blob in the middle of a large one's box shares no end; boxes that only overlap
    hold neither; a ball in one blob with a person beside it, or at a larger box's corner,
    shares one end of each axis but not both ends of the other; the bounds are
    :data:`RECUT_END_PX`."""
    from stereod.tracking.boxes import RECUT_END_PX, recuts

    ball = np.array([[100.0, 50.0, 40.0, 40.0]])
    e = RECUT_END_PX
    cases = {
        "ball and shadow to its right": ([98.0, 49.0, 140.0, 42.0], True),
        "ball and shadow to its left": ([0.0, 50.0, 141.0, 40.0], True),
        "a taller box, the ball at its top": ([100.0, 50.0, 40.0, 120.0], True),
        "the ball, a little off": ([100.0 + e, 50.0 - e, 40.0, 40.0], True),
        "a box around the ball, no end shared": ([60.0, 10.0, 120.0, 120.0], False),
        "beyond the bound": ([100.0 - e - 1.0, 50.0, 140.0, 40.0], False),
        "overlapping only": ([120.0, 50.0, 140.0, 40.0], False),
        "a ball at a larger box's corner": ([100.0, 10.0, 140.0, 80.0], False),
        "a ball and a person beside it, one blob": ([40.0, -60.0, 100.0, 150.0], False),
    }
    for name, (box, want) in cases.items():
        other = np.array([box])
        assert bool(recuts(ball, other)[0, 0]) is want, name
        assert bool(recuts(other, ball)[0, 0]) is want, name  # symmetric
    many = np.array([box for box, _ in cases.values()])
    assert np.array_equal(recuts(ball, many)[0], [want for _, want in cases.values()])
