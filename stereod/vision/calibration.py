"""The calibration file: one versioned JSON document, validated on load (paper sec. IV-V).

It holds both cameras' intrinsics (K, D: OpenCV's plumb-bob k1 k2 p1 p2 k3), the pair's
extrinsics (R, T: a point X in the left camera's frame is R X + T in the right one's, eq. 19's
form), the rectification (R1, R2, P1, P2, Q from ``stereoRectify``), the quality figures, the
board and the date. Its id is a hash of the numbers, so the id names exactly one geometry and
changes when any value does. Lengths are in the unit of the board's square (metres for a
calibration made with ``--square`` in metres).

Also here: export to ROS ``camera_info`` YAML and import of OpenCV FileStorage files (the
intrinsics/extrinsics YAML of OpenCV's ``stereo_calib`` sample).
"""

from __future__ import annotations

import codecs
import datetime
import hashlib
import json
import math
from pathlib import Path
from typing import Annotated, Any, Final, Literal

import cv2
import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
)

from stereod.errors import (
    CalibrationError,
    MissingInputError,
    describe_validation_error,
)
from stereod.files.bounds import (
    BASELINE_M,
    HFOV_DEG,
    IMAGE_SIDE_PX,
    MIN_BOARD_CORNERS,
    SQUARE_M,
    focal_range_px,
    not_bool,
)
from stereod.files.nesting import check_depth
from stereod.files.output_file import AtomicOutput
from stereod.files.paths import read_input_file
from stereod.files.versioned import known_format, warn_unknown_fields

FORMAT: Final = "stereod.calibration/1"


Matrix = list[list[float]]

_SHAPES: dict[str, tuple[int, int]] = {
    "K1": (3, 3),
    "K2": (3, 3),
    "D1": (1, 5),
    "D2": (1, 5),
    "R": (3, 3),
    "T": (3, 1),
    "R1": (3, 3),
    "R2": (3, 3),
    "P1": (3, 4),
    "P2": (3, 4),
    "Q": (4, 4),
}


