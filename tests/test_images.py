"""Images on the bus: what the overlay draws against a scene's truth, and the daemon's cost
rules (only while subscribed, joined to their pair, never a pair lost for one)."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import zenoh

from stereod import CanonicalRig, Pipeline, PipelineParams
from stereod.client import Image, ObjectsMessage, subscribe_images, subscribe_objects
from stereod.daemon.config import load_config
from stereod.daemon.daemon import Daemon
from stereod.sources.frames import Eye, StereoPair
from stereod.tracking.types import TrackLifecycle
from stereod.view.overlay import HEADER_PX, Annotations, PairImages, colour, masks, overlay
from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams
from stereod_fakes.synth import Ball, Renderer, Scene, SyntheticDriver

BALL = Ball(heading_deg=60.0, speed_mps=0.7, centre_m=(0.0, 0.1, 1.8))
SCENE = Scene(duration_s=3.0, fps=15.0, balls=[BALL], noise_sigma=1.0)


def test_a_held_mask_keeps_its_pixels_when_the_next_frame_comes() -> None:
    """The image thread holds ``Detector.mask`` by reference while the pipeline moves on: each
    frame must bind a new array, never write into the one handed out."""
    det = Detector(DetectorParams(warmup_frames=2))
    frames = [f.image for f, _ in Renderer(SCENE).frames()]
    held: list[tuple[np.ndarray, np.ndarray]] = []
    for img in frames[:30]:
        det.detect(img)
        if det.mask is not None:
            held.append((det.mask, det.mask.copy()))
    assert len(held) > 20
    for mask, copy in held:
        assert np.array_equal(mask, copy)
    assert len({id(m) for m, _ in held}) == len(held)


def _confirmed_pair():
    """A pair in the middle of the scene with a confirmed, valid track, and its images."""
    rig = SCENE.rig
    with Pipeline(PipelineParams(rig)) as pipe:
        for k, (left, right) in enumerate(Renderer(SCENE).frames()):
            result = pipe.process(StereoPair(k, left, right))
            valid = [s for s in result.tracks if s.velocity_valid]
            if valid and SCENE.frame_time_s(Eye.LEFT, k) >= BALL.t_mid_s:
                images = PairImages(
                    left.image, right.image, pipe.left.mask, pipe.right.mask, pipe.params.rig
                )
                return result, images, valid[0], left.t_ns
    raise AssertionError("the scene never gave a valid track")


def _near(img: np.ndarray, x: float, y: float, bgr: tuple[int, int, int], r: int = 4) -> bool:
    """Whether a pixel of colour ``bgr`` lies within ``r`` px of (x, y)."""
    xi, yi = int(round(x)), int(round(y))
    patch = img[max(yi - r, 0) : yi + r + 1, max(xi - r, 0) : xi + r + 1].astype(int)
    return bool(np.any(np.abs(patch - np.array(bgr)).sum(axis=2) <= 30))


def test_overlay_marks_the_track_where_the_ball_truly_is() -> None:
    result, images, track, t_left_ns = _confirmed_pair()
    assert track.lifecycle is TrackLifecycle.CONFIRMED
    pic = overlay(
        images,
        Annotations(result.seq, result.t_ns, result.skew_ns, result.left, result.right, [track]),
    )
    h, w = SCENE.height_px, SCENE.width_px
    assert pic.shape == (HEADER_PX + h, 2 * w, 3) and pic.dtype == np.uint8
    col = colour(track.track_id)
    t_s = (t_left_ns - SCENE.t0_ns) * 1e-9
    rig: CanonicalRig = SCENE.rig
    p = BALL.position_m(t_s)
    ahead = p + BALL.velocity_mps * 0.5
    (lp, rp), (la, ra) = rig.project(p[None]), rig.project(ahead[None])
    for dx, now, then in ((0, lp[0], la[0]), (w, rp[0], ra[0])):
        # The centroid cross sits on the ball's true image position...
        assert _near(pic, now[0] + dx, now[1] + HEADER_PX, col, 2), (dx, now)
        # ...and the velocity arrow ends where the ball truly is half a second later.
        tip = then - now
        assert _near(pic, now[0] + dx + tip[0], now[1] + HEADER_PX + tip[1], col, 6), (dx, then)
    # The box in both eyes: its top edge is drawn in the track's colour.
    x, y, bw, _ = track.observation.left_bbox_px
    assert _near(pic, x + bw / 2, y + HEADER_PX, col, 1)


def test_tentative_and_coasting_tracks_are_drawn_dashed() -> None:
    result, images, track, _ = _confirmed_pair()
    x, y, bw, _ = (int(v) for v in track.observation.left_bbox_px)
    edge = slice(x + 1, x + bw)
    solid = overlay(images, Annotations(0, 0, 0, result.left, result.right, [track]))
    for state in (TrackLifecycle.TENTATIVE, TrackLifecycle.COASTING):
        other = type(track)(
            **{**{f: getattr(track, f) for f in track.__slots__}, "lifecycle": state}
        )
        pic = overlay(images, Annotations(0, 0, 0, result.left, result.right, [other]))
        top_solid = solid[HEADER_PX + y, edge]
        top = pic[HEADER_PX + y, edge]
        assert np.array_equal(top_solid, np.tile(colour(track.track_id), (len(top_solid), 1)))
        # A dashed edge: some of its pixels are the frame's own.
        assert not np.all(np.abs(top.astype(int) - top_solid.astype(int)).sum(axis=1) == 0)


def test_masks_side_by_side() -> None:
    _, images, track, _ = _confirmed_pair()
    m = masks(images)
    h, w = SCENE.height_px, SCENE.width_px
    assert m.shape == (h, 2 * w)
    for dx, (x, y, bw, bh) in (
        (0, track.observation.left_bbox_px),
        (w, track.observation.right_bbox_px),
    ):
        inside = m[y : y + bh, dx + x : dx + x + bw]
        assert inside.mean() > 100, "the ball's blob is foreground in the mask"
    assert m.mean() < 10, "the wall is background"
    empty = masks(PairImages(images.left, images.right, None, None, images.rig))
    assert not empty.any()


def _daemon(endpoint: str, rate_hz: float) -> Daemon:
    cfg = load_config(
        overrides={
            "zenoh": {"connect": [endpoint]},
            "daemon": {"image_rate_hz": rate_hz},
        }
    )
    driver = SyntheticDriver(SCENE.model_dump(mode="json"))
    return Daemon(cfg, driver, rate=0.0, wait_subscriber_s=10.0)


def test_images_only_while_subscribed_and_joined_to_their_pair(
    endpoint: str, listener: zenoh.Session
) -> None:
    """With a subscriber on the overlay only, every pair is still published, overlays arrive
    with their pair's seq and t_ns, and no other image is encoded."""
    lock = threading.Lock()
    messages: dict[int, ObjectsMessage] = {}
    images: list[Image] = []

    def on_image(image: Image) -> None:
        with lock:
            images.append(image)

    def on_event(event: object) -> None:
        if isinstance(event, ObjectsMessage):
            with lock:
                messages[event.seq] = event

    with (
        subscribe_images(listener, on_image, name="overlay"),
        subscribe_objects(listener, on_event),
    ):
        daemon = _daemon(endpoint, rate_hz=100.0)
        summary = daemon.run()
        deadline = time.monotonic() + 10
        while len(messages) < summary.published and time.monotonic() < deadline:
            time.sleep(0.05)
    assert summary.error is None
    assert summary.published == summary.pairs == SCENE.n_frames
    assert summary.drops == {}
    worker = daemon.images
    assert worker is not None
    assert worker.encoded["left"] == worker.encoded["right"] == worker.encoded["mask"] == 0
    assert worker.encoded["overlay"] >= 1 and worker.failed == 0
    assert images, "no overlay arrived"
    for image in images:
        info = image.info
        assert info.name == "overlay" and info.rig == "minoru"
        assert info.seq in messages and messages[info.seq].t_ns == info.t_ns
        assert messages[info.seq].stamp_utc_ns == info.stamp_utc_ns
        pic = cv2.imdecode(np.frombuffer(image.jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert pic.shape == (info.height, info.width, 3) == (HEADER_PX + 480, 1280, 3)


def test_no_subscriber_no_image_and_every_key_when_asked(
    endpoint: str, listener: zenoh.Session
) -> None:
    daemon = _daemon(endpoint, rate_hz=100.0)
    with subscribe_objects(listener, lambda e: None):
        summary = daemon.run()
    assert summary.error is None and summary.published == summary.pairs
    assert daemon.images is not None and sum(daemon.images.encoded.values()) == 0

    got: dict[str, list[Image]] = {"left": [], "right": [], "mask": []}
    subs = [
        subscribe_images(listener, lambda i, n=name: got[n].append(i), name=name) for name in got
    ]
    daemon = _daemon(endpoint, rate_hz=100.0)
    with subscribe_objects(listener, lambda e: None):
        summary = daemon.run()
        deadline = time.monotonic() + 10
        while not all(got.values()) and time.monotonic() < deadline:
            time.sleep(0.05)
    for s in subs:
        s.close()
    assert summary.error is None and summary.published == summary.pairs
    for name, arrived in got.items():
        assert arrived, f"no {name} image arrived"
        pic = cv2.imdecode(np.frombuffer(arrived[-1].jpeg, np.uint8), cv2.IMREAD_UNCHANGED)
        width = 1280 if name == "mask" else 640
        assert pic.shape[:2] == (480, width), name


def test_images_off_declares_nothing(endpoint: str, listener: zenoh.Session) -> None:
    daemon = _daemon(endpoint, rate_hz=0.0)
    got: list[Image] = []
    with (
        subscribe_images(listener, got.append, name="*"),
        subscribe_objects(listener, lambda e: None),
    ):
        summary = daemon.run()
    assert summary.error is None and daemon.images is None and got == []
