"""The typed client against a real daemon over real Zenoh sessions on loopback."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
from pydantic import ValidationError

from stereod import client
from stereod.bus import keys
from stereod.bus.messages import CanonicalGeometry, StatusMessage
from stereod.bus.subscribe import format_sample
from stereod.client import (
    DaemonAlive,
    Event,
    ObjectsMessage,
    ObjectState,
    QueryError,
    Subscription,
    TrackEnded,
    object_events,
    parse_payload,
    query_calibration,
    query_config,
    query_stats,
    subscribe_objects,
    subscribe_status,
    wait_alive,
)
from stereod.daemon.config import load_config
from stereod.daemon.daemon import Daemon
from stereod_fakes.synth import SyntheticDriver
from tests.conftest import zenoh_config
from tests.test_api import readme_examples

SCENE = {"duration_s": 3.0, "fps": 15, "width_px": 320, "height_px": 240}


def run_daemon(
    endpoint: str, rate: float = 1.0, **scene: object
) -> tuple[Daemon, threading.Thread]:
    cfg = load_config(overrides={"zenoh": {"listen": [endpoint]}, "rig": {"name": "bench"}})
    daemon = Daemon(cfg, SyntheticDriver({**SCENE, **scene}), rate=rate, wait_subscriber_s=10)
    thread = threading.Thread(target=daemon.run)
    thread.start()
    return daemon, thread


def test_key_builders() -> None:
    assert keys.objects("bench") == "stereod/bench/objects"
    assert keys.track("bench", 7, prefix="lab/a") == "lab/a/bench/objects/7"
    assert keys.alive("*") == "stereod/*/alive"
    assert keys.image("overlay") == "stereod/minoru/image/overlay"
    assert keys.parse("stereod/bench/objects/7") == ("bench", "objects/7")
    assert keys.parse("other/bench/objects") is None
    for bad in ("a b", "a/b", ""):
        with pytest.raises(ValueError, match="rig name"):
            keys.objects(bad)
    with pytest.raises(ValueError, match="queryable"):
        keys.queryable("secrets")


def test_events_are_typed_and_complete(endpoint: str) -> None:
    """Objects messages arrive parsed; every track seen ends with a TrackEnded; the daemon's
    liveliness is seen coming and going."""
    events: list[Event] = []
    lock = threading.Lock()

    def on_event(event: Event) -> None:
        with lock:
            events.append(event)

    with zenoh.open(zenoh_config(connect=[endpoint])) as session:
        _, thread = run_daemon(endpoint, rate=0.0)
        with subscribe_objects(session, on_event, rig="bench") as sub:
            thread.join(30)
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                with lock:
                    if isinstance(events[-1], DaemonAlive) and not events[-1].alive:
                        break
                time.sleep(0.05)
        assert sub.rejected == 0
    messages = [e for e in events if isinstance(e, ObjectsMessage)]
    assert len(messages) == 45
    assert [m.seq for m in messages] == list(range(45))
    states = [o for m in messages for o in m.objects]
    assert states and all(isinstance(o, ObjectState) for o in states)
    ended = {e.track_id for e in events if isinstance(e, TrackEnded)}
    assert {o.track_id for o in states} <= ended
    alive = [e.alive for e in events if isinstance(e, DaemonAlive)]
    assert alive[0] is True and alive[-1] is False


def test_queries_and_the_iterator(endpoint: str) -> None:
    with zenoh.open(zenoh_config(connect=[endpoint])) as session:
        assert not wait_alive(session, rig="bench", timeout_s=0.2)
        asked = time.monotonic()
        with pytest.raises(QueryError, match=r"no daemon on the bus answered it within 1 s"):
            query_stats(session, rig="bench", timeout_s=1.0)  # asked again until the timeout
        assert 0.8 < time.monotonic() - asked < 3.0
        silent = session.declare_queryable(  # one that never replies: the wait runs out
            keys.queryable("stats", "mute"), lambda q: time.sleep(1.0)
        )
        with pytest.raises(QueryError, match=r"no reply within 0\.3 s"):
            query_stats(session, rig="mute", timeout_s=0.3)
        silent.undeclare()
        for bad in (math.nan, -1.0, "1"):
            with pytest.raises(ValueError, match="timeout_s must be"):
                wait_alive(session, rig="bench", timeout_s=bad)  # type: ignore[arg-type]
        for bad in (math.inf, 0.0, math.nan):
            with pytest.raises(ValueError, match="timeout_s must be a finite number"):
                query_stats(session, rig="bench", timeout_s=bad)
        daemon, thread = run_daemon(endpoint, rate=1.0, duration_s=4.0)
        try:
            assert wait_alive(session, rig="bench", timeout_s=10)
            assert wait_alive(session, rig="bench", timeout_s=math.inf)  # no limit: it is up
            assert query_config(session, rig="bench")["rig"]["name"] == "bench"
            geometry = query_calibration(session, rig="bench")
            assert isinstance(geometry, CanonicalGeometry)
            assert geometry.baseline_m == 0.06 and geometry.width_px == 320
            statuses: list[StatusMessage] = []
            with (
                subscribe_status(session, statuses.append, rig="bench"),
                object_events(session, rig="bench") as events,
            ):
                got = [events.get(5.0) for _ in range(5)]
                assert any(isinstance(e, ObjectsMessage) for e in got)
                assert query_stats(session, rig="bench").pairs >= 1
                # a session just opened knows of no daemon yet: its query is asked again
                with zenoh.open(zenoh_config(connect=[endpoint])) as fresh:
                    assert query_stats(fresh, rig="bench").pairs >= 1
                time.sleep(1.2)
            assert statuses and statuses[-1].rig == "bench"
        finally:
            daemon.stop()
            thread.join(15)


def test_parse_payload_is_lenient() -> None:
    assert parse_payload(b"\xff") is None
    # A schema that is no string, and JSON nested past Python's parser, raised (AttributeError,
    # RecursionError) out of a subscriber's callback.
    assert parse_payload(b'{"schema": null}') == {"schema": None}
    assert parse_payload(b'{"schema": 5, "a": [1]}') == {"schema": 5, "a": [1]}
    assert parse_payload(b"[" * 2000 + b"]" * 2000) is None
    assert format_sample("k", b'{"schema": null}') == 'k: {"schema": null}'
    assert format_sample("k", b"[" * 2000 + b"]" * 2000) == "k: 4000 bytes (not JSON)"
    assert parse_payload(b'{"schema": "other/1", "a": 1}') == {"schema": "other/1", "a": 1}
    golden = (Path(__file__).parent / "golden" / "objects_example.json").read_bytes()
    assert isinstance(parse_payload(golden), ObjectsMessage)


def test_parse_payload_gives_every_message_the_daemon_sends_its_class() -> None:
    """What the daemon publishes on each key, parsed back: objects, one object, status and
    stats each come back as their class (the status came back as plain data: its class was
    keyed by a schema the daemon never sends)."""
    from stereod.daemon.status import Health
    from stereod.sources.pairing import Pairer

    golden = ObjectsMessage.model_validate_json(
        (Path(__file__).parent / "golden" / "objects_example.json").read_bytes()
    )
    health = Health("bench", "test", Pairer(), on_change=lambda: None)
    for message in (golden, golden.objects[0], health.status(), health.stats()):
        payload = message.model_dump_json(by_alias=True).encode()
        assert type(parse_payload(payload)) is type(message), type(message).__name__


@pytest.mark.slow
def test_readme_client_example_runs(endpoint: str) -> None:
    """The README's client program, as a user would run it, against a running daemon."""
    code = readme_examples()["client"].replace('"minoru"', '"bench"')
    daemon, thread = run_daemon(endpoint, rate=1.0, duration_s=4.0)
    try:
        res = subprocess.run(
            [sys.executable, "-c", code, endpoint], capture_output=True, text=True, timeout=60
        )
    finally:
        daemon.stop()
        thread.join(15)
    assert res.returncode == 0, res.stderr
    assert "daemon up" in res.stdout
    assert "heading" in res.stdout and " ended" in res.stdout, res.stdout


