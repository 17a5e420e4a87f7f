"""A rig's objects message as arrays, one per field: what the fusion works on.

Each field the fusion uses becomes one numpy array over the message's objects, so that moving
them into the room, predicting, gating and fusing are whole-array operations. The fields it only
passes on (the pair's skew, each eye's blob, disparity and size) are the columns of
:data:`EXTRA`, so that the room's message is written from arrays too, with no model per object.
An object whose position or velocity is not finite is left out, as a daemon leaves out a
degenerate one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereod.bus.messages import ObjectsMessage
from stereod.tracking.types import TrackLifecycle
from stereod.vision.geometry import Geometry

EXTRA = (
    "skew_ns",
    "left_cx", "left_cy", "left_bx", "left_by", "left_bw", "left_bh", "left_area",
    "right_cx", "right_cy", "right_bx", "right_by", "right_bw", "right_bh", "right_area",
    "disparity_px", "size_m",
)  # fmt: skip
"""The columns of :attr:`RigWire.extra`: what the room's message repeats of its best member."""

STATES = (
    TrackLifecycle.TENTATIVE,
    TrackLifecycle.CONFIRMED,
    TrackLifecycle.COASTING,
    TrackLifecycle.STATIONARY,
)
"""Lifecycle states by their code in :attr:`RigWire.state`."""
TENTATIVE, CONFIRMED, COASTING, STATIONARY = range(4)


@dataclass(frozen=True)
class RigWire:
    """One rig message's objects as arrays, in the rig frame (m, m/s, UTC ns)."""

    rig: str
    seq: int
    stamp_utc_ns: int
    geometry: Geometry
    ids: np.ndarray
    """(n,) track ids (int64)."""
    state: np.ndarray
    """(n,) lifecycle codes, indexes into :data:`STATES`."""
    stamps_ns: np.ndarray
    """(n,) each object's UTC stamp, ns (int64)."""
    position: np.ndarray
    """(n, 3) m."""
    position_sigma: np.ndarray
    """(n, 3) m (NaN where the rig gave none finite)."""
    velocity: np.ndarray
    """(n, 3) m/s."""
    velocity_sigma: np.ndarray
    """(n, 3) m/s (NaN while the rig does not know it)."""
    velocity_valid: np.ndarray
    """(n,) bool."""
    heading_valid: np.ndarray
    """(n,) bool."""
    extra: np.ndarray
    """(n, len(EXTRA)) float64, the columns of :data:`EXTRA`."""

    def select(self, keep: np.ndarray) -> RigWire:
        """The same message with only the objects where ``keep`` (n,) is true."""
        return RigWire(
            self.rig, self.seq, self.stamp_utc_ns, self.geometry, self.ids[keep],
            self.state[keep], self.stamps_ns[keep], self.position[keep],
            self.position_sigma[keep], self.velocity[keep], self.velocity_sigma[keep],
            self.velocity_valid[keep], self.heading_valid[keep], self.extra[keep],
        )  # fmt: skip


_CODE_OF = {s: k for k, s in enumerate(STATES)}
_NAN3 = (float("nan"),) * 3


def from_message(msg: ObjectsMessage) -> RigWire:
    """A validated message's objects as :class:`RigWire` arrays (rig frame): one row of
    numbers per object, made into one array at once (a numpy call per field would cost more
    than the fields)."""
    objs = msg.objects
    n = len(objs)
    rows = [
        (o.track_id, _CODE_OF[o.state], o.stamp_utc_ns, *o.position_m, *o.position_sigma_m,
         *o.velocity_mps, *(o.velocity_sigma_mps or _NAN3), o.velocity_valid, o.heading_valid,
         o.skew_ns, *o.left.centroid_px, *o.left.bbox_px, o.left.area_px,
         *o.right.centroid_px, *o.right.bbox_px, o.right.area_px, o.disparity_px, o.size_m)
        for o in objs
    ]  # fmt: skip
    # Integers (ids, stamps) exactly in their own array; the rest as floats.
    ints = np.array([r[:3] for r in rows], dtype=np.int64).reshape(n, 3)
    f = np.array([r[3:] for r in rows], dtype=np.float64).reshape(n, 14 + len(EXTRA))
    wire = RigWire(
        rig=msg.rig,
        seq=msg.seq,
        stamp_utc_ns=msg.stamp_utc_ns,
        geometry=msg.geometry,
        ids=ints[:, 0],
        state=ints[:, 1].astype(np.int8),
        stamps_ns=ints[:, 2],
        position=f[:, 0:3],
        position_sigma=f[:, 3:6],
        velocity=f[:, 6:9],
        velocity_sigma=f[:, 9:12],
        velocity_valid=f[:, 12] != 0,
        heading_valid=f[:, 13] != 0,
        extra=f[:, 14:],
    )
    finite = np.isfinite(wire.position).all(axis=1) & np.isfinite(wire.velocity).all(axis=1)
    return wire if finite.all() else wire.select(finite)
