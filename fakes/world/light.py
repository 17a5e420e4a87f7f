"""Light: the directional light of the objects, and lamps (point, area) that cast shadows."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from ._base import F64, Vec3, _build


@dataclass(frozen=True)
class Lighting:
    """Lambert: radiance = colour * (ambient + diffuse * max(0, n . l)), l = towards the light."""

    towards_light: Vec3 = (-0.3, -1.0, -0.5)  # up (-Y), a bit left and towards the cameras
    ambient: float = 0.35
    diffuse: float = 0.75

    def unit(self) -> F64:
        v = np.asarray(self.towards_light, dtype=np.float64)
        return v / np.linalg.norm(v)


@dataclass(frozen=True)
class PointLight:
    """A lamp at ``position_m`` (rig frame).  Its irradiance on a surface facing it squarely
    at distance d is ``intensity * (reference_m / d)^2`` (inverse square law)."""

    position_m: Vec3
    intensity: float = 0.8
    reference_m: float = 2.0


@dataclass(frozen=True)
class AreaLight:
    """A rectangular lamp (soft shadows): centre plus two full edge vectors, sampled as an
    ``samples`` x ``samples`` grid of point lights (cell centres) sharing ``intensity``."""

    centre_m: Vec3
    edge_u_m: Vec3 = (0.4, 0.0, 0.0)
    edge_v_m: Vec3 = (0.0, 0.0, 0.4)
    intensity: float = 0.8
    reference_m: float = 2.0
    samples: int = 4


@dataclass(frozen=True)
class Lamps:
    """Lamps lighting the whole room, with cast shadows: surfaces (wall, floor, objects) get
    ``albedo * (ambient + sum over lamps of visible irradiance * max(0, n . l))``.

    A Scene without lamps (the default) keeps the unlit wall and floor and the directional
    :class:`Lighting` of the objects, without shadows.
    """

    ambient: float = 0.35
    points: tuple[PointLight, ...] = ()
    areas: tuple[AreaLight, ...] = ()

    def samples(self) -> tuple[F64, F64]:
        """Point-light positions (K, 3) m and their intensities at 1 m (K,)."""
        pos: list[F64] = []
        w: list[float] = []
        for p in self.points:
            pos.append(np.asarray(p.position_m, dtype=np.float64))
            w.append(p.intensity * p.reference_m**2)
        for a in self.areas:
            n = max(1, int(a.samples))
            g = (np.arange(n) + 0.5) / n - 0.5
            c = np.asarray(a.centre_m, dtype=np.float64)
            eu, ev = np.asarray(a.edge_u_m, np.float64), np.asarray(a.edge_v_m, np.float64)
            for i in g:
                for j in g:
                    pos.append(c + i * eu + j * ev)
                    w.append(a.intensity * a.reference_m**2 / (n * n))
        return np.reshape(np.asarray(pos, dtype=np.float64), (-1, 3)), np.asarray(w, np.float64)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Lamps:
        """Rebuild lamps from their ``asdict`` form in scene.json."""
        return cls(
            ambient=float(d.get("ambient", 0.35)),
            points=tuple(_build(PointLight, p) for p in d.get("points", [])),
            areas=tuple(_build(AreaLight, a) for a in d.get("areas", [])),
        )


Blocker = tuple[Any, F64]  # (solid with hit() and bound_m(), centre)


def irradiance(
    lamps: Lamps, p: F64, n: F64, blockers: Sequence[Blocker], shadows: bool = True
) -> F64:
    """Relative irradiance ``ambient + sum_k w_k vis_k max(0, n . l_k) / d_k^2`` at points p
    (N, 3) with unit normals n (N, 3); vis_k = 0 when a blocker cuts the segment to lamp k.

    The shadow ray starts 1 mm off the surface along n; a blocker is only tested for the
    rays passing within its bounding sphere (no per-pixel Python loops).
    """
    pos, w = lamps.samples()
    out = np.full(len(p), lamps.ambient, dtype=np.float64)
    start = p + 1e-3 * n
    for lp, wk in zip(pos, w, strict=True):
        d = lp - start
        dist2 = np.einsum("ij,ij->i", d, d)
        cos = np.einsum("ij,ij->i", n, lp - p) / np.sqrt(np.maximum(dist2, 1e-18))
        lit = cos > 0.0
        if shadows and blockers:
            lit &= ~occluded(start, d, blockers, lit)
        out += np.where(lit, wk * cos / np.maximum(dist2, 1e-18), 0.0)
    return out


def occluded(
    start: F64, d: F64, blockers: Sequence[Blocker], todo: npt.NDArray[np.bool_] | None = None
) -> npt.NDArray[np.bool_]:
    """Whether segments ``start + t d`` (t in (0, 1)) hit a blocker (only where ``todo``)."""
    hit = np.zeros(len(start), bool)
    idx_all = np.arange(len(start)) if todo is None else np.nonzero(todo)[0]
    if idx_all.size == 0:
        return hit
    sx, sy, sz = (np.ascontiguousarray(start[idx_all, i]) for i in range(3))
    ex, ey, ez = (np.ascontiguousarray(d[idx_all, i]) for i in range(3))
    dd = np.maximum(ex * ex + ey * ey + ez * ez, 1e-18)
    done = np.zeros(idx_all.size, bool)
    for solid, centre in blockers:
        # Distance from the bounding sphere's centre to each segment: a cheap conservative cull.
        rx, ry, rz = centre[0] - sx, centre[1] - sy, centre[2] - sz
        t = np.clip((rx * ex + ry * ey + rz * ez) / dd, 0.0, 1.0)
        gx, gy, gz = rx - t * ex, ry - t * ey, rz - t * ez
        near = (gx * gx + gy * gy + gz * gz <= solid.bound_m() ** 2) & ~done
        sel = np.nonzero(near)[0]
        if sel.size:
            idx = idx_all[sel]
            th = solid.hit(start[idx] - centre, d[idx])
            done[sel[th < 1.0]] = True
    hit[idx_all[done]] = True
    return hit
