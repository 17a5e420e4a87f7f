"""The device layer and the driver against the fake kernel at the IO seams."""

from __future__ import annotations

import time
from typing import Any

import cv2
import numpy as np
import pytest

from stereod.errors import ConfigError, DeviceError, DeviceLost
from stereod.sources.frames import EyeCounters
from stereod_fakes.v4l2_kernel import FakeCamera, FakeKernel
from stereod_v4l2_minoru import raw
from stereod_v4l2_minoru.device import V4L2Device
from stereod_v4l2_minoru.driver import MinoruDriver

from .jpegs import encode, scene, strip_dht

OPTS = {"left": "/dev/fake0", "right": "/dev/fake1", "width": 64, "height": 48, "fps": 30}


def kernel(**right: object) -> FakeKernel:
    return FakeKernel({"/dev/fake0": FakeCamera(), "/dev/fake1": FakeCamera(**right)})


def test_device_queries_and_streams() -> None:
    k = kernel()
    with V4L2Device("/dev/fake0", k) as dev:
        assert dev.formats() == [("YUYV", "YUYV 4:2:2")]
        assert (640, 480) in dev.frame_sizes("YUYV")
        assert dev.frame_rates("YUYV", 640, 480) == [15.0, 30.0]
        dev.set_format(64, 48, "YUYV")
        assert dev.set_fps(30) == 30.0
        dev.start(4)
        caps = [dev.read(0.1) for _ in range(5)]
        assert all(c is not None and c.monotonic for c in caps)
        assert [c.sequence for c in caps] == [0, 1, 2, 3, 4]  # type: ignore[union-attr]
        assert caps[1].t_ns - caps[0].t_ns == 33_333_000  # microsecond timeval  # type: ignore[union-attr]
        with pytest.raises(DeviceError, match="asked for 100x100 YUYV, the device gives 640x480"):
            dev.set_format(100, 100, "YUYV")


def test_driver_streams_bgr_by_default() -> None:
    """YUYV becomes BGR (BT.601 video range), which colour differencing needs."""
    src = MinoruDriver(OPTS, io=kernel()).open()
    try:
        f = src.left.read()
        assert f is not None and f.image.shape == (48, 64, 3)
        y, u, v = 20.0, FakeKernel.U - 128.0, FakeKernel.V - 128.0  # the fake's first frame
        c = 1.164 * (y - 16)
        want = np.clip([c + 2.018 * u, c - 0.391 * u - 0.813 * v, c + 1.596 * v], 0, 255)
        assert np.abs(f.image[10, 10].astype(float) - want).max() <= 1.5
        assert src.info.settings["color"] is True
    finally:
        src.close()


def test_driver_streams_gray_with_timestamps_and_counts_gaps_and_errors() -> None:
    k = kernel(skip_sequences={3, 4}, error_sequences={6})
    src = MinoruDriver({**OPTS, "color": False}, io=k).open()
    try:
        left = [src.left.read() for _ in range(6)]
        right = [src.right.read() for _ in range(6)]
        assert all(f is not None and f.image.shape == (48, 64) for f in left + right)
        assert [f.seq for f in right] == [0, 1, 2, 5, 7, 8]  # type: ignore[union-attr]
        assert src.right.counters() == EyeCounters({"sequence_gap": 3}, {"frame_error": 1})
        assert src.left.counters() == EyeCounters()
        assert left[0].image[0, 0] == 20  # the Y byte of YUYV  # type: ignore[union-attr]
        # Manual exposure on both eyes.
        for cam in k.cameras.values():
            assert cam.controls[raw.CONTROLS["exposure_auto"]] == raw.V4L2_EXPOSURE_MANUAL
    finally:
        src.close()


def test_short_buffer_is_a_counted_error_not_a_crash() -> None:
    src = MinoruDriver(OPTS, io=kernel(short_sequences={1})).open()
    try:
        frames = [src.right.read() for _ in range(3)]
        assert [f.seq for f in frames] == [0, 2, 3]  # type: ignore[union-attr]
        assert src.right.counters().errors == {"short_frame": 1}
    finally:
        src.close()


