"""Articulated people of the independent renderer: truth against the solids' union."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from stereod_fakes.world import (
    Act,
    Capsule,
    Person,
    Photometry,
    Rig,
    Scene,
    Sphere,
    load_scene,
    main,
    people_crossing,
    person_approach,
    person_sit_walk,
    write_scene,
)

NO_PHOTOMETRY = Photometry(left_gain=1.0, right_gain=1.0, drift_amplitude=0.0, noise_sigma=0.0)
SMALL = (96, 72, 15.0)


def union_samples(parts: list, lo: np.ndarray, hi: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Uniform random points of the box [lo, hi] inside the union of the parts, computed
    from each part's own description (capsule: segment centre +- half axis, radius)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n // 200_000):
        p = lo + (hi - lo) * rng.random((200_000, 3))
        inside = np.zeros(len(p), bool)
        for solid, c in parts:
            if isinstance(solid, Capsule):
                a = c - np.asarray(solid.half_axis_m)
                ab = 2.0 * np.asarray(solid.half_axis_m)
                k = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
                d = p - (a + k[:, None] * ab)
            else:
                assert isinstance(solid, Sphere)
                d = p - c
            inside |= (d * d).sum(axis=1) <= solid.radius_m**2
        out.append(p[inside])
    return np.concatenate(out)


def part_box(parts: list) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for solid, c in parts:
        ends = [c] if isinstance(solid, Sphere) else [c - solid.half_axis_m, c + solid.half_axis_m]
        for e in ends:
            lo, hi = np.minimum(lo, e - solid.radius_m), np.maximum(hi, e + solid.radius_m)
    return lo, hi


def test_person_truth_is_the_centroid_and_extent_of_the_union_of_its_solids() -> None:
    scene = person_sit_walk(2.0, mode=SMALL)
    person = scene.object("person")
    assert isinstance(person, Person)
    k = person.height_m / 1.79
    floor = person.floor_y_m
    # Seated and waving, standing up, walking, stopped.
    for t, seated in ((2.0, True), (4.9, None), (6.2, False), (7.5, False)):
        t_ns = scene.to_ns(t)
        d = scene.truth_details(t_ns)["person"]
        parts = person.parts(t)
        lo, hi = part_box(parts)
        np.testing.assert_allclose(d["lo"], lo, atol=1e-12)
        np.testing.assert_allclose(d["hi"], hi, atol=1e-12)
        pts = union_samples(parts, lo, hi, 600_000, seed=int(t * 10))
        assert np.all(pts.min(axis=0) - lo < 0.02) and np.all(hi - pts.max(axis=0) < 0.02)
        np.testing.assert_allclose(d["volume_centroid"], pts.mean(axis=0), atol=0.006)
        # The reported centre is the torso's: the thickest capsule's midpoint.
        torso = max((p for p in parts if isinstance(p[0], Capsule)), key=lambda p: p[0].radius_m)
        np.testing.assert_allclose(d["centre"], torso[1], atol=1e-12)
        np.testing.assert_allclose(scene.truth(t_ns)["person"][0], torso[1], atol=1e-12)
        if seated is not None:  # torso centre 0.30 m above the hips (0.91 m, or 0.47 m seated)
            hips = 0.47 if seated else 0.91
            assert d["centre"][1] == pytest.approx(floor - k * (hips + 0.30), abs=1e-9)
        assert hi[1] == pytest.approx(floor, abs=0.002) or not seated  # feet on the floor
    # Every pixel the person changes lies inside the projection of the reported extent.
    t_ns = scene.to_ns(6.2)
    coarse = replace(scene.room, texel_m=0.012)  # a coarser wall texture: quicker to make
    quiet = replace(scene, photometry=NO_PHOTOMETRY, room=coarse)
    no_person = replace(quiet, objects=(quiet.object("stool"),))
    changed = quiet.render_radiance("left", t_ns) - no_person.render_radiance("left", t_ns)
    rows, cols = np.nonzero(np.abs(changed).sum(axis=2) > 1e-3)
    d = quiet.truth_details(t_ns)["person"]
    corners = np.array(np.meshgrid(*zip(d["lo"], d["hi"]), indexing="ij")).reshape(3, -1).T
    uv = quiet.rig.project("left", corners)
    assert rows.size > 200
    assert cols.min() >= uv[:, 0].min() - 1 and cols.max() <= uv[:, 0].max() + 1
    assert rows.min() >= uv[:, 1].min() - 1 and rows.max() <= uv[:, 1].max() + 1


def test_walk_cycle_swings_legs_and_arms_and_a_stop_is_still() -> None:
    scene = person_sit_walk(3.0, mode=SMALL)
    person = scene.object("person")
    assert isinstance(person, Person)
    seg = person._segments[2]
    walk0, walk1 = seg.t0, seg.t1
    step = np.array([seg.p1[0] - seg.p0[0], 0.0, seg.p1[1] - seg.p0[1]])
    fwd = step / np.linalg.norm(step)
    gaps, arms = [], []
    for t in np.linspace(walk0, walk1, 25):
        parts = person.parts(float(t))
        feet = [c + np.asarray(s.half_axis_m) for s, c in (parts[3], parts[5])]
        hands = [c + np.asarray(s.half_axis_m) for s, c in (parts[7], parts[9])]
        gaps.append((feet[0] - feet[1]) @ fwd)  # along the walk
        arms.append((hands[0] - hands[1]) @ fwd)
    gaps_a, arms_a = np.asarray(gaps), np.asarray(arms)
    assert gaps_a.max() > 0.25 and gaps_a.min() < -0.25  # each leg leads in turn
    assert np.corrcoef(gaps_a, arms_a)[0, 1] < -0.9  # the arms swing against the legs
    assert abs(gaps_a[0]) < 1e-9 and abs(gaps_a[-1]) < 1e-9  # legs together at both ends
    mid = scene.to_ns(0.5 * (walk0 + walk1))
    np.testing.assert_allclose(scene.truth(mid)["person"][1], 1.2 * fwd, atol=1e-6)
    stop0, stop1 = person._segments[3].t0, person._segments[3].t1
    times = [t for t in scene.frame_times("left") if stop0 < scene.time_s(t) < stop1]
    assert len(times) > 10
    first = scene.render_radiance("left", times[0])
    for t in (times[1], times[-1]):
        assert np.array_equal(scene.render_radiance("left", t), first)
        assert np.all(scene.truth(t)["person"][1] == 0.0)


def test_person_approach_walks_straight_to_the_rig() -> None:
    scene = person_approach(mode=SMALL)
    person = scene.object("person")
    assert isinstance(person, Person)
    start = scene.truth(scene.to_ns(1.3))["person"][0]
    end = scene.truth(scene.frame_times("left")[-1])["person"][0]
    assert (start[0], start[2]) == pytest.approx((0.1, 3.5))
    assert (end[0], end[2]) == pytest.approx((0.1, 0.8))
    walk = person._segments[1]
    mid = scene.to_ns(0.5 * (walk.t0 + walk.t1))
    np.testing.assert_allclose(scene.truth(mid)["person"][1], [0.0, 0.0, -1.2], atol=1e-6)
    last = scene.frame_times("left")[-1]
    assert all(scene.visible("person", e, last) for e in ("left", "right"))


def test_two_people_cross_and_the_near_one_hides_the_far_one() -> None:
    scene = people_crossing(mode=SMALL)
    near, far = scene.object("near"), scene.object("far")
    assert isinstance(near, Person) and isinstance(far, Person)
    t_cross = near._segments[0].t0 + 2.4 / 1.2
    t_ns = scene.to_ns(t_cross)
    truth = scene.truth(t_ns)
    assert abs(truth["near"][0][0]) < 1e-9 and abs(truth["far"][0][0]) < 1e-9
    assert truth["near"][1][0] > 1.0 and truth["far"][1][0] < -0.9
    alone = replace(scene, objects=(far,))
    for eye in ("left", "right"):
        assert scene.coverage(eye, t_ns)["far"] < 0.5 * alone.coverage(eye, t_ns)["far"]


def test_person_scene_files_round_trip(tmp_path: Path) -> None:
    person = Person(
        name="p", start_xz_m=(0.0, 2.0), floor_y_m=1.0,
        acts=(Act("stand", 0.1, wave=True), Act("walk", to_xz_m=(0.3, 2.0))),
    )  # fmt: skip
    scene = Scene(rig=Rig(32, 24, 60.0), objects=(person,), duration_s=0.3)
    out = write_scene(scene, tmp_path / "rec")
    assert load_scene(out) == scene
    with (out / "truth.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(scene.all_frame_times())
    row = rows[-1]
    d = scene.truth_details(int(row["t_ns"]))["p"]
    assert row["kind"] == "Person"
    for key, axis in (("min", "lo"), ("max", "hi"), ("vol", "volume_centroid")):
        got = [float(row[f"{key}_{c}_m"]) for c in "xyz"]
        np.testing.assert_allclose(got, d[axis], atol=1e-8)


def test_cli_knows_the_room_presets(capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("person_sit_walk", "person_approach", "people_crossing", "robot_stop_go",
                 "lamp_ball", "lamp_ball_side"):  # fmt: skip
        assert main([name]) == 0
        assert name.split("_")[0] in capsys.readouterr().out
