"""The project's recording format (design sec. 6): what a stereo source delivered, replayable.

A recording is a directory::

    recording.json   manifest (pydantic-validated): format version, size, rate, codec, settings
    left.mkv         left eye video (FFV1 lossless by default; MJPG is lossy)
    left.csv         ``t_ns,seq,crc32``: one row per frame, monotonic capture time (ns),
                     sequence number and, with FFV1, the CRC-32 of the frame's pixels
    right.mkv, right.csv

Replay reproduces the frames (bit-exact with FFV1) and the timestamps and sequence numbers.
A lossless video damaged on disk still decodes, into other pixels, and FFmpeg says nothing
that reaches the caller: the CRC-32 beside each frame is how a reader finds such a frame and
leaves it out (:func:`read_frame_index`, :func:`checksum`). MJPG recordings, lossy, have none;
nor do recordings made before it was added, which replay as they did.
"""

from __future__ import annotations

import csv
import enum
import io
import logging
import os
import zlib
from pathlib import Path, PurePosixPath
from typing import Annotated, Any, Final, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
)

from stereod.errors import (
    InputError,
    MissingInputError,
    describe_validation_error,
)
from stereod.files.nesting import check_depth
from stereod.files.paths import MAX_TIMESTAMP_BYTES, path_problem, read_input_file
from stereod.files.versioned import known_format, warn_unknown_fields
from stereod.vision.calibration import Calibration

log = logging.getLogger(__name__)

MANIFEST = "recording.json"
FORMAT: Final = "stereod.recording/1"
CHECKSUM_COLUMN: Final = "crc32"
"""The timestamp CSV's third column: CRC-32 of each frame's pixels (FFV1 recordings)."""


class Codec(str, enum.Enum):
    """Video codec of a recording."""

    FFV1 = "ffv1"
    """Lossless (FFmpeg FFV1 in Matroska): replay gives back the exact pixels."""
    MJPG = "mjpg"
    """Motion JPEG in AVI: about 10x smaller, lossy."""


INT64_MAX = 2**63 - 1
"""The largest time or sequence number a recording may hold (they are int64 in memory)."""
MAX_SIDE_PX = 16384
"""The largest image width or height a recording may declare, px."""


def _inside(name: str) -> str:
    """A file name in a manifest: relative, inside the recording directory, printable."""
    problem = path_problem(name)
    if problem is not None:
        raise ValueError(f"the name {problem}")
    p = PurePosixPath(name)
    if not name or p.is_absolute() or ".." in p.parts:
        raise ValueError("must name a file inside the recording directory (e.g. left.mkv)")
    return name


class EyeFiles(BaseModel):
    model_config = ConfigDict(extra="ignore")
    video: Annotated[str, AfterValidator(_inside)]
    timestamps: Annotated[str, AfterValidator(_inside)]
    frames: int = Field(ge=0, le=10**9)


class Manifest(BaseModel):
    """``recording.json``: how to read a recording back."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False)

    format: Literal["stereod.recording/1"]
    width: int = Field(gt=0, le=MAX_SIDE_PX)
    height: int = Field(gt=0, le=MAX_SIDE_PX)
    fps: float | None = Field(default=None, gt=0, le=10000)
    codec: Codec = Codec.FFV1
    color: bool = False
    left: EyeFiles
    right: EyeFiles
    utc_offset_ns: int | None = Field(None, ge=-INT64_MAX, le=INT64_MAX)
    created_utc: str = ""
    settings: dict[str, Any] = Field(default_factory=dict)
    calibration: dict[str, Any] | None = None

    @field_validator("format", mode="before")
    @classmethod
    def _known_format(cls, v: Any) -> Any:
        return known_format(v, FORMAT)

    @field_validator("color", mode="before")
    @classmethod
    def _strict_color(cls, v: Any) -> Any:
        """true or false only: ``"yes"`` or ``1`` would be taken for colour, and every grey
        frame then for damage."""
        if not isinstance(v, bool):
            raise ValueError("must be true or false (JSON booleans)")
        return v

    @field_validator("calibration")
    @classmethod
    def _valid_calibration(cls, v: dict[str, Any] | None) -> dict[str, Any] | None:
        """The calibration in force when it was recorded, checked as a calibration file is
        (so every command that reads the recording refuses a bad one alike)."""
        if v is not None:
            try:
                Calibration.model_validate(v)
            except ValidationError as exc:
                raise ValueError(
                    f"not a valid calibration: {describe_validation_error(exc)}"
                ) from None
        return v


def read_manifest(directory: Path) -> Manifest:
    """Load and validate ``recording.json``, and check that every file it names that exists
    can be read; errors name the file and the field, or the file and the OS's reason."""
    path = directory / MANIFEST
    try:
        data = read_input_file(path, "a recording manifest")
    except (FileNotFoundError, NotADirectoryError) as exc:
        if not os.path.exists(directory):
            raise MissingInputError(f"{directory}: no such recording directory") from exc
        if directory.name == MANIFEST and os.path.isfile(directory):
            raise MissingInputError(
                f"{directory}: that is a recording's manifest; give its folder, {directory.parent}"
            ) from exc
        if os.path.isfile(directory) and os.path.isfile(directory.parent / MANIFEST):
            raise MissingInputError(
                f"{directory}: that is a file of the recording {directory.parent}; give the folder"
            ) from exc
        raise MissingInputError(
            f"{directory}: not a recording ({MANIFEST} missing); for plain videos use "
            "--left-video/--right-video"
        ) from exc
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read the manifest: {exc.strerror}") from exc
    check_depth(data.decode("utf-8", "replace"), "json", str(path), InputError)
    try:
        man = Manifest.model_validate_json(data)
    except ValidationError as exc:
        raise InputError(f"{path}: {describe_validation_error(exc)}") from exc
    warn_unknown_fields(path, Manifest, data)
    for files in (man.left, man.right):
        _check_readable(directory / files.video, "video file")
        _check_readable(directory / files.timestamps, "timestamp file")
    return man


