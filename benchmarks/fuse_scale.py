"""``stereod fuse`` at scale, simulated: 16 rigs x 30 Hz x about 10 objects each, from message
generators (no rendering), through one Zenoh router into one fusion node.

The rigs stand 3 m apart in a line along the room's X, all looking along +Z (neighbours'
views overlap, so about a third of the objects are seen by two rigs); 160 walkers stroll
between 3 and 6 m in front of them. Two generator processes publish eight rigs each (a real
:class:`~stereod.bus.publish.Publisher` per rig, as a daemon would), rig k's message k/16 of a
frame period after the frame's start (rigs on hosts of their own are not in phase; ``--burst``:
all at the start), all as clients of one router process; ``stereod fuse`` and a subscriber to
the room are clients of it too, every socket on loopback.

Measured over ``--seconds`` after a warm-up: every process's CPU (share of one core, from
/proc/<pid>/stat: the fusion node, the router, each generator, and this process, whose Zenoh
session is the room's subscriber); the generators' main-thread CPU a message, writing it and
publishing it; the fusion node's own added latency (a rig message's arrival in the node to the
room tracks it changed published on their own keys: p50, p99, p99.9 and the share within 10 ms,
over every rig message of the measured seconds, from the histograms its ``stats`` queryable
gives at their start and end);
the latency from a rig's stamp to a room track's arrival at a subscriber on ``objects/*`` and
to the room's whole message (at most ``--max-rate`` a second) at one on ``objects`` (same
host, same UTC clock); its step rate and what it dropped. Writes ``docs/bench/fuse_scale.md``.

The node and the router run at the nice value the node's systemd unit sets (``--node-nice``;
below 0 needs root, else they run at 0), the generators and the subscriber, which stand in
for other hosts, at ``--others-nice``. Nice -10 weighs a process 9.3 times one at 0 in the
kernel's fair scheduler, as the unit's ``CPUWeight=1000`` weighs its service 10 times one at
the default 100: the benchmark runs everything in one control group, where the nice value
does what the weight does between services.

Usage: ``python benchmarks/fuse_scale.py [--rigs 16] [--objects 10] [--fps 30] [--seconds 20]
[--max-rate 30] [--node-nice N] [--others-nice N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
import report
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from stereod.fusion.clock import ClockWatch  # noqa: E402
from stereod.fusion.fuser import Fuser  # noqa: E402
from stereod.fusion.histogram import difference, quantile_ms, share_within  # noqa: E402
from stereod.fusion.output import frame_payloads, join_room  # noqa: E402
from stereod.fusion.room import load_room  # noqa: E402
from stereod.fusion.status import FuseStatus  # noqa: E402
from stereod.fusion.wire import decode  # noqa: E402
from stereod_fakes.room_messages import Crowd, RigSim, Walker, walkers_from_json  # noqa: E402
from tests import processes  # noqa: E402
from tests.conftest import free_endpoint, zenoh_config  # noqa: E402
from tests.processes import start_stereod  # noqa: E402
from tests.test_router import start_router  # noqa: E402

SPACING_M = 3.0
UNIT = ROOT / "systemd" / "stereod-fuse@.service"


def unit_nice() -> int:
    """The ``Nice=`` the fusion node's systemd unit runs it at (0 if it sets none)."""
    for line in UNIT.read_text().splitlines():
        if line.startswith("Nice="):
            return int(line.split("=", 1)[1])
    return 0


def may_nice(nice: int) -> bool:
    """Whether this user may start a process at ``nice`` (below 0 needs CAP_SYS_NICE)."""
    probe = f"import os; os.setpriority(os.PRIO_PROCESS, 0, {nice})"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0


def at_nice(nice: int, interruptible: bool = False) -> Callable[[], None]:
    """A ``preexec_fn`` that runs the child at ``nice`` (set before it starts any thread, so
    all of its threads have it)."""

    def pre() -> None:
        if interruptible:
            processes.interruptible()
        os.setpriority(os.PRIO_PROCESS, 0, nice)

    return pre


class _Stamped(msgspec.Struct):
    """The one field of a room track's message the subscriber reads (the others skipped
    unparsed: the subscriber is the benchmark's, and should cost the host little)."""

    stamp_utc_ns: int


class _RoomHead(msgspec.Struct):
    """The fields of the room's message the subscriber reads."""

    stamp_utc_ns: int
    objects: list[msgspec.Raw]


