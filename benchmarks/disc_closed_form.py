"""Whether a small ball's centre in closed form (the first moments of a soft matte) is as
accurate as the disc fit (:func:`stereod.vision.disc.disc_centres`), and what each costs.

The closed form takes the same blobs the detector hands the fit (frame, background at the
frame's gain, box, starting centre, area). Over the box grown by ``PAD_PX`` it estimates
each pixel's coverage a = (f - b).(o - b) / |o - b|^2 (over the channels), clipped to 0..1,
with b the stored background there and o the object's colour, and takes the centre from
``cv2.moments`` of that float matte. Two ways of taking o:

- ``global``: one colour per blob, the mean of the pixels within r - 1 of the starting centre
  (r the radius of a disc of the blob's area; the centre pixel alone for a ball under 4 px);
- ``local``: the mean of those interior pixels within two pixels of each pixel (the object's
  shading followed), the interior itself weighing 1.

Beside them, ``matte``: the detector's centre without the fit
(:func:`stereod.vision.centroids.matte_centroid`, where the fit starts).

Scenes (rendered here, pixels integrated 16 x 16, the truth known): Lambertian balls over a
smooth random colour texture, noise added; each detected through :class:`Detector` with the
fit and again with the fit's call replaced by a closed form, so both centre the same blobs.
Prints, per scene and method, how many balls, centre error median, p90 and max (px), then
the CPU each takes a blob (ms) on the 3-24 px scene, then the pipeline's errors on the
independent renderer's thrown balls (``tests/accuracy.py``) with each method, and writes the
tables into ``docs/bench/disc_closed_form.md``.

Usage: ``python benchmarks/disc_closed_form.py [--balls N]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import report

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from stereod.vision import detect as detect_module
from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams
from stereod.vision.disc import PAD_PX, Candidate, disc_centres

SUB = 16
"""Samples per pixel side when integrating a pixel's colour."""

Point = tuple[float, float]
Centres = Callable[..., list[Point | None]]
"""A centring method, called as the detector calls :func:`disc_centres`."""


