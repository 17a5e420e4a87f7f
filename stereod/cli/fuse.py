"""``stereod fuse``: several rigs, one room. Subscribes to every rig's objects, fuses them in
the room frame (:mod:`stereod.fusion`) and publishes the room's tracks, one id per object, on
``<prefix>/rooms/<room>/objects`` (and ``objects/<id>``) in the objects message format, with
its own ``status`` (``stereod.fuse_status/1``), ``alive`` token and ``config``,
``calibration`` (the rig poses) and ``stats`` queryables.

The node's threads (event-driven fusion, each rig message's tracks published at once, the
room's whole message at most ``--max-rate`` times a second) are :mod:`stereod.fusion.node`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from stereod.bus import keys
from stereod.cli.common import (
    add_config,
    add_zenoh,
    file_arg,
    number,
    output_arg,
    path_arg,
    say,
    setup_logging,
    stdout_gone,
    summaries_off_stdout,
    zenoh_overrides,
)
from stereod.cli.signals import relayed
from stereod.errors import ConfigError, ReaderGone, StereodError
from stereod.files.output_file import AtomicOutput, check_outputs
from stereod.files.paths import shown
from stereod.fusion.params import MAX_RATE_HZ, FuseParams

if TYPE_CHECKING:
    import zenoh

    from stereod.daemon.sdnotify import Notifier
    from stereod.fusion.foxglove import RoomFoxgloveBridge
    from stereod.fusion.node import FuseNode
    from stereod.fusion.room import Room

log = logging.getLogger("stereod.fuse")

FOXGLOVE_PORT = 8767
"""The room's Foxglove WebSocket port (the rig view's is 8766, so both can run on one host)."""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "fuse",
        help="fuse several rigs' tracks into one room",
        description="Subscribe to the objects of every rig a room file lists, move them into "
        "the room frame, associate and fuse them, and publish the room's tracks (one id per "
        "object) on <prefix>/rooms/<room>/objects. Runs until SIGINT or SIGTERM; SIGHUP reads "
        "the room file again (a bad one is reported and the room kept).",
    )
    p.add_argument("--room", type=path_arg, required=True, metavar="FILE", help="room file (TOML)")
    add_config(p, " (its [zenoh] section: endpoints, mode, TLS through config_file)")
    p.add_argument(
        "--jsonl",
        type=output_arg,
        metavar="FILE",
        help="also write every room objects message, one per line (replaced at a clean stop; a "
        "device or FIFO written in place; - or /dev/stdout: standard output, and the summary "
        "goes to stderr)",
    )
    p.add_argument(
        "--mcap",
        type=file_arg,
        metavar="FILE",
        help="also write the room's tracks as ROS 2 messages (Odometry, markers, JSON) in the "
        "room frame, with /tf_static placing every rig's frame in the room (replaced at a "
        "clean stop)",
    )
    p.add_argument(
        "--gate",
        type=number(1.0, 1000.0),
        default=FuseParams().gate_chi2,
        metavar="CHI2",
        help="squared Mahalanobis distance beyond which a rig track is not a room track "
        "(default %(default)s: 99.9 %% of 3-D Gaussian samples)",
    )
    p.add_argument(
        "--rig-timeout",
        type=number(0.05, 60.0, unit="s"),
        default=FuseParams().rig_timeout_s,
        metavar="S",
        help="a rig silent this long loses its tracks, s (default %(default)s)",
    )
    p.add_argument(
        "--max-coast",
        type=number(0.0, 60.0, unit="s"),
        default=FuseParams().max_coast_s,
        metavar="S",
        help="a room track no rig sees this long ends, s (default %(default)s)",
    )
    p.add_argument(
        "--clock-bound",
        type=number(0.1, 10_000.0, unit="ms"),
        default=20.0,
        metavar="MS",
        help="flag a rig whose clock is off the reference rig's by more, ms (default %(default)s)",
    )
    p.add_argument(
        "--max-rate",
        type=number(1.0, 1000.0, unit="Hz"),
        default=MAX_RATE_HZ,
        metavar="HZ",
        help="the room's whole message at most this often, Hz (default %(default)s); each "
        "track's own key (objects/<id>) is updated as soon as a rig's message is fused",
    )
    g = p.add_argument_group("Foxglove (the topics and frames of --mcap, live)")
    g.add_argument(
        "--foxglove",
        action="store_true",
        help="also serve the room to the Foxglove app over its WebSocket protocol",
    )
    g.add_argument(
        "--foxglove-port",
        type=number(0, 65535, integer=True),
        default=FOXGLOVE_PORT,
        metavar="N",
        help="TCP port of the Foxglove WebSocket (default %(default)s; 0: any free port)",
    )
    g.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="ADDR",
        help="address of the Foxglove WebSocket (default 127.0.0.1: this machine only)",
    )
    p.add_argument(
        "--log-level",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        default="INFO",
        help="the least severe log lines written to stderr (default INFO)",
    )
    add_zenoh(p)
    p.set_defaults(func=run, reloads_on_sighup=True)  # its handler comes with the room


NOTHING_RECEIVED = (
    "stereod fuse: no message came from the room's rigs ({rigs}): connect their daemons and "
    "this node to one another, or all to one router (--connect / --listen, or [zenoh] in "
    "--config; peers do not find each other by multicast), and use the rig names of the "
    "room file (--rig)"
)
"""Said at the end of a run in which no rig's message arrived."""