def room_file(rigs: int) -> str:
    lines = ["[room]", 'name = "hall"']
    for i in range(rigs):
        lines += ["[[room.rigs]]", f'name = "r{i}"', f"translation_m = [{i * SPACING_M}, 0.0, 0.0]"]
    return "\n".join(lines) + "\n"


def walkers(rigs: int, per_rig: int, seed: int = 1) -> list[dict[str, object]]:
    rng = np.random.default_rng(seed)
    n = rigs * per_rig
    xs = np.linspace(-1.0, (rigs - 1) * SPACING_M + 1.0, n)
    return [
        {
            "id": i,
            "start_m": [float(xs[i]), float(rng.uniform(-0.3, 0.3)), float(rng.uniform(3.0, 6.0))],
            "velocity_mps": [float(rng.uniform(-0.05, 0.05)), 0.0, float(rng.uniform(-0.05, 0.05))],
        }
        for i in range(n)
    ]


def cpu_s(pid: int) -> float:
    """User + system CPU time of a process so far, s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def message_cost(rigs: int, per_rig: int, ticks: int = 90) -> tuple[float, float]:
    """The fusion node's own work for one rig message, in this process with no bus: parse,
    ingest, fuse that rig at its stamp, clock, its tracks' JSON and the room's message
    joined; thread CPU time a message, p50 and p99 over the last two thirds, ms (the
    messages of ``ticks`` frames of every rig, as the generators make them)."""
    tmp = Path(tempfile.mkdtemp(prefix="fuse-cost-")) / "room.toml"
    tmp.write_text(room_file(rigs))
    room = load_room(tmp)
    t0 = 1_700_000_000_000_000_000
    walk = [
        Walker(w.truth_id, w.start_m, w.velocity_mps, t0)
        for w in walkers_from_json(json.dumps(walkers(rigs, per_rig)))
    ]
    sims, crowd = [RigSim(r, seed=k) for k, r in enumerate(room.rigs)], Crowd(walk)
    payloads = [
        sim.payload(crowd, t0 + k * 33_333_333 + j * 100_000)[0]
        for k in range(ticks)
        for j, sim in enumerate(sims)
    ]
    fuser, clock = Fuser(room), ClockWatch([r.name for r in room.rigs])
    states: dict[int, bytes] = {}
    cpu = []
    for k, payload in enumerate(payloads):
        c0 = time.thread_time()
        msg = decode(payload)
        fuser.ingest_wire(msg)
        frame = fuser.fuse(msg.stamp_utc_ns, [msg.rig])
        clock.observe(frame)
        fuser.clock_corrections_ns = dict(clock.corrections_ns)
        states.update(frame_payloads(frame))
        for rid in frame.ended:
            states.pop(rid, None)
        join_room(room.name, k, msg.stamp_utc_ns, msg.geometry, 0.0, list(states.values()))
        cpu.append((time.thread_time() - c0) * 1e3)
    tail = np.array(cpu[len(cpu) // 3 :])
    return float(np.percentile(tail, 50)), float(np.percentile(tail, 99))


def fuse_status(session: zenoh.Session) -> FuseStatus:
    """The fusion node's status, from its ``stats`` queryable."""
    replies = list(session.get("stereod/rooms/hall/stats", timeout=10))
    return FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rigs", type=int, default=16)
    p.add_argument("--objects", type=int, default=10, help="objects per rig")
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--warmup", type=float, default=5.0)
    p.add_argument("--generators", type=int, default=2)
    p.add_argument(
        "--burst",
        action="store_true",
        help="every rig's message at the frame's start (default: the rigs' spread evenly over "
        "the frame period, as rigs on hosts of their own are not in phase)",
    )
    p.add_argument("--max-rate", type=float, default=30.0, help="fuse's --max-rate, Hz")
    p.add_argument(
        "--node-nice",
        type=int,
        default=None,
        help="the nice value of the fusion node and the router (default: the node's systemd "
        f"unit's Nice=, {unit_nice()}, if this user may set it, else 0)",
    )
    p.add_argument(
        "--others-nice",
        type=int,
        default=0,
        help="the nice value of the generators and the room's subscriber, which stand in for "
        "other hosts (default %(default)s)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=report.DOCS_BENCH,
        help="folder of the markdown table (default docs/bench), or a .md file",
    )
    a = p.parse_args()
    a.out = report.table_path(p, a.out, "fuse_scale.md")
    if a.node_nice is None:
        a.node_nice = unit_nice() if may_nice(unit_nice()) else 0
        if a.node_nice != unit_nice():
            print(f"not allowed to set nice {unit_nice()} (needs root): the node runs at 0")
    for flag, nice in (("--node-nice", a.node_nice), ("--others-nice", a.others_nice)):
        if not may_nice(nice):
            p.error(f"{flag} {nice} needs root (CAP_SYS_NICE); run as root or pass 0 or more")
    load = os.getloadavg()
    floor = report.floor_figures()  # before anything starts
    tmp = Path(tempfile.mkdtemp(prefix="fuse-scale-"))
    room = tmp / "room.toml"
    room.write_text(room_file(a.rigs))
    endpoint = free_endpoint()
    router = start_router(endpoint, preexec_fn=at_nice(a.node_nice))
    procs: list[subprocess.Popen] = []
    arrivals: list[tuple[int, int, int]] = []
    track_arrivals: list[tuple[int, int]] = []
    lock = threading.Lock()

    room_head = msgspec.json.Decoder(_RoomHead).decode
    stamped = msgspec.json.Decoder(_Stamped).decode

    def on_room(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        msg = room_head(sample.payload.to_bytes())
        with lock:
            arrivals.append((now, msg.stamp_utc_ns, len(msg.objects)))

    def on_track(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        if sample.kind != zenoh.SampleKind.PUT:
            return
        stamp = stamped(sample.payload.to_bytes()).stamp_utc_ns
        with lock:
            track_arrivals.append((now, stamp))

    try:
        fuse = start_stereod(
            "fuse", "--room", str(room), "--connect", endpoint, "--mode", "client",
            "--log-level", "WARNING", "--max-rate", str(a.max_rate), stdout=subprocess.DEVNULL,
            preexec_fn=at_nice(a.node_nice, interruptible=True),
        )  # fmt: skip
        procs.append(fuse)
        names = [f"r{i}" for i in range(a.rigs)]
        groups = [names[i :: a.generators] for i in range(a.generators)]
        wjson = json.dumps(walkers(a.rigs, a.objects))
        for i, g in enumerate(groups):
            stagger = [] if a.burst else ["--stagger", str(i / a.generators)]
            proc = subprocess.Popen(
                [sys.executable, "-m", "stereod_fakes.room_messages", str(room), *g,
                 "--connect", endpoint, "--mode", "client", "--walkers", wjson,
                 "--fps", str(a.fps), "--t0-from-stdin", "--report", *stagger],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT,
                preexec_fn=at_nice(a.others_nice),
            )  # fmt: skip
            procs.append(proc)
        for proc in procs[1:]:
            assert proc.stdout is not None and proc.stdout.readline().strip() == "up"
        t0 = time.time_ns()
        for proc in procs[1:]:
            assert proc.stdin is not None
            proc.stdin.write(f"{t0}\n")
            proc.stdin.flush()
        os.setpriority(os.PRIO_PROCESS, 0, a.others_nice)  # the session's threads inherit it
        with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as session:
            sub = session.declare_subscriber("stereod/rooms/hall/objects", on_room)
            tsub = session.declare_subscriber("stereod/rooms/hall/objects/*", on_track)
            time.sleep(a.warmup)
            with lock:
                arrivals.clear()
                track_arrivals.clear()
            s0 = fuse_status(session)
            pids = [p.pid for p in procs] + [router.pid, os.getpid()]
            c0, w0 = [cpu_s(pid) for pid in pids], time.monotonic()
            time.sleep(a.seconds)
            c1, w1 = [cpu_s(pid) for pid in pids], time.monotonic()
            status = fuse_status(session)
            sub.undeclare()
            tsub.undeclare()
    finally:
        outputs: list[str] = []
        try:
            for proc in reversed(procs):
                if proc.poll() is None:
                    proc.send_signal(signal.SIGTERM)
            outputs = [proc.communicate(timeout=60)[0] for proc in procs[1:]]
            if procs:
                procs[0].communicate(timeout=60)
        finally:  # whatever failed, nothing the benchmark started is left running
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate()
            router.terminate()
            router.communicate(timeout=30)
    reports = [json.loads(out or "null") for out in outputs]
    with lock:
        got = list(arrivals)
        got_tracks = list(track_arrivals)
    e2e = np.array([(now - stamp) / 1e6 for now, stamp, _ in got])
    e2e_track = np.array([(now - stamp) / 1e6 for now, stamp in got_tracks])

    def p50_99(x: np.ndarray) -> str:
        return f"{np.percentile(x, 50):.1f} / {np.percentile(x, 99):.1f} ms" if len(x) else "-"

    objects = np.array([n for _, _, n in got])
    added = difference(status.added_ms_counts, s0.added_ms_counts)  # the measured seconds'

    def added_p(q: float) -> float:
        return quantile_ms(added, q, status.added_ms_edges)

    share = [(b - c) / (w1 - w0) * 100 for b, c in zip(c1, c0, strict=True)]
    cpu, gens, router_cpu, sub_cpu = share[0], share[1:-2], share[-2], share[-1]
    rig_msgs = sum(link.messages for link in status.rigs.values()) - sum(
        link.messages for link in s0.rigs.values()
    )
    sent = [r for r in reports if r]
    gen_msgs = sum(r["messages"] for r in sent)
    build_ms = sum(r["build_s"] for r in sent) / max(gen_msgs, 1) * 1e3
    publish_ms = sum(r["publish_s"] for r in sent) / max(gen_msgs, 1) * 1e3
    phase = "all at each frame's start (--burst)" if a.burst else "spread evenly over a frame"
    lines = [
        "# stereod fuse at scale (benchmarks/fuse_scale.py)",
        "",
        f"{a.rigs} rigs x {a.fps:g} Hz, {a.rigs * a.objects} walkers (about {a.objects} per rig), "
        f"{a.generators} generator processes, one router, all on loopback; the rigs' messages "
        f"{phase}; {a.seconds:g} s measured after {a.warmup:g} s warm-up; host: "
        f"{os.cpu_count()} cores, load average {load[0]:.1f} at the start and "
        f"{os.getloadavg()[0]:.1f} at the end "
        + (
            "(other work shares the cores: CPU shares and latencies are those of a busy host)."
            if load[0] >= 1.0
            else "(no other work on the host at the start)."
        )
        + f" Host floor: {floor}. Nice values: the fusion node and the router "
        f"{a.node_nice}, the generators and the room's subscriber {a.others_nice}.",
        "",
        "| figure | value |",
        "|---|---|",
        f"| fuse CPU | {cpu:.0f} % of one core |",
        f"| router CPU | {router_cpu:.0f} % |",
        f"| generators' CPU, together (each) | {sum(gens):.0f} % "
        f"({', '.join(f'{g:.0f} %' for g in gens)}) |",
        f"| room subscriber's CPU (the benchmark's process) | {sub_cpu:.0f} % |",
        "| a generator's main thread a rig message: writing it / publishing it (the Publisher: "
        f"the message, and each object on its own key) | {build_ms:.2f} / {publish_ms:.2f} ms |",
        f"| rig messages sent per s (target {a.rigs * a.fps:g}) | "
        f"{sum(r['messages'] / r['seconds'] for r in sent):.0f} |",
        f"| rig messages received by fuse per s | {rig_msgs / (w1 - w0):.0f} |",
        f"| fusion steps per s | {(status.steps - s0.steps) / (w1 - w0):.1f} |",
        f"| room messages per s (--max-rate {a.max_rate:g}) | {len(got) / a.seconds:.1f} |",
        f"| room objects per message, median | {np.median(objects) if len(objects) else 0:.0f} |",
        f"| fusion step (one or more rig messages), p50 / p99 | {status.fuse_ms_p50 or 0:.1f} / "
        f"{status.fuse_ms_p99 or 0:.1f} ms |",
        f"| added latency in fuse (arrival to its tracks published), p50 / p99 / p99.9; share "
        f"within 10 ms | {added_p(0.5):.1f} / {added_p(0.99):.1f} / {added_p(0.999):.1f} ms; "
        f"{share_within(added, 10.0, status.added_ms_edges) * 100:.1f} % |",
        f"| rig stamp to a room track (objects/<id>) at a subscriber, p50 / p99 | "
        f"{p50_99(e2e_track)} |",
        f"| rig stamp to the room message at a subscriber, p50 / p99 | {p50_99(e2e)} |",
        f"| problems | {'; '.join(status.problems) or 'none'} |",
    ]
    cost = message_cost(a.rigs, a.objects)
    lines.insert(
        -1,
        f"| one rig message's work in fuse, no bus (thread CPU), p50 / p99 | "
        f"{cost[0]:.2f} / {cost[1]:.2f} ms |",
    )
    text = "\n".join(lines) + "\n"
    print(text)
    a.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