def soft_matte_centres(blobs: Sequence[Candidate], local: bool) -> list[tuple[float, float] | None]:
    """Centre (x, y px) of each blob as the first moments of its soft matte over its box
    grown by ``PAD_PX`` (None where that leaves the image, as the fit): ``local`` takes the
    object's colour near each pixel, else one colour per blob (see the module's docstring)."""
    out: list[tuple[float, float] | None] = []
    for frame, background, (x, y, w, h), (cx, cy), area in blobs:
        height, width = frame.shape[:2]
        x0, y0, x1, y1 = x - PAD_PX, y - PAD_PX, x + w + PAD_PX, y + h + PAD_PX
        if x0 < 0 or y0 < 0 or x1 > width or y1 > height:
            out.append(None)
            continue
        f = frame[y0:y1, x0:x1].astype(np.float32)
        b = background[y0:y1, x0:x1].astype(np.float32)
        if f.ndim == 2:
            f, b = f[..., None], b[..., None]
        ys, xs = np.mgrid[y0:y1, x0:x1]
        r = math.sqrt(area / math.pi)
        near = (xs - cx) ** 2 + (ys - cy) ** 2
        inner = near <= max(r - 1.0, 0.0) ** 2
        if not inner.any():
            inner = near == near.min()
        if local:
            mask = inner.astype(np.float32)
            count = cv2.boxFilter(mask, -1, (5, 5), normalize=False, borderType=cv2.BORDER_CONSTANT)
            total = np.dstack(
                [
                    cv2.boxFilter(
                        f[..., c] * mask,
                        -1,
                        (5, 5),
                        normalize=False,
                        borderType=cv2.BORDER_CONSTANT,
                    )
                    for c in range(f.shape[2])
                ]
            )
            o = np.where(count[..., None] > 0.5, total / np.maximum(count, 1.0)[..., None], 0.0)
            o = np.where(count[..., None] > 0.5, o, f[inner].mean(axis=0))
        else:
            o = f[inner].mean(axis=0)
        ob = o - b
        num, den = (np.sum((f - b) * ob, axis=2), np.sum(ob * ob, axis=2))
        a = np.clip(num / np.maximum(den, 1e-6), 0.0, 1.0).astype(np.float32)
        if local:
            a[inner] = 1.0
        m = cv2.moments(a)
        if m["m00"] <= 0:
            out.append(None)
            continue
        out.append((x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"]))
    return out


def as_detector_calls(centres: Callable[[Sequence[Candidate]], list[Point | None]]) -> Centres:
    """``centres`` called as the detector calls :func:`disc_centres` (the blobs, their warm
    starts, a list that takes each blob's radius): a closed form starts from nothing and
    gives no radius (nan)."""

    def call(
        blobs: Sequence[Candidate], starts: object = None, radii: list[float] | None = None
    ) -> list[Point | None]:
        if radii is not None:
            radii.extend([math.nan] * len(blobs))
        return centres(blobs)

    return call


METHODS: dict[str, Centres] = {
    "matte": as_detector_calls(lambda blobs: [None] * len(blobs)),
    "fit": disc_centres,
    "global": as_detector_calls(lambda blobs: soft_matte_centres(blobs, local=False)),
    "local": as_detector_calls(lambda blobs: soft_matte_centres(blobs, local=True)),
}


def sphere(h: int, w: int, u: float, v: float, r: float, light: np.ndarray) -> np.ndarray:
    """(h, w, 2): share of each pixel a sphere of image radius ``r`` px at (u, v) covers, and
    its mean Lambertian shading there (ambient 0.2), both over SUB x SUB samples a pixel."""
    ys, xs = np.mgrid[0 : h * SUB, 0 : w * SUB]
    px, py = (xs + 0.5) / SUB - 0.5, (ys + 0.5) / SUB - 0.5
    nx, ny = (px - u) / r, (py - v) / r
    rho2 = nx * nx + ny * ny
    inside = rho2 <= 1.0
    nz = -np.sqrt(np.clip(1.0 - rho2, 0.0, None))
    shade = 0.2 + 0.8 * np.clip(nx * light[0] + ny * light[1] + nz * light[2], 0.0, None)
    cover = inside.reshape(h, SUB, w, SUB).mean(axis=(1, 3))
    shaded = (inside * shade).reshape(h, SUB, w, SUB).mean(axis=(1, 3))
    return np.dstack([cover, shaded])


def wall(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """(h, w, 3) float: a smooth random colour texture about 110 +- 25."""
    coarse = rng.normal(110.0, 25.0, (h // 4 + 1, w // 4 + 1, 3))
    return np.asarray(cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC))


def random_light(rng: np.random.Generator) -> np.ndarray:
    """A unit light direction from in front, up to about 30 deg off the axis."""
    light = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -0.8])
    return light / np.linalg.norm(light)


Scene = tuple[np.ndarray, np.ndarray, tuple[float, float], float]
"""The wall (float, learnt as the background), the frame (float), the true centre (px) and the
gain the frame is taken at."""


def scenes(name: str, rng: np.random.Generator, n: int) -> Iterator[Scene]:
    """``n`` frames of scene ``name`` (see ``SCENES``)."""
    for _ in range(n):
        gain = 1.0
        if name == "matching wall":  # the quarter below right of the ball is its unlit colour
            h = w = 48
            colour = rng.uniform(120.0, 230.0, 3)
            bg = wall(rng, h, w)
            u, v, r = rng.uniform(20, 28), rng.uniform(20, 28), rng.uniform(3.0, 5.5)
            corner = (np.arange(h)[:, None, None] > v) & (np.arange(w)[None, :, None] > u)
            bg = np.where(corner, colour * 0.3 + rng.normal(0.0, 3.0, bg.shape), bg)
            ball = sphere(h, w, u, v, r, np.array([0.0, -0.8, -0.6]))
        elif name == "4-6 px":
            h = w = 32
            colour = rng.uniform(120.0, 230.0, 3)
            bg = wall(rng, h, w)
            u, v, r = rng.uniform(13, 18), rng.uniform(13, 18), rng.uniform(2.2, 2.8)
            ball = sphere(h, w, u, v, r, random_light(rng))
        else:
            r = rng.uniform(1.5, 12.0)
            h = w = 64
            colour = rng.uniform(60.0, 220.0, 3)
            if name == "grey":  # a grey ball as bright as a colour one's brightest channel
                colour = np.full(3, rng.uniform(170.0, 230.0))
            bg = wall(rng, h, w)
            if name == "at the edge":  # the ball's box within two pixels of the left edge
                u, v = rng.uniform(r - 0.5, r + 2.0), rng.uniform(26, 38)
            else:
                u, v = rng.uniform(26, 38), rng.uniform(26, 38)
            if name == "gain 1.15":
                gain = 1.15
            light = np.array([0.0, 0.0, -1.0]) if name == "flat 3-24 px" else random_light(rng)
            ball = sphere(h, w, u, v, r, light)
            if name == "flat 3-24 px":  # one colour all over: no shading
                ball[..., 1] = ball[..., 0]
        frame = ball[..., 1:2] * colour + (1.0 - ball[..., :1]) * bg
        if name == "grey":
            bg, frame = (np.repeat(a.mean(axis=2, keepdims=True), 3, axis=2) for a in (bg, frame))
        yield bg, frame, (u, v), gain


SCENES = ("matching wall", "4-6 px", "3-24 px", "flat 3-24 px", "grey", "gain 1.15", "at the edge")
"""Balls 6-11 px over a wall whose quarter is their unlit colour (``test_disc``'s hard case);
balls 4.4-5.6 px; balls 3-24 px shaded over a texture; the same of one colour all over; a
bright ball in grey; the same with the frame at 1.15 times the learnt background's gain (the other
eye's auto-exposure); balls 3-24 px touching or nearly touching the frame's left edge."""


def errors(
    name: str, seed: int, n: int, method: Centres, timing: list[float] | None = None
) -> list[float]:
    """Distance (px) of each detected ball's centre from the truth in ``n`` frames of scene
    ``name``, the detector's small round blobs centred by ``method``; appends each call's
    CPU seconds per blob to ``timing``."""
    rng = np.random.default_rng(seed)
    grey = name == "grey"

    def timed(
        blobs: Sequence[Candidate], starts: object = None, radii: list[float] | None = None
    ) -> list[Point | None]:
        start = time.thread_time()
        out = method(blobs, starts, radii)
        if timing is not None and blobs:
            timing.append((time.thread_time() - start) / len(blobs))
        return out

    out = []
    for bg, frame, truth, gain in scenes(name, rng, n):
        noise = 2.0 if name == "4-6 px" else 1.5
        det = Detector(DetectorParams(warmup_frames=1, color=not grey))

        def eight(a: np.ndarray, noise: float = noise) -> np.ndarray:
            a = np.clip(a + rng.normal(0.0, noise, a.shape), 0, 255).astype(np.uint8)
            return np.ascontiguousarray(a[..., 0]) if grey else a

        det.detect(eight(bg))
        with mock.patch.object(detect_module, "disc_centres", timed):
            blobs = det.detect(eight(frame * gain))
        if len(blobs) == 1:
            out.append(float(np.hypot(*(blobs.centroid_px[0] - truth))))
    return out


def thrown_rows(seeds: Sequence[int]) -> list[str]:
    """Markdown rows: for each thrown ball of the independent renderer (``make accuracy``'s
    fast cases, 320x240 at 42 deg, ``seeds``) and each method, the pipeline's median position
    error (share of eq. 12's one-pixel depth error, and mm), heading (deg) and speed errors."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests import accuracy as acc

    rows = []
    for seed in seeds:
        for case in acc.fast_cases(acc.MODES[0], seed):
            for method, centres in METHODS.items():
                with mock.patch.object(detect_module, "disc_centres", centres):
                    o = acc.score(case, acc.run_case(case)).objects[0]
                rows.append(
                    f"| {case.name}, seed {seed} | {method} | {o.position_ratio:.3f} "
                    f"| {1e3 * o.position_err_m:.1f} mm | {o.heading_err_deg:+.2f} deg "
                    f"| {o.speed_err:+.2%} |"
                )
                print(rows[-1], flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--balls", type=int, default=60, help="frames per scene (default 60)")
    parser.add_argument(
        "--out",
        type=Path,
        default=report.DOCS_BENCH,
        help="folder of the markdown table (default docs/bench)",
    )
    args = parser.parse_args()
    host = report.host()
    rows = [
        "| scene | method | balls | median | p90 | max |",
        "|---|---|---:|---:|---:|---:|",
    ]
    print(rows[0], rows[1], sep="\n")
    cost: dict[str, list[float]] = {m: [] for m in METHODS}
    for k, name in enumerate(SCENES):
        for method, centres in METHODS.items():
            e = errors(name, 100 + k, args.balls, centres, cost[method] if k == 2 else None)
            med, p90 = float(np.median(e)), float(np.percentile(e, 90))
            rows.append(
                f"| {name} | {method} | {len(e)} | {med:.3f} px | {p90:.3f} px | {max(e):.3f} px |"
            )
            print(rows[-1], flush=True)
    costs = ", ".join(
        f"{method} {1e3 * float(np.median(seconds)):.3f} ms"
        for method, seconds in cost.items()
        if method != "matte"
    )
    print(costs)
    thrown = [
        "| thrown ball | method | position / eq. 12 | position | heading | speed |",
        "|---|---|---:|---:|---:|---:|",
        *thrown_rows((0, 1)),
    ]
    text = "\n\n".join(
        [
            f"{host} {args.balls} frames a scene, one ball in each "
            "(`benchmarks/disc_closed_form.py`).",
            "\n".join(rows),
            f"CPU a blob (median, scene 3-24 px; the closed forms in numpy): {costs}.",
            "The independent renderer's thrown balls through the pipeline, 320x240 at 42 deg "
            "(errors over the middle of the path; nan: too few valid estimates there):",
            "\n".join(thrown),
        ]
    )
    print(f"wrote {report.write('disc_closed_form.md', text, args.out)}")


if __name__ == "__main__":
    main()
