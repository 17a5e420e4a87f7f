"""The rig message generators' payload writer (``RigSim.payload``, msgspec) against the wire
model: the same bytes as ``dump_objects`` of the model's message, a payload the model reads
back to the same bytes, and figures that are the walkers' truth moved into the rig frame."""

from __future__ import annotations

import json
import math
from itertools import pairwise

import numpy as np
import pytest

from stereod.bus.messages import ObjectsMessage, ObjectState, dump, dump_objects
from stereod.fusion.room import RigPose, rotation_matrix
from stereod_fakes.room_messages import FOCAL_PX, Crowd, RigSim, Walker

T0 = 1_700_000_000_000_000_000
FRAME_NS = 33_333_333

POSES = [
    RigPose(name="a"),
    RigPose(name="c", translation_m=(4.0, 0.0, 4.0), rotation_deg=(0.0, -90.0, 0.0)),
    RigPose(name="t", translation_m=(-1.5, 0.4, 2.0), rotation_deg=(12.0, 25.0, -7.0)),
]


def crossing(seed: int, n: int = 24) -> list[Walker]:
    """Walkers in and out of the rigs' views (ids end and start again), at t0's of their own."""
    rng = np.random.default_rng(seed)
    return [
        Walker(
            100 + k,
            (float(rng.uniform(-6, 6)), float(rng.uniform(-1, 1)), float(rng.uniform(-1, 9))),
            (float(rng.uniform(-2, 2)), float(rng.normal(0, 0.05)), float(rng.uniform(-2, 2))),
            T0 + int(rng.integers(-(10**9), 10**9)),
        )
        for k in range(n)
    ]


@pytest.mark.parametrize("pose", POSES, ids=lambda p: p.name)
@pytest.mark.parametrize("seed", [0, 7])
def test_payload_is_the_models_json_to_the_byte(pose: RigPose, seed: int) -> None:
    walkers = crossing(seed)
    kw = {"seed": seed, "clock_offset_ns": 40_000_000 * seed, "depth_sigma_per_m2": 0.005}
    model, fast = RigSim(pose, **kw), RigSim(pose, **kw)  # type: ignore[arg-type]
    crowd = Crowd(walkers)
    views: list[set[int]] = []
    for k in range(60):
        t = T0 + k * FRAME_NS
        msg = model.message(walkers, t)
        payload, tracks = fast.payload(crowd, t)
        assert (payload, tracks) == dump_objects(msg)
        # The payload is a valid message, and the model writes what it reads back the same.
        back = ObjectsMessage.model_validate_json(payload)
        assert dump_objects(back) == (payload, tracks)
        for (tid, body), obj in zip(tracks, back.objects, strict=True):
            assert tid == obj.track_id
            assert dump(ObjectState.model_validate_json(body)) == body
        views.append({tid for tid, _ in tracks})
    assert max(map(len, views)) >= 3
    assert any(a - b for a, b in pairwise(views))  # objects leave the view
    assert any(b - a for a, b in pairwise(views))  # and come into it under new ids


def test_empty_view_and_no_walkers() -> None:
    far = [Walker(1, (0.0, 0.0, -5.0), (0.0, 0.0, 0.0), T0)]
    for walkers in ([], far):
        model, fast = RigSim(POSES[0]), RigSim(POSES[0])
        payload, tracks = fast.payload(Crowd(walkers), T0)
        assert (payload, tracks) == dump_objects(model.message(walkers, T0))
        assert json.loads(payload)["objects"] == [] and tracks == []


def test_figures_are_the_truth_in_the_rig_frame() -> None:
    """With no noise, every object is its walker's truth moved into the rig, worked out here
    walker by walker, and a rig reports exactly the walkers in its view."""
    pose = POSES[2]
    walkers = crossing(3, n=40)
    sim = RigSim(pose, lateral_sigma_m=0.0, depth_sigma_per_m2=0.0, velocity_sigma_mps=0.0)
    crowd = Crowd(walkers)
    r = rotation_matrix(*pose.rotation_deg)
    t = np.array(pose.translation_m)
    seen_any = 0
    for k in range(0, 60, 5):
        t_ns = T0 + k * FRAME_NS
        objects = json.loads(sim.payload(crowd, t_ns)[0])["objects"]
        expect = []
        for w in walkers:
            dt = (t_ns - w.t0_ns) / 1e9
            p = r.T @ (np.array(w.start_m) + dt * np.array(w.velocity_mps) - t)
            v = r.T @ np.array(w.velocity_mps)
            if 0.3 < p[2] <= 8.0 and abs(math.degrees(math.atan2(p[0], p[2]))) < 30.0:
                expect.append((p, v))
        assert len(objects) == len(expect)
        seen_any += len(objects)
        for obj, (p, v) in zip(objects, expect, strict=True):
            assert obj["position_m"] == pytest.approx(p, abs=1e-12)
            assert obj["velocity_mps"] == pytest.approx(v, abs=1e-12)
            assert obj["speed_mps"] == pytest.approx(np.linalg.norm(v), abs=1e-12)
            heading = math.degrees(math.atan2(v[0], v[2])) % 360.0
            assert obj["heading_deg"] == pytest.approx(heading, abs=1e-9)
            assert obj["disparity_px"] == pytest.approx(FOCAL_PX * 0.06 / p[2], rel=1e-12)
            u = 320.0 + FOCAL_PX * p[0] / p[2]
            assert obj["left"]["centroid_px"][0] == pytest.approx(u, abs=1e-9)
            assert obj["position_sigma_m"] == [0.0, 0.0, 0.0]
    assert seen_any > 20


def test_crowd_positions_are_each_walkers() -> None:
    walkers = crossing(5)
    crowd = Crowd(walkers)
    for t_ns in (T0, T0 + 123_456_789, T0 - 2 * 10**9):
        expect = np.array([w.position(t_ns) for w in walkers])
        assert np.array_equal(crowd.positions(t_ns), expect)
