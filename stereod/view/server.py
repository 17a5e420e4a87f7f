"""``stereod view``'s server: a Zenoh session of its own that listens to one rig, and a small
aiohttp web server that pushes what it hears to browsers over a WebSocket.

::

    daemon --Zenoh (peer, or through a router)--> ViewHub (objects, track ends, liveliness,
                                                   status, overlay image, calibration query)
                                                     |  call_soon_threadsafe
                                                     v
    browser <--WebSocket /ws (JSON)-- aiohttp loop (its own thread) --GET /image/overlay.jpg

The page and its script are files in ``static/`` shipped with the package (no CDN, no build
step). Each WebSocket message is one JSON object with a ``type``: ``hello`` (everything a new
page needs: the daemon's liveliness, geometry, last status, each live track's recent history,
the last image), then ``objects``, ``ended``, ``alive``, ``status``, ``geometry`` and
``image`` as they happen. Images are not pushed: the page fetches ``/image/overlay.jpg`` when
told a new one arrived, so a slow browser only ever skips pictures.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import errno
import ipaddress
import json
import logging
import math
import threading
from pathlib import Path
from typing import Any

import zenoh
from aiohttp import WSMsgType, web

from stereod.bus import keys
from stereod.bus.messages import CanonicalGeometry, ObjectState, StatusMessage
from stereod.bus.publish import close_session, open_session
from stereod.client import (
    DaemonAlive,
    Event,
    Image,
    ObjectsMessage,
    QueryError,
    TrackEnded,
    query_calibration,
    subscribe_images,
    subscribe_objects,
    subscribe_status,
)
from stereod.daemon.config_zenoh import ZenohConfig
from stereod.errors import UnavailableError, UsageError, serve_hint
from stereod.vision.calibration import Calibration

log = logging.getLogger(__name__)

STATIC = Path(__file__).resolve().parent / "static"
"""The page, its script and style."""
HISTORY = 600
"""States kept per track for a page that opens late (40 s at 15 Hz)."""
TRACKS_KEPT = 30
"""Tracks (live or ended) whose history is kept."""
CLIENT_QUEUE = 512
"""Messages waiting for one browser; beyond that the oldest are dropped."""
LOCAL_NAMES = ("localhost", "127.0.0.1", "[::1]")
"""Host names a page on this machine may use, besides the address the view serves on."""


def _num(x: float | None) -> float | None:
    """A number JSON can carry: NaN and infinities become null."""
    return x if x is not None and math.isfinite(x) else None


def _vec(v: tuple[float, ...] | None) -> list[float | None] | None:
    return None if v is None else [_num(x) for x in v]


def compact(o: ObjectState) -> dict[str, Any]:
    """What the page draws of one object state (m, m/s, deg, s)."""
    return {
        "id": o.track_id,
        "state": o.state.value,
        "t": o.t_ns * 1e-9,
        "p": _vec(o.position_m),
        "v": _vec(o.velocity_mps),
        "valid": o.velocity_valid,
        "heading_valid": o.heading_valid,
        "speed": _num(o.speed_mps),
        "speed_sigma": _num(o.speed_sigma_mps),
        "heading": _num(o.heading_deg),
        "heading_sigma": _num(o.heading_sigma_deg),
        "raw": _vec(o.raw_velocity_mps),
    }


def geometry_of(reply: Calibration | CanonicalGeometry) -> dict[str, Any]:
    """The field of view (deg) and baseline (m) the map's wedge is drawn with."""
    if isinstance(reply, CanonicalGeometry):
        return {
            "geometry": "canonical",
            "hfov_deg": reply.hfov_deg,
            "baseline_m": reply.baseline_m,
        }
    p1, p2 = reply.array("P1"), reply.array("P2")
    width = reply.image_size[0]
    return {
        "geometry": "calibrated",
        "hfov_deg": math.degrees(2 * math.atan2(width / 2, float(p1[0, 0]))),
        "baseline_m": float(-p2[0, 3] / p2[0, 0]),
    }


