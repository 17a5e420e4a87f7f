"""``stereod replay``: play a recording or two videos through the pipeline and publish."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path
from typing import Any

from ..config import StereodConfig, load_config
from ..daemon import Daemon
from ..drivers import load_driver
from ..errors import StereodError, UsageError
from ..mcap_run import RunMcap, config_geometry
from ..output_file import check_not_input
from ..progress import Progress
from ..recording import read_manifest
from .common import (
    EPILOG_KEYS,
    add_pipeline,
    add_rate,
    add_wait_subscriber,
    command_log_level,
    load_checked,
    number,
    path_arg,
    pipeline_overrides,
    run_daemon,
    setup_logging,
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "replay",
        help="play a recording or two videos through the pipeline and publish",
        description="Play a recording directory (see `stereod synth`) or two plain video files "
        "through the full pipeline, publishing on Zenoh like the daemon. Exits 0 when the input "
        "was played in full, 65 when it was truncated or inconsistent, 66 when missing.",
        epilog=EPILOG_KEYS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("recording", nargs="?", type=path_arg, help="recording directory")
    v = p.add_argument_group("plain videos (instead of a recording)")
    v.add_argument("--left-video", type=path_arg, metavar="FILE", help="left eye video")
    v.add_argument("--right-video", type=path_arg, metavar="FILE", help="right eye video")
    v.add_argument(
        "--fps",
        type=number(0.01, 10000.0, unit="Hz"),
        metavar="HZ",
        help="frame rate of both videos, Hz: frame i is stamped i / fps",
    )
    v.add_argument(
        "--left-ts",
        type=path_arg,
        metavar="CSV",
        help="left capture times: header t_ns, one integer (ns) per frame",
    )
    v.add_argument(
        "--right-ts", type=path_arg, metavar="CSV", help="right capture times, as --left-ts"
    )
    add_rate(p, "playback speed: 1 real time (default), 2 twice as fast, 0 as fast as possible")
    p.add_argument("--loop", action="store_true", help="start again at the end (until Ctrl-C)")
    p.add_argument(
        "--jsonl",
        type=path_arg,
        metavar="FILE",
        help="also write every objects message, exactly as published, one per line (the file "
        "is replaced only when the run succeeds)",
    )
    p.add_argument(
        "--mcap",
        type=path_arg,
        metavar="OUT",
        help="also write the run as MCAP with ROS 2 messages: the frames of every pair, "
        "camera_info, tf and the tracks, as `stereod export` does (replaced only when the run "
        "succeeds)",
    )
    add_wait_subscriber(p, "playing")
    p.add_argument("-q", "--quiet", action="store_true", help="no summary on stdout")
    add_pipeline(p)
    p.set_defaults(func=run)


def driver_options(a: argparse.Namespace) -> dict[str, Any]:
    """The replay driver's options from the flags."""
    options: dict[str, Any]
    if a.recording is not None:
        if a.left_video or a.right_video:
            raise UsageError("give a recording directory or --left-video/--right-video, not both")
        options = {"path": a.recording}
    elif a.left_video or a.right_video:
        options = {
            "left_video": a.left_video,
            "right_video": a.right_video,
            "fps": a.fps,
            "left_ts": a.left_ts,
            "right_ts": a.right_ts,
        }
        options = {k: v for k, v in options.items() if v is not None}
    else:
        raise UsageError(
            "nothing to replay: give a recording directory or "
            "--left-video L --right-video R with --fps or --left-ts/--right-ts"
        )
    if a.loop:
        options["loop"] = True
    return options


def run(a: argparse.Namespace) -> int:
    options = driver_options(a)
    ov = pipeline_overrides(a)
    ov["driver"] = {"name": "replay", "options": options}
    cfg = load_config(a.config, ov)
    setup_logging(command_log_level(cfg))
    mcap = _mcap(a, cfg, options)
    daemon = Daemon(
        cfg,
        load_driver("replay", options),
        rate=a.rate,
        jsonl=a.jsonl,
        wait_subscriber_s=a.wait_subscriber,
        reload_config=lambda: load_checked(a.config, ov)[0],
        inputs=[a.config] if a.config is not None else [],
        on_message=mcap.outgoing if mcap is not None else None,
        keep_frames=mcap is not None,
    )
    total = None
    if a.recording is not None and not a.loop:
        with contextlib.suppress(StereodError):
            m = read_manifest(a.recording)
            total = min(m.left.frames, m.right.frames)
    st = daemon.pairer.stats
    bar = Progress(
        "replay",
        total=total,
        unit="pair",
        poll=lambda: (st.pairs, {"frames": sum(st.frames.values())}),
    )
    if mcap is None:
        return run_daemon(daemon, quiet=a.quiet, progress=bar)
    try:
        code = run_daemon(daemon, quiet=a.quiet, progress=bar)
    except BaseException:
        mcap.abort()
        raise
    summary = mcap.commit()
    if not a.quiet:
        print(summary.line() if summary else f"no pair was processed: {a.mcap} not written")
    return code


def _mcap(a: argparse.Namespace, cfg: StereodConfig, options: dict[str, Any]) -> RunMcap | None:
    """The MCAP file of ``--mcap``, refused when it is one of the inputs or the JSONL."""
    if a.mcap is None:
        return None
    if a.jsonl is not None and a.mcap.resolve() == a.jsonl.resolve():
        raise UsageError(f"--mcap {a.mcap} and --jsonl are the same file; give two names")
    inputs = [Path(p) for k, p in options.items() if k != "loop" and k != "fps"]
    inputs += [p for p in (a.config, cfg.rig.calibration) if p is not None]
    if a.recording is not None and a.recording.is_dir():
        inputs += sorted(a.recording.iterdir())
    check_not_input(a.mcap, inputs, "--mcap")
    return RunMcap(a.mcap, rig=cfg.rig.name, geometry=config_geometry(cfg))
