"""Three rendered rigs, one room: each rig's views rendered by the independent renderer from
its pose (``stereod_fakes.world.rooms``), each replayed by its own daemon process (``stereod
replay``, one UTC start for all), all through a router on loopback into ``stereod fuse``.

Truth: the balls' motion in the room frame. A ball walks from rig a's view through a and b's
overlap into b's alone (a handover); another rolls in c's view only (disjoint from the others).
A second room, two rigs at right angles with two balls through their overlap, is replayed with
one rig's clock 40 ms ahead (its ``--utc-start``): the shift is the truth of its offset.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from stereod.bus.messages import ObjectsMessage
from stereod.fusion.clock import ClockWatch
from stereod.fusion.fuser import FusedFrame, Fuser
from stereod.fusion.output import room_states
from stereod.fusion.room import load_room
from stereod.fusion.status import FuseStatus
from stereod_fakes.world import Scene
from stereod_fakes.world.rooms import RigPlacement, crossing_room, three_rig_room, write_room
from tests.processes import ROOT, run_stereod, start_stereod

from .conftest import free_endpoint, zenoh_config
from .fuse_procs import fuse_procs

pytestmark = pytest.mark.slow

NEAR_M = 0.35
"""A room track within this of a ball's true centre is that ball's (the balls are metres apart)."""


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> tuple[Scene, list[RigPlacement], Path]:
    """The room scene, its rigs and a folder with each rig's rendered views (``<rig>/``)."""
    scene, rigs = three_rig_room()
    return scene, rigs, write_room(scene, rigs, tmp_path_factory.mktemp("rooms"), "lab")


def replay(folder: Path, rig: str, endpoint: str, utc_start: int, jsonl: Path) -> subprocess.Popen:
    """The rig's daemon replaying its views; it waits for a subscriber before it plays, so
    that the fusion node's subscriptions start all rigs at once."""
    return start_stereod(
        "replay", "--left-video", str(folder / "left.mkv"), "--right-video",
        str(folder / "right.mkv"), "--left-ts", str(folder / "left.csv"), "--right-ts",
        str(folder / "right.csv"), "--rig", rig, "--utc-start", str(utc_start), "--connect",
        endpoint, "--mode", "client", "--rate", "1", "-q", "--wait-subscriber", "120",
        "--jsonl", str(jsonl),
    )  # fmt: skip


def fused_in_stamp_order(
    messages: list[ObjectsMessage], room_toml: Path, clock: ClockWatch | None = None
) -> Iterator[tuple[ObjectsMessage, FusedFrame | None]]:
    """Each rig message in stamp order, with the room fused at its instant once every rig's
    message of that instant is in (else ``None``): what a node whose rigs all keep up fuses.
    The live node fuses whichever rigs' messages have arrived when it steps, which a loaded
    host changes from run to run. With ``clock``, the rigs' clocks are watched and an offset
    it trusts is corrected, as the node does."""
    fuser = Fuser(load_room(room_toml))
    ordered = sorted(messages, key=lambda m: m.stamp_utc_ns)
    for k, m in enumerate(ordered):
        fuser.ingest(m)
        if k + 1 < len(ordered) and ordered[k + 1].stamp_utc_ns == m.stamp_utc_ns:
            yield m, None
            continue
        frame = fuser.fuse(m.stamp_utc_ns)
        if clock is not None:
            clock.observe(frame)
            fuser.clock_corrections_ns = dict(clock.corrections_ns)
        yield m, frame


