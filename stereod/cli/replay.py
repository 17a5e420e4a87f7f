"""``stereod replay``: play a recording or two videos through the pipeline and publish.

A replay that Ctrl-C or SIGTERM stops before the end of its input is interrupted, not done: it
writes none of its output files (an existing one stays as it was), says after how many pairs
it stopped and exits 130 (143 for SIGTERM). With ``--loop`` a signal is the only end, so there
it ends the run normally.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import re
import signal
from typing import TYPE_CHECKING, Any

from stereod.cli.common import (
    EPILOG_KEYS,
    add_pipeline,
    add_rate,
    add_wait_subscriber,
    check_calibration,
    command_log_level,
    file_arg,
    load_checked,
    number,
    output_arg,
    path_arg,
    pipeline_overrides,
    recording_arg,
    run_daemon,
    run_inputs,
    say,
    setup_logging,
    summaries_off_stdout,
)
from stereod.errors import ReaderGone, StereodError, UsageError
from stereod.files.output_file import Interrupted, check_outputs, signal_name, written_in_place

if TYPE_CHECKING:
    from stereod.daemon.config import StereodConfig
    from stereod.ros.mcap_run import RunMcap


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "replay",
        help="play a recording or two videos through the pipeline and publish",
        description="Play a recording directory (see `stereod synth`) or two plain video files "
        "through the full pipeline, publishing on Zenoh like the daemon. Exits 0 when the input "
        "was played in full, 65 when it was truncated or inconsistent, 66 when missing, 130 "
        "(143) when Ctrl-C (SIGTERM) stopped it before its end: then existing output files are "
        "left as they were and no new one is made. With --loop, Ctrl-C or SIGTERM ends the run "
        "normally. A reader of stdout that goes away (--jsonl /dev/stdout | head) ends it "
        "quietly with 0.",
        epilog=EPILOG_KEYS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "recording",
        nargs="?",
        type=recording_arg,
        help="recording directory (its recording.json names it too)",
    )
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
    p.add_argument(
        "--loop",
        action="store_true",
        help="start again at the end, until Ctrl-C or SIGTERM (which then end the run normally)",
    )
    p.add_argument(
        "--utc-start",
        type=utc_instant_arg,
        metavar="T",
        help="the first frame's UTC instant: ISO 8601 with a zone (2026-03-01T12:00:00Z) or "
        "integer ns since 1970; replays of one scene's rigs given one T share one clock (for "
        "`stereod fuse`)",
    )
    p.add_argument(
        "--jsonl",
        type=output_arg,
        metavar="FILE",
        help="also write every objects message, exactly as published, one per line (the file "
        "is replaced unless the run fails or, without --loop, is interrupted, and an input found "
        "truncated or damaged still gives the file of what played, exit 65; a "
        "symbolic link is written through, a device or FIFO such as /dev/null in place, a "
        "line at a time; - or /dev/stdout: standard output, and the summary goes to stderr)",
    )
    p.add_argument(
        "--mcap",
        type=file_arg,
        metavar="OUT",
        help="also write the run as MCAP with ROS 2 messages: the frames of every pair, "
        "camera_info, tf and the tracks, as `stereod export` does (written as --jsonl is)",
    )
    add_wait_subscriber(p, "playing")
    p.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    add_pipeline(p)
    p.set_defaults(func=run)


def driver_options(a: argparse.Namespace) -> dict[str, Any]:
    """The replay driver's options from the flags."""
    options: dict[str, Any]
    if a.recording is not None:
        if a.left_video or a.right_video:
            raise UsageError("give a recording directory or --left-video/--right-video, not both")
        given = [
            f
            for f, v in (("--fps", a.fps), ("--left-ts", a.left_ts), ("--right-ts", a.right_ts))
            if v is not None
        ]
        if given:
            raise UsageError(
                f"{' and '.join(given)}: for plain videos only; a recording plays at the capture "
                "times it holds (use --rate to play it faster or slower)"
            )
        options = {"path": a.recording}
    elif a.left_video or a.right_video:
        plain_video_flags(a)
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
    if a.utc_start is not None:
        options["utc_start_ns"] = a.utc_start
    return options


def utc_instant_arg(text: str) -> int:
    """An argparse type: a UTC instant as integer ns since 1970, or ISO 8601 with a zone
    (``Z`` or ``+01:00``), to the nanosecond (more digits than 9 after the point refused)."""
    from stereod.files.bounds import UTC_START_NS_MAX

    beyond = f"{text!r}: outside 1970..2100 (the stamps after it must stay within 64 bits)"
    t = text.strip()
    if re.fullmatch(r"[0-9]{1,19}", t):
        ns = int(t)
        if ns > UTC_START_NS_MAX:
            raise argparse.ArgumentTypeError(beyond)
        return ns
    m = re.fullmatch(r"(.+?T\d\d:\d\d:\d\d)(?:\.(\d{1,9}))?(Z|[+-]\d\d:?\d\d)", t)
    if m is None:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give an ISO 8601 instant with its zone, e.g. 2026-03-01T12:00:00.5Z, "
            "or integer ns since 1970"
        )
    zone = "+00:00" if m.group(3) == "Z" else m.group(3)
    if ":" not in zone:
        zone = f"{zone[:3]}:{zone[3:]}"
    try:
        whole = datetime.datetime.fromisoformat(m.group(1) + zone)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
    delta = whole - epoch
    ns = (delta.days * 86_400 + delta.seconds) * 10**9 + delta.microseconds * 1000
    ns += int((m.group(2) or "0").ljust(9, "0"))
    if not 0 <= ns <= UTC_START_NS_MAX:
        raise argparse.ArgumentTypeError(beyond)
    return ns


