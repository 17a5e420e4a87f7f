"""A general (non-canonical) stereo rig for synthetic scenes: two pinhole cameras with their
own intrinsics and plumb-bob distortion (eq. 14-17), the right one rotated slightly and
``baseline_m`` to the right of the left one (eq. 18-19). Renders textured planes (a wall, a
chessboard) by casting each pixel's ray, so distortion and rotation are exact, and projects
points with OpenCV's own camera model.

World frame: the left camera's axes, origin at ``baseline_m / 2`` to the left camera's right
(the midpoint of the baseline when the rig is canonical).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stereod.sources.frames import Eye


class CameraSpec(BaseModel):
    """One camera's intrinsics (px) and distortion (k1, k2, p1, p2, k3)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=np.float64).reshape(1, 5)


class RigSpec(BaseModel):
    """Two cameras; the right one ``baseline_m`` along the left one's +x, rotated by
    ``rotation_deg`` (a rotation vector, deg) relative to it."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    left: CameraSpec
    right: CameraSpec
    baseline_m: float = Field(0.060, gt=0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def R(self) -> np.ndarray:
        """Rotation from left-camera to right-camera coordinates (P_r = R P_l + T)."""
        rvec = np.radians(np.asarray(self.rotation_deg, dtype=np.float64))
        return cv2.Rodrigues(rvec)[0]

    @property
    def T(self) -> np.ndarray:
        """Translation (3,) m: the right camera's centre is (B, 0, 0) in left coordinates."""
        return -self.R @ np.array([self.baseline_m, 0.0, 0.0])

    def calibration(self, width: int = 640, height: int = 480, **changes: np.ndarray) -> Any:
        """This rig's exact calibration (a :class:`stereod.vision.calibration.Calibration`); keyword
        arguments replace matrices (``R=np.eye(3)``) to build deliberately wrong ones."""
        from stereod.vision.calibration import from_arrays

        arrays = {
            "K1": self.left.K,
            "D1": self.left.D,
            "K2": self.right.K,
            "D2": self.right.D,
            "R": self.R,
            "T": self.T,
            **changes,
        }
        return from_arrays((width, height), arrays, source="synthetic rig")

    def camera(self, eye: Eye) -> CameraSpec:
        return self.left if eye is Eye.LEFT else self.right

    def to_camera(self, eye: Eye, points_world_m: np.ndarray) -> np.ndarray:
        """(n, 3) world points (m) in one camera's coordinates."""
        p_left = np.atleast_2d(points_world_m) + np.array([self.baseline_m / 2, 0.0, 0.0])
        if eye is Eye.LEFT:
            return p_left
        return p_left @ self.R.T + self.T

    def project(self, eye: Eye, points_world_m: np.ndarray) -> np.ndarray:
        """(n, 2) image points (px) of (n, 3) world points, distortion included."""
        return self.project_camera(eye, self.to_camera(eye, points_world_m))

    def project_camera(self, eye: Eye, pc: np.ndarray) -> np.ndarray:
        """(n, 2) image points (px) of (n, 3) points in ``eye``'s own coordinates (m)."""
        cam = self.camera(eye)
        img, _ = cv2.projectPoints(pc.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D)
        return img.reshape(-1, 2)

    def centre_world(self, eye: Eye) -> np.ndarray:
        return np.array([(-0.5 if eye is Eye.LEFT else 0.5) * self.baseline_m, 0.0, 0.0])

    def to_world_direction(self, eye: Eye, dirs_cam: np.ndarray) -> np.ndarray:
        return dirs_cam if eye is Eye.LEFT else dirs_cam @ self.R


def minoru_like(width: int = 640, height: int = 480, hfov_deg: float = 60.0) -> RigSpec:
    """A plausible imperfect Minoru: focal lengths 1 % apart, barrel distortion, tangential
    terms, principal points off centre, and the right eye turned by about 1 degree."""
    f = width / (2 * math.tan(math.radians(hfov_deg) / 2))
    return RigSpec(
        left=CameraSpec(
            fx=f,
            fy=f * 1.002,
            cx=width / 2 + 4.0,
            cy=height / 2 - 3.0,
            dist=(-0.12, 0.05, 0.0008, -0.0006, 0.0),
        ),
        right=CameraSpec(
            fx=f * 1.01,
            fy=f * 1.012,
            cx=width / 2 - 5.0,
            cy=height / 2 + 2.0,
            dist=(-0.10, 0.03, -0.0005, 0.0007, 0.0),
        ),
        baseline_m=0.060,
        rotation_deg=(0.4, -0.8, 0.3),
    )


@functools.lru_cache(maxsize=4)
def _pixel_rays(rig: RigSpec, width: int, height: int, s: int) -> dict[Eye, np.ndarray]:
    """Each eye's sub-pixel ray directions (world frame) as one contiguous (n, 1, 3) block, the
    layout cv2.transform reads in one pass; kept for the next caster of the same rig (the
    undistortion of a 640x480 eye's 1.2 M samples takes seconds). Read only."""
    sub = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(width)[:, None] + sub[None, :]).ravel()
    ys = (np.arange(height)[:, None] + sub[None, :]).ravel()
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 1, 2)
    out = {}
    for eye in Eye:
        cam = rig.camera(eye)
        norm = cv2.undistortPoints(
            grid,
            cam.K,
            cam.D,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
        ).reshape(-1, 2)
        dirs = np.column_stack([norm, np.ones(len(norm))])
        rays = np.ascontiguousarray(rig.to_world_direction(eye, dirs))[:, None, :]
        rays.setflags(write=False)
        out[eye] = rays
    return out


