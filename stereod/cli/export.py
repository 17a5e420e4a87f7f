"""``stereod export``: a finished run (recording and/or JSONL) to an MCAP file of standard ROS 2
messages, for ``ros2 bag play``, Foxglove and PlotJuggler.

Ctrl-C or SIGTERM during an export ends it as interrupted: the temporary file is removed, an
existing ``--mcap`` file stays as it was, and the exit code is 130 (143 for SIGTERM).
"""

from __future__ import annotations

import argparse
import sys

from stereod.cli.common import (
    add_canonical_rig,
    file_arg,
    number,
    path_arg,
    recording_arg,
    refuse_rig_flags,
    say,
    summaries_off_stdout,
    summarise,
)
from stereod.errors import EX_DATAERR, ConfigError, StereodError, one_line
from stereod.files.output_file import check_outputs, stopped_by_signals

TOPICS = """\
topics (<rig> from the messages, e.g. minoru):
  /tf_static                                     tf2_msgs/msg/TFMessage (body -> rig -> cameras)
  /stereod/<rig>/{left,right}/image/compressed   sensor_msgs/msg/CompressedImage, per frame
  /stereod/<rig>/{left,right}/camera_info        sensor_msgs/msg/CameraInfo, per frame
  /stereod/<rig>/tracks/odom                     nav_msgs/msg/Odometry, per track state
  /stereod/<rig>/tracks/markers                  visualization_msgs/msg/MarkerArray, per pair
  /stereod/<rig>/tracks/track_<id>/speed_heading geometry_msgs/msg/Vector3Stamped (m/s, deg)
  /stereod/<rig>/objects                         std_msgs/msg/String, the JSON messages
"""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "export",
        help="export a run to MCAP with standard ROS 2 messages (ros2 bag, Foxglove)",
        description="Write a run (its recording directory and the JSONL of its messages, from "
        "`stereod replay REC --jsonl RUN.jsonl`) into one MCAP file of standard ROS 2 Humble "
        "messages: images, camera_info, tf, and the tracks as Odometry, markers and speed/"
        "heading. `ros2 bag play`, Foxglove and PlotJuggler open it without stereod. The file "
        "is replaced unless the export fails or Ctrl-C (exit 130) or SIGTERM (143) stops it; "
        "an input found truncated or damaged still gives the file of what could be exported "
        "(exit 65). A symbolic link is written through, a device or FIFO such as "
        "/dev/null in place.",
        epilog=TOPICS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "recording",
        nargs="?",
        type=recording_arg,
        help="the run's recording directory (images and per-frame camera_info; its "
        "recording.json names it too)",
    )
    p.add_argument(
        "--jsonl",
        type=path_arg,
        metavar="FILE",
        help="the run's objects messages, one JSON per line (`stereod replay --jsonl`)",
    )
    p.add_argument("--mcap", type=file_arg, metavar="OUT", required=True, help="MCAP file to write")
    p.add_argument(
        "--calibration",
        type=path_arg,
        metavar="FILE",
        help="the calibration the run used (default: the recording's own, or the canonical rig)",
    )
    add_canonical_rig(p, defaults=False, context="canonical rig, as the run used: ")
    p.add_argument(
        "--no-images",
        action="store_true",
        help="leave the images out (camera_info, tf and tracks only; nothing is decoded)",
    )
    p.add_argument("--png", action="store_true", help="images as PNG (lossless) instead of JPEG")
    p.add_argument(
        "--jpeg-quality",
        type=number(1, 100, integer=True),
        default=90,
        metavar="Q",
        help="JPEG quality of the images, 1-100 (default 90)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    with stopped_by_signals("export", a.mcap):
        return _export(a)


def _export(a: argparse.Namespace) -> int:
    from stereod.ros.export_mcap import export_run
    from stereod.vision.calibration import load

    if a.recording is None and a.jsonl is None:
        raise ConfigError(
            "nothing to export: give the run's recording directory and/or --jsonl RUN.jsonl"
        )
    check_outputs({"--mcap": a.mcap}, [a.jsonl, a.calibration, a.recording])
    cal = None
    if a.calibration is not None:
        refuse_rig_flags("given by --calibration", a.calibration, a.baseline, a.hfov)
        try:
            cal = load(a.calibration)
        except StereodError as exc:
            raise type(exc)(f"{exc}; it is given by --calibration") from exc
    rig = {"baseline_m": a.baseline, "hfov_deg": a.hfov}
    summaries_off_stdout(a.mcap)
    summary = export_run(
        a.mcap,
        jsonl=a.jsonl,
        recording=a.recording,
        calibration=cal,
        **{k: v for k, v in rig.items() if v is not None},  # else the Minoru's
        include_images=not a.no_images,
        image_format="png" if a.png else "jpeg",
        jpeg_quality=a.jpeg_quality,
    )
    if not a.quiet:
        say(summary.line(problems=False))
    if summary.problems:  # what could be exported was: the file stays, as replay's outputs do
        print(f"stereod: {one_line(summarise(summary.problems))}", file=sys.stderr)
        return EX_DATAERR
    return 0