def _calibration(room: Room) -> bytes:
    """The ``calibration`` queryable's reply: each rig's R (row-major) and t in the room."""
    return json.dumps(
        {
            "room": room.name,
            "convention": "p_room = R p_rig + t; R = Rz(rz) Ry(ry) Rx(rx), rotation_deg = "
            "[rx, ry, rz]",
            "rigs": {
                r.name: {
                    "rotation": r.rotation().round(12).tolist(),
                    "translation_m": list(r.translation_m),
                }
                for r in room.rigs
            },
        }
    ).encode()


RELOAD_REFUSED = "room file reload refused, keeping the room loaded before"
"""How a refused reload's problem begins (on the status until a reload is taken)."""


def _reload(
    path: Path,
    node: FuseNode,
    session: zenoh.Session,
    subs: dict[str, zenoh.Subscriber],
    prefix: str,
    notifier: Notifier,
    bridge: RoomFoxgloveBridge | None = None,
) -> None:
    """SIGHUP: read the room file again. A valid one (the same room's name) is handed to the
    fusion thread, subscriptions follow its rigs; anything else is one line on the status and
    in the log, and the room runs on as it was."""
    from stereod.fusion.room import load_room

    notifier.notify(RELOADING=1)
    try:
        room = load_room(path)
        old = node.room_next().name
        if room.name != old:
            raise ConfigError(
                f"{shown(path)}: the room's name changed from {old!r} to {room.name!r}; its keys "
                "follow the name, so restart stereod fuse to rename the room"
            )
    except Exception as exc:  # nothing in a new file may stop a running node
        reason = str(exc) if isinstance(exc, StereodError) else f"{type(exc).__name__}: {exc}"
        node.reload_problem = f"{RELOAD_REFUSED}: {reason}"
        log.error("%s", node.reload_problem)
        notifier.notify(READY=1)
        return
    names = {r.name for r in room.rigs}
    for r in room.rigs:
        if r.name not in subs:
            subs[r.name] = session.declare_subscriber(
                keys.objects(r.name, prefix=prefix), node.on_sample
            )
    for name in [n for n in subs if n not in names]:
        subs.pop(name).undeclare()
    with node.lock:
        node.pending_room = room
    node.reload_problem = None
    if bridge is not None:
        bridge.set_room(room)
    notifier.notify(READY=1)


def summary(node: FuseNode, restarts: int) -> str:
    """The run's last line: room messages, steps and rig messages, rig restarts, and the
    room's rigs never heard from, when others were (all silent has a line of its own)."""
    line = (
        f"{node.room_messages} room messages ({node.steps} fusion steps) from "
        f"{sum(node.received.values())} rig messages; {restarts} rig restarts seen"
    )
    silent = [rig for rig, n in node.received.items() if not n]
    if silent and len(silent) < len(node.received):
        line += f"; never heard from rig {', '.join(silent)}"
    return line