@pytest.mark.xdist_group("fuse_world_three")  # one worker renders the room once
def test_one_id_per_ball_across_three_rendered_rigs(
    rendered: tuple[Scene, list[RigPlacement], Path],
) -> None:
    """Every room track near a ball stays that ball's (no id switch), each ball has one id once
    confirmed; the walker's id is the same where only rig a sees it and where only rig b
    does (the handover), and rigs a and b each tracked it (their tracks, moved into the room
    by the placements, within 0.35 m of it). Where both see it, the room's median position
    error is no larger than the better rig's alone."""
    scene, rigs, folder = rendered
    messages: list[ObjectsMessage] = []
    with fuse_procs() as run:
        endpoint = run.endpoint
        with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as session:
            session.declare_subscriber(
                "stereod/rooms/lab/objects",
                lambda s: messages.append(ObjectsMessage.model_validate_json(s.payload.to_bytes())),
            )
            utc_start = time.time_ns()
            players = [
                replay(folder / r.name, r.name, endpoint, utc_start, folder / f"{r.name}.jsonl")
                for r in rigs
            ]
            for p in players:
                run.add(p)
            # All rigs' daemons up (their alive tokens on the bus) and waiting for a subscriber:
            # the fusion node's subscriptions then start them together.
            deadline = time.monotonic() + 120  # a guard against a hang, not a measurement
            alive: set[str] = set()
            while len(alive) < len(rigs) and time.monotonic() < deadline:
                tokens = session.liveliness().get("stereod/*/alive", timeout=5)
                alive = {str(r.ok.key_expr).split("/")[1] for r in tokens if r.ok}
                time.sleep(0.1)
            assert alive == {r.name for r in rigs}, alive
            run.start_fuse(folder / "room.toml")
            for p in players:
                _, err = p.communicate(timeout=300)
                assert p.returncode == 0, err
            time.sleep(1.0)
    seen_by = [
        ObjectsMessage.model_validate_json(line)
        for r in rigs
        for line in (folder / f"{r.name}.jsonl").read_text().splitlines()
    ]
    first = scene.frame_times("left")[0]
    balls = {o.name: o.trajectory for o in scene.objects}

    def scene_s(stamp_utc_ns: int) -> float:
        return scene.time_s(first + (stamp_utc_ns - utc_start))

    poses = {r.name: r for r in rigs}
    rig_saw: dict[str, set[str]] = {r.name: set() for r in rigs}
    # Each rig's error on the walker (m) at each of its stamps, its track moved into the room.
    walker_err: dict[str, dict[int, float]] = {"a": {}, "b": {}, "fused": {}}
    for m in seen_by:
        if m.rig not in poses:
            continue
        t_s, pose = scene_s(m.stamp_utc_ns), poses[m.rig]
        for o in m.objects:
            p = pose.rotation() @ np.array(o.position_m) + np.array(pose.translation_m)
            for n, tr in balls.items():
                err = float(np.linalg.norm(p - tr.position(t_s)))
                if o.state.value == "confirmed" and err < NEAR_M:
                    rig_saw[m.rig].add(n)
                    if n == "walker":
                        walker_err[m.rig][m.stamp_utc_ns] = err
    assert rig_saw == {"a": {"walker"}, "b": {"walker"}, "c": {"lone"}}, rig_saw

    ids: dict[int, str] = {}
    confirmed: dict[str, set[int]] = {name: set() for name in balls}
    walker_x: dict[int, list[float]] = {}
    for m in messages:
        for o in m.objects:
            t_s = scene_s(o.stamp_utc_ns)  # each room track at its own last fused instant
            d = {n: float(np.linalg.norm(np.array(o.position_m) - tr.position(t_s)))
                 for n, tr in balls.items() if tr.present(t_s)}  # fmt: skip
            near = min(d, key=d.__getitem__) if d else None
            if near is None or d[near] > NEAR_M:
                continue
            assert ids.setdefault(o.track_id, near) == near, f"id {o.track_id} switched balls"
            if o.state.value in ("confirmed", "stationary"):
                confirmed[near].add(o.track_id)
                if near == "walker":
                    walker_x.setdefault(o.track_id, []).append(float(balls[near].position(t_s)[0]))
                    walker_err["fused"][o.stamp_utc_ns] = d[near]
    assert all(len(v) == 1 for v in confirmed.values()), confirmed
    (xs,) = walker_x.values()
    # a alone sees x < 0.9 m, b alone x > 1.75 m (3 m ahead; see THREE_RIGS).
    assert min(xs) < 0.5 and max(xs) > 2.2, (min(xs), max(xs))
    # Where a and b both see the walker, the room's position is no further from the truth than
    # the better rig's alone (the same rig messages fused in stamp order).
    fused_err: dict[int, float] = {}
    for m, frame in fused_in_stamp_order(seen_by, folder / "room.toml"):
        if frame is None:
            continue
        walker = balls["walker"].position(scene_s(m.stamp_utc_ns))
        errs = [
            float(np.linalg.norm(np.array(o.position_m) - walker))
            for o in room_states(frame.tracks)
            if o.state.value in ("confirmed", "stationary")
        ]
        if errs and min(errs) < NEAR_M:
            fused_err[m.stamp_utc_ns] = min(errs)
    walker_err["fused"] = fused_err
    both = sorted(set(walker_err["a"]) & set(walker_err["b"]) & set(fused_err))
    assert len(both) >= 5, both
    median = {k: float(np.median([v[t] for t in both])) for k, v in walker_err.items()}
    assert median["fused"] <= min(median["a"], median["b"]), median


SHIFT_NS = 40_000_000
"""Rig b's clock, ahead of rig a's in the shifted replay, ns."""


