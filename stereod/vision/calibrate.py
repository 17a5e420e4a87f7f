"""Stereo calibration from chessboard pairs (paper sec. V, with Zhang's method).

The paper calibrates with Tsai's method; OpenCV implements Zhang's, which needs only several
views of a planar board and supersedes it. Per pair: find the board's inner corners in both
eyes and refine them to sub-pixel; then ``calibrateCamera`` per eye, ``stereoCalibrate``
refining both eyes' intrinsics and the rig together from those per-eye results, and
``stereoRectify``. With the intrinsics fixed after each eye is calibrated alone, the error of
each principal point goes into the direction of T (up to 3.9 deg on rendered boards of a
known rig, with a stereo RMS of 0.12 px); the joint refinement keeps it within 0.3 deg.

The result is checked before it may be written: a calibration from too few pairs, with a
large RMS, or with the eyes swapped (the right camera must sit at +x of the left one, so T's x
component is negative) is refused with the reason.

:class:`LiveCollector` picks pairs from a running stream: it keeps a pair when the board is
seen in both eyes in a pose that differs enough from those already kept.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereod.errors import CalibrationError, InputError, MissingInputError
from stereod.files.bounds import BASELINE_M, MIN_PAIRS
from stereod.files.paths import text_path
from stereod.sources.frames import Frame
from stereod.sources.pairing import Pairer
from stereod.vision.calibration import (
    Board,
    Calibration,
    Quality,
    from_arrays,
    rectify,
    swapped_problem,
)
from stereod.vision.calibration_io import OpenCVProblem, read_opencv_storage

SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 30, 0.01)
STEREO_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-5)


class CalibrationRejected(CalibrationError):
    """The calibration was computed but is clearly bad; ``--force`` writes it anyway."""

    exit_code = 65


@dataclass(frozen=True)
class Limits:
    """When a calibration is refused: fewer than ``min_pairs`` usable pairs, or a stereo RMS
    above ``max_rms_px`` (px)."""

    min_pairs: int = MIN_PAIRS
    max_rms_px: float = 1.0


@dataclass
class PairReport:
    """One pair's fate: used (with its residuals, px) or rejected (with the reason)."""

    name: str
    used: bool
    reason: str = ""
    epipolar_px: float | None = None
    row_residual_px: float | None = None


@dataclass
class Report:
    """Everything ``stereod calibrate`` prints, and the calibration itself."""

    calibration: Calibration
    pairs: list[PairReport] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    """Reasons the calibration is clearly bad (empty when it passed the checks)."""

    @property
    def quality(self) -> Quality:
        return self.calibration.quality


def board_points(board: Board) -> np.ndarray:
    """(n, 3) float32 corner positions on the board (board units), row by row."""
    grid = np.mgrid[0 : board.cols, 0 : board.rows].T.reshape(-1, 2)
    pts = np.zeros((board.cols * board.rows, 3), np.float32)
    pts[:, :2] = grid * board.square
    return pts