class RayCaster:
    """Every pixel's ray for both cameras of a rig (``samples`` x ``samples`` per pixel)."""

    def __init__(self, rig: RigSpec, width: int, height: int, samples: int = 2) -> None:
        self.rig = rig
        self.width, self.height, self.samples = width, height, samples

    @property
    def _rays(self) -> dict[Eye, np.ndarray]:
        return _pixel_rays(self.rig, self.width, self.height, self.samples)

    def plane_coords(
        self, eye: Eye, rotation: np.ndarray, origin_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where each sub-pixel ray meets the plane through ``origin_m`` spanned by the first
        two columns of ``rotation`` (world frame): plane coordinates u, v (m) as
        (h*s, w*s) arrays, and whether the plane is hit in front of the camera."""
        # directions in plane coordinates, d = ray @ rotation
        d = cv2.transform(self._rays[eye], np.ascontiguousarray(rotation.T)).reshape(-1, 3)
        o = (self.rig.centre_world(eye) - origin_m) @ rotation
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -o[2] / d[:, 2]
        hit = np.isfinite(s) & (s > 0)
        u = o[0] + s * d[:, 0]
        v = o[1] + s * d[:, 1]
        shape = (self.height * self.samples, self.width * self.samples)
        return u.reshape(shape), v.reshape(shape), hit.reshape(shape)

    def average(self, values: np.ndarray) -> np.ndarray:
        """Sub-pixel samples (h*s, w*s) averaged into pixels (h, w)."""
        s = self.samples
        return values.reshape(self.height, s, self.width, s).mean(axis=(1, 3))


def board_pose(
    rvec_deg: tuple[float, float, float],
    centre_m: tuple[float, float, float],
    size_m: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and origin (first inner corner) of a board of ``size_m`` (inner-corner span)
    centred at ``centre_m``, facing the cameras and tilted by ``rvec_deg``."""
    r = cv2.Rodrigues(np.radians(np.asarray(rvec_deg, dtype=np.float64)))[0]
    origin = np.asarray(centre_m) - r @ np.array([size_m[0] / 2, size_m[1] / 2, 0.0])
    return r, origin


def render_board(
    caster: RayCaster,
    eye: Eye,
    rotation: np.ndarray,
    origin_m: np.ndarray,
    cols: int,
    rows: int,
    square_m: float,
    background: float = 120.0,
) -> np.ndarray:
    """A grey uint8 image of a chessboard with ``cols`` x ``rows`` inner corners, the first at
    ``origin_m``, the board's axes the columns of ``rotation``; a white margin of one square."""
    u, v, hit = caster.plane_coords(eye, rotation, origin_m)
    i = np.floor(u / square_m)
    j = np.floor(v / square_m)
    on_squares = (i >= -1) & (i <= cols - 1) & (j >= -1) & (j <= rows - 1)
    on_board = (i >= -2) & (i <= cols) & (j >= -2) & (j <= rows)
    black = ((i + j) % 2 == 0) & on_squares
    img = np.where(on_board & hit, np.where(black, 30.0, 230.0), background)
    return np.clip(caster.average(img), 0, 255).astype(np.uint8)


def random_board_poses(
    n: int, cols: int, rows: int, square_m: float, seed: int = 0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` board poses (rotation, origin) spread over distance (0.5-1.1 m), position and tilt
    (up to 35 deg), the spread a calibration needs."""
    rng = np.random.default_rng(seed)
    size = ((cols - 1) * square_m, (rows - 1) * square_m)
    poses = []
    for _ in range(n):
        z = rng.uniform(0.5, 1.1)
        centre = (rng.uniform(-0.25, 0.25) * z, rng.uniform(-0.18, 0.18) * z, z)
        tilt = (rng.uniform(-35, 35), rng.uniform(-35, 35), rng.uniform(-15, 15))
        poses.append(board_pose(tilt, centre, size))
    return poses


def board_views(
    rig: RigSpec,
    width: int,
    height: int,
    cols: int,
    rows: int,
    square_m: float,
    poses: list[tuple[np.ndarray, np.ndarray]],
    noise_sigma: float = 1.0,
    seed: int = 0,
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Both eyes' images of a board in each pose, with sensor noise: (name, left, right)."""
    caster = RayCaster(rig, width, height)
    rng = np.random.default_rng(seed)
    out = []
    for k, (rot, origin) in enumerate(poses):
        imgs = []
        for eye in Eye:
            img = render_board(caster, eye, rot, origin, cols, rows, square_m).astype(np.float32)
            img += rng.normal(0.0, noise_sigma, img.shape).astype(np.float32)
            imgs.append(np.clip(img, 0, 255).astype(np.uint8))
        out.append((f"view{k:02d}", imgs[0], imgs[1]))
    return out


def write_board_recording(
    rig: RigSpec,
    out: Path,
    poses: list[tuple[np.ndarray, np.ndarray]],
    *,
    width: int = 640,
    height: int = 480,
    cols: int = 9,
    rows: int = 6,
    square_m: float = 0.03,
    fps: float = 15.0,
    hold_frames: int = 3,
    seed: int = 0,
) -> Path:
    """A recording of a chessboard moved from pose to pose in front of the rig, each pose held
    for ``hold_frames`` frames (as a person holding a board would), for live calibration."""
    from stereod.sources.frames import Frame
    from stereod.sources.recording_writer import RecordingWriter

    views = board_views(rig, width, height, cols, rows, square_m, poses, seed=seed)
    with RecordingWriter(out, width, height, fps=fps, settings={"synthetic": "chessboard"}) as w:
        k = 0
        for _, left, right in views:
            for _ in range(hold_frames):
                t = 1_000_000_000 + round(k * 1e9 / fps)
                w.write(Frame(Eye.LEFT, left, t, k))
                w.write(Frame(Eye.RIGHT, right, t, k))
                k += 1
    return out