def plain_video_flags(a: argparse.Namespace) -> None:
    """Refuse plain-video flags that do not make one input, naming the flags (the driver
    names its config fields instead, for the same mistake in a config file)."""
    if a.right_video is None:
        raise UsageError("--left-video needs --right-video too: plain videos are one per eye")
    if a.left_video is None:
        raise UsageError("--right-video needs --left-video too: plain videos are one per eye")
    if a.left_ts is not None and a.right_ts is None:
        raise UsageError("--left-ts needs --right-ts too: capture times are one file per eye")
    if a.right_ts is not None and a.left_ts is None:
        raise UsageError("--right-ts needs --left-ts too: capture times are one file per eye")
    if a.left_ts is not None and a.fps is not None:
        raise UsageError(
            "--fps and --left-ts/--right-ts are exclusive: give --fps HZ (frame i at i / fps) "
            "or the two timestamp files, not both"
        )
    if a.left_ts is None and a.fps is None:
        raise UsageError(
            "plain videos need their capture times: give --fps HZ or --left-ts/--right-ts CSV"
        )
    from stereod.files.output_file import same_file

    if same_file(a.left_video, a.right_video):
        raise UsageError(
            "--left-video and --right-video are one file: each eye needs its own video (one "
            "video for both has no disparity, and every match between the eyes would be a "
            "wrong one)"
        )


def run(a: argparse.Namespace) -> int:
    from stereod.cli.progress import Progress
    from stereod.cli.replay_daemon import InterruptibleReplay, LoopReplay
    from stereod.daemon.config import load_config
    from stereod.files.bounds import ROS_TIME_NS_MAX
    from stereod.sources.drivers import load_driver
    from stereod.sources.recording import read_manifest

    if a.mcap is not None and a.utc_start is not None and a.utc_start > ROS_TIME_NS_MAX:
        raise UsageError(
            f"--utc-start {a.utc_start} ns: after 2038-01-19, the last instant a ROS 2 stamp "
            "holds; give --mcap an earlier start, or leave out --mcap"
        )
    options = driver_options(a)
    ov = pipeline_overrides(a)
    ov["driver"] = {"name": "replay", "options": options}
    cfg = load_config(a.config, ov)
    setup_logging(command_log_level(cfg))
    check_calibration(cfg, a.config, ov)
    driver = load_driver("replay", options)
    check_outputs({"--jsonl": a.jsonl, "--mcap": a.mcap}, run_inputs(a.config, cfg, driver))
    mcap = _mcap(a, cfg)
    summaries_off_stdout(a.jsonl, a.mcap)
    daemon = (LoopReplay if a.loop else InterruptibleReplay)(
        cfg,
        driver,
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
    try:
        code = run_daemon(daemon, quiet=a.quiet, progress=bar, reloads=False)
    except Interrupted as exc:
        if mcap is not None:
            mcap.abort()
        raise Interrupted(_interrupted(a, exc.signum, daemon.summary.pairs), exc.signum) from None
    except ReaderGone as exc:
        if mcap is not None:
            mcap.abort()
        if not _replaced_files(a):
            raise  # nothing left unwritten: quietly for stdout's reader, else its one line
        # A file would hold part of the input: say which was left as it was, as a signal would.
        why = _interrupted(a, signal.SIGPIPE, daemon.summary.pairs, str(exc))
        raise Interrupted(why, signal.SIGPIPE) from None
    except BaseException:
        if mcap is not None:
            mcap.abort()
        raise
    unwritten = [str(p) for p in _replaced_files(a)] if not daemon.summary.pairs else []
    summary = mcap.commit() if mcap is not None else None
    if unwritten and not a.quiet:  # (a file from an earlier run stays as it was)
        say(f"no pair was processed: {' and '.join(unwritten)} not written")
    elif summary is not None and not a.quiet:
        say(summary.line())
    return code


def _mcap(a: argparse.Namespace, cfg: StereodConfig) -> RunMcap | None:
    """The MCAP file of ``--mcap`` (checked against the inputs and the JSONL before)."""
    if a.mcap is None:
        return None
    from stereod.ros.mcap_run import RunMcap, config_geometry

    return RunMcap(a.mcap, rig=cfg.rig.name, geometry=config_geometry(cfg))


def _replaced_files(a: argparse.Namespace) -> list[str]:
    """The outputs a replay writes by replacing a file at its end, so leaves as they were when
    it does not reach its end (a device or FIFO written in place is not one)."""
    return [str(p) for p in (a.jsonl, a.mcap) if p is not None and not written_in_place(p)]


def _interrupted(a: argparse.Namespace, signum: int, pairs: int, why: str = "") -> str:
    """What an interrupted replay says: after how many pairs, why (the signal, unless ``why``
    says), and which files it did not write (a device or FIFO written in place got what
    played)."""
    unit = "pair" if pairs == 1 else "pairs"
    if why:
        text = f"replay stopped after {pairs} {unit}: {why}"
    else:
        text = f"replay interrupted by {signal_name(signum)} after {pairs} {unit}"
    files = _replaced_files(a)
    if files:
        were = "they were" if len(files) > 1 else "it was"
        text += (
            f"; {' and '.join(files)} left as {were} (a replay writes its outputs only when "
            "it plays its input to the end)"
        )
    return text
