"""``stereod calibrate``: calibrate the rig from chessboard pairs (files or live)."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from stereod.bus import keys
from stereod.cli.common import (
    add_config,
    add_driver,
    number,
    open_driver,
    path_arg,
    recording_arg,
    size_arg,
)
from stereod.cli.progress import Progress
from stereod.errors import UsageError
from stereod.files.bounds import MIN_BOARD_CORNERS, MIN_PAIRS, MIN_ROOM_VIEWS, SQUARE_M
from stereod.files.output_file import check_outputs, stopped_by_signals

if TYPE_CHECKING:
    from stereod.vision import calibrate as cb
    from stereod.vision.calibration import Board


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate the stereo rig from chessboard pairs",
        description="Find a chessboard in both images of each pair, calibrate each camera, "
        "then refine both cameras and the pair together, then rectify (Zhang's method, "
        "OpenCV). "
        "Prints per-camera and stereo RMS, epipolar error, baseline, rectified row residual "
        "and per-pair residuals. Refuses a clearly bad result (too few pairs, RMS above "
        "--max-rms, left and right swapped) unless --force; exit 65 then.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--pairs",
        type=path_arg,
        metavar="DIR",
        help="folder of pairs: leftNN/rightNN images, or left/ and right/ folders",
    )
    src.add_argument(
        "--list",
        type=path_arg,
        metavar="FILE",
        help="list of pairs: an OpenCV imagelist (XML/YAML, left and right "
        "alternating) or text with 'LEFT RIGHT' per line",
    )
    src.add_argument(
        "--live",
        action="store_true",
        help="collect pairs from the configured driver (--config, --driver, "
        "--recording) while the board is moved in front of the rig",
    )
    src.add_argument(
        "--room",
        type=path_arg,
        metavar="OUT",
        help="write a room file (TOML): each --rig's pose in the first rig's frame, from "
        "board views that the rigs took at the same instants (same file name in each folder)",
    )
    p.add_argument(
        "--board",
        required=True,
        type=board_arg,
        metavar="COLSxROWS",
        help="inner corners of the chessboard, e.g. 9x6",
    )
    p.add_argument(
        "--square",
        required=True,
        type=SQUARE_M.arg(),
        metavar="M",
        help=f"side of one square, m, {SQUARE_M.range_text()} (every length of the result is "
        "in this unit)",
    )
    p.add_argument(
        "--out",
        type=path_arg,
        metavar="FILE",
        help="calibration file to write (default calibration.json; not with --room, whose "
        "file is the one --room names)",
    )
    p.add_argument(
        "--force", action="store_true", help="write even a calibration that fails the checks"
    )
    p.add_argument(
        "--min-pairs",
        type=number(1, 10000, integer=True),
        metavar="N",
        help=f"fewest usable pairs accepted (default {MIN_PAIRS}, at least 3); with --room, "
        f"fewest views of the board each rig must have (default {MIN_ROOM_VIEWS})",
    )
    p.add_argument(
        "--max-rms",
        type=number(0.0, 100.0, lo_open=True, unit="px"),
        default=1.0,
        metavar="PX",
        help="largest stereo RMS accepted, px (default 1.0); with --room, the largest "
        "reprojection RMS of a rig's board views, its own and through the room",
    )
    p.add_argument(
        "--corner-window",
        type=number(1, 100, integer=True),
        metavar="PX",
        help="half window of the sub-pixel corner refinement, px (default: adapted "
        "to the squares' size in the image; OpenCV's stereo_calib sample uses 11)",
    )
    room = p.add_argument_group("room calibration (--room)")
    room.add_argument(
        "--rig",
        action="append",
        type=rig_arg,
        default=[],
        metavar="NAME=CAL:DIR",
        help="a rig: its name, calibration file and folder of left-eye board images "
        "(or a calibration pairs folder with left/ or leftNN files); twice or more, the first "
        "is the reference whose frame is the room's",
    )
    room.add_argument(
        "--room-name",
        default="room",
        type=room_name_arg,
        metavar="NAME",
        help="the room's name in the file (default room)",
    )
    live = p.add_argument_group("live collection")
    live.add_argument(
        "--wanted",
        type=number(3, 10000, integer=True),
        default=15,
        metavar="N",
        help="pairs to collect before calibrating (default 15)",
    )
    add_config(live, " with the driver")
    add_driver(live)
    live.add_argument(
        "--recording",
        type=recording_arg,
        metavar="DIR",
        help="shorthand for the replay driver on this recording (its folder, or its "
        "recording.json)",
    )
    p.set_defaults(func=run)


def board_arg(text: str) -> tuple[int, int]:
    """An argparse type: ``COLSxROWS`` inner corners, at least 3 a side (OpenCV looks for no
    smaller board), so a bad ``--board`` is one line and exit 64 before any work."""
    cols, rows = size_arg(text)
    if min(cols, rows) < MIN_BOARD_CORNERS:
        raise argparse.ArgumentTypeError(
            f"{text!r}: a board needs at least {MIN_BOARD_CORNERS} inner corners a side; "
            "count the corners where four squares meet, e.g. 9x6"
        )
    return cols, rows


def rig_arg(text: str) -> tuple[str, Path, Path]:
    """An argparse type: ``NAME=CAL:DIR``, a rig's name, calibration file and image folder."""
    name, eq, rest = text.partition("=")
    cal, colon, folder = rest.partition(":")
    if not (eq and colon and cal and folder and re.match(keys.RIG_PATTERN, name)):
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected NAME=CAL:DIR, e.g. a=cal_a.json:views_a (NAME of letters, "
            "digits, _ and -)"
        )
    return name, path_arg(cal), path_arg(folder)


