"""The fusion step's room tracks held as stacked arrays: what the node publishes from a step's
columns is each room track's object state, and a frame kept while later steps run still gives
its tracks as they were at its step."""

from __future__ import annotations

import math

import numpy as np

from stereod.bus.messages import ObjectState
from stereod.fusion.fuser import Fuser, RoomTrack
from stereod.fusion.output import frame_payloads, object_payloads, speed_heading
from stereod.fusion.room import RigPose, Room
from stereod_fakes.room_messages import RigSim, Walker

FRAME_NS = 33_333_333


def _room() -> Room:
    """Three rigs 2.5 m apart, the outer ones turned 20 deg inwards: overlapping views."""
    rigs = [
        RigPose(name=n, translation_m=(2.5 * i, 0.0, 0.0), rotation_deg=(0.0, turn, 0.0))
        for i, (n, turn) in enumerate((("a", 20.0), ("b", 0.0), ("c", -20.0)))
    ]
    return Room(name="lab", rigs=rigs)


def _walkers() -> list[Walker]:
    """Eight walkers crossing the views at up to 0.8 m/s (handovers, shared tracks)."""
    rng = np.random.default_rng(3)
    return [
        Walker(i, (rng.uniform(-1.0, 6.0), 0.0, rng.uniform(2.0, 6.0)),
               (rng.uniform(-0.8, 0.8), 0.0, rng.uniform(-0.3, 0.3)))
        for i in range(8)
    ]  # fmt: skip


def test_a_steps_payloads_from_its_columns_are_its_tracks_object_states() -> None:
    """Each step's published payloads (``frame_payloads``, from the frame's columns) are, id
    by id, the object states of its room tracks: position and id as the track holds them,
    sigmas the roots of its covariances' diagonals, speed and heading with their sigmas as
    ``speed_heading`` (numpy, from the track's own velocity) gives them, age from its first
    sighting; and the same bytes as writing them from the track objects."""
    room = _room()
    sims = [RigSim(r, seed=k) for k, r in enumerate(room.rigs)]
    walkers = _walkers()
    fuser = Fuser(room)
    checked = shared = 0
    for k in range(60):
        for j, sim in enumerate(sims):
            t = k * FRAME_NS + j * 2_000_000
            fuser.ingest(sim.message(walkers, t))
            frame = fuser.fuse(t, [sim.pose.name])
            got = frame_payloads(frame)
            assert got == object_payloads(frame.tracks, frame.rows)
            assert [i for i, _ in got] == [tr.room_id for tr in frame.tracks] == frame.ids
            shared += len(frame.shared)
            for (rid, body), tr in zip(got, frame.tracks, strict=True):
                st = ObjectState.model_validate_json(body)
                assert st.track_id == rid == tr.room_id and st.state == tr.state
                assert st.stamp_utc_ns == tr.stamp_utc_ns == t
                assert np.array_equal(st.position_m, tr.position)
                assert np.array_equal(st.velocity_mps, tr.velocity)
                assert st.position_sigma_m is not None
                np.testing.assert_allclose(
                    st.position_sigma_m, np.sqrt(np.diag(tr.position_cov)), rtol=1e-15
                )
                speed, speed_sigma, heading, heading_sigma = speed_heading(
                    tr.velocity, tr.velocity_cov
                )
                assert math.isclose(st.speed_mps, speed, rel_tol=1e-12)
                assert st.speed_sigma_mps is not None
                assert math.isclose(st.speed_sigma_mps, speed_sigma, rel_tol=1e-9)
                assert math.isclose(st.heading_deg, heading, rel_tol=1e-12)
                if heading_sigma is None:
                    assert st.heading_sigma_deg is None
                else:
                    assert st.heading_sigma_deg is not None
                    assert math.isclose(st.heading_sigma_deg, heading_sigma, rel_tol=1e-9)
                assert math.isclose(st.age_s, (tr.stamp_utc_ns - tr.first_ns) * 1e-9)
                checked += 1
    assert checked > 500 and shared > 50


def test_a_kept_frame_gives_its_tracks_as_they_were_at_its_step() -> None:
    """Two fusers fed the same messages: one's frames asked for their tracks at once, the
    other's kept over the run and asked only at its end give the same tracks (ids, members,
    strains, states, positions), though the same room tracks were fused again, gained and
    lost members since."""
    room = _room()
    sims = [RigSim(r, seed=10 + k) for k, r in enumerate(room.rigs)]
    walkers = _walkers()
    now, late = Fuser(room), Fuser(room)
    at_once, kept = [], []
    for k in range(60):
        for j, sim in enumerate(sims):
            t = k * FRAME_NS + j * 2_000_000
            msg = sim.message(walkers, t)
            now.ingest(msg)
            late.ingest(msg)
            at_once.append(_described(now.fuse(t, [sim.pose.name]).tracks))
            kept.append(late.fuse(t, [sim.pose.name]))
    assert [_described(f.tracks) for f in kept] == at_once
    sizes = {len(m) for tracks in at_once for _, m, _, _, _ in tracks}
    changed = {  # room tracks whose members changed over the run
        rid for tracks in at_once for rid, m, _, _, _ in tracks if len(m) == 1
    } & {rid for tracks in at_once for rid, m, _, _, _ in tracks if len(m) == 2}
    assert sizes >= {1, 2} and changed


def _described(
    tracks: list[RoomTrack],
) -> list[tuple[int, dict[str, int], dict[tuple[str, int], float], object, list[float]]]:
    return [
        (t.room_id, dict(t.members), dict(t.strain), t.state, t.position.tolist()) for t in tracks
    ]
