"""What the commands share: option groups defined once, checked number types, logging setup,
and running a daemon under signals.

Numbers from the command line are checked where they are parsed: finite, in range, with the
unit in the message, so a bad flag is one line and exit 64 before anything starts.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from stereod.cli.signals import relayed
from stereod.errors import (
    EX_DATAERR,
    ConfigError,
    ReaderGone,
    StereodError,
    UsageError,
    one_line,
)
from stereod.files.bounds import BASELINE_M, HFOV_DEG, PLAYBACK_RATE, THRESHOLD_GREY, TIME_BASE_S
from stereod.files.output_file import is_stdout
from stereod.vision.detect_params import MAX_WARMUP_FRAMES, DetectorParams

log = logging.getLogger("stereod")

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")

EPILOG_KEYS = """\
keys (under --prefix, default 'stereod', and the rig name, default 'minoru'):
  stereod/<rig>/objects             one JSON message per stereo pair
  stereod/<rig>/objects/<track_id>  one track's state; DELETE when it ends
  stereod/<rig>/status              health, 1 Hz and on change
  stereod/<rig>/alive               liveliness token
  stereod/<rig>/{config,calibration,stats}  queryables
  stereod/<rig>/image/{left,right,overlay,mask}  JPEG, only while subscribed
"""


def number(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    unit: str = "",
    integer: bool = False,
) -> Callable[[str], Any]:
    """An argparse type: a finite number in [lo, hi] (lo excluded when ``lo_open``)."""

    def parse(text: str) -> float | int:
        shown = text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"
        try:
            value: float | int = int(text) if integer else float(text)
        except ValueError:  # also an integer of more than 4300 digits
            kind = "a whole number" if integer else "a number"
            raise argparse.ArgumentTypeError(f"{shown!r} is not {kind}") from None
        if isinstance(value, float) and not math.isfinite(value):  # an int always is
            raise argparse.ArgumentTypeError(f"{shown!r} must be a finite number")
        u = f" {unit}" if unit else ""
        if lo is not None and (value <= lo if lo_open else value < lo):
            rel = ">" if lo_open else ">="
            raise argparse.ArgumentTypeError(f"{shown}: must be {rel} {lo:g}{u}")
        if hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"{shown}: must be <= {hi:g}{u}")
        return value

    return parse


def path_arg(text: str) -> Path:
    """An argparse type: a path whose name is valid text (OpenCV and the log need that)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        shown = text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
        raise argparse.ArgumentTypeError(
            f"{shown!r}: the path is not valid UTF-8; rename the file or folder"
        ) from None
    return Path(text)


def file_arg(text: str) -> Path:
    """An argparse type: an output written to a file only (MCAP: binary, with an index at its
    end); ``-`` and an empty name are refused."""
    if text == "-":
        raise argparse.ArgumentTypeError(
            "- (standard output) is for --jsonl: give the file's name (or /dev/stdout to write "
            "it there all the same)"
        )
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: give a file name")
    return path_arg(text)


