"""The ``stereod`` command line: a thin layer over config, drivers and the daemon."""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from . import __version__
from .errors import EX_DATAERR, ConfigError, StereodError

log = logging.getLogger("stereod")

EPILOG_KEYS = """\
keys (under --prefix, default 'stereod', and the rig name, default 'minoru'):
  stereod/<rig>/objects             one JSON message per stereo pair
  stereod/<rig>/objects/<track_id>  one track's state; DELETE when it ends
  stereod/<rig>/status              health, 1 Hz and on change
  stereod/<rig>/alive               liveliness token
  stereod/<rig>/{config,calibration,stats}  queryables
"""


def _setup_logging(level: str) -> None:
    fmt = "%(levelname)s %(name)s: %(message)s"
    if sys.stderr.isatty():
        fmt = "%(asctime)s " + fmt
    logging.basicConfig(level=os.environ.get("STEREOD_LOG_LEVEL", level), format=fmt, force=True)


def _add_zenoh_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    g.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    g.add_argument("--mode", choices=["peer", "client", "router"], help="zenoh mode (peer)")
    g.add_argument("--prefix", help="key prefix (default: stereod)")


def _add_pipeline_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("rig and detector (override the config file)")
    g.add_argument("--config", type=Path, metavar="FILE", help="TOML config file")
    g.add_argument("--rig", help="rig name used in key expressions (default: minoru)")
    g.add_argument(
        "--baseline",
        type=float,
        metavar="M",
        help="distance between the cameras, m (default 0.060, the Minoru's)",
    )
    g.add_argument(
        "--hfov",
        type=float,
        metavar="DEG",
        help="horizontal field of view of one eye, deg (default 60)",
    )
    g.add_argument(
        "--calibration",
        type=Path,
        metavar="FILE",
        help="calibration file from `stereod calibrate` (replaces --baseline/--hfov)",
    )
    g.add_argument(
        "--beta",
        type=float,
        help="background update coefficient of eq. 3, per frame (default 0.02)",
    )
    g.add_argument(
        "--threshold",
        type=float,
        metavar="GREY",
        help="difference threshold t of eq. 4, grey levels 0-255 (default 25)",
    )
    g.add_argument("--min-area", type=int, metavar="PX", help="smallest blob, px (default 30)")
    g.add_argument(
        "--warmup",
        type=int,
        metavar="FRAMES",
        help="frames averaged into the initial background (default 10)",
    )
    g.add_argument(
        "--time-base",
        type=float,
        metavar="S",
        help="time base tau of eq. 21 for velocity, s (default 0.5)",
    )
    _add_zenoh_flags(p)


def _overrides(a: argparse.Namespace) -> dict[str, Any]:
    return {
        "rig": {
            "name": a.rig,
            "baseline_m": a.baseline,
            "hfov_deg": a.hfov,
            "calibration": a.calibration,
        },
        "detector": {
            "beta": a.beta,
            "threshold": a.threshold,
            "min_area_px": a.min_area,
            "warmup_frames": a.warmup,
        },
        "tracking": {"time_base_s": a.time_base},
        "zenoh": _zenoh_overrides(a),
    }


