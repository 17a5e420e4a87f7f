"""``stereod fuse`` end to end over real Zenoh sessions on loopback: three rig message
generators (separate processes, real Publishers) and the fusion node as a subprocess, all
through one router; a subscriber checks the room's ids and positions against the truth."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from stereod.bus.messages import ObjectsMessage, dump_objects
from stereod.fusion.room import RigPose
from stereod.fusion.status import FuseStatus
from stereod_fakes.room_messages import RigSim, Walker, walkers_from_json
from tests.processes import start_stereod

from .conftest import free_endpoint, stereod, zenoh_config
from .fuse_procs import ROOM, fuse_procs, stop

pytestmark = pytest.mark.slow


_EMPTY = (
    '{"schema": "stereod.objects/1", "rig": "a", "seq": 1, "t_ns": 0, "stamp_utc_ns": 0, '
    '"skew_ns": 0, "left_seq": 1, "right_seq": 1, "geometry": "canonical", '
    '"calibration_id": null, "latency": {"detect_ms": 0, "geometry_ms": 0, "track_ms": 0, '
    '"pipeline_ms": 0, "queue_ms": 0}, "objects": []}'
)
"""A rig's objects message with no object, as JSON (its stamp 0, to be replaced)."""


def test_three_rigs_through_a_router_make_one_id_per_object(tmp_path: Path) -> None:
    """Object 1 stands in a and c's overlap; object 2 walks from a's view into b's. Rig c's
    generator is killed and started again (its ids start over) while they are watched. The
    room has exactly two ids, each always at its own object's true position."""
    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    walkers = json.dumps(
        [
            {
                "id": 1,
                "start_m": [0.6, 0.0, 3.0],
                "velocity_mps": [0.0, 0.0, 0.05],
            },
            {
                "id": 2,
                "start_m": [2.5, 0.0, 6.0],
                "velocity_mps": [1.0, 0.0, 0.0],
            },
        ]
    )
    messages: list[ObjectsMessage] = []
    jsonl = tmp_path / "room.jsonl"
    summary = tmp_path / "fuse.out"
    with fuse_procs() as run, summary.open("w") as summary_out:
        fuse = run.start_fuse(room, "--jsonl", str(jsonl), stdout=summary_out)
        with zenoh.open(zenoh_config(connect=[run.endpoint], mode="client")) as session:
            sub = session.declare_subscriber(
                "stereod/rooms/lab/objects",
                lambda s: messages.append(ObjectsMessage.model_validate_json(s.payload.to_bytes())),
            )
            gens = {
                rig: run.generator(room, rig, walkers, seed)
                for seed, rig in enumerate(("a", "b", "c"))
            }
            t0 = run.go(list(gens.values()))
            truth = [
                Walker(w.truth_id, w.start_m, w.velocity_mps, t0)
                for w in walkers_from_json(walkers)
            ]
            end = t0 + 2_600_000_000
            restarted = False
            deadline = time.monotonic() + 120  # a guard against a hang, not a measurement
            while time.monotonic() < deadline:
                last = messages[-1].stamp_utc_ns if messages else 0
                if last > end:
                    break
                if not restarted and last > t0 + 1_000_000_000:
                    stop(gens["c"])
                    gens["c"] = run.generator(room, "c", walkers, 9)
                    run.go([gens["c"]], t0)  # the same walkers, where they are now
                    end = max(end, time.time_ns() + 1_500_000_000)
                    restarted = True
                time.sleep(0.05)
            assert restarted and messages and messages[-1].stamp_utc_ns > end
            # Garbage on a rig's key (nested far too deep for a recursive parser) is counted
            # and refused; the node runs on. (A rig's next message supersedes it unread when
            # both wait for one step, so it is sent until one was read.)
            while time.monotonic() < deadline:
                session.put("stereod/a/objects", b"[" * 100_000 + b"]" * 100_000)
                replies = list(session.get("stereod/rooms/lab/stats", timeout=10))
                status = FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())
                if any(
                    "that were not its objects" in p and "rig a: " in p for p in status.problems
                ):
                    break
                time.sleep(0.1)
            # So is a message stamped at 64 bits' end (a replay given such a --utc-start made
            # them, and the step's clock arithmetic overflowed: the node died with exit 70).
            far = json.loads(_EMPTY.replace('"stamp_utc_ns": 0', f'"stamp_utc_ns": {2**63 - 1}'))
            while time.monotonic() < deadline:
                session.put("stereod/a/objects", json.dumps(far).encode())
                replies = list(session.get("stereod/rooms/lab/stats", timeout=10))
                status = FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())
                if any("a stamp outside 1970..2116" in p for p in status.problems):
                    break
                time.sleep(0.1)
            stamp_said = [p for p in status.problems if "a stamp outside 1970..2116" in p]
            # And one that is no objects message names its fields (pydantic's own first line,
            # "1 validation error for ObjectsMessage", names none).
            said: list[str] = []
            while not said and time.monotonic() < deadline:
                session.put("stereod/a/objects", b'{"schema": "stereod.objects/1", "rig": "a"}')
                replies = list(session.get("stereod/rooms/lab/stats", timeout=10))
                status = FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())
                said = [p for p in status.problems if "seq: required field is missing" in p]
                time.sleep(0.1)
            alive = list(session.liveliness().get("stereod/rooms/lab/alive", timeout=5))
            sub.undeclare()
        for g in gens.values():
            stop(g)
        fuse.send_signal(signal.SIGTERM)
        out = fuse.communicate(timeout=30)
    assert fuse.returncode == 0, out
    assert len(alive) == 1 and alive[0].ok is not None
    assert set(status.rigs) == {"a", "b", "c"} and all(r.messages for r in status.rigs.values())
    assert status.rigs["c"].restarts == 1 and status.steps > 0
    assert any(
        p.startswith("samples on a rig's objects key that were not") for p in status.problems
    )
    assert stamp_said, "the stamp's reason on the status"
    assert any("(the last: rig a: seq: required field is missing; " in p for p in said), said
    watched = [m for m in messages if m.stamp_utc_ns > t0 - 1_000_000_000]
    ids: dict[int, int] = {}
    for m in watched:
        assert len(m.objects) <= 2
        for o in m.objects:
            d = [float(np.linalg.norm(np.array(o.position_m) - w.position(o.stamp_utc_ns)))
                 for w in truth]  # fmt: skip
            nearest = int(np.argmin(d))
            assert ids.setdefault(o.track_id, nearest) == nearest, "an id switched objects"
            err = np.abs(np.array(o.position_m) - truth[nearest].position(o.stamp_utc_ns))
            assert np.all(err < 4 * np.array(o.position_sigma_m) + 0.02), (o, err)
    assert sorted(ids.values()) == [0, 1], ids  # one id per object, none twice
    assert all(len(m.objects) == 2 for m in watched[-10:])
    lines = jsonl.read_text().splitlines()
    assert len(lines) >= len(watched) and json.loads(lines[-1])["rig"] == "lab"
    assert summary.read_text().startswith(f"{len(lines)} room messages ("), "the summary's count"


