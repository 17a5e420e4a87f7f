"""A reload never kills a running daemon: a real ``stereod run`` gets SIGHUP after its
configuration file was replaced by one bad file after another. Each is refused, the running
configuration stays, and the status key's ``problems`` says why (naming the file by its name,
not its path); a good file afterwards is taken."""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from stereod.client import query_config
from stereod.vision.calibration import canonical

from .conftest import zenoh_config
from .processes import start_stereod

pytestmark = pytest.mark.slow


def good(endpoint: str, threshold: float = 25.0, extra: str = "") -> str:
    return (
        '[rig]\nname = "svc"\n'
        '[driver]\nname = "synthetic"\n[driver.options]\nlive = true\nloop = true\n'
        "width_px = 160\nheight_px = 120\nfps = 15\n"
        f"[detector]\nthreshold = {threshold}\n"
        f'[zenoh]\nlisten = ["{endpoint}"]\n[daemon]\nstatus_period_s = 0.5\n{extra}'
    )


def singular(d: Path) -> Path:
    cal = json.loads(canonical(0.06, 60.0, 160, 120).model_dump_json())
    cal["K1"] = [[0, 0, 0], [0, 0, 0], [0, 0, 1]]
    cal["id"] = ""
    (d / "sing.json").write_text(json.dumps(cal))
    return d / "sing.json"


def flat(d: Path) -> Path:
    """A calibration whose rectified baseline -P2[0][3]/P2[0][0] is 1e-300 m in effect."""
    cal = json.loads(canonical(0.06, 60.0, 160, 120).model_dump_json())
    cal["P2"][0][3] = -1e-300
    cal["id"] = ""
    (d / "flat.json").write_text(json.dumps(cal))
    return d / "flat.json"


BAD: list[tuple[str, Callable[[Path, str], bytes | None], str]] = [
    ("not UTF-8", lambda d, e: b"\xff\xfe[rig]\n", "not a text file"),
    ("not TOML", lambda d, e: b"[rig\nname = 1\n", "invalid TOML"),
    (
        "a value out of range",
        lambda d, e: good(e).replace("threshold = 25.0", "beta = 2.0").encode(),
        "detector.beta = 2.0",
    ),
    (
        "an unknown field",
        lambda d, e: (good(e) + "[detector2]\nx = 1\n").encode(),
        "detector2: unknown field",
    ),
    (
        "a bad driver option",
        lambda d, e: good(e).replace("fps = 15", "fps = -15").encode(),
        "driver.options.fps = -15",
    ),
    (
        "garbage calibration",
        lambda d, e: (
            (d / "junk.json").write_text("garbage"),
            good(e)
            .replace('name = "svc"\n', f'name = "svc"\ncalibration = "{d}/junk.json"\n', 1)
            .encode(),
        )[1],
        "junk.json: not valid JSON",
    ),
    (
        "singular calibration",
        lambda d, e: (
            good(e)
            .replace('name = "svc"\n', f'name = "svc"\ncalibration = "{singular(d)}"\n', 1)
            .encode()
        ),
        "sing.json: K1: not a camera matrix",
    ),
    (
        "a calibration of a vanishing baseline",
        lambda d, e: (
            good(e)
            .replace('name = "svc"\n', f'name = "svc"\ncalibration = "{flat(d)}"\n', 1)
            .encode()
        ),
        "flat.json: P2: rectified baseline -P2[0][3]/P2[0][0] = ",
    ),
    (
        "a status period that floods the bus",
        lambda d, e: good(e).replace("status_period_s = 0.5", "status_period_s = 1e-9").encode(),
        "daemon.status_period_s = 1e-09: must be in 0.05..60 s",
    ),
    (
        "true for a number",
        lambda d, e: good(e).replace("threshold = 25.0", "threshold = true").encode(),
        "detector.threshold = True: must be a number",
    ),
    (
        "a Zenoh file that is not one",
        lambda d, e: (
            (d / "z.json5").write_text("{ mode: 3 }"),
            good(e).replace("[daemon]", f'config_file = "{d}/z.json5"\n[daemon]').encode(),
        )[1],
        "z.json5: invalid Zenoh config file",
    ),
    (
        "a Zenoh file nested 100000 deep (its parser died by SIGSEGV)",
        lambda d, e: (
            (d / "deep.json5").write_text("{mode: " + "[" * 100_000 + "]" * 100_000 + "}"),
            good(e).replace("[daemon]", f'config_file = "{d}/deep.json5"\n[daemon]').encode(),
        )[1],
        "deep.json5 (zenoh.config_file): nested deeper than 64 levels",
    ),
    (
        "TOML nested 520 deep",
        lambda d, e: (
            good(e)
            .replace("[driver.options]\n", "[driver.options]\nx = " + "[" * 520 + "]" * 520 + "\n")
            .encode()
        ),
        "svc.toml: nested deeper than 64 levels",
    ),
    (
        "a bad endpoint",
        lambda d, e: good(e).replace(e, "tcp/127.0.0.1:99999").encode(),
        "zenoh.listen.0",
    ),
    ("no file at all", lambda d, e: None, "no such config file"),
]


