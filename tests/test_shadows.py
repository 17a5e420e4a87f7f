"""Cast shadows told from objects (stereod.vision.shadows) on a textured floor built here."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.vision import shadows
from stereod.vision.shadows import shadow_mask

RATIO = (0.3, 0.95)


def _floor(h: int, w: int, seed: int = 4) -> np.ndarray:
    """A grey floor with a grain a few pixels across."""
    rng = np.random.default_rng(seed)
    small = rng.uniform(70, 170, (h // 2, w // 2)).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.uint8)


def _darkened(bg: np.ndarray, mask: np.ndarray, factor: float) -> np.ndarray:
    out = bg.copy()
    out[mask > 0] = (bg[mask > 0].astype(np.float32) * factor).astype(np.uint8)
    return out


def _strip(shape: tuple[int, int], x0: int, x1: int, y0: int, height: int) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    mask[y0 : y0 + height, x0:x1] = 255
    return mask


def test_a_shadow_strip_thinner_than_the_square_window_is_shadow() -> None:
    """A low lamp's shadow on the floor is a strip a few px high (3 px here, 60 px long), as in
    a 60 deg view at 320x240. No 7x7 window fits inside it: each mixes shadow and lit floor, and
    its one-factor test fails. The wide, low window finds it: nearly all of it is shadow."""
    bg = _floor(120, 160)
    strip = _strip(bg.shape, 40, 100, 70, 3)
    frame = _darkened(bg, strip, 0.55)
    shade = shadow_mask(frame, bg, strip, RATIO)
    assert shade is not None
    share = cv2.countNonZero(cv2.bitwise_and(shade, strip)) / cv2.countNonZero(strip)
    assert share >= 0.9, f"{share:.0%} of the strip found as shadow"


def test_a_thin_shadow_does_not_take_the_tall_object_it_touches() -> None:
    """A flat dark object (30 px tall) hides the floor's texture, though it is darker by a
    factor a shadow could have. Its thin shadow runs from its foot. The strip window's sure
    pixels reach only thin candidates: the shadow is found, the object is kept whole."""
    bg = _floor(120, 160)
    body = np.zeros(bg.shape, np.uint8)
    body[40:70, 50:70] = 255
    strip = _strip(bg.shape, 70, 130, 66, 3)
    frame = _darkened(bg, strip, 0.55)
    frame[body > 0] = np.uint8(0.6 * float(bg[body > 0].mean()))
    shade = shadow_mask(frame, bg, cv2.bitwise_or(body, strip), RATIO)
    assert shade is not None
    assert cv2.countNonZero(cv2.bitwise_and(shade, body)) == 0
    share = cv2.countNonZero(cv2.bitwise_and(shade, strip)) / cv2.countNonZero(strip)
    assert share >= 0.9, f"{share:.0%} of the strip found as shadow"


def test_a_square_shadow_is_found_by_the_square_window() -> None:
    """A wide shadow (40x20 px, factor 0.6) is shadow through the square window alone: its
    middle holds no thin candidate."""
    bg = _floor(120, 160)
    patch = np.zeros(bg.shape, np.uint8)
    patch[50:70, 60:100] = 255
    frame = _darkened(bg, patch, 0.6)
    shade = shadow_mask(frame, bg, patch, RATIO)
    assert shade is not None
    assert cv2.countNonZero(cv2.bitwise_and(shade, patch)) >= 0.95 * cv2.countNonZero(patch)


def test_a_dark_object_with_a_few_shadow_like_windows_is_kept() -> None:
    """A dark object (uniform, 24x60 px) in front of the textured floor is a candidate
    throughout: darker by a factor a shadow could have. An 8x8 spot of it happens to follow
    the floor's texture under one factor, as a few windows of a real object do by chance
    (dark trousers in front of a mottled wall: 3 to 8 % of them). One spot must not make the
    whole object shadow; a shadow of the same size is still found."""
    bg = _floor(120, 160)
    body = np.zeros(bg.shape, np.uint8)
    body[30:90, 60:84] = 255
    frame = bg.copy()
    frame[body > 0] = 50
    frame[50:58, 68:76] = (bg[50:58, 68:76] * 0.45).astype(np.uint8)
    shade = shadow_mask(frame, bg, body, (0.15, 0.95))
    taken = 0 if shade is None else cv2.countNonZero(cv2.bitwise_and(shade, body))
    assert taken <= 0.1 * cv2.countNonZero(body), f"{taken} of the object's px taken for shadow"
    patch = np.zeros(bg.shape, np.uint8)
    patch[30:90, 100:124] = 255
    shadowed = _darkened(frame, patch, 0.45)
    shade = shadow_mask(shadowed, bg, cv2.bitwise_or(body, patch), (0.15, 0.95))
    assert shade is not None
    assert cv2.countNonZero(cv2.bitwise_and(shade, patch)) >= 0.95 * cv2.countNonZero(patch)
    assert cv2.countNonZero(cv2.bitwise_and(shade, body)) <= 0.1 * cv2.countNonZero(body)


def test_a_stretch_no_window_fits_in_is_judged_by_the_share_of_all_its_windows() -> None:
    """A 6 px wide stretch of candidates (60 px tall): no 7x7 window fits inside it, so the
    share of sure windows is taken over all of it. As the foreground of a wide shadow, nearly
    all its windows are sure, and it is shadow. As a dark pole whose 7 rows in front of a
    patch of shade happen to keep the floor's texture (6 of its 360 windows), it is kept."""
    bg = _floor(120, 160)
    band = np.zeros(bg.shape, np.uint8)
    band[30:90, 77:83] = 255
    wide = np.zeros(bg.shape, np.uint8)
    wide[30:90, 70:90] = 255
    shade = shadow_mask(_darkened(bg, wide, 0.45), bg, band, (0.15, 0.95))
    assert shade is not None
    assert cv2.countNonZero(cv2.bitwise_and(shade, band)) == cv2.countNonZero(band)
    pole = bg.copy()
    pole[band > 0] = 50
    spot = np.zeros(bg.shape, np.uint8)
    spot[55:62, 70:90] = 255
    pole[spot > 0] = _darkened(bg, spot, 0.45)[spot > 0]
    shade = shadow_mask(pole, bg, band, (0.15, 0.95))
    taken = 0 if shade is None else cv2.countNonZero(cv2.bitwise_and(shade, band))
    assert taken == 0, f"{taken} of the pole's px taken for shadow"


