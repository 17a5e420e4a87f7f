"""Solids (sphere, upright cylinder, axis-aligned box, capsule) and their ray intersections.

Camera rays are ``c + s (dx, dy, 1)`` (``s`` = depth travelled); shadow rays have any
direction (:meth:`_Solid.hit`).  Each solid's ``trajectory`` moves its volume centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ._base import _NEAR_M, F64, Vec3
from .motion import Motion


@dataclass(frozen=True, kw_only=True)
class _Solid:
    """Common fields: a name, a trajectory of the volume centre, colour and an optional band.

    The band (``stripe_bgr``) covers the points whose local y (relative to the centre) is
    within ``stripe_half_width_m`` of ``stripe_offset_m`` (a horizontal band).
    """

    name: str
    trajectory: Motion
    colour_bgr: Vec3 = (40.0, 120.0, 230.0)
    stripe_bgr: Vec3 | None = None
    stripe_half_width_m: float = 0.0
    stripe_offset_m: float = 0.0

    def half_extent_m(self) -> F64:
        raise NotImplementedError

    # -- the object interface shared with articulated figures ---------------------------------

    def present(self, t_s: float) -> bool:
        """Whether the solid is in the scene at ``t_s``."""
        return self.trajectory.present(t_s)

    def parts(self, t_s: float) -> list[tuple[Shape, F64]]:
        """The solids making up the object at ``t_s`` with their centres: here only itself."""
        return [(self, self.trajectory.position(t_s))]  # type: ignore[list-item]

    def state(self, t_s: float) -> tuple[F64, F64]:
        """Truth (centre m, velocity m/s) at ``t_s``: the volume centre and its velocity."""
        return self.trajectory.state(t_s)

    def bound_m(self) -> float:
        """Radius of a sphere about the centre that contains the solid, m."""
        return float(np.linalg.norm(self.half_extent_m()))

    def hit(self, o: F64, d: F64) -> F64:
        """Ray parameter t > 1e-9 of the first hit of rays ``o + t d`` (o relative to the
        centre; both (N, 3)), inf where missed.  Used for shadow rays of any direction."""
        raise NotImplementedError

    def contains(self, q: F64) -> npt.NDArray[np.bool_]:
        """Whether points q (N, 3) relative to the centre are inside the solid."""
        raise NotImplementedError

    def volume_m3(self) -> float:
        """Volume of the solid, m^3."""
        raise NotImplementedError

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        """Ray depth s (= Z travelled) of the first hit of rays ``c + s (dx, dy, 1)``.

        ``o`` = camera centre minus object centre.  Returns inf where missed.
        """
        raise NotImplementedError

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        """Outward unit normals at surface points q (relative to the centre)."""
        raise NotImplementedError


@dataclass(frozen=True, kw_only=True)
class Sphere(_Solid):
    radius_m: float

    def half_extent_m(self) -> F64:
        return np.full(3, self.radius_m)

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        ox, oy, oz = (float(x) for x in o)
        r = self.radius_m
        a = dx * dx + dy * dy + 1.0
        b = ox * dx + oy * dy + oz
        c = ox * ox + oy * oy + oz * oz - r * r
        disc = b * b - a * c
        s = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        return np.where((disc >= 0.0) & (s > _NEAR_M), s, np.inf)

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        n = np.sqrt(qx * qx + qy * qy + qz * qz)
        return qx / n, qy / n, qz / n

    def hit(self, o: F64, d: F64) -> F64:
        return _first(*_sphere_roots(o, d, self.radius_m))

    def contains(self, q: F64) -> npt.NDArray[np.bool_]:
        return np.asarray(np.einsum("ij,ij->i", q, q) <= self.radius_m**2)

    def volume_m3(self) -> float:
        return 4.0 / 3.0 * math.pi * self.radius_m**3


@dataclass(frozen=True, kw_only=True)
class Cylinder(_Solid):
    """Upright cylinder (axis parallel to Y), like a small round robot."""

    radius_m: float
    height_m: float

    def half_extent_m(self) -> F64:
        return np.array([self.radius_m, 0.5 * self.height_m, self.radius_m])

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        ox, oy, oz = (float(x) for x in o)
        r, h = self.radius_m, 0.5 * self.height_m
        a = dx * dx + 1.0
        b = ox * dx + oz
        c = ox * ox + oz * oz - r * r
        disc = b * b - a * c
        s_side = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        y = oy + s_side * dy
        ok = (disc >= 0.0) & (s_side > _NEAR_M) & (np.abs(y) <= h)
        s = np.where(ok, s_side, np.inf)
        if abs(oy) > h:  # the camera sees one cap
            yc = -h if oy < -h else h
            with np.errstate(divide="ignore", invalid="ignore"):
                s_cap = (yc - oy) / dy
                xc = ox + s_cap * dx
                zc = oz + s_cap
                cap = np.isfinite(s_cap) & (s_cap > _NEAR_M) & (xc * xc + zc * zc <= r * r)
            s = np.where(cap & (s_cap < s), s_cap, s)
        return np.broadcast_to(s, np.broadcast_shapes(np.shape(dx), np.shape(dy)))

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        rho = np.sqrt(qx * qx + qz * qz)
        side = np.abs(rho - self.radius_m) < np.abs(np.abs(qy) - 0.5 * self.height_m)
        safe = np.where(rho > 0.0, rho, 1.0)
        nx = np.where(side, qx / safe, 0.0)
        ny = np.where(side, 0.0, np.sign(qy))
        nz = np.where(side, qz / safe, 0.0)
        return nx, ny, nz

    def hit(self, o: F64, d: F64) -> F64:
        r, h = self.radius_m, 0.5 * self.height_m
        a = d[:, 0] ** 2 + d[:, 2] ** 2
        b = o[:, 0] * d[:, 0] + o[:, 2] * d[:, 2]
        c = o[:, 0] ** 2 + o[:, 2] ** 2 - r * r
        cands = []
        for t in _roots(a, b, c):
            cands.append(np.where(np.abs(o[:, 1] + t * d[:, 1]) <= h, t, np.nan))
        with np.errstate(divide="ignore", invalid="ignore"):
            for yc in (-h, h):
                t = (yc - o[:, 1]) / d[:, 1]
                x, z = o[:, 0] + t * d[:, 0], o[:, 2] + t * d[:, 2]
                cands.append(np.where(x * x + z * z <= r * r, t, np.nan))
        return _first(*cands)

    def contains(self, q: F64) -> npt.NDArray[np.bool_]:
        rho2 = q[:, 0] ** 2 + q[:, 2] ** 2
        return np.asarray((rho2 <= self.radius_m**2) & (np.abs(q[:, 1]) <= 0.5 * self.height_m))

    def volume_m3(self) -> float:
        return math.pi * self.radius_m**2 * self.height_m


@dataclass(frozen=True, kw_only=True)
class Box(_Solid):
    """Axis-aligned box with half sizes (hx, hy, hz)."""

    half_size_m: Vec3

    def half_extent_m(self) -> F64:
        return np.asarray(self.half_size_m, dtype=np.float64)

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        hx, hy, hz = (float(x) for x in self.half_size_m)
        ox, oy, oz = (float(x) for x in o)
        with np.errstate(divide="ignore", invalid="ignore"):
            ix = 1.0 / dx
            iy = 1.0 / dy
            ax, bx = (-hx - ox) * ix, (hx - ox) * ix
            ay, by = (-hy - oy) * iy, (hy - oy) * iy
            az, bz = -hz - oz, hz - oz
            t_in = np.maximum(np.maximum(np.minimum(ax, bx), np.minimum(ay, by)), min(az, bz))
            t_out = np.minimum(np.minimum(np.maximum(ax, bx), np.maximum(ay, by)), max(az, bz))
            hit = (t_in <= t_out) & (t_in > _NEAR_M)
        return np.where(hit, t_in, np.inf)

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        h = self.half_extent_m()
        r0, r1, r2 = np.abs(qx) / h[0], np.abs(qy) / h[1], np.abs(qz) / h[2]
        axis = np.asarray(r1 > r0).astype(np.intp)  # argmax of (r0, r1, r2): first maximum
        axis[r2 > np.maximum(r0, r1)] = 2
        return tuple(  # type: ignore[return-value]
            np.where(axis == i, np.sign(q), 0.0) for i, q in enumerate((qx, qy, qz))
        )

    def hit(self, o: F64, d: F64) -> F64:
        h = self.half_extent_m()
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            a, b = (-h - o) * inv, (h - o) * inv
            t_in = np.nanmax(np.fmin(a, b), axis=1)
            t_out = np.nanmin(np.fmax(a, b), axis=1)
        ok = t_in <= t_out
        return _first(np.where(ok, t_in, np.nan), np.where(ok, t_out, np.nan))

    def contains(self, q: F64) -> npt.NDArray[np.bool_]:
        return np.asarray(np.all(np.abs(q) <= self.half_extent_m(), axis=1))

    def volume_m3(self) -> float:
        return float(8.0 * np.prod(self.half_extent_m()))


@dataclass(frozen=True, kw_only=True)
class Capsule(_Solid):
    """Capsule: the points within ``radius_m`` of the segment from ``-half_axis_m`` to
    ``+half_axis_m`` about the centre (any orientation; a limb or a torso)."""

    radius_m: float
    half_axis_m: Vec3

    def half_extent_m(self) -> F64:
        return np.abs(np.asarray(self.half_axis_m, dtype=np.float64)) + self.radius_m

    def bound_m(self) -> float:
        return float(np.linalg.norm(self.half_axis_m)) + self.radius_m

    def hit(self, o: F64, d: F64) -> F64:
        ax = np.asarray(self.half_axis_m, dtype=np.float64)
        r = self.radius_m
        aa = float(ax @ ax)
        cands = [*_sphere_roots(o - ax, d, r), *_sphere_roots(o + ax, d, r)]
        if aa > 0.0:
            # Side: |(o + t d) - ((o + t d).u) u|^2 = r^2 with u = ax / |ax|, |axial| <= |ax|.
            u = ax / math.sqrt(aa)
            od, dd = o @ u, d @ u
            po, pd = o - od[:, None] * u, d - dd[:, None] * u
            a = (pd * pd).sum(axis=1)
            b = (po * pd).sum(axis=1)
            c = (po * po).sum(axis=1) - r * r
            for t in _roots(a, b, c):
                cands.append(np.where(np.abs(od + t * dd) <= math.sqrt(aa), t, np.nan))
        return _first(*cands)

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        # :meth:`hit` with a common origin and dz = 1: the per-ray constants become scalars,
        # each float computed with the same operations in the same order (same bits).
        shape = np.broadcast_shapes(np.shape(dx), np.shape(dy))
        ex = np.broadcast_to(dx, shape).reshape(-1)
        ey = np.broadcast_to(dy, shape).reshape(-1)
        ox, oy, oz = (float(x) for x in o)
        ax = np.asarray(self.half_axis_m, dtype=np.float64)
        r = self.radius_m
        aa = float(ax @ ax)
        a = ex * ex
        a += ey * ey
        a += 1.0
        best = np.full(a.shape, np.inf)
        for sign in (-1.0, 1.0):
            px, py, pz = (
                ox + sign * float(ax[0]),
                oy + sign * float(ax[1]),
                oz + sign * float(ax[2]),
            )
            b = px * ex
            b += py * ey
            b += pz
            _closest(best, a, b, px * px + py * py + pz * pz - r * r)
        if aa > 0.0:
            u = ax / math.sqrt(aa)
            u0, u1, u2 = (float(x) for x in u)
            od = ox * u0 + oy * u1 + oz * u2
            dd = np.stack([ex, ey, np.ones(ex.shape)], axis=-1) @ u  # BLAS, as in hit()
            p0, p1, p2 = ox - od * u0, oy - od * u1, oz - od * u2
            q0, q1, q2 = ex - dd * u0, ey - dd * u1, 1.0 - dd * u2
            sa = q0 * q0
            sa += q1 * q1
            sa += q2 * q2
            sb = p0 * q0
            sb += p1 * q1
            sb += p2 * q2
            _closest(best, sa, sb, p0 * p0 + p1 * p1 + p2 * p2 - r * r, od, dd, math.sqrt(aa))
        best[best <= _NEAR_M] = np.inf
        return best.reshape(shape)

    def _axial(self, q: F64) -> F64:
        ax = np.asarray(self.half_axis_m, dtype=np.float64)
        aa = float(ax @ ax)
        k = np.clip(q @ ax / aa, -1.0, 1.0) if aa > 0.0 else np.zeros(len(q))
        return np.asarray(q - k[:, None] * ax)

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        n = self._axial(np.stack([qx, qy, qz], axis=-1).reshape(-1, 3))
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
        shape = np.shape(qx)
        return n[:, 0].reshape(shape), n[:, 1].reshape(shape), n[:, 2].reshape(shape)

    def contains(self, q: F64) -> npt.NDArray[np.bool_]:
        n = self._axial(q)
        return np.asarray(np.einsum("ij,ij->i", n, n) <= self.radius_m**2)

    def volume_m3(self) -> float:
        length = 2.0 * float(np.linalg.norm(self.half_axis_m))
        return math.pi * self.radius_m**2 * (length + 4.0 / 3.0 * self.radius_m)


def _roots(a: F64, b: F64, c: F64) -> tuple[F64, F64]:
    """Both roots of a t^2 + 2 b t + c = 0 (nan where none or a = 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - a * c
        sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        return (-b - sq) / a, (-b + sq) / a


def _sphere_roots(o: F64, d: F64, r: float) -> tuple[F64, F64]:
    ox, oy, oz, dx, dy, dz = o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2]
    a = dx * dx + dy * dy + dz * dz
    b = ox * dx + oy * dy + oz * dz
    c = ox * ox + oy * oy + oz * oz - r * r
    return _roots(a, b, c)


