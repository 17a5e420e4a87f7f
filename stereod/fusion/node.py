"""The fusion node's threads around one :class:`~stereod.fusion.fuser.Fuser` (``stereod fuse``).

Event-driven: a receiving thread only queues what arrives; one fusion thread takes everything
waiting, parses each rig's newest message and fuses those rigs' tracks at once at the newest
stamp (``Fuser.fuse(t, rigs)``): only the room tracks they touch are fused and written again.
Those tracks go out at once on their own keys (``objects/<id>``), so that a rig message's added
latency is one message's work, not a step period; the room's whole message (``objects``,
every track's latest state, each at its own stamp) goes out at most ``max_rate_hz`` times a
second, its objects' JSON kept per id between messages. Under load a step takes every message
waiting, so steps merge messages rather than fall behind. A step's tracks are published before
anything else is done with them (their JSON kept, the clock watch, the counts), and the room's
message, when due, waits while a rig message is waiting (for a second period at most): what
is left of a step's work never delays the next rig message's tracks. With no message for a
while it steps on by the time passed since the last one, so that rigs that all stopped end
their tracks.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque

import numpy as np
import zenoh
from pydantic import ValidationError

from stereod.bus import keys
from stereod.bus.messages import OBJECT_SCHEMA, ObjectsMessage, encoding_for
from stereod.bus.publish import Publisher
from stereod.errors import InputError, describe_validation_error, one_line
from stereod.files.output_file import AtomicOutput
from stereod.fusion.clock import ClockWatch
from stereod.fusion.fuser import Fuser
from stereod.fusion.histogram import EDGES_MS, LatencyHistogram
from stereod.fusion.mcap import RoomMcapWriter
from stereod.fusion.output import frame_payloads, join_room
from stereod.fusion.params import MAX_RATE_HZ
from stereod.fusion.room import Room
from stereod.fusion.status import WINDOW, FuseStatus, RigLink
from stereod.fusion.wire import RigWire, decode
from stereod.vision.geometry import Geometry

log = logging.getLogger("stereod.fuse")

IDLE_STEP_S = 0.1
"""With no message for this long, the fusion steps on by the time passed (s)."""
QUEUE_SIZE = 4096
"""Rig messages waiting for the fusion thread; beyond, the newest are dropped and counted."""


class RoomPublisher(Publisher):
    """A :class:`Publisher` that can also update some tracks' own keys without the room's
    whole message (a rig message touches a few of the room's tracks)."""

    def tracks(self, tracks: list[tuple[int, bytes]], ended: list[int]) -> None:
        """Put each (track id, object JSON) on ``objects/<id>`` and a DELETE per ended id."""
        with self._lock:
            try:
                for tid, body in tracks:
                    pub = self._tracks.get(tid)
                    if pub is None:
                        assert self._session is not None
                        pub = self._tracks[tid] = self._session.declare_publisher(
                            keys.track(self.rig, tid, prefix=self.prefix),
                            encoding=zenoh.Encoding(encoding_for(OBJECT_SCHEMA)),
                            congestion_control=zenoh.CongestionControl.DROP,
                        )
                    pub.put(body)
                for tid in ended:
                    self._end_track(tid)
            except zenoh.ZError as exc:
                self.errors += 1
                log.warning("publish failed: %s", exc)


class FuseNode:
    """The fusion node's threads and counters around one :class:`Fuser`."""

    def __init__(
        self,
        room: Room,
        fuser: Fuser,
        clock: ClockWatch,
        publisher: RoomPublisher,
        jsonl: AtomicOutput | None,
        prefix: str,
        mcap: RoomMcapWriter | None = None,
        max_rate_hz: float = MAX_RATE_HZ,
    ) -> None:
        self.room = room
        self.fuser = fuser
        self.clock = clock
        self.pub = publisher
        self.jsonl = jsonl
        self.mcap = mcap
        self.min_period_s = 1.0 / max_rate_hz
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
        self.last_rejected: str | None = None
        self.mcap_skipped = 0
        self.mcap_problem: str | None = None
        self.dropped = 0
        self.steps = 0
        self.room_messages = 0
        self.geometry = Geometry.CANONICAL
        self.fuse_ms: deque[float] = deque(maxlen=WINDOW)
        self.added_ms: deque[float] = deque(maxlen=WINDOW)
        self.added_hist = LatencyHistogram()
        """Every rig message's added latency since start, in bins (for the status)."""
        self._steps_at = (self.start, 0)
        self.heard_at: dict[str, float] = {}
        """Each rig's last message's arrival (monotonic s): a rig silent past the fuser's
        ``rig_timeout_s`` is not live, even while no other rig's stamp moves on."""
        self._rig_of: dict[str, str] = {}
        self._states: dict[int, bytes] = {}
        """Each live room track's object JSON, as last written (by id)."""
        self._room_due = False
        self._room_at = 0.0
        self._t_ns = 0
        self.pending_room: Room | None = None
        """A room file read again, for the fusion thread to take before its next step."""
        self.reload_problem: str | None = None
        """Why the last reload was refused (on the status until a reload is taken)."""

    @property
    def tracks(self) -> int:
        """Room tracks live now (with a member to describe them)."""
        return len(self._states)

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
        """Everything queued, waiting for something when empty: up to :data:`IDLE_STEP_S`, or
        until the room's message is due when one is waiting for its turn."""
        if not self.inbox:
            wait = IDLE_STEP_S
            if self._room_due:
                wait = max(0.0, min(wait, self._room_at + self.min_period_s - time.monotonic()))
            self.waiting = True
            if not self.inbox:  # a sample queued between the test and the flag is seen here
                self.wake.wait(wait)
            self.waiting = False
            self.wake.clear()
        batch = []
        while self.inbox:
            batch.append(self.inbox.popleft())
        return batch

    def _parse(self, key: str, payload: bytes) -> RigWire | None:
        """A rig's message as arrays, or None (counted, the rig named) for anything else, or
        for a message of another rig than its key's: ``wire.decode`` reads a plain message
        with ``msgspec``, with no model per object, and leaves anything else to the model
        (whose JSON parser bounds nesting itself)."""
        rig = self._rig(key)
        try:
            msg = decode(payload)
        except ValueError as exc:  # pydantic's text spans lines: its fields, on one
            why = describe_validation_error(exc) if isinstance(exc, ValidationError) else str(exc)
            self._reject(rig, one_line(why)[:200] or type(exc).__name__)
            return None
        if msg.rig != rig:  # another rig's name (a copied config): its tracks are not rig's
            self._reject(rig, f"a message of rig {msg.rig[:40]!r} on its key")
            return None
        return msg if self.fuser.knows(msg.rig) else None

    def _reject(self, rig: str, why: str) -> None:
        with self.lock:
            self.rejected += 1
            self.last_rejected = f"rig {rig}: {why}"

    def _rig(self, key: str) -> str:
        """The rig whose objects key ``key`` is ("" for none)."""
        rig = self._rig_of.get(key)
        if rig is None:
            parsed = keys.parse(key, prefix=self.prefix)
            rig = self._rig_of[key] = parsed[0] if parsed else ""
        return rig

    def loop(self) -> None:
        """The fusion thread: until :attr:`done`, drain the queue, fuse what came
        (:meth:`_handle`), publish the room's message when due."""
        last_rx: float | None = None
        try:
            while not self.done.is_set():
                self._take_room()
                last_rx = self._handle(self._drain(), last_rx)
                if self._room_due and self._room_turn(time.monotonic() - self._room_at):
                    self._publish_room()
            if self._room_due:  # the last tracks fused, before the node stops
                self._publish_room()
        except BaseException as exc:  # a fatal error ends the run with its own line
            self.error = exc
            self.done.set()

    def _handle(self, batch: list[tuple[float, str, bytes]], last_rx: float | None) -> float | None:
        """Ingest each rig's newest message in ``batch`` (a rig's message replaces its
        previous tracks) and fuse those rigs in one step, or, idle, step on by the time since
        the last message (``last_rx``, monotonic s) to end tracks. The room's instant never
        goes back: a rig whose message came after a newer one of another rig's has its tracks
        predicted on to that instant, and one more than the rig timeout behind is left out
        (it re-stamped every room track it touched with its own time, seconds back). Gives
        the arrival of the batch's last message, or ``last_rx`` without one."""
        newest = {key: (rx, payload) for rx, key, payload in batch}
        rigs: list[str] = []
        refused: set[tuple[float, str]] = set()
        for key, (rx, payload) in newest.items():
            msg = self._parse(key, payload)
            if msg is None:
                refused.add((rx, key))
                continue
            self.fuser.ingest_wire(msg)
            self.geometry = msg.geometry
            rigs.append(msg.rig)
        latest = self.fuser.latest_ns()
        if latest is not None:
            if batch:
                last_rx = max(rx for rx, _, _ in batch)
            if rigs:
                self._step(max(latest, self._t_ns), rigs, [rx for rx, _, _ in batch])
            elif last_rx is not None and time.monotonic() - last_rx >= IDLE_STEP_S:
                self._step(latest + int((time.monotonic() - last_rx) * 1e9), [], [])
        self._count([b for b in batch if (b[0], b[1]) not in refused])  # after the step
        return last_rx

    def _room_turn(self, since_s: float) -> bool:
        """Whether the room's message, due, goes out now, ``since_s`` after the last one: once
        ``min_period_s`` has passed and no rig message is waiting (a rig message's tracks go
        out first: the room's message waits for a step, never a step for it), or a second
        period has passed whatever is waiting."""
        if since_s < self.min_period_s:
            return False
        return not self.inbox or since_s >= 2 * self.min_period_s

    def _count(self, batch: list[tuple[float, str, bytes]]) -> None:
        with self.lock:
            for rx, key, _ in batch:
                rig = self._rig(key)
                if rig in self.received:
                    self.received[rig] += 1
                    self.heard_at[rig] = max(self.heard_at.get(rig, 0.0), rx)

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
        added = [r.name for r in room.rigs if not self.fuser.knows(r.name)]
        with self.lock:  # the status reads the room, the rigs' clocks and links together
            changed = self.fuser.set_room(room)
            self.clock.set_rigs([r.name for r in room.rigs], changed)
            self.room = room
            for r in room.rigs:
                self.received.setdefault(r.name, 0)
        if self.mcap is not None:
            self.mcap.set_room(room)
        log.info(
            "room file reloaded: %d rigs, %s%s",
            len(room.rigs),
            f"added: {', '.join(added)}; " if added else "",
            f"moved or gone: {', '.join(changed)}" if changed else "no rig moved",
        )

    def _step(self, t_ns: int, rigs: list[str], received: list[float]) -> None:
        """Fuse ``rigs``' new tracks at ``t_ns`` (UTC ns), publish the room tracks they
        touched on their own keys, then keep their JSON for the room's message, give the step
        to the clock watch (its corrections apply from the next message on, so the tracks
        need not wait for it) and mark the room's message due."""
        t0 = time.monotonic()
        frame = self.fuser.fuse(t_ns, rigs)
        fused = time.monotonic()
        touched = frame_payloads(frame)
        self.pub.tracks(touched, frame.ended)
        done = time.monotonic()
        self._states.update(touched)
        for rid in frame.ended:
            self._states.pop(rid, None)
        self.clock.observe(frame)
        self.fuser.clock_corrections_ns = dict(self.clock.corrections_ns)
        fuse_ms = (fused - t0 + time.monotonic() - done) * 1e3
        self._t_ns = max(self._t_ns, t_ns)
        self._room_due = self._room_due or bool(touched or frame.ended)
        with self.lock:
            self.steps += 1
            self.fuse_ms.append(fuse_ms)
            added = [(done - rx) * 1e3 for rx in received]
            self.added_ms.extend(added)
            self.added_hist.add(added)

    def _publish_room(self) -> None:
        """The room's message: every live track's latest state (each at its own stamp)."""
        payload = join_room(
            self.room.name, self.room_messages, self._t_ns, self.geometry,
            self.fuse_ms[-1] if self.fuse_ms else 0.0, list(self._states.values()),
        )  # fmt: skip
        self.pub.objects(payload, [], [])
        self._room_due, self._room_at = False, time.monotonic()
        self.room_messages += 1
        if self.jsonl is not None:
            self.jsonl.write(payload + b"\n")
        if self.mcap is not None:
            msg = ObjectsMessage.model_validate_json(payload)
            try:
                self.mcap.write_objects(msg, raw_json=payload.decode())
            except InputError as exc:  # a stamp ROS time cannot hold: left out, said
                with self.lock:
                    self.mcap_skipped += 1
                    self.mcap_problem = str(exc)

    def _behind(
        self,
        rigs: dict[str, RigLink],
        silent: dict[str, float],
        latest: int | None,
        timeout_s: float,
    ) -> list[str]:
        """Rigs whose messages come but whose stamps lie more than the rig timeout behind the
        newest rig's: their tracks are left out of the room, which only their clocks (or a
        replay's ``--utc-start``) can explain, so the status says so."""
        stamps = {n: link.last_stamp_utc_ns for n, link in rigs.items()}
        heard = {n: t for n, t in stamps.items() if t is not None and n not in silent}
        if latest is None or not heard:
            return []
        newest = max(heard, key=lambda n: heard[n])
        return [
            f"rig {n}: its stamps are {(latest - t) / 1e9:.1f} s behind rig {newest}'s, past the "
            f"rig timeout ({timeout_s:g} s), so its tracks are left out of the room: check "
            "both hosts' clocks (chrony, PTP), or the replays' --utc-start"
            for n, t in heard.items()
            if latest - t > timeout_s * 1e9
        ]

    def status(self, state: str = "running") -> FuseStatus:
        """The node's status now."""
        now = time.monotonic()
        latest = self.fuser.latest_ns()
        live = set(self.fuser.live_rigs(latest)) if latest is not None else set()
        timeout_s = self.fuser.params.rig_timeout_s
        rigs = {}
        with self.lock:
            silent = {r: now - t for r, t in self.heard_at.items() if now - t > timeout_s}
            live -= set(silent)
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
            added_counts = list(self.added_hist.counts)
            steps, tracks, dropped, rejected = self.steps, self.tracks, self.dropped, self.rejected
            last_rejected = self.last_rejected
            mcap_skipped, mcap_problem = self.mcap_skipped, self.mcap_problem
        problems = [
            f"rig {name}'s clock is {link.clock_offset_ms:+.1f} ms off the reference rig "
            f"{self.room.rigs[0].name}'s (bound {self.clock.bound_ms:g} ms): check its "
            "chrony or PTP"
            for name, link in rigs.items()
            if link.clock_off and link.clock_offset_ms is not None
        ]
        problems += [f"rig {n}: no message yet" for n, link in rigs.items() if not link.messages]
        problems += [
            f"rig {n}: no message for {s:.1f} s (over the rig timeout, {timeout_s:g} s): is "
            "its daemon running and connected?"
            for n, s in silent.items()
            if n in rigs
        ]
        problems += self._behind(rigs, silent, latest, timeout_s)
        if self.reload_problem is not None:
            problems.append(self.reload_problem)
        if dropped:
            problems.append(f"rig messages dropped, the fusion fell behind: {dropped}")
        if rejected:
            problems.append(
                f"samples on a rig's objects key that were not its objects: {rejected} (the "
                f"last: {last_rejected})"
            )
        if mcap_skipped:
            problems.append(
                f"room messages left out of the MCAP: {mcap_skipped} (the last: {mcap_problem})"
            )

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
            added_ms_edges=list(EDGES_MS),
            added_ms_counts=added_counts,
            clock_bound_ms=self.clock.bound_ms,
            problems=problems,
        )
