"""The fusion weighs each rig's position by its error along its viewing ray: rig messages built
here as a stereo rig's are (its depth error moves the point along its ray, ``X / Z`` in X per
unit of depth; the published sigmas the diagonal of that covariance), two rigs at right angles
seeing one object off both their axes, fused against the known truth."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.bus.messages import ObjectsMessage
from stereod.fusion.frames import ray_cov
from stereod.fusion.fuser import Fuser
from stereod.fusion.room import RigPose, Room
from stereod_fakes.room_messages import RigSim, Walker

FRAME_NS = 33_333_333
A = RigPose(name="a")
"""At the room's origin, looking along +Z."""
C = RigPose(name="c", translation_m=(4.0, 0.0, 4.0), rotation_deg=(0.0, -90.0, 0.0))
"""At (4, 0, 4), looking along -X: at right angles to a."""
TRUTH = np.array([1.3, 0.1, 3.0])
"""The object, still, in the room frame (m): 23 deg off a's axis and 18 deg off c's."""
DEPTH_SIGMA_M = {"a": 0.05, "c": 0.02}
"""Each rig's depth sigma, m (c nearer the object)."""
LATERAL_SIGMA_M = 0.004


def _stereo_message(
    sim: RigSim, pose: RigPose, t_ns: int, rng: np.random.Generator, bias_m: float
) -> ObjectsMessage:
    """``sim``'s message of the object at ``t_ns`` with its position replaced by a stereo
    measurement: depth error (plus ``bias_m``) along the viewing ray, lateral error across,
    and the published sigmas the square roots of that covariance's diagonal."""
    msg = sim.message([Walker(1, tuple(TRUTH), (0.0, 0.0, 0.0))], t_ns)
    p = pose.rotation().T @ (TRUTH - pose.translation())
    w = p / p[2]
    sd = DEPTH_SIGMA_M[pose.name]
    depth = sd * rng.standard_normal() + bias_m
    lateral = LATERAL_SIGMA_M * rng.standard_normal(2)
    got = p + depth * np.array([w[0], 0.0, 1.0]) + np.array([lateral[0], lateral[1], 0.0])
    sigma = (float(np.hypot(LATERAL_SIGMA_M, sd * w[0])), LATERAL_SIGMA_M, sd)
    obj = msg.objects[0].model_copy(
        update={"position_m": tuple(float(v) for v in got), "position_sigma_m": sigma}
    )
    return msg.model_copy(update={"objects": [obj]})


def _errors(bias_a_m: float, seed: int, stretch: range = range(200)) -> dict[str, float]:
    """RMS position error (m) against the truth over the fusion steps of ``stretch`` (of 200,
    rig a's depth off by ``bias_a_m`` in them and only in them): each rig alone (its track
    moved into the room) and fused. Every step has one room track, both rigs its members."""
    fuser = Fuser(Room(name="lab", rigs=[A, C]))
    sims = {"a": RigSim(A, seed=seed), "c": RigSim(C, seed=seed + 1)}
    rng = np.random.default_rng(seed)
    sq: dict[str, list[float]] = {"a": [], "c": [], "fused": []}
    for k in range(200):
        t = k * FRAME_NS
        for name, pose in (("a", A), ("c", C)):
            bias = bias_a_m if name == "a" and k in stretch else 0.0
            msg = _stereo_message(sims[name], pose, t, rng, bias)
            assert fuser.ingest(msg)
            p = pose.rotation() @ np.array(msg.objects[0].position_m) + pose.translation()
            if k in stretch:
                sq[name].append(float(np.sum(np.square(p - TRUTH))))
        (tr,) = fuser.fuse(t).tracks
        assert set(tr.members) == {"a", "c"}
        if k in stretch:
            sq["fused"].append(float(np.sum(np.square(tr.position - TRUTH))))
    return {k: float(np.sqrt(np.mean(v))) for k, v in sq.items()}


def test_the_covariance_along_the_ray_keeps_the_published_sigmas() -> None:
    """The rebuilt covariance has the published diagonal, puts the depth error's X share on
    the ray (X-Z correlation X / Z per unit of depth variance), and is positive definite; a
    point on the axis or behind the rig keeps the diagonal."""
    p = np.array([[1.3, 0.1, 3.0], [0.0, 0.2, 2.0], [0.5, 0.0, -1.0]])
    s = np.array([[np.hypot(0.004, 0.05 * 1.3 / 3.0), 0.004, 0.05], [0.01, 0.01, 0.1],
                  [0.01, 0.01, 0.1]])  # fmt: skip
    cov = ray_cov(p, s)
    np.testing.assert_allclose(np.diagonal(cov, axis1=1, axis2=2), np.square(s), rtol=1e-12)
    assert cov[0, 0, 2] == cov[0, 2, 0] and np.isclose(cov[0, 0, 2], 0.05**2 * 1.3 / 3.0)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    for i in (1, 2):
        np.testing.assert_array_equal(cov[i], np.diag(np.square(s[i])))


def test_two_consistent_rigs_fuse_better_than_either() -> None:
    """No bias: the fused error is well below the better rig's (each rig pins the other's
    depth across its own ray)."""
    rms = _errors(0.0, seed=11)
    assert rms["fused"] < 0.5 * min(rms["a"], rms["c"]), rms


def test_a_rig_biased_along_its_ray_does_not_pull_the_fused_position() -> None:
    """Rig a's depth is off by twice its stated sigma, along its ray: the fused position is
    still no worse than the good rig's alone (the bias lies where a claims little)."""
    rms = _errors(2.0 * DEPTH_SIGMA_M["a"], seed=12)
    assert rms["a"] > 1.5 * rms["c"], rms
    assert rms["fused"] <= rms["c"], rms


@pytest.mark.parametrize("sigmas", [3.0, 4.5, 6.0])
def test_a_stretch_biased_beyond_its_sigmas_fades_out_of_the_fusion(sigmas: float) -> None:
    """For two seconds in the middle of seven, rig a's depth is off by 3 to 6 times its stated
    sigma, along its ray (its members disagree beyond a chi-square bound at most steps): over
    that stretch the fused position is no worse than the good rig's alone, and the object
    keeps one room track with both rigs in it (no split)."""
    rms = _errors(sigmas * DEPTH_SIGMA_M["a"], seed=13, stretch=range(80, 140))
    assert rms["a"] > 2.0 * rms["c"], rms
    assert rms["fused"] <= rms["c"], rms
