"""The USB 2.0 preflight against arithmetic done by hand here.

Each case below: bytes a frame (YUYV 2 a pixel; MJPEG counted at 1 a pixel), times the rate,
over 8000 microframes a second, plus the 12-byte UVC header; whole 1024-byte transactions for
that; the bus time of those (the kernel's HS_USECS_ISO: (38 * 8 * 2083 + 2083 * (3 + 7 * 8 *
bytes // 6)) // 1000 + 5 ns, rounded up to whole us); two eyes against 100 us a microframe.
"""

from __future__ import annotations

import pytest

from stereod.errors import ConfigError
from stereod_v4l2_minoru import bandwidth
from stereod_v4l2_minoru.bandwidth import EyeReservation, choose, fits, reservation
from stereod_v4l2_minoru.driver import MinoruDriver


def test_bus_time_of_whole_transactions() -> None:
    # 1024 B: 7 * 8 * 1024 // 6 = 9557 bits; (633232 + 2083 * 9560) // 1000 + 5 = 20551 ns.
    assert bandwidth.hs_usecs_iso(1024) == 21
    # 2048 B: 19114 bits; (633232 + 2083 * 19117) // 1000 + 5 = 40458 ns.
    assert bandwidth.hs_usecs_iso(2048) == 41
    # 3072 B: 28672 bits; (633232 + 2083 * 28675) // 1000 + 5 = 60368 ns.
    assert bandwidth.hs_usecs_iso(3072) == 61


def test_yuyv_640x480_at_30_does_not_fit_and_mjpeg_does() -> None:
    # YUYV: 640 * 480 * 2 = 614400 B * 30 / 8000 = 2304 + 12 = 2316 B: 3 transactions, 61 us;
    # two eyes 122 us > 100.
    assert reservation("yuyv", 640, 480, 30) == EyeReservation(2316, 3, 61)
    assert not fits("yuyv", 640, 480, 30)
    # MJPEG at its worst: 640 * 480 * 1 = 307200 B * 30 / 8000 = 1152 + 12 = 1164 B:
    # 2 transactions, 41 us; two eyes 82 us <= 100.
    assert reservation("mjpeg", 640, 480, 30) == EyeReservation(1164, 2, 41)
    assert fits("mjpeg", 640, 480, 30)


def test_the_minoru_s_uncompressed_modes_that_fit() -> None:
    # 640x480 at 15: 614400 * 15 / 8000 = 1152 + 12 = 1164 B: 2 transactions, 82 us for two.
    assert reservation("yuyv", 640, 480, 15) == EyeReservation(1164, 2, 41)
    assert fits("yuyv", 640, 480, 15)
    # 320x240 at 30: 153600 * 30 / 8000 = 576 + 12 = 588 B: 1 transaction, 42 us for two.
    assert reservation("yuyv", 320, 240, 30) == EyeReservation(588, 1, 21)
    assert fits("yuyv", 320, 240, 30)
    # One eye alone at 640x480, 30 Hz: 61 us, fits.
    assert fits("yuyv", 640, 480, 30, eyes=1)


def test_a_mode_beyond_one_endpoint() -> None:
    # MJPEG 1280x720 at 30: 921600 * 30 / 8000 = 3456 + 12 = 3468 B > 3 * 1024.
    assert reservation("mjpeg", 1280, 720, 30).transactions == 4
    assert not fits("mjpeg", 1280, 720, 30)
    with pytest.raises(ValueError, match=r"3468 bytes .* lower the size or rate") as err:
        choose("mjpeg", 1280, 720, 30)
    assert 'mjpeg"' not in str(err.value)  # switching format would not help


def test_auto_picks_yuyv_when_both_eyes_fit_uncompressed() -> None:
    assert choose("auto", 640, 480, 15) == "yuyv"
    assert choose("auto", 320, 240, 30) == "yuyv"
    assert choose("auto", 640, 480, 30) == "mjpeg"
    assert choose("mjpeg", 320, 240, 30) == "mjpeg"


def test_the_driver_refuses_yuyv_640x480_at_30_in_one_line() -> None:
    """Before any device is opened (the nodes named do not exist): a configuration error
    (exit 78) that names the figures and both fixes."""
    opts = {"left": "/dev/none0", "right": "/dev/none1", "width": 640, "height": 480, "fps": 30}
    with pytest.raises(ConfigError) as err:
        MinoruDriver({**opts, "pixel_format": "yuyv"})
    msg = str(err.value)
    assert err.value.exit_code == 78 and "\n" not in msg
    assert msg.startswith("driver.options: 640x480 YUYV at 30 fps reserves 61 us")
    assert "122 us for both, over the 100 us" in msg
    assert 'set pixel_format = "mjpeg"' in msg and "lower the size or rate" in msg
    assert MinoruDriver({**opts, "pixel_format": "mjpeg"}).options.pixel_format == "mjpeg"
    assert MinoruDriver(opts).options.pixel_format == "mjpeg"  # auto, the default
    assert MinoruDriver({**opts, "fps": 15}).options.pixel_format == "yuyv"


def test_pixel_format_names() -> None:
    """Any case, and the fourccs the setting took before (YUYV, MJPG); anything else names
    the field."""
    for given, want in (("YUYV", "yuyv"), ("MJPG", "mjpeg"), ("MJPEG", "mjpeg"), ("Auto", "yuyv")):
        assert MinoruDriver({"pixel_format": given}).options.pixel_format == want
    with pytest.raises(ConfigError, match=r"driver\.options\.pixel_format = 'h264'"):
        MinoruDriver({"pixel_format": "h264"})
