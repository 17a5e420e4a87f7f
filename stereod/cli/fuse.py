"""``stereod fuse``: several rigs, one room. Subscribes to every rig's objects, fuses them in
the room frame (:mod:`stereod.fusion`) and publishes the room's tracks, one id per object, on
``<prefix>/rooms/<room>/objects`` (and ``objects/<id>``) in the objects message format, with
its own ``status`` (``stereod.fuse_status/1``), ``alive`` token and ``config``,
``calibration`` (the rig poses) and ``stats`` queryables.

A receiving thread only queues what arrives; one fusion thread drains the queue, ingests every
message waiting and makes one fusion step at the newest stamp, so under load steps merge
messages rather than fall behind. With no message for a while it steps on by the time passed
since the last one, so that rigs that all stopped end their tracks.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import signal
import threading
import time
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import zenoh

from stereod.bus import keys
from stereod.bus.messages import ObjectsMessage, encoding_for
from stereod.bus.publish import Publisher
from stereod.cli.common import (
    add_config,
    add_zenoh,
    number,
    path_arg,
    say,
    setup_logging,
    stdout_gone,
    summaries_off_stdout,
    zenoh_overrides,
)
from stereod.daemon.config import load_config
from stereod.daemon.sdnotify import Notifier
from stereod.errors import ConfigError, ReaderGone, StereodError
from stereod.files.output_file import AtomicOutput, check_outputs
from stereod.files.paths import shown
from stereod.fusion.clock import ClockWatch
from stereod.fusion.fuser import FuseParams, Fuser
from stereod.fusion.mcap import RoomMcapWriter
from stereod.fusion.output import room_payload
from stereod.fusion.room import Room, load_room
from stereod.fusion.status import FUSE_STATUS_SCHEMA, FuseStatus, RigLink
from stereod.vision.geometry import Geometry

if TYPE_CHECKING:
    from stereod.fusion.foxglove import RoomFoxgloveBridge

log = logging.getLogger("stereod.fuse")

IDLE_STEP_S = 0.1
"""With no message for this long, the fusion steps on by the time passed (s)."""
QUEUE_SIZE = 4096
"""Rig messages waiting for the fusion thread; beyond, the newest are dropped and counted."""
WINDOW = 1000
FOXGLOVE_PORT = 8767
"""The room's Foxglove WebSocket port (the rig view's is 8766, so both can run on one host)."""
"""Steps whose timings make the status's percentiles."""


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
        type=path_arg,
        metavar="FILE",
        help="also write every room objects message, one per line (replaced at a clean stop; a "
        "device or FIFO written in place; /dev/stdout sends the summary to stderr)",
    )
    p.add_argument(
        "--mcap",
        type=path_arg,
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
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"], default="INFO")
    add_zenoh(p)
    p.set_defaults(func=run)


class FuseNode:
    """The fusion node's threads and counters around one :class:`Fuser`."""

    def __init__(
        self,
        room: Room,
        fuser: Fuser,
        clock: ClockWatch,
        publisher: Publisher,
        jsonl: AtomicOutput | None,
        prefix: str,
        mcap: RoomMcapWriter | None = None,
    ) -> None:
        self.room = room
        self.fuser = fuser
        self.clock = clock
        self.pub = publisher
        self.jsonl = jsonl
        self.mcap = mcap
        self.inbox: deque[tuple[float, str, bytes]] = deque()
        self.wake = threading.Event()
        self.waiting = False
        self.prefix = prefix
        self.done = threading.Event()
        self.error: BaseException | None = None
        self.lock = threading.Lock()
        self.start = time.monotonic()
        self.received = {r.name: 0 for r in room.rigs}
        self.rejected = 0
        self.dropped = 0
        self.steps = 0
        self.tracks = 0
        self.geometry = Geometry.CANONICAL
        self.fuse_ms: deque[float] = deque(maxlen=WINDOW)
        self.added_ms: deque[float] = deque(maxlen=WINDOW)
        self._steps_at = (self.start, 0)
        self._rig_of: dict[str, str] = {}
        self.pending_room: Room | None = None
        """A room file read again, for the fusion thread to take before its next step."""
        self.reload_problem: str | None = None
        """Why the last reload was refused (on the status until a reload is taken)."""

    def on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh's callback: queue the payload with its arrival time (never blocks the
        session, parses nothing: under load most messages are superseded by their rig's
        next one before the fusion thread gets to them). A deque's append takes no lock, and
        the fusion thread is woken only when it waits, so a message costs the receiving
        thread a few microseconds of the interpreter."""
        if len(self.inbox) >= QUEUE_SIZE:
            with self.lock:
                self.dropped += 1
            return
        self.inbox.append((time.monotonic(), str(sample.key_expr), sample.payload.to_bytes()))
        if self.waiting:
            self.wake.set()

    def _drain(self) -> list[tuple[float, str, bytes]]:
        """Everything queued, waiting up to :data:`IDLE_STEP_S` for something when empty."""
        if not self.inbox:
            self.waiting = True
            if not self.inbox:  # a sample queued between the test and the flag is seen here
                self.wake.wait(IDLE_STEP_S)
            self.waiting = False
            self.wake.clear()
        batch = []
        while self.inbox:
            batch.append(self.inbox.popleft())
        return batch

    def _parse(self, payload: bytes) -> ObjectsMessage | None:
        """A rig's message, or None (counted) for anything else. pydantic's own JSON parser
        (Rust) bounds nesting itself, refusing a payload nested too deep as invalid, and
        parses a message faster than ``json`` alone."""
        try:
            msg = ObjectsMessage.model_validate_json(payload)
        except ValueError:
            with self.lock:
                self.rejected += 1
            return None
        return msg if self.fuser.knows(msg.rig) else None

    def loop(self) -> None:
        """The fusion thread: until :attr:`done`, drain the queue, parse each rig's newest
        message (a rig's message replaces its previous tracks), step, publish."""
        last_rx: float | None = None
        try:
            while not self.done.is_set():
                self._take_room()
                batch = self._drain()
                newest = {key: payload for _, key, payload in batch}
                for payload in newest.values():
                    msg = self._parse(payload)
                    if msg is None:
                        continue
                    self.fuser.ingest(msg)
                    self.geometry = msg.geometry
                with self.lock:
                    for _, key, _ in batch:
                        rig = self._rig_of.get(key)
                        if rig is None:
                            parsed = keys.parse(key, prefix=self.prefix)
                            rig = self._rig_of[key] = parsed[0] if parsed else ""
                        if rig in self.received:
                            self.received[rig] += 1
                latest = self.fuser.latest_ns()
                if latest is None:
                    continue
                if batch:
                    last_rx = max(rx for rx, _, _ in batch)
                    t_ns = latest
                else:  # idle: step on by the time since the last message
                    assert last_rx is not None
                    t_ns = latest + int((time.monotonic() - last_rx) * 1e9)
                self._step(t_ns, [rx for rx, _, _ in batch])
        except BaseException as exc:  # a fatal error ends the run with its own line
            self.error = exc
            self.done.set()

    def room_next(self) -> Room:
        """The room the next step fuses: one read again and not yet taken, else the running
        one."""
        with self.lock:
            return self.pending_room or self.room

    def _take_room(self) -> None:
        """Swap in a room file read again (fusion thread, between two steps)."""
        with self.lock:
            room, self.pending_room = self.pending_room, None
        if room is None:
            return
        with self.lock:  # the status reads the room, the rigs' clocks and links together
            changed = self.fuser.set_room(room)
            self.clock.set_rigs([r.name for r in room.rigs], changed)
            self.room = room
            for r in room.rigs:
                self.received.setdefault(r.name, 0)
        log.info(
            "room file reloaded: %d rigs, %s",
            len(room.rigs),
            f"moved or gone: {', '.join(changed)}" if changed else "no rig moved",
        )

    def _step(self, t_ns: int, received: list[float]) -> None:
        t0 = time.monotonic()
        frame = self.fuser.fuse(t_ns)
        self.clock.observe(frame)
        self.fuser.clock_corrections_ns = dict(self.clock.corrections_ns)
        fuse_ms = (time.monotonic() - t0) * 1e3
        payload, tracks = room_payload(self.room.name, self.steps, frame, self.geometry, fuse_ms)
        self.pub.objects(payload, tracks, frame.ended)
        done = time.monotonic()
        if self.jsonl is not None:
            self.jsonl.write(payload + b"\n")
        if self.mcap is not None:
            msg = ObjectsMessage.model_validate_json(payload)
            self.mcap.write_objects(msg, raw_json=payload.decode())
        with self.lock:
            self.steps += 1
            self.tracks = len(tracks)
            self.fuse_ms.append(fuse_ms)
            self.added_ms.extend((done - rx) * 1e3 for rx in received)

    def status(self, state: str = "running") -> FuseStatus:
        """The node's status now."""
        now = time.monotonic()
        latest = self.fuser.latest_ns()
        live = set(self.fuser.live_rigs(latest)) if latest is not None else set()
        rigs = {}
        with self.lock:
            for r in self.room.rigs:
                est = self.clock.estimate(r.name)
                rigs[r.name] = RigLink(
                    live=r.name in live,
                    messages=self.received[r.name],
                    tracks=self.fuser.rig_track_count(r.name),
                    last_stamp_utc_ns=self.fuser.rig_stamp(r.name),
                    restarts=self.fuser.restarts.get(r.name, 0),
                    clock_offset_ms=est.offset_ms,
                    clock_samples=est.samples,
                    clock_off=est.off,
                    clock_sigma_ms=est.sigma_ms,
                    clock_correction_ms=est.correction_ms,
                )
            t_prev, n_prev = self._steps_at
            rate = (self.steps - n_prev) / max(now - t_prev, 1e-3)
            self._steps_at = (now, self.steps)
            fuse = np.asarray(self.fuse_ms) if self.fuse_ms else None
            added = np.asarray(self.added_ms) if self.added_ms else None
            steps, tracks, dropped, rejected = self.steps, self.tracks, self.dropped, self.rejected
        problems = [
            f"rig {name}'s clock is {link.clock_offset_ms:+.1f} ms off the reference rig "
            f"{self.room.rigs[0].name}'s (bound {self.clock.bound_ms:g} ms): check its "
            "chrony or PTP"
            for name, link in rigs.items()
            if link.clock_off and link.clock_offset_ms is not None
        ]
        problems += [f"rig {n}: no message yet" for n, link in rigs.items() if not link.messages]
        if self.reload_problem is not None:
            problems.append(self.reload_problem)
        if dropped:
            problems.append(f"rig messages dropped, the fusion fell behind: {dropped}")
        if rejected:
            problems.append(f"samples on a rig's objects key that were not objects: {rejected}")

        def pct(a: np.ndarray | None, q: float) -> float | None:
            return None if a is None else float(np.percentile(a, q))

        return FuseStatus(
            room=self.room.name,
            state="stopping" if state == "stopping" else "running",
            stamp_utc_ns=time.time_ns(),
            uptime_s=now - self.start,
            rigs=rigs,
            tracks=tracks,
            steps=steps,
            published=self.pub.published,
            steps_per_s=rate,
            fuse_ms_p50=pct(fuse, 50),
            fuse_ms_p99=pct(fuse, 99),
            added_ms_p50=pct(added, 50),
            added_ms_p99=pct(added, 99),
            clock_bound_ms=self.clock.bound_ms,
            problems=problems,
        )


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


def run(a: argparse.Namespace) -> int:
    """Fuse the room until SIGINT or SIGTERM (exit 0), reading the room file again on SIGHUP;
    a bad room file or configuration at start is one line and 78, a missing one 66, an
    unreachable router 69 (a bad one at a reload is reported, and the room kept)."""
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
    publisher = Publisher(zcfg, room.name, queryables, on_status_subscriber=status_now.set)
    jsonl = AtomicOutput(a.jsonl) if a.jsonl is not None else None
    try:
        mcap = RoomMcapWriter(a.mcap, room) if a.mcap is not None else None
    except BaseException:
        if jsonl is not None:
            jsonl.discard()
        raise
    node = FuseNode(room, fuser, clock, publisher, jsonl, prefix, mcap)
    notifier = Notifier()
    committed = False
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
                log.info("foxglove: serving room %s at %s", room.name, bridge.url)
            worker = threading.Thread(target=node.loop, name="fuse", daemon=True)
            worker.start()
            reload_now = threading.Event()

            def hangup(*_: object) -> None:
                reload_now.set()
                status_now.set()

            def stop(*_: object) -> None:
                node.done.set()
                status_now.set()

            for signum in (signal.SIGINT, signal.SIGTERM):
                signal.signal(signum, stop)
            signal.signal(signal.SIGHUP, hangup)
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
        if jsonl is not None:
            jsonl.commit()
        if mcap is not None:
            mcap.close()
        committed = True
        say(
            f"{node.steps} room messages from {sum(node.received.values())} rig messages; "
            f"{len(fuser.restarts)} rig restarts seen"
        )
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
