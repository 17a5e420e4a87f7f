"""The independent renderer's people scenes, pixel for pixel: frames of the three scenes
tests/test_people.py runs (two people crossing, a person walking up, a robot pushing a box;
320x240, 42 deg) hash to the SHA-256 digests the renderer gave before its ray casting was
batched and culled, so a faster cast is proven to draw the very same uint8 frames."""

from __future__ import annotations

import hashlib

import pytest

from stereod_fakes import world

MODE = (320, 240, 30.0)
HFOV_DEG = 42.0

SCENES: dict[str, dict[str, float]] = {
    "people_crossing": {"lead_in_s": 0.5},
    "person_approach": {"start_m": 1.8, "lead_in_s": 0.5, "hold_s": 0.5},
    "robot_push_box": {"lead_in_s": 0.5, "after_s": 6.0},
}
"""The scenes' parameters, as tests/accuracy.py's ``world_room`` builds them for test_people."""

DIGESTS: dict[str, dict[int, str]] = {
    "people_crossing": {
        200: "fbab8d5005d90173b2d5f464ed220656321adb75a9c75d0f5f275aac22932d3a",
        230: "e60aec5af64dc03be128ffe955ce4f4cbe929e70b95fae5bdf2dfa9b0b4c52e0",
        260: "71d903175e34ada178e4748cfe10fe436cec4852c7cd38a8702ccee633ab8e13",
    },
    "person_approach": {
        60: "050b3ec5e499e7bf94804ee694579197a4799973e5c03ca0666f1f5087173c23",
        120: "be17af345fa5531691caaaa65ae01a4b5851895411ecf57d3bd0f9773a40f38e",
        160: "43736ae07bb5227fad1c410967f11e213e80103f42ba9931c682d67606681042",
    },
    "robot_push_box": {
        100: "92f8e138e835f1a37deac405d448bcc23254b814a034f2455fe99750bae6e4f0",
        300: "99221b30f4107f2eac8b5e3e1f176c8a2e20367fdf00ec2e74ae4fe49b1ea89c",
        500: "b0dae2bf5fe52ac94d715f3ee11df239162bd7911e16f33fafa10572e4828a50",
    },
}
"""SHA-256 of the uint8 image of frame k (index in capture order, both eyes) of each scene,
rendered by the per-solid, full-grid cast (crossing: near person whole, both in view, far
one alone; approach: 2 m, 1.4 m, 1 m away; push: box alone, robot at the box, box moved)."""


@pytest.mark.parametrize("name", sorted(SCENES))
def test_people_scene_frames_are_bit_identical_to_the_reference_digests(name: str) -> None:
    scene = getattr(world, name)(
        mode=MODE, hfov_deg=HFOV_DEG, seed=0, skew="wander", **SCENES[name]
    )
    order = sorted(
        (t, i, seq)
        for i, eye in enumerate(("left", "right"))
        for seq, t in enumerate(scene.frame_times(eye))
    )
    got = {}
    for k in DIGESTS[name]:
        t_ns, i, _ = order[k]
        image = scene.render(("left", "right")[i], t_ns)
        got[k] = hashlib.sha256(image.tobytes()).hexdigest()
    assert got == DIGESTS[name]
