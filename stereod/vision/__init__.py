"""Images to 3D: background subtraction, blob centres, grouping, skew, calibration and stereo
geometry."""
