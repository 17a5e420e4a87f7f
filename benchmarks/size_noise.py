"""How noisy a ball's blob area is, as the depth ratio at a track's second sight reads it.

The skew stage takes how much a track's depth changed between two frames of one eye from its
blob's areas (:func:`stereod.tracking.skew.size_depth_ratio`: a ball's image area goes as
1 / (Z^2 cos), cos of its angle off the axis), and only beyond ``SIZE_NOISE / sqrt(A)``. This
measures that noise where it matters: for each thrown ball of ``make accuracy`` (the
independent renderer's ``fast_ball``, across the view and towards the rig, 10 and 20 m/s,
three seeds, the four modes), every pair of consecutive frames in which one eye sees the ball
whole (its box off the image's edge) gives k = (half the log of the angle-corrected area
ratio, less the log of the true depth ratio) x sqrt(A), A the smaller area. Prints, per mode,
how many pairs, k's standard deviation, its 95th percentile and its largest magnitude:
``SIZE_NOISE`` should lie above what a sharp blob gives, not inside the spread.

Usage: ``python benchmarks/size_noise.py``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from stereod.pipeline import Pipeline, PipelineParams
from stereod.tracking import skew
from tests import accuracy as acc


def samples(case: acc.Case) -> list[float]:
    """k for every pair of consecutive whole sightings of the ball in one eye."""
    rig = case.mode.rig
    frames = list(case.frames())
    at = {(f.eye.value, f.seq): f.t_ns for f in frames}
    seen: dict[str, list[tuple[float, float, float]]] = {"left": [], "right": []}
    with Pipeline(PipelineParams(rig)) as pipe:
        for r in pipe.run(iter(frames), int(0.75e9 / case.mode.fps)):
            for eye, blobs, seq in (("left", r.left, r.left_seq), ("right", r.right, r.right_seq)):
                truth = case.truth(at[(eye, seq)]).get("ball")
                if len(blobs) != 1 or truth is None:
                    continue
                x, y, w, h = (int(v) for v in blobs.bbox_px[0])
                if x <= 0 or y <= 0 or x + w >= rig.width_px or y + h >= rig.height_px:
                    continue
                cx, cy = rig.principal_point_px(eye == "left")
                u, v = blobs.centroid_px[0]
                cos = rig.focal_px / math.sqrt(rig.focal_px**2 + (u - cx) ** 2 + (v - cy) ** 2)
                seen[eye].append((float(blobs.area_px[0]), cos, float(truth[0][2])))
    out = []
    for track in seen.values():
        for (a0, c0, z0), (a1, c1, z1) in itertools.pairwise(track):
            read = 0.5 * math.log((a0 * c0) / (a1 * c1))  # log of Z now over Z then, from sizes
            out.append((read - math.log(z1 / z0)) * math.sqrt(min(a0, a1)))
    return out


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    print(f"SIZE_NOISE = {skew.SIZE_NOISE}")
    print("mode                 pairs   sd(k)   95th pct |k|   max |k|")
    for mode in acc.MODES:
        ks: list[float] = []
        for seed in (0, 1, 2):
            for direction in ("lateral", "radial"):
                for speed in (10.0, 20.0):
                    case = acc.world_preset(
                        "fast_ball", mode, seed, direction=direction, speed_mps=speed
                    )
                    ks += samples(case)
        k = np.abs(np.array(ks))
        print(
            f"{mode.name:20s} {len(k):5d}   {np.std(ks):5.2f}   {np.percentile(k, 95):12.2f}"
            f"   {k.max():7.2f}"
        )


if __name__ == "__main__":
    main()
