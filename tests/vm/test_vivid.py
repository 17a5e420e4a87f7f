"""The V4L2 driver against the kernel's vivid driver (in the VM): real nodes, real kernel
timestamps and sequence numbers, a real unplug and re-plug."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from stereod.frames import Eye
from stereod.pairing import HYSTERESIS, Pairer
from stereod_fakes.replay import ReplayDriver
from stereod_v4l2_minoru.device import V4L2Device
from stereod_v4l2_minoru.driver import MinoruDriver

from ..conftest import ROOT, free_endpoint, zenoh_config
from ..processes import stereod_command
from .conftest import disconnect

W, H, FPS = 320, 180, 25.0


def options(nodes: list[str]) -> dict:
    return {
        "left": nodes[0],
        "right": nodes[1],
        "width": W,
        "height": H,
        "fps": FPS,
        "manual_exposure": False,
    }


def test_capture_both_eyes_with_kernel_timestamps(vivid: list[str]) -> None:
    with V4L2Device(vivid[0]) as dev:
        assert "YUYV" in [f for f, _ in dev.formats()]
        assert (W, H) in dev.frame_sizes("YUYV")
    source = MinoruDriver(options(vivid)).open()
    try:
        frames = {Eye.LEFT: [], Eye.RIGHT: []}
        for _ in range(25):  # alternately, as the two capture threads keep both eyes current
            for eye in (source.left, source.right):
                f = eye.read()
                assert f is not None
                frames[eye.eye].append(f)
        for eye, fs in frames.items():
            t = np.array([f.t_ns for f in fs])
            seq = np.array([f.seq for f in fs])
            assert np.all(np.diff(t) > 0), f"{eye} timestamps not increasing"
            period = float(np.median(np.diff(t))) / 1e6
            assert abs(period - 1000 / FPS) < 4, f"{eye} period {period:.1f} ms"
            assert np.all(np.diff(seq) >= 1)
            img = fs[0].image
            assert img.shape == (H, W, 3)
            # vivid's default pattern is colour bars: YUYV must arrive as colour, not grey.
            spread = img.max(axis=2).astype(int) - img.min(axis=2)
            assert np.mean(spread > 60) > 0.3, f"{eye} frame is not in colour"
            # CLOCK_MONOTONIC: the kernel stamps frames on the clock time.monotonic_ns reads.
            assert abs(fs[-1].t_ns - time.monotonic_ns()) < 5e9
        pairer = Pairer(int(1e9 / FPS))
        pairs = []
        for f in sorted(frames[Eye.LEFT] + frames[Eye.RIGHT], key=lambda f: f.t_ns):
            pairs += pairer.push(f)
        assert len(pairs) >= 15
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
        f'[zenoh]\nlisten = ["{endpoint}"]\n[daemon]\nstatus_period_s = 0.5\n'
    )


def test_one_eye_unplugged_and_replugged_while_the_other_streams(
    vivid: list[str], tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """The left eye's camera is unplugged while streaming (its node fails with ENODEV and its
    udev name goes away), then plugged in again (the name comes back, here on another node):
    the status key says the left eye is down while the right one streams on, and the left eye
    streams again within 2 s of its name reappearing."""
    endpoint = free_endpoint()
    eyes = tmp_path / "minoru"
    eyes.mkdir()
    left = eyes / "left"  # what udev's /dev/minoru/left is: a name for whichever node
    left.symlink_to(vivid[0])
    cfg = tmp_path / "vivid.toml"
    write_config(cfg, [str(left), vivid[1]], endpoint)
    log = (tmp_path / "daemon.log").open("w")
    proc = subprocess.Popen(
        stereod_command("run", "--config", str(cfg)),
        cwd=ROOT,
        stdout=log,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "STEREOD_LOG_LEVEL": "INFO"},
    )
    objects: list[dict] = []
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
            s.declare_subscriber(
                "stereod/vivid/objects", lambda m: objects.append(json.loads(m.payload.to_bytes()))
            )
            s.declare_subscriber(
                "stereod/vivid/status",
                lambda m: statuses.append((time.monotonic(), json.loads(m.payload.to_bytes()))),
            )
            assert wait(lambda: len(objects) >= 20, 120), (
                f"no objects from the vivid streams ({len(statuses)} statuses): "
                + (tmp_path / "daemon.log").read_text()[-3000:]
            )
            assert wait(
                lambda: any(
                    st["left"]["state"] == st["right"]["state"] == "streaming" for st in since(0)
                ),
                30,
            )
            unplugged = time.monotonic()
            left.unlink()
            disconnect(vivid[0])
            assert wait(
                lambda: any(st["left"]["state"] == "down" for st in since(unplugged)), 60
            ), "the status key never said the left eye was down"
            down = time.monotonic()
            # Two status periods with the left eye down: the right eye's frames keep coming.
            assert wait(
                lambda: len([1 for st in since(down) if st["left"]["state"] == "down"]) >= 3, 30
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
                lambda: any(st["left"]["state"] == "streaming" for st in since(plugged)), 30
            ), "the left eye did not stream again"
            back = next(
                at
                for at, st in list(statuses)
                if at >= plugged and st["left"]["state"] == "streaming"
            )
            recovery_s = back - plugged
            reporter = request.config.pluginmanager.get_plugin("terminalreporter")
            if reporter is not None:  # the measurement, in the run's output
                reporter.write_line(f"left eye: re-plug to streaming {recovery_s:.3f} s")
            assert recovery_s < 2.0, f"re-plug to streaming took {recovery_s:.2f} s (bound 2 s)"
            assert wait(lambda: len(objects) > objects_before + 10, 60), "pairs did not resume"
            assert wait(lambda: since(plugged)[-1]["reconnects"].get("left") == 1, 10)
            assert "right" not in since(plugged)[-1]["reconnects"]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=60)
        log.close()
    assert proc.returncode == 0, (tmp_path / "daemon.log").read_text()[-3000:]


def test_record_and_replay_reproduce_timestamps(vivid: list[str], tmp_path: Path) -> None:
    """Every frame recorded from the kernel driver replays with its own timestamp and sequence
    number. The VM is emulated (no KVM in CI), so how many of vivid's ``FPS`` frames a second
    the recorder keeps depends on the host's load (28 of 50 in 2 s once): the count asked for,
    a quarter of what vivid sends, is only enough to make the round trip mean something."""
    cfg = tmp_path / "rec.toml"
    write_config(cfg, vivid, free_endpoint())
    out = tmp_path / "rec"
    seconds = 3
    res = subprocess.run(
        stereod_command("record", str(out), "--seconds", str(seconds), "--config", str(cfg)),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    csv = {eye: (out / f"{eye}.csv").read_text().splitlines()[1:] for eye in ("left", "right")}
    floor = int(FPS * seconds / 4)
    assert min(len(rows) for rows in csv.values()) >= floor, {k: len(v) for k, v in csv.items()}
    with ReplayDriver({"path": out}).open() as src:
        for eye, reader in (("left", src.left), ("right", src.right)):
            for row in csv[eye]:
                t, seq = (int(x) for x in row.split(",")[:2])
                f = reader.read()
                assert f is not None and (f.t_ns, f.seq) == (t, seq)
            assert reader.read() is None
