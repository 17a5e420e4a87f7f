"""Scene files: the two videos, per-eye timestamp CSVs, truth.csv and scene.json."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any, TextIO

import cv2

from ._base import EYES
from .scene import Scene

EXTRA = ["kind", "vol_x_m", "vol_y_m", "vol_z_m", "min_x_m", "min_y_m", "min_z_m"]
EXTRA += ["max_x_m", "max_y_m", "max_z_m", "readout_s"]


def write_scene(scene: Scene, out_dir: str | Path) -> Path:
    """Write left/right.mkv (FFV1), left/right.csv, truth.csv and scene.json into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    size = (scene.rig.width_px, scene.rig.height_px)
    fourcc = cv2.VideoWriter.fourcc(*"FFV1")
    writers: dict[str, cv2.VideoWriter] = {}
    stamp_files: dict[str, TextIO] = {}
    stamp_writers: dict[str, Any] = {}
    try:
        for eye in EYES:
            fps = 1.0 / scene.clock(eye).period_s
            wr = cv2.VideoWriter(str(out / f"{eye}.mkv"), fourcc, fps, size, True)
            if not wr.isOpened():
                raise RuntimeError(f"cannot open FFV1 writer for {out / f'{eye}.mkv'}")
            writers[eye] = wr
            fh = (out / f"{eye}.csv").open("w", newline="")
            stamp_files[eye] = fh
            stamp_writers[eye] = csv.writer(fh)
            stamp_writers[eye].writerow(["t_ns", "seq"])
        for fr in scene.frames():
            writers[fr.eye].write(fr.image)
            stamp_writers[fr.eye].writerow([fr.t_ns, fr.seq])
    finally:
        for wr in writers.values():
            wr.release()
        for sf in stamp_files.values():
            sf.close()
    with (out / "truth.csv").open("w", newline="") as fh:
        tw = csv.writer(fh)
        tw.writerow(["object", "t_ns", "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps", *EXTRA])
        readout = f"{scene.transport.row_readout_s:.9f}"
        for t in scene.all_frame_times():
            for name, d in scene.truth_details(t).items():
                nums = [d[k] for k in ("centre", "velocity", "volume_centroid", "lo", "hi")]
                cells = [f"{x:.9f}" for a in nums for x in a]
                tw.writerow([name, t, *cells[:6], d["kind"], *cells[6:], readout])
    rig = scene.rig
    meta = {
        "scene": scene.to_dict(),
        "derived": {
            "focal_px": rig.focal_px,
            "cx_px": rig.cx,
            "cy_px": rig.cy,
            "vfov_deg": rig.vfov_deg,
            "frames": {eye: len(scene.frame_times(eye)) for eye in EYES},
            "pixel_convention": "integer (u, v) is the pixel centre; principal point (W-1)/2",
            "timestamp_convention": "t_ns = start of exposure of row 0; image row r averages "
            "[t + r * readout_s / H, + exposure]",
            "readout_s": scene.transport.row_readout_s,
            "centre_convention": "x/y/z_m: volume centre of a solid; torso centre of a person "
            "(vol_*: centroid of the figure's volume; min_*/max_*: its axis-aligned extent)",
            "frame": "rig frame: X right, Y down, Z forward; origin between camera centres",
        },
    }
    (out / "scene.json").write_text(json.dumps(meta, indent=2))
    return out


def load_scene(path: str | Path) -> Scene:
    """Rebuild a Scene from a ``scene.json`` written by :func:`write_scene` (or its folder)."""
    p = Path(path)
    if p.is_dir():
        p = p / "scene.json"
    data = json.loads(p.read_text())
    return Scene.from_dict(data.get("scene", data))
