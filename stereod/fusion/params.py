"""The fusion node's settings and their defaults, apart from the code that uses them, so that
``stereod fuse --help`` states them without loading NumPy or Zenoh."""

from __future__ import annotations

from dataclasses import dataclass

CHI2_3DOF_999 = 16.27
"""Squared Mahalanobis distance below which 99.9 % of a 3-D Gaussian's samples fall."""
MAX_RATE_HZ = 30.0
"""Room messages per second at most, by default (each object's own key is updated at once)."""


@dataclass(frozen=True)
class FuseParams:
    """How association and track ends are decided (s, dimensionless chi-square bounds)."""

    gate_chi2: float = CHI2_3DOF_999
    """A rig track further than this squared Mahalanobis distance is not that room track."""
    rig_timeout_s: float = 1.0
    """A rig silent this long (by its stamps against the fusion instant) loses its tracks, s."""
    max_coast_s: float = 2.0
    """A room track no rig sees for this long ends, s."""
    birth_s: float = 0.5
    """A rig track within the gate of a room track that it cannot join (that room track has
    its rig's track already) opens a room track of its own once seen this long, s."""
