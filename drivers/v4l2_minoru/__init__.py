"""The Minoru capture driver: two UVC eyes through V4L2 (ioctl, mmap), discovery and controls.

Layers, bottom up: :mod:`.raw` (kernel structs and constants, from ``linux/videodev2.h``),
:mod:`.ioctl` (the one function every syscall goes through), :mod:`.device` (one V4L2 capture
device), :mod:`.convert` (pixel formats to what the pipeline needs), :mod:`.discovery` (sysfs
and USB), :mod:`.driver` (the ``v4l2_minoru`` driver: both eyes, recovery after a re-plug).
"""