class ViewHub:
    """What the view knows of one rig, fed by Zenoh callbacks and read by the web server.

    ``emit`` is where every update goes (set by the server to hand it to the event loop)."""

    def __init__(self, rig: str, prefix: str) -> None:
        self.rig = rig
        self.prefix = prefix
        self._lock = threading.Lock()
        self.alive: bool | None = None
        self.geometry: dict[str, Any] | None = None
        self.status: dict[str, Any] | None = None
        self.image: Image | None = None
        self._tracks: collections.OrderedDict[int, collections.deque[dict[str, Any]]] = (
            collections.OrderedDict()
        )
        self.ended: set[int] = set()
        self.emit: Any = lambda msg: None
        self.session: zenoh.Session | None = None

    # -- Zenoh side (Zenoh's threads) ----------------------------------------------------------

    def on_event(self, event: Event) -> None:
        if isinstance(event, ObjectsMessage):
            objs = [compact(o) for o in event.objects]
            with self._lock:
                for o in objs:
                    hist = self._tracks.get(o["id"])
                    if hist is None:
                        hist = self._tracks[o["id"]] = collections.deque(maxlen=HISTORY)
                        while len(self._tracks) > TRACKS_KEPT:
                            old, _ = self._tracks.popitem(last=False)
                            self.ended.discard(old)
                    hist.append(o)
            self.emit(
                {"type": "objects", "seq": event.seq, "t": event.t_ns * 1e-9, "objects": objs}
            )
        elif isinstance(event, TrackEnded):
            with self._lock:
                self.ended.add(event.track_id)
            self.emit({"type": "ended", "track_id": event.track_id})
        elif isinstance(event, DaemonAlive):
            if event.alive and self.alive is False:  # a new daemon: its ids start again
                with self._lock:
                    self._tracks.clear()
                    self.ended.clear()
            self.alive = event.alive
            self.emit({"type": "alive", "alive": event.alive})
            if event.alive:
                threading.Thread(target=self._ask_geometry, name="view-query", daemon=True).start()

    def _ask_geometry(self) -> None:
        """Ask the daemon for its geometry (off Zenoh's callback thread)."""
        if self.session is None:
            return
        try:
            reply = query_calibration(self.session, rig=self.rig, prefix=self.prefix)
        except (QueryError, zenoh.ZError) as exc:
            log.warning("view: no geometry from the daemon (%s); the map has no wedge", exc)
            return
        self.geometry = geometry_of(reply)
        self.emit({"type": "geometry", **self.geometry})

    def on_status(self, status: StatusMessage) -> None:
        self.status = status.model_dump(mode="json", by_alias=True)
        self.emit({"type": "status", "status": self.status})

    def on_image(self, image: Image) -> None:
        self.image = image
        self.emit(_image_message(image))

    # -- web side ------------------------------------------------------------------------------

    def hello(self) -> dict[str, Any]:
        """Everything a page that just connected needs."""
        with self._lock:
            tracks = {str(k): list(v) for k, v in self._tracks.items()}
            ended = sorted(self.ended)
        return {
            "type": "hello",
            "rig": self.rig,
            "alive": self.alive,
            "geometry": self.geometry,
            "status": self.status,
            "tracks": tracks,
            "ended": ended,
            "image": _image_message(self.image) if self.image is not None else None,
        }


def browser_json(msg: Any) -> str:
    """``msg`` as JSON a browser's ``JSON.parse`` reads: a number that is not finite (a NaN a
    daemon's status may carry) becomes null, where Python would write a bare ``NaN`` that
    makes the page drop the message."""
    try:
        return json.dumps(msg, allow_nan=False)
    except ValueError:
        return json.dumps(_finite(msg), allow_nan=False)


def _finite(value: Any) -> Any:
    """``value`` with every float that is not finite replaced by None, at any depth."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _host_name(host: str) -> str:
    """``host`` as it appears in a URL's authority: IPv6 in brackets, lower case."""
    host = host.strip().lower()
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def _split_authority(authority: str) -> tuple[str, int | None]:
    """``name:port`` (``[v6]:port``) as (name, port); the port is None when absent, -1 when
    it is not a number."""
    text = authority.strip().lower()
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            return text, -1
        name, rest = text[: end + 1], text[end + 1 :]
        if not rest:
            return name, None
        if not rest.startswith(":"):
            return text, -1
        port = rest[1:]
    else:
        name, colon, port = text.rpartition(":")
        if not colon:
            return text, None
    return name, int(port) if port.isdigit() else -1


