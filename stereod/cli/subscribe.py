"""``stereod subscribe``: print what arrives on the bus, readably or as raw JSON."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING

from stereod.cli.common import DEFAULT_CONNECT, add_zenoh, consumer_zenoh, number
from stereod.cli.interrupt import wait_until
from stereod.cli.signals import relayed
from stereod.errors import UsageError, describe_validation_error

if TYPE_CHECKING:
    import zenoh


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "subscribe",
        help="print what arrives on the bus",
        description="Subscribe to stereod keys and print each sample readably (or --json). "
        f"Without --connect, --listen or --zenoh-config it connects to {DEFAULT_CONNECT} "
        "(where `stereod demo` listens; give a daemon `[zenoh] listen` or `--listen` to reach "
        "it there).",
    )
    p.add_argument(
        "keyexpr", nargs="?", default="stereod/**", help="key expression (default: stereod/**)"
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="raw JSON, one line per sample (a sample that is no JSON, such as an image, as "
        '{"key", "bytes", "encoding"}; a DELETE as {"key", "delete": true})',
    )
    p.add_argument(
        "--count", type=number(1, 10**12, integer=True), metavar="N", help="exit after N samples"
    )
    p.add_argument(
        "--duration",
        type=number(0.0, 10**9, lo_open=True, unit="s"),
        metavar="S",
        help="exit after S seconds",
    )
    add_zenoh(p, listens=False)
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    import zenoh
    from pydantic import ValidationError

    from stereod.bus.publish import opened_session, reachable
    from stereod.bus.subscribe import format_sample, json_line
    from stereod.daemon.config_zenoh import ZenohConfig

    ov = consumer_zenoh(a)
    try:
        zcfg = ZenohConfig(**ov)
    except ValidationError as exc:
        raise UsageError(f"zenoh flags: {describe_validation_error(exc)}") from exc
    try:
        key = zenoh.KeyExpr(a.keyexpr)
    except zenoh.ZError as exc:
        raise UsageError(
            f"key expression {a.keyexpr!r} is not valid (no empty chunks, e.g. 'stereod/**')"
        ) from exc
    done = threading.Event()
    count = 0
    lock = threading.Lock()
    failed: list[OSError] = []

    def on_sample(s: zenoh.Sample) -> None:
        nonlocal count
        key = str(s.key_expr)
        payload = s.payload.to_bytes()
        deleted = s.kind == zenoh.SampleKind.DELETE
        if a.json:
            line = json_line(key, payload, deleted, str(s.encoding))
        else:
            line = format_sample(key, payload, deleted)
        with lock:
            if done.is_set():
                return
            try:
                print(line, flush=True)
            except OSError as exc:  # a full disk, a reader gone: stop, and say so at the end
                failed.append(exc)
                done.set()
                return
            count += 1
            if a.count is not None and count >= a.count:
                done.set()

    def on_signal(_signum: int) -> None:
        done.set()

    stopping = relayed(dict.fromkeys((signal.SIGINT, signal.SIGTERM), on_signal))
    with stopping, opened_session(zcfg, consumer=True) as session:
        sub = session.declare_subscriber(key, on_sample)
        start = time.monotonic()
        if zcfg.connect and not reachable(session, min(1.0, a.duration or 1.0)):
            print(
                f"stereod: no Zenoh peer or router answers at {', '.join(zcfg.connect)} "
                "(is the daemon running there?); listening anyway",
                file=sys.stderr,
                flush=True,
            )
        wait_until(done, None if a.duration is None else a.duration - (time.monotonic() - start))
        sub.undeclare()
    if failed:  # a reader that had enough (`| head`, exit 0), or a full disk (exit 74)
        raise failed[0]
    return 0
