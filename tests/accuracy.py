"""Accuracy cases from two renderers written apart, and their scoring against the truth.

A case is one scene from one renderer through one rig: the project's own renderer
(``stereod_fakes.synth``, discs through the canonical rig) or the independent ray-caster
(``stereod_fakes.world``: shaded solids, a textured wall and floor, free-running clocks whose
skew wanders between -1/2 and +1/2 frame, per-eye gain, drift, noise). Both give each object's
true 3D centre and velocity at any instant. The scoring matches every published track state to
the object it follows and reports, per object:

- heading and speed error: the median over valid estimates (``heading_valid`` for the heading,
  ``velocity_valid`` for the speed) in the middle 60 % of the object's time in view of
  (estimate - truth at that instant);
- position error as a share of eq. 12's one-pixel depth error at the true depth (median, same
  window);
- how many confirmed track ids followed it (one is right; two is an id switch), how many
  confirmed tracks followed nothing (ghosts), or were seen where no object is for longer than
  the detector's ``absorb_s`` in one stretch (a ghost stretch: a track that followed a robot
  out of view, then held the floor a moved box uncovered, counts as a ghost too);
- in which of its frames in view it was first tracked, and first had a valid velocity.

Used by ``benchmarks/accuracy.py`` (every combination) and by the accuracy tests (a subset).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereod import CanonicalRig, Eye, Frame, PairResult, Pipeline, PipelineParams
from stereod.tracking.motion import angle_diff_deg
from stereod.tracking.types import TrackLifecycle, TrackState
from stereod.vision.detect_params import DetectorParams
from stereod.vision.geometry.rectified import CalibratedRig
from stereod_fakes import world
from stereod_fakes.rig import RigSpec
from stereod_fakes.scenarios import TABLE_I, table_one_scene
from stereod_fakes.synth import Renderer, Scene


@dataclass(frozen=True)
class RigMode:
    """An image size, frame rate and field of view (the Minoru streams both eyes at 320x240
    and 30 Hz, or 640x480 and 15 Hz; its field angle is about 42 deg by one public measure)."""

    width_px: int
    height_px: int
    fps: float
    hfov_deg: float

    @property
    def name(self) -> str:
        return f"{self.width_px}x{self.height_px}@{self.fps:g} {self.hfov_deg:g}deg"

    @property
    def rig(self) -> CanonicalRig:
        return CanonicalRig(0.060, self.hfov_deg, self.width_px, self.height_px)


MODES = (
    RigMode(320, 240, 30.0, 42.0),
    RigMode(320, 240, 30.0, 60.0),
    RigMode(640, 480, 15.0, 42.0),
    RigMode(640, 480, 15.0, 60.0),
)

Truth = Callable[[int], dict[str, tuple[np.ndarray, np.ndarray]]]
"""t_ns -> {object name: (centre (3,) m, velocity (3,) m/s)} for the objects present."""


@dataclass
class Case:
    """One scene of one renderer through one rig mode."""

    renderer: str
    mode: RigMode
    name: str
    seed: int
    frames: Callable[[], Iterator[Frame]]
    truth: Truth
    in_view: Callable[[str, int], bool]
    """Whether an object's centre is in both eyes' images (and it is not wholly hidden)."""
    objects: list[str]
    fast: bool = False
    readout_s: float = 0.0
    """The rolling shutter's readout the scene was rendered with (s), given to the pipeline."""

    @property
    def label(self) -> str:
        return f"{self.renderer} {self.mode.name} {self.name} seed {self.seed}"


WEBCAM = world.Transport(
    rolling_shutter=True, readout_s=0.030, yuyv_422=True, mjpeg_quality=75, flicker_depth=0.2
)
"""What a cheap USB webcam adds: a 30 ms rolling shutter, 4:2:2 chroma, MJPEG at quality 75,
and lamps on 50 Hz mains whose light swings by 20 % at 100 Hz (seen through the exposure of
:data:`WEBCAM_EXPOSURE_S`)."""
WEBCAM_EXPOSURE_S = 1.0 / 60.0
"""A webcam's auto exposure indoors (s): the flicker averages over 1.7 of its periods, so each
row's brightness still swings by about 3 %. (An instantaneous exposure would show the full 20 %
as bands down the frame, which no camera set for mains lighting does.)"""