def output_arg(text: str) -> Path:
    """An argparse type: an output file, ``-`` for standard output (``/dev/stdout``: written
    in place, a line at a time); an empty one (which would be the folder the command runs
    in) is refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: give a file name, or - for standard output")
    return Path("/dev/stdout") if text == "-" else path_arg(text)


def recording_arg(text: str) -> Path:
    """An argparse type: a recording, named by its folder or by its manifest file
    (``rec/recording.json`` is the recording ``rec``)."""
    from stereod.sources.recording import recording_folder

    return recording_folder(path_arg(text))


def add_rate(p: argparse.ArgumentParser, help_text: str) -> None:
    p.add_argument("--rate", type=PLAYBACK_RATE.arg(), default=1.0, metavar="X", help=help_text)


def add_wait_subscriber(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument(
        "--wait-subscriber",
        type=number(0.0, 3600.0, unit="s"),
        default=0.0,
        metavar="S",
        help="wait up to S seconds for a subscriber to the objects key or the tracks' keys "
        f"(objects/*) before {what}",
    )


def add_config(p: argparse.ArgumentParser | argparse._ArgumentGroup, what: str = "") -> None:
    p.add_argument("--config", type=path_arg, metavar="FILE", help=f"TOML config file{what}")


def add_driver(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    p.add_argument("--driver", help="driver name (replay, synthetic, v4l2_minoru, ...)")


DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
"""Where ``view`` and ``subscribe`` look for a daemon when given no endpoint (``stereod demo``
listens there)."""


def endpoint_arg(text: str) -> str:
    """An argparse type: a Zenoh endpoint, checked where it is parsed (a malformed one such as
    ``tcp/[::1`` is exit 64 naming the flag, not a session waiting for ever)."""
    from stereod.bus.endpoints import check_endpoint

    try:
        return check_endpoint(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None


def add_zenoh(p: argparse.ArgumentParser, *, listens: bool = True) -> None:
    """--connect, --listen, --mode, --prefix; ``listens``: the command's session listens on
    loopback when no endpoint is given (a daemon), else nowhere (a consumer)."""
    g = p.add_argument_group("zenoh")
    g.add_argument(
        "--connect",
        action="append",
        type=endpoint_arg,
        metavar="ENDPOINT",
        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    g.add_argument(
        "--listen",
        action="append",
        type=endpoint_arg,
        metavar="ENDPOINT",
        help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable; default: "
        + (
            "the config's, else loopback only, a free port (7447 in router mode))"
            if listens
            else "none: it connects)"
        ),
    )
    g.add_argument("--mode", choices=["peer", "client", "router"], help="zenoh mode (peer)")
    g.add_argument("--prefix", help="key prefix (default: stereod)")
    if not listens:
        g.add_argument(
            "--zenoh-config",
            metavar="FILE",
            help="a Zenoh config file (JSON5: TLS certificates, mTLS) to start from, as a "
            "daemon's [zenoh] config_file; the flags above go on top of it (without "
            "--connect or --listen, the file's endpoints stand)",
        )


def add_canonical_rig(
    p: argparse.ArgumentParser | argparse._ArgumentGroup,
    *,
    defaults: bool,
    context: str = "",
    hfov_help: str = "",
) -> None:
    """``--baseline`` (m) and ``--hfov`` (deg) of a canonical rig, within their physical
    bounds (:mod:`stereod.files.bounds`). With ``defaults`` they default to the Minoru's 0.060 m
    and 60 deg; without, to None, so a config file's values stand. ``context`` opens both
    help texts."""
    p.add_argument(
        "--baseline",
        type=BASELINE_M.arg(),
        default=0.060 if defaults else None,
        metavar="M",
        help=f"{context}distance between the cameras, m (default 0.060, the Minoru's)",
    )
    p.add_argument(
        "--hfov",
        type=HFOV_DEG.arg(),
        default=60.0 if defaults else None,
        metavar="DEG",
        help=f"{context}horizontal field of view of one eye, deg (default 60){hfov_help}",
    )


def add_pipeline(p: argparse.ArgumentParser) -> None:
    """The rig, detector and tracker flags that override a config file, and the Zenoh ones."""
    g = p.add_argument_group("rig and detector (override the config file)")
    add_config(g)
    g.add_argument("--rig", help="rig name used in key expressions (default: minoru)")
    add_canonical_rig(
        g,
        defaults=False,
        hfov_help="; without a calibration, depth is only as good as this figure",
    )
    g.add_argument(
        "--calibration",
        type=path_arg,
        metavar="FILE",
        help="calibration file from `stereod calibrate` (replaces --baseline/--hfov)",
    )
    g.add_argument(
        "--beta",
        type=number(0.0, 1.0),
        help="background update coefficient of eq. 3, per frame (default 0.02)",
    )
    g.add_argument(
        "--threshold",
        type=THRESHOLD_GREY.arg(),
        metavar="GREY",
        help="difference threshold t of eq. 4, grey levels 0-255 (default 25)",
    )
    g.add_argument(
        "--min-area",
        type=number(1, 10**7, integer=True),
        metavar="PX",
        help=f"smallest blob, px (default {DetectorParams().min_area_px})",
    )
    g.add_argument(
        "--warmup",
        type=number(1, MAX_WARMUP_FRAMES, integer=True),
        metavar="FRAMES",
        help="frames that make the initial background (their median unless the config says "
        f"mean; default {DetectorParams().warmup_frames})",
    )
    g.add_argument(
        "--time-base",
        type=TIME_BASE_S.arg(),
        metavar="S",
        help="time base tau of eq. 21 for velocity, s (default 0.5)",
    )
    add_zenoh(p)


def zenoh_overrides(a: argparse.Namespace) -> dict[str, Any]:
    """The ``[zenoh]`` overrides of :func:`add_zenoh`'s flags (unset flags are None)."""
    return {
        "connect": a.connect,
        "listen": a.listen,
        "mode": a.mode,
        "prefix": a.prefix,
        "config_file": getattr(a, "zenoh_config", None),
    }


def consumer_zenoh(a: argparse.Namespace) -> dict[str, Any]:
    """A consumer's (subscribe, view) ``[zenoh]`` settings from its flags: those given, and
    :data:`DEFAULT_CONNECT` when neither an endpoint nor a Zenoh file says where to go."""
    ov = {k: v for k, v in zenoh_overrides(a).items() if v is not None}
    if not ov.get("connect") and not ov.get("listen") and "config_file" not in ov:
        ov["connect"] = [DEFAULT_CONNECT]
    return ov


def pipeline_overrides(a: argparse.Namespace) -> dict[str, Any]:
    """The config overrides of :func:`add_pipeline`'s flags (unset flags are None)."""
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
        "zenoh": zenoh_overrides(a),
    }