def _closest(
    best: F64, a: F64, b: F64, c: float, od: float = 0.0, dd: F64 | None = None, lim: float = 0.0
) -> None:
    """Lower ``best`` in place to the roots t > 1e-9 of a t^2 + 2 b t + c = 0 (as
    :func:`_roots` and :func:`_first`), only those with |od + t dd| <= lim if ``dd`` is given.
    The far root (never below the near one) is only solved where the near one is no hit."""
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b
        disc -= a * c
        sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        nb = -b
        t = nb - sq
        t /= a
        ok = t > 1e-9
        if dd is not None:
            ok &= np.abs(od + t * dd) <= lim
        rest = np.flatnonzero(~ok & (disc >= 0.0))
        ok &= t < best
        np.copyto(best, t, where=ok)
        if rest.size:
            t = (nb[rest] + sq[rest]) / a[rest]
            ok = t > 1e-9
            if dd is not None:
                ok &= np.abs(od + t * dd[rest]) <= lim
            ok &= t < best[rest]
            best[rest[ok]] = t[ok]


def _first(*cands: F64) -> F64:
    """Smallest candidate t > 1e-9 per ray (nan / non-positive ignored), inf if none."""
    out = np.full(np.shape(cands[0]), np.inf)
    for t in cands:
        ok = np.isfinite(t) & (t > 1e-9)
        out = np.where(ok & (t < out), t, out)
    return out


Shape = Sphere | Cylinder | Box | Capsule
_SHAPES: dict[str, type[Sphere] | type[Cylinder] | type[Box] | type[Capsule]] = {
    "Capsule": Capsule,
    "Sphere": Sphere,
    "Cylinder": Cylinder,
    "Box": Box,
}
