"""The V4L2 driver against the kernel's vivid driver (in the VM): real nodes, real kernel
timestamps and sequence numbers, a real unplug and re-plug."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from stereod.sources.frames import Eye
from stereod.sources.pairing import HYSTERESIS, Pairer
from stereod.vision.detect_params import DetectorParams
from stereod_fakes.replay import ReplayDriver
from stereod_v4l2_minoru.device import V4L2Device
from stereod_v4l2_minoru.driver import MinoruDriver

from ..conftest import ROOT, free_endpoint, zenoh_config
from ..processes import stereod_command
from .conftest import FPS, SLACK, H, Pace, W, disconnect

PAIRS = 15
"""Pairs the skew checks need to mean something."""
OBJECTS = 10
"""Objects messages (one per pair) that show the daemon publishes from both streams, and over
which it measures its own pace (0.3 pairs/s under TCG on a loaded host, 40 s to 10 of them)."""
RESUMED = 5
WARMUP = DetectorParams().warmup_frames
"""Pairs the background takes to learn a scene (the daemon runs with the default)."""
"""Objects messages after the re-plug that show pairs flow again."""
ROUND_TRIP = 18
"""Frames an eye's recording must hold for its replay to check something (vivid sends as
many in 0.72 s)."""
STATUS_PERIOD_S = 0.5


def options(nodes: list[str]) -> dict:
    return {
        "left": nodes[0],
        "right": nodes[1],
        "width": W,
        "height": H,
        "fps": FPS,
        "manual_exposure": False,
    }


def pair_up(frames: dict[Eye, list]) -> list:
    """The pairs a fresh pairer makes of both eyes' frames so far, in capture order."""
    pairer = Pairer(int(1e9 / FPS))
    pairs = []
    for f in sorted(frames[Eye.LEFT] + frames[Eye.RIGHT], key=lambda f: f.t_ns):
        pairs += pairer.push(f)
    return pairs


def test_capture_both_eyes_with_kernel_timestamps(vivid: list[str], pace: Pace) -> None:
    """Both eyes are read in turn until PAIRS pairs form, for at most as many frames as the
    measured pace needs for them (SLACK times): a starved guest reads more, as the kernel
    drops frames while it waits and fewer of them find a partner."""
    with V4L2Device(vivid[0]) as dev:
        assert "YUYV" in [f for f, _ in dev.formats()]
        assert (W, H) in dev.frame_sizes("YUYV")
    source = MinoruDriver(options(vivid)).open()
    try:
        frames: dict[Eye, list] = {Eye.LEFT: [], Eye.RIGHT: []}
        reads = pace.reads_for(PAIRS)
        pairs: list = []
        for _ in range(reads):  # alternately, as the two capture threads keep both eyes current
            for eye in (source.left, source.right):
                f = eye.read()
                assert f is not None
                frames[eye.eye].append(f)
            if len(frames[Eye.LEFT]) % 5 == 0:
                pairs = pair_up(frames)
                if len(pairs) >= PAIRS:
                    break
        now = time.monotonic_ns()
        pairs = pair_up(frames)
        assert len(pairs) >= PAIRS, f"{len(pairs)} pairs from {reads} frames an eye"
        for eye, fs in frames.items():
            t = np.array([f.t_ns for f in fs])
            seq = np.array([f.seq for f in fs])
            assert np.all(np.diff(t) > 0), f"{eye} timestamps not increasing"
            assert np.all(np.diff(seq) >= 1)
            # The kernel's own frame period: time over sequence numbers, so frames it dropped
            # while the reader was late (a sequence gap) do not lengthen it.
            period = float(np.median(np.diff(t) / np.diff(seq))) / 1e6
            assert abs(period - 1000 / FPS) < 4, f"{eye} period {period:.1f} ms"
            img = fs[0].image
            assert img.shape == (H, W, 3)
            # vivid's default pattern is colour bars: YUYV must arrive as colour, not grey.
            spread = img.max(axis=2).astype(int) - img.min(axis=2)
            assert np.mean(spread > 60) > 0.3, f"{eye} frame is not in colour"
            # CLOCK_MONOTONIC: the kernel stamps frames on the clock time.monotonic_ns reads.
            assert abs(fs[-1].t_ns - now) < 5e9
        # Two free-running eyes are at most half a frame apart, or 0.6 of one while the pairer
        # keeps its phase (HYSTERESIS) as their skew hovers about half a frame; a frame the
        # kernel dropped (a sequence gap, counted below) leaves its partner up to one frame
        # from the next one.
        skews = np.array([abs(p.skew_ns) for p in pairs])
        assert np.mean(skews <= (0.5 + HYSTERESIS) * 1e9 / FPS + 2e6) >= 0.9, skews
        assert skews.max() <= 1e9 / FPS, skews
        gaps = source.left.counters().drops.get(
            "sequence_gap", 0
        ) + source.right.counters().drops.get("sequence_gap", 0)
        assert gaps == sum(int(np.sum(np.diff([f.seq for f in fs]) - 1)) for fs in frames.values())
    finally:
        source.close()


