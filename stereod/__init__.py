"""stereod: stereo motion daemon for a Minoru-style USB stereo webcam.

Frames from two eyes are paired by kernel timestamp, moving objects are found by background
subtraction, triangulated to 3D in the rig frame, associated over time and published over Zenoh.
"""

__version__ = "0.1.0"