def test_a_bad_room_file_is_one_line_and_exit_78(tmp_path: Path) -> None:
    room = tmp_path / "room.toml"
    room.write_text(ROOM.replace('name = "c"', 'name = "a"'))
    res = stereod("fuse", "--room", str(room))
    assert res.returncode == 78
    assert res.stderr.count("\n") == 1 and "rig 'a' is listed twice" in res.stderr
    assert str(room) in res.stderr
    missing = stereod("fuse", "--room", str(tmp_path / "none.toml"))
    assert missing.returncode == 66 and "no such room file" in missing.stderr


def test_a_node_that_heard_from_no_rig_says_how_to_connect_them(tmp_path: Path) -> None:
    """A node on its own (no rig's daemon connected to it) ends on SIGTERM with exit 0, its
    count of nothing, and one line naming the room's rigs and how to connect them; its
    outputs, with nothing to hold, leave a previous run's files as they were."""
    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    jsonl, mcap = tmp_path / "room.jsonl", tmp_path / "room.mcap"
    jsonl.write_text("earlier\n")
    mcap.write_text("earlier\n")
    fuse = start_stereod(
        "fuse", "--room", str(room), "--listen", free_endpoint(), "--jsonl", str(jsonl),
        "--mcap", str(mcap),
    )  # fmt: skip
    assert fuse.stderr is not None
    for line in fuse.stderr:  # until its subscriptions are up
        if "fusing 3 rigs" in line:
            break
    fuse.send_signal(signal.SIGTERM)
    out, err = fuse.communicate(timeout=30)
    assert fuse.returncode == 0, err
    assert out.startswith("0 room messages (0 fusion steps) from 0 rig messages")
    (said,) = [line for line in err.splitlines() if "no message came" in line]
    assert "(a, b, c)" in said and "--connect / --listen" in said
    assert f"no room message: {jsonl} and {mcap} not written" in out
    assert jsonl.read_text() == "earlier\n" and mcap.read_text() == "earlier\n"


