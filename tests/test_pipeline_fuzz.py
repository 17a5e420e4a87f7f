"""Fuzz the public pipeline API with the mistakes a library user can make: images of any
dtype, shape or layout, capture times in any order or unit, eyes given by name or swapped.
The property: each frame and pair is either taken or refused with a one-line TypeError or
ValueError, never another exception from deep inside, and what is taken never gives a
non-finite position or velocity."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from stereod import CanonicalRig, Frame, Pipeline, PipelineParams, StereoPair
from stereod.sources.frames import Eye
from tests.fuzz import FUZZ

RIG = CanonicalRig(0.06, 60.0, 32, 24)

seeds = st.integers(0, 2**32 - 1)
good_images = st.tuples(
    st.just("wall"),
    st.just((24, 32, 3)),  # (a grey frame after colour ones starts the background afresh)
    st.just(False),
    st.integers(-1, 24 * 32 - 1),  # where a bright square is on a fixed wall (-1: nowhere)
)
any_images = st.tuples(
    st.sampled_from(["uint8", "uint16", "float32", "bool", "int64"]),
    st.sampled_from([(24, 32), (24, 32, 3), (24, 32, 4), (24, 32, 1), (12, 16), (24,), (0, 0)]),
    st.booleans(),  # column-major
    seeds,
)
images = st.one_of(good_images, good_images, good_images, any_images)
"""Mostly frames the pipeline takes, so that runs get past the warm-up and detect."""
frame_steps = st.integers(30_000_000, 36_000_000)
times = st.one_of(
    frame_steps,
    frame_steps,
    frame_steps,
    frame_steps,
    st.integers(-(10**9), 10**9),
    st.integers(0, 10**6),
    st.sampled_from([0, 1, 10**18]),
)
"""Each eye's time step from its frame in the last pair taken: mostly a camera's."""
pairs = st.lists(
    st.tuples(images, images, times, times, st.sampled_from(["ok"] * 6 + ["names", "swap"])),
    min_size=1,
    max_size=20,
)


WALL = np.random.default_rng(0).integers(0, 200, (24, 32, 3)).astype(np.uint8)


def make(spec: tuple[str, tuple[int, ...], bool, int], shift_px: int = 0) -> np.ndarray:
    """A ``wall`` spec's image is a fixed wall with a 6 px square at a drawn place, moved
    ``shift_px`` left (the right eye's disparity), so runs detect and track; any other's is
    noise of its dtype and shape."""
    dtype, shape, column_major, seed = spec
    if dtype == "wall":
        image = WALL.copy()
        if seed >= 0:
            y, x = divmod(seed, 32)
            x = max(x - shift_px, 0)
            image[y : y + 6, x : x + 6] = 250
        return image if len(shape) == 3 else image[..., 1].copy()
    rng = np.random.default_rng(seed)
    image = (rng.random(shape) * 255).astype(dtype)
    return np.asfortranarray(image) if column_major else image


def one_line(exc: Exception) -> bool:
    text = str(exc)
    return bool(text) and "\n" not in text


@FUZZ
@given(pairs=pairs)
def test_any_input_is_taken_or_refused_in_one_line(pairs: list) -> None:
    taken = [10**9, 10**9]
    with Pipeline(PipelineParams(RIG)) as pipe:
        for k in range(12):  # the wall alone, past the warm-up, so what follows is detected
            taken = [taken[0] + 33_333_333, taken[1] + 33_333_333]
            wall = make(("wall", (24, 32, 3), False, -1))
            pipe.process(StereoPair.of(wall, wall, taken[0], taken[1], seq=k))
        for k, (left_spec, right_spec, dl, dr, how) in enumerate(pairs, start=12):
            t = [taken[0] + dl, taken[1] + dr]
            eyes: tuple[Eye | str, Eye | str] = (Eye.LEFT, Eye.RIGHT)
            if how == "names":
                eyes = ("left", "right")
            elif how == "swap":
                eyes = (Eye.RIGHT, Eye.LEFT)
            if left_spec[0] == right_spec[0] == "wall":  # one square, seen by both eyes
                right_spec = (*right_spec[:3], left_spec[3])
            try:
                pair = StereoPair(
                    k,
                    Frame(eyes[0], make(left_spec), t[0], k),  # type: ignore[arg-type]
                    Frame(eyes[1], make(right_spec, 2), t[1], k),  # type: ignore[arg-type]
                )
                result = pipe.process(pair)
            except (TypeError, ValueError) as exc:
                assert one_line(exc), repr(exc)
                continue
            taken = t
            for s in result.tracks:
                assert np.all(np.isfinite(s.position_m)) and np.all(np.isfinite(s.velocity_mps))
