"""Ray casting of the objects' image regions (box-filtered pixels, adaptive supersampling).

A mixin of :class:`~.scene.Scene`: the rules (coarse grid, edge and ring refinement) are
described in the package docstring and depend on the pixel only, never on the region.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from ._base import _NEAR_M, F32, F64, I32, Rect
from .camera import Quality, Rig
from .light import Blocker, Lamps, Lighting, irradiance
from .shapes import Shape

_Placed = tuple[str, Shape, F64]  # (object name, solid, centre)


class _Caster:
    """Object-region ray casting; the scene supplies the fields and the background."""

    rig: Rig
    quality: Quality
    lighting: Lighting
    lamps: Lamps | None

    def _background_image(self, eye: str) -> F32:
        raise NotImplementedError

    def _bg_rays(self, eye: str, dx: F64, dy: F64, blockers: list[Blocker]) -> F32:
        raise NotImplementedError

    def _pixel_rect(self, eye: str, lo: F64, hi: F64, margin: int) -> Rect | None:
        """Conservative pixel rectangle of the box [lo, hi] (clipped to Z >= near) or None."""
        if hi[2] <= _NEAR_M:
            return None
        rig = self.rig
        z_lo = max(float(lo[2]), _NEAR_M)
        cam_x = float(rig.camera_centre(eye)[0])
        f = rig.focal_px
        us, vs = [], []
        for z in (z_lo, float(hi[2])):
            for x in (float(lo[0]), float(hi[0])):
                us.append(rig.cx + f * (x - cam_x) / z)
            for y in (float(lo[1]), float(hi[1])):
                vs.append(rig.cy + f * y / z)
        c0 = max(0, math.floor(min(us) + 0.5) - margin)
        c1 = min(rig.width_px, math.floor(max(us) + 0.5) + 1 + margin)
        r0 = max(0, math.floor(min(vs) + 0.5) - margin)
        r1 = min(rig.height_px, math.floor(max(vs) + 0.5) + 1 + margin)
        if c0 >= c1 or r0 >= r1:
            return None
        return (r0, r1, c0, c1)

    def _groups(self, eye: str, placed: list[_Placed]) -> list[tuple[Rect, list[_Placed]]]:
        groups: list[tuple[Rect, list[_Placed]]] = []
        for item in placed:
            half = item[1].half_extent_m()
            rect = self._pixel_rect(eye, item[2] - half, item[2] + half, 2)
            if rect is not None:
                groups.append((rect, [item]))
        merged = True
        while merged:
            merged = False
            for i in range(len(groups)):
                for j in range(i + 1, len(groups)):
                    a, b = groups[i][0], groups[j][0]
                    if a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]:
                        rect = (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
                        groups[i] = (rect, groups[i][1] + groups[j][1])
                        del groups[j]
                        merged = True
                        break
                if merged:
                    break
        return groups

    def _shade(
        self, solid: Shape, o: F64, s: F64, dx: F64, dy: F64, centre: F64, blockers: list[Blocker]
    ) -> F32:
        qx, qy, qz = o[0] + s * dx, o[1] + s * dy, o[2] + s
        nx, ny, nz = solid.normals(qx, qy, qz)
        if self.lamps is None:
            lt = self.lighting
            lv = lt.unit()
            lam = lt.ambient + lt.diffuse * np.maximum(0.0, nx * lv[0] + ny * lv[1] + nz * lv[2])
        else:
            p = np.stack([qx, qy, qz], axis=-1) + centre
            others = [b for b in blockers if b[0] is not solid]  # convex: no self-shadow
            lam = irradiance(self.lamps, p, np.stack([nx, ny, nz], axis=-1), others)
        col = np.asarray(solid.colour_bgr, np.float64)
        rad = lam[:, None] * col[None, :]
        if solid.stripe_bgr is not None and solid.stripe_half_width_m > 0.0:
            band = np.abs(qy - solid.stripe_offset_m) <= solid.stripe_half_width_m
            stripe = np.asarray(solid.stripe_bgr, np.float64)
            rad[band] = lam[band, None] * stripe[None, :]
        return rad.astype(np.float32)

    def _cast(
        self, eye: str, group: list[_Placed], dx: F64, dy: F64, blockers: list[Blocker]
    ) -> tuple[I32, F32]:
        """Nearest hit per ray: (local object id, i.e. index in :func:`_names`, or -1; shaded
        radiance or 0).  A solid of a many-part object is only cast for the rays that can
        meet its bounding box."""
        shape = np.broadcast_shapes(dx.shape, dy.shape)
        cam = self.rig.camera_centre(eye)
        best = np.full(shape, np.inf)
        part = np.full(shape, -1, np.int32)
        names = _names(group)
        dxb, dyb = np.broadcast_to(dx, shape), np.broadcast_to(dy, shape)
        # A coarse grid (a row of dx times a column of dy): a solid's window is a sub-grid.
        grid = dx.ndim == 2 and dy.ndim == 2 and dx.shape[0] == 1 and dy.shape[1] == 1
        whole = (slice(None), slice(None))
        # Per solid, the rays its hits lie among: a sub-grid, or flat indices (ascending).
        spans: list[tuple[slice, slice] | npt.NDArray[np.intp]] = []
        ranges: tuple[F64, F64, F64, F64] | None = None  # per row: dx min, max, dy min, max
        for k, (_, solid, centre) in enumerate(group):
            spans.append(whole)
            if len(names) == len(group):  # one solid per object: every ray is cast
                s = solid.intersect(cam - centre, dx, dy)
                closer = s < best
                best = np.where(closer, s, best)
                part[closer] = k
                continue
            lim = _slopes(solid.half_extent_m(), centre - cam)
            if lim is None:
                s = solid.intersect(cam - centre, dx, dy)
                closer = s < best
                best = np.where(closer, s, best)
                part[closer] = k
                continue
            if grid:
                cs = _span((dx[0] >= lim[0]) & (dx[0] <= lim[1]))
                rs = _span((dy[:, 0] >= lim[2]) & (dy[:, 0] <= lim[3]))
                if cs is None or rs is None:
                    spans[k] = (slice(0, 0), slice(0, 0))
                    continue
                spans[k] = (rs, cs)
                s = solid.intersect(cam - centre, dx[:, cs], dy[rs])
                sub = best[rs, cs]
                closer = s < sub
                sub[closer] = s[closer]
                part[rs, cs][closer] = k
                continue
            # Rows of rays (a refined pixel's): only the rows whose slope ranges meet the
            # window are tested ray by ray; the window's rays are the same, in the same order.
            if ranges is None:
                ranges = (dxb.min(axis=1), dxb.max(axis=1), dyb.min(axis=1), dyb.max(axis=1))
            rows = np.flatnonzero(
                (ranges[1] >= lim[0])
                & (ranges[0] <= lim[1])
                & (ranges[3] >= lim[2])
                & (ranges[2] <= lim[3])
            )
            sx, sy = dxb[rows], dyb[rows]
            window = (sx >= lim[0]) & (sx <= lim[1]) & (sy >= lim[2]) & (sy <= lim[3])
            idx = (rows[:, None] * shape[1] + np.arange(shape[1]))[window]
            spans[k] = idx
            if idx.size == 0:
                continue
            s = solid.intersect(cam - centre, sx[window], sy[window])
            flat = best.reshape(-1)
            closer = s < flat[idx]
            flat[idx[closer]] = s[closer]
            part.reshape(-1)[idx[closer]] = k
        rad = np.zeros((*shape, 3), np.float32)
        ids = np.full(shape, -1, np.int32)
        for k, (name, solid, centre) in enumerate(group):
            win = spans[k]  # row-major order within it is that of the whole grid
            if isinstance(win, np.ndarray):
                at = win[part.reshape(-1)[win] == k]
                if at.size:
                    ids.reshape(-1)[at] = names.index(name)
                    rad.reshape(-1, 3)[at] = self._shade(
                        solid,
                        cam - centre,
                        best.reshape(-1)[at],
                        dxb.reshape(-1)[at],
                        dyb.reshape(-1)[at],
                        centre,
                        blockers,
                    )
                continue
            m = part[win] == k
            if m.any():
                ids[win][m] = names.index(name)
                rad[win][m] = self._shade(
                    solid, cam - centre, best[win][m], dxb[win][m], dyb[win][m], centre, blockers
                )
        return ids, rad

    def _render_group(
        self,
        eye: str,
        rect: Rect,
        group: list[_Placed],
        want_image: bool,
        bg: F32,
        blockers: list[Blocker],
        keep: tuple[int, int],
    ) -> tuple[F32 | None, dict[str, float]]:
        """Radiance of the pixels of ``rect`` (background ``bg`` where no object is seen) and
        the coverage (px) of each object name, counted in rows ``keep`` only."""
        rig, q = self.rig, self.quality
        f, s = rig.focal_px, q.supersample
        r0, r1, c0, c1 = rect
        h, w = r1 - r0, c1 - c0
        # Coarse pass: an (S+1) x (S+1) grid per pixel that includes the pixel's borders (shared
        # with the neighbours), so a silhouette edge crossing a pixel always separates samples.
        m, n = np.arange(w * s + 1), np.arange(h * s + 1)
        u = (c0 + m // s - 0.5) + (m % s) / s  # same floats whatever the region origin
        v = (r0 + n // s - 0.5) + (n % s) / s
        du, dv = ((u - rig.cx) / f)[None, :], ((v - rig.cy) / f)[:, None]
        ids, rad = self._cast(eye, group, du, dv, blockers)
        cmin = np.minimum.reduce([ids[:, k : k + w * s : s] for k in range(s + 1)])
        cmax = np.maximum.reduce([ids[:, k : k + w * s : s] for k in range(s + 1)])
        idmin = np.minimum.reduce([cmin[k : k + h * s : s] for k in range(s + 1)])
        idmax = np.maximum.reduce([cmax[k : k + h * s : s] for k in range(s + 1)])
        mixed = (idmin != idmax).astype(np.uint8)
        ring = cv2.dilate(mixed, np.ones((3, 3), np.uint8)).astype(bool)
        pure = (idmin == idmax) & (idmin >= 0) & ~ring
        cov: dict[str, float] = {}
        out: F32 | None = None
        if want_image:
            out = bg[r0:r1, c0:c1].copy()
            ru = 0.5 * (rad[:, :-1] + rad[:, 1:])  # composite trapezoid rule over the pixel
            ruv = 0.5 * (ru[:-1] + ru[1:])
            out[pure] = _box_mean(ruv, h, w, s)[pure]
        kept = np.zeros((h, 1), bool)
        kept[max(0, keep[0] - r0) : max(0, keep[1] - r0)] = True
        for k, name in enumerate(_names(group)):
            cov[name] = cov.get(name, 0.0) + float(np.count_nonzero(pure & kept & (idmin == k)))
        # Edge pass on mixed pixels (E x E) and on their 8 neighbours, which can only hide
        # slivers < 1/(2 S^2) px between the coarse samples (ring_supersample^2 rays).
        mixed_b = mixed.astype(bool)
        for sel, rays in ((mixed_b, q.edge_supersample), (ring & ~mixed_b, q.ring_supersample)):
            rr, cc = np.nonzero(sel & kept)
            if rr.size:
                self._refine(eye, group, r0 + rr, c0 + cc, rays, out, rr, cc, cov, blockers, bg)
        return out, cov

    def _refine(
        self,
        eye: str,
        group: list[_Placed],
        rows: npt.NDArray[np.intp],
        cols: npt.NDArray[np.intp],
        e: int,
        out: F32 | None,
        rr: npt.NDArray[np.intp],
        cc: npt.NDArray[np.intp],
        cov: dict[str, float],
        blockers: list[Blocker],
        bg: F32,
    ) -> None:
        """Re-cast pixels (rows, cols) with an E x E sheared ("n-rooks") grid, stratified to
        1/E^2 along both axes; write them to out[rr, cc] and add their coverage to cov.

        Rays that miss every object see the wall or floor: its texture (no lamps), or, lit,
        its texture and unshadowed light per ray times the pixel's shadow ratio in ``bg``
        (the frame's shadowed background over the static lit one)."""
        rig = self.rig
        f = rig.focal_px
        i, j = np.meshgrid(np.arange(e), np.arange(e), indexing="ij")
        ox = ((i + (j + 0.5) / e) / e - 0.5).ravel()
        oy = ((j + (i + 0.5) / e) / e - 0.5).ravel()
        dx = (cols[:, None] + ox[None, :] - rig.cx) / f
        dy = (rows[:, None] + oy[None, :] - rig.cy) / f
        ids, rad = self._cast(eye, group, dx, dy, blockers)
        for k, name in enumerate(_names(group)):
            cov[name] += float(np.count_nonzero(ids == k)) / (e * e)
        if out is not None:
            miss = ids < 0
            if self.lamps is None:
                rad[miss] = self._bg_rays(eye, dx[miss], dy[miss], blockers)
            else:
                static = self._background_image(eye)[rows, cols]
                ratio = bg[rows, cols] / np.maximum(static, np.float32(1e-6))
                lit = self._bg_rays(eye, dx[miss], dy[miss], [])
                rad[miss] = lit * np.broadcast_to(ratio[:, None, :], rad.shape)[miss]
            out[rr, cc] = rad.mean(axis=1)


def _box_mean(ruv: npt.NDArray[Any], h: int, w: int, s: int) -> npt.NDArray[Any]:
    """Mean of each S x S block of ``ruv`` (h S, w S, 3): ``reshape(h, s, w, s, 3).mean(axis=(1,
    3))`` summed in the same order (block rows, then columns) without numpy's slow
    many-axis reduction, so the same float32 bits."""
    v = ruv.reshape(h, s, w, s, 3)
    acc = v[:, 0, :, 0].copy()
    for i in range(s):
        for j in range(s):
            if i or j:
                acc += v[:, i, :, j]
    acc /= np.float32(s * s)
    return acc


def _names(group: list[_Placed]) -> list[str]:
    """Object names of a group, each once, in order of first appearance."""
    return list(dict.fromkeys(name for name, _, _ in group))


def _slopes(half: F64, rel: F64) -> tuple[float, float, float, float] | None:
    """Bounds (dx lo, dx hi, dy lo, dy hi) of the rays (dx, dy, 1) that can meet the box
    ``rel +- half`` (relative to the camera), or None when the box reaches behind the near
    plane (then every ray is a candidate)."""
    lo, hi = rel - half, rel + half
    if lo[2] <= _NEAR_M:
        return None
    xs = [lo[0] / lo[2], lo[0] / hi[2], hi[0] / lo[2], hi[0] / hi[2]]
    ys = [lo[1] / lo[2], lo[1] / hi[2], hi[1] / lo[2], hi[1] / hi[2]]
    eps = 1e-9
    return (
        float(min(xs) - eps),
        float(max(xs) + eps),
        float(min(ys) - eps),
        float(max(ys) + eps),
    )


def _span(sel: npt.NDArray[np.bool_]) -> slice | None:
    """The slice of the True entries of ``sel`` (True on one run: the rays' slopes grow
    along the grid), or None if there are none."""
    idx = np.flatnonzero(sel)
    if idx.size == 0:
        return None
    if idx[-1] - idx[0] + 1 != idx.size:
        raise ValueError("ray slopes of a coarse grid must be monotonic")
    return slice(int(idx[0]), int(idx[-1]) + 1)