def test_zenoh_config_tries_a_missing_daemon_again_soon() -> None:
    conf = json.loads(client.zenoh_config("tcp/127.0.0.1:7447").get_json("connect"))
    assert conf["endpoints"] == ["tcp/127.0.0.1:7447"]
    assert conf["retry"]["period_max_ms"] <= 250  # Zenoh's own default grows to 4000
    with pytest.raises(ValueError, match="nonsense"):
        client.zenoh_config("nonsense")


def test_zenoh_config_file_that_is_not_there_or_a_folder_is_a_value_error(
    tmp_path: Path,
) -> None:
    """As its docstring says: a caller catching ValueError is told, the file named."""
    for where in (tmp_path / "gone.json5", tmp_path):
        with pytest.raises(ValueError, match=str(where.name)):
            client.zenoh_config("tcp/127.0.0.1:7447", config_file=where)


@pytest.mark.slow
def test_readme_client_example_started_before_the_daemon(endpoint: str) -> None:
    """As the README says to run it: the program first, the daemon a few seconds later (here
    8 s, past Zenoh's default retries at 1, 3 and 7 s); it sees the whole run."""
    code = readme_examples()["client"].replace('"minoru"', '"bench"')
    program = subprocess.Popen(
        [sys.executable, "-c", code, endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(8.0)
        daemon, thread = run_daemon(endpoint, rate=1.0, duration_s=4.0)
        try:
            out, err = program.communicate(timeout=60)
        finally:
            daemon.stop()
            thread.join(15)
    finally:
        program.kill()
    assert program.returncode == 0, err
    # The daemon waits for a subscriber before it plays, so a client that found it in time
    # queried it before its first pair.
    assert "daemon up, 0 pairs so far" in out, out
    assert "heading" in out and " ended" in out, out


def test_a_status_that_does_not_parse_is_logged_once_on_one_line(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """pydantic's own text of a refused sample spans a line per field; the subscription's
    warning is one line naming the key and the fields, and only the first is logged."""
    sub = Subscription()
    with pytest.raises(ValidationError) as bad:
        StatusMessage.model_validate_json(b'{"schema": "stereod.status/1", "rig": 5}')
    with caplog.at_level("WARNING", logger="stereod.client"):
        sub._rejected("stereod/minoru/status", bad.value)
        sub._rejected("stereod/minoru/status", bad.value)
    (record,) = caplog.records
    text = record.getMessage()
    assert "\n" not in text and sub.rejected == 2
    assert text.startswith(
        "ignoring a sample on stereod/minoru/status that does not parse: rig = 5"
    )