def allowed_authority(authority: str, host: str, port: int) -> bool:
    """Whether ``authority`` (a Host header, or an Origin's ``name:port``) names this view:
    its own address or a localhost name, with its port (HTTP's 80 may be left out). Any other
    name is a page of some other site (DNS rebinding: a name of theirs that resolves here)."""
    name, given = _split_authority(authority)
    if (given if given is not None else 80) != port:
        return False
    if name in LOCAL_NAMES or name == _host_name(host):
        return True
    if _host_name(host) in ("0.0.0.0", "[::]"):  # every address of this machine: any literal
        with contextlib.suppress(ValueError):
            ipaddress.ip_address(name.strip("[]"))
            return True
    return False


def _image_message(image: Image) -> dict[str, Any]:
    i = image.info
    return {
        "type": "image",
        "seq": i.seq,
        "t": i.t_ns * 1e-9,
        "width": i.width,
        "height": i.height,
    }


class ViewServer:
    """The view of one rig: a Zenoh session and a web server on ``host:port`` (0: any free
    port), both run until :meth:`stop`. Use :meth:`start` (returns once the page is served)
    or as a context manager. ``port_flag`` is the flag that sets the port on the command that
    serves the page (``--port`` for ``stereod view``, ``--view-port`` for ``stereod demo``):
    the error for a port that cannot be bound names it."""

    def __init__(
        self,
        zenoh_cfg: ZenohConfig,
        *,
        rig: str = keys.DEFAULT_RIG,
        host: str = "127.0.0.1",
        port: int = 8765,
        port_flag: str = "--port",
    ) -> None:
        self.zenoh_cfg = zenoh_cfg
        self.port_flag = port_flag
        self.hub = ViewHub(rig, zenoh_cfg.prefix)
        self.host = host
        self.port = port
        self.clients = 0
        """Pages connected right now."""
        self.connected = threading.Event()
        """Set once a page has connected."""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._queues: set[asyncio.Queue[str]] = set()
        self._sockets: set[web.WebSocketResponse] = set()
        self._session: zenoh.Session | None = None
        self._subs: list[Any] = []
        self.refused = 0
        """Requests refused for their Host or Origin (another site's page)."""

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    @property
    def session(self) -> zenoh.Session | None:
        """The view's Zenoh session while it runs (for :mod:`stereod.ros.foxglove`)."""
        return self._session

    # -- life ----------------------------------------------------------------------------------

    def start(self) -> ViewServer:
        """Open the session, subscribe, serve the page; raise :class:`UnavailableError` when
        the port is in use (another program serves there), :class:`UsageError` when the
        address cannot be bound otherwise (a host that is not this machine's)."""
        self._thread = threading.Thread(target=self._serve, name="view-http", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            self._thread.join()
            err = self._error
            if isinstance(err, OSError):
                where = f"view: cannot serve on {self.host}:{self.port}: {err.strerror or err}"
                flag = self.port_flag
                if err.errno == errno.EADDRINUSE:  # taken now, maybe free later
                    raise UnavailableError(
                        f"{where} (another program serves there; pick another port with "
                        f"{flag}, or {flag} 0 for any free one)"
                    ) from err
                raise UsageError(f"{where} ({serve_hint(err, '--host', flag)})") from err
            raise err
        hub = self.hub
        try:
            session = self._session = open_session(self.zenoh_cfg, consumer=True)
        except BaseException:
            self.stop()
            raise
        hub.session = session
        rig, prefix = hub.rig, hub.prefix
        self._subs = [
            subscribe_status(session, hub.on_status, rig=rig, prefix=prefix),
            subscribe_images(session, hub.on_image, name="overlay", rig=rig, prefix=prefix),
            subscribe_objects(session, hub.on_event, rig=rig, prefix=prefix),
        ]
        log.info("view: serving %s for rig %s", self.url, hub.rig)
        return self

    def stop(self) -> None:
        """Close the pages' sockets, stop serving, close the session (idempotent)."""
        for s in self._subs:
            s.close()
        self._subs.clear()
        self.hub.session = None
        if self._session is not None:
            close_session(self._session)
            self._session = None
        loop, thread = self._loop, self._thread
        if loop is not None and thread is not None and thread.is_alive():
            loop.call_soon_threadsafe(loop.stop)
            thread.join(10)
        self._thread = None

    def __enter__(self) -> ViewServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- the event loop's thread ---------------------------------------------------------------

    def _serve(self) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop
        runner = web.AppRunner(self._app(), handle_signals=False, access_log=None)
        try:
            loop.run_until_complete(runner.setup())
            site = web.TCPSite(runner, self.host, self.port)
            loop.run_until_complete(site.start())
            self.port = int(runner.addresses[0][1])
        except BaseException as exc:  # reported by start() in the caller's thread
            self._error = exc
            loop.run_until_complete(runner.cleanup())
            loop.close()
            self._ready.set()
            return
        self.hub.emit = self._emit
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            self.hub.emit = lambda msg: None
            loop.run_until_complete(runner.cleanup())
            loop.close()

    def _emit(self, msg: dict[str, Any]) -> None:
        """Hand a message to every page (any thread)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        text = browser_json(msg)
        with contextlib.suppress(RuntimeError):  # the loop stopped meanwhile
            loop.call_soon_threadsafe(self._broadcast, text)

    def _broadcast(self, text: str) -> None:
        for q in self._queues:
            if q.full():
                q.get_nowait()
            q.put_nowait(text)

    def _app(self) -> web.Application:
        app = web.Application(middlewares=[self._same_origin])
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/image/overlay.jpg", self._overlay)
        app.router.add_static("/static/", STATIC, follow_symlinks=False)
        app.on_shutdown.append(self._close_sockets)
        return app

    @web.middleware
    async def _same_origin(self, request: web.Request, handler: Any) -> web.StreamResponse:
        """Refuse (403, so no WebSocket upgrade either) a request whose Host is not this view's
        address or a localhost name with its port, or whose Origin is another site's: a page
        from elsewhere that reaches this port through a name of its own (DNS rebinding) must
        not read the camera overlay or the tracks. The first refusal is logged."""
        host = request.headers.get("Host", "")
        origin = request.headers.get("Origin")
        ok = allowed_authority(host, self.host, self.port)
        if ok and origin is not None:
            scheme, sep, authority = origin.partition("://")
            ok = sep == "://" and scheme.lower() == "http"
            ok = ok and allowed_authority(authority, self.host, self.port)
        if not ok:
            self.refused += 1
            if self.refused == 1:
                log.warning(
                    "view: refused a request for %s with Host %r and Origin %r (a page of "
                    "another site; open %s instead); further refusals are not logged",
                    request.path,
                    host[:80],
                    (origin or "")[:80],
                    self.url,
                )
            raise web.HTTPForbidden(text="stereod view: this page is served to its own address")
        response: web.StreamResponse = await handler(request)
        return response

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def _overlay(self, request: web.Request) -> web.Response:
        image = self.hub.image
        if image is None:
            raise web.HTTPNotFound(text="no overlay image yet")
        return web.Response(
            body=image.jpeg,
            content_type="image/jpeg",
            headers={"Cache-Control": "no-store", "X-Stereod-Seq": str(image.info.seq)},
        )

    async def _ws(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=20)
        await ws.prepare(request)
        queue: asyncio.Queue[str] = asyncio.Queue(CLIENT_QUEUE)
        self._queues.add(queue)
        self._sockets.add(ws)
        self.clients += 1
        self.connected.set()
        sender = asyncio.ensure_future(self._send(ws, queue))
        try:
            await ws.send_str(browser_json(self.hub.hello()))
            async for msg in ws:  # the page sends nothing; this waits for it to go
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            sender.cancel()
            self._queues.discard(queue)
            self._sockets.discard(ws)
            self.clients -= 1
        return ws

    async def _send(self, ws: web.WebSocketResponse, queue: asyncio.Queue[str]) -> None:
        try:
            while not ws.closed:
                await ws.send_str(await queue.get())
        except (ConnectionError, RuntimeError):  # the page went away mid-send
            pass

    async def _close_sockets(self, app: web.Application) -> None:
        for ws in list(self._sockets):
            await ws.close(code=1001, message=b"stereod view stopping")