def world_room(
    preset: str,
    mode: RigMode,
    seed: int,
    *,
    webcam: bool = False,
    quality: dict[str, int] | None = None,
    photometry: dict[str, float] | None = None,
    **kw: object,
) -> Case:
    """One of the independent renderer's room scenes (``lamp_ball``, ``person_sit_walk``,
    ``person_approach``, ``people_crossing``, ``robot_stop_go``, or ``robot_ball`` with a
    heading and speed), optionally through a webcam's transport (:data:`WEBCAM`), whose
    rolling shutter's readout the pipeline is then told of. ``quality`` replaces fields of the
    scene's render quality (``world.Quality``): the suite renders some scenes more coarsely
    than the benchmark (e.g. ``rolling_band_rows`` 8, a band of 1 ms at 320x240 cast at one
    instant, in which a ball at 1 m/s moves 1 mm; the benchmark casts every row apart).
    ``photometry`` replaces fields of its gains and noise (``world.Photometry``)."""
    fn = getattr(world, preset)
    if webcam:
        kw = {**kw, "exposure_s": WEBCAM_EXPOSURE_S}
    scene = fn(
        mode=(mode.width_px, mode.height_px, mode.fps), hfov_deg=mode.hfov_deg, seed=seed,
        skew="wander", **kw,
    )  # fmt: skip
    if webcam:
        scene = dataclasses.replace(scene, transport=WEBCAM)
    if quality:
        scene = dataclasses.replace(scene, quality=dataclasses.replace(scene.quality, **quality))
    if photometry:
        light = dataclasses.replace(scene.photometry, **photometry)
        scene = dataclasses.replace(scene, photometry=light)
    shown = {k: v for k, v in kw.items() if k != "exposure_s"}
    label = preset + "".join(f" {v}" for v in shown.values()) + (" webcam" if webcam else "")
    case = _world_case(scene, mode, label, seed, False)
    case.readout_s = WEBCAM.readout_s if webcam else 0.0
    return case


