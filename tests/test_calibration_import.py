"""``stereod calibration import``: OpenCV's stereo_calib files, their rectification kept when
they hold one, and errors that name the file holding the bad value or the flag to change.

The files are written here with cv2.FileStorage from a rig of known geometry
(``minoru_like()``), their rectification made by cv2.stereoRectify directly; the truth of a
triangulated point is the point itself, in the rig frame (the left camera's axes turned by R1,
origin at the midpoint of the camera centres).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from stereod.cli import main
from stereod.vision.calibration import load
from stereod.vision.geometry.rectified import CalibratedRig
from stereod_fakes.rig import minoru_like

from .test_cli import error_in_process

RIG = minoru_like()
SIZE = (640, 480)


def opencv_rectification(alpha: float) -> dict[str, np.ndarray]:
    """R1 R2 P1 P2 Q as stereo_calib makes them (zero disparity at infinity, ``alpha``)."""
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(
        RIG.left.K, RIG.left.D, RIG.right.K, RIG.right.D, SIZE, RIG.R, RIG.T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha,
    )  # fmt: skip
    return {"R1": r1, "R2": r2, "P1": p1, "P2": p2, "Q": q}


def write_files(folder: Path, **extrinsics: np.ndarray) -> Path:
    """intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml (R T, then ``extrinsics``, which may
    replace R or T) of the rig; the intrinsics' path."""
    intr = cv2.FileStorage(str(folder / "intrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for name, m in (("M1", RIG.left.K), ("D1", RIG.left.D), ("M2", RIG.right.K)):
        intr.write(name, m)
    intr.write("D2", RIG.right.D)
    intr.release()
    extr = cv2.FileStorage(str(folder / "extrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for name, m in {"R": RIG.R, "T": RIG.T.reshape(3, 1), **extrinsics}.items():
        extr.write(name, m)
    extr.release()
    return folder / "intrinsics.yml"


def imported(
    capsys: pytest.CaptureFixture[str], intrinsics: Path, size: str = "640x480"
) -> tuple[str, Path]:
    out = intrinsics.with_name("cal.json")
    assert main(["calibration", "import", str(intrinsics), "--size", size, "--out", str(out)]) == 0
    return capsys.readouterr().out, out


def triangulation_error_m(path: Path) -> float:
    """Largest distance (m) between points 1-4 m in front of the rig and where the imported
    calibration triangulates their projections (made with the rig's own K, D, R, T)."""
    cal = load(path)
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.8, -0.5, 1.0], [0.8, 0.5, 4.0], (30, 3))
    left, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), RIG.left.K, RIG.left.D)
    rvec = cv2.Rodrigues(RIG.R)[0]
    right, _ = cv2.projectPoints(pts, rvec, RIG.T, RIG.right.K, RIG.right.D)
    rig = CalibratedRig(cal)
    got, _ = rig.triangulate(
        rig.rectify_left(left.reshape(-1, 2)), rig.rectify_right(right.reshape(-1, 2))
    )
    middle = -RIG.R.T @ RIG.T / 2.0  # the midpoint of the camera centres, left frame
    truth = (pts - middle) @ cal.array("R1").T
    return float(np.linalg.norm(got - truth, axis=1).max())