def load_checked(path: Path | None, overrides: dict[str, Any]) -> tuple[Any, Any]:
    """The configuration and its driver, with everything a run reads checked now: the
    config itself, the driver's options, the Zenoh config file and the calibration file. Used
    alike at start, by ``run --check`` and on every reload, so that a file that passes one
    passes all three."""
    from stereod.bus.publish import session_config
    from stereod.daemon.config import load_config

    cfg = load_config(path, overrides)
    driver = open_driver(cfg, path, overrides)
    session_config(cfg.zenoh)
    check_calibration(cfg, path, overrides, driver.frame_size())
    return cfg, driver


def open_driver(cfg: Any, path: Path | None, overrides: dict[str, Any]) -> Any:
    """The driver a configuration ``cfg`` (from ``path`` and the flags ``overrides``) names,
    with its options; a bad option's error names where that option came from (the file, its
    environment variable, a flag: then it is a usage error, exit 64). A driver named by
    ``--driver`` runs without the file's options when the file names another driver: missing
    options are then said to be the flag's, with where they go."""
    from stereod.files.config_input import origin
    from stereod.sources.drivers import load_driver

    named = origin(("driver", "name"), path, overrides)
    bare = named == "command line" and not cfg.driver.options

    def where(key: str | None) -> str:
        if bare:
            return (
                f"command line: --driver {cfg.driver.name} is given no options (a config's "
                "[driver.options] go with the [driver] name it gives)"
            )
        return origin(("driver", "options", *([key] if key else [])), path, overrides)

    try:
        return load_driver(cfg.driver.name, cfg.driver.options, origin=where, name_origin=named)
    except ConfigError as exc:
        if str(exc).startswith("command line"):  # a bad flag, exit 64
            raise UsageError(str(exc)) from exc
        raise


def check_calibration(
    cfg: Any,
    path: Path | None,
    overrides: dict[str, Any],
    frame_size: tuple[int, int] | None = None,
) -> None:
    """Read the calibration file a configuration ``cfg`` (from ``path`` and ``overrides``)
    names, if any, made for ``frame_size`` (width, height px) where the driver's options say
    it; its error says which setting named it, for the user to change. A
    calibration's own baseline and field of view stand: ``--baseline`` or ``--hfov`` beside
    one (given by the flag or by the config) is refused (they were silently ignored)."""
    from stereod.files.config_input import origin
    from stereod.vision.calibration import load as load_calibration

    if cfg.rig.calibration is None:
        return
    where = origin(("rig", "calibration"), path, overrides)
    named = "given by --calibration" if where == "command line" else f"rig.calibration in {where}"
    rig = overrides.get("rig") or {}
    refuse_rig_flags(named, cfg.rig.calibration, rig.get("baseline_m"), rig.get("hfov_deg"))
    try:
        load_calibration(cfg.rig.calibration, frame_size)
    except StereodError as exc:
        raise type(exc)(f"{exc}; it is {named}") from exc


