"""The batched disc fit against the fit one blob at a time (``tests/disc_reference.py``) on
the blobs a detector finds in rendered frames: several balls of several sizes per frame,
grey and colour, both eyes' blobs in one batch."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams
from stereod.vision.disc import Candidate, disc_centres, is_round
from tests.disc_reference import disc_centre
from tests.shaded_balls import shaded_balls

TOLERANCE_PX = 1e-9
"""How far a batched centre may be from the one-at-a-time fit's: the two sum the same
products in another order and solve by another LU, which moves a centre by about 1e-13 px."""


def _eye(rng: np.random.Generator, h: int, w: int, color: bool) -> tuple[np.ndarray, np.ndarray]:
    """A textured wall and a frame of it with five shaded balls 4-22 px across, each pixel
    the share the ball covers (sampled 8 x 8) of the ball's colour, plus sensor noise
    (uint8, (h, w) or (h, w, 3))."""
    wall, frame, _ = shaded_balls(rng, h, w, (2.0, 3.3, 5.0, 7.5, 10.5), 25.0, 40.0)
    if not color:
        wall, frame = wall.mean(axis=2), frame.mean(axis=2)
    return wall.astype(np.uint8), frame.astype(np.uint8)


def _candidates(rng: np.random.Generator, color: bool) -> list[Candidate]:
    """Every round blob a detector (matte centres, no disc fit) finds in one eye's frame,
    as the detector hands it to the fit."""
    wall, frame = _eye(rng, 80, 220, color)
    det = Detector(DetectorParams(warmup_frames=1, disc_max_px=0, color=color))
    det.detect(wall)
    blobs = det.detect(frame)
    background = cv2.convertScaleAbs(det.background)
    out = []
    for (cx, cy), (x, y, w, h), area, own in zip(
        blobs.centroid_px, blobs.bbox_px, blobs.area_px, blobs.support, strict=True
    ):
        if max(w, h) <= DetectorParams().disc_max_px and is_round(own, int(area)):
            box = (int(x), int(y), int(w), int(h))
            out.append(Candidate(frame, background, box, (float(cx), float(cy)), int(area)))
    return out


@pytest.mark.parametrize("color", [False, True])
def test_the_batched_fit_gives_the_centres_of_the_fit_one_blob_at_a_time(color: bool) -> None:
    """Both eyes' round blobs (five balls an eye, 4 to 22 px across, four pairs) fitted in
    one batch give each blob's centre within ``TOLERANCE_PX`` of its own fit's, and fail
    (None) where it fails."""
    rng = np.random.default_rng(11 if color else 12)
    fitted = 0
    for _ in range(4):
        blobs = _candidates(rng, color) + _candidates(rng, color)
        assert len(blobs) >= 4
        batched = disc_centres(blobs)
        for blob, got in zip(blobs, batched, strict=True):
            want = disc_centre(*blob)
            assert (got is None) == (want is None)
            if got is not None and want is not None:
                assert got == pytest.approx(want, abs=TOLERANCE_PX)
                fitted += 1
    assert fitted >= 15


def test_a_blob_the_fit_refuses_leaves_the_others_as_fitted_alone() -> None:
    """A blob whose margin leaves the image gets no centre, and a blob started 4 px off its
    ball gets what its own fit gives (a fit that moves over a pixel is refused); the blobs
    batched with them get the centres they get alone."""
    rng = np.random.default_rng(5)
    blobs = _candidates(rng, True)
    first = blobs[0]
    outside = first._replace(box=(0, 3, 6, 6), centre=(3.0, 6.0))
    off = first._replace(centre=(first.centre[0] + 4.0, first.centre[1]))
    batched = disc_centres([outside, *blobs, off])
    assert batched[0] is None
    assert batched[1:] == [disc_centres([b])[0] for b in [*blobs, off]]
    for blob, got in zip([*blobs, off], batched[1:], strict=True):
        want = disc_centre(*blob)
        assert (got is None) == (want is None)
        if got is not None and want is not None:
            assert got == pytest.approx(want, abs=TOLERANCE_PX)
