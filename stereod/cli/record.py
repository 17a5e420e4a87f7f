"""``stereod record``: write what the cameras deliver into a recording, for replay.

Ctrl-C and SIGTERM are how a recording without ``--seconds`` ends, so they end it normally: the
frames recorded so far are kept, the ``--mcap`` file is written with them, the summary says
which signal stopped it, and the exit code is 0. A failure of either eye ends it with that
error instead (:mod:`stereod.sources.record`): no summary, no ``--mcap``, the error's exit code. The
recording directory is always new, so nothing that was there is replaced.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

from stereod.cli.common import (
    add_config,
    add_driver,
    check_calibration,
    command_log_level,
    file_arg,
    number,
    open_driver,
    path_arg,
    run_inputs,
    setup_logging,
    summarise,
)
from stereod.cli.progress import Progress
from stereod.cli.signals import relayed
from stereod.errors import EX_DATAERR, one_line
from stereod.files.output_file import check_outputs, signal_name

if TYPE_CHECKING:
    from stereod.daemon.config import StereodConfig
    from stereod.sources.frames import Driver, Eye, Frame, SourceInfo


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "record",
        help="record what the cameras deliver, for replay",
        description="Write both eyes' frames with their capture timestamps and sequence "
        "numbers, the camera settings and the calibration in force into a recording "
        "directory (replay it with `stereod replay DIR`). It records until --seconds, the end "
        "of the input, or Ctrl-C or SIGTERM, which end it normally: what was recorded is kept, "
        "and --mcap is written with it (stopped before the first frame, nothing is kept, and "
        "the exit is 128 plus the signal's number).",
    )
    p.add_argument("out", type=path_arg, help="recording directory to create")
    p.add_argument(
        "--seconds",
        type=number(0.0, 10**7, lo_open=True, unit="s"),
        metavar="S",
        help="stop after S seconds of stream",
    )
    p.add_argument(
        "--codec",
        choices=["ffv1", "mjpg"],
        default="ffv1",
        help="ffv1 lossless (default) or mjpg lossy",
    )
    p.add_argument(
        "--mcap",
        type=file_arg,
        metavar="OUT",
        help="also write an MCAP file with ROS 2 messages: each eye's frames, camera_info and "
        "tf (the geometry of the config's [rig]); replaced only when the recording succeeds",
    )
    add_config(p, " with the driver")
    add_driver(p)
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    from stereod.daemon.config import load_config

    ov = {"driver": {"name": a.driver}} if a.driver else {}
    cfg = load_config(a.config, ov)
    setup_logging(command_log_level(cfg))
    check_calibration(cfg, a.config, ov)
    driver = open_driver(cfg, a.config, ov)
    stop = threading.Event()
    caught: list[int] = []

    def on_signal(signum: int) -> None:
        caught.append(signum)
        stop.set()

    with relayed({signal.SIGINT: on_signal, signal.SIGTERM: on_signal}):
        return _record(a, cfg, driver, stop, caught)


def _record(
    a: argparse.Namespace,
    cfg: StereodConfig,
    driver: Driver,
    stop: threading.Event,
    caught: list[int],
) -> int:
    """Record until ``stop`` (set by the signals in ``caught``), then say what was kept."""
    from stereod.ros.mcap_run import RunMcap, config_geometry
    from stereod.sources.record import record

    check_outputs({"--mcap": a.mcap}, run_inputs(a.config, cfg, driver))
    mcap = None
    if a.mcap is not None:
        mcap = RunMcap(a.mcap, rig=cfg.rig.name, geometry=config_geometry(cfg))
    with Progress("record", total=a.seconds, unit="s") as bar:
        progress = _RecordProgress(bar) if bar.shown else None
        on_frame: Callable[[Frame], None] | None = progress
        on_start: Callable[[SourceInfo, int | None], None] | None = None
        if mcap is not None:
            on_frame = _both(mcap.frame, progress)
            on_start = mcap.start_source
        problems: list[str] = []
        try:
            counts = record(
                driver,
                a.out,
                seconds=a.seconds,
                codec=a.codec,
                calibration=cfg.rig.calibration,
                stop=stop,
                on_frame=on_frame,
                on_start=on_start,
                problems=problems,
            )
        except BaseException:
            if mcap is not None:
                mcap.abort()
            raise
    how = f" (stopped by {signal_name(caught[0])})" if caught else ""
    if not counts["left"] + counts["right"]:
        if mcap is not None:
            mcap.abort()
        why = f" ({one_line(summarise(problems))})" if problems else ""
        print(f"stereod: no frame recorded{how}: {a.out} not written{why}", file=sys.stderr)
        return 128 + caught[0] if caught else EX_DATAERR
    print(f"recorded {counts['left']} left and {counts['right']} right frames to {a.out}{how}")
    if mcap is not None:
        summary = mcap.commit()
        print(summary.line() if summary else f"no frame recorded: {a.mcap} not written")
    if problems:  # the input was damaged: what could be read is kept, and the run fails
        print(f"stereod: {one_line(summarise(problems))}", file=sys.stderr)
        return EX_DATAERR
    return 0


def _both(
    first: Callable[[Frame], None], second: Callable[[Frame], None] | None
) -> Callable[[Frame], None]:
    if second is None:
        return first

    def call(frame: Frame) -> None:
        first(frame)
        second(frame)

    return call


class _RecordProgress:
    """Stream seconds, frames and dropped frames (gaps in each eye's sequence numbers)."""

    def __init__(self, bar: Progress) -> None:
        self.bar = bar
        self.first_ns: int | None = None
        self.frames = 0
        self.drops = 0
        self.last_seq: dict[Eye, int] = {}

    def __call__(self, frame: Frame) -> None:
        if self.first_ns is None:
            self.first_ns = frame.t_ns
        from stereod.sources.frames import frames_missed  # (imported by the run already)

        self.drops += frames_missed(self.last_seq.get(frame.eye), frame.seq)
        self.last_seq[frame.eye] = frame.seq
        self.frames += 1
        self.bar.set(
            round((frame.t_ns - self.first_ns) * 1e-9, 1), frames=self.frames, drops=self.drops
        )