def _zenoh_overrides(a: argparse.Namespace) -> dict[str, Any]:
    return {"connect": a.connect, "listen": a.listen, "mode": a.mode, "prefix": a.prefix}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stereod",
        description="Stereo motion daemon: finds moving objects in a stereo webcam's two views, "
        "triangulates them to 3D (m), tracks them, and publishes position, velocity (m/s), speed "
        "and heading (deg) over Zenoh.",
        epilog=EPILOG_KEYS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"stereod {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser(
        "replay",
        help="play a recording or two videos through the pipeline and publish",
        description="Play a recording directory (see `stereod synth`) or two plain video files "
        "through the full pipeline, publishing on Zenoh like the daemon. Exits 0 when the input "
        "was played in full, 65 when it was truncated or inconsistent, 66 when missing.",
        epilog=EPILOG_KEYS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("recording", nargs="?", type=Path, help="recording directory")
    v = p.add_argument_group("plain videos (instead of a recording)")
    v.add_argument("--left-video", type=Path, metavar="FILE", help="left eye video")
    v.add_argument("--right-video", type=Path, metavar="FILE", help="right eye video")
    v.add_argument("--fps", type=float, help="frame rate of both videos, Hz")
    v.add_argument(
        "--left-ts",
        type=Path,
        metavar="CSV",
        help="left capture times: header t_ns, one integer (ns) per frame",
    )
    v.add_argument("--right-ts", type=Path, metavar="CSV", help="right capture times, as --left-ts")
    p.add_argument(
        "--rate",
        type=float,
        default=1.0,
        help="playback speed: 1 real time (default), 2 twice as fast, 0 as fast as possible",
    )
    p.add_argument("--loop", action="store_true", help="start again at the end (until Ctrl-C)")
    p.add_argument(
        "--jsonl",
        type=Path,
        metavar="FILE",
        help="also write every objects message, exactly as published, one per line",
    )
    p.add_argument(
        "--wait-subscriber",
        type=float,
        default=0.0,
        metavar="S",
        help="wait up to S seconds for a subscriber on the objects key before playing",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no summary on stdout")
    _add_pipeline_flags(p)

    p = sub.add_parser(
        "run",
        help="run the daemon from a config file",
        description="Run the daemon with the driver, rig, detector and Zenoh settings of a TOML "
        "config file. Environment variables STEREOD_<SECTION>__<FIELD> override the file, flags "
        "override both. Exits 78 on a bad configuration.",
        epilog=EPILOG_KEYS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--driver", help="driver name (replay, synthetic, v4l2_minoru, ...)")
    p.add_argument(
        "--rate",
        type=float,
        default=1.0,
        help="playback speed for file drivers: 1 real time, 0 as fast as possible",
    )
    p.add_argument(
        "--check", action="store_true", help="validate the configuration, print it as JSON and exit"
    )
    _add_pipeline_flags(p)

    p = sub.add_parser(
        "subscribe",
        help="print what arrives on the bus",
        description="Subscribe to stereod keys and print each sample readably (or --json).",
    )
    p.add_argument(
        "keyexpr", nargs="?", default="stereod/**", help="key expression (default: stereod/**)"
    )
    p.add_argument("--json", action="store_true", help="raw JSON, one line per sample")
    p.add_argument("--count", type=int, metavar="N", help="exit after N samples")
    p.add_argument("--duration", type=float, metavar="S", help="exit after S seconds")
    _add_zenoh_flags(p)

    p = sub.add_parser(
        "synth",
        help="render a synthetic stereo recording with ground truth",
        description="Render spheres moving on straight lines in front of a textured wall, seen "
        "by a canonical stereo rig, into a recording directory with truth.json.",
    )
    p.add_argument("out", type=Path, help="output recording directory")
    p.add_argument(
        "--ball",
        action="append",
        metavar="SPEC",
        help="a sphere as comma-separated key=value: heading (deg), speed (m/s), "
        "x, y, z (m, position at mid-time), radius (m), vy (m/s); e.g. "
        "'heading=60,speed=0.7,z=1.8' (repeatable; default one such ball)",
    )
    p.add_argument("--size", default="640x480", metavar="WxH", help="image size, px")
    p.add_argument("--fps", type=float, default=15.0, help="frame rate, Hz (default 15)")
    p.add_argument(
        "--hfov",
        type=float,
        default=60.0,
        metavar="DEG",
        help="horizontal field of view, deg (default 60)",
    )
    p.add_argument(
        "--baseline",
        type=float,
        default=0.060,
        metavar="M",
        help="camera distance, m (default 0.060)",
    )
    p.add_argument("--duration", type=float, default=4.0, metavar="S", help="length, s (4)")
    p.add_argument(
        "--lead-in",
        type=float,
        default=1.2,
        metavar="S",
        help="seconds of empty scene before the balls appear (background warm-up)",
    )
    p.add_argument(
        "--travel",
        type=float,
        default=1.6,
        metavar="S",
        help="seconds each ball is in view, centred on its x, y, z (default 1.6)",
    )
    p.add_argument(
        "--noise",
        type=float,
        default=1.5,
        metavar="GREY",
        help="sensor noise sigma, grey levels (default 1.5)",
    )
    p.add_argument(
        "--skew-ms",
        type=float,
        default=0.0,
        metavar="MS",
        help="right eye's capture delay after the left, ms (default 0)",
    )
    p.add_argument(
        "--drift",
        type=float,
        default=0.0,
        help="lighting gain amplitude, fraction (e.g. 0.05), period 20 s",
    )
    p.add_argument("--color", action="store_true", help="BGR frames instead of grey")
    p.add_argument(
        "--codec",
        choices=["ffv1", "mjpg"],
        default="ffv1",
        help="ffv1 lossless (default) or mjpg lossy",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed for texture and noise")

    p = sub.add_parser(
        "calibrate",
        help="calibrate the stereo rig from chessboard pairs",
        description="Find a chessboard in both images of each pair, calibrate each camera, "
        "then the pair with the intrinsics fixed, then rectify (Zhang's method, OpenCV). "
        "Prints per-camera and stereo RMS, epipolar error, baseline, rectified row residual "
        "and per-pair residuals. Refuses a clearly bad result (too few pairs, RMS above "
        "--max-rms, left and right swapped) unless --force; exit 65 then.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--pairs",
        type=Path,
        metavar="DIR",
        help="folder of pairs: leftNN/rightNN images, or left/ and right/ folders",
    )
    src.add_argument(
        "--list",
        type=Path,
        metavar="FILE",
        help="list of pairs: an OpenCV imagelist (XML/YAML, left and right "
        "alternating) or text with 'LEFT RIGHT' per line",
    )
    src.add_argument(
        "--live",
        action="store_true",
        help="collect pairs from the configured driver (--config, --driver, "
        "--recording) while the board is moved in front of the rig",
    )
    p.add_argument(
        "--board",
        required=True,
        metavar="COLSxROWS",
        help="inner corners of the chessboard, e.g. 9x6",
    )
    p.add_argument(
        "--square",
        required=True,
        type=float,
        metavar="M",
        help="side of one square, m (every length of the result is in this unit)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("calibration.json"),
        metavar="FILE",
        help="calibration file to write (default calibration.json)",
    )
    p.add_argument(
        "--force", action="store_true", help="write even a calibration that fails the checks"
    )
    p.add_argument(
        "--min-pairs",
        type=int,
        default=6,
        metavar="N",
        help="fewest usable pairs accepted (default 6)",
    )
    p.add_argument(
        "--max-rms",
        type=float,
        default=1.0,
        metavar="PX",
        help="largest stereo RMS accepted, px (default 1.0)",
    )
    p.add_argument(
        "--corner-window",
        type=int,
        metavar="PX",
        help="half window of the sub-pixel corner refinement, px (default: adapted "
        "to the squares' size in the image; OpenCV's stereo_calib sample uses 11)",
    )
    live = p.add_argument_group("live collection")
    live.add_argument(
        "--wanted",
        type=int,
        default=15,
        metavar="N",
        help="pairs to collect before calibrating (default 15)",
    )
    live.add_argument("--config", type=Path, metavar="FILE", help="TOML config with the driver")
    live.add_argument("--driver", help="driver name (default from the config)")
    live.add_argument(
        "--recording",
        type=Path,
        metavar="DIR",
        help="shorthand for the replay driver on this recording",
    )

    p = sub.add_parser("calibration", help="show, export or import calibration files")
    csub = p.add_subparsers(dest="calibration_command", metavar="ACTION", required=True)
    c = csub.add_parser("show", help="print a calibration file's figures")
    c.add_argument("file", type=Path, help="calibration file")
    c = csub.add_parser("export", help="write ROS camera_info YAML (left.yaml, right.yaml)")
    c.add_argument("file", type=Path, help="calibration file")
    c.add_argument("--ros", required=True, type=Path, metavar="DIR", help="output folder")
    c = csub.add_parser(
        "import",
        help="convert OpenCV FileStorage files (stereo_calib's intrinsics.yml/extrinsics.yml)",
    )
    c.add_argument("intrinsics", type=Path, help="file with M1 D1 M2 D2")
    c.add_argument(
        "extrinsics",
        type=Path,
        nargs="?",
        help="file with R T [R1 R2 P1 P2 Q] (default: extrinsics.yml beside)",
    )
    c.add_argument(
        "--size", required=True, metavar="WxH", help="image size the calibration was made at, px"
    )
    c.add_argument(
        "--out",
        type=Path,
        default=Path("calibration.json"),
        metavar="FILE",
        help="calibration file to write (default calibration.json)",
    )

    p = sub.add_parser(
        "install-service",
        help="install the systemd units, udev rules and a default config",
        description="Write stereod.service and stereod@.service (with this stereod's path), "
        "the Minoru udev rules and /etc/stereod/stereod.toml (never overwritten), then reload "
        "udev and systemd when they are running. Then: systemctl enable --now stereod.",
    )
    p.add_argument(
        "--prefix",
        type=Path,
        default=Path("/"),
        metavar="DIR",
        help="install under DIR instead of / (packaging, tests); nothing is reloaded",
    )
    p.add_argument("--dry-run", action="store_true", help="print the steps, change nothing")
    p.add_argument(
        "--uninstall",
        action="store_true",
        help="remove the units and rules (the configuration stays)",
    )

    p = sub.add_parser(
        "devices",
        help="list video capture devices and find the Minoru's eyes",
        description="List capture nodes (sysfs, index 0) with USB ids, port path, bus speed, "
        "formats, frame sizes, frame rates and controls; mark the Minoru eyes (0ac8:3410, "
        "0ac8:3420) and which eye each is by hub port.",
    )
    p.add_argument(
        "--reset",
        choices=["left", "right"],
        metavar="EYE",
        help="USB-reset a wedged eye (left or right)",
    )
    p.add_argument("--brief", action="store_true", help="one line per device, no modes")

    p = sub.add_parser(
        "record",
        help="record what the cameras deliver, for replay",
        description="Write both eyes' frames with their capture timestamps and sequence "
        "numbers, the camera settings and the calibration in force into a recording "
        "directory (replay it with `stereod replay DIR`).",
    )
    p.add_argument("out", type=Path, help="recording directory to create")
    p.add_argument("--seconds", type=float, metavar="S", help="stop after S seconds of stream")
    p.add_argument(
        "--codec",
        choices=["ffv1", "mjpg"],
        default="ffv1",
        help="ffv1 lossless (default) or mjpg lossy",
    )
    p.add_argument("--config", type=Path, metavar="FILE", help="TOML config with the driver")
    p.add_argument("--driver", help="driver name (default from the config)")

    p = sub.add_parser("schema", help="print the JSON Schema of the wire messages")
    p.add_argument("name", nargs="?", help="one schema, e.g. stereod.objects/1 (default: all)")

    p = sub.add_parser(
        "demo",
        help="render a scene, replay it, watch it arrive over Zenoh, compare with the truth",
        description="Renders a ball crossing the default rig's view at a known heading and "
        "speed, replays it through the daemon in real time, prints positions and velocities as "
        "they arrive over Zenoh, and ends with measured against true heading and speed.",
    )
    p.add_argument("--rate", type=float, default=1.0, help="playback speed (0: fastest)")
    p.add_argument("--keep", type=Path, metavar="DIR", help="keep the rendered recording here")
    p.add_argument("--heading", type=float, default=60.0, help="true heading, deg (60)")
    p.add_argument("--speed", type=float, default=0.7, help="true speed, m/s (0.7)")
    return parser


def _cmd_replay(a: argparse.Namespace) -> int:
    from .config import load_config
    from .daemon import Daemon
    from .drivers import load_driver

    options: dict[str, Any]
    if a.recording is not None:
        if a.left_video or a.right_video:
            raise ConfigError("give a recording directory or --left-video/--right-video, not both")
        options = {"path": a.recording}
    elif a.left_video or a.right_video:
        options = {
            "left_video": a.left_video,
            "right_video": a.right_video,
            "fps": a.fps,
            "left_ts": a.left_ts,
            "right_ts": a.right_ts,
        }
        options = {k: v for k, v in options.items() if v is not None}
    else:
        raise ConfigError(
            "nothing to replay: give a recording directory or "
            "--left-video L --right-video R with --fps or --left-ts/--right-ts"
        )
    if a.loop:
        options["loop"] = True
    if a.rate < 0:
        raise ConfigError(f"--rate {a.rate}: must be >= 0 (0 plays as fast as possible)")
    ov = _overrides(a)
    ov["driver"] = {"name": "replay", "options": options}
    cfg = load_config(a.config, ov)
    _setup_logging(cfg.daemon.log_level)
    daemon = Daemon(
        cfg,
        load_driver("replay", options),
        rate=a.rate,
        jsonl=a.jsonl,
        wait_subscriber_s=a.wait_subscriber,
        reload_config=lambda: load_config(a.config, ov),
    )
    return _run_daemon(daemon, quiet=a.quiet)


def _run_daemon(daemon: Any, quiet: bool = False, problems_fail: bool = True) -> int:
    """Run until the input ends or a signal; SIGHUP reloads. With ``problems_fail`` (replay)
    a run that hit input problems exits 65 after printing them; a daemon exits 0 on a clean
    stop, its problems having gone to the log and the status key."""

    def on_signal(signum: int, _frame: Any) -> None:
        log.info("signal %d: stopping", signum)
        daemon.stop()

    def on_hup(_signum: int, _frame: Any) -> None:
        daemon.reload()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGHUP, on_hup)
    t0 = time.monotonic()
    summary = daemon.run()
    if not quiet:
        drops = ", ".join(f"{k} {v}" for k, v in summary.drops.items()) or "none"
        print(
            f"{summary.pairs} pairs from {summary.frames.get('left', 0)} left and "
            f"{summary.frames.get('right', 0)} right frames, {summary.published} messages "
            f"published, {summary.objects} object observations in "
            f"{time.monotonic() - t0:.1f} s; drops: {drops}",
            flush=True,
        )
    if summary.error is not None:
        raise summary.error
    if summary.problems and problems_fail:
        for p in summary.problems:
            print(f"stereod: {p}", file=sys.stderr)
        return EX_DATAERR
    return 0


def _cmd_run(a: argparse.Namespace) -> int:
    from .config import DEFAULT_CONFIG_PATH, load_config
    from .daemon import Daemon
    from .drivers import load_driver

    ov = _overrides(a)
    if a.driver:
        ov["driver"] = {"name": a.driver}
    path = a.config
    if path is None and DEFAULT_CONFIG_PATH.exists():
        path = DEFAULT_CONFIG_PATH
    cfg = load_config(path, ov)
    if a.check:
        print(cfg.model_dump_json(indent=2))
        return 0
    _setup_logging(cfg.daemon.log_level)
    driver = load_driver(cfg.driver.name, cfg.driver.options)
    daemon = Daemon(cfg, driver, rate=a.rate, reload_config=lambda: load_config(path, ov))
    return _run_daemon(daemon, quiet=True, problems_fail=False)


def _cmd_subscribe(a: argparse.Namespace) -> int:
    import zenoh

    from .config import ZenohConfig
    from .publish import open_session
    from .subscribe import format_sample

    try:
        zcfg = ZenohConfig(**{k: v for k, v in _zenoh_overrides(a).items() if v is not None})
    except ValueError as exc:
        raise ConfigError(f"zenoh flags: {exc}") from exc
    done = threading.Event()
    count = 0
    lock = threading.Lock()

    def on_sample(s: zenoh.Sample) -> None:
        nonlocal count
        key = str(s.key_expr)
        payload = s.payload.to_bytes()
        deleted = s.kind == zenoh.SampleKind.DELETE
        if a.json:
            line = (
                json.dumps({"key": key, "delete": True})
                if deleted
                else payload.decode("utf-8", "replace")
            )
        else:
            line = format_sample(key, payload, deleted)
        with lock:
            if done.is_set():
                return
            print(line, flush=True)
            count += 1
            if a.count is not None and count >= a.count:
                done.set()

    signal.signal(signal.SIGINT, lambda *_: done.set())
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    with open_session(zcfg) as session:
        sub = session.declare_subscriber(a.keyexpr, on_sample)
        done.wait(a.duration)
        sub.undeclare()
    return 0


def _parse_ball(spec: str) -> dict[str, Any]:
    keys = {
        "heading": "heading_deg",
        "speed": "speed_mps",
        "radius": "radius_m",
        "vy": "vy_mps",
        "brightness": "brightness",
    }
    out: dict[str, Any] = {}
    centre = [0.0, 0.1, 1.8]
    for part in filter(None, spec.split(",")):
        k, sep, v = part.partition("=")
        k = k.strip()
        if not sep:
            raise ConfigError(f"--ball {spec!r}: expected key=value, got {part!r}")
        try:
            val = float(v)
        except ValueError as exc:
            raise ConfigError(f"--ball {spec!r}: {k} = {v!r} is not a number") from exc
        if k in ("x", "y", "z"):
            centre["xyz".index(k)] = val
        elif k in keys:
            out[keys[k]] = val
        else:
            raise ConfigError(
                f"--ball {spec!r}: unknown key {k!r} (heading, speed, x, y, z, "
                "radius, vy, brightness)"
            )
    out["centre_m"] = tuple(centre)
    return out


def scene_from_args(a: argparse.Namespace) -> Any:
    """The :class:`stereod_fakes.synth.Scene` described by ``stereod synth`` flags."""
    from pydantic import ValidationError

    from stereod_fakes.synth import Scene

    try:
        w, h = (int(x) for x in a.size.lower().split("x"))
    except ValueError as exc:
        raise ConfigError(f"--size {a.size!r}: expected WIDTHxHEIGHT in px, e.g. 640x480") from exc
    if not a.lead_in + a.travel <= a.duration:
        raise ConfigError(
            f"--lead-in {a.lead_in} s + --travel {a.travel} s must fit in --duration {a.duration} s"
        )
    t_on, t_off = a.lead_in, a.lead_in + a.travel
    balls = [_parse_ball(s) for s in (a.ball or [""])]
    for b in balls:
        b.update(t_on_s=t_on, t_off_s=t_off, t_mid_s=(t_on + t_off) / 2)
    try:
        return Scene(
            width_px=w,
            height_px=h,
            fps=a.fps,
            hfov_deg=a.hfov,
            baseline_m=a.baseline,
            duration_s=a.duration,
            noise_sigma=a.noise,
            skew_s=a.skew_ms / 1e3,
            drift=a.drift,
            color=a.color,
            seed=a.seed,
            balls=balls,
        )
    except ValidationError as exc:
        e = exc.errors(include_url=False)[0]
        loc = ".".join(str(p) for p in e["loc"])
        raise ConfigError(f"synth: {loc} = {e.get('input')!r}: {e['msg']}") from exc


def _cmd_synth(a: argparse.Namespace) -> int:
    from stereod.recording import Codec
    from stereod_fakes.synth import write_scene

    scene = scene_from_args(a)
    write_scene(scene, a.out, Codec(a.codec))
    print(
        f"wrote {scene.n_frames} stereo frames ({scene.width_px}x{scene.height_px} at "
        f"{scene.fps:g} Hz) and truth.json to {a.out}"
    )
    return 0


def _cmd_schema(a: argparse.Namespace) -> int:
    from .messages import ALL_MESSAGES

    if a.name is not None:
        if a.name not in ALL_MESSAGES:
            raise ConfigError(f"schema {a.name!r}: unknown; known: {', '.join(ALL_MESSAGES)}")
        models = {a.name: ALL_MESSAGES[a.name]}
    else:
        models = ALL_MESSAGES
    out = {name: m.model_json_schema(by_alias=True) for name, m in models.items()}
    print(json.dumps(out if a.name is None else out[a.name], indent=2))
    return 0


def _cmd_demo(a: argparse.Namespace) -> int:
    from .demo import run_demo

    _setup_logging("WARNING")
    return run_demo(rate=a.rate, keep=a.keep, heading_deg=a.heading, speed_mps=a.speed)


def _size(text: str, flag: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError as exc:
        raise ConfigError(f"{flag} {text!r}: expected WIDTHxHEIGHT, e.g. 640x480") from exc
    if w <= 0 or h <= 0:
        raise ConfigError(f"{flag} {text!r}: both numbers must be positive")
    return w, h


def _cmd_calibrate(a: argparse.Namespace) -> int:
    from . import calibrate as cb
    from .calibration import Board, save

    cols, rows = _size(a.board, "--board")
    if a.square <= 0:
        raise ConfigError(f"--square {a.square}: must be > 0 (m)")
    board = Board(cols=cols, rows=rows, square=a.square)
    limits = cb.Limits(min_pairs=a.min_pairs, max_rms_px=a.max_rms)
    tty = sys.stderr.isatty()

    def progress(k: int, name: str, total: int) -> None:
        end = "\r" if tty else "\n"
        print(f"looking for the board: {k}/{total} {name}", end=end, file=sys.stderr, flush=True)

    if a.live:
        report = _calibrate_live(a, board, limits)
    else:
        pairs = cb.pairs_in_directory(a.pairs) if a.pairs else cb.pairs_from_list(a.list)
        report = cb.calibrate_files(
            pairs, board, limits, lambda k, n: progress(k, n, len(pairs)), a.corner_window
        )
        if tty:
            print(file=sys.stderr)
    print(cb.format_report(report))
    if report.problems:
        for problem in report.problems:
            print(f"stereod: calibration is clearly bad: {problem}", file=sys.stderr)
        if not a.force:
            print(
                f"stereod: not written to {a.out} (use --force to write it anyway)", file=sys.stderr
            )
            return cb.CalibrationRejected.exit_code
    save(report.calibration, a.out)
    print(f"wrote {a.out} (calibration id {report.calibration.id})")
    return 0


def _calibrate_live(a: argparse.Namespace, board: Any, limits: Any) -> Any:
    from . import calibrate as cb
    from .config import load_config
    from .drivers import load_driver
    from .frames import merged

    ov: dict[str, Any] = {}
    if a.recording is not None:
        ov["driver"] = {"name": "replay", "options": {"path": a.recording}}
    elif a.driver:
        ov["driver"] = {"name": a.driver}
    cfg = load_config(a.config, ov)
    collector = cb.LiveCollector(board)
    driver = load_driver(cfg.driver.name, cfg.driver.options)

    def progress(n: int, wanted: int) -> None:
        print(f"pairs kept: {n}/{wanted}", file=sys.stderr, flush=True)

    with driver.open() as source:
        cb.collect_live(
            merged(source.left, source.right),
            collector,
            a.wanted,
            int(cfg.pairing.tolerance_ms * 1e6),
            progress=progress,
        )
    if len(collector.kept) < a.wanted:
        print(f"the stream ended with {len(collector.kept)} of {a.wanted} pairs", file=sys.stderr)
    if collector.size is None or not collector.kept:
        raise cb.CalibrationRejected(
            f"the {board.cols}x{board.rows} board was not seen in both eyes in "
            f"{collector.seen} pairs: check --board and that the board is in view"
        )
    return cb.calibrate(
        collector.kept, board, collector.size, limits, source=f"live, {len(collector.kept)} pairs"
    )


def _cmd_calibration(a: argparse.Namespace) -> int:
    from . import calibration as cal_mod
    from .calibrate import Report, format_report

    if a.calibration_command == "show":
        cal = cal_mod.load(a.file)
        print(
            f"{a.file}: calibration {cal.id}, {cal.image_size[0]}x{cal.image_size[1]}, "
            f"made {cal.created_utc or 'at an unknown date'} ({cal.source or 'unknown source'})"
        )
        if cal.quality.pairs_used:
            print(format_report(Report(cal)).split("per pair")[0].rstrip())
        else:
            print(f"baseline |T|: {cal.baseline:.5g}")
        return 0
    if a.calibration_command == "export":
        cal = cal_mod.load(a.file)
        for path in cal_mod.export_ros(cal, a.ros):
            print(f"wrote {path}")
        return 0
    cal = cal_mod.import_opencv(a.intrinsics, a.extrinsics, _size(a.size, "--size"))
    cal_mod.save(cal, a.out)
    print(f"wrote {a.out} (calibration id {cal.id}, baseline |T| {cal.baseline:.5g})")
    return 0


def _cmd_install_service(a: argparse.Namespace) -> int:
    from .install import apply, plan

    actions = plan(a.prefix, uninstall=a.uninstall)
    for action in actions:
        print(("would " if a.dry_run else "") + action.describe())
    if not a.dry_run:
        apply(actions)
    if not actions:
        print("nothing to do")
    return 0


def _cmd_devices(a: argparse.Namespace) -> int:
    from stereod_v4l2_minoru.device import V4L2Device
    from stereod_v4l2_minoru.discovery import find_nodes
    from stereod_v4l2_minoru.usb import reset

    nodes = find_nodes()
    if a.reset:
        eyes = [n for n in nodes if n.eye == a.reset]
        if not eyes or eyes[0].usb is None or eyes[0].usb.busnum is None:
            raise StereodError(f"no Minoru {a.reset} eye found to reset")
        usb = eyes[0].usb
        assert usb.devnum is not None
        reset(usb.busnum, usb.devnum)
        print(f"reset {a.reset} eye ({eyes[0].device}, USB {usb.port_path})")
        return 0
    if not nodes:
        print("no video capture devices found")
        return 0
    for n in nodes:
        u = n.usb
        where = (
            f"USB {u.vendor}:{u.product} port {u.port_path} {u.speed_mbps:g} Mbit/s"
            if u and u.speed_mbps
            else f"USB {u.vendor}:{u.product} port {u.port_path}"
            if u
            else "not USB"
        )
        mark = f"  Minoru {n.eye} eye" if n.eye else ("  Minoru" if u and u.is_minoru else "")
        print(f"{n.device}: {n.name} ({where}){mark}")
        if a.brief:
            continue
        try:
            with V4L2Device(n.device) as dev:
                for fourcc, desc in dev.formats():
                    print(f"  {fourcc} ({desc})")
                    for w, h in dev.frame_sizes(fourcc):
                        rates = ", ".join(f"{r:g}" for r in dev.frame_rates(fourcc, w, h))
                        print(f"    {w}x{h} at {rates} fps")
                for c in dev.controls():
                    print(f"  control {c.name} [{c.minimum}..{c.maximum}] default {c.default}")
        except StereodError as exc:
            print(f"  cannot query: {exc}")
    return 0


def _cmd_record(a: argparse.Namespace) -> int:
    from .config import load_config
    from .drivers import load_driver
    from .record import record

    ov: dict[str, Any] = {"driver": {"name": a.driver}} if a.driver else {}
    cfg = load_config(a.config, ov)
    _setup_logging(cfg.daemon.log_level)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    driver = load_driver(cfg.driver.name, cfg.driver.options)
    counts = record(
        driver, a.out, seconds=a.seconds, codec=a.codec, calibration=cfg.rig.calibration, stop=stop
    )
    print(f"recorded {counts['left']} left and {counts['right']} right frames to {a.out}")
    return 0


COMMANDS = {
    "devices": _cmd_devices,
    "record": _cmd_record,
    "install-service": _cmd_install_service,
    "calibrate": _cmd_calibrate,
    "calibration": _cmd_calibration,
    "replay": _cmd_replay,
    "run": _cmd_run,
    "subscribe": _cmd_subscribe,
    "synth": _cmd_synth,
    "schema": _cmd_schema,
    "demo": _cmd_demo,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stereod`` console script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except StereodError as exc:
        print(f"stereod: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
