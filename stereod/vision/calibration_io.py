"""A calibration to and from other tools' files: ROS camera_info YAML out, OpenCV FileStorage
(stereo_calib's intrinsics.yml and extrinsics.yml) in."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Literal, TypeVar

import cv2
import numpy as np

from stereod.errors import (
    CalibrationError,
    InputError,
    MissingInputError,
    OutputError,
    StereodError,
    UsageError,
)
from stereod.files.nesting import Syntax, check_depth
from stereod.files.output_file import output_target
from stereod.files.paths import read_input_file
from stereod.vision.calibration import (
    MAX_ENTRY,
    Calibration,
    create_output,
    from_arrays,
    rectification_problem,
    swapped_problem,
)

T = TypeVar("T")


def _yaml_matrix(name: str, a: np.ndarray) -> str:
    data = ", ".join(repr(float(x)) for x in a.ravel())
    return f"{name}:\n  rows: {a.shape[0]}\n  cols: {a.shape[1]}\n  data: [{data}]\n"


def ros_camera_info(cal: Calibration, eye: Literal["left", "right"]) -> str:
    """ROS ``camera_info`` YAML (camera_calibration_parsers format) for one eye. The right
    projection matrix carries P[0, 3] = -fx * B, as ROS expects."""
    k, d, r, p = ("K1", "D1", "R1", "P1") if eye == "left" else ("K2", "D2", "R2", "P2")
    w, h = cal.image_size
    return (
        f"image_width: {w}\nimage_height: {h}\ncamera_name: stereod_{eye}\n"
        + _yaml_matrix("camera_matrix", cal.array(k))
        + "distortion_model: plumb_bob\n"
        + _yaml_matrix("distortion_coefficients", cal.array(d))
        + _yaml_matrix("rectification_matrix", cal.array(r))
        + _yaml_matrix("projection_matrix", cal.array(p))
    )


def export_ros(cal: Calibration, directory: Path) -> list[Path]:
    """Write ``left.yaml`` and ``right.yaml`` into ``directory``, made if missing (with its
    missing parents, as a recording's folder is); return their paths."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except FileExistsError as exc:  # a file, or a link to one, by that name
        raise OutputError(
            f"{directory}: is a file; --ros takes the folder for left.yaml and right.yaml"
        ) from exc
    except OSError as exc:
        raise OutputError(f"{directory}: cannot create the folder: {exc.strerror}") from exc
    for eye in ("left", "right"):  # both can be written before either is
        output_target(directory / f"{eye}.yaml")
    out = []
    for eye in ("left", "right"):
        path = directory / f"{eye}.yaml"
        with create_output(path) as output:
            output.write(ros_camera_info(cal, eye).encode())  # type: ignore[arg-type]
        out.append(path)
    return out


def read_opencv_storage(
    path: Path,
    what: str,
    error: type[StereodError],
    read: Callable[[cv2.FileStorage], T | OpenCVProblem],
) -> T:
    """Parse an OpenCV FileStorage file (YAML, XML or JSON) and return what ``read`` takes
    from it. The file must be UTF-8 text; OpenCV parses it from memory, so no file name
    reaches it, and a parse failure becomes ``error`` naming the file. ``read`` must return
    plain data (arrays, strings), never a ``cv2.FileNode``: a node that outlives its storage
    crashes the interpreter when it is collected. It reports a problem by returning an
    :class:`OpenCVProblem`, which is raised as ``error`` once the storage is gone."""
    try:
        data = read_input_file(path, "an OpenCV FileStorage file", too_large=error)
    except FileNotFoundError as exc:
        raise MissingInputError(f"{path}: no such file") from exc
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read it: {exc.strerror}") from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(
            f"{path}: not an OpenCV FileStorage text file (byte {exc.start} is not UTF-8); "
            f"expected {what} in YAML or XML"
        ) from exc
    head = text.lstrip("\ufeff \t\r\n")[:5]
    if "\x00" in text or not head.startswith(("%YAML", "<?xml", "{")):
        raise error(
            f"{path}: not an OpenCV FileStorage file: it must begin with %YAML, <?xml or {{ "
            f"(expected {what} as OpenCV writes it)"
        )
    syntax: Syntax = "yaml" if head.startswith("%YAML") else "xml" if head[0] == "<" else "json"
    check_depth(text, syntax, str(path), error)
    result = _parse_storage(text, read)
    if isinstance(result, OpenCVProblem):
        raise error(f"{path}: {result.text}")
    return result


class OpenCVProblem:
    """What was wrong in a FileStorage file, as :func:`read_opencv_storage`'s reader says it."""

    def __init__(self, text: str) -> None:
        self.text = text


def _parse_storage(
    text: str, read: Callable[[cv2.FileStorage], T | OpenCVProblem]
) -> T | OpenCVProblem:
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:
        return OpenCVProblem(
            "not a valid OpenCV FileStorage file (malformed or cut short; OpenCV says "
            f"{_cv_reason(exc)!r})"
        )
    try:
        if not fs.isOpened():
            return OpenCVProblem("not a valid OpenCV FileStorage file")
        try:
            return read(fs)
        except (cv2.error, SystemError, UnicodeError) as exc:
            return OpenCVProblem(f"cannot read it: {_cv_reason(exc)}")
    finally:
        fs.release()


