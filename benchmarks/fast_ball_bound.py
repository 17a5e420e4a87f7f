"""How well a thrown ball's heading and speed can be known from its frames at all.

For each thrown-ball scene of ``make accuracy`` (the independent renderer's ``fast_ball``:
10 and 20 m/s, across the view and towards the rig), takes the ball's true centre at each
frame it is in view, projects it into both eyes, adds the centroid error the pipeline assumes
(``--sigma``, px per coordinate per eye), triangulates (eq. 9) and fits a straight line in X
and Z to every frame at once, weighted by the depth's error (Z^2), many times over. The spread
of the fitted heading and ground speed is what the images hold at that centroid error: an
estimate made as the ball flies, from the frames seen so far, can only do worse. Prints one
line per scene, as the README's Accuracy section quotes it.

Usage: ``python benchmarks/fast_ball_bound.py [--sigma 0.15] [--runs 1000]``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests import accuracy as acc


def bound(case: acc.Case, sigma_px: float, runs: int, rng: np.random.Generator) -> str:
    """One line: frames in view, depths, and the fitted heading's and speed's spread."""
    rig = case.mode.rig
    times = [
        f.t_ns for f in case.frames() if f.eye.value == "left" and case.in_view("ball", f.t_ns)
    ]
    truth = [case.truth(t)["ball"] for t in times]
    p = np.array([c for c, _ in truth])
    v = np.mean([vel for _, vel in truth], axis=0)
    left, right = rig.project(p)
    t = (np.array(times) - times[0]) * 1e-9
    heading = math.degrees(math.atan2(v[0], v[2]))
    speed = math.hypot(v[0], v[2])
    dh, ds = [], []
    for _ in range(runs):
        pts, _ = rig.triangulate(
            left + rng.normal(0.0, sigma_px, left.shape),
            right + rng.normal(0.0, sigma_px, right.shape),
            sigma_px,
        )
        vx = np.polyfit(t, pts[:, 0], 1, w=1.0 / p[:, 2])[0]
        vz = np.polyfit(t, pts[:, 2], 1, w=1.0 / p[:, 2] ** 2)[0]
        dh.append((math.degrees(math.atan2(vx, vz)) - heading + 180.0) % 360.0 - 180.0)
        ds.append((math.hypot(vx, vz) - speed) / speed)
    return (
        f"{case.mode.name:18s} {case.name:22s} seed {case.seed}: {len(times):2d} frames, "
        f"Z {p[:, 2].min():.1f} to {p[:, 2].max():.1f} m; heading {np.std(dh):.2f} deg, "
        f"speed {100 * np.std(ds):.1f} % (1 sigma)"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sigma", type=float, default=0.15, help="centroid error, px (0.15)")
    ap.add_argument("--runs", type=int, default=1000, help="noisy draws per scene (1000)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds (0 1 2)")
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    for mode in acc.MODES:
        for seed in a.seeds:
            for case in acc.fast_cases(mode, seed):
                print(bound(case, a.sigma, a.runs, rng), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