def find_corners(
    gray: np.ndarray, board: Board, *, fast: bool = False, window: int | None = None
) -> np.ndarray | None:
    """The board's inner corners (n, 1, 2) float32 px, refined to sub-pixel; ``None`` when the
    whole board is not seen. ``fast`` rejects frames without a board quickly (live use).
    ``window`` is cornerSubPix's half window (px); by default it adapts to the board's size in
    the image (OpenCV's stereo_calib sample uses 11 whatever the size)."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    if fast:
        flags |= cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(gray, (board.cols, board.rows), flags=flags)
    if not found:
        return None
    # The refinement window must not reach the next corner: at most 11 px (OpenCV's sample)
    # and at most 0.4 of the smallest square seen.
    grid = corners.reshape(board.rows, board.cols, 2)
    side = min(
        float(np.linalg.norm(np.diff(grid, axis=1), axis=2).min()),
        float(np.linalg.norm(np.diff(grid, axis=0), axis=2).min()),
    )
    win = window if window is not None else int(max(2, min(11, 0.4 * side)))
    return cv2.cornerSubPix(gray, corners, (win, win), (-1, -1), SUBPIX_CRITERIA)


def _gray(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def read_image(path: Path) -> np.ndarray:
    """A grey image from a file; errors name the file. The bytes are decoded in memory
    (``cv2.imread`` lets libjpeg print "Premature end of JPEG file" on stderr, past OpenCV's
    silenced log, and returns what it could decode); a JPEG or PNG cut short (no end marker)
    is refused as damaged rather than searched for a board it has lost."""
    text_path(path, "calibration image")
    if not path.is_file():
        raise MissingInputError(f"{path}: no such image file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read the image: {exc.strerror}") from exc
    cut = _cut_short(data)
    if cut is not None:
        raise InputError(f"{path}: a damaged image ({cut}): copy it again or drop the pair")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: not a readable image")
    return img


def _cut_short(data: bytes) -> str | None:
    """Why an image's bytes end before the image does (a JPEG without its end-of-image marker
    FF D9, a PNG without its IEND chunk, in the last 1 kB), or None."""
    tail = data[-1024:]
    if data.startswith(b"\xff\xd8") and b"\xff\xd9" not in tail:
        return "the JPEG stops before its end marker: cut short"
    if data.startswith(b"\x89PNG\r\n\x1a\n") and b"IEND" not in tail:
        return "the PNG stops before its IEND chunk: cut short"
    return None


IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}


def pairs_in_directory(directory: Path) -> list[tuple[Path, Path]]:
    """Left/right image pairs in a folder: files whose names contain ``left`` matched with the
    same name with ``right`` (``left03.png`` and ``right03.png``), or ``left/`` and ``right/``
    subfolders with equal file names. An image without its partner comes with the partner's
    expected path, which does not exist: :func:`calibrate_files` reports it as rejected."""
    if not os.path.isdir(directory):
        raise MissingInputError(f"{directory}: no such folder of calibration pairs")
    if os.path.isdir(directory / "left") and os.path.isdir(directory / "right"):
        lefts = _images(directory / "left", "")
        rights = _images(directory / "right", "")
        pairs = [(p, directory / "right" / p.name) for p in lefts]
        partners = [directory / "left" / p.name for p in rights]
    else:
        lefts = _images(directory, "left")
        rights = [p for p in _images(directory, "right") if p not in lefts]
        pairs = [(p, p.with_name(p.name.replace("left", "right"))) for p in lefts]
        partners = [p.with_name(p.name.replace("right", "left")) for p in rights]
    pairs += [(a, b) for a, b in zip(partners, rights, strict=True) if a not in lefts]
    if not any(a.is_file() and b.is_file() for a, b in pairs):
        raise InputError(
            f"{directory}: no image pairs (expected leftNN/rightNN files or left/ and right/)"
        )
    return pairs


def _images(folder: Path, containing: str) -> list[Path]:
    """The image files in ``folder`` whose names contain ``containing``, sorted."""
    try:
        names = sorted(folder.iterdir())
    except OSError as exc:
        raise MissingInputError(f"{folder}: cannot list the folder: {exc.strerror}") from exc
    return [p for p in names if containing in p.name and p.suffix.lower() in IMAGE_SUFFIXES]


def _image_list(fs: cv2.FileStorage) -> list[str] | OpenCVProblem:
    """The names in a FileStorage's ``imagelist`` sequence."""
    node = fs.getNode("imagelist")
    if node.empty() or not node.isSeq():
        return OpenCVProblem("no 'imagelist' sequence in this OpenCV file")
    names = []
    for i in range(node.size()):
        item = node.at(i)
        if not item.isString():
            return OpenCVProblem("'imagelist' must hold file names only")
        names.append(item.string())
    return names


