"""Room calibration: each rig's pose in the room from chessboard views that rigs see at once.

Each rig finds the board in its left eye and solves its pose (``cv2.solvePnP`` with the left
camera's K1 and D1), then moves it into the rig frame: the rectified cameras' orientation
(``R1``) with the origin at the midpoint of the baseline, as the rig's tracks are published
(:mod:`stereod.vision.geometry.rectified`). Two rigs that see the board in one view give the
rig-to-rig transform ``T_a<-b = T_a<-board T_board<-b``. Over several views the rotations are
averaged (the chordal mean: the sum of the rotation matrices projected onto SO(3) by SVD) and
the translations by their mean. The rigs' poses are chained from the first (reference) rig,
whose frame is the room's, along a breadth-first tree of the rig pairs with shared views.

Quality figures: each rig's RMS reprojection error of its own board poses (px), the RMS error
of the board seen by the other rigs and carried into this rig through the room poses (px), and,
where the pairs make a loop (three rigs or more), the loop-closure error of every pair left out
of the tree: the difference between its direct transform and the chained one (mm, deg).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereod.errors import CalibrationError, InputError, MissingInputError
from stereod.fusion.room import rotation_matrix
from stereod.vision.calibrate import IMAGE_SUFFIXES, board_points, find_corners, read_image
from stereod.vision.calibration import Board, Calibration, rotation_angle_deg

MIN_SHARED_VIEWS = 1
"""Fewest views two rigs must share for their transform to be used."""
MAX_VIEW_DISAGREEMENT_DEG = 5.0
"""Most one view's rig-to-rig rotation may differ from the pair's mean, deg: a few tenths is
noise; more is a board whose corners one rig numbered from the other end (a board turned
upside down for it), or images of different instants."""


@dataclass(frozen=True)
class RigViews:
    """One rig's name, calibration and its left-eye images keyed by file name."""

    name: str
    calibration: Calibration
    images: dict[str, Path]


@dataclass(frozen=True)
class Pose:
    """A rigid transform ``p -> R p + t`` (R (3, 3), t (3,) in m)."""

    r: np.ndarray
    t: np.ndarray

    def inverse(self) -> Pose:
        """The transform back: ``p -> R^T p - R^T t``."""
        return Pose(self.r.T, -self.r.T @ self.t)

    def __matmul__(self, other: Pose) -> Pose:
        """This after ``other``."""
        return Pose(self.r @ other.r, self.r @ other.t + self.t)


@dataclass
class RigResult:
    """One rig's pose in the room and its quality figures."""

    name: str
    pose: Pose
    views: int
    """Views in which this rig found the board."""
    rms_px: float
    """RMS reprojection error of its own board poses, px."""
    room_rms_px: float | None = None
    """RMS error of the board seen by other rigs, carried here through the room poses, px."""


@dataclass
class LoopError:
    """A rig pair left out of the chain: its direct transform against the chained one."""

    a: str
    b: str
    translation_mm: float
    rotation_deg: float


@dataclass
class RoomReport:
    """The rigs' poses (the first is the reference) and the figures of their quality."""

    rigs: list[RigResult]
    loops: list[LoopError] = field(default_factory=list)


def euler_deg(r: np.ndarray) -> tuple[float, float, float]:
    """(rx, ry, rz) in deg with ``r = Rz(rz) Ry(ry) Rx(rx)`` (the room file's convention;
    ry in -90..90 deg, rx = 0 at ry = +-90 deg where only rz - rx or rz + rx is defined)."""
    sy = float(np.clip(-r[2, 0], -1.0, 1.0))
    ry = math.asin(sy)
    if math.hypot(r[2, 1], r[2, 2]) > 1e-9:
        rx = math.atan2(r[2, 1], r[2, 2])
        rz = math.atan2(r[1, 0], r[0, 0])
    else:
        rx = 0.0
        rz = math.atan2(-r[0, 1], r[1, 1])
    return math.degrees(rx), math.degrees(ry), math.degrees(rz)


def mean_rotation(rotations: Sequence[np.ndarray]) -> np.ndarray:
    """The chordal mean of rotations: their sum projected onto SO(3) (SVD, det +1)."""
    u, _, vt = np.linalg.svd(np.sum(rotations, axis=0))
    d = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(u @ vt)))])
    return np.asarray(u @ d @ vt)


def rig_frame(cal: Calibration) -> Pose:
    """The transform from the left camera's frame into the rig frame: ``R1``, then the origin
    moved from the left eye to the midpoint of the baseline (``-P2[0][3] / P2[0][0]`` long)."""
    p2 = cal.array("P2")
    half = 0.5 * float(-p2[0, 3] / p2[0, 0])
    return Pose(cal.array("R1"), np.array([-half, 0.0, 0.0]))