def test_a_rig_whose_clock_reads_after_2038_leaves_the_mcap_but_not_the_node(
    tmp_path: Path,
) -> None:
    """ROS time holds seconds in 32 bits. A rig stamping its messages in 2100 (``replay
    --utc-start`` takes it) made ``fuse --mcap`` exit 65 at the first room message; now the
    node fuses on, leaves those room messages out of the MCAP, says so on its status, and
    its MCAP is whole at a clean stop."""
    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    t0 = 4_102_444_800_000_000_000  # 2100-01-01
    sim = RigSim(RigPose(name="a"), seed=1)
    walker = [Walker(1, (0.3, 0.0, 3.0), (0.2, 0.0, 0.0), t0)]
    endpoint = free_endpoint()
    mcap = tmp_path / "room.mcap"
    fuse = start_stereod("fuse", "--room", str(room), "--listen", endpoint, "--mcap", str(mcap))
    assert fuse.stderr is not None
    for line in fuse.stderr:
        if "fusing 3 rigs" in line:
            break
    said: list[str] = []
    with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as session:
        deadline = time.monotonic() + 60  # a guard against a hang, not a measurement
        k = 0
        while not said and time.monotonic() < deadline:
            payload, _ = dump_objects(sim.message(walker, t0 + k * 33_333_333))
            session.put("stereod/a/objects", payload)
            k += 1
            time.sleep(0.03)
            if k % 10 == 0:
                replies = list(session.get("stereod/rooms/lab/stats", timeout=10))
                status = FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())
                said = [p for p in status.problems if "left out of the MCAP" in p]
    fuse.send_signal(signal.SIGTERM)
    out, err = fuse.communicate(timeout=30)
    assert fuse.returncode == 0, err
    assert said and "outside ROS time" in said[0], status.problems
    assert status.steps > 0 and " room messages " in out
    with mcap.open("rb") as f:
        assert make_reader(f).get_summary() is not None


def test_the_run_s_last_line_names_a_rig_never_heard_from() -> None:
    """Rig a heard and rig b never: the last line said only "from 1 rig messages"; it now
    names b (with no rig heard, a line of its own names them all)."""
    from stereod.cli.fuse import summary
    from tests.test_fuse_node import _node

    node = _node(20.0)
    assert summary(node, 0).endswith("from 0 rig messages; 0 rig restarts seen")
    node.received["a"] = 3
    assert summary(node, 1) == (
        "0 room messages (0 fusion steps) from 3 rig messages; 1 rig restarts seen; never "
        "heard from rig b"
    )
    node.received["b"] = 1
    assert summary(node, 1).endswith("1 rig restarts seen")
