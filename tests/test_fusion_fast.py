"""The fusion's cheaper paths give what the plain formulas give: position and velocity fused
in one stacked operation, and a rig's clock offset kept between observations."""

from __future__ import annotations

import numpy as np

from stereod.fusion import rows as tab
from stereod.fusion.clock import ClockWatch
from stereod.fusion.fuser import Fuser, fuse_gaussians
from stereod.fusion.room import RigPose, Room
from stereod_fakes.room_messages import RigSim, Walker

FRAME_NS = 33_333_333


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` random symmetric positive definite 3x3 matrices, (n, 9) row-major, m^2."""
    a = rng.normal(size=(n, 3, 3)) * 0.1
    return (a @ a.transpose(0, 2, 1) + 0.01 * np.eye(3)).reshape(n, 9)


def test_fused_states_are_each_runs_information_form_fusion() -> None:
    """``rows.fuse_states`` on rows of runs of 1 to 4 members gives, for every run, the
    position and velocity that ``fuse_gaussians`` (``numpy.linalg.inv``, member by member)
    gives, within 1e-12 relative, and exactly what ``rows.fuse_groups`` gives for each."""
    rng = np.random.default_rng(7)
    sizes = [1, 2, 1, 3, 4, 1, 2]
    n = sum(sizes)
    f = np.zeros((n, tab.WIDTH))
    f[:, tab.POS] = rng.normal(size=(n, 3)) * 3.0
    f[:, tab.VEL] = rng.normal(size=(n, 3))
    f[:, tab.PCOV], f[:, tab.VCOV] = _spd(rng, n), _spd(rng, n)
    starts = np.cumsum([0, *sizes[:-1]])
    got = tab.fuse_states(f, starts)
    assert got.shape == (len(sizes), tab.WIDTH)
    for g, (a, size) in enumerate(zip(starts, sizes, strict=True)):
        for x, c in ((tab.POS, tab.PCOV), (tab.VEL, tab.VCOV)):
            mean, cov = fuse_gaussians(
                [f[j, x] for j in range(a, a + size)],
                [f[j, c].reshape(3, 3) for j in range(a, a + size)],
            )
            assert np.allclose(got[g, x], mean, rtol=1e-12, atol=1e-12)
            assert np.allclose(got[g, c], cov.ravel(), rtol=1e-12, atol=1e-15)
    for x, c in ((tab.POS, tab.PCOV), (tab.VEL, tab.VCOV)):
        mean, cov = tab.fuse_groups(f[:, x], f[:, c], starts)
        assert np.array_equal(got[:, x], mean) and np.array_equal(got[:, c], cov)


def test_a_clock_estimate_asked_every_step_follows_every_observation() -> None:
    """Rig c's clock is 25 ms ahead. A clock watch asked for c's offset after every step (as
    the node's status and its association do) ends with the same estimate, to the bit, as one
    asked only at the end, and that estimate is 25 ms within 5 ms: an offset kept between
    steps is dropped whenever an observation comes in."""
    a = RigPose(name="a")
    c = RigPose(name="c", translation_m=(4.0, 0.0, 4.0), rotation_deg=(0.0, -90.0, 0.0))
    walkers = [Walker(1, (0.0, 0.0, 3.0), (0.8, 0.0, 0.3))]

    def watch(ask: bool) -> tuple[ClockWatch, list[float | None]]:
        sims = {
            "a": RigSim(a, depth_sigma_per_m2=0.005, seed=41),
            "c": RigSim(c, depth_sigma_per_m2=0.005, seed=42, clock_offset_ns=25_000_000),
        }
        fuser = Fuser(Room(name="lab", rigs=[a, c]))
        clock = ClockWatch(["a", "c"], bound_ms=20.0, correct=False)
        asked = []
        for k in range(120):
            for sim in sims.values():
                fuser.ingest(sim.message(walkers, k * FRAME_NS))
                t = fuser.latest_ns()
                assert t is not None
                clock.observe(fuser.fuse(t, [sim.pose.name]))
                if ask:
                    asked.append(clock.estimate("c").offset_ms)
        return clock, asked

    every, asked = watch(True)
    once, _ = watch(False)
    end = once.estimate("c")
    assert end.offset_ms is not None and abs(end.offset_ms - 25.0) < 5.0, end
    assert every.estimate("c") == end
    # The estimate moved as observations came in (it was not held from an early step).
    assert len({x for x in asked if x is not None}) > 10


def test_strains_moved_on_at_once_are_each_members_own_step() -> None:
    """``rows.strain_steps`` over members of several tracks, each with its own time step
    (negative ones included: no move), gives the floats ``rows.strain_step`` gives track by
    track, to a unit in the last place (numpy's SIMD ``expm1`` and the C library's differ by
    one on some CPUs), and a negative step's exactly."""
    rng = np.random.default_rng(11)
    sizes = [2, 3, 2, 4, 2]
    dts = [0.033, -0.01, 0.0, 0.5, 2.0]
    strain = rng.uniform(0.0, 20.0, sum(sizes))
    nis = rng.uniform(0.0, 40.0, sum(sizes))
    run = np.repeat(np.arange(len(sizes)), sizes)
    got = tab.strain_steps(strain, nis, np.array(dts)[run]).tolist()
    want = []
    for a, size, dt in zip(np.cumsum([0, *sizes[:-1]]), sizes, dts, strict=True):
        want += tab.strain_step(strain[a : a + size].tolist(), nis[a : a + size].tolist(), dt)
    np.testing.assert_array_max_ulp(np.array(got), np.array(want), maxulp=1)
    assert got[2:5] == strain[2:5].tolist()  # the negative step moved nothing


def test_a_rigs_observations_kept_in_one_array_are_the_last_window_in_order() -> None:
    """A clock watch keeps each rig's last ``window`` observations in one array it reads as
    two columns: after every one of 1000 appends (the buffer wrapping many times), the
    columns are a ``deque(maxlen=window)``'s contents in order, and the robust mean and its
    standard error are those of ``numpy.average`` over them within three robust sigmas."""
    from collections import deque

    from stereod.fusion.clock import MIN_SAMPLES, _Samples, _weighted_median

    rng = np.random.default_rng(5)
    window = 37
    watch = ClockWatch(["a", "b"], window=window)
    kept: deque[tuple[float, float]] = deque(maxlen=window)
    for k in range(1000):
        obs = (float(rng.normal(12.0, 3.0)), float(rng.uniform(0.1, 5.0)))
        watch._samples["b"].append(*obs)
        watch._means.pop("b", None)
        kept.append(obs)
        x, w = watch._samples["b"].columns()
        assert x.tolist() == [v for v, _ in kept] and w.tolist() == [u for _, u in kept], k
        if len(kept) >= MIN_SAMPLES and k % 97 == 0:
            xs, ws = np.array([v for v, _ in kept]), np.array([u for _, u in kept])
            mid = _weighted_median(xs, ws)
            sigma = 1.4826 * _weighted_median(np.abs(xs - mid), ws)
            inside = np.abs(xs - mid) <= 3.0 * sigma
            mean = float(np.average(xs[inside], weights=ws[inside]))
            spread = float(np.average((xs[inside] - mean) ** 2, weights=ws[inside]))
            est = watch.estimate("b")
            assert est.offset_ms == mean and est.samples == min(k + 1, window)
            assert est.sigma_ms == float(np.sqrt(spread / inside.sum()))
    assert isinstance(watch._samples["b"], _Samples)