def test_no_new_file_kills_a_running_daemon(tmp_path: Path, endpoint: str) -> None:
    cfg = tmp_path / "svc.toml"
    cfg.write_text(good(endpoint))
    proc = start_stereod("run", "--config", str(cfg), cwd=tmp_path)
    statuses: list[dict] = []
    try:
        with zenoh.open(zenoh_config(connect=[endpoint])) as s:
            s.declare_subscriber(
                "stereod/svc/status", lambda m: statuses.append(json.loads(m.payload.to_bytes()))
            )

            def wait(pred: Callable[[], bool], timeout: float = 20) -> bool:
                deadline = time.monotonic() + timeout
                while time.monotonic() < deadline:
                    if pred():
                        return True
                    time.sleep(0.05)
                return False

            assert wait(lambda: any(st["state"] == "running" for st in statuses), 30)
            for what, make, reason in BAD:
                content = make(tmp_path, endpoint)
                if content is None:
                    cfg.unlink()
                else:
                    cfg.write_bytes(content)
                seen = len(statuses)
                proc.send_signal(signal.SIGHUP)
                assert wait(
                    lambda reason=reason, seen=seen: any(
                        reason in p for st in statuses[seen:] for p in st["problems"]
                    )
                ), f"{what}: no problem saying {reason!r}: {statuses[-1]['problems']}"
                assert proc.poll() is None, f"{what}: the daemon died"
                latest = statuses[-1]["problems"][-1]
                assert "keeping the running configuration" in latest, latest
                refused = [p for p in statuses[-1]["problems"] if "reload refused" in p]
                assert refused == [latest], refused  # the refusal before is replaced
                assert str(tmp_path) not in latest, f"a private path on the bus: {latest}"
                assert query_config(s, rig="svc")["detector"]["threshold"] == 25.0
            cfg.write_text(good(endpoint, threshold=31.0))
            proc.send_signal(signal.SIGHUP)
            assert wait(lambda: query_config(s, rig="svc")["detector"]["threshold"] == 31.0)
            assert statuses[-1]["state"] == "running"
            # The refusals hold no more: the status key stops listing them (the log keeps them).
            assert wait(lambda: not any("reload refused" in p for p in statuses[-1]["problems"])), (
                statuses[-1]["problems"]
            )
            # What waits for a restart is reported as it runs, not as the file has it.
            before = query_config(s, rig="svc")
            renamed = good(endpoint, 33.0, "[pairing]\ntolerance_ms = 31.0\n")
            renamed = renamed.replace('"svc"', '"svc2"').replace("status_period_s = 0.5", "")
            cfg.write_text(renamed.replace("width_px = 160", "width_px = 320"))
            seen = len(statuses)
            proc.send_signal(signal.SIGHUP)
            assert wait(lambda: query_config(s, rig="svc")["detector"]["threshold"] == 33.0)
            running = query_config(s, rig="svc")
            assert running["rig"]["name"] == "svc"
            assert running["driver"]["options"]["width_px"] == 160
            assert running["pairing"] == before["pairing"] and running["daemon"] == before["daemon"]
            waiting = "driver, daemon, rig.name, pairing.tolerance_ms take effect at the next"
            assert wait(lambda: any(waiting in p for st in statuses[seen:] for p in st["problems"]))
            # The running file again: nothing waits any more, and the status stops saying so.
            cfg.write_text(good(endpoint, threshold=34.0))
            proc.send_signal(signal.SIGHUP)
            assert wait(lambda: query_config(s, rig="svc")["detector"]["threshold"] == 34.0)
            settled = wait(lambda: not any(waiting in p for p in statuses[-1]["problems"]))
            assert settled, statuses[-1]["problems"]
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert err.count("reload refused") == len(BAD), err