def write_config(path: Path, nodes: list[str], endpoint: str) -> None:
    opts = options(nodes)
    lines = "".join(f"{k} = {json.dumps(v)}\n" for k, v in opts.items())
    path.write_text(
        f'[rig]\nname = "vivid"\n[driver]\nname = "v4l2_minoru"\n[driver.options]\n{lines}'
        f'[zenoh]\nlisten = ["{endpoint}"]\n[daemon]\nstatus_period_s = {STATUS_PERIOD_S}\n'
    )


def test_one_eye_unplugged_and_replugged_while_the_other_streams(
    vivid: list[str], pace: Pace, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """The left eye's camera is unplugged while streaming (its node fails with ENODEV and its
    udev name goes away), then plugged in again (the name comes back, here on another node):
    the status key says the left eye is down while the right one streams on, and the left eye
    streams again within 2 s of its name reappearing. Each wait is sized from the guest's
    measured start-up and frame pace (:meth:`Pace.wait_s`)."""
    endpoint = free_endpoint()
    eyes = tmp_path / "minoru"
    eyes.mkdir()
    left = eyes / "left"  # what udev's /dev/minoru/left is: a name for whichever node
    left.symlink_to(vivid[0])
    cfg = tmp_path / "vivid.toml"
    write_config(cfg, [str(left), vivid[1]], endpoint)
    log = (tmp_path / "daemon.log").open("w")
    started = time.monotonic()
    proc = subprocess.Popen(
        stereod_command("run", "--config", str(cfg)),
        cwd=ROOT,
        stdout=log,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "STEREOD_LOG_LEVEL": "INFO"},
    )
    objects: list[dict] = []
    arrivals: list[float] = []  # time.monotonic() at each objects message's arrival

    def on_objects(m: zenoh.Sample) -> None:
        arrivals.append(time.monotonic())
        objects.append(json.loads(m.payload.to_bytes()))

    statuses: list[tuple[float, dict]] = []  # (time.monotonic() at arrival, message)

    def wait(pred, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if pred():
                return True
            time.sleep(0.02)
        return False

    def since(t: float) -> list[dict]:
        return [st for at, st in list(statuses) if at >= t]

    try:
        with zenoh.open(zenoh_config(connect=[endpoint])) as s:
            s.declare_subscriber("stereod/vivid/objects", on_objects)
            s.declare_subscriber(
                "stereod/vivid/status",
                lambda m: statuses.append((time.monotonic(), json.loads(m.payload.to_bytes()))),
            )
            # Started, the background warmed up, then OBJECTS pairs.
            first = pace.wait_s(starts=1, frames=WARMUP + OBJECTS)
            assert wait(lambda: len(objects) >= OBJECTS, first), (
                f"{len(objects)} of {OBJECTS} objects messages from the vivid streams in "
                f"{first:.0f} s ({len(statuses)} statuses): "
                + (tmp_path / "daemon.log").read_text()[-3000:]
            )
            # From here on the daemon's own pace, read off this run's arrivals: it detects and
            # publishes, so it keeps fewer pairs a second than the reader that measured `pace`.
            # Its objects come in bursts (0.3 to 25 pairs/s over the first ten, from one run to
            # the next), so the pace is taken over its whole run so far, start-up included.
            span_s = max(arrivals[OBJECTS - 1] - started, 1e-6)
            run = dataclasses.replace(pace, fps=min(pace.fps, (WARMUP + OBJECTS) / span_s))
            reporter = request.config.pluginmanager.get_plugin("terminalreporter")
            if reporter is not None:
                reporter.write_line(
                    f"daemon: first objects after {arrivals[0] - started:.1f} s, "
                    f"then {run.fps:.1f} pairs/s"
                )
            assert wait(
                lambda: any(
                    st["left"]["state"] == st["right"]["state"] == "streaming" for st in since(0)
                ),
                run.wait_s(seconds=2 * STATUS_PERIOD_S),
            )
            unplugged = time.monotonic()
            left.unlink()
            disconnect(vivid[0])
            # A read on the unplugged node fails at once (ENODEV), or within its read timeout.
            assert wait(
                lambda: any(st["left"]["state"] == "down" for st in since(unplugged)),
                run.wait_s(seconds=0.5 + 2 * STATUS_PERIOD_S, frames=1),
            ), "the status key never said the left eye was down"
            down = time.monotonic()
            # Two status periods with the left eye down: the right eye's frames keep coming.
            assert wait(
                lambda: len([1 for st in since(down) if st["left"]["state"] == "down"]) >= 3,
                run.wait_s(seconds=3 * STATUS_PERIOD_S),
            )
            during = [st for st in since(down) if st["left"]["state"] == "down"]
            assert all(st["right"]["state"] == "streaming" for st in during), during[-1]
            assert during[-1]["right"]["frames"] > during[0]["right"]["frames"], (
                "the right eye stopped while only the left one was unplugged"
            )
            assert during[-1]["state"] == "degraded"
            assert proc.poll() is None, "the daemon must survive the unplug"
            objects_before = len(objects)
            left.symlink_to(vivid[2])  # re-plugged: udev names the eye again
            plugged = time.monotonic()
            assert wait(
                lambda: any(st["left"]["state"] == "streaming" for st in since(plugged)),
                run.wait_s(seconds=2.0 + STATUS_PERIOD_S, frames=1),
            ), "the left eye did not stream again"
            back = next(
                at
                for at, st in list(statuses)
                if at >= plugged and st["left"]["state"] == "streaming"
            )
            recovery_s = back - plugged
            if reporter is not None:  # the measurement, in the run's output
                reporter.write_line(f"left eye: re-plug to streaming {recovery_s:.3f} s")
            assert recovery_s < 2.0, f"re-plug to streaming took {recovery_s:.2f} s (bound 2 s)"
            assert wait(
                lambda: len(objects) >= objects_before + RESUMED,
                run.wait_s(frames=WARMUP + RESUMED),  # the re-plugged eye's scene is learned anew
            ), "pairs did not resume"
            assert wait(
                lambda: since(plugged)[-1]["reconnects"].get("left") == 1,
                run.wait_s(seconds=2 * STATUS_PERIOD_S),
            )
            assert "right" not in since(plugged)[-1]["reconnects"]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=pace.wait_s(starts=1))
        log.close()
    assert proc.returncode == 0, (tmp_path / "daemon.log").read_text()[-3000:]