def square_mismatch(name: str, cal_path: Path, cal: Calibration, square: float) -> str | None:
    """Why ``square`` (``--square``, m) does not fit rig ``name``'s calibration, or ``None``.

    The board's poses, and so the room's translations, scale with ``square``: a wrong one
    moves every rig by its ratio to the true one while every reprojection RMS stays the same
    (the corners are fitted as well at any scale). A calibration made by ``stereod calibrate``
    records its board's square (the unit of its baseline); another value is refused unless
    the room's board is another board than the rig's (``--force``). A calibration that
    records no board (an imported one) cannot be checked."""
    if cal.board is None or math.isclose(cal.board.square, square, rel_tol=1e-6):
        return None
    rec = cal.board.square
    return (
        f"--square {square:g} but rig {name}'s calibration {cal_path} was made with squares of "
        f"{rec:g}: the room's distances scale with --square (by {square / rec:.3g} here) and no "
        f"RMS shows it; give --square {rec:g}, or --force if the room's board is another "
        "board than the rig's"
    )


def left_images(folder: Path) -> dict[str, Path]:
    """A rig's left-eye images by file name: those in ``folder/left`` when it exists, else the
    images in ``folder`` whose names do not contain ``right``."""
    if not folder.is_dir():
        raise MissingInputError(f"{folder}: no such folder of board images")
    where = folder / "left" if (folder / "left").is_dir() else folder
    try:
        names = sorted(where.iterdir())
    except OSError as exc:
        raise MissingInputError(f"{where}: cannot list the folder: {exc.strerror}") from exc
    found = {
        p.name: p
        for p in names
        if p.suffix.lower() in IMAGE_SUFFIXES and "right" not in p.name and p.is_file()
    }
    if not found:
        raise InputError(f"{where}: no images (png, jpg, ...) of the board")
    return found


def _board_pose(cal: Calibration, corners: np.ndarray, obj: np.ndarray) -> tuple[Pose, float]:
    """The board's pose in the rig frame and the fit's RMS reprojection error (px)."""
    k, d = cal.array("K1"), cal.array("D1")
    ok, rvec, tvec = cv2.solvePnP(obj, corners, k, d, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("solvePnP found no board pose")
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, d)
    err = float(np.sqrt(np.mean(np.sum((proj - corners.reshape(-1, 1, 2)) ** 2, axis=2))))
    cam = Pose(cv2.Rodrigues(rvec)[0], tvec.reshape(3))
    return rig_frame(cal) @ cam, err


def calibrate_room(rigs: Sequence[RigViews], board: Board) -> RoomReport:
    """Each rig's pose in the frame of ``rigs[0]`` from the views (images of one name) that
    two rigs or more saw; raises :class:`InputError` (exit 65, as every refused calibration)
    when a rig shares no view with the others, never finds the board, or two rigs' views of
    one name disagree."""
    obj = board_points(board)
    poses: dict[str, dict[str, Pose]] = {}
    corners_of: dict[str, dict[str, np.ndarray]] = {}
    rms: dict[str, float] = {}
    for rig in rigs:
        poses[rig.name], corners_of[rig.name] = {}, {}
        errs: list[float] = []
        for view, path in rig.images.items():
            gray = read_image(path)
            w, h = rig.calibration.image_size
            if gray.shape[:2] != (h, w):
                raise InputError(
                    f"{path}: {gray.shape[1]}x{gray.shape[0]} px, rig {rig.name}'s calibration "
                    f"is for {w}x{h}: use its left eye's images at the calibrated size"
                )
            c = find_corners(gray, board)
            if c is None:
                continue
            pose, err = _board_pose(rig.calibration, c, obj)
            poses[rig.name][view], corners_of[rig.name][view] = pose, c
            errs.append(err)
        if not errs:
            raise InputError(
                f"rig {rig.name}: the {board.cols}x{board.rows} board was found in none of "
                f"its {len(rig.images)} images: check --board and the images"
            )
        rms[rig.name] = float(np.sqrt(np.mean(np.square(errs))))

    names = [r.name for r in rigs]
    edges: dict[tuple[str, str], Pose] = {}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            shared = sorted(set(poses[a]) & set(poses[b]))
            if len(shared) < MIN_SHARED_VIEWS:
                continue
            rel = [poses[a][v] @ poses[b][v].inverse() for v in shared]
            ab = Pose(mean_rotation([p.r for p in rel]), np.mean([p.t for p in rel], axis=0))
            for v, p in zip(shared, rel, strict=True):
                off = rotation_angle_deg(ab.r.T @ p.r)
                if off > MAX_VIEW_DISAGREEMENT_DEG:
                    raise InputError(
                        f"view {v}: rigs {a} and {b} disagree with their other shared views by "
                        f"{off:.1f} deg (a board seen upside down, its corners numbered from "
                        "the other end, or images not taken at one instant): leave it out"
                    )
            edges[(a, b)], edges[(b, a)] = ab, ab.inverse()

    room: dict[str, Pose] = {names[0]: Pose(np.eye(3), np.zeros(3))}
    tree: set[tuple[str, str]] = set()
    queue = [names[0]]
    while queue:
        a = queue.pop(0)
        for b in names:
            if b not in room and (a, b) in edges:
                room[b] = room[a] @ edges[(a, b)]
                tree |= {(a, b), (b, a)}
                queue.append(b)
    lost = [n for n in names if n not in room]
    if lost:
        raise InputError(
            f"rig {lost[0]} shares no board view with rig {names[0]} nor with a rig chained "
            "to it: take views (same file name in each rig's folder) that both rigs see"
        )

    loops = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if (a, b) in edges and (a, b) not in tree:
                chained = room[a].inverse() @ room[b]
                diff = edges[(a, b)].inverse() @ chained
                loops.append(
                    LoopError(
                        a, b, 1000.0 * float(np.linalg.norm(diff.t)), rotation_angle_deg(diff.r)
                    )
                )

    results = []
    for rig in rigs:
        errs2: list[np.ndarray] = []
        cal = rig.calibration
        cam_from_rig = rig_frame(cal).inverse()
        for view, c in corners_of[rig.name].items():
            for other in names:
                if other == rig.name or view not in poses[other]:
                    continue
                board_in_cam = cam_from_rig @ room[rig.name].inverse() @ room[other]
                board_in_cam = board_in_cam @ poses[other][view]
                rvec = cv2.Rodrigues(board_in_cam.r)[0]
                proj, _ = cv2.projectPoints(
                    obj, rvec, board_in_cam.t, cal.array("K1"), cal.array("D1")
                )
                errs2.append(np.sum((proj - c.reshape(-1, 1, 2)) ** 2, axis=2).ravel())
        results.append(
            RigResult(
                name=rig.name,
                pose=room[rig.name],
                views=len(poses[rig.name]),
                rms_px=rms[rig.name],
                room_rms_px=float(np.sqrt(np.mean(np.concatenate(errs2)))) if errs2 else None,
            )
        )
    return RoomReport(results, loops)