def _scattered(colour: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """A 320x240 floor (BGR or grey) with three things far apart, as people spread across a
    room leave them: a wide shadow top left, a low lamp's strip bottom right, and a flat dark
    object (uniform, no texture) in the middle. The frame, the background, the foreground
    and each thing's mask."""
    bg = _floor(240, 320)
    if colour:
        bg = cv2.merge((bg, _floor(240, 320, seed=5), _floor(240, 320, seed=6)))
    things = {name: np.zeros((240, 320), np.uint8) for name in ("wide", "strip", "body")}
    things["wide"][20:50, 20:70] = 255
    things["strip"][200:203, 220:290] = 255
    things["body"][100:150, 150:175] = 255
    frame = _darkened(_darkened(bg, things["wide"], 0.6), things["strip"], 0.55)
    frame[things["body"] > 0] = 45
    foreground = cv2.bitwise_or(cv2.bitwise_or(things["wide"], things["strip"]), things["body"])
    return frame, bg, foreground, things


@pytest.mark.parametrize("colour", [False, True], ids=["grey", "bgr"])
def test_shadows_far_apart_are_judged_each_in_its_own_rectangle(
    colour: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Shadows and objects spread across the view are judged in one rectangle around each
    group of them, not in the one around all: the same shadow as judged in that one, pixel
    for pixel, found where it was made (the wide shadow, the strip) and not on the object."""
    frame, bg, foreground, things = _scattered(colour)
    assert len(shadows._crops(foreground, shadows.SHADOW_WINDOW_PX)) == 3
    shade = shadow_mask(frame, bg, foreground, RATIO)
    assert shade is not None
    for name, least in (("wide", 0.95), ("strip", 0.9)):
        found = cv2.countNonZero(cv2.bitwise_and(shade, things[name]))
        assert found >= least * cv2.countNonZero(things[name]), (name, found)
    assert cv2.countNonZero(cv2.bitwise_and(shade, things["body"])) == 0
    monkeypatch.setattr(shadows, "SHADOW_MAX_CROPS", 0)  # one rectangle around all
    assert len(shadows._crops(foreground, shadows.SHADOW_WINDOW_PX)) == 1
    whole = shadow_mask(frame, bg, foreground, RATIO)
    assert whole is not None and np.array_equal(shade, whole)
