"""The room (textured wall and floor) and its seeded procedural colour textures."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from ._base import F32, F64, Vec3
from .camera import Rig


@dataclass(frozen=True)
class Room:
    """Back wall at Z = ``wall_distance_m``, floor plane Y = ``floor_height_m`` (None: none)."""

    wall_distance_m: float = 4.0
    floor_height_m: float | None = 0.35
    texture: Literal["noise", "flat"] = "noise"
    flat_wall_bgr: Vec3 = (128.0, 128.0, 128.0)
    flat_floor_bgr: Vec3 = (96.0, 96.0, 96.0)
    texel_m: float = 0.004


@dataclass
class _Textures:
    atlas: F32  # wall rows [0, wall_rows), floor rows [floor_row0, ...)
    texel: float
    wall_x0: float
    wall_y0: float
    wall_shape: tuple[int, int]
    floor_x0: float
    floor_z0: float
    floor_row0: int
    floor_shape: tuple[int, int]


def _value_noise(rng: np.random.Generator, ny: int, nx: int, cell: float, ch: int = 1) -> F32:
    """Smooth value noise in about [-1, 1], lattice spacing ``cell`` texels, shape (ny, nx, ch)."""
    cell = max(cell, 1.0)
    gy, gx = math.ceil(ny / cell) + 3, math.ceil(nx / cell) + 3
    lattice = rng.uniform(-1.0, 1.0, size=(gy, gx, ch)).astype(np.float32)
    size = (max(nx + 1, round(gx * cell)), max(ny + 1, round(gy * cell)))
    big = cv2.resize(lattice, size, interpolation=cv2.INTER_CUBIC)
    big = big.reshape(size[1], size[0], ch)
    oy = int(rng.integers(0, max(1, size[1] - ny)))
    ox = int(rng.integers(0, max(1, size[0] - nx)))
    return np.ascontiguousarray(big[oy : oy + ny, ox : ox + nx])


def _fbm(
    rng: np.random.Generator, ny: int, nx: int, texel: float, octaves: Sequence[tuple[float, float]]
) -> F32:
    out = np.zeros((ny, nx, 1), np.float32)
    for wavelength_m, amp in octaves:
        out += amp * _value_noise(rng, ny, nx, wavelength_m / texel)
    return out


def _palette_mix(rng: np.random.Generator, ny: int, nx: int, cell: float, palette: F32) -> F32:
    w = np.exp(4.0 * _value_noise(rng, ny, nx, cell, palette.shape[0]))
    w /= w.sum(axis=2, keepdims=True)
    return np.asarray(w @ palette, dtype=np.float32)


def _wall_texture(
    rng: np.random.Generator, ny: int, nx: int, texel: float, x0: float, y0: float, floor_y: float
) -> F32:
    palette = np.array(
        [
            [95, 140, 185],  # warm beige / orange-ish
            [150, 150, 140],  # grey
            [70, 90, 150],  # terracotta
            [170, 185, 200],  # light cream
            [60, 75, 95],  # dark brown
            [150, 110, 80],  # blue-grey
        ],
        np.float32,
    )
    tex = _palette_mix(rng, ny, nx, 1.2 / texel, palette)
    lum = 1.0 + _fbm(rng, ny, nx, texel, [(0.35, 0.22), (0.09, 0.14), (0.025, 0.08), (0.01, 0.05)])
    tint = 1.0 + 0.06 * _value_noise(rng, ny, nx, 0.15 / texel, 3)
    tex = tex * lum * tint
    # Posters / doors: sharp-edged uniform-ish rectangles, some close to object colours.
    xs = x0 + (np.arange(nx) + 0.5) * texel
    ys = y0 + (np.arange(ny) + 0.5) * texel
    x_lo, x_hi = xs[0] + 0.3, xs[-1] - 0.3
    y_lo, y_hi = ys[0] + 0.3, min(ys[-1], floor_y) - 0.15
    extras = np.array([[40, 120, 230], [150, 90, 40], [60, 160, 60], [200, 200, 200]], np.float32)
    colours = np.concatenate([palette, extras])
    for _ in range(8):
        cxp, cyp = rng.uniform(x_lo, x_hi), rng.uniform(y_lo, max(y_lo, y_hi))
        hw, hh = rng.uniform(0.1, 0.4), rng.uniform(0.1, 0.45)
        col = colours[rng.integers(0, len(colours))] * rng.uniform(0.7, 1.15)
        c0, c1 = np.searchsorted(xs, [cxp - hw, cxp + hw])
        r0, r1 = np.searchsorted(ys, [cyp - hh, cyp + hh])
        if c1 > c0 and r1 > r0:
            patch = lum[r0:r1, c0:c1] * 0.3 + 0.7
            tex[r0:r1, c0:c1] = col * patch
    return np.clip(tex, 8.0, 240.0).astype(np.float32)


def _floor_texture(
    rng: np.random.Generator, nz: int, nx: int, texel: float, x0: float, z0: float
) -> F32:
    palette = np.array(
        [[60, 100, 140], [120, 120, 115], [90, 110, 125], [150, 160, 170]], np.float32
    )
    tex = _palette_mix(rng, nz, nx, 1.5 / texel, palette)
    lum = 1.0 + _fbm(rng, nz, nx, texel, [(0.2, 0.15), (0.05, 0.1), (0.012, 0.07)])
    tile, grout = 0.30, 0.006
    xs = x0 + (np.arange(nx) + 0.5) * texel
    zs = z0 + (np.arange(nz) + 0.5) * texel
    ix = np.floor(xs / tile).astype(np.int64)
    iz = np.floor(zs / tile).astype(np.int64)
    tones = rng.uniform(0.82, 1.15, size=(iz.max() - iz.min() + 1, ix.max() - ix.min() + 1))
    tone = tones[(iz - iz.min())[:, None], (ix - ix.min())[None, :]].astype(np.float32)
    tex = tex * lum * tone[:, :, None]
    gmask = (np.mod(zs, tile) < grout)[:, None] | (np.mod(xs, tile) < grout)[None, :]
    tex[gmask] = np.array([45, 50, 55], np.float32)
    return np.clip(tex, 8.0, 240.0).astype(np.float32)


def _make_textures(rig: Rig, room: Room, seed: int) -> _Textures:
    rng = np.random.default_rng([seed, 7001])
    tau = room.texel_m
    f = rig.focal_px
    tx, ty = 0.5 * rig.width_px / f, 0.5 * rig.height_px / f
    zw = room.wall_distance_m
    margin = 0.25
    half_x = 0.5 * rig.baseline_m + zw * tx + margin
    wall_y0 = -zw * ty - margin
    floor_y = room.floor_height_m
    wall_y1 = (floor_y if floor_y is not None else zw * ty) + margin
    wnx, wny = math.ceil(2 * half_x / tau), math.ceil((wall_y1 - wall_y0) / tau)
    wall = _wall_texture(rng, wny, wnx, tau, -half_x, wall_y0, floor_y if floor_y else 1e9)
    if floor_y is not None:
        z0 = max(0.0, floor_y / ty - margin)
        fnz, fnx = math.ceil((zw + margin - z0) / tau), wnx
        floor = _floor_texture(rng, fnz, fnx, tau, -half_x, z0)
    else:
        z0, fnz, fnx = 0.0, 1, 1
        floor = np.zeros((1, 1, 3), np.float32)
    row0 = wny + 4
    atlas = np.zeros((row0 + fnz, max(wnx, fnx), 3), np.float32)
    atlas[:wny, :wnx] = wall
    atlas[row0:, :fnx] = floor
    return _Textures(atlas, tau, -half_x, wall_y0, (wny, wnx), -half_x, z0, row0, (fnz, fnx))


def _remap(atlas: F32, mx: F32, my: F32) -> F32:
    """Bilinear lookup of ``atlas`` at float texel coordinates (any shape, any size, none
    included: a band of rows where no ray needs the background)."""
    n = mx.size
    if n == 0:
        return np.zeros((*mx.shape, 3), np.float32)
    cols = min(max(n, 1), 1024)
    rows = -(-n // cols)
    px = np.zeros(rows * cols, np.float32)
    py = np.zeros(rows * cols, np.float32)
    px[:n] = mx.ravel()
    py[:n] = my.ravel()
    out = cv2.remap(
        atlas,
        px.reshape(rows, cols),
        py.reshape(rows, cols),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return np.asarray(out.reshape(-1, 3)[:n].reshape((*mx.shape, 3)), dtype=np.float32)


def _bilinear(img: F32, mx: F64, my: F64) -> F64:
    """Exact float64 bilinear interpolation with edge clamping (reference lookups)."""
    h, w = img.shape[:2]
    x = np.clip(mx, 0.0, w - 1.0)
    y = np.clip(my, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2 if h > 1 else 0)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    im = img.astype(np.float64)
    top = im[y0, x0] * (1 - fx) + im[y0, x1] * fx
    bot = im[y1, x0] * (1 - fx) + im[y1, x1] * fx
    return np.asarray(top * (1 - fy) + bot * fy)
