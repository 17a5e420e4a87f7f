"""Per-frame 3D truth of the hand in TemugeB/handpose3d's two-webcam clip.

The source repository (MIT) ships the two 720x720 videos and the calibration but no keypoint
numbers: its program computes MediaPipe hand landmarks at run time and saves nothing unless
told to. This script makes them, in two steps:

1. ``--detect`` (needs the ``mediapipe`` package, 0.10.14, whose hand model ships inside the
   wheel): MediaPipe Hands on every frame of both videos with the settings of the repository's
   ``handpose3d.py`` (one hand, detection and tracking confidence 0.5, video mode), written to
   ``keypoints_2d.csv`` (pixels, full precision to 0.01 px).
2. Always: each landmark seen in both views is undistorted (``cv2.undistortPoints``) and
   triangulated with ``cv2.triangulatePoints`` on the dataset's calibration, in cam0's frame.
   ``truth.csv`` gets, per frame, the palm centre (mean of the wrist and the four finger
   MCP joints, MediaPipe landmarks 0 5 9 13 17) in metres, its reprojection error, and two
   bone lengths as a check of the units.

The calibration's length unit is undocumented (its author's calibration recipe measures in
chessboard squares unless told the square size). It is not the centimetre: the wrist to
middle-finger MCP distance comes out at 2.09 units, and an adult hand's is about 9 cm. So
``truth.csv`` gives positions in the calibration's units (``*_u``) and, as an estimate, in
metres (``*_m``) with the unit taken as 9 cm over the median of that distance (about 4.3 cm,
good to perhaps 15 %: hands differ).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import cv2
import numpy as np

N_LANDMARKS = 21
PALM = (0, 5, 9, 13, 17)
WRIST, INDEX_MCP, MIDDLE_MCP, PINKY_MCP = 0, 5, 9, 17
# Wrist to middle-finger MCP of an adult hand (m): sets the estimated unit, see above.
HAND_WRIST_MIDDLE_MCP_M = 0.09


def read_dat(path: Path) -> dict[str, list[np.ndarray]]:
    """The matrices of one of the repository's ``.dat`` files: blocks headed ``name:``
    followed by rows of numbers; a repeated name gives a second matrix."""
    out: dict[str, list[np.ndarray]] = {}
    name, rows = "", list[list[float]]()
    for line in [*path.read_text().splitlines(), "end:"]:
        s = line.strip()
        if not s or s.startswith("#") or s.endswith(":"):
            if name and rows:
                out.setdefault(name, []).append(np.array(rows, dtype=np.float64))
            rows = []
            if s.endswith(":"):
                name = s[:-1]
            continue
        rows.append([float(v) for v in s.split()])
    return out


def load_calibration(folder: Path) -> dict[str, np.ndarray]:
    """K, distortion (k1 k2 p1 p2 k3) per camera and the cam0 to cam1 rotation and
    translation, derived from the world-to-camera R, T of each camera
    (``x_cam = R X + T``, as the repository's ``get_projection_matrix`` uses them)."""
    c0, c1 = read_dat(folder / "c0.dat"), read_dat(folder / "c1.dat")
    rt0, rt1 = read_dat(folder / "rot_trans_c0.dat"), read_dat(folder / "rot_trans_c1.dat")
    r0, t0 = rt0["R"][0], rt0["T"][0].reshape(3)
    r1, t1 = rt1["R"][0], rt1["T"][0].reshape(3)
    rot = r1 @ r0.T
    return {
        "K0": c0["intrinsic"][0],
        "D0": c0["distortion"][0].reshape(-1),
        "K1": c1["intrinsic"][0],
        "D1": c1["distortion"][0].reshape(-1),
        "R": rot,
        "T": t1 - rot @ t0,
        # the file's own "cam0 to cam1" block, kept to check the derivation against
        "R_file": rt1["R"][1],
        "T_file": rt1["T"][1].reshape(3),
    }


def detect(videos: list[Path], out_csv: Path) -> None:
    """Run MediaPipe Hands on both videos and write every landmark (px) to ``out_csv``."""
    import mediapipe as mp  # only this step needs it

    with open(out_csv, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "cam", "landmark", "u_px", "v_px"])
        for cam, video in enumerate(videos):
            hands = mp.solutions.hands.Hands(
                min_detection_confidence=0.5, max_num_hands=1, min_tracking_confidence=0.5
            )
            cap = cv2.VideoCapture(str(video))
            f = 0
            while True:
                ok, frame = cap.read()
                if not ok:
                    break
                h, wd = frame.shape[:2]
                res = hands.process(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
                if res.multi_hand_landmarks:
                    for i, lm in enumerate(res.multi_hand_landmarks[0].landmark):
                        w.writerow([f, cam, i, f"{lm.x * wd:.2f}", f"{lm.y * h:.2f}"])
                f += 1
            hands.close()


def read_keypoints(path: Path) -> tuple[int, np.ndarray]:
    """Frame count and an array (frames, 2 cams, 21, 2) of pixels, NaN where unseen."""
    rows = list(csv.DictReader(path.open()))
    n = max(int(r["frame"]) for r in rows) + 1
    kp = np.full((n, 2, N_LANDMARKS, 2), np.nan)
    for r in rows:
        kp[int(r["frame"]), int(r["cam"]), int(r["landmark"])] = (
            float(r["u_px"]),
            float(r["v_px"]),
        )
    return n, kp


def triangulate(cal: dict[str, np.ndarray], uv0: np.ndarray, uv1: np.ndarray) -> np.ndarray:
    """3D points (N, 3) in cam0's frame, calibration units, from pixel pairs (N, 2)."""
    n0 = cv2.undistortPoints(uv0.reshape(-1, 1, 2), cal["K0"], cal["D0"]).reshape(-1, 2)
    n1 = cv2.undistortPoints(uv1.reshape(-1, 1, 2), cal["K1"], cal["D1"]).reshape(-1, 2)
    p0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    p1 = np.hstack([cal["R"], cal["T"].reshape(3, 1)])
    xh = cv2.triangulatePoints(p0, p1, n0.T, n1.T)
    return (xh[:3] / xh[3]).T


def reprojection_px(cal: dict[str, np.ndarray], pts: np.ndarray, uv: list[np.ndarray]) -> float:
    """RMS distance (px) between the points projected into both views and the detections."""
    errs = []
    for (rv, tv), k, d, obs in (
        ((np.zeros(3), np.zeros(3)), cal["K0"], cal["D0"], uv[0]),
        ((cv2.Rodrigues(cal["R"])[0], cal["T"]), cal["K1"], cal["D1"], uv[1]),
    ):
        proj, _ = cv2.projectPoints(pts, rv, tv, k, d)
        errs.append(np.linalg.norm(proj.reshape(-1, 2) - obs, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def main(argv: list[str] | None = None) -> int:
    """Detect (optionally) and triangulate; write ``truth.csv``; print a summary line."""
    here = Path(__file__).resolve().parent
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        type=Path,
        default=here.parents[2].parent / "shared" / "data" / "temugeb_handpose3d",
        help="folder with media/ and camera_parameters/ (default ../shared/data/...)",
    )
    ap.add_argument("--detect", action="store_true", help="run MediaPipe to remake the 2D file")
    ap.add_argument("--out", type=Path, default=here)
    args = ap.parse_args(argv)
    kp_csv = args.out / "keypoints_2d.csv"
    if args.detect:
        media = args.data / "media"
        detect([media / "cam0_test.mp4", media / "cam1_test.mp4"], kp_csv)

    cal = load_calibration(args.data / "camera_parameters")
    n, kp = read_keypoints(kp_csv)
    seen = [f for f in range(n) if not np.isnan(kp[f]).any()]
    points = {f: triangulate(cal, kp[f, 0], kp[f, 1]) for f in seen}
    bones = np.array([np.linalg.norm(p[MIDDLE_MCP] - p[WRIST]) for p in points.values()])
    unit_m = HAND_WRIST_MIDDLE_MCP_M / float(np.median(bones))
    rows = []
    for f in range(n):
        row: dict[str, object] = {"frame": f, "t_s": f"{f / 30:.4f}"}
        if f in points:
            pts = points[f]
            palm = pts[list(PALM)].mean(axis=0)
            row.update(
                x_u=f"{palm[0]:.3f}",
                y_u=f"{palm[1]:.3f}",
                z_u=f"{palm[2]:.3f}",
                x_m=f"{palm[0] * unit_m:.4f}",
                y_m=f"{palm[1] * unit_m:.4f}",
                z_m=f"{palm[2] * unit_m:.4f}",
                reproj_px=f"{reprojection_px(cal, pts, [kp[f, 0], kp[f, 1]]):.2f}",
                wrist_middle_mcp_u=f"{np.linalg.norm(pts[MIDDLE_MCP] - pts[WRIST]):.3f}",
                index_pinky_mcp_u=f"{np.linalg.norm(pts[PINKY_MCP] - pts[INDEX_MCP]):.3f}",
            )
        rows.append(row)
    fields = [
        "frame",
        "t_s",
        "x_u",
        "y_u",
        "z_u",
        "x_m",
        "y_m",
        "z_m",
        "reproj_px",
        "wrist_middle_mcp_u",
        "index_pinky_mcp_u",
    ]
    with open(args.out / "truth.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields, restval="")
        w.writeheader()
        w.writerows(rows)
    reproj = np.array([float(str(r["reproj_px"])) for r in rows if "x_u" in r])
    rot_diff = np.degrees(np.linalg.norm(cv2.Rodrigues(cal["R"] @ cal["R_file"].T)[0]))
    print(
        f"{len(points)} of {n} frames triangulated; wrist to middle MCP median "
        f"{np.median(bones):.3f} u, so 1 u is about {unit_m * 100:.2f} cm; "
        f"reprojection median {np.median(reproj):.2f} px, 90th percentile "
        f"{np.percentile(reproj, 90):.2f} px; "
        f"|T| {np.linalg.norm(cal['T']):.2f} (file {np.linalg.norm(cal['T_file']):.2f}), "
        f"R differs from the file's by {rot_diff:.2f} deg"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
