"""The pipeline on rendered scenes: 3D positions against the truth and the eq. 12 bound."""

from __future__ import annotations

import dataclasses
import math
from functools import partial

import numpy as np
import pytest

from stereod import PipelineParams, pipeline
from stereod.sources import pairing
from stereod.tracking.motion import circular_median_deg
from stereod.tracking.skew import SIZE_NOISE
from stereod.tracking.types import Observation, TrackerParams
from stereod.vision.blobs import Blobs
from stereod.vision.detect_params import DetectorParams
from stereod.vision.geometry.errors import SEGMENTATION_SLACK, segmentation_error_px
from stereod_fakes.synth import Ball, Scene
from tests.scenes import run_recording, run_scene, sigma, states


def run_default(scene: Scene, workers: int = 1) -> list:
    params = PipelineParams(scene.rig, detector=DetectorParams(), detect_workers=workers)
    return run_scene(scene, params)


@pytest.mark.parametrize("workers", [1, 2])
def test_positions_within_one_pixel_bound(workers: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(pipeline, "PARALLEL_MIN_PX", 0)  # two threads even for small frames
    scene = Scene(balls=[Ball(heading_deg=30, speed_mps=0.7, centre_m=(0.0, 0.0, 2.0))])
    ball = scene.balls[0]
    results = run_default(scene, workers)
    errs, seen = [], 0
    for o in states(results):
        seen += 1
        truth = ball.position_m((o.t_ns - scene.t0_ns) / 1e9)
        err = np.abs(o.position_m - truth)
        bound = scene.rig.depth_error_one_px_m(truth[2])
        assert err[2] <= bound, f"depth error {err[2]:.4f} m beyond eq. 12's {bound:.4f} m"
        assert np.all(err <= 4 * sigma(o) + 1e-3)
        errs.append(err)
    assert seen >= 0.9 * ball_frames(scene)
    assert np.median(np.array(errs)[:, 2]) < 0.01


def ball_frames(scene: Scene) -> int:
    b = scene.balls[0]
    return int((b.t_off_s - b.t_on_s) * scene.fps)


def test_two_balls_get_two_tracks_with_their_velocities() -> None:
    balls = [
        Ball(heading_deg=90, speed_mps=0.4, centre_m=(0.0, -0.2, 1.6)),
        Ball(heading_deg=180, speed_mps=0.6, centre_m=(0.2, 0.2, 2.2), radius_m=0.06),
    ]
    results = run_default(Scene(balls=balls))
    by_track: dict[int, list] = {}
    for o in states(results, confirmed=True, valid=True):
        by_track.setdefault(o.track_id, []).append(o)
    assert len(by_track) == 2
    medians = sorted(
        (
            circular_median_deg([o.heading_deg for o in s]),
            float(np.median([o.speed_mps for o in s])),
        )
        for s in by_track.values()
    )
    for (heading, speed), b in zip(medians, balls):
        assert heading == pytest.approx(b.heading_deg, abs=1.0)
        assert speed == pytest.approx(b.speed_mps, rel=0.03)


def tracks_by_frame(scene: Scene, **params: object) -> list[dict[int, str]]:
    results = run_scene(scene, PipelineParams(scene.rig, **params))  # type: ignore[arg-type]
    return [{o.track_id: o.lifecycle.value for o in r.tracks} for r in results]


def test_crossing_objects_keep_their_ids() -> None:
    """Two balls at different depths cross in front of each other (their images merge for a
    few frames, while both tracks coast); afterwards each ball has the id it had before."""
    balls = [
        Ball(
            heading_deg=90,
            speed_mps=0.5,
            centre_m=(0.0, 0.0, 1.6),
            t_on_s=1.0,
            t_off_s=3.4,
            t_mid_s=2.2,
        ),
        Ball(
            heading_deg=270,
            speed_mps=0.5,
            centre_m=(0.0, 0.03, 2.6),
            t_on_s=1.0,
            t_off_s=3.4,
            t_mid_s=2.2,
            radius_m=0.08,
        ),
    ]
    scene = Scene(duration_s=3.6, balls=balls)
    before: dict[int, set[int]] = {0: set(), 1: set()}
    after: dict[int, set[int]] = {0: set(), 1: set()}
    for result in run_scene(scene, PipelineParams(scene.rig)):
        t = (result.t_ns - scene.t0_ns) / 1e9
        if abs(t - 2.2) < 0.4:
            continue
        for o in result.tracks:
            if o.lifecycle == "confirmed":
                d = [np.linalg.norm(o.position_m - b.position_m(t)) for b in balls]
                k = int(np.argmin(d))
                assert d[k] < 0.05, f"track {o.track_id} is {d[k]:.3f} m from ball {k}"
                (before if t < 2.2 else after)[k].add(o.track_id)
    assert before == after, f"ids before the crossing {before}, after {after}"
    assert all(len(ids) == 1 for ids in before.values()) and before[0] != before[1]


def test_stopped_object_stays_tracked_while_background_is_frozen() -> None:
    """A ball rolls in and stops. With the background frozen under it, it stays tracked; with
    learning everywhere (the paper's eq. 3), it fades into the background and its track ends."""
    ball = Ball(
        heading_deg=90,
        speed_mps=0.4,
        centre_m=(0.0, 0.0, 1.6),
        t_on_s=1.0,
        t_off_s=1e9,
        t_mid_s=1.5,
        t_stop_s=2.0,
    )
    scene = Scene(duration_s=7.0, balls=[ball])
    detector = DetectorParams(beta=0.05)
    frozen = tracks_by_frame(scene, detector=detector)
    paper = dataclasses.replace(detector, hold_foreground=False)
    learning = tracks_by_frame(scene, detector=paper, freeze_background=False)
    assert frozen[-1] and set(frozen[-1].values()) == {"stationary"}, frozen[-1]
    assert learning[-1] == {}, "with eq. 3 everywhere, the stopped ball should fade"
    # A short freeze lets the background take it after that time.
    short = tracks_by_frame(scene, detector=detector, tracker=TrackerParams(hold_still_s=1.0))
    assert short[-1] == {}
    # Untracked, held foreground is absorbed after absorb_s.
    held = dataclasses.replace(detector, absorb_s=1.0)
    absorbed = tracks_by_frame(scene, detector=held, freeze_background=False)
    assert absorbed[-1] == {}


def test_object_that_stops_for_45_s_keeps_its_id_and_moves_on() -> None:
    """Stop and go (design sec. 11): a ball rolls, stands still for 45 s (within the default
    ``hold_still_s`` of 60 s), and rolls on. One id from its confirmation to the end; while
    it stands it is ``stationary`` and where the scene put it; moving again, ``confirmed``."""
    ball = Ball(
        heading_deg=90,
        speed_mps=0.4,
        centre_m=(-0.2, 0.0, 1.6),
        t_on_s=0.8,
        t_off_s=1e9,
        t_mid_s=1.0,
        t_stop_s=1.5,
        t_resume_s=46.5,
    )
    scene = Scene(width_px=320, height_px=240, fps=10.0, duration_s=48.5, balls=[ball])
    results = run_scene(scene, PipelineParams(scene.rig))
    ids: set[int] = set()
    still: list[float] = []
    for r in results:
        t = (r.t_ns - scene.t0_ns) / 1e9
        seen = [o for o in r.tracks if o.lifecycle.value in ("confirmed", "stationary")]
        if t > 1.3:
            assert len(seen) == 1, f"at {t:.1f} s: {[(o.track_id, o.lifecycle) for o in r.tracks]}"
            ids.add(seen[0].track_id)
            o = seen[0]
            if 3.0 < t < 46.5:
                assert o.lifecycle.value == "stationary", (t, o.lifecycle)
                still.append(float(np.linalg.norm(o.position_m - ball.position_m(t))))
            if t > 47.5:
                assert o.lifecycle.value == "confirmed", (t, o.lifecycle)
                assert np.linalg.norm(o.position_m - ball.position_m(t)) < 0.05
    assert len(ids) == 1, f"ids {ids}"
    assert max(still) < 0.02, f"the stopped ball drifts {max(still):.3f} m"


def test_rolling_shutter_readout_puts_each_blob_at_its_rows_instant() -> None:
    """A rolling shutter (30 ms from the first row to the last) reads a ball on row v at
    v / height x 30 ms after the frame's instant. A ball moving right and down at 1 m/s each
    way then seems to lag by up to 2 cm and moves faster down the image than it does (the
    rows it reaches are read later): with ``readout_s`` set, each blob is taken at its rows'
    instant, and positions and speed agree with the scene's truth."""
    ball = Ball(
        heading_deg=90,
        speed_mps=1.0,
        vy_mps=1.0,
        centre_m=(0.0, 0.0, 2.0),
        t_on_s=0.9,
        t_off_s=1.6,
        t_mid_s=1.25,
    )
    scene = Scene(
        width_px=320, height_px=240, fps=30.0, duration_s=1.7, balls=[ball], readout_s=0.03
    )

    def errors(readout_s: float) -> tuple[float, float]:
        params = PipelineParams(
            scene.rig, readout_s=readout_s, tracker=TrackerParams(gravity_mps2=(0, 0, 0))
        )
        pos, spd = [], []
        for r in run_scene(scene, params):
            t = (r.t_ns - scene.t0_ns) / 1e9
            for o in r.tracks:
                if o.velocity_valid:
                    pos.append(float(np.linalg.norm(o.position_m - ball.position_m(t))))
                    spd.append(o.speed_mps / math.sqrt(2.0) - 1.0)
        assert len(pos) >= 8
        return float(np.median(pos)), float(np.median(np.abs(spd)))

    pos_off, spd_off = errors(0.0)
    pos_on, spd_on = errors(0.03)
    assert pos_off > 0.008, f"without the readout the ball should lag, got {pos_off:.4f} m"
    assert pos_on < 0.4 * pos_off and pos_on < 0.005, (pos_on, pos_off)
    assert spd_off > 0.012, f"without the readout the speed should be off, got {spd_off:.1%}"
    assert spd_on < 0.005, f"speed off by {spd_on:.1%} with the readout"


def test_an_object_cut_by_the_bottom_edge_is_tracked_by_its_x_and_depth() -> None:
    """A person close to the camera has their feet or head out of view. Both eyes lose the
    same rectified rows, so the disparity holds: a ball whose bottom the image's edge cuts is
    tracked (it was only ever placed, never filtered), its X, depth and speed right; its
    height is what the edge hides."""
    ball = Ball(
        heading_deg=90,
        speed_mps=0.5,
        centre_m=(0.0, 0.85, 2.5),
        radius_m=0.3,
        t_on_s=1.0,
        t_off_s=3.0,
        t_mid_s=2.0,
    )
    scene = Scene(width_px=320, height_px=240, duration_s=3.2, balls=[ball])
    ok = 0
    for r in run_scene(scene, PipelineParams(scene.rig)):
        t = (r.t_ns - scene.t0_ns) / 1e9
        for o in r.tracks:
            assert o.observation.cut and not o.observation.clipped
            if o.velocity_valid and 1.3 < t < 2.7:
                truth = ball.position_m(t)
                assert abs(o.position_m[0] - truth[0]) < 0.03, (t, o.position_m, truth)
                assert abs(o.position_m[2] - truth[2]) < 0.05, (t, o.position_m, truth)
                assert o.speed_mps == pytest.approx(0.5, rel=0.1)
                ok += 1
    assert ok >= 10, f"{ok} valid states"


@pytest.fixture(scope="module")
def recovered_calibration(tmp_path_factory: pytest.TempPathFactory):
    """A calibration recovered from rendered chessboards through the non-canonical rig."""
    from stereod.vision.calibrate import calibrate, detect_pairs
    from stereod.vision.calibration import Board, save
    from stereod_fakes.rig import board_views, minoru_like, random_board_poses

    rig = minoru_like()
    board = Board(cols=9, rows=6, square=0.03)
    views = board_views(rig, 640, 480, 9, 6, 0.03, random_board_poses(30, 9, 6, 0.03, seed=2))
    found, _, size = detect_pairs(views, board)
    cal = calibrate(found, board, size).calibration
    path = tmp_path_factory.mktemp("cal") / "calibration.json"
    save(cal, path)
    return rig, cal, path


@pytest.mark.slow
@pytest.mark.parametrize(("heading", "speed"), [(60.0, 0.7), (270.0, 0.4)])
def test_non_canonical_rig_with_recovered_calibration(
    recovered_calibration, tmp_path, heading: float, speed: float
) -> None:
    """A ball through a distorted, rotated rig with half a frame of skew, measured with the
    calibration recovered from rendered boards: heading within 1 deg, speed within 3 %, as in
    the canonical case. Truth is expressed in the calibration's rig frame (rectified axes)."""
    from stereod.tracking.motion import circular_median_deg
    from stereod.vision.geometry.rectified import CalibratedRig
    from stereod_fakes.scenarios import table_one_scene
    from stereod_fakes.synth import write_scene

    spec, cal, _ = recovered_calibration
    scene = table_one_scene(heading, speed).model_copy(update={"rig_spec": spec})
    rec = write_scene(scene, tmp_path / "rec")
    rig = CalibratedRig(cal)
    assert rig.geometry == "calibrated" and rig.calibration_id == cal.id
    valid = states(run_recording(rec, PipelineParams(rig)), confirmed=True, valid=True)
    assert len(valid) >= 8
    v_rig = cal.array("R1") @ scene.balls[0].velocity_mps
    true_heading = float(np.degrees(np.arctan2(v_rig[0], v_rig[2])) % 360)
    got = circular_median_deg([o.heading_deg for o in valid])
    err = (got - true_heading + 180) % 360 - 180
    assert abs(err) <= 1.0, f"heading {got:.2f} deg, truth {true_heading:.2f} deg"
    spd = float(np.median([o.speed_mps for o in valid]))
    assert spd == pytest.approx(speed, rel=0.03), f"speed {spd:.3f} m/s, truth {speed}"


def test_a_reconfigured_pipeline_keeps_the_pending_background_update() -> None:
    """Eq. 3 with a pair's frames runs when the next pair is detected; a reconfiguration in
    between applies it before handing the backgrounds over, so the new pipeline's background
    is the one an unbroken run has (to the last bit)."""
    from stereod.pipeline import Pipeline
    from stereod.sources.frames import StereoPair
    from stereod_fakes.synth import Renderer

    scene = Scene(duration_s=1.2, balls=[Ball(heading_deg=90.0, speed_mps=0.5)])
    pairs = [StereoPair(k, left, right) for k, (left, right) in enumerate(Renderer(scene).frames())]
    params = PipelineParams(scene.rig)
    whole = Pipeline(params)
    for pair in pairs:
        whole.process(pair)
    split = Pipeline(params)
    for pair in pairs[:-1]:
        split.process(pair)
    split, _ = split.reconfigured(dataclasses.replace(params, skew_window_s=0.3))
    split.process(pairs[-1])
    for a, b in ((whole.left, split.left), (whole.right, split.right)):
        assert a.background is not None and b.background is not None
        np.testing.assert_array_equal(a.background, b.background)


def test_a_reload_of_the_readout_reaches_the_tracker_it_keeps() -> None:
    """A reload that changes only ``readout_s`` keeps the tracks (and the tracker), whose
    association then takes each row's instant with the new readout, as the skew stage does:
    30 ms over 240 rows is 125 us a row."""
    from stereod.pipeline import Pipeline
    from stereod.vision.geometry.stereo import CanonicalRig

    params = PipelineParams(CanonicalRig(0.06, 60.0, 320, 240))
    first = Pipeline(params)
    second, ended = first.reconfigured(dataclasses.replace(params, readout_s=0.03))
    assert ended == [] and second.tracker is first.tracker
    assert second.tracker.line_ns == pytest.approx(0.03e9 / 240)


def test_two_workers_find_what_one_finds(monkeypatch: pytest.MonkeyPatch) -> None:
    """The eyes on two threads (forced here for a small frame) give the same tracks, to the
    bit, as on one: each eye's detector is its own, and eq. 3 runs in the same order."""
    scene = Scene(duration_s=2.0, balls=[Ball(heading_deg=120, speed_mps=0.8)])
    one = states(run_default(scene, 1))
    monkeypatch.setattr(pipeline, "PARALLEL_MIN_PX", 0)
    two = states(run_default(scene, 2))
    assert len(one) == len(two) > 10
    for a, b in zip(one, two, strict=True):
        assert a.track_id == b.track_id and a.t_ns == b.t_ns
        assert np.array_equal(a.position_m, b.position_m)
        assert np.array_equal(a.velocity_mps, b.velocity_mps)


def test_detecting_the_earlier_eye_ahead_finds_what_the_pair_finds() -> None:
    """With the right eye half a frame late, the left frame waits for its partner: detecting
    it meanwhile (what the daemon does while idle) gives the same tracks, to the bit, as
    detecting both eyes once the pair is formed (the pairer drops nothing here). Every pair
    after the first two uses it (the pairer knows the frame period from an eye's second
    frame on)."""
    from stereod.pipeline import Pipeline
    from stereod.sources.frames import Eye, StereoPair
    from stereod_fakes.synth import Renderer

    scene = Scene(duration_s=2.0, skew_s=1 / 60, balls=[Ball(heading_deg=60, speed_mps=0.7)])
    params = PipelineParams(scene.rig)
    frames = [f for pair in Renderer(scene).frames() for f in pair]
    tolerance = int(0.75e9 / scene.fps)
    with Pipeline(params) as pipe:
        ahead = list(pipe.run(frames, tolerance))
        assert pipe.detected_ahead == len(ahead) - 2
    pairer = pairing.Pairer(tolerance)
    with Pipeline(params) as pipe:
        at_once = [pipe.process(p) for f in frames for p in pairer.push(f)]
        assert pipe.detected_ahead == 0
    a, b = states(ahead), states(at_once)
    assert len(a) == len(b) > 10
    for x, y in zip(a, b, strict=True):
        assert x.track_id == y.track_id and x.t_ns == y.t_ns
        assert np.array_equal(x.position_m, y.position_m)
        assert np.array_equal(x.velocity_mps, y.velocity_mps)
    # Only an eye's next frame, once: not one that skips a frame, not the same one twice.
    left = [f for f in frames if f.eye is Eye.LEFT]
    right = [f for f in frames if f.eye is Eye.RIGHT]
    with Pipeline(params) as pipe:
        assert not pipe.detect_ahead(left[0])  # no pair yet: nothing to follow
        pipe.process(StereoPair(0, left[0], right[0]))
        assert not pipe.detect_ahead(left[2])
        assert not pipe.detect_ahead(dataclasses.replace(left[1], t_ns=left[0].t_ns))  # not later
        assert pipe.detect_ahead(left[1])
        assert not pipe.detect_ahead(left[1])
        # a frame detected ahead that its pair does not hold is dropped
        pipe.process(StereoPair(1, left[2], right[2]))
        assert pipe.detected_ahead == 0


def _blobs(area: int) -> Blobs:
    return Blobs(
        centroid_px=np.zeros((1, 2)),
        bbox_px=np.array([[0, 0, 54, 47]], np.int32),
        area_px=np.array([area], np.int32),
        support=(np.zeros((47, 54), np.uint8),),
    )


def _seen(left_area: int, right_area: int) -> Observation:
    z2 = np.zeros(2)
    return Observation(
        np.zeros(3), np.eye(3), z2, z2, z2, z2, np.zeros(4), np.zeros(4), left_area, right_area,
        16.0, 0.1,
    )  # fmt: skip


def _noise(*areas: int) -> float:
    """The areas' own noise in a difference of two log area ratios."""
    return 2.0 * SIZE_NOISE / math.sqrt(min(areas))


def test_a_part_of_an_object_lost_in_one_eye_only_widens_that_observations_error() -> None:
    """Before a track's filter runs: one eye's blob lost a share s of its area since the
    track's last observation and the other's did not: the centroids may have moved by
    (s - slack - s / 2 - noise) times half the blob's width (s / 2 is the pair's mean
    growth, which the eyes' skew alone can split; the noise is the areas' own). While the
    loss lasts, the two areas still differ by s: (s - slack - noise) times half the width."""
    seg = partial(segmentation_error_px, size_noise=SIZE_NOISE)
    before = _seen(2440, 2440)
    lost = seg(_blobs(2440), _blobs(1950), 0, 0, before, 54.0)
    s = np.log(2440 / 1950)
    noise = _noise(1950)
    assert lost == pytest.approx((s - SEGMENTATION_SLACK - s / 2 - noise) * 27.0)
    assert lost > 0.7
    # both eyes lost the same share (the object turned, or left the light): no jump
    assert seg(_blobs(1950), _blobs(1950), 0, 0, before, 54.0) == 0.0
    # an object coming closer, one eye a little later than the other: growth, not a jump
    assert seg(_blobs(3200), _blobs(2900), 0, 0, before, 54.0) == 0.0
    # within the slack: noise
    assert seg(_blobs(2440), _blobs(2400), 0, 0, before, 54.0) == 0.0
    # a loss that lasts: the areas changed alike since the last observation, but one eye
    # still holds a share s less of the object than the other, so its centroid is still off
    lasting = _seen(2440, 1950)
    still = seg(_blobs(2440), _blobs(1950), 0, 0, lasting, 54.0)
    assert still == pytest.approx((s - SEGMENTATION_SLACK - noise) * 27.0)
    # the same two blobs of a calibrated rig whose lenses scale the eyes' images differently:
    # the areas compared are the rectified ones, and those agree
    assert seg(_blobs(2440), _blobs(1950), 0, 0, lasting, 54.0, (2300.0, 2300.0)) == 0.0
    # and the same areas from an object that grew in both eyes by more than they differ: skew
    assert seg(_blobs(2440), _blobs(1950), 0, 0, _seen(1700, 1700), 54.0) == 0.0
    # a small blob's area wobbles by its outline's pixels: a ball 5 px across, 20 px, that
    # reads 23 px in one eye and 19 in the other has lost nothing
    assert seg(_blobs(23), _blobs(19), 0, 0, _seen(20, 20), 5.0) == 0.0


def test_with_the_filter_running_a_loss_counts_against_the_growth_each_eye_should_show() -> None:
    """Once the track's filter runs, each eye's area change is compared with what the
    track's depth at that eye's two instants says it should be. A robot that keeps its
    distance, one eye losing a share s of it: the whole loss counts on its first frame
    (s - slack - noise), not half of it. An object coming closer loses the same share in
    one eye: the mean growth no longer hides it. A ball thrown at the rig, whose later eye
    grew less for being seen sooner: exactly what the skew explains, nothing counts."""
    seg = partial(segmentation_error_px, size_noise=SIZE_NOISE)
    before = _seen(2440, 2440)
    s = np.log(2440 / 1950)
    noise = _noise(1950)
    still = seg(_blobs(2440), _blobs(1950), 0, 0, before, 54.0, None, (0.0, 0.0))
    assert still == pytest.approx((s - SEGMENTATION_SLACK - noise) * 27.0)
    assert still > 2 * seg(_blobs(2440), _blobs(1950), 0, 0, before, 54.0)
    near_l, near_r = int(2440 * 1.5), int(2440 * 1.5 / 1.25)  # grew 1.5 in both, one lost 0.2
    closer = seg(_blobs(near_l), _blobs(near_r), 0, 0, before, 54.0, None, (0.405, 0.405))
    assert closer == pytest.approx(
        (np.log(1.25) - SEGMENTATION_SLACK - _noise(2440)) * 27.0, rel=1e-3
    )
    assert seg(_blobs(near_l), _blobs(near_r), 0, 0, before, 54.0) == 0.0  # as it was
    thrown = _seen(400, 400)
    grow_l, grow_r = 0.30, 0.12  # the right eye's last frame was later: it grew less since
    ball_l, ball_r = round(400 * math.exp(grow_l)), round(400 * math.exp(grow_r))
    assert seg(_blobs(ball_l), _blobs(ball_r), 0, 0, thrown, 22.0, None, (grow_l, grow_r)) == 0.0


def test_centroids_on_rows_apart_widen_the_observations_error() -> None:
    """A rectified pair sees an object on one row in both eyes; where its two centroids come
    to lie rows apart, the segmentations disagree, and the disparity may be off by as much:
    each centroid's sigma gains the gap over sqrt(2). An object seen on one row, then 2 px
    lower in the right eye than in the left: that observation's lateral variance is
    (0.15^2 + 2^2 / 2) / 0.15^2 times what it is on one row (closed form: the triangulation's
    covariance is the centroids' variance times a Jacobian of the positions alone). A gap
    that stays (a calibration's row error) or goes back to none widens nothing."""
    from stereod import CanonicalRig, Frame, Pipeline, StereoPair
    from stereod.sources.frames import Eye

    rig = CanonicalRig(0.06, 60.0, 320, 180)
    rng = np.random.default_rng(1)
    bg = rng.integers(0, 255, (180, 320, 3)).astype(np.uint8)

    def second_sight(
        gaps: tuple[int, int], skew_ns: int = 0, **params: bool
    ) -> tuple[np.ndarray, float | None]:
        """The object's observation on its second pair, its right image ``gaps`` px lower
        and ``skew_ns`` later."""
        with Pipeline(PipelineParams(rig, **params)) as pipe:
            for k in range(12):
                left, right = bg.copy(), bg.copy()
                if k >= 10:  # appears after the warm-up and stays
                    g = gaps[k - 10]
                    left[60:100, 100:130] = (0, 255, 0)
                    right[60 + g : 100 + g, 94:124] = (0, 255, 0)
                t = k * 40_000_000
                pair = StereoPair(
                    k, Frame(Eye.LEFT, left, t, k), Frame(Eye.RIGHT, right, t + skew_ns, k)
                )
                tracks = pipe.process(pair).tracks
        (s,) = tracks
        return s.observation.cov_m2, s.observation.row_gap_px

    same, gap = second_sight((0, 0))
    assert gap == pytest.approx(0.0, abs=1e-6)
    apart, gap = second_sight((0, 2))
    assert gap == pytest.approx(-2.0, abs=1e-6)
    sigma0 = PipelineParams(rig).centroid_sigma_px
    assert apart[0, 0] / same[0, 0] == pytest.approx((sigma0**2 + 2.0) / sigma0**2, rel=1e-9)
    for gaps in ((2, 2), (2, 0)):
        cov, _ = second_sight(gaps)
        assert cov[0, 0] == pytest.approx(same[0, 0], rel=1e-9), gaps
    # Eyes 10 ms apart, not brought to one instant: the rows' gap may be motion, not
    # segmentation, and says nothing.
    late, gap = second_sight((0, 2), 10_000_000, skew_compensation=False)
    late_same, _ = second_sight((0, 0), 10_000_000, skew_compensation=False)
    assert gap is None
    assert late[0, 0] == pytest.approx(late_same[0, 0], rel=1e-9)


@pytest.mark.parametrize("disparity_px", [0, 6])
def test_one_view_in_both_eyes_never_makes_a_track_at_infinity(disparity_px: int) -> None:
    """Both eyes see the same image (no parallax, as two copies of one test pattern do) of an
    object moving fast, the right eye 10 ms late: blobs are matched with room for that skew,
    and brought to one instant their disparity is nil. Such a position is at infinity, so no
    track state is published with a non-finite number, and every pair is processed. The
    same object with a real disparity is one track at eq. 9's depth B f / d (within 1 %: the
    flat object is taken to be as deep as wide, 0.3 % here)."""
    from stereod import CanonicalRig, Frame, Pipeline, StereoPair
    from stereod.sources.frames import Eye

    rig = CanonicalRig(0.06, 60.0, 320, 180)
    rng = np.random.default_rng(0)
    bg = rng.integers(0, 255, (180, 320, 3)).astype(np.uint8)
    depths: dict[int, list[float]] = {}
    with Pipeline(PipelineParams(rig)) as pipe:
        for k in range(70):
            left, right = bg.copy(), bg.copy()
            if k >= 10:  # enters after the warm-up
                x = 20 + 4 * (k - 10)
                left[60:100, x : x + 30] = (0, 255, 0)
                if disparity_px:  # a stereo view, and the right eye's 10 ms of motion: 1 px
                    x += 1 - disparity_px
                right[60:100, x : x + 30] = (0, 255, 0)
            t = k * 40_000_000
            pair = StereoPair(k, Frame(Eye.LEFT, left, t, k), Frame(Eye.RIGHT, right, t + 10**7, k))
            for s in pipe.process(pair).tracks:
                assert np.all(np.isfinite(s.position_m)) and s.position_m[2] > 0, (k, s)
                assert np.all(np.isfinite(s.velocity_mps)), (k, s)
                depths.setdefault(s.track_id, []).append(float(s.position_m[2]))
    if disparity_px == 0:
        assert depths == {}
    else:
        assert len(depths) == 1
        (z,) = depths.values()
        assert len(z) > 50
        assert np.median(z) == pytest.approx(0.06 * rig.focal_px / disparity_px, rel=0.01)


def test_a_pair_the_pipeline_cannot_use_is_refused_before_anything_changes() -> None:
    """A frame not of the rig's size, eyes given the wrong way round, one eye grey and the
    other BGR, or a capture time that is not later than its eye's last one (or so little
    later that it is in another unit) raise a ValueError that names the pair, the eye and
    what to change, before anything changes: the run then gives what it gives without the
    bad pairs, to the bit."""
    import math

    from stereod import CanonicalRig, Frame, Pipeline, StereoPair
    from stereod.sources.frames import Eye

    rig = CanonicalRig(0.06, 60.0, 64, 48)
    rng = np.random.default_rng(3)
    wall = rng.integers(0, 255, (48, 64)).astype(np.uint8)

    def pair(k: int) -> StereoPair:
        left, right = wall.copy(), wall.copy()
        if k >= 12:  # a square enters after the warm-up, 2 px of disparity
            left[20:30, 2 * k : 2 * k + 10] = 250
            right[20:30, 2 * k - 2 : 2 * k + 8] = 250
        return StereoPair.of(left, right, k * 10**8, k * 10**8 + 10**6, seq=k)

    def run(bad: bool) -> list[tuple[int, list[np.ndarray]]]:
        got = []
        with Pipeline(PipelineParams(rig)) as pipe:
            for k in range(20):
                if bad and k == 14:
                    refuse(pipe, k)
                r = pipe.process(pair(k))
                got.append((r.seq, [s.position_m for s in r.tracks]))
        return got

    def refuse(pipe: Pipeline, k: int) -> None:
        t = k * 10**8
        last = t - 10**8
        small = np.full((24, 32), 90, np.uint8)
        with pytest.raises(
            ValueError, match=rf"pair {k}: the right frame is 32x24 px but the rig is 64x48"
        ):
            pipe.process(StereoPair.of(wall, small, t, t, seq=k))
        swapped = StereoPair(k, Frame(Eye.RIGHT, wall, t, k), Frame(Eye.LEFT, wall, t, k))
        with pytest.raises(ValueError, match=f"pair {k}: its left frame is the right eye's"):
            pipe.process(swapped)
        with pytest.raises(
            ValueError, match=rf"left frame's capture time {last} ns is not after .*\({last} ns\)"
        ):
            pipe.process(StereoPair.of(wall, wall, last, t, seq=k))
        ms = StereoPair.of(wall, wall, last + 66, t, seq=k)  # times in ms read as ns
        with pytest.raises(ValueError, match=f"pair {k}: the left frame was captured 66 ns after"):
            pipe.process(ms)
        bgr = np.dstack((wall, wall, wall))
        with pytest.raises(ValueError, match=f"pair {k}: one eye's frame is grey and the other"):
            pipe.process(StereoPair.of(wall, bgr, t, t, seq=k))
        # a frame of another size or format is not detected ahead either (the detector would
        # start its background afresh for it, and its pair may be refused)
        assert not pipe.detect_ahead(Frame(Eye.RIGHT, small, t, k))
        assert not pipe.detect_ahead(Frame(Eye.RIGHT, bgr, t, k))

    clean, refused = run(False), run(True)
    assert any(tracks for _, tracks in clean[12:])
    assert [s for s, _ in refused] == [s for s, _ in clean]
    for (_, a), (_, b) in zip(clean, refused, strict=True):
        assert len(a) == len(b)
        for pa, pb in zip(a, b, strict=True):
            np.testing.assert_array_equal(pa, pb)
    for name, value in (("centroid_sigma_px", math.nan), ("skew_window_s", 0.0)):
        with pytest.raises(ValueError, match=f"{name} must be a finite number > 0"):
            PipelineParams(rig, **{name: value})
    with pytest.raises(ValueError, match="detect_workers must be 1 or 2"):
        PipelineParams(rig, detect_workers=0)
    with pytest.raises(TypeError, match=r"rig must be a CanonicalRig .* got NoneType"):
        PipelineParams(None)  # type: ignore[arg-type]


def test_the_wrong_kind_of_argument_is_a_type_error_saying_what_is_wanted() -> None:
    """What the README promises the library raises on bad input: TypeError or ValueError
    with a line that says what was wanted, never an AttributeError from deep inside."""
    from stereod import CanonicalRig, Frame, Pipeline
    from stereod.sources.frames import Eye

    rig = CanonicalRig(0.06, 60.0, 32, 24)
    image = np.zeros((24, 32), np.uint8)
    left, right = Frame(Eye.LEFT, image, 1_000_000, 0), Frame(Eye.RIGHT, image, 1_000_000, 0)
    with pytest.raises(TypeError, match=r"takes a PipelineParams.* got NoneType"):
        Pipeline(None)  # type: ignore[arg-type]
    with Pipeline(PipelineParams(rig)) as pipe:
        with pytest.raises(TypeError, match=r"StereoPair\(seq, left, right\).* got tuple"):
            pipe.process((left, right))  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="item 2 is a int, not a Frame"):
            list(pipe.run([left, right, 3]))  # type: ignore[list-item]
        with pytest.raises(TypeError, match="detect_ahead takes a Frame, got ndarray"):
            pipe.detect_ahead(image)  # type: ignore[arg-type]