def test_record_and_replay_reproduce_timestamps(
    vivid: list[str], pace: Pace, tmp_path: Path
) -> None:
    """Every frame recorded from the kernel driver replays with its own timestamp and sequence
    number. How many frames a second the recorder keeps depends on the guest's pace (under TCG
    on a loaded host, 14 of vivid's 75 in 3 s once), so it records for as long as the measured
    pace needs for SLACK times ROUND_TRIP frames an eye, and must keep ROUND_TRIP."""
    cfg = tmp_path / "rec.toml"
    write_config(cfg, vivid, free_endpoint())
    out = tmp_path / "rec"
    seconds = math.ceil(SLACK * ROUND_TRIP / pace.fps)
    res = subprocess.run(
        stereod_command("record", str(out), "--seconds", str(seconds), "--config", str(cfg)),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=pace.wait_s(starts=1, seconds=seconds),
    )
    assert res.returncode == 0, res.stderr
    csv = {eye: (out / f"{eye}.csv").read_text().splitlines()[1:] for eye in ("left", "right")}
    kept = {k: len(v) for k, v in csv.items()}
    assert min(kept.values()) >= ROUND_TRIP, f"{kept} frames kept in {seconds} s"
    with ReplayDriver({"path": out}).open() as src:
        for eye, reader in (("left", src.left), ("right", src.right)):
            for row in csv[eye]:
                t, seq = (int(x) for x in row.split(",")[:2])
                f = reader.read()
                assert f is not None and (f.t_ns, f.seq) == (t, seq)
            assert reader.read() is None