def pairs_from_list(path: Path) -> list[tuple[Path, Path]]:
    """Pairs from a list file: an OpenCV ``imagelist`` (XML/YAML, left and right alternating,
    as OpenCV's stereo_calib.xml) or text with one ``LEFT RIGHT`` per line; relative names are
    relative to the list's folder."""
    if not os.path.isfile(path):
        raise MissingInputError(f"{path}: no such list file")
    names: list[str] = []
    if path.suffix.lower() in (".xml", ".yml", ".yaml", ".json"):
        names = read_opencv_storage(path, "an image list", InputError, _image_list)
    else:
        try:
            text = path.read_bytes().decode("utf-8")
        except OSError as exc:
            raise MissingInputError(f"{path}: cannot read the list: {exc.strerror}") from exc
        except UnicodeDecodeError as exc:
            raise InputError(
                f"{path}: not a text file (byte {exc.start} is not UTF-8); an image list has "
                "'LEFT RIGHT' per line"
            ) from exc
        for n, line in enumerate(text.splitlines(), 1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            if len(parts) != 2:
                raise InputError(f"{path} line {n}: expected 'LEFT RIGHT', got {line!r}")
            names += parts
    if len(names) % 2:
        raise InputError(f"{path}: odd number of images ({len(names)}): pairs are left, right")
    for s in names:
        text_path(s, f"image named in {path}")
    paths = [Path(s) if Path(s).is_absolute() else path.parent / s for s in names]
    for p in paths:
        if not os.path.isfile(p):
            raise MissingInputError(f"{path} names {p}: no such image file")
    return list(zip(paths[0::2], paths[1::2], strict=True))


def detect_pairs(
    images: Iterable[tuple[str, np.ndarray, np.ndarray]],
    board: Board,
    progress: Callable[[int, str, bool], None] | None = None,
    window: int | None = None,
) -> tuple[list[tuple[str, np.ndarray, np.ndarray]], list[PairReport], tuple[int, int]]:
    """Find the board in both eyes of every pair; returns the usable pairs' corners, a report
    per rejected pair, and the image size (w, h). Mixed sizes are an error naming the pair.
    ``progress(k, name, found)`` is called after each pair; ``window``: see
    :func:`find_corners`."""
    found: list[tuple[str, np.ndarray, np.ndarray]] = []
    rejected: list[PairReport] = []
    size: tuple[int, int] | None = None
    for k, (name, left, right) in enumerate(images, 1):
        gl, gr = _gray(left), _gray(right)
        for g, eye in ((gl, "left"), (gr, "right")):
            s = (g.shape[1], g.shape[0])
            if size is None:
                size = s
            elif s != size:
                raise InputError(
                    f"{name}: {eye} image is {s[0]}x{s[1]}, earlier images are "
                    f"{size[0]}x{size[1]}: all images must have one size"
                )
        cl = find_corners(gl, board, window=window)
        cr = find_corners(gr, board, window=window)
        if cl is None or cr is None:
            eyes = " and ".join(e for e, c in (("left", cl), ("right", cr)) if c is None)
            rejected.append(PairReport(name, False, f"board not found in the {eyes} image"))
        else:
            found.append((name, cl, cr))
        if progress is not None:
            progress(k, name, cl is not None and cr is not None)
    if size is None:
        raise InputError("no calibration images were given")
    return found, rejected, size


def epipolar_errors(
    left: np.ndarray,
    right: np.ndarray,
    k1: np.ndarray,
    d1: np.ndarray,
    k2: np.ndarray,
    d2: np.ndarray,
    f: np.ndarray,
) -> np.ndarray:
    """Per point, the distances (px) of each undistorted point to the epipolar line of its
    partner, both views summed (OpenCV's stereo_calib sample's check)."""
    ul = cv2.undistortPoints(left, k1, d1, P=k1)
    ur = cv2.undistortPoints(right, k2, d2, P=k2)
    l1 = cv2.computeCorrespondEpilines(ul, 1, f).reshape(-1, 3)
    l2 = cv2.computeCorrespondEpilines(ur, 2, f).reshape(-1, 3)
    ul, ur = ul.reshape(-1, 2), ur.reshape(-1, 2)
    return np.abs(ur[:, 0] * l1[:, 0] + ur[:, 1] * l1[:, 1] + l1[:, 2]) + np.abs(
        ul[:, 0] * l2[:, 0] + ul[:, 1] * l2[:, 1] + l2[:, 2]
    )


def calibrate(
    found: Sequence[tuple[str, np.ndarray, np.ndarray]],
    board: Board,
    image_size: tuple[int, int],
    limits: Limits = Limits(),
    rejected: Sequence[PairReport] = (),
    source: str = "",
) -> Report:
    """Calibrate from corners found in both eyes; the report lists the checks that failed."""
    if len(found) < 2:
        raise CalibrationRejected(
            f"only {len(found)} pair(s) with the board in both eyes; at least "
            f"{max(limits.min_pairs, 2)} needed: check --board (inner corners, COLSxROWS)"
        )
    obj = [board_points(board)] * len(found)
    left = [c for _, c, _ in found]
    right = [c for _, _, c in found]
    with _one_thread():  # OpenCV's threads sum in varying order: ids differed run to run
        rms_l, k1, d1, _, _ = cv2.calibrateCamera(obj, left, image_size, None, None)
        rms_r, k2, d2, _, _ = cv2.calibrateCamera(obj, right, image_size, None, None)
        fixed = cv2.stereoCalibrate(
            obj, left, right, k1, d1, k2, d2, image_size,
            flags=cv2.CALIB_FIX_INTRINSIC, criteria=STEREO_CRITERIA,
        )  # fmt: skip
        joint = cv2.stereoCalibrate(
            obj, left, right, k1, d1, k2, d2, image_size,
            flags=cv2.CALIB_USE_INTRINSIC_GUESS, criteria=STEREO_CRITERIA,
        )  # fmt: skip
    # The joint fit is kept when it fits at least as well with principal points in the image;
    # a pair that is no pair (two instants) can send it astray (cx 696 px in a 640 px image),
    # and then the fixed-intrinsics fit says more about what is wrong.
    rms, k1, d1, k2, d2, r, t, _, f = joint if _sound(joint, fixed, image_size) else fixed
    rect = rectify(image_size, k1, d1, k2, d2, r, t)
    pairs = list(rejected)
    epis, rows = [], []
    for name, cl, cr in found:
        e = epipolar_errors(cl, cr, k1, d1, k2, d2, f)
        a = cv2.undistortPoints(cl, k1, d1, R=rect["R1"], P=rect["P1"]).reshape(-1, 2)
        b = cv2.undistortPoints(cr, k2, d2, R=rect["R2"], P=rect["P2"]).reshape(-1, 2)
        row = np.abs(a[:, 1] - b[:, 1])
        epis.append(e)
        rows.append(row)
        pairs.append(PairReport(name, True, "", float(e.mean()), float(row.mean())))
    quality = Quality(
        rms_left_px=float(rms_l),
        rms_right_px=float(rms_r),
        rms_stereo_px=float(rms),
        epipolar_error_px=float(np.concatenate(epis).mean()),
        rectified_row_residual_px=float(np.concatenate(rows).mean()),
        pairs_used=len(found),
        pairs_rejected=len(rejected),
    )
    baseline = float(np.linalg.norm(t))
    badly_fitted = None
    if rms > limits.max_rms_px:
        # --square scales lengths only and cannot change an RMS: name the pair that fits worst.
        errs = [float(e.mean()) for e in epis]
        worst = int(np.argmax(errs))
        badly_fitted = (
            f"stereo RMS {rms:.3f} px is above {limits.max_rms_px:g} px; the worst pair is "
            f"{found[worst][0]} (epipolar error {errs[worst]:.3g} px, the median pair's "
            f"{float(np.median(errs)):.3g} px): drop it, or other blurred pairs or pairs whose "
            "images were not taken at once"
        )
    try:
        cal = from_arrays(
            image_size,
            {"K1": k1, "D1": d1, "K2": k2, "D2": d2, "R": r, "T": t, **rect},
            quality=quality,
            board=board,
            source=source,
        )
    except CalibrationError as exc:  # no rig: a result no calibration file can hold
        first = str(exc).removeprefix("calibration: ").split(" (", 1)[0].split("; ", 1)[0]
        same = ", the same view in both eyes?" if baseline < 1e-3 else ""
        if not same and BASELINE_M.problem(baseline) is not None:
            # Every length scales with --square: a baseline out of bounds is a wrong square.
            raise InputError(
                f"{source or 'the pairs'}: the baseline came out {baseline * 1000:.4g} mm with "
                f"--square {board.square:g}, outside a rig's {BASELINE_M.range_text()}: every "
                "length of the result scales with --square; check it is the side of one "
                "square in metres"
            ) from exc
        if badly_fitted is not None:  # a fit spoilt by a bad pair: that pair is the cause
            raise InputError(
                f"{source or 'the pairs'}: {badly_fitted}; no calibration file can hold the "
                f"result ({first}), --force or not"
            ) from exc
        raise InputError(
            f"{source or 'the pairs'}: the board's views give no stereo rig ({first}{same}): "
            "give pairs whose left and right images come from the two eyes at once; no "
            "calibration file can hold this one, --force or not"
        ) from exc
    problems = []
    if len(found) < limits.min_pairs:
        problems.append(
            f"only {len(found)} usable pairs, at least {limits.min_pairs} needed: add views of "
            "the board at different distances and angles"
        )
    if badly_fitted is not None:
        problems.append(badly_fitted)
    swapped = swapped_problem(t)
    if swapped is not None:
        problems.append(swapped)
    return Report(cal, sorted(pairs, key=lambda p: p.name), problems)


@contextlib.contextmanager
def _one_thread() -> Iterator[None]:
    """OpenCV on one thread within: the same pairs then give the same calibration to the
    last bit, and so the same id (with its threads, sums taken in another order each run
    moved the numbers by about 1e-12, and every run had an id of its own)."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


def _sound(joint: Sequence, fixed: Sequence, image_size: tuple[int, int]) -> bool:
    """Whether a joint ``stereoCalibrate`` result fits at least as well as the one with the
    intrinsics fixed (RMS, px) and keeps both principal points, and the rectified ones, inside
    the image."""
    w, h = image_size
    if not joint[0] <= fixed[0] + 1e-9:
        return False
    rect = rectify(image_size, joint[1], joint[2], joint[3], joint[4], joint[5], joint[6])
    ks = (joint[1], joint[3], rect["P1"], rect["P2"])
    return all(0 <= k[0, 2] <= w and 0 <= k[1, 2] <= h for k in ks)


def calibrate_files(
    pairs: Sequence[tuple[Path, Path]],
    board: Board,
    limits: Limits = Limits(),
    progress: Callable[[int, str, bool], None] | None = None,
    window: int | None = None,
) -> Report:
    """Calibrate from image files (``pairs_in_directory`` or ``pairs_from_list``). A pair one
    of whose images does not exist (an image in a folder without its partner) is rejected,
    naming the missing image."""
    unpaired, complete = [], []
    for a, b in pairs:
        if os.path.exists(a) and os.path.exists(b):
            complete.append((a, b))
        else:
            here, gone, eye = (a, b, "right") if os.path.exists(a) else (b, a, "left")
            unpaired.append(PairReport(here.name, False, f"no {eye} image ({gone} not found)"))
    images = ((a.name, read_image(a), read_image(b)) for a, b in complete)
    found, rejected, size = detect_pairs(images, board, progress, window)
    for k, r in enumerate(unpaired, len(complete) + 1):
        if progress is not None:
            progress(k, r.name, False)
    rejected += unpaired
    if not found:
        raise CalibrationRejected(
            f"the {board.cols}x{board.rows} board was not found in both images of any of the "
            f"{len(complete)} pairs: check --board (inner corners, COLSxROWS)"
        )
    source = f"{len(complete)} pairs from {complete[0][0].parent}"
    return calibrate(found, board, size, limits, rejected, source)


class LiveCollector:
    """Keeps stereo pairs in which the board is seen in both eyes in a new pose.

    A pose is new when the board's corners in the left image moved, on average, by more than
    ``min_change`` of the image diagonal from every pose already kept.
    """

    def __init__(self, board: Board, min_change: float = 0.05) -> None:
        self.board = board
        self.min_change = min_change
        self.kept: list[tuple[str, np.ndarray, np.ndarray]] = []
        self.size: tuple[int, int] | None = None
        self.seen = 0

    def offer(self, name: str, left: np.ndarray, right: np.ndarray) -> bool:
        """Look at one pair; return True when it was kept."""
        self.seen += 1
        gl, gr = _gray(left), _gray(right)
        self.size = (gl.shape[1], gl.shape[0])
        cl = find_corners(gl, self.board, fast=True)
        if cl is None:
            return False
        diag = math.hypot(*self.size)
        for _, kept, _ in self.kept:
            moved = np.linalg.norm(kept.reshape(-1, 2) - cl.reshape(-1, 2), axis=1)
            if float(np.mean(moved)) < self.min_change * diag:
                return False
        cr = find_corners(gr, self.board, fast=True)
        if cr is None:
            return False
        self.kept.append((name, cl, cr))
        return True


def collect_live(
    frames: Iterable[Frame],
    collector: LiveCollector,
    wanted: int,
    tolerance_ns: int,
    every_s: float = 0.1,
    progress: Callable[[int, int], None] | None = None,
) -> None:
    """Pair a stream's frames and offer a pair to ``collector`` at most every ``every_s``
    seconds of stream time until it has ``wanted`` pairs or the stream ends."""
    pairer = Pairer(tolerance_ns)
    last_t: int | None = None
    for frame in frames:
        for pair in pairer.push(frame):
            if last_t is not None and pair.t_ns - last_t < every_s * 1e9:
                continue
            last_t = pair.t_ns
            if collector.offer(f"pair{pair.seq:05d}", pair.left.image, pair.right.image):
                if progress is not None:
                    progress(len(collector.kept), wanted)
                if len(collector.kept) >= wanted:
                    return


def format_report(report: Report) -> str:
    """The human-readable summary ``stereod calibrate`` prints."""
    q = report.quality
    cal = report.calibration
    unit = "m" if cal.board is not None and cal.board.square < 1.0 else "square units"
    lines = [
        f"pairs used: {q.pairs_used}; rejected: "
        f"{'not recorded' if q.pairs_rejected is None else q.pairs_rejected}",
        f"RMS reprojection error: left {q.rms_left_px:.3f} px, right {q.rms_right_px:.3f} px, "
        f"stereo {q.rms_stereo_px:.3f} px",
        f"epipolar error (both views): {q.epipolar_error_px:.3f} px; rectified row residual "
        f"|y_L - y_R|: {q.rectified_row_residual_px:.3f} px",
        f"baseline |T|: {cal.baseline:.5g} {unit}; T = "
        f"({', '.join(f'{v:+.4g}' for v in cal.array('T').ravel())}); relative rotation "
        f"{_angle_deg(cal.array('R')):.3f} deg",
        f"focal lengths: left {cal.array('K1')[0, 0]:.1f} px, right {cal.array('K2')[0, 0]:.1f} px",
        "per pair (epipolar error, rectified row residual, px):",
    ]
    for p in report.pairs:
        if p.used:
            lines.append(f"  {p.name:<24} {p.epipolar_px:7.3f} {p.row_residual_px:7.3f}")
        else:
            lines.append(f"  {p.name:<24} rejected: {p.reason}")
    return "\n".join(lines)


def _angle_deg(r: np.ndarray) -> float:
    return math.degrees(float(np.linalg.norm(cv2.Rodrigues(r)[0])))