@pytest.fixture(scope="module")
def crossing(tmp_path_factory: pytest.TempPathFactory) -> tuple[Scene, list[RigPlacement], Path]:
    """Two rigs at right angles and two balls through their overlap, rendered."""
    scene, rigs = crossing_room()
    return scene, rigs, write_room(scene, rigs, tmp_path_factory.mktemp("crossing"), "lab")


@pytest.mark.xdist_group("fuse_world_crossing")  # one worker renders the crossing once
def test_a_replay_whose_clock_is_40_ms_ahead_is_found_and_corrected(
    crossing: tuple[Scene, list[RigPlacement], Path],
) -> None:
    """Rig b's views replayed with its first frame stamped 40 ms later than rig a's first
    (``--utc-start``), though both were captured at once: the fusion node finds b 40 ms
    ahead (within 8 ms), flags it and corrects b's stamps by it; over the last second the
    room's balls are within 2 cm of the truth at each room track's own instant."""
    scene, rigs, folder = crossing
    messages: list[ObjectsMessage] = []
    with fuse_procs() as run:
        endpoint = run.endpoint
        with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as session:
            session.declare_subscriber(
                "stereod/rooms/lab/objects",
                lambda s: messages.append(ObjectsMessage.model_validate_json(s.payload.to_bytes())),
            )
            utc_start = time.time_ns()
            shift = {"a": 0, "b": SHIFT_NS}
            players = [
                replay(folder / r.name, r.name, endpoint, utc_start + shift[r.name],
                       folder / f"{r.name}.jsonl")
                for r in rigs
            ]  # fmt: skip
            for p in players:
                run.add(p)
            deadline = time.monotonic() + 120  # a guard against a hang, not a measurement
            alive: set[str] = set()
            while len(alive) < len(rigs) and time.monotonic() < deadline:
                tokens = session.liveliness().get("stereod/*/alive", timeout=5)
                alive = {str(r.ok.key_expr).split("/")[1] for r in tokens if r.ok}
                time.sleep(0.1)
            assert alive == {r.name for r in rigs}, alive
            run.start_fuse(folder / "room.toml")
            for p in players:
                _, err = p.communicate(timeout=300)
                assert p.returncode == 0, err
            replies = list(session.get("stereod/rooms/lab/stats", timeout=10))
            status = FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())
    # The node ran, heard both rigs and judged b's clock. Its estimate rests on which rigs'
    # messages it fused together, which a loaded host changes from run to run; the estimate
    # itself is judged on the same rig messages fused in stamp order, each instant once every
    # rig's message of it is in, as a node whose rigs keep up does.
    assert status.rigs["b"].live and status.rigs["b"].clock_samples > 0, status.rigs["b"]
    rig_messages = [
        ObjectsMessage.model_validate_json(line)
        for r in rigs
        for line in (folder / f"{r.name}.jsonl").read_text().splitlines()
    ]
    clock = ClockWatch([r.name for r in rigs])
    for _ in fused_in_stamp_order(rig_messages, folder / "room.toml", clock):
        pass
    b = clock.estimate("b")
    assert b.offset_ms == pytest.approx(SHIFT_NS / 1e6, abs=8.0), b
    assert b.correction_ms == pytest.approx(SHIFT_NS / 1e6, abs=8.0) and b.off, b
    first = scene.frame_times("left")[0]
    # The last second the node had the balls confirmed (on a loaded host its last messages
    # can come after the rigs' last, with every room track coasting).
    seen = [
        m.stamp_utc_ns for m in messages if any(o.state.value == "confirmed" for o in m.objects)
    ]
    assert seen, f"no confirmed room track in {len(messages)} messages"
    end = max(seen)
    errors = []
    for m in messages:
        if m.stamp_utc_ns < end - 1_000_000_000:
            continue
        for o in m.objects:
            truth = scene.truth(first + (o.stamp_utc_ns - utc_start))
            if o.state.value == "confirmed":
                d = [float(np.linalg.norm(np.array(o.position_m) - p)) for p, _ in truth.values()]
                errors.append(min(d))
    assert len(errors) > 20, f"{len(errors)} confirmed states in the last second"
    assert float(np.median(errors)) < 0.02, np.median(errors)


