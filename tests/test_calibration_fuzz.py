"""Fuzzing calibration files: our JSON (as a run loads it), and OpenCV FileStorage YAML/XML
(as ``calibration import`` reads it). Whatever they hold: a calibration every number of which
is usable, or one line and a sysexits code; the files never change."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from stereod.errors import StereodError
from stereod.vision.calibration import Calibration, canonical, load
from stereod.vision.calibration_io import import_opencv
from stereod.vision.geometry.rectified import CalibratedRig

from .fuzz import (
    FUZZ,
    SYSEXITS,
    accepted_or_refused,
    deep_storage,
    digest,
    json_values,
    not_killed,
)
from .processes import run_stereod

GOOD = json.loads(canonical(0.06, 60.0, 64, 48).model_dump_json())
MATRICES = ["K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"]

numbers = st.floats(allow_nan=True, allow_infinity=True) | st.integers(-(2**64), 2**64)


@st.composite
def calibrations(draw: st.DrawFn) -> dict:
    """The canonical rig's file with a few fields or matrix entries replaced."""
    cal = json.loads(json.dumps(GOOD))
    if draw(st.booleans()):
        cal["id"] = ""  # edited files are accepted without an id, so reach the number checks
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from([*GOOD, "extra"]))
        m = cal.get(key)
        if (
            key in MATRICES
            and isinstance(m, list)
            and m
            and all(isinstance(r, list) and r for r in m)
            and draw(st.booleans())
        ):
            i = draw(st.integers(0, len(m) - 1))
            j = draw(st.integers(0, len(m[i]) - 1))
            m[i][j] = draw(numbers)
        else:
            cal[key] = draw(json_values)
    return cal


def check_loaded(path: Path) -> None:
    before = digest(path)
    result = accepted_or_refused(load, path, (64, 48))
    if isinstance(result, Calibration):
        for name in MATRICES:
            assert np.all(np.isfinite(result.array(name)))
        rig = accepted_or_refused_rig(result)
        if rig is not None:
            pts = rig.rectify_left(np.array([[10.0, 20.0], [40.0, 30.0]]))
            assert pts.shape == (2, 2)
    assert digest(path) == before


def accepted_or_refused_rig(cal: Calibration) -> CalibratedRig | None:
    """The rig, or None when it refuses the geometry with a ValueError (which the daemon
    turns into a one-line CalibrationError: see stereod.daemon.params.make_rig)."""
    try:
        return CalibratedRig(cal)
    except ValueError as exc:
        assert "\n" not in str(exc)
        return None


@FUZZ
@given(cal=calibrations())
@example(cal={**GOOD, "id": "", "K1": [[0, 0, 0], [0, 0, 0], [0, 0, 1]]})
@example(cal={**GOOD, "id": "", "R": [[1, 0, 0], [0, 1, 0], [0, 0, 0]]})
@example(cal={**GOOD, "id": "", "T": [[0], [0], [0]]})
def test_calibration_json(tmp_path_factory, cal: dict) -> None:
    path = tmp_path_factory.mktemp("cal") / "c.json"
    path.write_text(json.dumps(cal))
    check_loaded(path)


@FUZZ
@given(data=st.binary(max_size=300))
def test_calibration_any_bytes(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("cal") / "c.json"
    path.write_bytes(data)
    check_loaded(path)


def yaml_matrix(name: str, rows: int, cols: int, dt: str, data: list) -> str:
    values = ", ".join(str(v) for v in data)
    return (
        f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: {dt}\n"
        f"   data: [ {values} ]\n"
    )


def xml_matrix(name: str, rows: int, cols: int, dt: str, data: list) -> str:
    values = " ".join(str(v) for v in data)
    return (
        f'<{name} type_id="opencv-matrix"><rows>{rows}</rows><cols>{cols}</cols>'
        f"<dt>{dt}</dt><data>{values}</data></{name}>\n"
    )


CANONICAL = {
    "M1": np.array(GOOD["K1"]),
    "D1": np.zeros((1, 5)),
    "M2": np.array(GOOD["K2"]),
    "D2": np.zeros((1, 5)),
    "R": np.eye(3),
    "T": np.array([[-0.06], [0.0], [0.0]]),
}
sizes = st.integers(-2, 6)
cell = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(2**70), 2**70).map(str),
    st.sampled_from([".nan", ".inf", "x", "", "1e999", "-0"]),
)


