"""``stereod calibration show|export|import``: read, convert and bring in calibration files."""

from __future__ import annotations

import argparse
from pathlib import Path

from stereod.cli.common import path_arg, size_arg
from stereod.files.bounds import IMAGE_SIDE_PX
from stereod.files.output_file import check_outputs


def image_size_arg(text: str) -> tuple[int, int]:
    """An argparse type: ``WIDTHxHEIGHT`` of a camera's frames, each side within
    :data:`~stereod.files.bounds.IMAGE_SIDE_PX` (a flag error, exit 64, not a calibration's)."""
    w, h = size_arg(text)
    for side in (w, h):
        problem = IMAGE_SIDE_PX.problem(side)
        if problem is not None:
            raise argparse.ArgumentTypeError(f"{text}: each side {problem}")
    return w, h


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("calibration", help="show, export or import calibration files")
    csub = p.add_subparsers(dest="calibration_command", metavar="ACTION", required=True)
    c = csub.add_parser("show", help="print a calibration file's figures")
    c.add_argument("file", type=path_arg, help="calibration file")
    c = csub.add_parser("export", help="write ROS camera_info YAML (left.yaml, right.yaml)")
    c.add_argument("file", type=path_arg, help="calibration file")
    c.add_argument(
        "--ros", required=True, type=path_arg, metavar="DIR", help="output folder (made if missing)"
    )
    c = csub.add_parser(
        "import",
        help="convert OpenCV FileStorage files (stereo_calib's intrinsics.yml/extrinsics.yml)",
    )
    c.add_argument("intrinsics", type=path_arg, help="file with M1 D1 M2 D2")
    c.add_argument(
        "extrinsics",
        type=path_arg,
        nargs="?",
        help="file with R T [R1 R2 P1 P2 Q] (default: extrinsics.yml beside)",
    )
    c.add_argument(
        "--size",
        required=True,
        type=image_size_arg,
        metavar="WxH",
        help=f"image size the calibration was made at, px, each side {IMAGE_SIDE_PX.range_text()}",
    )
    c.add_argument(
        "--out",
        type=path_arg,
        default=Path("calibration.json"),
        metavar="FILE",
        help="calibration file to write (default calibration.json)",
    )
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    from stereod.vision import calibration as cal_mod
    from stereod.vision import calibration_io
    from stereod.vision.calibrate import Report, format_report

    if a.calibration_command == "show":
        cal = cal_mod.load(a.file)
        print(
            f"{a.file}: calibration {cal.id}, {cal.image_size[0]}x{cal.image_size[1]}, "
            f"made {cal.created_utc or 'at an unknown date'} ({cal.source or 'unknown source'})"
        )
        if cal.quality.pairs_used:
            print(format_report(Report(cal)).split("per pair")[0].rstrip())
        else:
            print(f"baseline |T|: {cal.baseline:.5g}")
        return 0
    if a.calibration_command == "export":
        cal = cal_mod.load(a.file)
        for eye in ("left", "right"):
            check_outputs({"--ros": a.ros / f"{eye}.yaml"}, [a.file])
        for path in calibration_io.export_ros(cal, a.ros):
            print(f"wrote {path}")
        return 0
    cal = calibration_io.import_opencv(a.intrinsics, a.extrinsics, a.size)
    extrinsics = a.extrinsics or a.intrinsics.with_name("extrinsics" + a.intrinsics.suffix)
    check_outputs({"--out": a.out}, [a.intrinsics, extrinsics])
    cal_mod.save(cal, a.out)
    print(f"{cal.source}: rectified focal length P1 {cal.array('P1')[0, 0]:.1f} px")
    print(f"wrote {a.out} (calibration id {cal.id}, baseline |T| {cal.baseline:.5g})")
    return 0