def room_name_arg(text: str) -> str:
    """An argparse type: a room's name, one Zenoh key chunk."""
    if not re.match(keys.RIG_PATTERN, text):
        raise argparse.ArgumentTypeError(f"{text!r}: a room's name is letters, digits, _ and -")
    return text


def run(a: argparse.Namespace) -> int:
    from stereod.vision import calibrate as cb
    from stereod.vision.calibration import Board, create_output, write

    cols, rows = a.board
    board = Board(cols=cols, rows=rows, square=a.square)
    if a.room is not None or a.rig:
        return _room(a, board)
    a.out = a.out or Path("calibration.json")
    if a.min_pairs is not None and a.min_pairs < 3:
        raise UsageError(f"--min-pairs {a.min_pairs}: a stereo calibration needs 3 pairs or more")
    limits = cb.Limits(min_pairs=a.min_pairs or MIN_PAIRS, max_rms_px=a.max_rms)
    pairs = None
    if not a.live:
        pairs = cb.pairs_in_directory(a.pairs) if a.pairs else cb.pairs_from_list(a.list)
        images = [p for pair in pairs for p in pair]
        check_outputs({"--out": a.out}, [a.list, *images])

    # The output is made before the work, so that one that cannot be written is refused first;
    # whatever ends the work early (a signal too) removes its temporary file.
    with stopped_by_signals("calibrate", a.out), create_output(a.out) as out:
        report = _live(a, board, limits) if pairs is None else _files(a, pairs, board, limits)
        print(cb.format_report(report))
        if refused("calibration", report.problems, a.out, a.force):
            out.discard()
            return cb.CalibrationRejected.exit_code
        write(report.calibration, out)
    print(f"wrote {a.out} (calibration id {report.calibration.id})")
    return 0


def refused(what: str, problems: list[str], out: Path, force: bool) -> bool:
    """Whether a result with ``problems`` is refused (not written to ``out``); said on stderr
    either way, and written anyway with ``force``."""
    if not problems:
        return False
    bad = f"{what} is clearly bad: {'; '.join(problems)}"
    if force:
        print(f"stereod: {bad}; written anyway (--force)", file=sys.stderr)
        return False
    print(f"stereod: {bad}; not written to {out} (use --force to write it anyway)", file=sys.stderr)
    return True


