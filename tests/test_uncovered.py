"""Uncovered background (a moved object's old place) against objects and shadows, by the
edges along each blob's outline: a textured floor with a box drawn in the background and
moved in the frame, a ball, and a soft shadow, all drawn here with numpy and OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.vision.blobs import Blobs
from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams
from stereod.vision.uncovered import (
    MAX_CROP_PX,
    UNCOVERED_SCORE,
    left_behind,
    outline_scores,
    uncovered,
)

OBJECT_SCORE = 0.45
"""An object's outline scores at least this: the background model's edges there are at most
0.55 of the frame's."""


def outline_score(
    frame: np.ndarray, background: np.ndarray, support: np.ndarray, at: tuple[int, int]
) -> float:
    """The whole outline's score."""
    return outline_scores(frame, background, support, at)[0]


def blob_scores(frame: np.ndarray, background: np.ndarray, blobs: Blobs) -> np.ndarray:
    """Each blob's whole outline score."""
    return np.array(
        [
            outline_score(frame, background, s, (int(b[0]), int(b[1])))
            for s, b in zip(blobs.support, blobs.bbox_px, strict=True)
        ]
    )


W, H = 320, 240
BOX_THEN = (40, 100, 60, 50)  # x, y, w, h px: where the box stood while the background was learned
BOX_NOW = (180, 110, 60, 50)  # where it was pushed to
BALL = ((130, 60), 14)  # centre (x, y) and radius px
SHADE = (200, 20, 70, 40)  # a shadow's box
SHADE_FACTOR = 0.6


