"""From a configuration to what the pipeline runs with: the rig geometry and the parameters.

This is the one place that reads a ``StereodConfig`` (``daemon/config.py``) for the pipeline, so
``stereod run --check`` and a reload validate exactly what a run would use.
"""

from __future__ import annotations

from stereod.daemon.config import StereodConfig
from stereod.errors import CalibrationError
from stereod.pipeline import PipelineParams
from stereod.vision import calibration
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig


def make_rig(cfg: StereodConfig, width: int, height: int) -> CanonicalRig | CalibratedRig:
    """The geometry for frames of ``width`` x ``height`` px: the configured calibration, checked
    against that size, or the canonical rig of eq. 9."""
    if cfg.rig.calibration is None:
        return CanonicalRig(cfg.rig.baseline_m, cfg.rig.hfov_deg, width, height)
    cal = calibration.load(cfg.rig.calibration, (width, height))
    try:
        return CalibratedRig(cal)
    except ValueError as exc:
        raise CalibrationError(f"{cfg.rig.calibration}: {exc}") from exc


def pipeline_params(cfg: StereodConfig, width: int, height: int) -> PipelineParams:
    """Pipeline parameters from a configuration, for frames of ``width`` x ``height`` px."""
    return PipelineParams(
        rig=make_rig(cfg, width, height),
        detector=cfg.detector.params(),
        matching=cfg.matching.params(),
        tracker=cfg.tracking.params(),
        centroid_sigma_px=cfg.matching.centroid_sigma_px,
        silhouette_depth=cfg.matching.silhouette_depth,
        detect_workers=cfg.daemon.detect_workers,
        skew_compensation=cfg.pairing.skew_compensation,
        freeze_background=cfg.tracking.freeze_background,
        refine=cfg.refine.params(),
        grouping=cfg.grouping.params(),
        readout_s=cfg.rig.readout_s,
    )
