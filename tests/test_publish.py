"""The Zenoh publisher against a real session on loopback."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
import zenoh

from stereod.bus.publish import Publisher, open_session, session_config, session_summary
from stereod.client import wait_alive
from stereod.daemon.config import ZenohConfig
from stereod.errors import ConfigError, UnavailableError
from tests.conftest import stereod


def test_objects_tracks_deletes_and_failing_queryable(
    endpoint: str, listener: zenoh.Session
) -> None:
    got: list[tuple[str, str, bytes]] = []
    lock = threading.Lock()

    def on(s: zenoh.Sample) -> None:
        with lock:
            got.append((str(s.key_expr), str(s.kind), s.payload.to_bytes()))

    sub = listener.declare_subscriber("stereod/r/**", on)

    def broken() -> bytes:
        raise RuntimeError("no stats yet")

    seen_status_sub = threading.Event()
    with Publisher(
        ZenohConfig(connect=[endpoint]), "r", {"stats": broken}, seen_status_sub.set
    ) as pub:
        deadline = time.monotonic() + 10
        while not pub.has_objects_subscriber() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert pub.has_objects_subscriber()
        assert seen_status_sub.wait(5), "matching listener did not fire for the status key"
        pub.objects(b'{"n": 1}', [(7, b'{"t": 7}')], [])
        pub.objects(b'{"n": 2}', [], [7])
        # get() does not wait for a queryable: the liveliness token, declared last, says
        # the queryables are known.
        assert wait_alive(listener, rig="r", timeout_s=10)
        replies = list(listener.get("stereod/r/stats", timeout=5))
        assert replies and replies[0].err is not None
        assert "no stats yet" in replies[0].err.payload.to_bytes().decode()
        time.sleep(0.3)
    sub.undeclare()
    keys = [(k, kind.split(".")[-1]) for k, kind, _ in got]
    assert ("stereod/r/objects", "PUT") in keys
    assert ("stereod/r/objects/7", "PUT") in keys
    assert ("stereod/r/objects/7", "DELETE") in keys
    assert pub.published == 2 and pub.errors == 0


def test_a_subscriber_to_the_tracks_keys_alone_counts_as_one(
    endpoint: str, listener: zenoh.Session
) -> None:
    """``--wait-subscriber`` waits for someone to read the results: a subscriber to the
    tracks' keys (``objects/*``, which does not match ``objects``) is one; one to another
    rig's keys, or to the status key, is not."""
    with Publisher(ZenohConfig(connect=[endpoint]), "r", {}) as pub:
        others = [
            listener.declare_subscriber(k, lambda s: None)
            for k in ("stereod/q/**", "stereod/r/status")
        ]
        time.sleep(1.0)
        assert not pub.has_objects_subscriber()
        sub = listener.declare_subscriber("stereod/r/objects/*", lambda s: None)
        deadline = time.monotonic() + 10
        while not pub.has_objects_subscriber() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert pub.has_objects_subscriber()
        sub.undeclare()
        for o in others:
            o.undeclare()


def test_a_session_given_to_the_publisher_stays_open_with_nothing_of_it_left(
    endpoint: str, listener: zenoh.Session
) -> None:
    """The demo opens its session before the publisher (to hold its port): the publisher
    publishes on it, and on close ends its tracks and withdraws its token and keys, leaving
    the session open for its owner to close."""
    got: list[tuple[str, str]] = []
    sub = listener.declare_subscriber(
        "stereod/r/**", lambda s: got.append((str(s.key_expr), str(s.kind).split(".")[-1]))
    )
    session = open_session(ZenohConfig(connect=[endpoint]))
    try:
        with Publisher(ZenohConfig(), "r", {}, session=session) as pub:
            assert wait_alive(listener, rig="r", timeout_s=10)
            pub.objects(b'{"n": 1}', [(3, b'{"t": 3}')], [])
            time.sleep(0.3)
        assert not session.is_closed()
        time.sleep(0.3)
        assert not list(listener.liveliness().get("stereod/r/alive", timeout=1.0))
        session.put("stereod/r/after", b"still open")
        time.sleep(0.3)
    finally:
        session.close()
        sub.undeclare()
    assert ("stereod/r/objects/3", "PUT") in got and ("stereod/r/objects/3", "DELETE") in got
    assert ("stereod/r/after", "PUT") in got