def recording_folder(path: Path) -> Path:
    """The recording ``path`` names: the folder itself, or the folder of the manifest file
    ``path`` names (``out/scene/recording.json`` is the recording ``out/scene``)."""
    if path.name == MANIFEST and os.path.isfile(path):
        return path.parent
    return path


def recording_files(directory: Path) -> list[Path]:
    """The files in a recording directory, sorted (so an output can be checked against them);
    a directory that cannot be listed is one line naming it and the OS's reason."""
    try:
        return sorted(directory.iterdir())
    except OSError as exc:
        raise MissingInputError(f"{directory}: cannot list the recording: {exc.strerror}") from exc


def _check_readable(path: Path, what: str) -> None:
    """Refuse a recording's file that exists but cannot be opened (no permission), naming it
    and the OS's reason, before any reader (OpenCV's among them) meets it. A missing file or
    a folder is left to its reader, which has its own words for them."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read {what}: {exc.strerror}") from exc
    os.close(fd)


def read_timestamps(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a timestamp CSV: header ``t_ns`` (optionally ``t_ns,seq``), one integer row per frame.

    Returns (n,) int64 times (ns) and (n,) int64 sequence numbers (row index when absent).
    Times must strictly increase; the error names the file and row. (Sequence numbers may go
    back: a camera re-plugged during a recording counts from 0 again.) A recording's ``crc32``
    column is ignored here (a plain video's timestamps): :func:`read_frame_index` reads it.
    """
    t, seq, _ = read_frame_index(path, checksums=False)
    return t, seq


