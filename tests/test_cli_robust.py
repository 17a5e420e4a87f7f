"""Issue #11's table, row by row: what a new user typed or a file held, run as ``stereod`` in
a subprocess. Every row ends with exactly one line on stderr, the right sysexits code, no
traceback, and every input file as it was."""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereod.cli import main
from stereod.sources.recording import Codec
from stereod.vision.calibration import canonical, save
from stereod_fakes.synth import Ball, Scene, write_scene

from .fuzz import digest
from .processes import collect, receiver, run_stereod, start_stereod

pytestmark = pytest.mark.slow

W, H = 64, 48


@dataclass
class Row:
    """One row of the table: ``argv`` (``{d}`` is the row's folder), files to make first,
    the exit code and a pattern the one stderr line must match."""

    what: str
    argv: list[str]
    code: int
    pattern: str
    setup: Callable[[Path], None] = lambda d: None
    env: dict[str, str] = field(default_factory=dict)


def recording(d: Path, name: str = "rec", codec: Codec = Codec.FFV1) -> Path:
    scene = Scene(width_px=W, height_px=H, fps=15, duration_s=1.2, balls=[Ball()])
    return write_scene(scene, d / name, codec)


def non_utf8_recording(d: Path) -> None:
    src = recording(d)
    out = Path(os.fsdecode(bytes(d) + b"/r\xff"))
    out.mkdir()
    for p in src.iterdir():
        (out / p.name).write_bytes(p.read_bytes())


def edit(path: Path, old: str, new: str) -> None:
    path.write_text(path.read_text().replace(old, new, 1))


def csv_row(d: Path, row: bytes) -> None:
    rec = recording(d)
    lines = (rec / "left.csv").read_bytes().splitlines(keepends=True)
    (rec / "left.csv").write_bytes(b"".join([*lines[:3], row, *lines[4:]]))


def calibration_pairs_with_non_utf8_names(d: Path) -> None:
    (d / "pairs").mkdir()
    img = np.zeros((H, W), np.uint8)
    for eye in (b"left", b"right"):
        _, png = cv2.imencode(".png", img)
        Path(os.fsdecode(bytes(d) + b"/pairs/" + eye + b"\xff01.png")).write_bytes(png.tobytes())


def singular_calibration(d: Path) -> None:
    recording(d)
    cal = json.loads(canonical(0.06, 60.0, W, H).model_dump_json())
    cal["K1"] = [[0, 0, 0], [0, 0, 0], [0, 0, 1]]
    cal["id"] = ""
    (d / "cal.json").write_text(json.dumps(cal))


def opencv_files(d: Path) -> None:
    """intrinsics.yml and extrinsics.yml as OpenCV's stereo_calib writes them."""
    cal = canonical(0.06, 60.0, W, H)
    for name, keys in (("intrinsics", ("M1", "D1", "M2", "D2")), ("extrinsics", ("R", "T"))):
        fs = cv2.FileStorage(str(d / f"{name}.yml"), cv2.FILE_STORAGE_WRITE)
        for key in keys:
            fs.write(key, cal.array({"M1": "K1", "M2": "K2"}.get(key, key)))
        fs.release()