def test_timestamps_not_on_the_monotonic_clock_are_restamped() -> None:
    """A device whose buffers are not stamped on CLOCK_MONOTONIC (TIMESTAMP_COPY) would put
    its eye on another clock than the other eye and the UTC offset: it is stamped at dequeue
    on CLOCK_MONOTONIC instead, and counted."""
    src = MinoruDriver(OPTS, io=kernel(clock_copy=True)).open()
    try:
        before = time.monotonic_ns()
        f = src.right.read()
        after = time.monotonic_ns()
        assert f is not None and before <= f.t_ns <= after
        assert src.right.counters().errors == {"clock_not_monotonic": 1}
        left = src.left.read()
        assert left is not None and left.t_ns == 5_000_000_000  # the kernel's stamp, kept
    finally:
        src.close()


def test_enospc_says_the_eyes_do_not_fit_the_bus() -> None:
    with pytest.raises(DeviceError, match=r'not enough USB bandwidth .* "mjpeg", or use 640x480'):
        MinoruDriver(OPTS, io=kernel(enospc_on_streamon=True)).open()


def test_unplug_raises_lost_once_then_recovers_with_controls_reapplied() -> None:
    k = kernel()
    opts = {**OPTS, "retry_s": 0.01, "controls": {"gain": 42}}
    src = MinoruDriver(opts, io=k).open()
    try:
        assert src.right.read() is not None
        k.unplug("/dev/fake1")
        with pytest.raises(DeviceLost):
            src.right.read()
        k.replug("/dev/fake1")
        assert k.cameras["/dev/fake1"].controls[raw.CONTROLS["exposure_auto"]] == 3
        f = src.right.read()
        assert f is not None
        cam = k.cameras["/dev/fake1"]
        assert cam.controls[raw.CONTROLS["exposure_auto"]] == raw.V4L2_EXPOSURE_MANUAL
        assert cam.controls[raw.CONTROLS["gain"]] == 42
    finally:
        src.close()


def test_interrupt_ends_a_blocked_read() -> None:
    k = kernel()
    src = MinoruDriver({**OPTS, "retry_s": 0.01}, io=k).open()
    k.unplug("/dev/fake0")
    with pytest.raises(DeviceLost):
        src.left.read()
    src.left.interrupt()
    assert src.left.read() is None
    src.close()


def test_interrupt_ends_a_read_waiting_on_a_stalled_camera_at_once() -> None:
    """A read waits for a frame in slices of ``INTERRUPT_S``, not ``read_timeout_s`` (up to
    10 s) at once: a stop ends it within a slice, so the daemon never leaves the eye behind."""
    import threading

    k = kernel(stall_after=2)
    src = MinoruDriver({**OPTS, "read_timeout_s": 5.0, "stall_s": 10.0}, io=k).open()
    while src.right.read() is not None and k.cameras["/dev/fake1"].next_seq < 2:
        pass
    done = threading.Event()
    t = threading.Thread(target=lambda: (src.right.read(), done.set()))
    t.start()
    time.sleep(0.3)  # waiting for a frame that does not come
    assert not done.is_set()
    src.right.interrupt()
    assert done.wait(2.0)  # far within the 5 s one wait took (at most INTERRUPT_S now)
    t.join()
    src.close()


def test_option_errors() -> None:
    with pytest.raises(ConfigError, match=r"driver\.options\.controls\.shutter: unknown control"):
        MinoruDriver({"controls": {"shutter": 1}})
    with pytest.raises(ConfigError, match=r"driver\.options\.fps"):
        MinoruDriver({"fps": 0})
    with pytest.raises(DeviceLost, match="no such device"):
        MinoruDriver({**OPTS, "left": "/dev/none"}, io=kernel()).open()


def test_a_node_that_is_not_a_camera_is_a_config_error() -> None:
    """The real kernel's answer to a V4L2 query on /dev/null (ENOTTY): a wrong path in the
    configuration, exit 78, which systemd does not retry, rather than an unavailable device."""
    with pytest.raises(ConfigError, match=r"/dev/null: not a V4L2 device; point the eye") as err:
        V4L2Device("/dev/null").open()
    assert err.value.exit_code == 78