def test_the_files_rectification_is_kept(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """stereo_calib writes an alpha=1 rectification (OpenCV's sample pairs: P1 focal 425.8 px);
    import recomputed it at alpha -1 (538.8 px) and said nothing, though the docs said it was
    read. Now the file's R1 R2 P1 P2 Q are kept, said on import, and triangulate the rig's own
    projections within 0.1 mm of the truth."""
    rect = opencv_rectification(1.0)
    out, path = imported(capsys, write_files(tmp_path, **rect))
    assert "rectification read from extrinsics.yml" in out
    cal = load(path)
    for name, m in rect.items():
        np.testing.assert_allclose(cal.array(name), m, rtol=1e-12, atol=1e-12)
    assert f"P1 {rect['P1'][0, 0]:.1f} px" in out
    assert rect["P1"][0, 0] < opencv_rectification(-1.0)["P1"][0, 0] - 20  # another alpha
    assert triangulation_error_m(path) < 1e-4


def test_a_partial_rectification_is_computed_and_said(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    rect = opencv_rectification(1.0)
    del rect["Q"]
    out, path = imported(capsys, write_files(tmp_path, **rect))
    assert "rectification computed (extrinsics.yml lacks Q)" in out
    want = opencv_rectification(-1.0)["P1"]
    np.testing.assert_allclose(load(path).array("P1"), want, rtol=1e-9)
    assert triangulation_error_m(path) < 1e-4


def test_a_rectification_that_does_not_fit_r_and_t_is_refused(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """R1 turned by 0.5 deg about y: the rig frame, and every position, would turn with it."""
    rect = opencv_rectification(1.0)
    rect["R1"] = cv2.Rodrigues(np.array([0.0, np.radians(0.5), 0.0]))[0] @ rect["R1"]
    intr = write_files(tmp_path, **rect)
    error_in_process(
        capsys,
        ["calibration", "import", str(intr), "--size", "640x480", "--out", f"{tmp_path}/c.json"],
        65,
        r"extrinsics\.yml: R1 R2 P1 P2 Q do not fit R and T \(R2 R differs from R1 by 0\.0087\): "
        r"remove them from the file",
    )
    assert not (tmp_path / "c.json").exists()


def test_a_swapped_rig_is_refused_as_calibrate_refuses_it(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """T.x > 0 (the right camera on the left) was imported (exit 0) and then refused by every
    run (78); now import refuses it with calibrate's message, naming the file."""
    intr = write_files(tmp_path, T=-RIG.T.reshape(3, 1))
    error_in_process(
        capsys,
        ["calibration", "import", str(intr), "--size", "640x480", "--out", f"{tmp_path}/c.json"],
        65,
        r"extrinsics\.yml: left and right look swapped \(T\.x = \+0\.0599\d > 0: the 'right' "
        r"camera is on the left\): swap the left and right images",
    )


@pytest.mark.parametrize(
    ("file", "field", "value", "said"),
    [
        ("extrinsics", "T", np.nan, "holds a non-finite number"),
        ("extrinsics", "T", 1e300, r"holds 1e\+300, beyond any calibration"),
        ("extrinsics", "R", np.inf, "holds a non-finite number"),
        ("intrinsics", "M2", np.nan, "holds a non-finite number"),
    ],
)
def test_a_bad_number_is_named_in_the_file_that_holds_it(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    file: str,
    field: str,
    value: float,
    said: str,
) -> None:
    """A NaN in extrinsics.yml was reported as in intrinsics.yml (65), 1e300 the same (78)."""
    intr = write_files(tmp_path)
    path = tmp_path / f"{file}.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    keys = ("R", "T") if file == "extrinsics" else ("M1", "D1", "M2", "D2")
    mats = {k: fs.getNode(k).mat() for k in keys}
    fs.release()
    mats[field] = mats[field].copy()
    mats[field].flat[0] = value
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, m in mats.items():
        fs.write(k, m)
    fs.release()
    error_in_process(
        capsys,
        ["calibration", "import", str(intr), "--size", "640x480", "--out", f"{tmp_path}/c.json"],
        65,
        rf"^stereod: .*/{file}\.yml: field {field} {said}",
    )


@pytest.mark.parametrize("size", ["320x240", "1280x960"])
def test_a_size_the_principal_points_do_not_fit_names_size(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, size: str
) -> None:
    """The files do not record the size: 320x240 for a 640x480 calibration said "the file is
    damaged ... recalibrate" four times, and 1280x960 was accepted. The principal points
    (324, 237) px sit at 101 % or 25 % of the width: exit 64, --size named, 640x480 offered."""
    intr = write_files(tmp_path)
    error_in_process(
        capsys,
        ["calibration", "import", str(intr), "--size", size, "--out", f"{tmp_path}/c.json"],
        64,
        rf"--size {size}: .*intrinsics\.yml's M1 has its principal point at \(324\.0, 237\.0\) "
        r"px, .*made at another size; give --size of its images \(640x480 is the common mode "
        r"nearest",
    )
