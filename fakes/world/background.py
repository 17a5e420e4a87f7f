"""What the cameras see behind the objects: the wall and the floor, unlit or lit by lamps.

A mixin of :class:`~.scene.Scene`.  Without lamps the background is the texture itself
(radiance = texture).  With lamps a surface point's radiance is ``texture * irradiance``
(:func:`~.light.irradiance`, floor normal up, wall normal towards the rig).  The static lit
background is cast once per eye like the unlit one; per frame only the pixels that may lie in
a shadow are re-lit: a pixel whose centre's segment to a lamp passes within 2 cm of an
object's bounding sphere, and its 8 neighbours.  Those pixels take the static lit value times
the ratio of the mean shadowed to the mean unshadowed irradiance over an S x S grid of rays
(``Quality.shadow_supersample``); fully lit pixels keep the static value exactly.  Pixels
re-cast at an object's edge apply their pixel's ratio to the unshadowed light of each ray.
"""

from __future__ import annotations

from functools import cached_property

import cv2
import numpy as np
import numpy.typing as npt

from ._base import EYES, F32, F64, _eye_index
from .camera import Quality, Rig
from .light import Blocker, Lamps, irradiance
from .textures import Room, _bilinear, _make_textures, _remap, _Textures

Bound = tuple[F64, float]  # (centre m, radius m) of an object's bounding sphere