@st.composite
def storage_files(draw: st.DrawFn) -> tuple[str, str, str]:
    """An intrinsics and an extrinsics file in YAML or XML, a few matrices disturbed (shape,
    type, entries, or gone), and sometimes cut short."""
    fmt = draw(st.sampled_from(["yaml", "xml"]))
    write = yaml_matrix if fmt == "yaml" else xml_matrix
    docs = []
    for names in (("M1", "D1", "M2", "D2"), ("R", "T")):
        body = ""
        for name in names:
            m = CANONICAL[name]
            rows, cols, dt, data = m.shape[0], m.shape[1], "d", [repr(float(x)) for x in m.ravel()]
            change = draw(st.sampled_from(["none", "none", "shape", "dt", "cell", "drop"]))
            if change == "drop":
                continue
            if change == "shape":
                rows, cols = draw(sizes), draw(sizes)
            elif change == "dt":
                dt = draw(st.sampled_from(["f", "i", "u", "3d", "x", ""]))
            elif change == "cell":
                data[draw(st.integers(0, len(data) - 1))] = draw(cell)
            body += write(name, rows, cols, dt, data)
        if fmt == "yaml":
            doc = "%YAML:1.0\n---\n" + body
        else:
            doc = '<?xml version="1.0"?>\n<opencv_storage>\n' + body + "</opencv_storage>\n"
        if draw(st.booleans()) and draw(st.booleans()):
            doc = doc[: draw(st.integers(0, len(doc)))]
        docs.append(doc)
    return fmt, docs[0], docs[1]


@FUZZ
@given(files=storage_files())
def test_opencv_import(tmp_path_factory, files: tuple[str, str, str]) -> None:
    fmt, intrinsics, extrinsics = files
    d = tmp_path_factory.mktemp("cv")
    intr, extr = d / f"intrinsics.{fmt}", d / f"extrinsics.{fmt}"
    intr.write_text(intrinsics)
    extr.write_text(extrinsics)
    before = (digest(intr), digest(extr))
    result = accepted_or_refused(import_opencv, intr, extr, (64, 48))
    if isinstance(result, Calibration):
        for name in MATRICES:
            assert np.all(np.isfinite(result.array(name)))
    assert (digest(intr), digest(extr)) == before


@FUZZ
@given(data=st.binary(max_size=200), suffix=st.sampled_from([".yml", ".xml", ".json"]))
@example(data=b"hello", suffix=".yml")
@example(data=b'<?xml version="1.0"?>\n<opencv_storage>\n<M1', suffix=".xml")
def test_opencv_import_any_bytes(tmp_path_factory, data: bytes, suffix: str) -> None:
    d = tmp_path_factory.mktemp("cv")
    intr = d / f"intrinsics{suffix}"
    intr.write_bytes(data)
    (d / f"extrinsics{suffix}").write_bytes(data)
    result = accepted_or_refused(import_opencv, intr, None, (64, 48))
    assert isinstance(result, StereodError)


@settings(FUZZ, max_examples=8, deadline=None)  # whole processes: each takes about a second
@given(storage=deep_storage(), command=st.sampled_from(["import", "list"]))
@example(storage=(".yml", "%YAML:1.0\n---\nM1: " + "[" * 100_000 + "]" * 100_000), command="import")
@example(storage=(".xml", '<?xml version="1.0"?>\n' + "<a>" * 100_000), command="list")
def test_deeply_nested_storage_in_a_process(
    tmp_path_factory, storage: tuple[str, str], command: str
) -> None:
    """A FileStorage file nesting far deeper than any real one (OpenCV's parser overflowed
    its stack on it: SIGSEGV), or holding numbers of thousands of digits, as ``calibration
    import`` and ``calibrate --list`` read it: one line and a sysexits code, never a signal."""
    suffix, text = storage
    d = tmp_path_factory.mktemp("deep")
    path = d / f"intrinsics{suffix}"
    path.write_text(text)
    out = str(d / "c.json")
    if command == "import":
        argv = ["calibration", "import", str(path), "--size", "64x48", "--out", out]
    else:
        argv = ["calibrate", "--list", str(path), "--board", "9x6", "--square", "1", "--out", out]
    res = run_stereod(*argv, timeout=120, cwd=d)
    not_killed(res.returncode, res.stderr[-300:])
    assert res.returncode in SYSEXITS - {70}, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