def run(a: argparse.Namespace) -> int:
    """Fuse the room until SIGINT or SIGTERM (exit 0), reading the room file again on SIGHUP;
    a bad room file or configuration at start is one line and 78, a missing one 66, an
    unreachable router 69 (a bad one at a reload is reported, and the room kept)."""
    import zenoh

    from stereod.bus.messages import encoding_for
    from stereod.daemon.config import load_config
    from stereod.daemon.sdnotify import Notifier
    from stereod.fusion.clock import ClockWatch
    from stereod.fusion.collector import freeze_startup_heap
    from stereod.fusion.fuser import Fuser
    from stereod.fusion.mcap import RoomMcapWriter
    from stereod.fusion.node import FuseNode, RoomPublisher
    from stereod.fusion.room import load_room
    from stereod.fusion.status import FUSE_STATUS_SCHEMA

    room = load_room(a.room)
    cfg = load_config(a.config, {"zenoh": zenoh_overrides(a)})
    setup_logging(a.log_level)
    inputs = [a.room, a.config, cfg.zenoh.config_file]
    check_outputs({"--jsonl": a.jsonl, "--mcap": a.mcap}, inputs)
    summaries_off_stdout(a.jsonl, a.mcap)
    params = FuseParams(gate_chi2=a.gate, rig_timeout_s=a.rig_timeout, max_coast_s=a.max_coast)
    fuser = Fuser(room, params)
    clock = ClockWatch([r.name for r in room.rigs], bound_ms=a.clock_bound)
    prefix = cfg.zenoh.prefix
    # The room's keys are those of a rig named after the room under <prefix>/rooms.
    zcfg = cfg.zenoh.model_copy(update={"prefix": f"{prefix}/rooms"})
    config = {
        "room": room.model_dump(mode="json"),
        "fuse": {
            "gate_chi2": params.gate_chi2,
            "rig_timeout_s": params.rig_timeout_s,
            "max_coast_s": params.max_coast_s,
            "clock_bound_ms": a.clock_bound,
        },
    }

    def stats() -> bytes:
        return node.status().model_dump_json(by_alias=True).encode()

    def calibration() -> bytes:
        return _calibration(node.room)

    queryables = {
        "config": lambda: json.dumps(config).encode(),
        "calibration": calibration,
        "stats": stats,
    }
    status_now = threading.Event()
    publisher = RoomPublisher(zcfg, room.name, queryables, on_status_subscriber=status_now.set)
    jsonl = AtomicOutput(a.jsonl) if a.jsonl is not None else None
    try:
        mcap = RoomMcapWriter(a.mcap, room) if a.mcap is not None else None
    except BaseException:
        if jsonl is not None:
            jsonl.discard()
        raise
    node = FuseNode(room, fuser, clock, publisher, jsonl, prefix, mcap, a.max_rate)
    reload_now = threading.Event()

    def hangup(_signum: int) -> None:
        reload_now.set()
        status_now.set()

    def stop(_signum: int) -> None:
        node.done.set()
        status_now.set()

    notifier = Notifier()
    committed = False
    # To the end, outputs committed: a late signal only stops what has already stopped.
    with relayed({signal.SIGINT: stop, signal.SIGTERM: stop, signal.SIGHUP: hangup}):
        try:
            with publisher, contextlib.ExitStack() as stack:
                bridge: RoomFoxgloveBridge | None = None
                if publisher.rig_taken:
                    raise ConfigError(
                        f"another stereod fuse already publishes room {room.name!r} under "
                        f"{publisher.base}/ on this bus; give this room another name in {a.room}"
                    )
                session = publisher.session
                status_pub = session.declare_publisher(
                    keys.status(room.name, prefix=zcfg.prefix),
                    encoding=zenoh.Encoding(encoding_for(FUSE_STATUS_SCHEMA)),
                    congestion_control=zenoh.CongestionControl.DROP,
                )
                subs = {
                    r.name: session.declare_subscriber(
                        keys.objects(r.name, prefix=prefix), node.on_sample
                    )
                    for r in room.rigs
                }
                if a.foxglove:
                    from stereod.fusion.foxglove import RoomFoxgloveBridge

                    bridge = RoomFoxgloveBridge(
                        session, room, prefix=prefix, host=a.foxglove_host, port=a.foxglove_port
                    )
                    stack.enter_context(bridge)
                frozen = freeze_startup_heap()
                log.debug("start-up heap frozen: %d objects left out of collections", frozen)
                worker = threading.Thread(target=node.loop, name="fuse", daemon=True)
                worker.start()
                notifier.notify(READY=1, STATUS=f"fusing room {room.name}")
                log.info(
                    "fusing %d rigs into %s",
                    len(room.rigs),
                    keys.objects(room.name, prefix=zcfg.prefix),
                )
                period = cfg.daemon.status_period_s
                last = 0.0
                while not node.done.is_set():
                    status_now.wait(min(period, 0.25))
                    if reload_now.is_set():
                        reload_now.clear()
                        _reload(a.room, node, session, subs, prefix, notifier, bridge)
                        config["room"] = node.room_next().model_dump(mode="json")
                    now = time.monotonic()
                    if status_now.is_set() or now - last >= period:
                        status_now.clear()
                        st = node.status()
                        status_pub.put(st.model_dump_json(by_alias=True).encode())
                        notifier.notify(
                            WATCHDOG=1,
                            STATUS=f"{st.tracks} tracks, {st.steps_per_s:.1f} steps/s, "
                            f"{sum(link.live for link in st.rigs.values())}/{len(st.rigs)} rigs",
                        )
                        last = now
                notifier.notify(STOPPING=1)
                worker.join()
                for s in subs.values():
                    s.undeclare()
                status_pub.put(node.status("stopping").model_dump_json(by_alias=True).encode())
                status_pub.undeclare()
            if node.error is not None:
                raise node.error
            if node.room_messages:
                if jsonl is not None:
                    jsonl.commit()
                if mcap is not None:
                    mcap.close()
                committed = True
            say(summary(node, len(fuser.restarts)))
            unwritten = [str(p) for p in (a.jsonl, a.mcap) if p is not None]
            if not committed and unwritten:  # a file from an earlier run stays as it was
                say(f"no room message: {' and '.join(unwritten)} not written")
            if not any(node.received.values()):
                print(NOTHING_RECEIVED.format(rigs=", ".join(r.name for r in room.rigs)),
                      file=sys.stderr)  # fmt: skip
        except ReaderGone as exc:
            if exc.stdout:
                stdout_gone()
                return 0
            raise
        finally:
            if jsonl is not None and not committed:
                jsonl.discard()
            if mcap is not None and not committed:
                mcap.abort()
            notifier.close()
        return 0
