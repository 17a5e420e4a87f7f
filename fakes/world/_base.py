"""Shared types, constants and small helpers of the renderer (no rendering here)."""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]
I32 = npt.NDArray[np.int32]
Vec3 = tuple[float, float, float]
Eye = Literal["left", "right"]
EYES: tuple[Eye, Eye] = ("left", "right")
Mode = tuple[int, int, float]
MODE_320x240_30: Mode = (320, 240, 30.0)
MODE_640x480_15: Mode = (640, 480, 15.0)
Skew = float | Literal["wander"]
Rect = tuple[int, int, int, int]  # row0, row1, col0, col1 (end exclusive)

_NEAR_M = 0.01
_ZERO3: Vec3 = (0.0, 0.0, 0.0)


def _eye_index(eye: str) -> int:
    if eye == "left":
        return 0
    if eye == "right":
        return 1
    raise ValueError(f"eye must be 'left' or 'right', not {eye!r}")


def _vec(a: npt.ArrayLike) -> Vec3:
    x, y, z = (float(c) for c in np.asarray(a, dtype=np.float64))
    return (x, y, z)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def _tuplify(x: Any) -> Any:
    if isinstance(x, list):
        return tuple(_tuplify(v) for v in x)
    return x


def _build(cls: Any, d: dict[str, Any]) -> Any:
    return cls(**{k: _tuplify(v) for k, v in d.items()})
