"""A calibration to and from other tools' files: ROS camera_info YAML out, OpenCV FileStorage
(stereo_calib's intrinsics.yml and extrinsics.yml) in."""

from __future__ import annotations

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
)
from stereod.files.nesting import Syntax, check_depth
from stereod.files.output_file import output_target
from stereod.files.paths import read_input_file
from stereod.vision.calibration import Calibration, create_output, from_arrays

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
    keys: list[str],
) -> Callable[[cv2.FileStorage], dict[str, np.ndarray] | OpenCVProblem]:
    """A FileStorage reader of the matrices ``keys`` as float64 arrays."""

    def read(fs: cv2.FileStorage) -> dict[str, np.ndarray] | OpenCVProblem:
        out = {}
        for key in keys:
            node = fs.getNode(key)
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


def import_opencv(
    intrinsics: Path, extrinsics: Path | None, image_size: tuple[int, int]
) -> Calibration:
    """Read OpenCV FileStorage files (``M1 D1 M2 D2`` and ``R T``, optionally ``R1 R2 P1 P2
    Q``) such as OpenCV's ``stereo_calib`` sample writes; ``extrinsics`` defaults to
    ``extrinsics.yml`` beside the intrinsics. The rectification is recomputed for
    ``image_size`` when the file lacks it."""
    beside = extrinsics is None
    if extrinsics is None:
        extrinsics = intrinsics.with_name("extrinsics" + intrinsics.suffix)
    arrays: dict[str, np.ndarray] = {}
    names = {"M1": "K1", "D1": "D1", "M2": "K2", "D2": "D2"}
    for path, wanted in ((intrinsics, names), (extrinsics, {"R": "R", "T": "T"})):
        if not path.exists():
            hint = ""
            if beside and path == extrinsics:  # not named: looked for beside the intrinsics
                hint = (
                    f" (R and T, looked for beside {intrinsics.name}: give the extrinsics "
                    "file after the intrinsics)"
                )
            raise MissingInputError(f"{path}: no such OpenCV calibration file{hint}")
        found = read_opencv_storage(
            path, "an OpenCV calibration file", InputError, _matrices(list(wanted))
        )
        arrays.update({ours: found[key] for key, ours in wanted.items()})
    for key, ours, size in (("M1", "K1", 9), ("M2", "K2", 9), ("R", "R", 9), ("T", "T", 3)):
        if arrays[ours].size != size:
            where = intrinsics if key.startswith("M") else extrinsics
            raise InputError(
                f"{where}: field {key} has {arrays[ours].size} numbers, a {key} has {size}"
            )
    for d in ("D1", "D2"):
        v = arrays[d].ravel()
        if v.size < 5:
            v = np.concatenate([v, np.zeros(5 - v.size)])
        elif v.size > 5:
            if np.any(v[5:] != 0):
                raise CalibrationError(
                    f"{intrinsics}: field {d} has {v.size} coefficients (rational model); "
                    "only plumb-bob k1 k2 p1 p2 k3 is supported"
                )
            v = v[:5]
        arrays[d] = v.reshape(1, 5)
    if not all(np.all(np.isfinite(a)) for a in arrays.values()):
        raise InputError(f"{intrinsics}: a matrix holds a non-finite number (NaN or infinity)")
    try:
        return from_arrays(image_size, arrays, source=f"imported from {intrinsics.name}")
    except CalibrationError as exc:
        raise CalibrationError(f"{intrinsics}: {str(exc).removeprefix('calibration: ')}") from exc
    except cv2.error as exc:
        raise InputError(f"{intrinsics}: cannot rectify these matrices: {_cv_reason(exc)}") from exc