def test_a_failing_delete_is_counted_and_the_other_tracks_still_end(endpoint: str) -> None:
    """A DELETE that Zenoh refuses (here: the session closed under the publisher) was
    raised out of ``objects_end`` and ended the daemon with exit 70, and inside ``objects``
    it skipped the other ended tracks' DELETEs. It is counted and logged; every ended track
    is withdrawn."""
    session = open_session(ZenohConfig(connect=[endpoint]))
    pub = Publisher(ZenohConfig(), "r", {}, session=session).open()
    pub.objects(b"{}", [(1, b"{}"), (2, b"{}"), (3, b"{}")], [])
    session.close()
    pub.objects_end([1])
    pub.objects(b"{}", [], [2, 3])
    assert pub.errors == 1 + 1 + 2  # the DELETEs of 1, 2 and 3, and the objects message
    assert pub._tracks == {}
    pub.close()


def test_a_publisher_whose_open_fails_leaves_nothing_declared(endpoint: str) -> None:
    """A declaration that fails half-way through ``open`` left the session open (or, on
    a session the caller gave, the entities declared so far): they are withdrawn."""
    session = open_session(ZenohConfig(connect=[endpoint]))
    try:
        bad = {"config": lambda: b"{}", "no good": lambda: b"{}"}  # no such queryable
        with pytest.raises(ValueError, match="no queryable 'no good'"):
            Publisher(ZenohConfig(), "r", bad, session=session).open()
        assert not list(session.liveliness().get("stereod/r/alive", timeout=0.5))
        assert not list(session.get("stereod/r/config", timeout=0.5))
    finally:
        session.close()
    own = Publisher(ZenohConfig(connect=[endpoint]), "r", {"no good": lambda: b"{}"})
    with pytest.raises(ValueError, match="no queryable 'no good'"):
        own.open()
    assert own._session is None  # its own session was closed


def test_session_config_has_no_multicast_by_default() -> None:
    cfg = session_config(ZenohConfig(listen=["tcp/127.0.0.1:0"]))
    assert '"enabled":false' in cfg.get_json("scouting/multicast").replace(" ", "")


def listen_of(zc: zenoh.Config) -> object:
    return json.loads(zc.get_json("listen/endpoints"))


def test_nothing_listens_where_the_user_did_not_say(tmp_path: Path) -> None:
    """Zenoh's own default listens on every interface (tcp/[::]:0 for a peer): a daemon gets
    loopback instead, a consumer nothing, and what the user says is kept, from stereod's config
    or from a Zenoh file that changes the listeners."""
    assert "[::]" in json.dumps(listen_of(zenoh.Config()))  # the default this guards against
    assert listen_of(session_config(ZenohConfig())) == ["tcp/127.0.0.1:0"]
    assert listen_of(session_config(ZenohConfig(mode="router"))) == ["tcp/127.0.0.1:7447"]
    connect = ["tcp/127.0.0.1:7447"]
    assert listen_of(session_config(ZenohConfig(connect=connect), consumer=True)) == []
    told = ["tcp/0.0.0.0:7447"]
    assert listen_of(session_config(ZenohConfig(listen=told), consumer=True)) == told
    plain = tmp_path / "plain.json5"
    plain.write_text("{ mode: 'peer' }")
    zc = session_config(ZenohConfig(config_file=plain))
    assert listen_of(zc) == ["tcp/127.0.0.1:0"]
    assert json.loads(zc.get_json("scouting/multicast/enabled")) is False
    opened = tmp_path / "opened.json5"
    opened.write_text(
        "{ listen: { endpoints: ['tcp/0.0.0.0:7448'] }, scouting: { multicast: { enabled: true,"
        " listen: false } } }"
    )
    zc = session_config(ZenohConfig(config_file=opened))
    assert listen_of(zc) == ["tcp/0.0.0.0:7448"]
    assert json.loads(zc.get_json("scouting/multicast/enabled")) is True
    quiet = ZenohConfig(config_file=opened, multicast_scouting=False)
    assert json.loads(session_config(quiet).get_json("scouting/multicast/enabled")) is False


def test_an_endpoint_not_up_yet_is_tried_again_within_a_quarter_second(tmp_path: Path) -> None:
    """A subscriber started before its daemon connects within 0.25 s of the daemon listening
    (Zenoh's own default waits 1 s, then up to 4 s); a user's own Zenoh file decides itself."""
    ep = ["tcp/127.0.0.1:7447"]
    retry = json.loads(session_config(ZenohConfig(connect=ep)).get_json("connect/retry"))
    assert retry["period_init_ms"] <= 100 and retry["period_max_ms"] <= 250
    own = tmp_path / "z.json5"
    own.write_text("{}")
    zc = session_config(ZenohConfig(connect=ep, config_file=own))
    assert json.loads(zc.get_json("connect/retry")) is None