def check_report(report: RoomReport, min_views: int, max_rms_px: float) -> list[str]:
    """What makes a room calibration clearly bad: a rig that saw the board in fewer than
    ``min_views`` views, or whose reprojection RMS (its own board poses, or the board other
    rigs saw carried to it through the room) exceeds ``max_rms_px`` (a blurred view, images of
    different instants; not a wrong square, which scales the poses and leaves every RMS the
    same: :func:`square_mismatch`). Empty when it passes."""
    problems = []
    for r in report.rigs:
        if r.views < min_views:
            problems.append(
                f"rig {r.name} saw the board in {r.views} views, fewer than --min-pairs {min_views}"
            )
        for what, rms in (("of its own views", r.rms_px), ("through the room", r.room_rms_px)):
            if rms is not None and rms > max_rms_px:
                problems.append(
                    f"rig {r.name}'s reprojection RMS {what} is {rms:.3f} px, above --max-rms "
                    f"{max_rms_px:g}"
                )
    return problems


def room_toml(name: str, report: RoomReport) -> str:
    """The room file (TOML) of ``report``: each rig's translation (m) and rotation (deg,
    ``R = Rz Ry Rx``), with the quality figures as comments."""
    lines = ["[room]", f'name = "{name}"']
    for r in report.rigs:
        rx, ry, rz = (a + 0.0 for a in euler_deg(r.pose.r))  # no -0.0 in the file
        tx, ty, tz = (float(v) + 0.0 for v in r.pose.t)
        lines += [
            "",
            "[[room.rigs]]",
            f'name = "{r.name}"',
            f"translation_m = [{tx:.6f}, {ty:.6f}, {tz:.6f}]",
            f"rotation_deg = [{rx:.5f}, {ry:.5f}, {rz:.5f}]",
        ]
    lines.append("")
    text = "\n".join(lines)
    # The round trip the file promises: its numbers give back each rig's rotation.
    for r in report.rigs:
        back = rotation_matrix(*euler_deg(r.pose.r))
        if np.abs(back - r.pose.r).max() > 1e-6:  # pragma: no cover - a convention bug
            raise CalibrationError(f"rig {r.name}: the rotation does not survive its angles")
    return text


def format_report(report: RoomReport) -> str:
    """The figures ``stereod calibrate --room`` prints: per rig, then per loop."""
    out = []
    for r in report.rigs:
        room = "-" if r.room_rms_px is None else f"{r.room_rms_px:.3f}"
        rx, ry, rz = euler_deg(r.pose.r)
        out.append(
            f"rig {r.name}: {r.views} views, reprojection RMS {r.rms_px:.3f} px, through the "
            f"room {room} px; at [{r.pose.t[0]:.4f}, {r.pose.t[1]:.4f}, {r.pose.t[2]:.4f}] m, "
            f"turned [{rx:.3f}, {ry:.3f}, {rz:.3f}] deg"
        )
    for lp in report.loops:
        out.append(
            f"loop {lp.a}-{lp.b}: closure error {lp.translation_mm:.2f} mm, "
            f"{lp.rotation_deg:.3f} deg"
        )
    if len(report.rigs) >= 3 and not report.loops:
        out.append("no loop: no rig pair outside the chain shares a view")
    return "\n".join(out)
