"""The event-driven fusion step, restricted to the room tracks a rig's message touches and to
those its gate can reach, gives the room tracks of the step that predicts and gates every rig
track against every room track (``tests/fuse_reference.py``), on generated messages of many
rigs and walkers: same ids, members and states, positions to 1e-7 m and velocities to 1e-9 m/s."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.fusion.fuser import Fuser
from stereod.fusion.room import RigPose, Room
from stereod.fusion.rows import gate_d2, inv3, reach
from stereod_fakes.room_messages import RigSim, Walker
from tests.fuse_reference import Fuser as ReferenceFuser

FRAME_NS = 33_333_333
RIGS = 8
TICKS = 170
SILENT = ("r3", range(50, 95))
"""A rig silent for 1.5 s (longer than ``rig_timeout_s``): it loses its links and comes back."""
RESTART = ("r5", 120)
"""A rig whose daemon restarts at this tick (its sequence numbers and track ids start again)."""


def _room() -> Room:
    """Rigs 2.5 m apart along X, turned by up to 25 deg about Y in turn, so that their depth
    axes (the long axis of a track's covariance) cross in the overlaps."""
    rigs = [
        RigPose(
            name=f"r{i}",
            translation_m=(2.5 * i, 0.0, 0.0),
            rotation_deg=(0.0, (-25.0, 0.0, 25.0, 10.0)[i % 4], 0.0),
        )
        for i in range(RIGS)
    ]
    return Room(name="hall", rigs=rigs)


def _walkers(seed: int) -> list[Walker]:
    """Forty walkers, some in pairs closer than a gate (so that a rig's track can contradict
    a room track it cannot join), crossing the rigs' views at up to 1 m/s."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(40):
        x, z = rng.uniform(-2.0, 2.5 * RIGS + 1.0), rng.uniform(1.5, 7.0)
        if i % 5 == 1:  # beside the previous one
            x, z = out[-1].start_m[0] + 0.3, out[-1].start_m[2] + 0.4
        v = (rng.uniform(-1.0, 1.0), 0.0, rng.uniform(-0.6, 0.6))
        out.append(Walker(i, (x, rng.uniform(-0.3, 0.3), z), v))
    return out


def _frame(frame: object) -> list[tuple[object, ...]]:
    return [
        (t.room_id, t.state, t.stamp_utc_ns, dict(t.members), t.last_seen_ns)
        for t in frame.tracks  # type: ignore[attr-defined]
    ]


def _step_both(fast: Fuser, full: ReferenceFuser, msg: object, t: int, rig: str) -> None:
    """One rig message into both fusers, each fusing that rig at ``t``: the same frame."""
    assert fast.ingest(msg) and full.ingest(msg)  # type: ignore[arg-type]
    got, want = fast.fuse(t, [rig]), full.fuse(t, [rig])
    assert _frame(got) == _frame(want), (t, rig)
    assert got.ended == want.ended, (t, rig)
    for a, b in zip(got.tracks, want.tracks, strict=True):
        # Covariances along viewing rays are ill-conditioned (condition numbers of 1e4 and
        # more), and the two fusers invert them by different routes: positions to 1e-7 m,
        # covariances to 1e-6 of each entry.
        np.testing.assert_allclose(a.position, b.position, rtol=0, atol=1e-7)
        np.testing.assert_allclose(a.velocity, b.velocity, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.position_cov, b.position_cov, rtol=1e-6, atol=1e-15)
    assert sorted(got.shared) == sorted(want.shared), (t, rig)
    for rid, ms in got.shared.items():
        assert [(r, s) for r, s, _ in ms] == [(r, s) for r, s, _, _ in want.shared[rid]]


@pytest.mark.parametrize("seed", [1, 2])
def test_the_restricted_step_gives_the_room_tracks_of_gating_every_track(seed: int) -> None:
    room = _room()
    sims = {r.name: RigSim(r, seed=seed * 100 + k) for k, r in enumerate(room.rigs)}
    walkers = _walkers(seed)
    fast, full = Fuser(room), ReferenceFuser(room)
    opened = 0
    for k in range(TICKS):
        if k == RESTART[1]:
            pose = room.rig(RESTART[0])
            assert pose is not None
            sims[RESTART[0]] = RigSim(pose, seed=seed * 100 + 99)
        for j, (name, sim) in enumerate(sims.items()):
            if name == SILENT[0] and k in SILENT[1]:
                continue
            t = k * FRAME_NS + j * 1_000_000
            _step_both(fast, full, sim.message(walkers, t), t, name)
        if k % 10 == 9:  # a full step now and then, as the node's idle step makes
            t = (k + 1) * FRAME_NS
            assert _frame(fast.fuse(t)) == _frame(full.fuse(t)), k
        opened = max(opened, max((t.room_id for t in fast.tracks()), default=0))
    final = fast.tracks()
    assert [t.room_id for t in final] == [t.room_id for t in full.tracks()]
    # The scene did what it is for: many room tracks, handovers, the silent rig's and the
    # restarted rig's tracks joined again, and tracks shared by rigs.
    assert len(final) >= 25 and opened < 80
    assert fast.restarts == {RESTART[0]: 1}
    assert sum(len(t.members) >= 2 for t in final) >= 5


def test_a_crowded_rig_and_rigs_joining_late_give_the_same_room_tracks() -> None:
    """Rigs with more tracks than the row table's first blocks hold (60 walkers before two
    rigs side by side), and a third rig whose first message comes after the others' (the
    table grows while it holds rows): the same room tracks as gating every track."""
    rigs = [RigPose(name=n, translation_m=(x, 0.0, 0.0)) for n, x in (("a", 0), ("b", 1), ("c", 2))]
    room = Room(name="crowd", rigs=rigs)
    rng = np.random.default_rng(5)
    walkers = [
        Walker(i, (rng.uniform(-1.0, 2.0), 0.0, rng.uniform(3.0, 6.0)),
               (rng.uniform(-0.3, 0.3), 0.0, rng.uniform(-0.3, 0.3)))
        for i in range(60)
    ]  # fmt: skip
    sims = {r.name: RigSim(r, seed=k) for k, r in enumerate(rigs)}
    fast, full = Fuser(room), ReferenceFuser(room)
    for k in range(30):
        for j, (name, sim) in enumerate(sims.items()):
            if name == "c" and k < 12:
                continue
            t = k * FRAME_NS + j * 1_000_000
            _step_both(fast, full, sim.message(walkers, t), t, name)
    assert fast.rig_track_count("a") > 40 and fast.rig_track_count("c") > 40
    assert [t.room_id for t in fast.tracks()] == [t.room_id for t in full.tracks()]


def test_the_reach_bound_keeps_every_pair_within_the_gate() -> None:
    """Against the exact squared Mahalanobis distance (``np.linalg.solve``) of random pairs
    with elongated, turned covariances (a stereo rig's depth error) and distances around the
    gate: every pair within the gate is within reach, and the bound drops most far pairs."""
    rng = np.random.default_rng(7)
    n, gate = 2000, 16.27

    def covs(q: np.ndarray) -> np.ndarray:
        sigma = rng.uniform(0.005, 0.02, (n, 3))
        sigma[:, 2] = rng.uniform(0.1, 0.6, n)  # depth: tens of times the others
        s2 = np.square(sigma)
        return (q * s2[:, None, :]) @ np.transpose(q, (0, 2, 1))

    turn = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    # Half the pairs seen along one axis (two rigs side by side), half across.
    a, b = covs(turn), covs(np.where((np.arange(n) % 2)[:, None, None] == 0, turn, turn[::-1]))
    s = a + b
    # Offsets along each pair's longest axis and at random, scaled to d2 in (0, 3 gate).
    w, v = np.linalg.eigh(s)
    along = v[:, :, 2] * np.sqrt(w[:, 2])[:, None]
    rand = np.einsum("nij,nj->ni", np.linalg.cholesky(s), rng.normal(size=(n, 3)))
    d = np.where(rng.random(n)[:, None] < 0.5, along, rand / np.sqrt(3.0))
    d *= np.sqrt(gate * rng.uniform(0.0, 3.0, n))[:, None]
    x = rng.normal(size=(n, 3)) * 5.0
    m = x - d
    exact = np.einsum("ni,ni->n", d, np.linalg.solve(s, d[..., None])[..., 0])
    ta, tb = np.trace(a, axis1=1, axis2=2), np.trace(b, axis1=1, axis2=2)
    near = np.array([reach(x[i : i + 1], ta[i : i + 1], m[i : i + 1], tb[i : i + 1], gate)[0, 0]
                     for i in range(n)])  # fmt: skip
    within = exact <= gate
    assert within.sum() > n // 4
    assert near[within].all()
    assert near[exact > 2.0 * gate].mean() < 0.5
    grid = reach(x[:50], ta[:50], m[:60], tb[:60], gate)  # every x against every m at once
    assert grid.shape == (50, 60) and np.array_equal(np.diagonal(grid), near[:50])
    flat = a.reshape(n, 9)
    np.testing.assert_allclose(gate_d2(x, a.reshape(n, 9), m, b.reshape(n, 9)), exact, rtol=1e-9)
    np.testing.assert_allclose(inv3(flat), np.linalg.inv(a).reshape(n, 9), rtol=1e-8, atol=1e-8)