def floor(seed: int = 3) -> np.ndarray:
    """A textured floor (BGR uint8): smoothed noise, grey levels about 90 to 170."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0.0, 1.0, (H, W)).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), 1.5)
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    grey = 90.0 + 80.0 * tex
    tint = np.array([1.0, 0.95, 0.9], np.float32)
    return np.clip(grey[..., None] * tint, 0, 255).astype(np.uint8)


def draw_box(image: np.ndarray, box: tuple[int, int, int, int]) -> None:
    """A dark brown box with a lit top band (brighter than the floor), drawn in place."""
    x, y, w, h = box
    cv2.rectangle(image, (x, y), (x + w - 1, y + h - 1), (40, 60, 110), -1)
    cv2.rectangle(image, (x, y), (x + w - 1, y + h // 5), (120, 170, 230), -1)


def scene() -> tuple[np.ndarray, np.ndarray]:
    """(background, frame): the box at its old place in the background; in the frame it was
    pushed to ``BOX_NOW``, a ball has come in and a soft shadow (darker by ``SHADE_FACTOR``,
    its edge blurred over a few pixels, the floor's texture kept) lies on the floor."""
    bg = floor()
    draw_box(bg, BOX_THEN)
    frame = floor()
    draw_box(frame, BOX_NOW)
    cv2.circle(frame, BALL[0], BALL[1], (30, 170, 220), -1, cv2.LINE_AA)
    shade = np.zeros((H, W), np.float32)
    x, y, w, h = SHADE
    cv2.rectangle(shade, (x, y), (x + w - 1, y + h - 1), 1.0, -1)
    shade = cv2.GaussianBlur(shade, (0, 0), 2.5)
    lit = 1.0 - (1.0 - SHADE_FACTOR) * shade
    frame = np.clip(frame.astype(np.float32) * lit[..., None], 0, 255).astype(np.uint8)
    return bg, frame


def rect_support(box: tuple[int, int, int, int]) -> tuple[np.ndarray, tuple[int, int]]:
    x, y, w, h = box
    return np.full((h, w), 255, np.uint8), (x, y)


def ball_support() -> tuple[np.ndarray, tuple[int, int]]:
    (cx, cy), r = BALL
    support = np.zeros((2 * r + 3, 2 * r + 3), np.uint8)
    cv2.circle(support, (r + 1, r + 1), r, 255, -1)
    return support, (cx - r - 1, cy - r - 1)


def test_uncovered_floor_scores_as_uncovered_and_objects_as_objects() -> None:
    """Along the box's old outline the background has the box's edges and the frame floor
    meeting floor: uncovered. The box at its new place and the ball have edges the
    background lacks: objects. The shadow keeps the floor's texture, and its soft edge is
    a change of light, not an outline: neither."""
    bg, frame = scene()
    bgf = bg.astype(np.float32)  # T is float32
    old = outline_score(frame, bgf, *rect_support(BOX_THEN))
    box = outline_score(frame, bgf, *rect_support(BOX_NOW))
    ball = outline_score(frame, bgf, *ball_support())
    x, y, w, h = SHADE  # the shadow's detected outline: where it is darker by a tenth or more
    shade = outline_score(frame, bgf, *rect_support((x - 2, y - 2, w + 4, h + 4)))
    assert old <= UNCOVERED_SCORE
    assert box >= OBJECT_SCORE
    assert ball >= OBJECT_SCORE
    assert UNCOVERED_SCORE < shade < OBJECT_SCORE
    assert uncovered(outline_scores(frame, bgf, *rect_support(BOX_THEN)))
    assert not uncovered(outline_scores(frame, bgf, *rect_support(BOX_NOW)))
    assert not uncovered(outline_scores(frame, bgf, *ball_support()))


def test_a_region_still_joined_by_an_object_is_not_uncovered() -> None:
    """The box's old place and the ball in one blob (a robot that has not yet left the floor
    it uncovered): over its whole outline the background's edges may still win, but the
    ball's side of it has the frame's: not uncovered, not relearned."""
    bg, frame = scene()
    r = BALL[1]
    x, y, w, h = BOX_THEN
    cv2.circle(frame, (x + w + r - 4, y + h // 2), r, (30, 170, 220), -1, cv2.LINE_AA)
    support = np.zeros((h, w + 2 * r), np.uint8)
    support[:, :w] = 255
    cv2.circle(support, (w + r - 4, h // 2), r, 255, -1)
    whole, sector = outline_scores(frame, bg.astype(np.float32), support, (x, y))
    assert sector > 0.3
    assert not uncovered((whole, sector))
    # Grey frames score alike (a detector working on luminance).
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    grey_bg = cv2.cvtColor(bg, cv2.COLOR_BGR2GRAY).astype(np.float32)
    assert outline_score(grey, grey_bg, *rect_support(BOX_THEN)) <= UNCOVERED_SCORE
    assert outline_score(grey, grey_bg, *ball_support()) >= OBJECT_SCORE


def test_a_blob_is_scored_from_around_it_only() -> None:
    """Only a crop around each blob is read: the rest of the image may be anything."""
    bg, frame = scene()
    blobs = Blobs(
        centroid_px=np.zeros((2, 2)),
        bbox_px=np.array([BOX_THEN, BOX_NOW], np.int32),
        area_px=np.array([3000, 3000], np.int32),
        support=(rect_support(BOX_THEN)[0], rect_support(BOX_NOW)[0]),
    )
    before = blob_scores(frame, bg.astype(np.float32), blobs)
    rng = np.random.default_rng(0)
    scrambled, scrambled_bg = frame.copy(), bg.copy()
    far = (slice(0, 80), slice(250, 320))  # away from both blobs
    scrambled[far] = rng.integers(0, 256, scrambled[far].shape, dtype=np.uint8)
    scrambled_bg[far] = rng.integers(0, 256, scrambled_bg[far].shape, dtype=np.uint8)
    after = blob_scores(scrambled, scrambled_bg.astype(np.float32), blobs)
    np.testing.assert_array_equal(before, after)
    assert before[0] <= UNCOVERED_SCORE and before[1] >= OBJECT_SCORE


@pytest.mark.parametrize("color", [True, False])
def test_the_detectors_uncovered_blob_is_relearned_at_once(color: bool) -> None:
    """Through the real detector: its blobs are the box's old place, the box's new one and
    the ball (the shadow is left out as shadow). :func:`left_behind` marks only the old place
    (both eyes alike here) and hands it to the background: the next frame's blobs are the box
    and the ball alone, where with the detector's own hold the old place would stay
    foreground for ``absorb_s``."""
    params = DetectorParams(color=color)
    bg, frame = scene()
    eyes = (Detector(params), Detector(params))
    rng = np.random.default_rng(1)
    t_ns = 0
    for _ in range(params.warmup_frames):
        noisy = np.clip(bg + rng.normal(0, 1.0, bg.shape), 0, 255).astype(np.uint8)
        for eye in eyes:
            eye.find(noisy, t_ns)
            eye.learn()
        t_ns += 33_333_333
    found = [eye.find(frame, t_ns) for eye in eyes]
    blobs = found[0]
    centres = {tuple(np.round(c).astype(int)) for c in blobs.centroid_px}
    assert len(blobs) == 3, centres
    matches = np.array([(k, k) for k in range(len(blobs))])
    gone = left_behind(found[0], found[1], matches, eyes)
    x, y, w, h = BOX_THEN
    old = [x <= c[0] < x + w and y <= c[1] < y + h for c in blobs.centroid_px]
    assert gone == old and sum(old) == 1
    for eye in eyes:
        eye.learn()
    t_ns += 33_333_333
    again = eyes[0].find(frame, t_ns)
    assert len(again) == 2
    assert not any(x <= c[0] < x + w and y <= c[1] < y + h for c in again.centroid_px)


def test_a_large_blob_is_scored_alike_at_half_resolution() -> None:
    """The scene three times larger: the crops around the old and the new box exceed
    ``MAX_CROP_PX`` and are scored at half resolution, with the same verdicts."""
    bg, frame = scene()
    big = (3 * W, 3 * H)
    bg3 = cv2.resize(bg, big, interpolation=cv2.INTER_LINEAR).astype(np.float32)
    frame3 = cv2.resize(frame, big, interpolation=cv2.INTER_LINEAR)
    for box, gone in ((BOX_THEN, True), (BOX_NOW, False)):
        x, y, w, h = (3 * v for v in box)
        assert (w + 6) * (h + 6) > MAX_CROP_PX
        support, at = rect_support((x, y, w, h))
        assert uncovered(outline_scores(frame3, bg3, support, at)) is gone