def truncated(d: Path, codec: Codec = Codec.MJPG) -> None:
    rec = recording(d, "rec", codec)
    video = next(rec.glob("left.*"))
    data = video.read_bytes()
    video.write_bytes(data[: len(data) // 2])


ROWS = [
    Row(
        "--warmup beyond what the config allows",
        ["replay", "{d}/rec", "--warmup", "5000"],
        64,
        r"--warmup: 5000: must be <= 1000",
        recording,
    ),
    Row(
        "non-UTF-8 recording dir",
        ["replay", "{d}/r\udcff", "--rate", "0"],
        64,
        "not valid UTF-8",
        non_utf8_recording,
    ),
    Row(
        "non-UTF-8 --left-video",
        [
            "replay",
            "--left-video",
            "{d}/r\udcff/left.mkv",
            "--right-video",
            "{d}/rec/right.mkv",
            "--fps",
            "15",
        ],
        64,
        "not valid UTF-8",
        non_utf8_recording,
    ),
    Row(
        "non-UTF-8 synth output",
        [
            "synth",
            "{d}/out\udcff",
            "--duration",
            "0.5",
            "--size",
            "32x24",
            "--lead-in",
            "0.1",
            "--travel",
            "0.2",
        ],
        64,
        "not valid UTF-8",
    ),
    Row(
        "non-UTF-8 calibration image names",
        ["calibrate", "--pairs", "{d}/pairs", "--board", "9x6", "--square", "0.025"],
        65,
        r"left\\udcff01\.png.*not valid UTF-8",
        calibration_pairs_with_non_utf8_names,
    ),
    Row(
        "non-UTF-8 config at start",
        ["run", "--config", "{d}/c.toml"],
        78,
        "not a text file",
        lambda d: (d / "c.toml").write_bytes(b"\xff\xfe[x"),
    ),
    Row(
        "--jsonl ''",
        ["replay", "{d}/rec", "--rate", "0", "--jsonl", ""],
        64,
        "--jsonl: is empty: give a file name, or - for standard output",
        recording,
    ),
    Row(
        "fuse --jsonl ''",
        ["fuse", "--room", "{d}/room.toml", "--jsonl", " "],
        64,
        "--jsonl: is empty",
        lambda d: (d / "room.toml").write_text('[room]\nname = "lab"\n[[room.rigs]]\nname = "a"\n'),
    ),
    Row(
        "--jsonl /dev/full",
        ["replay", "{d}/rec", "--rate", "0", "--jsonl", "/dev/full"],
        73,
        "/dev/full: writing failed: No space left on device; free space on its file system, "
        "or write it elsewhere",
        recording,
    ),
    Row(
        "--fps 1e-300",
        [
            "replay",
            "--left-video",
            "{d}/rec/left.mkv",
            "--right-video",
            "{d}/rec/right.mkv",
            "--fps",
            "1e-300",
        ],
        64,
        "--fps: 1e-300: must be >= 0.01 Hz",
        recording,
    ),
    Row(
        "--jsonl kept when the input is missing",
        ["replay", "{d}/nosuch", "--jsonl", "{d}/k.jsonl"],
        66,
        "no such recording directory",
        lambda d: (d / "k.jsonl").write_text("x\n"),
    ),
    Row(
        "--jsonl is an input",
        ["replay", "{d}/rec", "--rate", "0", "--jsonl", "{d}/rec/left.csv"],
        64,
        "that is an input of this run",
        recording,
    ),
    Row(
        "timestamp above 2^63",
        ["replay", "{d}/rec", "--rate", "0"],
        65,
        r"left\.csv line 4: .* out of range",
        lambda d: csv_row(d, b"99999999999999999999,2\n"),
    ),
    Row(
        "timestamp CSV not UTF-8",
        ["replay", "{d}/rec", "--rate", "0"],
        65,
        r"left\.csv: not a text file",
        lambda d: csv_row(d, b"\xff\xfe,2\n"),
    ),
    Row(
        "config TOML not UTF-8",
        ["run", "--check", "--config", "{d}/c.toml"],
        78,
        "not a text file",
        lambda d: (d / "c.toml").write_bytes(b'[rig]\nname = "\xff"\n'),
    ),
    Row(
        "calibration import of a non-OpenCV file",
        ["calibration", "import", "{d}/in.yml", "--size", "640x480", "--out", "{d}/out.json"],
        65,
        "not an OpenCV FileStorage file",
        lambda d: (d / "in.yml").write_text("hello"),
    ),
    Row(
        "calibrate --list of truncated XML",
        ["calibrate", "--list", "{d}/l.xml", "--board", "9x6", "--square", "0.025"],
        65,
        "not a valid OpenCV FileStorage file",
        lambda d: (d / "l.xml").write_text(
            '<?xml version="1.0"?>\n<opencv_storage>\n<imagelist>\n'
        ),
    ),
    Row(
        "calibrate --list of a binary file",
        ["calibrate", "--list", "{d}/l.xml", "--board", "9x6", "--square", "0.025"],
        65,
        "not UTF-8",
        lambda d: (d / "l.xml").write_bytes(bytes(range(256))),
    ),
    Row("subscribe 'a//b'", ["subscribe", "a//b"], 64, "key expression 'a//b' is not valid"),
    Row(
        "STEREOD_ZENOH__CONNECT=foo",
        ["run", "--check", "--driver", "synthetic"],
        78,
        "STEREOD_ZENOH__CONNECT='foo'",
        env={"STEREOD_ZENOH__CONNECT": "foo"},
    ),
    Row(
        "STEREOD_LOG_LEVEL=LOUD",
        ["run", "--check", "--driver", "synthetic"],
        78,
        "STEREOD_LOG_LEVEL='LOUD'",
        env={"STEREOD_LOG_LEVEL": "LOUD"},
    ),
    Row(
        "synth --ball heading=nan",
        ["synth", "{d}/s", "--ball", "heading=nan"],
        64,
        "must be a finite number",
    ),
    Row("demo --heading nan", ["demo", "--heading", "nan"], 64, "must be a finite number"),
    Row(
        "synth --size 100000x100",
        ["synth", "{d}/s", "--size", "100000x100"],
        64,
        "width_px = 100000",
    ),
    Row(
        "synthetic width_px = 100000",
        ["run", "--config", "{d}/c.toml", "--rate", "0"],
        78,
        r"c\.toml: driver\.options\.width_px = 100000",
        lambda d: (d / "c.toml").write_text(
            '[driver]\nname = "synthetic"\n[driver.options]\nwidth_px = 100000\n'
        ),
    ),
    Row(
        "singular camera matrix",
        ["replay", "{d}/rec", "--rate", "0", "--calibration", "{d}/cal.json"],
        78,
        r"cal\.json: K1: not a camera matrix",
        singular_calibration,
    ),
    Row(
        "run --check with driver fps = -15",
        ["run", "--check", "--config", "{d}/c.toml"],
        78,
        r"c\.toml: driver\.options\.fps = -15",
        lambda d: (d / "c.toml").write_text(
            '[driver]\nname = "v4l2_minoru"\n[driver.options]\nfps = -15\n'
        ),
    ),
    Row(
        "record --seconds -1",
        ["record", "{d}/r", "--seconds", "-1", "--driver", "synthetic"],
        64,
        "--seconds: -1: must be > 0",
    ),
    Row(
        "--connect to nothing in peer mode",
        ["replay", "{d}/rec", "--rate", "0", "-q", "--connect", "tcp/127.0.0.1:1"],
        0,
        "no Zenoh peer or router reachable at tcp/127.0.0.1:1",
        recording,
    ),
    Row(
        "devices --reset with no camera",
        ["devices", "--reset", "left"],
        69,
        "no Minoru left eye found",
    ),
    Row("--rate nan", ["replay", "{d}/rec", "--rate", "nan"], 64, "'nan' must be a finite number"),
    Row(
        "--wait-subscriber -1",
        ["replay", "{d}/rec", "--wait-subscriber", "-1"],
        64,
        "must be >= 0 s",
    ),
    Row("subscribe --count -1", ["subscribe", "--count", "-1"], 64, "--count: -1: must be >= 1"),
    Row(
        "unknown STEREOD_BOGUS__X",
        ["run", "--check", "--driver", "synthetic"],
        78,
        "STEREOD_BOGUS__X: names no configuration field",
        env={"STEREOD_BOGUS__X": "1"},
    ),
    Row(
        "run --rate -1",
        ["run", "--rate", "-1", "--driver", "synthetic"],
        64,
        r"--rate: -1: must be in 0 or 0\.01\.\.1000 x real time",
    ),
    Row(
        "manifest width disagrees with the video",
        ["replay", "{d}/rec", "--rate", "0"],
        65,
        r"left\.mkv: frames are 64x48 but .* says 128x48",
        lambda d: edit(recording(d) / "recording.json", f'"width": {W}', '"width": 128'),
    ),
    Row(
        "truncated mjpg recording",
        ["replay", "{d}/rec", "--rate", "0", "-q"],
        65,
        r"left\.avi: truncated: the manifest says 18 frames, only \d+ decoded",
        truncated,
    ),
    Row(
        "bad Zenoh endpoint",
        ["replay", "{d}/rec", "--rate", "0", "--listen", "tcp/nonsense:99999"],
        64,
        r"argument --listen: 'tcp/nonsense:99999': tcp endpoints end in a port",
        recording,
    ),
    Row(
        "unclosed IPv6 endpoint on subscribe",
        ["subscribe", "--connect", "tcp/[::1", "--duration", "5"],
        64,
        r"argument --connect: 'tcp/\[::1': an IPv6 address is closed by '\]'",
    ),
    Row(
        "endpoint without a port on view",
        ["view", "--connect", "tcp/127.0.0.1", "--port", "0"],
        64,
        r"argument --connect: 'tcp/127\.0\.0\.1': tcp endpoints end in a port",
    ),
    Row(
        "endpoint of an unknown protocol",
        ["run", "--check", "--driver", "synthetic", "--listen", "tpc/127.0.0.1:7447"],
        64,
        r"argument --listen: 'tpc/127\.0\.0\.1:7447': unknown protocol 'tpc'",
    ),
    Row(
        "unclosed IPv6 endpoint in the config",
        ["run", "--check", "--driver", "synthetic", "--config", "{d}/c.toml"],
        78,
        r"zenoh\.connect\.0 = 'tcp/\[::1': an IPv6 address is closed",
        lambda d: (d / "c.toml").write_text('[zenoh]\nconnect = ["tcp/[::1"]\n'),
    ),
    Row(
        "unclosed IPv6 endpoint in the environment",
        ["run", "--check", "--driver", "synthetic"],
        78,
        r"STEREOD_ZENOH__CONNECT.*an IPv6 address is closed",
        env={"STEREOD_ZENOH__CONNECT": '["tcp/[::1"]'},
    ),
    Row(
        "bad Zenoh endpoint in the config",
        ["replay", "{d}/rec", "--rate", "0", "--config", "{d}/c.toml"],
        78,
        r"zenoh\.connect\.0 = 'foo': an endpoint is",
        lambda d: (recording(d), (d / "c.toml").write_text('[zenoh]\nconnect = ["foo"]\n')),
    ),
    Row(
        "a Zenoh config file that is not one",
        ["run", "--check", "--driver", "synthetic", "--config", "{d}/c.toml"],
        78,
        r"z\.json5: invalid Zenoh config file: unknown field `bogus`",
        lambda d: (
            (d / "z.json5").write_text("{ bogus: 1 }"),
            (d / "c.toml").write_text(f'[zenoh]\nconfig_file = "{d}/z.json5"\n'),
        ),
    ),
    Row(
        "calibration import over its own input",
        [
            "calibration",
            "import",
            "{d}/intrinsics.yml",
            "--size",
            "64x48",
            "--out",
            "{d}/intrinsics.yml",
        ],
        64,
        "--out .*intrinsics.yml: that is an input of this run",
        lambda d: opencv_files(d),
    ),
    Row(
        "replay a file of a recording",
        ["replay", "{d}/rec/left.csv"],
        66,
        r"rec/left.csv: that is a file of the recording .*rec; give the folder$",
        lambda d: recording(d),
    ),
    Row(
        "replay with a run's output as the calibration",
        ["replay", "{d}/rec", "--calibration", "{d}/run.jsonl"],
        78,
        r"run.jsonl: not valid JSON \(.*\); it is given by --calibration$",
        lambda d: (recording(d), (d / "run.jsonl").write_text('{"a": 1} {"b": 2}\n')),
    ),
    Row(
        "run --check with a config naming a missing calibration",
        ["run", "--check", "--config", "{d}/c.toml"],
        66,
        r"none.json: no such calibration file; it is rig.calibration in .*c.toml$",
        lambda d: (d / "c.toml").write_text(f'[rig]\ncalibration = "{d}/none.json"\n'),
    ),
    Row(
        "calibration export --ros to a file",
        ["calibration", "export", "{d}/cal.json", "--ros", "{d}/fig.png"],
        73,
        r"fig.png: is a file; --ros takes the folder for left.yaml and right.yaml",
        lambda d: (
            save(canonical(0.06, 60.0, W, H), d / "cal.json"),
            (d / "fig.png").write_bytes(b"png"),
        ),
    ),
    Row(
        "replay with --calibration and --hfov",
        ["replay", "{d}/rec", "--calibration", "{d}/cal.json", "--hfov", "42"],
        64,
        r"--hfov describes the canonical rig, and the calibration given by --calibration "
        r"\(.*cal.json\) gives its own: leave out --hfov$",
        lambda d: (recording(d), save(canonical(0.06, 60.0, W, H), d / "cal.json")),
    ),
    Row(
        "run --check with a config's calibration and --baseline",
        ["run", "--check", "--config", "{d}/c.toml", "--baseline", "0.2"],
        64,
        r"--baseline describes the canonical rig, and the calibration rig.calibration in "
        r".*c.toml \(.*cal.json\) gives its own",
        lambda d: (
            save(canonical(0.06, 60.0, W, H), d / "cal.json"),
            (d / "c.toml").write_text(f'[rig]\ncalibration = "{d}/cal.json"\n'),
        ),
    ),
    Row(
        "export with --calibration and --baseline",
        [
            "export",
            "{d}/rec",
            "--mcap",
            "{d}/o.mcap",
            "--calibration",
            "{d}/cal.json",
            "--baseline",
            "0.2",
        ],
        64,
        r"--baseline describes the canonical rig, and the calibration given by --calibration",
        lambda d: (recording(d), save(canonical(0.06, 60.0, W, H), d / "cal.json")),
    ),
    Row(
        "calibration export --ros with right.yaml a folder",
        ["calibration", "export", "{d}/cal.json", "--ros", "{d}/ros"],
        73,
        r"ros/right.yaml: is a directory",
        lambda d: (
            save(canonical(0.06, 60.0, W, H), d / "cal.json"),
            (d / "ros" / "right.yaml").mkdir(parents=True),
            (d / "ros" / "left.yaml").write_text("earlier\n"),
        ),
    ),
    Row(
        "calibration export over the calibration",
        ["calibration", "export", "{d}/left.yaml", "--ros", "{d}"],
        64,
        "--ros .*left.yaml: that is an input of this run",
        lambda d: save(canonical(0.06, 60.0, W, H), d / "left.yaml"),
    ),
    Row(
        "record into an existing recording",
        ["record", "{d}/rec", "--driver", "replay", "--config", "{d}/c.toml"],
        73,
        r"rec: already exists, and is a folder that is not empty; a recording goes into a new",
        lambda d: (
            recording(d),
            (d / "c.toml").write_text(f'[driver.options]\npath = "{d}/rec"\n'),
        ),
    ),
    Row(
        "synth into an existing file",
        ["synth", "{d}/run.jsonl"],
        73,
        r"run.jsonl: already exists, and is a file; a recording goes into a new folder",
        lambda d: (d / "run.jsonl").write_text("{}\n"),
    ),
]


def replay_config(d: Path) -> None:
    """A recording and a config whose replay driver reads it."""
    recording(d)
    (d / "c.toml").write_text(f'[driver]\nname = "replay"\n[driver.options]\npath = "{d}/rec"\n')


def run_jsonl(d: Path) -> None:
    """A run's JSONL under a figure's name (r.png), and a truth CSV."""
    (d / "r.png").write_text('{"schema": "stereod.objects/1"}\n')
    (d / "truth.csv").write_text("object,t_ns,x_m,y_m,z_m\nb,0,0,0,1\n")


def played(d: Path) -> None:
    """A recording and the JSONL of its replay, r.jsonl."""
    recording(d)
    res = run_stereod("replay", str(d / "rec"), "--rate", "0", "-q", "--jsonl", str(d / "r.jsonl"))
    assert res.returncode == 0, res.stderr


def deep_zenoh(d: Path) -> None:
    n = 100_000
    (d / "z.json5").write_text("{mode: " + "[" * n + "]" * n + "}")
    (d / "c.toml").write_text(f'[zenoh]\nconfig_file = "{d}/z.json5"\n')


def deep_storage(d: Path, suffix: str) -> None:
    n = 100_000
    text = {
        ".yml": "%YAML:1.0\n---\nM1: " + "[" * n + "]" * n + "\n",
        ".xml": '<?xml version="1.0"?>\n<opencv_storage>'
        + "<a>" * n
        + "</a>" * n
        + "</opencv_storage>\n",
        ".json": '{"M1": ' + "[" * n + "]" * n + "}\n",
    }[suffix]
    (d / f"intrinsics{suffix}").write_text(text)


NESTED_TOML = "a = " + "[" * 520 + "]" * 520 + "\n"

OUTPUT_IS_INPUT = [
    Row(
        "record --mcap over the replayed left video",
        ["record", "{d}/new", "--config", "{d}/c.toml", "--mcap", "{d}/rec/left.mkv"],
        64,
        r"--mcap .*rec/left\.mkv: that is an input of this run",
        replay_config,
    ),
    Row(
        "record --mcap over the replayed right CSV",
        ["record", "{d}/new", "--config", "{d}/c.toml", "--mcap", "{d}/rec/right.csv"],
        64,
        r"--mcap .*rec/right\.csv: that is an input of this run",
        replay_config,
    ),
    Row(
        "record --mcap over its config",
        ["record", "{d}/new", "--config", "{d}/c.toml", "--mcap", "{d}/c.toml"],
        64,
        r"--mcap .*c\.toml: that is an input of this run",
        replay_config,
    ),
    Row(
        "plot -o over its run",
        ["plot", "{d}/r.png", "-o", "{d}/r.png"],
        64,
        r"--out .*r\.png: that is an input of this run",
        run_jsonl,
    ),
    Row(
        "plot -o a hard link to --truth",
        ["plot", "{d}/r.png", "--truth", "{d}/truth.csv", "-o", "{d}/fig.png"],
        64,
        r"--out .*fig\.png: that is an input of this run \(.*truth\.csv\)",
        lambda d: (run_jsonl(d), os.link(d / "truth.csv", d / "fig.png")),
    ),
    Row(
        "export --mcap a symbolic link to the manifest",
        ["export", "{d}/rec", "--mcap", "{d}/link.mcap"],
        64,
        r"--mcap .*link\.mcap: that is an input of this run \(.*recording\.json\)",
        lambda d: (recording(d), (d / "link.mcap").symlink_to(d / "rec" / "recording.json")),
    ),
    Row(
        "replay --jsonl a hard link to the config",
        ["replay", "{d}/rec", "--rate", "0", "--config", "{d}/c.toml", "--jsonl", "{d}/h.jsonl"],
        64,
        r"--jsonl .*h\.jsonl: that is an input of this run \(.*c\.toml\)",
        lambda d: (replay_config(d), os.link(d / "c.toml", d / "h.jsonl")),
    ),
    Row(
        "replay --mcap over a plain video",
        [
            "replay",
            "--left-video",
            "{d}/rec/left.mkv",
            "--right-video",
            "{d}/rec/right.mkv",
            "--fps",
            "15",
            "--mcap",
            "{d}/rec/right.mkv",
        ],
        64,
        r"--mcap .*right\.mkv: that is an input of this run",
        recording,
    ),
    Row(
        "calibration import --out a hard link to the extrinsics",
        ["calibration", "import", "{d}/intrinsics.yml", "--size", "64x48", "--out", "{d}/c.json"],
        64,
        r"--out .*c\.json: that is an input of this run \(.*extrinsics\.yml\)",
        lambda d: (opencv_files(d), os.link(d / "extrinsics.yml", d / "c.json")),
    ),
]

PARSERS_BOUNDED = [
    Row(
        "Zenoh config file nested 100000 deep",
        ["run", "--check", "--config", "{d}/c.toml"],
        78,
        r"z\.json5 \(zenoh\.config_file\): nested deeper than 64 levels",
        deep_zenoh,
    ),
    Row(
        "config TOML nested 520 deep",
        ["run", "--check", "--config", "{d}/c.toml"],
        78,
        r"c\.toml: nested deeper than 64 levels",
        lambda d: (d / "c.toml").write_text(NESTED_TOML),
    ),
    Row(
        "config TOML dotted keys 520 deep",
        ["run", "--check", "--config", "{d}/c.toml"],
        78,
        r"c\.toml: nested deeper than 64 levels",
        lambda d: (d / "c.toml").write_text("[driver.options]\n" + "a." * 520 + "b = 1\n"),
    ),
    Row(
        "environment JSON nested 520 deep",
        ["run", "--check"],
        78,
        r"environment variable STEREOD_ZENOH__CONNECT: nested deeper than 64 levels",
        env={"STEREOD_ZENOH__CONNECT": "[" * 520 + "]" * 520},
    ),
    Row(
        "number of 5000 digits in the config",
        ["run", "--check", "--config", "{d}/c.toml"],
        78,
        r"c\.toml: holds a number of more than 1000 digits",
        lambda d: (d / "c.toml").write_text("[detector]\nbeta = " + "9" * 5000 + "\n"),
    ),
    *[
        Row(
            f"calibration import of a FileStorage {suffix} nested 100000 deep",
            [
                "calibration",
                "import",
                f"{{d}}/intrinsics{suffix}",
                "--size",
                "64x48",
                "--out",
                "{d}/c.json",
            ],
            65,
            rf"intrinsics\{suffix}: nested deeper than 64 levels",
            lambda d, suffix=suffix: deep_storage(d, suffix),
        )
        for suffix in (".yml", ".xml", ".json")
    ],
    Row(
        "calibrate --list of a FileStorage nested 100000 deep",
        ["calibrate", "--list", "{d}/intrinsics.yml", "--board", "9x6", "--square", "1"],
        65,
        r"intrinsics\.yml: nested deeper than 64 levels",
        lambda d: deep_storage(d, ".yml"),
    ),
    Row(
        "plot --truth of 1e308",
        ["plot", "{d}/r.jsonl", "--truth", "{d}/t.csv", "-o", "{d}/fig.png"],
        65,
        r"t\.csv:2: x_m = 1e\+308 is out of range",
        lambda d: (
            played(d),
            (d / "t.csv").write_text("object,t_ns,x_m,y_m,z_m\nb,0,1e308,1e308,1\n"),
        ),
    ),
]

NOT_UTF8_ARGUMENTS = [
    Row(
        "subscribe key expression not UTF-8",
        ["subscribe", "stereod/\udcff"],
        64,
        r"stereod subscribe: keyexpr stereod/\\udcff: not valid UTF-8",
    ),
    Row(
        "plot --title not UTF-8",
        ["plot", "{d}/r.png", "-o", "{d}/fig.png", "--title", "caf\udce9"],
        64,
        r"stereod plot: --title caf\\udce9: not valid UTF-8",
        run_jsonl,
    ),
    Row(
        "view --host not UTF-8",
        ["view", "--host", "\udcff"],
        64,
        r"stereod view: --host \\udcff: not valid UTF-8",
    ),
]

MINOR = [
    Row(
        "missing Zenoh config file",
        ["run", "--check", "--config", "{d}/c.toml"],
        66,
        r"nosuch\.json5: cannot read the Zenoh config file: no such file \(zenoh\.config_file\)",
        lambda d: (d / "c.toml").write_text(f'[zenoh]\nconfig_file = "{d}/nosuch.json5"\n'),
    ),
    Row(
        'manifest "color": "yes"',
        ["replay", "{d}/rec", "--rate", "0"],
        65,
        r"rec/recording\.json: color = 'yes': must be true or false",
        lambda d: (
            recording(d),
            edit(d / "rec" / "recording.json", '"color": false', '"color": "yes"'),
        ),
    ),
]

ROWS += OUTPUT_IS_INPUT + PARSERS_BOUNDED + NOT_UTF8_ARGUMENTS + MINOR


def files_in(d: Path) -> dict[Path, str]:
    return {p: digest(p) for p in d.rglob("*") if p.is_file()}


@pytest.mark.parametrize("row", ROWS, ids=[r.what for r in ROWS])
def test_row(row: Row, tmp_path: Path) -> None:
    row.setup(tmp_path)
    inputs = files_in(tmp_path)
    argv = [a.replace("{d}", str(tmp_path)) for a in row.argv]
    res = run_stereod(*argv, timeout=120, env=row.env, cwd=tmp_path)
    lines = res.stderr.splitlines()
    assert res.returncode == row.code, (res.returncode, res.stderr)
    assert "Traceback" not in res.stderr, res.stderr
    assert len(lines) == 1, f"{len(lines)} lines on stderr:\n{res.stderr}"
    assert re.search(row.pattern, lines[0]), lines[0]
    # Short apart from the paths it names (the test's folder is longer under a parallel run).
    short = lines[0].replace(str(tmp_path), "D")
    assert len(short) < 300, f"{len(short)} characters without the folder's path"
    assert ".rs:" not in lines[0] and "/root/.cargo" not in lines[0]
    assert {p: h for p, h in files_in(tmp_path).items() if p in inputs} == inputs, (
        "an input changed"
    )


def test_intact_mjpg_recording_plays_without_a_word(tmp_path: Path) -> None:
    rec = recording(tmp_path, "rec", Codec.MJPG)
    res = run_stereod("replay", str(rec), "--rate", "0", "-q", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr


def test_truncated_recording_is_said_once_with_loop(tmp_path: Path) -> None:
    truncated(tmp_path)
    jsonl = tmp_path / "out.jsonl"
    proc = start_stereod(
        "replay",
        str(tmp_path / "rec"),
        "--rate",
        "0",
        "-q",
        "--loop",
        "--jsonl",
        str(jsonl),
        cwd=tmp_path,
    )
    deadline = time.monotonic() + 60
    # The messages of the run so far are in the JSONL's temporary file; three laps, then stop.
    while time.monotonic() < deadline:
        part = list(tmp_path.glob(".out.jsonl.*.part"))
        if part and part[0].read_bytes().count(b"\n") >= 3 * 9:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 65, err
    assert len(err.splitlines()) == 1 and err.count("truncated:") == 1, err
    assert json.loads(jsonl.read_text().splitlines()[-1])["seq"] >= 3 * 9 - 1


def test_an_unexpected_exception_is_one_line_naming_its_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The last guard: a bug anywhere in a command is one line, exit 70, the traceback in a
    file the line names."""
    import stereod.cli.schema

    def bug(_args: object) -> int:
        return {}["missing"]  # a KeyError, as a bug would raise

    monkeypatch.setenv("STEREOD_CRASH_DIR", str(tmp_path))
    monkeypatch.setattr(stereod.cli.schema, "run", bug)
    assert main(["schema"]) == 70
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("stereod: internal error: KeyError"), lines
    log = re.search(r"details in (\S+);", lines[0])
    assert log and Path(log.group(1)).parent == tmp_path
    assert "Traceback" in Path(log.group(1)).read_text()


def test_a_full_disk_on_stdout_stops_subscribe_with_74(tmp_path: Path, endpoint: str) -> None:
    """As for every command: one line, exit 74 (it was 73, the code of an output that cannot
    be created)."""
    recording(tmp_path)
    with open("/dev/full", "w") as full:
        sub = start_stereod(
            "subscribe", "--listen", endpoint, "--duration", "60", stdout=full, cwd=tmp_path
        )
        time.sleep(1.0)  # its session listens
        pub = run_stereod(
            "replay", str(tmp_path / "rec"), "--rate", "0", "-q", "--connect", endpoint
        )
        assert pub.returncode == 0, pub.stderr
        _, err = sub.communicate(timeout=60)
    assert sub.returncode == 74, err
    assert err.splitlines() == ["stereod: cannot write to standard output: No space left on device"]


@pytest.mark.parametrize("jsonl", ["-", "/dev/stdout"])
def test_a_full_disk_on_stdout_given_as_the_jsonl_is_74_too(tmp_path: Path, jsonl: str) -> None:
    """``--jsonl -`` (or ``/dev/stdout``) into a full disk is standard output failing, as
    for every command: one line, 74 (it was 73, the code of an output file that cannot be
    created)."""
    recording(tmp_path)
    with open("/dev/full", "w") as full:
        proc = start_stereod(
            "replay", str(tmp_path / "rec"), "--rate", "0", "-q", "--jsonl", jsonl, stdout=full
        )
        _, err = proc.communicate(timeout=120)
    assert proc.returncode == 74, err
    assert err.splitlines() == ["stereod: cannot write to standard output: No space left on device"]


def test_a_frozen_peer_does_not_make_subscribe_fail_on_its_way_out(
    listener: object, endpoint: str
) -> None:
    """Another subscriber on the bus is stopped (SIGSTOP) and never answers again: closing a
    session then times out in Zenoh (after about ten seconds), yet ``subscribe`` got what it
    asked for, so it says so in one line and exits 0, not as an internal error (70)."""
    frozen = start_stereod("subscribe", "stereod/**", "--connect", endpoint, "--duration", "120")
    try:
        time.sleep(1.5)  # it joins the bus
        frozen.send_signal(signal.SIGSTOP)
        stop = threading.Event()

        def put() -> None:
            while not stop.wait(0.1):
                listener.put("stereod/frozen/status", b"{}")  # type: ignore[attr-defined]

        threading.Thread(target=put, daemon=True).start()
        try:
            got = run_stereod(
                "subscribe", "stereod/frozen/status", "--connect", endpoint, "--count", "1"
            )
        finally:
            stop.set()
    finally:
        frozen.send_signal(signal.SIGCONT)
        frozen.kill()
        frozen.communicate(timeout=30)
    assert got.returncode == 0, got.stderr
    assert got.stdout.startswith("stereod/frozen/status:")
    assert "internal error" not in got.stderr


def test_subscribe_to_an_endpoint_nothing_answers_on_says_so(endpoint: str) -> None:
    """Silence from a wrong address looks like an idle rig: it is said once, on stderr."""
    got = run_stereod("subscribe", "--connect", endpoint, "--duration", "1")
    assert got.returncode == 0, got.stderr
    assert got.stdout == ""
    assert f"no Zenoh peer or router answers at {endpoint}" in got.stderr
    assert got.stderr.count("\n") == 1


def test_eyes_whose_clocks_disagree_by_seconds_say_why_nothing_paired(tmp_path: Path) -> None:
    """The right eye's timestamp file 10 s ahead of the left's: no frame finds a partner,
    and rather than a run that merely counts drops, it fails (65) saying how far apart the
    eyes' last frames were."""
    rec = recording(tmp_path)
    rows = (rec / "right.csv").read_text().splitlines()
    shifted = [rows[0]] + [
        f"{int(t) + 10_000_000_000},{rest}" for t, rest in (r.split(",", 1) for r in rows[1:])
    ]
    (tmp_path / "right10.csv").write_text("\n".join(shifted) + "\n")
    got = run_stereod(
        "replay",
        *("--left-video", str(rec / "left.mkv"), "--right-video", str(rec / "right.mkv")),
        *("--left-ts", str(rec / "left.csv"), "--right-ts", str(tmp_path / "right10.csv")),
        *("--rate", "0", "-q"),
    )
    assert got.returncode == 65, got.stderr
    assert "no pairs: no frame had a partner of the other eye within" in got.stderr
    assert "last frames were 10 s apart" in got.stderr


def test_a_replay_under_a_rig_name_already_on_the_bus_is_refused(
    tmp_path: Path, endpoint: str
) -> None:
    """A replay connected to a bus where a daemon already publishes its rig name would mix its
    messages into that rig's: it is refused before it plays (78), its outputs untouched."""
    from stereod.daemon.config import load_config
    from stereod.daemon.daemon import Daemon
    from stereod_fakes.synth import SyntheticDriver

    rec = recording(tmp_path)
    out = tmp_path / "run.jsonl"
    out.write_text("kept\n")
    cfg = load_config(overrides={"zenoh": {"listen": [endpoint]}})
    live = Daemon(cfg, SyntheticDriver({"duration_s": 30.0, "fps": 15, "live": True}))
    thread = threading.Thread(target=live.run)
    thread.start()
    try:
        deadline = time.monotonic() + 20
        while live.health.state.value != "running" and time.monotonic() < deadline:
            time.sleep(0.05)
        got = run_stereod(
            "replay", str(rec), "--rate", "0", "-q", "--connect", endpoint, "--jsonl", str(out)
        )
    finally:
        live.stop()
        thread.join(15)
    assert got.returncode == 78, got.stderr
    assert "another stereod already publishes rig 'minoru'" in got.stderr
    assert "--rig NAME" in got.stderr
    assert out.read_text() == "kept\n"


def _handles(pid: int, sig: int) -> bool:
    """Whether process ``pid`` ignores or catches ``sig`` now (/proc/PID/status)."""
    try:
        fields = dict(
            line.split(":\t", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
        )
    except (OSError, ValueError):
        return False
    bit = 1 << (sig - 1)
    return bool((int(fields["SigIgn"], 16) | int(fields["SigCgt"], 16)) & bit)


def _queued(fd: int) -> int:
    """Bytes waiting in the pipe read by ``fd``."""
    import fcntl
    import struct
    import termios

    return int(struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0" * 4))[0])


def test_a_daemon_asked_to_reload_while_it_starts_keeps_starting(tmp_path: Path) -> None:
    """``systemctl reload`` (SIGHUP) in the first instant of ``stereod run``, while Python
    still imports NumPy, OpenCV and Zenoh, where its default would end the process: the
    daemon lives on, and stops cleanly when told to."""
    cfg = tmp_path / "live.toml"
    cfg.write_text(
        '[driver]\nname = "synthetic"\n[driver.options]\n'
        "width_px = 160\nheight_px = 120\nlive = true\nloop = true\n"
    )
    sock, address = receiver(tmp_path)
    proc = start_stereod("run", "--config", str(cfg), cwd=tmp_path, env={"NOTIFY_SOCKET": address})
    try:
        # As soon as the entry point has set SIGHUP aside (its first statement, long before
        # the imports are done); before that the interpreter itself is starting, a moment
        # systemd never reloads in (it waits for READY=1), and on a busy machine 0.1 s after
        # the start can fall within it.
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not _handles(proc.pid, signal.SIGHUP):
            time.sleep(0.005)
        proc.send_signal(signal.SIGHUP)
        # Stopped only once it says it is running, as systemd would: Ctrl-C while it still
        # starts is an interrupted start (130), however long a loaded host takes to get there.
        started = collect(sock, "READY=1", 120)
        assert "READY=1" in started, (started, proc.poll())
        assert proc.poll() is None, proc.communicate()[1]
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
        sock.close()
    assert proc.returncode == 0, err
    assert "Traceback" not in err


def test_ctrl_c_ends_a_replay_whose_pipe_reader_stopped_reading(tmp_path: Path) -> None:
    """The JSONL goes into a named pipe whose reader reads nothing: the pipe fills and the
    writer waits, as it should. Ctrl-C still ends the run within a few seconds (the reader
    then counts as gone), where it used to wait for that reader for good."""
    import fcntl

    rec = recording(tmp_path)
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        fcntl.fcntl(reader, fcntl.F_SETPIPE_SZ, 4096)  # full after a few messages
        proc = start_stereod(
            "replay", str(rec), "--rate", "0", "-q", "--jsonl", str(fifo), cwd=tmp_path
        )
        # Once the replay takes Ctrl-C itself and has written into the pipe, which then
        # stays as it is (full: the writer waits on it; the replay has ended its frames).
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
            _queued(reader) and _handles(proc.pid, signal.SIGINT)
        ):
            time.sleep(0.02)
        queued = _queued(reader)
        time.sleep(1.0)
        assert proc.poll() is None and _queued(reader) == queued > 0
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=20)
        finally:
            proc.kill()
        assert proc.returncode == 130, err
        assert "interrupted by SIGINT" in err, err
    finally:
        os.close(reader)


@pytest.mark.parametrize("rate", ["0", "1"])
def test_a_timestamp_file_that_jumps_is_played_on_and_said(tmp_path: Path, rate: str) -> None:
    """The left eye's timestamps jump 11.6 days ahead from its tenth frame on (still in order,
    so the file is valid on its own): in real time the replay does not sleep through the jump,
    and since the eyes then never pair again, the run exits 65 saying so."""
    rec = recording(tmp_path)
    csv = rec / "left.csv"
    head, *rows = csv.read_text().splitlines()
    for k in range(10, len(rows)):
        t, rest = rows[k].split(",", 1)
        rows[k] = f"{int(t) + 10**15},{rest}"
    csv.write_text("\n".join([head, *rows]) + "\n")
    t0 = time.monotonic()
    res = run_stereod("replay", str(rec), "--rate", rate, "-q", cwd=tmp_path, timeout=60)
    assert time.monotonic() - t0 < 30
    assert res.returncode == 65, res.stderr
    assert "found no partner of the other eye" in res.stderr, res.stderr
