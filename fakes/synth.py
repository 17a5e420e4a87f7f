"""Synthetic stereo scenes with known 3D truth, and the ``synthetic`` driver that plays them.

The rig is the canonical one of paper sec. III (two parallel pinhole cameras ``baseline_m``
apart, square pixels, principal point at the image centre), looking at a textured wall at
``wall_m``. Spheres move on straight lines at constant velocity; each eye renders them at its
own capture instant, so a skew between the eyes shows up in the images exactly as it would with
free-running cameras. Sensor noise, a slow lighting drift and colour are optional. The truth
(every sphere's trajectory and the rig) is written beside the recording as ``truth.json``.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from stereod.errors import ConfigError, InputError, MissingInputError, describe_validation_error
from stereod.files.bounds import UTC_NS_MAX
from stereod.sources.frames import Driver, Eye, EyeSource, Frame, SourceInfo, StereoSource
from stereod.sources.recording import Codec
from stereod.sources.recording_writer import RecordingWriter
from stereod.vision.geometry.stereo import CanonicalRig

from .rig import RayCaster, RigSpec

TRUTH = "truth.json"
MAX_SIDE_PX = 4096
"""The largest synthetic image width or height, px."""


class Ball(BaseModel):
    """A sphere on a straight line: at ``t_mid_s`` it is at ``centre_m`` (rig frame, m), and it
    moves at ``speed_mps`` along ``heading_deg`` (eq. 23's convention) in the XZ plane, plus
    ``vy_mps`` vertically. It is visible between ``t_on_s`` and ``t_off_s``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    centre_m: tuple[float, float, float] = (0.0, 0.1, 1.8)
    heading_deg: float = 60.0
    speed_mps: float = Field(0.7, ge=0.0)
    vy_mps: float = 0.0
    radius_m: float = Field(0.05, gt=0.0)
    brightness: float = Field(225.0, ge=0.0, le=255.0, description="Grey level of the lit side")
    t_mid_s: float = 2.0
    t_on_s: float = 1.2
    t_off_s: float = 2.8
    t_stop_s: float | None = Field(None, description="From this time on the ball stands still")
    t_resume_s: float | None = Field(
        None, description="From this time on a stopped ball moves on at its velocity"
    )

    @property
    def velocity_mps(self) -> np.ndarray:
        h = math.radians(self.heading_deg)
        return np.array([self.speed_mps * math.sin(h), self.vy_mps, self.speed_mps * math.cos(h)])

    def position_m(self, t_s: float | np.ndarray) -> np.ndarray:
        """(3,) or (n, 3) rig-frame position (m) at time(s) ``t_s`` (s from the scene's start)."""
        t = np.asarray(t_s, dtype=np.float64)
        if self.t_stop_s is not None:
            moving = np.minimum(t, self.t_stop_s)
            if self.t_resume_s is not None:
                moving = moving + np.maximum(t - max(self.t_resume_s, self.t_stop_s), 0.0)
            t = moving
        return np.asarray(self.centre_m) + (t[..., None] - self.t_mid_s) * self.velocity_mps

    def velocity_at(self, t_s: float) -> np.ndarray:
        """(3,) velocity (m/s) at ``t_s``: zero once stopped."""
        stopped = self.t_stop_s is not None and t_s >= self.t_stop_s
        if stopped and self.t_resume_s is not None and self.t_stop_s is not None:
            stopped = t_s < max(self.t_resume_s, self.t_stop_s)
        return np.zeros(3) if stopped else self.velocity_mps

    def visible(self, t_s: float) -> bool:
        return self.t_on_s <= t_s <= self.t_off_s


class Scene(BaseModel):
    """Everything needed to render a stereo sequence; units in the field names. The bounds
    keep a scene renderable: at most 4096 px a side, 1000 Hz, an hour."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    width_px: int = Field(640, gt=0, le=MAX_SIDE_PX)
    height_px: int = Field(480, gt=0, le=MAX_SIDE_PX)
    hfov_deg: float = Field(60.0, ge=1.0, le=179.0)
    baseline_m: float = Field(0.060, gt=0.0, le=10.0)
    fps: float = Field(15.0, ge=0.1, le=1000.0)
    duration_s: float = Field(4.0, gt=0.0, le=3600.0)
    skew_s: float = Field(
        0.0, ge=-1.0, le=1.0, description="Right eye's capture delay after the left eye, s"
    )
    noise_sigma: float = Field(
        1.5, ge=0.0, le=100.0, description="Sensor noise, grey levels (1 sigma)"
    )
    drift: float = Field(0.0, ge=0.0, lt=1.0, description="Lighting gain amplitude (fraction)")
    drift_period_s: float = Field(20.0, ge=0.01, le=1e6)
    wall_m: float = Field(
        4.0, ge=0.01, le=1000.0, description="Distance of the textured background wall, m"
    )
    color: bool = False
    readout_s: float = Field(
        0.0,
        ge=0.0,
        le=0.1,
        description="Rolling shutter: row y is captured readout_s * y / height_px after the "
        "frame's instant, s (0: global shutter)",
    )
    seed: int = Field(0, ge=0, le=2**32 - 1)
    t0_ns: int = Field(
        1_000_000_000, ge=0, le=UTC_NS_MAX, description="Monotonic time of the first frame, ns"
    )
    balls: list[Ball] = Field(default_factory=lambda: [Ball()], max_length=100)
    rig_spec: RigSpec | None = Field(
        None,
        description="A non-canonical rig (own intrinsics, distortion, rotation); "
        "hfov_deg and baseline_m then only size the wall's texture",
    )

    @property
    def rig(self) -> CanonicalRig:
        return CanonicalRig(self.baseline_m, self.hfov_deg, self.width_px, self.height_px)

    @property
    def n_frames(self) -> int:
        return int(math.floor(self.duration_s * self.fps + 1e-9))

    def frame_time_s(self, eye: Eye, k: int) -> float:
        """Capture instant of frame ``k`` of ``eye`` in seconds from the scene's start."""
        return k / self.fps + (self.skew_s if eye is Eye.RIGHT else 0.0)

    def t_ns(self, t_s: float) -> int:
        return self.t0_ns + round(t_s * 1e9)


def scene_from_truth(path: Path) -> Scene:
    """Load the :class:`Scene` a recording was rendered from (its ``truth.json``)."""
    try:
        return Scene.model_validate_json(path.read_bytes())
    except FileNotFoundError as exc:
        raise MissingInputError(f"{path}: no such truth file") from exc
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read the truth file: {exc.strerror}") from exc
    except ValidationError as exc:
        raise InputError(
            f"{path}: not a scene truth file: {describe_validation_error(exc)}"
        ) from exc


_SUPERSAMPLE = 8
_SUB = (np.arange(_SUPERSAMPLE) + 0.5) / _SUPERSAMPLE - 0.5


def _paint_disc(img: np.ndarray, u: float, v: float, r: float, value: float) -> None:
    """Blend a disc of centre (u, v) and radius r (px) into ``img`` (h, w, c) float32 in place,
    each pixel weighted by the share of it the disc covers (8 x 8 supersampling; pixel (i, j)
    spans [j - 0.5, j + 0.5] x [i - 0.5, i + 0.5]), so the disc's centroid is (u, v) to about a
    hundredth of a pixel wherever it falls."""
    h, w = img.shape[:2]
    x0, x1 = max(int(np.floor(u - r)) - 1, 0), min(int(np.ceil(u + r)) + 2, w)
    y0, y1 = max(int(np.floor(v - r)) - 1, 0), min(int(np.ceil(v + r)) + 2, h)
    if x0 >= x1 or y0 >= y1:
        return
    xs = (np.arange(x0, x1)[:, None] + _SUB[None, :]).ravel() - u
    ys = (np.arange(y0, y1)[:, None] + _SUB[None, :]).ravel() - v
    inside = (ys[:, None] ** 2 + xs[None, :] ** 2) <= r * r
    cover = inside.reshape(y1 - y0, _SUPERSAMPLE, x1 - x0, _SUPERSAMPLE).mean(axis=(1, 3))
    patch = img[y0:y1, x0:x1]
    patch += (value - patch) * cover[:, :, None].astype(np.float32)


class Renderer:
    """Draws the frames of a :class:`Scene` (deterministic for a given seed)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        rig = scene.rig
        self._rig = rig
        rng = np.random.default_rng(scene.seed)
        pad = int(math.ceil(rig.baseline_m * rig.focal_px / scene.wall_m)) + 4
        h, w = scene.height_px, scene.width_px + pad
        channels = 3 if scene.color else 1
        tex = np.zeros((h, w, channels), np.float32)
        for scale, amp in ((64, 20.0), (16, 10.0), (4, 5.0)):
            small = rng.normal(0.0, 1.0, (h // scale + 2, w // scale + 2, channels))
            up = cv2.resize(small.astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
            tex += amp * up.reshape(h, w, channels)
        tex += 100.0 + np.linspace(-15, 15, w, dtype=np.float32)[None, :, None]
        self._texture = np.clip(tex, 0, 255)
        self._wall_disp = rig.baseline_m * rig.focal_px / scene.wall_m
        self._pad = pad
        self._rng = np.random.default_rng(scene.seed + 1)

    def background(self, eye: Eye) -> np.ndarray:
        """The wall as ``eye`` sees it, float32 (h, w, c): a wall point at left column x is at
        right column x - B f / Z_wall (its disparity). Through a non-canonical rig every
        pixel's ray is cast onto the wall instead."""
        if self.scene.rig_spec is not None:
            return self._background_cast(eye)
        x0 = self._wall_disp if eye is Eye.RIGHT else 0.0
        m = np.array([[1, 0, x0], [0, 1, 0]], np.float32)
        bg = cv2.warpAffine(
            self._texture,
            m,
            (self.scene.width_px, self.scene.height_px),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        )
        return bg.reshape(self.scene.height_px, self.scene.width_px, -1)

    def _background_cast(self, eye: Eye) -> np.ndarray:
        sc = self.scene
        assert sc.rig_spec is not None
        caster = RayCaster(sc.rig_spec, sc.width_px, sc.height_px)
        u, v, _ = caster.plane_coords(eye, np.eye(3), np.array([0.0, 0.0, sc.wall_m]))
        f, r = self._rig.focal_px, self._rig
        map_x = (f * (u + r.baseline_m / 2) / sc.wall_m + r.cx_px).astype(np.float32)
        map_y = (f * v / sc.wall_m + r.cy_px).astype(np.float32)
        tex = self._texture
        planes = [
            caster.average(
                cv2.remap(
                    tex[..., c], map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
                )
            )
            for c in range(tex.shape[2])
        ]
        return np.stack(planes, axis=-1).astype(np.float32)

    def project(self, eye: Eye, p_m: np.ndarray) -> tuple[float, float, float]:
        """Image position (px) of a world point in ``eye`` and its depth in that camera (m)."""
        spec = self.scene.rig_spec
        if spec is None:
            left_px, right_px = self._rig.project(p_m[None, :])
            u, v = (left_px if eye is Eye.LEFT else right_px)[0]
            return float(u), float(v), float(p_m[2])
        uv = spec.project(eye, p_m[None, :])[0]
        depth = float(spec.to_camera(eye, p_m[None, :])[0, 2])
        return float(uv[0]), float(uv[1]), depth

    def silhouette(self, eye: Eye, p_m: np.ndarray, radius_m: float) -> tuple[float, float, float]:
        """Centre (px) and radius (px) of the disc standing for a sphere's image in ``eye``.

        A sphere's silhouette is an ellipse centred on the image of its centre brought r^2 / Z
        nearer along the optical axis (in that camera's coordinates); its semi-minor axis is
        f r / (Z^2 - r^2)^(1/2). The disc keeps that centre and that radius."""
        spec = self.scene.rig_spec
        pc = (
            np.asarray(p_m, dtype=np.float64)
            + np.array([(0.5 if eye is Eye.LEFT else -0.5) * self._rig.baseline_m, 0.0, 0.0])
            if spec is None
            else spec.to_camera(eye, p_m[None, :])[0]
        )
        z = float(pc[2])
        near = pc * np.array([1.0, 1.0, 1.0 - radius_m**2 / z**2])
        if spec is None:
            f = self._rig.focal_px
            u = f * near[0] / near[2] + self._rig.cx_px
            v = f * near[1] / near[2] + self._rig.cy_px
        else:
            f = spec.camera(eye).fx
            u, v = spec.project_camera(eye, near[None, :])[0]
        return float(u), float(v), f * radius_m / math.sqrt(z * z - radius_m**2)

    def render(self, eye: Eye, t_s: float, background: np.ndarray | None = None) -> np.ndarray:
        """One uint8 frame of ``eye`` at ``t_s`` seconds: grey (h, w) or BGR (h, w, 3)."""
        sc = self.scene
        img = (self.background(eye) if background is None else background).copy()
        balls = [b for b in sc.balls if b.visible(t_s)]
        balls.sort(key=lambda b: -float(b.position_m(t_s)[2]))
        for b in balls:
            if sc.readout_s > 0:
                self._paint_rolling(img, eye, b, t_s)
                continue
            p = b.position_m(t_s)
            if p[2] <= b.radius_m:
                continue
            self._paint_ball(img, eye, b, p)
        gain = 1.0 + sc.drift * math.sin(2 * math.pi * t_s / sc.drift_period_s)
        if gain != 1.0:
            img *= gain
        if sc.noise_sigma > 0:
            img += self._rng.normal(0.0, sc.noise_sigma, img.shape).astype(np.float32)
        out = np.clip(img, 0, 255).astype(np.uint8)
        return out if sc.color else out[..., 0]

    def _paint_ball(self, img: np.ndarray, eye: Eye, b: Ball, p: np.ndarray, row0: int = 0) -> None:
        """A lit sphere at ``p`` (m): a dimmer disc, a brighter cap offset towards the light
        (up-left); ``img`` holds the image's rows from ``row0`` on."""
        u, v, r_px = self.silhouette(eye, p, b.radius_m)
        v -= row0
        _paint_disc(img, u, v, r_px, b.brightness * 0.9)
        _paint_disc(img, u - r_px / 4, v - r_px / 4, r_px / 2, b.brightness)

    def _paint_rolling(self, img: np.ndarray, eye: Eye, b: Ball, t_s: float) -> None:
        """The ball through a rolling shutter: each image row painted as the ball is when that
        row is read (``t_s`` plus the row's share of ``readout_s``)."""
        h = img.shape[0]
        line_s = self.scene.readout_s / h
        rows: set[int] = set()
        for t in (t_s, t_s + self.scene.readout_s):
            p = b.position_m(t)
            if p[2] > b.radius_m:
                _, v, r_px = self.silhouette(eye, p, b.radius_m)
                rows.update(range(max(int(v - r_px) - 2, 0), min(int(v + r_px) + 3, h)))
        if rows:
            lo, hi = min(rows), max(rows)
            for y in range(lo, hi + 1):
                p = b.position_m(t_s + y * line_s)
                if p[2] > b.radius_m:
                    self._paint_ball(img[y : y + 1], eye, b, p, y)

    def frames(self) -> Iterator[tuple[Frame, Frame]]:
        """Both eyes' frames in order, stamped with the scene's monotonic times (ns)."""
        sc = self.scene
        bgs = {eye: self.background(eye) for eye in Eye}
        for k in range(sc.n_frames):
            pair = []
            for eye in Eye:
                t = sc.frame_time_s(eye, k)
                pair.append(Frame(eye, self.render(eye, t, bgs[eye]), sc.t_ns(t), k))
            yield pair[0], pair[1]


def write_scene(
    scene: Scene,
    out: Path,
    codec: Codec = Codec.FFV1,
    on_pair: Callable[[int], None] | None = None,
) -> Path:
    """Render ``scene`` into recording directory ``out`` with its ``truth.json``; return ``out``.
    ``on_pair(k)`` is called after stereo frame ``k`` is written (progress)."""
    with RecordingWriter(
        out,
        scene.width_px,
        scene.height_px,
        fps=scene.fps,
        codec=codec,
        color=scene.color,
        settings={"synthetic": True},
    ) as writer:
        for k, (left, right) in enumerate(Renderer(scene).frames()):
            writer.write(left)
            writer.write(right)
            if on_pair is not None:
                on_pair(k)
        writer.write_text(TRUTH, truth_text(scene))
    return out


def truth_text(scene: Scene) -> str:
    """The ``truth.json`` of a recording of ``scene``: the scene itself, which
    :func:`scene_from_truth` reads back."""
    return json.dumps(scene.model_dump(mode="json"), indent=2) + "\n"


class _SynthEye(EyeSource):
    def __init__(self, eye: Eye, source: _SynthSource) -> None:
        self.eye = eye
        self._source = source
        self._k = 0

    def read(self) -> Frame | None:
        src = self._source
        sc = src.scene
        n = sc.n_frames
        if self._k >= n and not src.flags.loop:
            return None
        k = self._k
        self._k += 1
        lap, i = divmod(k, n)
        t_scene = sc.frame_time_s(self.eye, i)  # each lap plays the scene's own instants again
        t = t_scene + lap * n / sc.fps
        if src.prerendered is not None:
            img = src.prerendered[self.eye][i]
        else:
            with src.render_lock:
                img = src.renderer.render(self.eye, t_scene, src.backgrounds[self.eye])
        if not src.flags.live:
            return Frame(self.eye, img, sc.t_ns(t), k)
        # Like a camera: the frame is delivered at its capture instant, stamped on the host's
        # monotonic clock; the clock starts at the first read of either eye.
        start = src.start_s()
        delay = start + t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        return Frame(self.eye, img, round((start + t) * 1e9), k)


class _SynthSource(StereoSource):
    def __init__(self, scene: Scene, flags: SynthFlags) -> None:
        self.scene = scene
        self.flags = flags
        self.render_lock = threading.Lock()
        self.renderer = Renderer(scene)
        self.backgrounds = {eye: self.renderer.background(eye) for eye in Eye}
        self.prerendered: dict[Eye, np.ndarray] | None = None
        if flags.prerender:
            self.prerendered = {eye: self._prerender(eye) for eye in Eye}
        self._start_s: float | None = None
        # A loop's times go past the scene, and a live source stamps its frames on the host's
        # clock: the scene's truth holds for neither.
        files = {} if flags.loop or flags.live else {TRUTH: truth_text(scene)}
        info = SourceInfo(
            scene.width_px, scene.height_px, scene.fps, flags.live, "synthetic scene", files=files
        )
        super().__init__(_SynthEye(Eye.LEFT, self), _SynthEye(Eye.RIGHT, self), info)

    def _prerender(self, eye: Eye) -> np.ndarray:
        """Every frame of one eye, rendered into one array made first (n, h, w[, 3]) uint8, so
        that the renderer's scratch arrays are freed around it rather than between frames."""
        sc = self.scene
        first = self.renderer.render(eye, sc.frame_time_s(eye, 0), self.backgrounds[eye])
        frames = np.empty((sc.n_frames, *first.shape), first.dtype)
        frames[0] = first
        for k in range(1, sc.n_frames):
            frames[k] = self.renderer.render(eye, sc.frame_time_s(eye, k), self.backgrounds[eye])
        return frames

    def start_s(self) -> float:
        """The host's monotonic time (s) of the scene's start: the first read."""
        with self.render_lock:
            if self._start_s is None:
                self._start_s = time.monotonic()
            return self._start_s


MAX_PRERENDER_BYTES = 8 * 2**30
"""The most memory (bytes, both eyes, colour) ``prerender`` may take: a scene beyond it is
refused when the options are read (``run --check`` says so), not when it fails to open."""


class SynthFlags(BaseModel):
    """How the ``synthetic`` driver plays its scene (options beside the scene's own fields)."""

    model_config = ConfigDict(extra="forbid")

    live: bool = Field(
        False, description="Deliver each frame at its capture instant, like a camera"
    )
    prerender: bool = Field(False, description="Render every frame when opened, not when read")
    loop: bool = Field(False, description="Start again at the end, timestamps continuing")


class SyntheticDriver(Driver):
    """Render a :class:`Scene` on the fly (the ``[driver.options]`` table is the scene).

    With ``live = true`` it behaves like a camera: each eye delivers its frames at their capture
    instants on the host's monotonic clock, and the daemon treats it as live (one thread per eye,
    drop-oldest queues). ``prerender = true`` renders every frame when the source opens, so
    that rendering costs nothing while it plays (benchmarks); ``loop = true`` plays the scene
    again and again, timestamps continuing."""

    name = "synthetic"

    def __init__(self, options: dict[str, Any]) -> None:
        options = dict(options)
        own = {k: options.pop(k) for k in list(options) if k in SynthFlags.model_fields}
        try:
            self.flags = SynthFlags.model_validate(own)
            self.scene = Scene.model_validate(options)
        except ValidationError as exc:
            raise ConfigError(describe_validation_error(exc, "driver.options", Scene)) from exc
        self.live = self.flags.live
        if self.flags.prerender:
            sc = self.scene
            need = 2 * sc.n_frames * sc.width_px * sc.height_px * 3
            if need > MAX_PRERENDER_BYTES:
                raise ConfigError(
                    f"driver.options.prerender: {sc.n_frames} frames an eye at "
                    f"{sc.width_px}x{sc.height_px} need {need / 2**30:.3g} GiB, over "
                    f"{MAX_PRERENDER_BYTES / 2**30:g} GiB; shorten duration_s, or set "
                    "prerender = false to render each frame as it is read"
                )

    def open(self) -> StereoSource:
        return _SynthSource(self.scene, self.flags)

    def options_read(self) -> dict[str, Any]:
        return {
            **self.flags.model_dump(mode="json", exclude_unset=True),
            **self.scene.model_dump(mode="json", exclude_unset=True),
        }

    def frame_size(self) -> tuple[int, int]:
        return self.scene.width_px, self.scene.height_px