def _cv_reason(exc: BaseException) -> str:
    """The message of an OpenCV error, without OpenCV's source paths and line numbers."""
    cause: BaseException = exc.__cause__ or exc.__context__ or exc
    text = getattr(cause, "err", None) or str(cause)
    return " ".join(str(text).split())[:160] or type(exc).__name__


def _matrices(
    keys: list[str], optional: tuple[str, ...] = ()
) -> Callable[[cv2.FileStorage], dict[str, np.ndarray] | OpenCVProblem]:
    """A FileStorage reader of the matrices ``keys`` as float64 arrays; those of ``optional``
    may be missing (they are left out of the result)."""

    def read(fs: cv2.FileStorage) -> dict[str, np.ndarray] | OpenCVProblem:
        out = {}
        for key in keys:
            node = fs.getNode(key)
            if node.empty() and key in optional:
                continue
            if node.empty():
                return OpenCVProblem(f"field {key} is missing")
            m = _matrix_node(node)
            if isinstance(m, str):
                return OpenCVProblem(f"field {key} is not an OpenCV matrix: {m}")
            out[key] = m
        return out

    return read


_MATRIX_TYPES = set("ucwsifd")
"""OpenCV's one-letter element types (uchar, char, ushort, short, int, float, double)."""


def _matrix_node(node: cv2.FileNode) -> np.ndarray | str:
    """An ``opencv-matrix`` node read number by number, as float64 (rows, cols); what is
    wrong with it otherwise. ``FileNode.mat()`` is not used: OpenCV corrupts its heap on a
    matrix with negative columns."""
    if not node.isMap():
        return "expected rows, cols, dt and data"
    rows, cols, dt, data = (node.getNode(k) for k in ("rows", "cols", "dt", "data"))
    if not (rows.isInt() and cols.isInt() and dt.isString() and data.isSeq()):
        return "expected rows, cols, dt and data"
    r, c, kind = int(rows.real()), int(cols.real()), dt.string()
    if not (1 <= r <= 16 and 1 <= c <= 16):
        return f"{r}x{c} is not the size of a calibration matrix"
    if kind not in _MATRIX_TYPES:
        return f"dt {kind!r} is not a one-channel number type"
    if data.size() != r * c:
        return f"{data.size()} numbers for a {r}x{c} matrix"
    values = []
    for i in range(r * c):
        item = data.at(i)
        if not (item.isReal() or item.isInt()):
            return f"entry {i} is not a number"
        values.append(item.real())
    return np.array(values, dtype=np.float64).reshape(r, c)


RECTIFICATION = ("R1", "R2", "P1", "P2", "Q")
"""The rectification matrices an extrinsics file may hold, as stereo_calib writes them."""
_NUMBERS = {"M1": 9, "M2": 9, "R": 9, "T": 3, "R1": 9, "R2": 9, "P1": 12, "P2": 12, "Q": 16}
_OURS = {"M1": "K1", "M2": "K2"}
_THEIRS = {"K1": "M1", "K2": "M2"}
PRINCIPAL_POINT_SPAN = (0.3, 0.7)
"""Where a camera's principal point may lie, as a fraction of the image's side: within a few
per cent of the middle for a webcam; at a quarter or at the edge, the calibration was made at
another size than ``--size`` (twice or half of it)."""


