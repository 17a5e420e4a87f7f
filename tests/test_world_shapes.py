"""Ray intersection of the solids (capsule; shadow rays of any direction) against brute force."""

from __future__ import annotations

import numpy as np

from stereod_fakes.world import Box, Capsule, Cylinder, Sphere, Trajectory

STILL = Trajectory((0.0, 0.0, 0.0))


def march(solid, o: np.ndarray, d: np.ndarray, t_max: float = 3.0, n: int = 30001) -> np.ndarray:
    """First t on a fine grid where o + t d is inside the solid (inf if never): brute force."""
    ts = np.linspace(0.0, t_max, n)[1:]
    out = np.full(len(o), np.inf)
    for i in range(len(o)):
        inside = solid.contains(o[i] + ts[:, None] * d[i])
        if inside.any():
            out[i] = ts[np.argmax(inside)]
    return out


def test_hits_of_rays_in_any_direction_match_marching() -> None:
    rng = np.random.default_rng(3)
    solids = [
        Capsule(name="c", trajectory=STILL, radius_m=0.1, half_axis_m=(0.15, -0.2, 0.1)),
        Capsule(name="k", trajectory=STILL, radius_m=0.07, half_axis_m=(0.0, 0.0, 0.0)),
        Sphere(name="s", trajectory=STILL, radius_m=0.2),
        Cylinder(name="y", trajectory=STILL, radius_m=0.15, height_m=0.3),
        Box(name="b", trajectory=STILL, half_size_m=(0.2, 0.1, 0.15)),
    ]
    o = rng.normal(size=(300, 3))
    o *= (1.0 / np.linalg.norm(o, axis=1))[:, None]  # start 1 m from the centre
    aim = rng.uniform(-0.12, 0.12, size=(300, 3)) - o  # towards points near the solid
    d = aim / np.linalg.norm(aim, axis=1)[:, None]
    for solid in solids:
        got = solid.hit(o, d)
        want = march(solid, o, d)
        assert np.all(np.isinf(got) == np.isinf(want)), solid.name
        fin = np.isfinite(got)
        assert fin.sum() > 30, solid.name
        assert np.abs(got[fin] - want[fin]).max() < 2e-4, solid.name
        # Camera rays (dx, dy, 1) of the capsule: the same first hit.
        if isinstance(solid, Capsule):
            dz = d[:, 2] > 0.2
            s = solid.intersect(o[dz][0], d[dz][:1, 0] / d[dz][:1, 2], d[dz][:1, 1] / d[dz][:1, 2])
            t = solid.hit(o[dz][:1], d[dz][:1] / d[dz][:1, 2:])
            assert np.allclose(s, np.where(t > 0.01, t, np.inf))


def test_capsule_normals_and_volume() -> None:
    cap = Capsule(name="c", trajectory=STILL, radius_m=0.1, half_axis_m=(0.0, 0.3, 0.0))
    nx, ny, nz = cap.normals(np.array([0.1, 0.0]), np.array([0.1, 0.4]), np.array([0.0, 0.0]))
    np.testing.assert_allclose([nx, ny, nz], [[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]], atol=1e-12)
    g = (np.arange(-50, 50) + 0.5) * 0.01
    pts = np.stack(np.meshgrid(g[40:60], g, g[40:60], indexing="ij"), axis=-1).reshape(-1, 3)
    vol = cap.contains(pts).sum() * 1e-6
    assert abs(vol - cap.volume_m3()) < 0.02 * cap.volume_m3()