def test_an_endpoint_another_process_listens_on_is_unavailable_not_a_config_error(
    endpoint: str, listener: zenoh.Session
) -> None:
    """Taken now, perhaps free in a moment (the daemon a restart replaces is still stopping):
    exit 69, which systemd retries, not 78, which it does not."""
    with pytest.raises(UnavailableError, match="another process listens there") as err:
        open_session(ZenohConfig(listen=[endpoint]))
    assert err.value.exit_code == 69


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ('{ connect: { endpoints: ["tcp/127.0.0.1:notaport"] } }', "connect.endpoints"),
        ('{ listen: { endpoints: ["tcp/[::1"] } }', "listen.endpoints 'tcp/[::1'"),
        ('{ listen: { endpoints: { router: ["foo/1.2.3.4:1"], peer: [] } } }', "unknown protocol"),
        ('{ connect: { endpoints: ["tcp/127.0.0.1"] } }', "tcp/127.0.0.1"),
    ],
)
def test_an_endpoint_in_a_zenoh_file_is_checked_as_one_in_our_settings(
    tmp_path: Path, text: str, said: str
) -> None:
    """A malformed endpoint in the Zenoh file (a list, or one per mode) is a ConfigError naming
    the file and the endpoint, as `run --check` reports it; it used to pass, then never
    connect or fail to open without saying where."""
    own = tmp_path / "zenoh.json5"
    own.write_text(text)
    with pytest.raises(ConfigError) as err:
        session_config(ZenohConfig(config_file=own))
    assert str(own) in str(err.value) and said in str(err.value)
    own.write_text('{ connect: { endpoints: ["tcp/127.0.0.1:7447"] }, listen: { endpoints: '
                   '{ router: ["tcp/[::1]:7447"], peer: ["udp/127.0.0.1:0"] } } }')  # fmt: skip
    session_config(ZenohConfig(config_file=own))


def test_the_session_summary_says_the_mode_and_endpoints_a_zenoh_file_gives(
    tmp_path: Path,
) -> None:
    """A start-up line names what the session takes: our flags, or a Zenoh file's mode and
    endpoints (a client file's, a file with per-mode lists), or that it has none."""
    assert session_summary(ZenohConfig(connect=["tcp/127.0.0.1:7447"]), consumer=True) == (
        "peer, to tcp/127.0.0.1:7447"
    )
    assert session_summary(ZenohConfig(listen=["tcp/127.0.0.1:7448"])) == (
        "peer, listening on tcp/127.0.0.1:7448"
    )
    client = tmp_path / "client.json5"
    client.write_text('{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:7461"]}}')
    assert session_summary(ZenohConfig(config_file=client), consumer=True) == (
        "client, to tcp/127.0.0.1:7461"
    )
    per_mode = tmp_path / "per_mode.json5"
    per_mode.write_text(
        '{mode: "router", listen: {endpoints: {router: ["tcp/127.0.0.1:7462"], '
        'peer: ["tcp/127.0.0.1:7463"]}}}'
    )
    assert session_summary(ZenohConfig(config_file=per_mode)) == (
        "router, listening on tcp/127.0.0.1:7462"
    )
    scouting = tmp_path / "scouting.json5"
    scouting.write_text("{scouting: {multicast: {enabled: true}}}")
    assert session_summary(ZenohConfig(config_file=scouting), consumer=True) == (
        "peer, with no endpoint to connect to or listen on"
    )


def test_a_consumer_file_that_reaches_nothing_is_refused(tmp_path: Path) -> None:
    """A program's Zenoh file with no endpoint and multicast scouting off would wait for ever
    in silence (``subscribe`` did): it is refused, naming the file and the fix; a daemon's
    listens on loopback by default, and one that scouts may find peers."""
    empty = tmp_path / "empty.json5"
    empty.write_text("{}")
    with pytest.raises(ConfigError, match=r"empty\.json5: the Zenoh session would have no"):
        session_config(ZenohConfig(config_file=empty), consumer=True)
    assert session_summary(ZenohConfig(config_file=empty)).startswith(
        "peer, listening on tcp/127.0.0.1:"
    )
    res = stereod("subscribe", "--zenoh-config", str(empty), "--duration", "5")
    assert res.returncode == 78 and res.stdout == "", res
    assert res.stderr.splitlines() == [
        f"stereod: {empty}: the Zenoh session would have no endpoint to connect to or listen "
        "on, and multicast scouting is off, so it would reach no daemon: add connect: "
        '{endpoints: ["tcp/HOST:7447"]} to the file, or give --connect'
    ]