def refuse_rig_flags(
    named: str, calibration: Path, baseline: float | None, hfov: float | None
) -> None:
    """Refuse (64) ``--baseline`` or ``--hfov`` given beside a ``calibration`` (``named``: the
    setting that gave it), whose own baseline and field of view stand."""
    for flag, value in (("--baseline", baseline), ("--hfov", hfov)):
        if value is not None:
            raise UsageError(
                f"{flag} describes the canonical rig, and the calibration {named} "
                f"({calibration}) gives its own: leave out {flag}"
            )


def run_inputs(config: Path | None, cfg: Any, driver: Any = None) -> list[Path]:
    """Every file a command that runs a configuration reads: the config file, the calibration
    and Zenoh config file it names, and the driver's files (a recording folder, videos,
    timestamp CSVs): what no output of the command may be."""
    found: list[Path | None] = [config, cfg.rig.calibration, cfg.zenoh.config_file]
    if driver is not None:
        found += driver.inputs()
    return [p for p in found if p is not None]


def quiet_third_party() -> None:
    """Silence OpenCV's and FFmpeg's own messages on stderr: every problem they report (a
    file that does not open, a truncated video) reaches the user once, in our words. Through
    the variables OpenCV reads when it loads (so a command that never needs it does not load
    it; one a user sets is kept), and through its API where it is loaded already."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
    cv2 = sys.modules.get("cv2")
    if cv2 is not None and os.environ["OPENCV_LOG_LEVEL"] == "SILENT":
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def setup_logging(level: str) -> None:
    """Configure the root logger (the entry point's job); STEREOD_LOG_LEVEL overrides. Below
    DEBUG, foxglove-sdk's server logs warnings only."""
    env = os.environ.get("STEREOD_LOG_LEVEL")
    if env is not None:
        if env.upper() not in LOG_LEVELS:
            raise ConfigError(f"STEREOD_LOG_LEVEL={env!r}: must be one of {', '.join(LOG_LEVELS)}")
        level = env.upper()
    fmt = "%(levelname)s %(name)s: %(message)s"
    if sys.stderr.isatty():
        fmt = "%(asctime)s " + fmt
    logging.basicConfig(level=level, format=fmt, force=True)
    # foxglove-sdk's server says it started on its own loopback port, behind the bridge's
    # front: at INFO a user would read that port as the one to connect to
    debug = logging.getLogger().getEffectiveLevel() <= logging.DEBUG
    logging.getLogger("foxglove.websocket.server").setLevel(
        logging.NOTSET if debug else logging.WARNING
    )


def run_daemon(
    daemon: Any,
    *,
    quiet: bool | None = False,
    problems_fail: bool = True,
    progress: Any = None,
    reloads: bool = True,
) -> int:
    """Run until the input ends or a signal; SIGHUP reloads when ``reloads`` (the daemon),
    and otherwise ends the run as SIGTERM does (a replay is a one-shot command). With
    ``problems_fail`` (replay) a run that hit input problems exits 65 after saying them in one
    line (notices, such as a reload's or a change of the whole scene, do not count); a daemon
    exits 0 on a clean stop, its problems having gone to the log and the status key, or 65
    when its input ended and was bad (a truncated recording played by the replay driver). A
    fatal error is raised after the summary (its one line is the caller's to print).
    ``progress`` (a :class:`~stereod.cli.progress.Progress`) is closed before the summary is
    printed. ``quiet`` None: the summary only for a file source (a camera's service writes
    none to its journal at every stop)."""
    if problems_fail:
        daemon.health.log_problems = False

    def on_signal(signum: int) -> None:
        log.info("signal %d: stopping", signum)
        daemon.stop()

    def on_hup(signum: int) -> None:
        if reloads:
            daemon.reload()
        else:
            on_signal(signum)

    handlers = {signal.SIGINT: on_signal, signal.SIGTERM: on_signal, signal.SIGHUP: on_hup}
    t0 = time.monotonic()
    with relayed(handlers):  # to the end: a late signal stops nothing, and kills nothing
        try:
            summary = daemon.run()
        finally:
            if progress is not None:
                progress.close()
        return _ended(daemon, summary, t0, quiet=quiet, problems_fail=problems_fail)


def _ended(daemon: Any, summary: Any, t0: float, *, quiet: bool | None, problems_fail: bool) -> int:
    """:func:`run_daemon`'s summary line and exit code once the run is over."""
    if isinstance(summary.error, ReaderGone) and summary.error.stdout:
        stdout_gone()
    if quiet is None:  # said for a file source that was opened, not for a camera
        quiet = daemon.health.live or not daemon.health.source_description
    if not quiet:
        drops = ", ".join(f"{k} {v}" for k, v in summary.drops.items()) or "none"
        say(
            f"{summary.pairs} pairs from {summary.frames.get('left', 0)} left and "
            f"{summary.frames.get('right', 0)} right frames, {summary.published} messages "
            f"published, {summary.objects} object observations in "
            f"{time.monotonic() - t0:.1f} s; drops: {drops}"
        )
    if summary.error is not None:
        raise summary.error
    failing = daemon.health.failing()
    if failing and problems_fail:
        print(f"stereod: {one_line(summarise(failing))}", file=sys.stderr)
        return EX_DATAERR
    if summary.input_problems:
        print(f"stereod: {one_line(summarise(summary.input_problems))}", file=sys.stderr)
        return EX_DATAERR
    return 0


_summaries_to_stderr = False
_stdout_gone = False


def stdout_gone() -> None:
    """The reader of an output that is stdout went away (``--jsonl /dev/stdout | head``):
    the run's summary lines are no longer wanted anywhere."""
    global _stdout_gone
    _stdout_gone = True


def summaries_off_stdout(*outputs: Path | None) -> None:
    """Print the run's summary lines (:func:`say`) on stderr when one of ``outputs`` is this
    process's stdout (``--jsonl /dev/stdout | jq``): on stdout they would land inside it."""
    global _summaries_to_stderr
    _summaries_to_stderr = any(p is not None and is_stdout(p) for p in outputs)


def say(text: str) -> None:
    """Print a line on stdout (stderr when an output is stdout, see
    :func:`summaries_off_stdout`); a reader that went away (``| head``) is not an error of
    ours, and the exit code stays that of the run."""
    if _stdout_gone:
        return
    try:
        print(text, flush=True, file=sys.stderr if _summaries_to_stderr else sys.stdout)
    except BrokenPipeError:
        stdout_to_nowhere()


def stdout_to_nowhere() -> None:
    """Point standard output's descriptor at /dev/null: it failed (a reader gone, a full
    disk), and the interpreter's own last flush would fail again, with a message of its own."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, sys.stdout.fileno())
        finally:
            os.close(null)


def summarise(problems: list[str], shown: int = 3) -> str:
    """Several problems as one line: the first ``shown`` distinct ones and how many more."""
    distinct = list(dict.fromkeys(problems))
    text = "; ".join(distinct[:shown])
    if len(distinct) > shown:
        text += f"; and {len(distinct) - shown} more"
    return text


def command_log_level(cfg: Any) -> str:
    """The log level of a command that is not the daemon (replay, record, calibrate): the
    configured one when the file or environment sets it, else WARNING, so that the command's
    own output is not buried under the daemon's INFO lines."""
    level: str = cfg.daemon.log_level
    return level if "log_level" in cfg.daemon.model_fields_set else "WARNING"


def size_arg(text: str) -> tuple[int, int]:
    """An argparse type: ``WIDTHxHEIGHT`` (or ``COLSxROWS``), two positive whole numbers."""
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected two whole numbers like 640x480"
        ) from None
    if not (0 < w <= 100_000 and 0 < h <= 100_000):
        raise argparse.ArgumentTypeError(f"{text!r}: both numbers must be in 1..100000")
    return w, h