def through_calibrated_rig(
    case: Case, spec: RigSpec, noise_sigma: float = 0.0
) -> tuple[Case, CalibratedRig]:
    """The case as the eyes of a calibrated rig (``spec``: each eye's intrinsics, lens
    distortion and turn) would see it, and that rig's geometry from its exact calibration.
    Each image px of an eye looks along the ray its rectification gives; the rendered frame
    (a canonical rig's, whose cameras are the rectified ones) is read there, scaled from the
    rig's rectified focal length to the render's. The rectified frame is the render's, so
    the truth stands. Resampling would smooth a rendered sensor's noise where a px falls
    between four, so the case is rendered without it (``photometry={"noise_sigma": 0}``) and
    Gaussian noise of ``noise_sigma`` (grey levels) is added to each resampled frame, seeded
    by the case's seed, the eye and the instant; and without a webcam's transport (its MJPEG
    blocks would be resampled)."""
    w, h = case.mode.width_px, case.mode.height_px
    canon = case.mode.rig
    cal = spec.calibration(w, h)
    rig = CalibratedRig(cal)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    grid = np.column_stack((xs.ravel(), ys.ravel()))
    scale = canon.focal_px / rig.focal_px
    maps: dict[Eye, tuple[np.ndarray, np.ndarray]] = {}
    for eye, rectify, cx in (
        (Eye.LEFT, rig.rectify_left, rig.cx_left_px),
        (Eye.RIGHT, rig.rectify_right, rig.cx_right_px),
    ):
        r = rectify(grid).reshape(h, w, 2)
        maps[eye] = (
            ((r[..., 0] - cx) * scale + canon.cx_px).astype(np.float32),
            ((r[..., 1] - rig.cy_px) * scale + canon.cy_px).astype(np.float32),
        )
    rendered = case.frames

    def frames() -> Iterator[Frame]:
        for f in rendered():
            image = cv2.remap(
                f.image.astype(np.float32),
                *maps[f.eye],
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
            if noise_sigma > 0.0:
                eye = 0 if f.eye is Eye.LEFT else 1
                rng = np.random.default_rng([case.seed, eye, f.t_ns])
                image += rng.standard_normal(image.shape, dtype=np.float32) * noise_sigma
            yield Frame(f.eye, np.clip(image + 0.5, 0.0, 255.0).astype(np.uint8), f.t_ns, f.seq)

    return dataclasses.replace(case, name=f"{case.name} calibrated", frames=frames), rig


CACHE_ENV = "STEREOD_WORLD_CACHE"
"""A directory to keep rendered scenes in (set it to iterate on the tracker in seconds; a
person scene takes minutes to render at 320x240). Unset, every run renders afresh."""


def _cache_dir(scene: world.Scene) -> Path | None:
    """Where a scene's frames are kept: the cache directory, a digest of everything the
    scene is made of (so any change of parameters renders afresh), or None without a cache."""
    root = os.environ.get(CACHE_ENV)
    if not root:
        return None
    text = json.dumps(scene.to_dict(), sort_keys=True, default=str)
    return Path(root) / hashlib.sha256(text.encode()).hexdigest()[:24]


def world_frames(scene: world.Scene) -> Iterator[Frame]:
    """A scene's frames in capture order, read from the cache (:data:`CACHE_ENV`) if they
    were rendered before, else rendered (and stored there, if set)."""
    where = _cache_dir(scene)
    if where is not None and (where / "meta.npy").exists():
        meta = np.load(where / "meta.npy")
        images = np.load(where / "images.npy", mmap_mode="r")
        for (eye, t_ns, seq), image in zip(meta.tolist(), images, strict=True):
            yield Frame(Eye(("left", "right")[eye]), np.array(image), int(t_ns), int(seq))
        return
    kept: list[tuple[int, int, int]] = []
    images_out = None
    n = len(scene.frame_times("left")) + len(scene.frame_times("right"))
    for f in scene.frames():
        if where is not None:
            if images_out is None:
                where.mkdir(parents=True, exist_ok=True)
                images_out = np.lib.format.open_memmap(
                    where / f"images.{os.getpid()}.npy", "w+", np.uint8, (n, *f.image.shape)
                )
            images_out[len(kept)] = f.image
            kept.append((0 if f.eye == "left" else 1, f.t_ns, f.seq))
        yield Frame(Eye(f.eye), f.image, f.t_ns, f.seq)
    if where is not None and images_out is not None and len(kept) == n:
        images_out.flush()
        del images_out
        (where / f"images.{os.getpid()}.npy").replace(where / "images.npy")
        np.save(where / f"meta.{os.getpid()}.npy", np.array(kept, np.int64))
        (where / f"meta.{os.getpid()}.npy").replace(where / "meta.npy")


def _world_case(scene: world.Scene, mode: RigMode, name: str, seed: int, fast: bool) -> Case:
    def frames() -> Iterator[Frame]:
        return world_frames(scene)

    rig = mode.rig

    @functools.cache
    def truth(t_ns: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return scene.truth(t_ns)

    # Whether an object shows at all, ray cast on a coarse grid with one ray per pixel (the
    # full image's supersampled cast of a person near the rig takes seconds), once an instant.
    coarse = dataclasses.replace(
        scene,
        rig=dataclasses.replace(
            scene.rig, width_px=max(scene.rig.width_px // 4, 2),
            height_px=max(scene.rig.height_px // 4, 2),
        ),
        quality=world.Quality(1, 1, 1, 1, 1, 1),
    )  # fmt: skip

    @functools.cache
    def coverage(eye: str, t_ns: int) -> dict[str, float]:
        return coarse.coverage(eye, t_ns)

    def in_view(obj: str, t_ns: int) -> bool:
        got = truth(t_ns).get(obj)
        if got is None or got[0][2] <= 0.1:
            return False
        if not (
            coverage("left", t_ns).get(obj, 0.0) > 0 and coverage("right", t_ns).get(obj, 0.0) > 0
        ):
            return False
        left, right = rig.project(got[0][None, :])
        return all(
            0 <= p[0, 0] <= rig.width_px - 1 and 0 <= p[0, 1] <= rig.height_px - 1
            for p in (left, right)
        )

    return Case(
        "world",
        mode,
        name,
        seed,
        frames,
        truth,
        in_view,
        [o.name for o in scene.objects],
        fast,
    )


def world_robot(heading_deg: float, speed_mps: float, mode: RigMode, seed: int) -> Case:
    """A ball rolling on the floor at a Table I heading and speed (independent renderer)."""
    scene = world.robot_ball(
        heading_deg,
        speed_mps,
        mode=(mode.width_px, mode.height_px, mode.fps),
        hfov_deg=mode.hfov_deg,
        seed=seed,
        skew="wander",
    )
    return _world_case(scene, mode, f"ball {heading_deg:g} deg {speed_mps:g} m/s", seed, False)


def world_preset(preset: str, mode: RigMode, seed: int, **kw: object) -> Case:
    """One of the independent renderer's hard cases: ``crossing``, ``robot_cylinder``,
    ``robot_box``, ``fast_ball`` (with ``direction`` and ``speed_mps``)."""
    fn = getattr(world, preset)
    scene = fn(
        mode=(mode.width_px, mode.height_px, mode.fps),
        hfov_deg=mode.hfov_deg,
        seed=seed,
        skew="wander",
        **kw,
    )
    label = preset + "".join(f" {v}" for v in kw.values())
    return _world_case(scene, mode, label, seed, preset == "fast_ball")


def synth_robot(heading_deg: float, speed_mps: float, mode: RigMode, seed: int) -> Case:
    """A Table I motion from the project's own renderer, the right eye half a frame late."""
    base = table_one_scene(heading_deg, speed_mps, fps=mode.fps, seed=seed)
    scene: Scene = base.model_copy(
        update={
            "width_px": mode.width_px,
            "height_px": mode.height_px,
            "hfov_deg": mode.hfov_deg,
        }
    )
    rig = scene.rig

    def frames() -> Iterator[Frame]:
        for left, right in Renderer(scene).frames():
            yield left
            yield right

    def truth(t_ns: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        t = (t_ns - scene.t0_ns) / 1e9
        return {
            f"ball{i}": (b.position_m(t), b.velocity_at(t))
            for i, b in enumerate(scene.balls)
            if b.visible(t)
        }

    def in_view(obj: str, t_ns: int) -> bool:
        got = truth(t_ns).get(obj)
        if got is None:
            return False
        left, right = rig.project(got[0][None, :])
        return all(
            0 <= p[0, 0] < rig.width_px and 0 <= p[0, 1] < rig.height_px for p in (left, right)
        )

    return Case(
        "synth",
        mode,
        f"ball {heading_deg:g} deg {speed_mps:g} m/s",
        seed,
        frames,
        truth,
        in_view,
        [f"ball{i}" for i in range(len(scene.balls))],
    )


def table_one_cases(renderer: str, mode: RigMode, seed: int) -> list[Case]:
    """The paper's eight Table I motions through one renderer."""
    make = world_robot if renderer == "world" else synth_robot
    return [make(row.heading_deg, row.speed_mps, mode, seed) for row in TABLE_I]


def hard_cases(mode: RigMode, seed: int) -> list[Case]:
    """The independent renderer's crossing pair and non-spherical robots."""
    return [
        world_preset("crossing", mode, seed),
        world_preset("robot_cylinder", mode, seed),
        world_preset("robot_box", mode, seed),
    ]


def fast_cases(mode: RigMode, seed: int) -> list[Case]:
    """Thrown balls at 10 and 20 m/s, across the view and towards the rig."""
    return [
        world_preset("fast_ball", mode, seed, direction=d, speed_mps=v)
        for d in ("lateral", "radial")
        for v in (10.0, 20.0)
    ]


def run_case(case: Case, params: PipelineParams | None = None) -> list[PairResult]:
    """Every pair's result for a case (default parameters: what the daemon would use)."""
    p = params or PipelineParams(case.mode.rig, readout_s=case.readout_s)
    with Pipeline(p) as pipe:
        return list(pipe.run(case.frames(), int(0.75e9 / case.mode.fps)))


@dataclass
class ObjectScore:
    """How one object was measured (NaN where there was nothing to measure)."""

    name: str
    heading_err_deg: float = math.nan
    heading_p90_deg: float = math.nan
    """The 90th percentile of the same estimates' |heading error|: what single frames show,
    which the median hides (a box's heading strays as it crosses the rig)."""
    speed_err: float = math.nan
    """Relative: (estimate - truth) / truth."""
    position_ratio: float = math.nan
    """Median position error over eq. 12's one-pixel depth error at that depth."""
    position_err_m: float = math.nan
    track_ids: list[int] = field(default_factory=list)
    """Confirmed track ids that followed the object."""
    frames_in_view: int = 0
    first_tracked: int | None = None
    """The first of its frames in view (1 = the first) with a track state on it."""
    first_valid: int | None = None
    """The first of its frames in view with a valid velocity on it."""
    valid_estimates: int = 0
    """States scored for the heading (the fewer: a heading is valid only with the speed)."""
    frames_tracked: int = 0
    """Its frames in view with a confirmed track state on it (moving or stopped)."""
    closest_tracked_m: float = math.nan
    """The smallest true depth (m) at which a confirmed track state was on it."""

    @property
    def tracked_share(self) -> float:
        """The share of its frames in view in which a confirmed track was on it."""
        return self.frames_tracked / self.frames_in_view if self.frames_in_view else math.nan


@dataclass
class CaseScore:
    case: Case
    objects: list[ObjectScore]
    ghosts: list[int]
    """Confirmed track ids that followed no object, or had a ghost stretch
    (``ghost_stretch_s``)."""
    ghost_life_s: dict[int, float] = field(default_factory=dict)
    """How long (s) each ghost was reported confirmed or stationary (first to last such
    state; for one that followed an object, its longest ghost stretch)."""
    ghost_stretch_s: dict[int, float] = field(default_factory=dict)
    """Tracks seen (confirmed or stationary) on no object of the truth for longer than
    ``absorb_s`` in one stretch, though most of their states were on one: the longest such
    stretch (s), first to last state of it (states coasting between are passed over, a state
    seen on an object ends it). What a moved object uncovers is learned by the background
    after ``absorb_s``; a track that holds it out longer is a ghost."""


SEEN = (TrackLifecycle.CONFIRMED, TrackLifecycle.STATIONARY)
"""The states of a confirmed track seen in its pair (moving, or stopped)."""


STILL_MPS = 0.05
"""Below this true speed (m/s) an object is stopped: its heading and speed are not scored."""


def _gate_m(rig: CanonicalRig, depth_m: float) -> float:
    """Largest distance (m) at which a track state is taken to be on an object."""
    return max(0.2, 3.0 * float(rig.depth_error_one_px_m(depth_m)))


def score(
    case: Case,
    results: list[PairResult],
    gate_m: float | None = None,
    absorb_s: float = DetectorParams().absorb_s,
) -> CaseScore:
    """Score a run of ``case`` (see the module docstring). ``gate_m``: the largest distance
    (m) of a track state from an object's true centre to be on it (default: three times eq.
    12's one-pixel error at its depth, at least 0.2 m; a person's centre, what their silhouettes
    show of them, is a looser thing). ``absorb_s``: the longest (s) a track may be seen on no
    object in one stretch (the detector's, by default). An object in view that never moves (a
    stool) is scenery, which background subtraction rightly never reports: it is not scored."""
    rig = case.mode.rig
    # Which object each (pair, track) state is on, if any.
    on: dict[int, list[str | None]] = {}
    in_view_at: dict[str, list[int]] = {name: [] for name in case.objects}
    moved: set[str] = set()  # objects seen moving: one that never does (a stool) is scenery
    rows = []
    for k, r in enumerate(results):
        truth = case.truth(r.t_ns)
        visible = {n: truth[n] for n in truth if case.in_view(n, r.t_ns)}
        for n in visible:
            in_view_at[n].append(k)
            if float(np.linalg.norm(visible[n][1])) >= STILL_MPS:
                moved.add(n)
        for s in r.tracks:
            best, best_d = None, math.inf
            for n, (p, _) in visible.items():
                d = float(np.linalg.norm(s.position_m - p))
                gate = gate_m if gate_m is not None else _gate_m(rig, float(p[2]))
                if d < best_d and d <= gate:
                    best, best_d = n, d
            on.setdefault(s.track_id, []).append(best)
            rows.append((k, s, best))
    # A track follows the object most of its states are on.
    follows: dict[int, str | None] = {}
    for tid, names in on.items():
        named = [n for n in names if n is not None]
        follows[tid] = max(set(named), key=named.count) if named else None
    confirmed = {s.track_id for _, s, _ in rows if s.lifecycle in SEEN}
    ghosts = sorted(t for t in confirmed if follows[t] is None)
    life: dict[int, list[int]] = {}
    for _, s, _ in rows:
        if s.track_id in ghosts and s.lifecycle in SEEN:
            life.setdefault(s.track_id, []).append(s.t_ns)
    ghost_life = {t: (max(ts) - min(ts)) * 1e-9 for t, ts in life.items()}
    stretches = {t: s for t, s in _off_stretches(rows).items() if s > absorb_s and t not in ghosts}
    ghosts = sorted([*ghosts, *stretches])
    ghost_life.update(stretches)
    scores = []
    for name in case.objects:
        if name not in moved and in_view_at[name]:
            continue
        o = ObjectScore(name)
        frames = in_view_at[name]
        o.frames_in_view = len(frames)
        o.track_ids = sorted(t for t in confirmed if follows[t] == name)
        if not frames:
            scores.append(o)
            continue
        order = {k: i + 1 for i, k in enumerate(frames)}
        lo = frames[0] + 0.2 * (frames[-1] - frames[0])
        hi = frames[-1] - 0.2 * (frames[-1] - frames[0])
        dh, ds, dp, ratio = [], [], [], []
        tracked: set[int] = set()
        for k, s, n in rows:
            if n == name and k in order and s.lifecycle in SEEN:
                tracked.add(k)
                z = float(case.truth(s.t_ns)[name][0][2])
                o.closest_tracked_m = (
                    z if math.isnan(o.closest_tracked_m) else min(o.closest_tracked_m, z)
                )
            if n != name or follows.get(s.track_id) != name:
                continue
            if k in order:
                i = order[k]
                o.first_tracked = i if o.first_tracked is None else min(o.first_tracked, i)
                if s.velocity_valid:
                    o.first_valid = i if o.first_valid is None else min(o.first_valid, i)
            if not lo <= k <= hi or s.lifecycle not in SEEN:
                continue
            p, v = case.truth(s.t_ns)[name]
            err = float(np.linalg.norm(s.position_m - p))
            dp.append(err)
            ratio.append(err / float(rig.depth_error_one_px_m(float(p[2]))))
            speed = float(np.linalg.norm(v))
            if speed < STILL_MPS:  # stopped: no heading, and no speed to be a share of
                continue
            if s.heading_valid:
                dh.append(angle_diff_deg(s.heading_deg, math.degrees(math.atan2(v[0], v[2]))))
            if s.velocity_valid:
                ds.append((s.speed_mps - speed) / speed)
        o.valid_estimates = len(dh)
        o.frames_tracked = len(tracked)
        if dh:
            o.heading_err_deg = float(np.median(dh))
            o.heading_p90_deg = float(np.percentile(np.abs(dh), 90))
        if ds:
            o.speed_err = float(np.median(ds))
        if dp:
            o.position_err_m = float(np.median(dp))
            o.position_ratio = float(np.median(ratio))
        scores.append(o)
    return CaseScore(case, scores, ghosts, ghost_life, stretches)


def _off_stretches(rows: list[tuple[int, TrackState, str | None]]) -> dict[int, float]:
    """Each track's longest stretch (s) of states seen (confirmed or stationary) on no object,
    from ``rows`` (pair index, state, the object it is on or None) in pair order: first to
    last state of the stretch; coasting and tentative states are passed over, a state seen on
    an object ends it."""
    start: dict[int, int] = {}
    longest: dict[int, float] = {}
    for _, s, on in rows:
        if s.lifecycle not in SEEN:
            continue
        tid = s.track_id
        if on is not None:
            start.pop(tid, None)
            continue
        t0 = start.setdefault(tid, s.t_ns)
        longest[tid] = max(longest.get(tid, 0.0), (s.t_ns - t0) * 1e-9)
    return longest