def import_opencv(
    intrinsics: Path, extrinsics: Path | None, image_size: tuple[int, int]
) -> Calibration:
    """Read OpenCV FileStorage files (``M1 D1 M2 D2`` and ``R T``, optionally ``R1 R2 P1 P2
    Q``) such as OpenCV's ``stereo_calib`` sample writes; ``extrinsics`` defaults to
    ``extrinsics.yml`` beside the intrinsics. The file's rectification is kept when it holds
    all five matrices and they fit R and T (whatever ``alpha`` made them: its focal length is
    the file's); otherwise it is computed for ``image_size`` (alpha -1, as ``calibrate``
    does). The result's ``source`` says which. Errors name the file that holds the bad value
    (65), or ``--size`` when the principal points say the calibration was made at another
    size (64); a rig whose right camera is on the left is refused as ``calibrate`` does."""
    beside = extrinsics is None
    if extrinsics is None:
        extrinsics = intrinsics.with_name("extrinsics" + intrinsics.suffix)
    arrays: dict[str, np.ndarray] = {}
    for path, wanted, optional in (
        (intrinsics, ["M1", "D1", "M2", "D2"], ()),
        (extrinsics, ["R", "T", *RECTIFICATION], RECTIFICATION),
    ):
        if not path.exists():
            hint = ""
            if beside and path == extrinsics:  # not named: looked for beside the intrinsics
                hint = (
                    f" (R and T, looked for beside {intrinsics.name}: give the extrinsics "
                    "file after the intrinsics)"
                )
            raise MissingInputError(f"{path}: no such OpenCV calibration file{hint}")
        found = read_opencv_storage(
            path, "an OpenCV calibration file", InputError, _matrices(wanted, optional)
        )
        for key, m in found.items():
            _check_numbers(path, key, m)
            arrays[_OURS.get(key, key)] = m
    for d in ("D1", "D2"):
        arrays[d] = _plumb_bob(intrinsics, d, arrays[d])
    _check_size(intrinsics, arrays, image_size)
    swapped = swapped_problem(arrays["T"])
    if swapped is not None:
        raise InputError(f"{extrinsics}: {swapped}")
    held = [k for k in RECTIFICATION if k in arrays]
    if len(held) == len(RECTIFICATION):
        problem = rectification_problem(arrays)
        if problem is not None:
            raise InputError(
                f"{extrinsics}: R1 R2 P1 P2 Q do not fit R and T ({problem}): remove them from "
                "the file to have them computed, or write them again with R and T"
            )
        how = f"rectification read from {extrinsics.name}"
    else:
        for k in held:
            del arrays[k]
        missing = " ".join(k for k in RECTIFICATION if k not in held)
        how = f"rectification computed ({extrinsics.name} lacks {missing})"
    try:
        return from_arrays(image_size, arrays, source=f"imported from {intrinsics.name}; {how}")
    except CalibrationError as exc:
        text = str(exc).removeprefix("calibration: ").split("; the file is damaged")[0]
        field = text.split(" ", 1)[0].split(":", 1)[0].split(".", 1)[0]
        where = intrinsics if field in ("K1", "D1", "K2", "D2") else extrinsics
        text = f"field {_THEIRS.get(field, field)}{text[len(field) :]}"
        raise InputError(f"{where}: {text}") from exc
    except cv2.error as exc:
        raise InputError(f"{intrinsics}: cannot rectify these matrices: {_cv_reason(exc)}") from exc


def _check_numbers(path: Path, key: str, m: np.ndarray) -> None:
    """Matrix ``key`` of ``path`` has its number of entries, all finite and within any
    calibration's; else an error naming the file and the field."""
    want = _NUMBERS.get(key)
    if want is not None and m.size != want:
        raise InputError(f"{path}: field {key} has {m.size} numbers, a {key} has {want}")
    if not np.all(np.isfinite(m)):
        raise InputError(f"{path}: field {key} holds a non-finite number (NaN or infinity)")
    if np.abs(m).max() > MAX_ENTRY:
        raise InputError(
            f"{path}: field {key} holds {np.abs(m).max():g}, beyond any calibration "
            f"(|x| <= {MAX_ENTRY:g})"
        )


def _plumb_bob(path: Path, key: str, d: np.ndarray) -> np.ndarray:
    """Distortion ``key`` as the five plumb-bob coefficients (1, 5): fewer are padded with
    zeros; more (the rational model) are refused unless those past the fifth are zero."""
    v = d.ravel()
    if v.size < 5:
        v = np.concatenate([v, np.zeros(5 - v.size)])
    elif v.size > 5:
        if np.any(v[5:] != 0):
            raise InputError(
                f"{path}: field {key} has {v.size} coefficients (rational model); "
                "only plumb-bob k1 k2 p1 p2 k3 is supported"
            )
        v = v[:5]
    return v.reshape(1, 5)


def _check_size(path: Path, arrays: dict[str, np.ndarray], size: tuple[int, int]) -> None:
    """The principal points of M1 and M2 lie near the middle of a ``size`` (w, h) image;
    else ``--size`` is not the size the calibration was made at (the files do not record
    it), and the error says which size the principal points suggest."""
    lo, hi = PRINCIPAL_POINT_SPAN
    for key in ("K1", "K2"):
        k = arrays[key]
        cx, cy = float(k[0, 2]), float(k[1, 2])
        if not all(lo * side <= c <= hi * side for c, side in ((cx, size[0]), (cy, size[1]))):
            raise UsageError(
                f"--size {size[0]}x{size[1]}: {path}'s {_THEIRS[key]} has its principal point "
                f"at ({cx:.1f}, {cy:.1f}) px, {cx / size[0]:.0%} and {cy / size[1]:.0%} of "
                "that image (near 50 % in a camera): the calibration was made at another size; "
                f"give --size of its images ({_likely_size(cx, cy)})"
            )


_CAMERA_MODES: tuple[tuple[int, int], ...] = (
    *((160, 120), (320, 240), (352, 288), (640, 360), (640, 480), (800, 600), (960, 540)),
    *((1024, 768), (1280, 720), (1280, 960), (1600, 1200), (1920, 1080), (3840, 2160)),
)
"""Common webcam modes (w, h), px: the hint for a --size that does not fit."""


def _likely_size(cx: float, cy: float) -> str:
    """The common camera mode whose middle is nearest a principal point (px), as a hint."""
    w, h = min(_CAMERA_MODES, key=lambda m: math.hypot(m[0] / 2 - cx, m[1] / 2 - cy))
    twice = f"{2 * cx:.0f}x{2 * cy:.0f}"
    return f"{w}x{h} is the common mode nearest; twice the principal point is {twice}"