def _room(a: argparse.Namespace, board: Board) -> int:
    """``--room``: the rigs' poses from their shared board views, written as a room file."""
    from stereod.vision import room_calibration as room_cal
    from stereod.vision.calibrate import CalibrationRejected
    from stereod.vision.calibration import create_output, load

    if a.room is None:
        raise UsageError("--rig is for --room: add --room OUT.toml")
    if a.out is not None:
        raise UsageError(
            f"--out {a.out}: --room writes the room file it names ({a.room}); drop --out"
        )
    names = [name for name, _, _ in a.rig]
    if len(names) < 2:
        raise UsageError("--room needs two --rig NAME=CAL:DIR or more")
    if len(set(names)) != len(names):
        raise UsageError(f"--rig: a name is given twice ({names}); give each rig one name")
    rigs, mismatches = [], []
    for name, cal_path, folder in a.rig:
        images = room_cal.left_images(folder)
        check_outputs({"--room": a.room}, [cal_path, *images.values()])
        cal = load(cal_path)
        rigs.append(room_cal.RigViews(name, cal, images))
        mismatches.append(room_cal.square_mismatch(name, cal_path, cal, a.square))
    unchecked = [r.name for r in rigs if r.calibration.board is None]
    if unchecked:
        print(
            f"rig(s) {', '.join(unchecked)}: the calibration records no board, so --square "
            f"{a.square:g} is not checked against it (the room's distances scale with --square)"
        )
    if mismatch := next((m for m in mismatches if m is not None), None):
        if not a.force:
            raise CalibrationRejected(f"{mismatch}; nothing written to {a.room}")
        print(f"stereod: {mismatch}; going on (--force)", file=sys.stderr)
    with stopped_by_signals("calibrate", a.room), create_output(a.room) as out:
        report = room_cal.calibrate_room(rigs, board)
        print(room_cal.format_report(report))
        problems = room_cal.check_report(report, a.min_pairs or MIN_ROOM_VIEWS, a.max_rms)
        if refused("room calibration", problems, a.room, a.force):
            out.discard()
            return CalibrationRejected.exit_code
        out.write(room_cal.room_toml(a.room_name, report).encode())
    print(f"wrote {a.room} (room {a.room_name!r}, {len(rigs)} rigs)")
    return 0


def _files(
    a: argparse.Namespace, pairs: list[tuple[Path, Path]], board: Board, limits: cb.Limits
) -> cb.Report:
    from stereod.vision import calibrate as cb

    seen = {True: 0, False: 0}
    with Progress("looking for the board", total=len(pairs), unit="pair") as bar:

        def progress(k: int, name: str, found: bool) -> None:
            seen[found] += 1
            bar.update(1, found=seen[True], rejected=seen[False], last=name)

        return cb.calibrate_files(pairs, board, limits, progress, a.corner_window)


def _live(a: argparse.Namespace, board: Board, limits: cb.Limits) -> cb.Report:
    from stereod.daemon.config import load_config
    from stereod.sources.frames import merged
    from stereod.vision import calibrate as cb

    ov: dict[str, object] = {}
    if a.recording is not None:
        ov["driver"] = {"name": "replay", "options": {"path": a.recording}}
    elif a.driver:
        ov["driver"] = {"name": a.driver}
    cfg = load_config(a.config, ov)
    collector = cb.LiveCollector(board)
    driver = open_driver(cfg, a.config, ov)
    # Not the config's calibration: this run does not read it, and replacing it is the point.
    check_outputs({"--out": a.out}, [a.config, *driver.inputs()])
    with (
        driver.open() as source,
        Progress("pairs kept", total=a.wanted, unit="pair") as bar,
    ):
        check_outputs({"--out": a.out}, source.info.inputs)
        cb.collect_live(
            merged(source.left, source.right),
            collector,
            a.wanted,
            int(cfg.pairing.tolerance_ms * 1e6),
            progress=lambda n, wanted: bar.set(n, seen=collector.seen),
        )
    print(f"pairs kept: {len(collector.kept)}/{a.wanted}", file=sys.stderr, flush=True)
    if len(collector.kept) < a.wanted:
        print(f"the stream ended with {len(collector.kept)} of {a.wanted} pairs", file=sys.stderr)
    if collector.size is None or not collector.kept:
        raise cb.CalibrationRejected(
            f"the {board.cols}x{board.rows} board was not seen in both eyes in "
            f"{collector.seen} pairs: check --board and that the board is in view"
        )
    return cb.calibrate(
        collector.kept, board, collector.size, limits, source=f"live, {len(collector.kept)} pairs"
    )