def test_an_eye_that_stops_streaming_is_reopened() -> None:
    """A camera can stop delivering mid-stream and stay open: after ``stall_s`` without a
    frame the eye is lost (so the daemon reports it) and reopened, and streams again."""
    k = kernel(stall_after=3)
    opts = {**OPTS, "retry_s": 0.01, "read_timeout_s": 0.05, "stall_s": 0.3}
    src = MinoruDriver(opts, io=k).open()
    try:
        assert [src.right.read().seq for _ in range(3)] == [0, 1, 2]  # type: ignore[union-attr]
        t0 = time.monotonic()
        with pytest.raises(DeviceLost, match=r"/dev/fake1: no frame for 0\.[3-9] s"):
            src.right.read()
        assert 0.3 <= time.monotonic() - t0 < 2.0
        f = src.right.read()
        assert f is not None and f.seq == 3
        assert src.left.read() is not None  # the other eye never noticed
    finally:
        src.close()


class MjpegKernel(FakeKernel):
    """The fake kernel with a UVC camera's second format: Motion-JPEG (MJPG), whose frames
    are :func:`jpegs.scene` images encoded by OpenCV at quality 90 (its green level stepping
    with the sequence), each buffer's ``bytesused`` the JPEG's length. ``faults`` maps a
    sequence number to what a camera may send instead, on every camera: ``empty`` (0 bytes),
    ``truncated`` (cut mid-scan, no EOI), ``garbage``, ``no_dht`` (the frame without its
    Huffman tables), ``small`` (a frame of a quarter of the size)."""

    def __init__(
        self, cameras: dict[str, FakeCamera], faults: dict[int, str] | None = None
    ) -> None:
        super().__init__(cameras)
        self.faults = faults or {}
        self.formats: dict[int, int] = {}
        """The pixel format each camera (by id) was set to."""

    @staticmethod
    def image(width: int, height: int, seq: int) -> np.ndarray:
        return scene(width, height, level=60 + (seq * 10) % 120)

    def format_of(self, path: str) -> str:
        return raw.fourcc_str(self.formats[id(self.cameras[path])])

    def _vidioc_enum_fmt(self, cam: FakeCamera, d: raw.v4l2_fmtdesc) -> None:
        if d.index == 1:
            d.pixelformat, d.description = raw.V4L2_PIX_FMT_MJPEG, b"Motion-JPEG"
            return
        super()._vidioc_enum_fmt(cam, d)

    def _vidioc_s_fmt(self, cam: FakeCamera, f: raw.v4l2_format) -> None:
        wanted = f.fmt.pix.pixelformat
        super()._vidioc_s_fmt(cam, f)
        if wanted == raw.V4L2_PIX_FMT_MJPEG:  # uvcvideo: sizeimage the uncompressed size
            f.fmt.pix.pixelformat, f.fmt.pix.bytesperline = wanted, 0
        self.formats[id(cam)] = f.fmt.pix.pixelformat

    def _vidioc_dqbuf(self, cam: FakeCamera, b: raw.v4l2_buffer) -> None:
        super()._vidioc_dqbuf(cam, b)
        if self.formats.get(id(cam)) != raw.V4L2_PIX_FMT_MJPEG:
            return
        seq = b.sequence
        img = self.image(cam.width, cam.height, seq)
        jpg = encode(img)
        fault = self.faults.get(seq)
        if fault == "empty":
            jpg = b""
        elif fault == "truncated":
            jpg = jpg[: len(jpg) * 3 // 4]
        elif fault == "garbage":
            jpg = bytes(np.random.default_rng(seq).integers(0, 256, 2000, dtype=np.uint8))
        elif fault == "no_dht":
            jpg = strip_dht(jpg)
        elif fault == "small":
            jpg = encode(img[: cam.height // 2, : cam.width // 2])
        buf = cam.buffers[b.index]
        assert len(jpg) <= len(buf)
        buf[: len(jpg)] = jpg
        b.bytesused = len(jpg)


def mjpeg_kernel(faults: dict[int, str] | None = None, **right: Any) -> MjpegKernel:
    return MjpegKernel({"/dev/fake0": FakeCamera(), "/dev/fake1": FakeCamera(**right)}, faults)


def test_mjpeg_is_negotiated_and_decoded_to_bgr_and_grey() -> None:
    """With ``pixel_format = "mjpeg"`` both eyes are set to MJPG and each buffer's bytesused
    bytes decode to the image the camera encoded: BGR by default, the luma with ``color =
    false`` (BT.601, as OpenCV's BGR to grey computes it from the image)."""
    k = mjpeg_kernel()
    with V4L2Device("/dev/fake0", k) as dev:
        assert dev.formats() == [("YUYV", "YUYV 4:2:2"), ("MJPG", "Motion-JPEG")]
    src = MinoruDriver({**OPTS, "pixel_format": "mjpeg"}, io=k).open()
    try:
        assert k.format_of("/dev/fake0") == k.format_of("/dev/fake1") == "MJPG"
        for seq in range(3):
            f = src.left.read()
            assert f is not None and f.seq == seq and f.image.shape == (48, 64, 3)
            want = MjpegKernel.image(64, 48, seq).astype(int)
            assert np.abs(f.image.astype(int) - want)[4:-4, 4:28].max() <= 6
            assert np.abs(f.image.astype(int) - want)[4:-4, 36:60].max() <= 6
        assert src.info.settings["pixel_format"] == "mjpeg"
    finally:
        src.close()
    src = MinoruDriver({**OPTS, "pixel_format": "mjpeg", "color": False}, io=mjpeg_kernel()).open()
    try:
        f = src.right.read()
        assert f is not None and f.image.shape == (48, 64)
        want = cv2.cvtColor(MjpegKernel.image(64, 48, 0), cv2.COLOR_BGR2GRAY).astype(int)
        assert np.abs(f.image.astype(int) - want)[4:-4, 4:60].max() <= 6
        assert src.right.counters() == EyeCounters()
    finally:
        src.close()


def test_auto_negotiates_by_the_bus() -> None:
    """``auto`` (the default) streams YUYV where both eyes fit USB 2.0 uncompressed (64x48
    at 30 Hz) and MJPEG where they do not (640x480 at 30 Hz)."""
    k = mjpeg_kernel()
    src = MinoruDriver(OPTS, io=k).open()
    try:
        assert k.format_of("/dev/fake0") == "YUYV"
        assert src.left.read() is not None
    finally:
        src.close()
    k = mjpeg_kernel()
    src = MinoruDriver({**OPTS, "width": 640, "height": 480}, io=k).open()
    try:
        assert k.format_of("/dev/fake0") == k.format_of("/dev/fake1") == "MJPG"
        f = src.right.read()
        assert f is not None and f.image.shape == (480, 640, 3)
        assert np.abs(f.image.astype(int) - MjpegKernel.image(640, 480, 0))[8:-8, 8:312].max() <= 6
    finally:
        src.close()


def test_bad_mjpeg_frames_are_counted_and_skipped_and_the_eye_streams_on() -> None:
    """A frame that is empty, cut short, not a JPEG, flagged V4L2_BUF_FLAG_ERROR, or of
    another size is counted and left out; the frames around it arrive, decoded."""
    faults = {1: "empty", 2: "truncated", 4: "garbage", 6: "small"}
    k = mjpeg_kernel(faults, error_sequences={5})
    src = MinoruDriver({**OPTS, "pixel_format": "mjpeg"}, io=k).open()
    try:
        frames = [src.right.read() for _ in range(4)]
        assert [f.seq for f in frames] == [0, 3, 7, 8]  # type: ignore[union-attr]
        for f in frames:
            assert f is not None
            want = MjpegKernel.image(64, 48, f.seq).astype(int)
            assert np.abs(f.image.astype(int) - want)[4:-4, 4:28].max() <= 6
        # The flagged frame is also a gap in the sequence, as with YUYV.
        assert src.right.counters() == EyeCounters(
            {"sequence_gap": 1}, {"bad_jpeg": 3, "frame_error": 1, "wrong_size": 1}
        )
    finally:
        src.close()


def test_mjpeg_frames_without_huffman_tables_stream() -> None:
    """A camera that leaves the DHT out of its frames: they decode to the same pixels as the
    frames with it, and nothing is counted."""
    k = mjpeg_kernel({0: "no_dht", 1: "no_dht"})
    src = MinoruDriver({**OPTS, "pixel_format": "mjpeg"}, io=k).open()
    try:
        for seq in (0, 1):
            f = src.left.read()
            assert f is not None and f.seq == seq
            whole = encode(MjpegKernel.image(64, 48, seq))
            np.testing.assert_array_equal(f.image, cv2.imdecode(np.frombuffer(whole, np.uint8), 1))
        assert src.left.counters() == EyeCounters()
    finally:
        src.close()
