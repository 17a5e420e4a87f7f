"""Pictures of what the pipeline saw in one pair: each eye, the foreground masks, and an
annotated side-by-side overlay (the paper's Figs 9-10), as arrays and as JPEG bytes.

Pure drawing on numpy arrays with OpenCV: no threads, no Zenoh. The image thread
(:mod:`stereod.bus.images`) calls it off the pipeline's path. The overlay puts the left eye on the
left and the right eye on the right (each ``w`` px wide) and marks, in each eye:

- every detected blob: a thin grey box (the detector's view, eq. 4-5);
- every track's blob: a box in the track's colour, its centroid (a cross), a label with the
  track id and its speed and heading once valid, and a velocity arrow (where the object will
  be in ``ARROW_S`` seconds, projected into that eye);
- a confirmed track seen in this pair: solid box, and its matched pair joined by a line with
  the rectified row it was matched on (identical to the image row for the canonical rig);
- a tentative track: a dashed box labelled ``tentative``; a coasting track: a dashed box at its
  last seen place labelled ``coasting`` (its state is predicted).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import cv2
import numpy as np

from stereod.tracking.types import TrackLifecycle, TrackState
from stereod.vision.blobs import Blobs
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig

ARROW_S = 0.5
"""The velocity arrow points to where the object will be this many seconds later (s)."""
HEADER_PX = 22
"""Height of the text band above the overlay (px)."""

_PALETTE = [  # BGR, distinguishable on grey
    (60, 200, 255),
    (80, 220, 80),
    (255, 160, 60),
    (200, 90, 255),
    (60, 90, 255),
    (255, 230, 60),
    (170, 255, 200),
    (140, 140, 255),
]
_BLOB = (150, 150, 150)
_TEXT = (255, 255, 255)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class PairImages:
    """What the pipeline used for one pair, held by reference (never copied, never changed).

    ``left``/``right`` the eyes' frames, uint8 (h, w) grey or (h, w, 3) BGR; ``left_mask``/
    ``right_mask`` the detectors' foreground bitmaps M of eq. 4 (uint8 0/255, None during the
    background warm-up); ``rig`` the geometry in force, for the velocity arrows.
    """

    left: np.ndarray
    right: np.ndarray
    left_mask: np.ndarray | None
    right_mask: np.ndarray | None
    rig: CanonicalRig | CalibratedRig


@dataclass(frozen=True)
class Annotations:
    """What the overlay marks: each eye's blobs and the tracks, with the pair's times."""

    seq: int
    t_ns: int
    skew_ns: int
    left: Blobs
    right: Blobs
    tracks: list[TrackState] = field(default_factory=list)


def colour(track_id: int) -> tuple[int, int, int]:
    """The BGR colour of a track (stable for its id)."""
    return _PALETTE[track_id % len(_PALETTE)]


def project(rig: CanonicalRig | CalibratedRig, points_m: np.ndarray) -> tuple[np.ndarray, ...]:
    """(n, 3) rig-frame points (m) to (n, 2) image px in the left and the right eye.

    For a calibrated rig the rig frame is the rectified cameras' common axes with the origin
    midway between them: a point is moved into each rectified camera (x shifted by half the
    baseline), rotated back into that real camera (R1, R2 transposed) and projected with its
    own intrinsics and distortion, so the result lands on the raw image the overlay shows.
    """
    p = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
    if isinstance(rig, CanonicalRig):
        return rig.project(p)
    cal = rig.calibration
    half = rig.baseline_m / 2.0
    out = []
    for shift, r, k, d in (
        (+half, cal.array("R1"), cal.array("K1"), cal.array("D1")),
        (-half, cal.array("R2"), cal.array("K2"), cal.array("D2")),
    ):
        cam = (p + np.array([shift, 0.0, 0.0])) @ r  # R^T x for each row x
        px, _ = cv2.projectPoints(cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, d)
        out.append(px.reshape(-1, 2))
    return out[0], out[1]


def to_bgr(image: np.ndarray) -> np.ndarray:
    """A uint8 (h, w, 3) BGR copy of a grey or BGR frame."""
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return image.copy()


def _pt(x: float, y: float) -> tuple[int, int]:
    return (int(round(x)), int(round(y)))


def _dashed_rect(
    img: np.ndarray, x: int, y: int, w: int, h: int, col: tuple[int, int, int], dash: int = 5
) -> None:
    corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h), (x, y)]
    for (x0, y0), (x1, y1) in itertools.pairwise(corners):
        n = max(int(max(abs(x1 - x0), abs(y1 - y0)) // dash), 1)
        for i in range(0, n, 2):
            a, b = i / n, min(i + 1, n) / n
            cv2.line(
                img,
                _pt(x0 + (x1 - x0) * a, y0 + (y1 - y0) * a),
                _pt(x0 + (x1 - x0) * b, y0 + (y1 - y0) * b),
                col,
                1,
                cv2.LINE_AA,
            )


def _label(img: np.ndarray, text: str, x: int, above: int, col: tuple[int, int, int]) -> None:
    """Text on a dark band whose bottom is 2 px above row ``above``, kept inside the image."""
    (tw, th), base = cv2.getTextSize(text, _FONT, 0.42, 1)
    h, w = img.shape[:2]
    x = min(max(x, 0), max(w - tw - 2, 0))
    y = min(max(above - 2 - base, th + 2), h - base - 1)
    cv2.rectangle(img, (x, y - th - 2), (x + tw + 2, y + base), (0, 0, 0), -1)
    cv2.putText(img, text, (x + 1, y), _FONT, 0.42, col, 1, cv2.LINE_AA)


def _track_label(s: TrackState) -> str:
    if s.lifecycle is TrackLifecycle.TENTATIVE:
        return f"#{s.track_id} tentative"
    if s.lifecycle is TrackLifecycle.COASTING:
        return f"#{s.track_id} coasting"
    if s.heading_valid:
        return f"#{s.track_id} {s.speed_mps:.2f} m/s {s.heading_deg:.0f} deg"
    if s.velocity_valid:
        return f"#{s.track_id} {s.speed_mps:.2f} m/s"
    return f"#{s.track_id}"


def overlay(images: PairImages, ann: Annotations) -> np.ndarray:
    """The annotated side-by-side picture of one pair: uint8 (HEADER_PX + h, 2 w, 3) BGR."""
    left, right = to_bgr(images.left), to_bgr(images.right)
    h, w = left.shape[:2]
    canvas = np.zeros((HEADER_PX + h, 2 * w, 3), np.uint8)
    canvas[HEADER_PX:, :w] = left
    canvas[HEADER_PX:, w:] = right
    eyes = ((0, ann.left), (w, ann.right))
    for dx, blobs in eyes:
        for x, y, bw, bh in blobs.bbox_px:
            cv2.rectangle(
                canvas,
                (dx + int(x), HEADER_PX + int(y)),
                (dx + int(x + bw), HEADER_PX + int(y + bh)),
                _BLOB,
                1,
            )
    cv2.line(canvas, (w, HEADER_PX), (w, HEADER_PX + h), (0, 0, 0), 1)
    arrows = _arrows(images.rig, ann.tracks)
    for k, s in enumerate(ann.tracks):
        _draw_track(canvas, s, w, arrows[k] if arrows is not None else None)
    text = (
        f"pair {ann.seq}  t {ann.t_ns / 1e9:.3f} s  skew {ann.skew_ns / 1e6:+.1f} ms  "
        f"blobs {len(ann.left)}/{len(ann.right)}  tracks {len(ann.tracks)}"
    )
    cv2.putText(canvas, text, (6, HEADER_PX - 7), _FONT, 0.45, _TEXT, 1, cv2.LINE_AA)
    cv2.putText(canvas, "left", (w - 40, HEADER_PX - 7), _FONT, 0.45, _TEXT, 1, cv2.LINE_AA)
    cv2.putText(canvas, "right", (2 * w - 48, HEADER_PX - 7), _FONT, 0.45, _TEXT, 1, cv2.LINE_AA)
    return canvas


def _arrows(rig: CanonicalRig | CalibratedRig, tracks: list[TrackState]) -> np.ndarray | None:
    """(n, 2, 2) image displacement (px) of each track's velocity arrow in the left and right
    eye: the projection of p + v ARROW_S minus that of p; None when nothing projects."""
    if not tracks:
        return None
    p = np.array([s.position_m for s in tracks], dtype=np.float64)
    v = np.array([s.velocity_mps for s in tracks], dtype=np.float64)
    ahead = p + v * ARROW_S
    ok = (p[:, 2] > 1e-3) & (ahead[:, 2] > 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):
        try:
            l0, r0 = project(rig, p)
            l1, r1 = project(rig, ahead)
        except cv2.error:
            return None
        d = np.stack([l1 - l0, r1 - r0], axis=1)
    d[~ok] = 0.0
    return np.where(np.isfinite(d), d, 0.0)


def _draw_track(canvas: np.ndarray, s: TrackState, w: int, arrow: np.ndarray | None) -> None:
    ob = s.observation
    col = colour(s.track_id)
    seen = s.lifecycle in (TrackLifecycle.CONFIRMED, TrackLifecycle.STATIONARY)
    centres = (ob.left_image_px, ob.right_image_px)
    for e, (dx, bbox, c) in enumerate(
        ((0, ob.left_bbox_px, centres[0]), (w, ob.right_bbox_px, centres[1]))
    ):
        x, y, bw, bh = (int(v) for v in bbox)
        x += dx
        y += HEADER_PX
        if seen:
            cv2.rectangle(canvas, (x, y), (x + bw, y + bh), col, 2)
        else:
            _dashed_rect(
                canvas, x, y, bw, bh, col if s.lifecycle is TrackLifecycle.COASTING else _TEXT
            )
        cx, cy = float(c[0]) + dx, float(c[1]) + HEADER_PX
        cv2.drawMarker(canvas, _pt(cx, cy), col, cv2.MARKER_CROSS, 9, 1, cv2.LINE_AA)
        if arrow is not None and s.velocity_valid and np.hypot(*arrow[e]) >= 1.0:
            cv2.arrowedLine(
                canvas,
                _pt(cx, cy),
                _pt(cx + arrow[e, 0], cy + arrow[e, 1]),
                col,
                2,
                cv2.LINE_AA,
                tipLength=0.25,
            )
        _label(canvas, _track_label(s), x, y - 1, col)
    if seen:
        lx, ly = float(ob.left_image_px[0]), float(ob.left_image_px[1]) + HEADER_PX
        rx, ry = float(ob.right_image_px[0]) + w, float(ob.right_image_px[1]) + HEADER_PX
        cv2.line(canvas, _pt(lx, ly), _pt(rx, ry), col, 1, cv2.LINE_AA)
        row = float(ob.left_px[1])
        _label(canvas, f"row {row:.1f}", int(round((lx + rx) / 2)) - 30, int(round(ly)) - 2, col)


def masks(images: PairImages) -> np.ndarray:
    """Both eyes' foreground masks M (eq. 4) side by side, uint8 (h, 2 w), 255 = foreground;
    black for an eye still learning its background."""
    h, w = images.left.shape[:2]
    out = np.zeros((h, 2 * w), np.uint8)
    if images.left_mask is not None and images.left_mask.shape == (h, w):
        out[:, :w] = images.left_mask
    if images.right_mask is not None and images.right_mask.shape == (h, w):
        out[:, w:] = images.right_mask
    return out


def jpeg(image: np.ndarray, quality: int = 80) -> bytes:
    """JPEG bytes of a uint8 grey or BGR image (``quality`` 1-100)."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"JPEG encoding failed for an image of shape {image.shape}")
    return buf.tobytes()