@pytest.mark.xdist_group("fuse_world_crossing")
def test_where_both_rigs_see_a_ball_the_room_is_no_further_from_it_than_the_better_rig(
    crossing: tuple[Scene, list[RigPlacement], Path], tmp_path: Path
) -> None:
    """The two balls roll side by side through the crossing rigs' overlap. Each rig's views
    are replayed (``stereod replay``, one UTC start), and their messages fused in stamp order,
    each instant once both rigs' messages of it are in, the rigs' clocks watched as the node
    watches them. Over the instants both rigs and the
    room have a ball, the room's median position error is no larger than the better rig's.

    Rig a sees the balls 0.625 m apart in depth, a disparity step of 1.3 px: were they grouped
    as one object there, its track would lie between them and pull the room's position."""
    scene, rigs, folder = crossing
    utc_start = 1_700_000_000_000_000_000
    messages: list[ObjectsMessage] = []
    for r in rigs:
        jsonl = tmp_path / f"{r.name}.jsonl"
        done = run_stereod(
            "replay", "--left-video", str(folder / r.name / "left.mkv"), "--right-video",
            str(folder / r.name / "right.mkv"), "--left-ts", str(folder / r.name / "left.csv"),
            "--right-ts", str(folder / r.name / "right.csv"), "--rig", r.name, "--utc-start",
            str(utc_start), "--rate", "0", "-q", "--jsonl", str(jsonl), "--listen",
            "tcp/127.0.0.1:0", timeout=300,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        messages += [ObjectsMessage.model_validate_json(s) for s in jsonl.read_text().splitlines()]
    first = scene.frame_times("left")[0]
    poses = {r.name: r for r in rigs}
    clock = ClockWatch([r.name for r in rigs])
    errors: dict[tuple[str, int], dict[str, float]] = {}

    def nearest(who: str, t_ns: int, states: list, rot: np.ndarray, t: np.ndarray) -> None:
        truth = scene.truth(first + (t_ns - utc_start))
        for name, (p, _) in truth.items():
            d = [
                float(np.linalg.norm(rot @ np.array(o.position_m) + t - p))
                for o in states
                if o.state.value in ("confirmed", "stationary")
            ]
            if d and min(d) < NEAR_M:
                errors.setdefault((name, t_ns), {})[who] = min(d)

    for m, frame in fused_in_stamp_order(messages, folder / "room.toml", clock):
        pose = poses[m.rig]
        nearest(m.rig, m.stamp_utc_ns, m.objects, pose.rotation(), np.array(pose.translation_m))
        if frame is not None:
            nearest("room", frame.t_ns, room_states(frame.tracks), np.eye(3), np.zeros(3))
    for ball in ("near", "far"):
        shared = [e for (name, _), e in errors.items() if name == ball and len(e) == 3]
        assert len(shared) >= 30, (ball, len(shared))
        median = {who: float(np.median([e[who] for e in shared])) for who in ("a", "b", "room")}
        assert median["room"] <= min(median["a"], median["b"]), (ball, median)
        # Rig a's own track of the ball is the ball's, not a point between the two.
        assert median["a"] < 0.01, (ball, median)


def _recipe() -> str:
    """The shell commands of docs/fusion.md's "Testing without cameras"."""
    text = (ROOT / "docs" / "fusion.md").read_text()
    section = text.split("## Testing without cameras", 1)[1].split("\n## ", 1)[0]
    (block,) = re.findall(r"```sh\n(.*?)```", section, re.S)
    return block


RENDER_LINE = (
    'python -c "from stereod_fakes.world.rooms import three_rig_room, write_room; '
    "write_room(*three_rig_room(), 'room')\""
)
"""The recipe's first line: what :func:`rendered` does (the same call, name and defaults)."""


@pytest.mark.xdist_group("fuse_world_three")  # one worker renders the room once
def test_the_documented_recipe_fuses_the_rendered_room(
    rendered: tuple[Scene, list[RigPlacement], Path], tmp_path: Path
) -> None:
    """docs/fusion.md's commands as written, run by bash on the room their first line renders
    (rendered here by the same call), on a free port instead of 7447: the node hears every
    rig, ends cleanly on SIGTERM, and its room messages hold the two balls, one id each."""
    render, *rest = _recipe().splitlines()
    assert render == RENDER_LINE
    _, rigs, folder = rendered
    (tmp_path / "room").symlink_to(folder)
    script = "\n".join(rest).replace("tcp/127.0.0.1:7447", free_endpoint())
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    res = subprocess.run(
        ["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    said = r"(\d+) room messages \(\d+ fusion steps\) from (\d+) rig messages"
    summary = re.search(said, res.stdout)
    assert summary is not None, (res.stdout, res.stderr)
    lines = (tmp_path / "room.jsonl").read_text().splitlines()
    assert int(summary[1]) == len(lines) > 0 and int(summary[2]) >= len(rigs)
    assert "no message came" not in res.stderr
    ids = {o["track_id"] for line in lines for o in json.loads(line)["objects"]}
    assert len(ids) == 2, ids