class _Backdrop:
    """Wall and floor radiance; the scene supplies the fields."""

    rig: Rig
    room: Room
    quality: Quality
    seed: int
    lamps: Lamps | None

    @cached_property
    def _textures(self) -> _Textures:
        return _make_textures(self.rig, self.room, self.seed)

    @cached_property
    def _bg_cache(self) -> dict[str, F32]:
        return {}

    def _background(self, eye: str, dx: F64, dy: F64) -> F32:
        """Radiance of the wall / floor along rays (dx, dy, 1) from the eye's centre."""
        room = self.room
        cam_x = float(self.rig.camera_centre(eye)[0])
        zw = room.wall_distance_m
        shape = np.broadcast_shapes(np.shape(dx), np.shape(dy))
        dxb, dyb = np.broadcast_to(dx, shape), np.broadcast_to(dy, shape)
        if room.floor_height_m is not None:
            yf = room.floor_height_m
            on_floor = dyb * zw > yf
            s = np.where(on_floor, yf / np.where(on_floor, dyb, 1.0), zw)
        else:
            on_floor = np.zeros(shape, bool)
            s = np.full(shape, zw)
        if room.texture == "flat":
            wall = np.asarray(room.flat_wall_bgr, np.float32)
            flo = np.asarray(room.flat_floor_bgr, np.float32)
            return np.where(on_floor[..., None], flo, wall).astype(np.float32)
        tex = self._textures
        tau = tex.texel
        x = cam_x + s * dxb
        wy, wx = tex.wall_shape
        fz, fx = tex.floor_shape
        mx_w = np.clip((x - tex.wall_x0) / tau - 0.5, 0.0, wx - 1.0)
        my_w = np.clip((zw * dyb - tex.wall_y0) / tau - 0.5, 0.0, wy - 1.0)
        mx_f = np.clip((x - tex.floor_x0) / tau - 0.5, 0.0, fx - 1.0)
        my_f = tex.floor_row0 + np.clip((s - tex.floor_z0) / tau - 0.5, 0.0, fz - 1.0)
        mx = np.where(on_floor, mx_f, mx_w).astype(np.float32)
        my = np.where(on_floor, my_f, my_w).astype(np.float32)
        return _remap(tex.atlas, mx, my)

    def _background_image(self, eye: str) -> F32:
        cache = self._bg_cache
        if eye not in cache:
            rig = self.rig
            s = self.quality.background_supersample
            f = rig.focal_px
            w, h = rig.width_px, rig.height_px
            offs = (np.arange(s) + 0.5) / s - 0.5
            dx = ((np.arange(w)[:, None] + offs[None, :]).ravel() - rig.cx) / f
            out = np.empty((h, w, 3), np.float32)
            step = max(1, (1 << 19) // (w * s * s))
            for r0 in range(0, h, step):
                r1 = min(h, r0 + step)
                v = (np.arange(r0, r1)[:, None] + offs[None, :]).ravel()
                samp = self._bg_rays(eye, dx[None, :], ((v - rig.cy) / f)[:, None], [])
                out[r0:r1] = samp.reshape(r1 - r0, s, w, s, 3).mean(axis=(1, 3))
            cache[eye] = out
        return cache[eye]

    def background_radiance(self, eye: str) -> F32:
        """Static background radiance image of an eye (before photometry), float32 BGR."""
        return self._background_image(EYES[_eye_index(eye)]).copy()

    def wall_radiance(self, x: npt.ArrayLike, y: npt.ArrayLike) -> F64:
        """Wall texture (BGR radiance) at world points (x, y, wall distance)."""
        xa, ya = np.asarray(x, np.float64), np.asarray(y, np.float64)
        if self.room.texture == "flat":
            return np.broadcast_to(np.asarray(self.room.flat_wall_bgr, np.float64), (*xa.shape, 3))
        t = self._textures
        wall = t.atlas[: t.wall_shape[0], : t.wall_shape[1]]
        return _bilinear(wall, (xa - t.wall_x0) / t.texel - 0.5, (ya - t.wall_y0) / t.texel - 0.5)

    def floor_radiance(self, x: npt.ArrayLike, z: npt.ArrayLike) -> F64:
        """Floor texture (BGR radiance) at world points (x, floor height, z)."""
        xa, za = np.asarray(x, np.float64), np.asarray(z, np.float64)
        if self.room.texture == "flat":
            return np.broadcast_to(np.asarray(self.room.flat_floor_bgr, np.float64), (*xa.shape, 3))
        t = self._textures
        fl = t.atlas[t.floor_row0 : t.floor_row0 + t.floor_shape[0], : t.floor_shape[1]]
        return _bilinear(fl, (xa - t.floor_x0) / t.texel - 0.5, (za - t.floor_z0) / t.texel - 0.5)

    # -- lamps and shadows --------------------------------------------------------------------

    def _surface(self, eye: str, dx: F64, dy: F64) -> tuple[F64, F64]:
        """World points (N, 3) and unit normals (N, 3) where rays (dx, dy, 1) meet the room."""
        room = self.room
        cam_x = float(self.rig.camera_centre(eye)[0])
        zw = room.wall_distance_m
        dxb, dyb = (np.ravel(a) for a in np.broadcast_arrays(dx, dy))
        if room.floor_height_m is not None:
            on_floor = dyb * zw > room.floor_height_m
            s = np.where(on_floor, room.floor_height_m / np.where(on_floor, dyb, 1.0), zw)
        else:
            on_floor = np.zeros(dxb.shape, bool)
            s = np.full(dxb.shape, zw)
        p = np.stack([cam_x + s * dxb, s * dyb, s], axis=-1)
        n = np.zeros_like(p)
        n[:, 1] = np.where(on_floor, -1.0, 0.0)
        n[:, 2] = np.where(on_floor, 0.0, -1.0)
        return p, n

    def _bg_rays(self, eye: str, dx: F64, dy: F64, blockers: list[Blocker]) -> F32:
        """Background radiance along rays, lit by the lamps with shadows (texture if none)."""
        tex = self._background(eye, dx, dy)
        if self.lamps is None:
            return tex
        p, n = self._surface(eye, dx, dy)
        irr = irradiance(self.lamps, p, n, blockers).reshape(tex.shape[:-1])
        return (tex * irr[..., None]).astype(np.float32)

    @cached_property
    def _centres(self) -> dict[str, tuple[F64, F64]]:
        """Per eye: room points and normals at the pixel centres, (H, W, 3) each."""
        rig = self.rig
        out: dict[str, tuple[F64, F64]] = {}
        for eye in EYES:
            dx = np.asarray((np.arange(rig.width_px) - rig.cx) / rig.focal_px, np.float64)
            dy = np.asarray((np.arange(rig.height_px) - rig.cy) / rig.focal_px, np.float64)
            p, n = self._surface(eye, dx[None, :], dy[:, None])
            shape = (rig.height_px, rig.width_px, 3)
            out[eye] = (p.reshape(shape), n.reshape(shape))
        return out

    def _shadowed(
        self, eye: str, blockers: list[Blocker], bounds: list[Bound], r0: int, r1: int
    ) -> F32:
        """The lit background with the objects' shadows in rows [r0, r1) (others static)."""
        out = self._background_image(eye).copy()
        if self.lamps is None or not blockers or r1 <= r0:
            return out
        lamp_pos, _ = self.lamps.samples()
        p, n = self._centres[eye]
        p, n = p[r0:r1].reshape(-1, 3), n[r0:r1].reshape(-1, 3)
        maybe = np.zeros(len(p), bool)
        for lp in lamp_pos:
            d = lp - p
            dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-18)
            for centre, radius in bounds:
                rel = centre - p
                t = np.clip(np.einsum("ij,ij->i", rel, d) / dd, 0.0, 1.0)
                gap = rel - t[:, None] * d
                maybe |= np.einsum("ij,ij->i", gap, gap) <= (radius + 0.02) ** 2
        w = self.rig.width_px
        mask = cv2.dilate(maybe.reshape(r1 - r0, w).astype(np.uint8), np.ones((3, 3), np.uint8))
        rr, cc = np.nonzero(mask)
        if rr.size == 0:
            return out
        rows = rr + r0
        s = max(1, self.quality.shadow_supersample)
        offs = (np.arange(s) + 0.5) / s - 0.5
        ox, oy = (a.ravel() for a in np.meshgrid(offs, offs))
        f = self.rig.focal_px
        dx = (cc[:, None] + ox[None, :] - self.rig.cx) / f
        dy = (rows[:, None] + oy[None, :] - self.rig.cy) / f
        sp, sn = self._surface(eye, dx, dy)
        lit = irradiance(self.lamps, sp, sn, blockers).reshape(-1, s * s).mean(axis=1)
        full = irradiance(self.lamps, sp, sn, [], shadows=False).reshape(-1, s * s).mean(axis=1)
        ratio = (lit / np.maximum(full, 1e-12)).astype(np.float32)
        out[rows, cc] *= ratio[:, None]
        return out
