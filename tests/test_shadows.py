"""Cast shadows told from objects (stereod.vision.shadows) on a textured floor built here."""

from __future__ import annotations

from typing import Any

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


def _fields(found: shadows._Relit | None) -> list[np.ndarray | None]:
    """Every mask :func:`shadows._relit` gives, placed in the whole image."""
    if found is None:
        return []
    masks = (found.cand, found.core, found.judged, found.thin, found.thin_core)
    return [None if m is None else found.full(m) for m in masks]


def _judged_alike(
    frame: np.ndarray, bg: np.ndarray, foreground: np.ndarray, mp: pytest.MonkeyPatch
) -> int:
    """Judge the candidates group by group, then in the one rectangle around them all (as
    before groups were), and check every mask is the same pixel for pixel; the number of
    rectangles the groups took."""
    crops: list[int] = []
    split = shadows._crops

    def counted(cand: np.ndarray, margin: int) -> list[tuple[tuple[slice, slice], Any]]:
        out = split(cand, margin)
        crops.append(len(out))
        return out

    with mp.context() as m:
        m.setattr(shadows, "_crops", counted)
        grouped = _fields(shadows._relit(frame, bg, foreground, RATIO))
    with mp.context() as m:
        m.setattr(shadows, "SHADOW_MAX_CROPS", 0)
        whole = _fields(shadows._relit(frame, bg, foreground, RATIO))
    assert len(grouped) == len(whole)
    for i, (g, w) in enumerate(zip(grouped, whole, strict=True)):
        assert (g is None) == (w is None), i
        if g is not None:
            assert w is not None
            assert np.array_equal(g, w), (i, int(np.count_nonzero(g != w)))
    return crops[0] if crops else 0


@pytest.mark.parametrize("colour", [False, True], ids=["grey", "bgr"])
def test_shadows_far_apart_are_judged_each_in_its_own_rectangle(
    colour: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Shadows and objects spread across the view are judged in one rectangle around each
    group of them, not in the one around all: the shadows are found where they were made
    (the wide one, the strip) and not on the object, and every mask is what the one
    rectangle around all gives, pixel for pixel."""
    frame, bg, foreground, things = _scattered(colour)
    assert len(shadows._crops(foreground, shadows.SHADOW_WINDOW_PX)) == 3
    shade = shadow_mask(frame, bg, foreground, RATIO)
    assert shade is not None
    for name, least in (("wide", 0.95), ("strip", 0.9)):
        found = cv2.countNonZero(cv2.bitwise_and(shade, things[name]))
        assert found >= least * cv2.countNonZero(things[name]), (name, found)
    assert cv2.countNonZero(cv2.bitwise_and(shade, things["body"])) == 0
    assert _judged_alike(frame, bg, foreground, monkeypatch) == 3


def test_a_group_inside_another_groups_rectangle_is_judged_in_its_own(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An L-shaped shadow's rectangle holds a small shadow of another group at its edge,
    where that rectangle's border would cut the small one's windows: each pixel is judged
    only in its own group's rectangle, as in the one around all. (A third shadow in the far
    corner makes the rectangle around all large enough to be split.)"""
    bg = _floor(240, 320)
    shade = np.zeros(bg.shape, np.uint8)
    shade[20:110, 20:28] = 255  # the L's upright
    shade[100:110, 20:120] = 255  # its foot
    shade[10:40, 115:140] = 255  # another group, astride the L's rectangle's right edge
    shade[200:230, 270:310] = 255  # far away
    frame = _darkened(bg, shade, 0.6)
    assert _judged_alike(frame, bg, shade, monkeypatch) == 3


def test_random_scenes_are_judged_alike_by_groups_and_whole(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Random shadows and dark flat objects of random sizes, anywhere on a floor whose sides
    are no multiple of the cells' (their groups' rectangles meet the image's edges and each
    other): every mask is the same judged by groups as in the one rectangle around all, and
    most scenes are split."""
    split = [_random_scene(seed, monkeypatch) > 1 for seed in range(16)]
    assert sum(split) >= 8, split


def _random_scene(seed: int, monkeypatch: pytest.MonkeyPatch) -> int:
    """One random scene judged both ways (:func:`_judged_alike`); its number of rectangles."""
    rng = np.random.default_rng(seed)
    h, w = 173, 237
    bg = _floor(h, w, seed=seed + 10)
    if seed % 2:
        bg = cv2.merge((bg, _floor(h, w, seed=seed + 20), _floor(h, w, seed=seed + 30)))
    frame = bg.copy()
    foreground: np.ndarray = np.zeros((h, w), np.uint8)
    for _ in range(int(rng.integers(2, 9))):
        x0, y0 = int(rng.integers(0, w - 4)), int(rng.integers(0, h - 4))
        thing = np.zeros((h, w), np.uint8)
        tall = 3 if rng.random() < 0.4 else int(rng.integers(3, 40))  # a low lamp's strip
        thing[y0 : y0 + tall, x0 : x0 + int(rng.integers(3, 60))] = 255
        if rng.random() < 0.7:
            frame = _darkened(frame, thing, float(rng.uniform(0.4, 0.8)))
        else:
            frame[thing > 0] = int(rng.integers(20, 60))
        foreground = cv2.bitwise_or(foreground, thing)
    return _judged_alike(frame, bg, foreground, monkeypatch)