def _is_number(x: object) -> bool:
    """A JSON number (not a boolean, which Python counts as one)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


MAX_ENTRY = 1e9
"""The largest magnitude of any matrix entry (px, or lengths in the board's unit): larger
numbers are damage, and would overflow the geometry's arithmetic."""


class Board(BaseModel):
    """The chessboard: inner corners per row and column, square side (length unit)."""

    model_config = ConfigDict(extra="ignore")
    cols: int = Field(ge=MIN_BOARD_CORNERS)
    rows: int = Field(ge=MIN_BOARD_CORNERS)
    square: Annotated[float, BeforeValidator(not_bool), SQUARE_M.validator()]


class Quality(BaseModel):
    """How well the calibration fits its images (px)."""

    model_config = ConfigDict(extra="ignore")
    rms_left_px: float | None = None
    rms_right_px: float | None = None
    rms_stereo_px: float | None = None
    epipolar_error_px: float | None = None
    rectified_row_residual_px: float | None = None
    pairs_used: int | None = None
    pairs_rejected: int | None = Field(
        None, description="Pairs left out (no board, an image without its partner)"
    )


class Calibration(BaseModel):
    """A stereo calibration; matrices as nested lists, shapes checked, every number finite."""

    model_config = ConfigDict(extra="ignore")

    format: Literal["stereod.calibration/1"] = FORMAT
    id: str = ""
    image_size: tuple[int, int] = Field(description="width, height (px)")
    K1: Matrix
    D1: Matrix
    K2: Matrix
    D2: Matrix
    R: Matrix
    T: Matrix
    R1: Matrix
    R2: Matrix
    P1: Matrix
    P2: Matrix
    Q: Matrix
    quality: Quality = Field(default_factory=Quality)
    board: Board | None = None
    created_utc: str = ""
    source: str = ""

    @field_validator("format", mode="before")
    @classmethod
    def _known_format(cls, v: Any) -> Any:
        return known_format(v, FORMAT)

    @field_validator("image_size", mode="before")
    @classmethod
    def _size_not_bools(cls, v: Any) -> Any:
        return not_bool(v)

    @field_validator("image_size")
    @classmethod
    def _size_in_bounds(cls, v: tuple[int, int]) -> tuple[int, int]:
        for side in v:
            problem = IMAGE_SIDE_PX.problem(side)
            if problem is not None:
                raise ValueError(f"{v[0]}x{v[1]}: each side {problem}")
        return v

    @field_validator("T", "D1", "D2", mode="before")
    @classmethod
    def _vector_as_matrix(cls, v: Any, info: Any) -> Any:
        """A vector written flat (``"T": [x, y, z]``, as by hand or by other tools) is taken
        as the column (T) or row (D) the file stores."""
        if isinstance(v, list) and v and all(_is_number(x) for x in v):
            return [[x] for x in v] if _SHAPES[info.field_name][1] == 1 else [v]
        return v

    @field_validator(*_SHAPES, mode="before")
    @classmethod
    def _numbers_not_bools(cls, v: Any) -> Any:
        """true/false is no matrix entry (pydantic would read it as 1/0)."""
        if isinstance(v, list) and any(
            isinstance(x, bool) or (isinstance(x, list) and any(isinstance(y, bool) for y in x))
            for x in v
        ):
            raise ValueError("holds true/false where a number is meant")
        return v

    @field_validator(*_SHAPES)
    @classmethod
    def _shape_and_finite(cls, v: Matrix, info: Any) -> Matrix:
        want = _SHAPES[info.field_name]
        a = np.asarray(v, dtype=np.float64)
        if a.shape != want and not (info.field_name.startswith("D") and a.size == 5):
            raise ValueError(f"must be {want[0]}x{want[1]}, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("contains a non-finite number (NaN or infinity)")
        if a.size and np.abs(a).max() > MAX_ENTRY:
            raise ValueError(
                f"holds {np.abs(a).max():g}, beyond any calibration (|x| <= {MAX_ENTRY:g})"
            )
        a = a.reshape(want)
        problem = _matrix_problem(info.field_name, a) or _geometry_problem(
            info.field_name, a, info.data
        )
        if problem is not None:
            raise ValueError(
                f"{problem}; the file is damaged or not from a calibration: recalibrate"
            )
        out: Matrix = a.tolist()  # type: ignore[assignment]
        return out

    def array(self, name: str) -> np.ndarray:
        """One matrix as a float64 array of its documented shape."""
        return np.asarray(getattr(self, name), dtype=np.float64).reshape(_SHAPES[name])

    @property
    def baseline(self) -> float:
        """|T|, in the board's length unit."""
        return float(np.linalg.norm(self.array("T")))

    def content_id(self) -> str:
        """Hash of the numbers and image size: the calibration id."""
        numbers = {k: self.array(k).round(12).tolist() for k in _SHAPES}
        blob = json.dumps({"size": list(self.image_size), **numbers}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _matrix_problem(name: str, a: np.ndarray) -> str | None:
    """Why matrix ``name`` cannot be what its name says (a singular camera matrix, a rotation
    that is not one, a zero baseline), or None."""
    if name in ("K1", "K2"):
        if not (a[0, 0] > 0 and a[1, 1] > 0):
            fx, fy = a[0, 0], a[1, 1]
            return f"not a camera matrix: focal lengths fx = {fx:g}, fy = {fy:g} px must be > 0"
        if np.abs(a[2] - (0.0, 0.0, 1.0)).max() > 1e-6 or abs(a[1, 0]) > 1e-6:
            return "not a camera matrix: its bottom row must be 0 0 1, and K[1][0] 0"
    elif name in ("R", "R1", "R2"):
        if np.abs(a).max() > 1.0 + 1e-5 or np.abs(a @ a.T - np.eye(3)).max() > 1e-5:
            return "not a rotation matrix (R R^T must be the identity, det R = +1)"
        if np.linalg.det(a) < 0:
            return "not a rotation matrix (R R^T must be the identity, det R = +1)"
    elif name == "T":
        if not np.abs(a).max() > 0:
            return "the baseline |T| is zero: the two cameras cannot be at one place"
    elif name in ("P1", "P2"):
        if not (a[0, 0] > 0 and a[1, 1] > 0):
            fx, fy = a[0, 0], a[1, 1]
            return f"not a projection matrix: focal lengths {fx:g}, {fy:g} px must be > 0"
        if np.abs(a[2] - (0.0, 0.0, 1.0, 0.0)).max() > 1e-6 or abs(a[1, 0]) > 1e-6:
            return "not a rectified projection matrix: its bottom row must be 0 0 1 0, P[1][0] 0"
    return None


RECTIFIED_REL_TOL = 1e-3
"""How far (relative) the rectified baseline may differ from |T|, and Q from P1 and P2:
``stereoRectify`` makes them agree to rounding, and a file written with six significant
digits still does; a larger difference is an edit of one matrix without the others."""


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= RECTIFIED_REL_TOL * max(abs(a), abs(b), 1e-12)


DISTORTION_ROUND_TRIP_PX = 0.5
"""How far (px) an image point may come back after its lens distortion is undone and applied
again: a lens model that a camera's calibration fits inverts over its image to far less; one
that does not (a coefficient typed wrong) folds the image and rectifies nothing."""


def distortion_problem(k: np.ndarray, d: np.ndarray, size: tuple[int, int]) -> str | None:
    """Why camera matrix ``k`` with distortion ``d`` cannot be a lens over an image of
    ``size`` (w, h, px), or None. Points of a 17 x 13 grid within the ellipse the image's
    sides touch (its corners are left out: a fit has few board corners there, and a real fit
    may fold them) must come back within :data:`DISTORTION_ROUND_TRIP_PX` when the
    distortion is undone (``undistortPoints``, iterated to convergence) and applied again
    (``projectPoints``); and the rays of the left and right sides' middles, undistorted,
    must span a field of view within :data:`HFOV_DEG`'s bounds (the focal length's own is
    checked apart)."""
    w, h = size
    xs, ys = np.meshgrid(np.linspace(0.0, w - 1.0, 17), np.linspace(0.0, h - 1.0, 13))
    inside = ((xs / (w - 1.0) - 0.5) ** 2 + (ys / (h - 1.0) - 0.5) ** 2) <= 0.25 + 1e-9
    px = np.column_stack((xs[inside], ys[inside]))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    d = d.reshape(1, -1)
    eye = np.eye(3)
    ideal = cv2.undistortPoints(px.reshape(-1, 1, 2), k, d, None, eye, eye, criteria)
    rays = np.column_stack((ideal.reshape(-1, 2), np.ones(len(px))))
    back: np.ndarray = np.full_like(px, np.nan)
    if np.all(np.isfinite(rays)):
        back = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, d)[0].reshape(-1, 2)
    off = np.linalg.norm(back - px, axis=1)
    worst = int(np.argmax(np.where(np.isfinite(off), off, np.inf)))
    if not off[worst] <= DISTORTION_ROUND_TRIP_PX:
        x, y = px[worst]
        return (
            f"lens distortion {d.ravel().round(6).tolist()} cannot be undone over the image: "
            f"the point {x:.0f}, {y:.0f} px comes back {off[worst]:.3g} px off, more than "
            f"{DISTORTION_ROUND_TRIP_PX:g}, when undistorted and distorted again"
        )
    # The sides' middles: the image's edges, half a px outside its first and last centres.
    sides = np.array([[-0.5, 0.5 * (h - 1.0)], [w - 0.5, 0.5 * (h - 1.0)]])
    hfov = {}
    for lens in ("pinhole", "lens"):
        coeffs = d if lens == "lens" else np.zeros_like(d)
        ends = cv2.undistortPoints(sides.reshape(-1, 1, 2), k, coeffs, None, eye, eye, criteria)
        (xl, _), (xr, _) = ends.reshape(2, 2)
        hfov[lens] = math.degrees(math.atan(float(xr)) - math.atan(float(xl)))
    problem = HFOV_DEG.problem(hfov["lens"])
    if problem is not None and abs(hfov["lens"] - hfov["pinhole"]) > 1e-6:
        return (
            f"lens distortion {d.ravel().round(6).tolist()} makes the horizontal field of view "
            f"{hfov['lens']:.3g} deg: it {problem}"
        )
    return None


def _geometry_problem(name: str, a: np.ndarray, data: dict[str, Any]) -> str | None:
    """Why matrix ``name`` is outside what a real rig can be (:mod:`stereod.files.bounds`), given
    the fields validated before it (``data``: image_size, then K1 .. Q in file order), or None.
    Checked: each camera's focal lengths give a field of view within the bounds, its principal
    point lies in the image, its lens distortion can be undone over the image
    (:func:`distortion_problem`), |T| and the rectified baseline are within the baseline's bounds
    and agree, and Q is the one P1 and P2 make."""
    size = data.get("image_size")
    if name in ("K1", "K2", "P1", "P2") and size is not None:
        w, h = size
        lo, hi = focal_range_px(w)  # fy too: a webcam's pixels are square to a few per cent
        for axis, f, c, side in (("x", a[0, 0], a[0, 2], w), ("y", a[1, 1], a[1, 2], h)):
            if not lo <= f <= hi:
                return (
                    f"focal length f{axis} = {f:.6g} px is outside {lo:.4g}..{hi:.4g} px, a "
                    f"horizontal field of view of {HFOV_DEG.range_text()} over {w} px "
                    f"({HFOV_DEG.why})"
                )
            if not 0.0 <= c <= side:
                return f"principal point c{axis} = {c:.6g} px is outside the image (0..{side} px)"
    camera = {"D1": "K1", "D2": "K2"}.get(name)
    if camera is not None and size is not None and data.get(camera) is not None:
        problem = distortion_problem(np.asarray(data[camera], np.float64), a, size)
        if problem is not None:
            return problem
    if name == "T":
        problem = BASELINE_M.problem(float(np.linalg.norm(a)))
        if problem is not None:
            return f"baseline |T| = {float(np.linalg.norm(a)):.6g}: {problem}"
    if name == "P2" and a[0, 0] > 0:
        # Its sign says which eye is which: a swapped pair (negative) is the calibrating
        # command's to report and the rig's to refuse, its size is bounded here.
        rectified = float(-a[0, 3] / a[0, 0])
        problem = BASELINE_M.problem(abs(rectified))
        if problem is not None:
            return f"rectified baseline -P2[0][3]/P2[0][0] = {rectified:.6g}: {problem}"
        t = data.get("T")
        if t is not None and not _close(abs(rectified), float(np.linalg.norm(t))):
            return (
                f"rectified baseline -P2[0][3]/P2[0][0] = {rectified:.6g} is not |T| = "
                f"{float(np.linalg.norm(t)):.6g}"
            )
    if name == "Q" and data.get("P1") is not None and data.get("P2") is not None:
        p1, p2 = np.asarray(data["P1"]), np.asarray(data["P2"])
        tx = p2[0, 3] / p2[0, 0]
        want = {
            "Q[0][3] = -cx": (a[0, 3], -p1[0, 2]),
            "Q[1][3] = -cy": (a[1, 3], -p1[1, 2]),
            "Q[2][3] = f": (a[2, 3], p1[0, 0]),
            "Q[3][2] = -1/Tx": (a[3, 2], -1.0 / tx),
        }
        for what, (got, expected) in want.items():
            if not _close(float(got), float(expected)):
                return f"{what} of P1 and P2 is {expected:.6g}, the file holds {got:.6g}"
    return None


RECTIFICATION_TOL = 1e-4
"""How far R2 R may differ from R1 (per entry), and R2 T from the x axis (relative to |T|),
in a rectification that fits R and T: stereoRectify makes them agree to rounding."""


def rectification_problem(a: dict[str, np.ndarray]) -> str | None:
    """Why the file's R1 R2 P1 P2 Q are not a rectification of its R and T, or None: R2 R
    must be R1 (both eyes turned to one orientation), R2 T lie along x with the sign of P2's
    baseline term, and P1 and P2 share their focal lengths and row centre (Q and the
    baseline's length are checked where every calibration is loaded). ``a`` holds the arrays
    by name (R T R1 R2 P1 P2)."""
    r1, r2 = a["R1"].reshape(3, 3), a["R2"].reshape(3, 3)
    p1, p2 = a["P1"].reshape(3, 4), a["P2"].reshape(3, 4)
    t = a["T"].ravel()
    turn = float(np.abs(r2 @ a["R"].reshape(3, 3) - r1).max())
    if turn > RECTIFICATION_TOL:
        return f"R2 R differs from R1 by {turn:.2g}"
    moved = r2 @ t
    if float(np.abs(moved[1:]).max()) > RECTIFICATION_TOL * float(np.linalg.norm(t)):
        return f"R2 T = ({moved[0]:.4g}, {moved[1]:.4g}, {moved[2]:.4g}) is not along x"
    if p2[0, 0] > 0 and (p2[0, 3] / p2[0, 0]) * moved[0] < 0:
        return f"P2[0][3] = {p2[0, 3]:.6g} has the other sign than T's x part"
    for what, i, j in (("fx", 0, 0), ("fy", 1, 1), ("cy", 1, 2)):
        if abs(p1[i, j] - p2[i, j]) > 1e-3 * max(abs(p1[i, j]), 1.0):
            return f"P1 and P2 have {what} {p1[i, j]:.6g} and {p2[i, j]:.6g}"
    return None


def swapped_problem(t: np.ndarray) -> str | None:
    """Why a rig of translation ``t`` (left to right camera) has its eyes swapped, or None:
    the right camera must sit at +x of the left one, so T's x component is negative."""
    tx = float(np.asarray(t).ravel()[0])
    if tx > 0:
        return (
            f"left and right look swapped (T.x = {tx:+.4g} > 0: the 'right' camera is on the "
            "left): swap the left and right images (or the eyes' ports) and calibrate again"
        )
    return None


def from_arrays(
    image_size: tuple[int, int],
    arrays: dict[str, np.ndarray],
    *,
    quality: Quality | None = None,
    board: Board | None = None,
    source: str = "",
) -> Calibration:
    """A :class:`Calibration` from numpy arrays (K1, D1, K2, D2, R, T; R1..Q are computed with
    ``stereoRectify`` when absent), stamped with today's date and its content id."""
    a = {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}
    if "R1" not in a:
        a.update(rectify(image_size, a["K1"], a["D1"], a["K2"], a["D2"], a["R"], a["T"]))
    try:
        cal = Calibration(
            image_size=image_size,
            **{k: a[k].reshape(_SHAPES[k]).tolist() for k in _SHAPES},
            quality=quality or Quality(),
            board=board,
            created_utc=datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            source=source,
        )
    except ValidationError as exc:
        raise CalibrationError(f"calibration: {describe_validation_error(exc)}") from exc
    return cal.model_copy(update={"id": cal.content_id()})


def canonical(baseline_m: float, hfov_deg: float, width: int, height: int) -> Calibration:
    """The canonical rig of eq. 9 written as a calibration: identical distortion-free cameras,
    principal point at the image centre, no rotation, the right one ``baseline_m`` along +x."""
    f = width / (2.0 * math.tan(math.radians(hfov_deg) / 2.0))
    k = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return from_arrays(
        (width, height),
        {
            "K1": k,
            "D1": np.zeros(5),
            "K2": k,
            "D2": np.zeros(5),
            "R": np.eye(3),
            "T": np.array([-baseline_m, 0.0, 0.0]),
        },
        source=f"canonical rig: {baseline_m:g} m, {hfov_deg:g} deg",
    )


def rectify(
    image_size: tuple[int, int],
    k1: np.ndarray,
    d1: np.ndarray,
    k2: np.ndarray,
    d2: np.ndarray,
    r: np.ndarray,
    t: np.ndarray,
) -> dict[str, np.ndarray]:
    """R1, R2, P1, P2, Q of ``stereoRectify`` (zero disparity at infinity, no scaling)."""
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(
        k1,
        d1.reshape(1, -1),
        k2,
        d2.reshape(1, -1),
        image_size,
        r,
        t.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=-1,
    )
    return {"R1": r1, "R2": r2, "P1": p1, "P2": p2, "Q": q}


def load(path: Path, image_size: tuple[int, int] | None = None) -> Calibration:
    """Read and validate a calibration file; with ``image_size`` (w, h) also check that it was
    made for frames of that size. Errors name the file and the field."""
    try:
        text = read_input_file(path, "a calibration file", too_large=CalibrationError)
        text = text.removeprefix(codecs.BOM_UTF8)  # a byte-order mark, as some editors write
    except FileNotFoundError as exc:
        raise MissingInputError(f"{path}: no such calibration file") from exc
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read calibration file: {exc.strerror}") from exc
    try:
        decoded = text.decode("utf-8")
    except UnicodeDecodeError:
        decoded = "\0"
    if "\0" in decoded:  # a video, an image: no calibration, whatever its brackets say
        raise CalibrationError(
            f"{path}: not a calibration file: it is not UTF-8 text (a calibration is the JSON "
            "`stereod calibrate` writes, or `stereod calibration import` makes of OpenCV's)"
        )
    check_depth(decoded, "json", str(path), CalibrationError)
    try:
        cal = Calibration.model_validate_json(text)
    except ValidationError as exc:
        raise CalibrationError(f"{path}: {describe_validation_error(exc)}") from exc
    warn_unknown_fields(path, Calibration, text)
    if cal.id and cal.id != cal.content_id():
        raise CalibrationError(
            f"{path}: field id: {cal.id} does not match the numbers ({cal.content_id()}); "
            "the file was edited or damaged: recalibrate, or remove the id to accept it"
        )
    if not cal.id:  # written or edited by hand: its numbers must still be one rig
        arrays = {k: cal.array(k) for k in ("R", "T", "R1", "R2", "P1", "P2")}
        problem = rectification_problem(arrays) or swapped_problem(arrays["T"])
        if problem is not None:
            raise CalibrationError(
                f"{path}: its numbers are not one rig's ({problem}): recalibrate, or import "
                "the OpenCV files it came from with `stereod calibration import`"
            )
        cal = cal.model_copy(update={"id": cal.content_id()})
    if image_size is not None and tuple(cal.image_size) != tuple(image_size):
        raise CalibrationError(
            f"{path}: made for {cal.image_size[0]}x{cal.image_size[1]} frames, the stream is "
            f"{image_size[0]}x{image_size[1]}: calibrate at this size or change the camera mode"
        )
    return cal


def save(cal: Calibration, path: Path) -> None:
    """Write a calibration file (JSON) atomically: a write that fails leaves what was there."""
    with create_output(path) as out:
        write(cal, out)


def write(cal: Calibration, out: AtomicOutput) -> None:
    """Write a calibration file (JSON) into an output of :func:`create_output`."""
    out.write((cal.model_dump_json(indent=2) + "\n").encode())


def create_output(path: Path) -> AtomicOutput:
    """An output file, a temporary file created beside it; committed by rename. Made before
    the work that fills it, it refuses a path that cannot be written (a folder that does not
    exist, a directory, no permission) before that work is done, as every output is."""
    return AtomicOutput(path)


def rotation_angle_deg(r: np.ndarray) -> float:
    """Angle (deg) of a rotation matrix."""
    return math.degrees(float(np.linalg.norm(cv2.Rodrigues(np.asarray(r, np.float64))[0])))