def test_run_says_what_it_dropped_when_frames_come_out_of_capture_order(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """One eye's whole sequence before the other's: the pairer holds 8 frames of an eye, so
    most are dropped; run counts them by reason and warns once at the end. Frames in capture
    order are all paired, with nothing to warn about."""
    from stereod import CanonicalRig, Frame, Pipeline
    from stereod.sources.frames import Eye

    rig = CanonicalRig(0.06, 60.0, 32, 24)
    grey = np.full((24, 32), 90, np.uint8)
    left = [Frame(Eye.LEFT, grey, k * 33_333_333, k) for k in range(40)]
    right = [Frame(Eye.RIGHT, grey, k * 33_333_333 + 10**6, k) for k in range(40)]
    with Pipeline(PipelineParams(rig)) as pipe, caplog.at_level("WARNING", "stereod.pipeline"):
        assert pipe.pairing is None
        in_order = [f for pair in zip(left, right, strict=True) for f in pair]
        assert len(list(pipe.run(in_order))) == 40
        assert caplog.records == []
    with Pipeline(PipelineParams(rig)) as pipe, caplog.at_level("WARNING", "stereod.pipeline"):
        got = len(list(pipe.run(left + right)))
    assert pipe.pairing is not None and got == pipe.pairing.pairs < 40
    dropped = pipe.pairing.drops[pairing.DROP_OVERFLOW]
    assert dropped == 40 - 8
    (warning,) = caplog.records
    assert f"dropped {dropped} frames while pairing (overflow {dropped})" in warning.message
    assert "in the order they were captured" in warning.message
    caplog.clear()
    with Pipeline(PipelineParams(rig)) as pipe, caplog.at_level("WARNING", "stereod.pipeline"):
        assert list(pipe.run(left)) == []
    assert "got 40 left frames and no right one: nothing can be paired" in caplog.text


@pytest.mark.parametrize("skew_ms", [30.0, -30.0])
def test_a_first_sight_of_eyes_apart_in_time_says_how_little_its_depth_is_known(
    skew_ms: float,
) -> None:
    """A ball at 2 m, 0.8 m/s, the right eye 30 ms after the left (or before). Its first sight
    cannot be brought to one instant (no image motion yet): its centroids, 30 ms apart, read
    the depth 0.5 to 1 m off. Its published sigma says so (the truth within three of them;
    it said 7 cm, 14 of them off); from the next pair on the eyes are brought to one instant
    and the position is within a few sigmas and a centimetre or two."""
    ball = Ball(heading_deg=120, speed_mps=0.8, centre_m=(0.0, 0.1, 2.0))
    scene = Scene(skew_s=skew_ms * 1e-3, balls=[ball], seed=2)
    results = run_scene(scene, PipelineParams(scene.rig))
    seen = [(r.t_ns, s) for r in results for s in r.tracks if s.track_id == 1]
    (t0, first), (t1, second) = seen[0], seen[1]
    off = abs(float(first.position_m[2]) - float(ball.position_m((t0 - scene.t0_ns) * 1e-9)[2]))
    assert off > 0.3, off  # (the scene still shows what is widened for)
    assert off < 3.0 * float(sigma(first)[2]), (off, sigma(first))
    truth = ball.position_m((t1 - scene.t0_ns) * 1e-9)
    assert float(np.linalg.norm(second.position_m - truth)) < 0.03
