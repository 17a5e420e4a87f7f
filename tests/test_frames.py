"""Frames refuse what the detectors cannot read, each with a message that says what to do."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.sources.frames import Eye, Frame, StereoPair

GREY = np.zeros((24, 32), np.uint8)


def test_an_eye_given_as_its_name_is_the_eye() -> None:
    assert Frame("left", GREY, 0, 0).eye is Eye.LEFT  # type: ignore[arg-type]
    assert Frame("right", GREY, 0, 0).eye is Eye.RIGHT  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="eye must be 'left' or 'right', got 'centre'"):
        Frame("centre", GREY, 0, 0)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("image", "error", "message"),
    [
        (np.zeros((24, 32), np.float32), TypeError, "must be uint8 .* got float32"),
        (np.zeros((24, 32), np.uint16), TypeError, "must be uint8 .* got uint16"),
        (np.zeros((24, 32, 4), np.uint8), ValueError, "COLOR_BGRA2BGR"),
        (np.zeros((24, 32, 1), np.uint8), ValueError, r"got shape \(24, 32, 1\)"),
        (np.zeros((24,), np.uint8), ValueError, r"got shape \(24,\)"),
        (np.zeros((0, 0), np.uint8), ValueError, r"got shape \(0, 0\)"),
        ([[0, 1], [2, 3]], TypeError, "must be a numpy array, got list"),
        (None, TypeError, "must be a numpy array, got NoneType"),
    ],
)
def test_an_image_the_detectors_cannot_read_is_refused(
    image: object, error: type[Exception], message: str
) -> None:
    with pytest.raises(error, match=f"left frame 7: image .*{message}"):
        Frame(Eye.LEFT, image, 0, 7)  # type: ignore[arg-type]


def test_an_image_not_laid_out_row_by_row_is_copied_into_one_that_is() -> None:
    """A transpose (column-major) is what OpenCV's in-place calls cannot write to; a view of
    a contiguous image is kept as it is."""
    column_major = np.arange(24 * 32, dtype=np.uint8).reshape(32, 24).T
    frame = Frame(Eye.LEFT, column_major, 0, 0)
    assert frame.image.flags.c_contiguous
    np.testing.assert_array_equal(frame.image, column_major)
    assert Frame(Eye.LEFT, GREY, 0, 0).image is GREY


def test_capture_times_are_integer_nanoseconds() -> None:
    assert Frame(Eye.LEFT, GREY, np.int64(5), 0).t_ns == 5
    assert type(Frame(Eye.LEFT, GREY, np.int64(5), 0).t_ns) is int
    with pytest.raises(TypeError, match=r"integer count of nanoseconds, got 1.5: .*1e9"):
        Frame(Eye.LEFT, GREY, 1.5, 0)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="integer count of nanoseconds"):
        StereoPair.of(GREY, GREY, 0.0, 0.0)  # type: ignore[arg-type]


@pytest.mark.parametrize("t", [-(2**63) - 1, 2**63, 2**70])
def test_a_capture_time_beyond_64_bits_is_refused(t: int) -> None:
    """A clock counts ns in a signed 64-bit integer: a time outside that is refused with the
    frame, so no pipeline ever holds it as its last (after which it refused every real frame
    as not later). A time line of one's own may start below 0 (a right eye 10 ms before the
    left eye's 0)."""
    with pytest.raises(ValueError, match=rf"left frame 3: t_ns {t} does not fit a clock's"):
        Frame(Eye.LEFT, GREY, t, 3)
    assert Frame(Eye.LEFT, GREY, 2**63 - 1, 3).t_ns == 2**63 - 1
    assert Frame(Eye.LEFT, GREY, -(2**63), 3).t_ns == -(2**63)
    assert Frame(Eye.RIGHT, GREY, -10_000_000, 0).t_ns == -10_000_000


@pytest.mark.parametrize("t", [True, np.bool_(True)])
def test_a_capture_time_given_as_a_truth_value_is_refused(t: object) -> None:
    with pytest.raises(TypeError, match=r"integer count of nanoseconds, got (np\.)?True"):
        Frame(Eye.LEFT, GREY, t, 0)  # type: ignore[arg-type]
