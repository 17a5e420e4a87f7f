"""The calibration file: validation, ids, ROS export and OpenCV import round trips."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from stereod.errors import CalibrationError, MissingInputError, OutputError
from stereod.vision.calibrate import calibrate_files, format_report, pairs_from_list
from stereod.vision.calibration import (
    Board,
    Calibration,
    from_arrays,
    load,
    save,
)
from stereod.vision.calibration_io import export_ros, import_opencv
from stereod.vision.geometry.rectified import CalibratedRig
from stereod_fakes.rig import minoru_like

from .conftest import shared_data, stereod


def a_calibration() -> Calibration:
    cal: Calibration = minoru_like().calibration()
    return cal


def test_save_load_round_trip_and_id(tmp_path: Path) -> None:
    cal = a_calibration()
    path = tmp_path / "c.json"
    save(cal, path)
    back = load(path, (640, 480))
    assert back == cal and back.id == cal.content_id() and len(cal.id) == 16
    # As the config and room files, one saved by an editor with a byte-order mark reads the same
    # (it was "not valid JSON ... column 1").
    marked = tmp_path / "bom.json"
    marked.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert load(marked, (640, 480)) == cal
    other = from_arrays(
        (640, 480),
        {**{k: cal.array(k) for k in ("K1", "D1", "K2", "D2", "R")}, "T": cal.array("T") * 1.001},
    )
    assert other.id != cal.id


def _turned(deg: float) -> np.ndarray:
    """A rotation of ``deg`` about the y axis."""
    return cv2.Rodrigues(np.array([0.0, np.radians(deg), 0.0]))[0]


@pytest.mark.parametrize(
    ("edit", "said"),
    [
        (lambda c: {"P2": (c.array("P2") * [[1.05], [1], [1]]).tolist()}, "P1 and P2 have fx"),
        (lambda c: {"R1": (_turned(5.0) @ c.array("R1")).tolist()}, "R2 R differs from R1"),
        (lambda c: {"T": (-c.array("T")).tolist()}, r"P2\[0\]\[3\] = .* has the other sign"),
    ],
    ids=["P2 focal 5 % off", "R1 turned 5 deg", "T flipped"],
)
def test_a_file_edited_by_hand_must_still_be_one_rig(tmp_path: Path, edit, said: str) -> None:
    """A file whose id was removed (to accept an edit) loaded whatever its numbers: P2's
    focal length 5 % off P1's put a point 41 cm off, R1 turned 5 deg 1.39 m off. Its
    rectification must fit its R and T, with the right eye at +x."""
    cal = a_calibration()
    edited = cal.model_copy(update={**edit(cal), "id": ""})
    path = tmp_path / "edited.json"
    path.write_text(edited.model_dump_json())
    with pytest.raises(
        CalibrationError, match=rf"edited.json: its numbers are not one rig's \({said}"
    ):
        load(path, (640, 480))
    path.write_text(cal.model_copy(update={"id": ""}).model_dump_json())
    assert load(path, (640, 480)).id == cal.id  # unedited, it loads as it was


def test_a_vector_written_flat_is_read_as_the_column_or_row_it_stands_for(
    tmp_path: Path,
) -> None:
    """``"T": [x, y, z]`` and ``"D1": [k1, k2, p1, p2, k3]``, as a hand or another tool writes
    them: the same calibration as the stored 3x1 and 1x5 (its id checks out); a flat vector
    of the wrong length still names the shape wanted."""
    cal = a_calibration()
    data = json.loads(cal.model_dump_json())
    data["T"] = [row[0] for row in data["T"]]
    data["D1"], data["D2"] = data["D1"][0], data["D2"][0]
    path = tmp_path / "c.json"
    path.write_text(json.dumps(data))
    assert load(path) == cal
    data["T"] = data["T"][:2]
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationError, match=r"T: must be 3x1, got shape \(2, 1\)"):
        load(path)


@pytest.mark.parametrize(
    ("d1", "said"),
    [
        ([1e8, 0, 0, 0, 0], r"makes the horizontal field of view 0\.\d+ deg: it must be in 5"),
        ([-0.6, 0, 0, 0, 0], r"cannot be undone over the image: the point 0, 240 px comes back"),
    ],
    ids=["k1 1e8", "k1 -0.6 folds"],
)
def test_a_lens_distortion_no_lens_has_is_refused(tmp_path: Path, d1: list, said: str) -> None:
    """A distortion coefficient of 1e8 (a typing slip) loaded, its camera seeing 0.2 deg of
    the scene; k1 = -0.6 at this focal length folds the image before its sides, so no ray
    reaches them. Each is refused naming D1, hand-edited (no id) or not; the rig's own
    distortion, and none, load."""
    cal = a_calibration()
    path = tmp_path / "lens.json"
    for d in ([0.0] * 5, cal.array("D1").ravel().tolist()):
        path.write_text(cal.model_copy(update={"D1": [d], "id": ""}).model_dump_json())
        load(path, (640, 480))
    path.write_text(cal.model_copy(update={"D1": [d1], "id": ""}).model_dump_json())
    with pytest.raises(CalibrationError, match=rf"lens.json: D1: lens distortion .*{said}"):
        load(path, (640, 480))
    with pytest.raises(CalibrationError, match=rf"calibration: D1: lens distortion .*{said}"):
        from_arrays(
            (640, 480),
            {**{k: cal.array(k) for k in ("K1", "K2", "D2", "R", "T")}, "D1": np.array(d1, float)},
        )


@pytest.mark.parametrize(
    ("edit", "pattern"),
    [
        (lambda d: d.pop("K1"), r"K1: required field is missing"),
        (lambda d: d.update(K1=[[1, 0], [0, 1]]), r"K1: must be 3x3, got shape \(2, 2\)"),
        (lambda d: d["T"].__setitem__(0, ["NaN"]), r"T: contains a non-finite number"),
        (lambda d: d.update(image_size=[0, 480]), r"image_size: 0x480: each side must be in 16"),
        (lambda d: d["D1"][0].__setitem__(0, 0.5), r"field id: .* does not match the numbers"),
    ],
)
def test_bad_files_name_the_field(tmp_path: Path, edit, pattern: str) -> None:
    data = json.loads(a_calibration().model_dump_json())
    edit(data)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(data).replace('"NaN"', "NaN"))
    with pytest.raises(CalibrationError, match=pattern) as err:
        load(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_size_mismatch_and_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    save(a_calibration(), path)
    with pytest.raises(CalibrationError, match="made for 640x480 frames, the stream is 320x240"):
        load(path, (320, 240))
    with pytest.raises(MissingInputError, match="no such calibration file"):
        load(tmp_path / "none.json")
    path.write_text("garbage{")
    with pytest.raises(CalibrationError, match=r"c\.json: not valid JSON"):
        load(path)


@pytest.mark.parametrize(
    "content",
    [
        b"RIFF\x00\x01AVI " + b"[" * 100,  # a video whose bytes hold many brackets
        b"\x89PNG\r\n\x1a\n\xff\xfe",  # an image: not UTF-8
        b'{"image_size": [640, 480]\x00}',  # text with a NUL in it
    ],
)
def test_a_file_that_is_not_text_is_not_a_calibration(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "c.avi"
    path.write_bytes(content)
    with pytest.raises(CalibrationError, match=r"c\.avi: not a calibration file: it is not UTF-8"):
        load(path)


def test_ros_camera_info_round_trip(tmp_path: Path) -> None:
    cal = a_calibration()
    left, right = export_ros(cal, tmp_path)
    for path, (k, d, r, p) in ((left, ("K1", "D1", "R1", "P1")), (right, ("K2", "D2", "R2", "P2"))):
        info = yaml.safe_load(path.read_text())
        assert (info["image_width"], info["image_height"]) == (640, 480)
        assert info["distortion_model"] == "plumb_bob"
        for field, name in (
            ("camera_matrix", k),
            ("distortion_coefficients", d),
            ("rectification_matrix", r),
            ("projection_matrix", p),
        ):
            m = info[field]
            got = np.asarray(m["data"]).reshape(m["rows"], m["cols"])
            np.testing.assert_array_equal(got, cal.array(name))
    info = yaml.safe_load(right.read_text())
    p2 = np.asarray(info["projection_matrix"]["data"]).reshape(3, 4)
    assert p2[0, 3] == pytest.approx(-p2[0, 0] * 0.060, rel=1e-6)  # -fx * B, B in metres


def test_ros_export_makes_its_folder_but_save_needs_one(tmp_path: Path) -> None:
    """``calibration export --ros DIR`` makes DIR, as documented; a calibration file (``--out``
    of ``calibrate`` and ``calibration import``) goes into a folder that exists, as every
    output file does."""
    cal = a_calibration()
    left, right = export_ros(cal, tmp_path / "ros" / "rig")
    assert left.parent == tmp_path / "ros" / "rig" and left.is_file() and right.is_file()
    with pytest.raises(OutputError, match=r"folder .*/no does not exist; create it first"):
        save(cal, tmp_path / "no" / "c.json")
    assert not (tmp_path / "no").exists()


def test_opencv_filestorage_import_triangulates_like_the_source(tmp_path: Path) -> None:
    cal = a_calibration()
    intr = cv2.FileStorage(str(tmp_path / "intrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for ours, theirs in (("K1", "M1"), ("D1", "D1"), ("K2", "M2"), ("D2", "D2")):
        intr.write(theirs, cal.array(ours))
    intr.release()
    extr = cv2.FileStorage(str(tmp_path / "extrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for name in ("R", "T", "R1", "R2", "P1", "P2", "Q"):
        extr.write(name, cal.array(name))
    extr.release()
    imported = import_opencv(tmp_path / "intrinsics.yml", None, (640, 480))
    src, dst = CalibratedRig(cal), CalibratedRig(imported)
    rng = np.random.default_rng(0)
    left = rng.uniform([50, 50], [590, 430], (20, 2))
    right = left - [30.0, 0.0]
    a, _ = src.triangulate(src.rectify_left(left), src.rectify_right(right))
    b, _ = dst.triangulate(dst.rectify_left(left), dst.rectify_right(right))
    np.testing.assert_allclose(b, a, rtol=1e-9)
    with pytest.raises(MissingInputError, match="no such OpenCV calibration file"):
        import_opencv(tmp_path / "nope.yml", None, (640, 480))
    # the extrinsics, not named, were looked for beside the intrinsics: the error says so
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "intr.yml").write_bytes((tmp_path / "intrinsics.yml").read_bytes())
    with pytest.raises(MissingInputError, match=r"extrinsics\.yml: .*looked for beside intr\.yml"):
        import_opencv(alone / "intr.yml", None, (640, 480))


def test_show_says_how_many_pairs_were_rejected(tmp_path: Path) -> None:
    """calibrate's first line, pairs used and rejected, is what show prints of the file (it
    used to say rejected: 0 whatever calibrate had said). An 8x6 board is not found in one
    of OpenCV's 9x6 sample pairs."""
    pairs = pairs_from_list(shared_data("opencv_stereo", "stereo_calib.xml"))
    report = calibrate_files(pairs, Board(cols=8, rows=6, square=1.0))
    said = format_report(report).splitlines()[0]
    assert said == "pairs used: 12; rejected: 1"
    path = tmp_path / "c.json"
    save(report.calibration, path)
    res = stereod("calibration", "show", str(path))
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[1] == said, res.stdout


def test_a_newer_file_with_fields_this_version_does_not_know_loads_and_says_which(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Within ``stereod.calibration/1`` fields are only added: a file from a newer stereod,
    with a new top-level field and a new quality figure, loads as the same calibration (the
    id still checks out) and one warning names both fields; a new format version is refused."""
    cal = a_calibration()
    data = json.loads(cal.model_dump_json())
    data["temperature_c"] = 21.5
    data["quality"]["coverage"] = 0.8
    path = tmp_path / "c.json"
    path.write_text(json.dumps(data))
    assert load(path, (640, 480)) == cal
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and str(path) in warned[0]
    assert "quality.coverage, temperature_c" in warned[0]
    data["format"] = "stereod.calibration/2"
    path.write_text(json.dumps(data))
    with pytest.raises(
        CalibrationError,
        match=r"c\.json: format = 'stereod\.calibration/2': this stereod reads "
        r"stereod\.calibration/1; a newer stereod wrote this file: upgrade stereod",
    ):
        load(path)