def read_frame_index(
    path: Path, checksums: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`read_timestamps`, and the per-frame CRC-32s when ``checksums`` and the header's
    third column is ``crc32`` ((n,) uint32; None when there is none: a lossy recording, one
    made before the column existed, a plain timestamp file). Errors name the file and
    line."""
    rows = _csv_rows(path)
    if not rows or [c.strip() for c in rows[0][:1]] != ["t_ns"]:
        raise InputError(
            f"{path}: first line must be the header 't_ns' (or 't_ns,seq', or a recording's "
            "'t_ns,seq,crc32')"
        )
    has_seq = len(rows[0]) > 1 and rows[0][1].strip() == "seq"
    if checksums:
        _warn_unknown_columns(path, [c.strip() for c in rows[0]])
    t = np.empty(len(rows) - 1, np.int64)
    seq = np.arange(len(rows) - 1, dtype=np.int64)
    for i, row in enumerate(rows[1:]):
        cells = row[:2] if has_seq else row[:1]
        try:
            values = [int(c) for c in cells]
        except ValueError:
            values = []
        if len(values) != len(cells) or len(cells) != (2 if has_seq else 1):
            raise InputError(
                f"{path} line {i + 2}: expected {'two integers' if has_seq else 'an integer'}, "
                f"got {_shown_row(row)}"
            )
        if not all(0 <= v <= INT64_MAX for v in values):
            raise InputError(
                f"{path} line {i + 2}: {_shown_row(row)} is out of range (0 to 2^63 - 1: "
                "nanoseconds on the monotonic clock, sequence numbers from 0)"
            )
        t[i] = values[0]
        if has_seq:
            seq[i] = values[1]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        j = int(bad[0]) + 1
        raise InputError(
            f"{path} line {j + 2}: timestamp {t[j]} is not after {t[j - 1]} "
            "(timestamps must strictly increase)"
        )
    return t, seq, _checksums(path, rows) if checksums and has_seq else None


def _csv_rows(path: Path) -> list[list[str]]:
    """The rows of a timestamp CSV, header first, without the blank rows at its end."""
    try:
        data = read_input_file(path, "a timestamp file", limit=MAX_TIMESTAMP_BYTES)
    except FileNotFoundError as exc:
        raise MissingInputError(f"{path}: no such timestamp file") from exc
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read timestamp file: {exc.strerror}") from exc
    try:
        text = data.decode("utf-8-sig")  # a byte-order mark, as some editors write, is no data
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: not a text file (byte {exc.start} is not UTF-8); a timestamp file is a "
            "CSV with the header t_ns"
        ) from exc
    try:
        rows = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as exc:
        raise InputError(f"{path}: not a valid CSV file: {exc}") from exc
    # Blank lines at the end are no frames, nor rows of empty cells (a spreadsheet's ",,").
    while rows and not "".join(rows[-1]).strip():
        rows.pop()
    return rows


def checksum(image: np.ndarray) -> int:
    """CRC-32 (zlib's) of an image's pixels in row-major order: what a lossless recording
    stores beside each frame and checks when the frame is decoded again."""
    return zlib.crc32(np.ascontiguousarray(image).data)


RECORDING_COLUMNS: Final = ("t_ns", "seq", CHECKSUM_COLUMN)
"""A recording's timestamp CSV columns, in order."""


def _warn_unknown_columns(path: Path, header: list[str]) -> None:
    """One warning naming the columns of a recording's timestamp CSV that are not where this
    stereod reads them (a misspelt or misplaced ``seq`` or ``crc32`` would otherwise turn the
    frames' check off without a word); they are ignored."""
    unknown = [
        c for i, c in enumerate(header) if i >= len(RECORDING_COLUMNS) or c != RECORDING_COLUMNS[i]
    ]
    if unknown:
        log.warning(
            "%s: ignoring columns this stereod does not read there: %s (a recording's columns "
            "are %s, in that order)",
            path,
            ", ".join(repr(c) for c in unknown),
            ",".join(RECORDING_COLUMNS),
        )


def _checksums(path: Path, rows: list[list[str]]) -> np.ndarray | None:
    """The ``crc32`` column of a timestamp CSV's ``rows`` (header first), or None. Columns
    this stereod does not know are named in one warning (a misspelt ``crc32`` would
    otherwise turn the check off without a word) and ignored."""
    if len(rows[0]) < 3 or rows[0][2].strip() != CHECKSUM_COLUMN:
        return None
    crc = np.empty(len(rows) - 1, np.uint32)
    for i, row in enumerate(rows[1:]):
        try:
            value = int(row[2])
        except (IndexError, ValueError):
            value = -1
        if not 0 <= value < 2**32:
            raise InputError(
                f"{path} line {i + 2}: expected a CRC-32 (an integer from 0 to 2^32 - 1) in "
                f"the third column, got {_shown_row(row)}; remove 'crc32' from the header to "
                "read the recording without checking its frames"
            )
        crc[i] = value
    return crc


def damaged_frames_problem(video: Path, csv: Path, frames: list[int], outcome: str) -> str:
    """The one problem line for the frames of ``video`` (indices from 0, ascending) whose
    pixels differ from the CRC-32 recorded for them in ``csv``; ``outcome`` says what became
    of them."""
    first, last = frames[0], frames[-1]
    if len(frames) == 1:
        which = f"frame {first}"
    elif last - first + 1 == len(frames):
        which = f"frames {first} to {last}"
    else:
        shown = ", ".join(str(i) for i in frames[:5])
        which = f"{len(frames)} frames ({shown}{', ...' if len(frames) > 5 else ''})"
    return (
        f"{video}: {which} decoded into pixels that differ from the CRC-32 recorded for them "
        f"in {csv.name} (the video or {csv.name} is damaged); {outcome}; restore the recording "
        f"from a copy, or remove 'crc32' from {csv.name}'s header to use it unchecked"
    )


def _shown_row(row: list[str], limit: int = 60) -> str:
    text = ",".join(row)
    return repr(text if len(text) <= limit else text[: limit - 3] + "...")


def size_problem(width: int, height: int) -> str | None:
    """Why frames of ``width`` x ``height`` px cannot be recorded as they are, or None.
    OpenCV's FFmpeg video writer (both codecs) silently drops the last column or row of a
    frame of odd width or height, so the videos would not match the manifest."""
    if width % 2 == 0 and height % 2 == 0:
        return None
    even = f"{max(width - width % 2, 2)}x{max(height - height % 2, 2)}"
    return (
        f"{width}x{height} px cannot be recorded: the video writer needs an even width and "
        f"height (it would drop the last column or row); use an even size such as {even}"
    )
