"""V4L2 kernel ABI: constants, ctypes structs and ioctl request numbers.

Transcribed from ``include/uapi/linux/videodev2.h`` (Linux 6.1) for the subset a capture
device needs. Request numbers are computed with the kernel's ``_IOC`` encoding from each
struct's size, not typed in; the tests compare sizes and numbers with the C header.
"""

from __future__ import annotations

import ctypes

# _IOC encoding (asm-generic/ioctl.h): dir:2 | size:14 | type:8 | nr:8.
_IOC_NRBITS, _IOC_TYPEBITS, _IOC_SIZEBITS = 8, 8, 14
_IOC_NRSHIFT = 0
_IOC_TYPESHIFT = _IOC_NRSHIFT + _IOC_NRBITS
_IOC_SIZESHIFT = _IOC_TYPESHIFT + _IOC_TYPEBITS
_IOC_DIRSHIFT = _IOC_SIZESHIFT + _IOC_SIZEBITS
_IOC_WRITE, _IOC_READ = 1, 2


def _ioc(direction: int, nr: int, struct: type[ctypes.Structure] | type[ctypes.c_int]) -> int:
    return (
        (direction << _IOC_DIRSHIFT)
        | (ord("V") << _IOC_TYPESHIFT)
        | (nr << _IOC_NRSHIFT)
        | (ctypes.sizeof(struct) << _IOC_SIZESHIFT)
    )


def _ior(nr: int, s: type) -> int:
    return _ioc(_IOC_READ, nr, s)


def _iow(nr: int, s: type) -> int:
    return _ioc(_IOC_WRITE, nr, s)


def _iowr(nr: int, s: type) -> int:
    return _ioc(_IOC_READ | _IOC_WRITE, nr, s)


def fourcc(code: str) -> int:
    """v4l2_fourcc('Y','U','Y','V')."""
    a, b, c, d = (ord(ch) for ch in code)
    return a | (b << 8) | (c << 16) | (d << 24)


def fourcc_str(value: int) -> str:
    return "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4))


V4L2_BUF_TYPE_VIDEO_CAPTURE = 1
V4L2_MEMORY_MMAP = 1
V4L2_FIELD_NONE = 1
V4L2_FIELD_ANY = 0
V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_STREAMING = 0x04000000
V4L2_CAP_DEVICE_CAPS = 0x80000000
V4L2_BUF_FLAG_ERROR = 0x00000040
V4L2_BUF_FLAG_TIMESTAMP_MASK = 0x0000E000
V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC = 0x00002000
V4L2_BUF_FLAG_TIMESTAMP_COPY = 0x00004000
V4L2_FRMSIZE_TYPE_DISCRETE = 1
V4L2_FRMIVAL_TYPE_DISCRETE = 1
V4L2_CAP_TIMEPERFRAME = 0x1000
V4L2_CTRL_FLAG_DISABLED = 0x0001
V4L2_CTRL_FLAG_NEXT_CTRL = 0x80000000
V4L2_PIX_FMT_YUYV = fourcc("YUYV")
V4L2_PIX_FMT_MJPEG = fourcc("MJPG")

# Camera controls (V4L2_CID_*) the driver sets by name.
V4L2_CID_BASE = 0x00980900
V4L2_CID_CAMERA_CLASS_BASE = 0x009A0900
CONTROLS = {
    "brightness": V4L2_CID_BASE + 0,
    "contrast": V4L2_CID_BASE + 1,
    "saturation": V4L2_CID_BASE + 2,
    "auto_white_balance": V4L2_CID_BASE + 12,
    "gain": V4L2_CID_BASE + 19,
    "white_balance_temperature": V4L2_CID_BASE + 26,
    "exposure_auto": V4L2_CID_CAMERA_CLASS_BASE + 1,
    "exposure_absolute": V4L2_CID_CAMERA_CLASS_BASE + 2,
    "exposure_auto_priority": V4L2_CID_CAMERA_CLASS_BASE + 3,
}
V4L2_EXPOSURE_MANUAL = 1


class v4l2_capability(ctypes.Structure):
    _fields_ = [
        ("driver", ctypes.c_char * 16),
        ("card", ctypes.c_char * 32),
        ("bus_info", ctypes.c_char * 32),
        ("version", ctypes.c_uint32),
        ("capabilities", ctypes.c_uint32),
        ("device_caps", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 3),
    ]


class v4l2_fmtdesc(ctypes.Structure):
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("description", ctypes.c_char * 32),
        ("pixelformat", ctypes.c_uint32),
        ("mbus_code", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 3),
    ]


class v4l2_frmsize_discrete(ctypes.Structure):
    _fields_ = [("width", ctypes.c_uint32), ("height", ctypes.c_uint32)]


class v4l2_frmsize_stepwise(ctypes.Structure):
    _fields_ = [
        (n, ctypes.c_uint32)
        for n in ("min_width", "max_width", "step_width", "min_height", "max_height", "step_height")
    ]


class _frmsize_union(ctypes.Union):
    _fields_ = [("discrete", v4l2_frmsize_discrete), ("stepwise", v4l2_frmsize_stepwise)]


class v4l2_frmsizeenum(ctypes.Structure):
    _anonymous_ = ("u",)
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("pixel_format", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("u", _frmsize_union),
        ("reserved", ctypes.c_uint32 * 2),
    ]


class v4l2_fract(ctypes.Structure):
    _fields_ = [("numerator", ctypes.c_uint32), ("denominator", ctypes.c_uint32)]


class v4l2_frmival_stepwise(ctypes.Structure):
    _fields_ = [("min", v4l2_fract), ("max", v4l2_fract), ("step", v4l2_fract)]


class _frmival_union(ctypes.Union):
    _fields_ = [("discrete", v4l2_fract), ("stepwise", v4l2_frmival_stepwise)]


class v4l2_frmivalenum(ctypes.Structure):
    _anonymous_ = ("u",)
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("pixel_format", ctypes.c_uint32),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("u", _frmival_union),
        ("reserved", ctypes.c_uint32 * 2),
    ]


class v4l2_pix_format(ctypes.Structure):
    _fields_ = [
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("pixelformat", ctypes.c_uint32),
        ("field", ctypes.c_uint32),
        ("bytesperline", ctypes.c_uint32),
        ("sizeimage", ctypes.c_uint32),
        ("colorspace", ctypes.c_uint32),
        ("priv", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("ycbcr_enc", ctypes.c_uint32),
        ("quantization", ctypes.c_uint32),
        ("xfer_func", ctypes.c_uint32),
    ]


class _format_union(ctypes.Union):
    # The kernel union holds structs with pointers (v4l2_window), so it is 8-byte aligned.
    _fields_ = [
        ("pix", v4l2_pix_format),
        ("raw_data", ctypes.c_uint8 * 200),
        ("_align", ctypes.c_uint64),
    ]


class v4l2_format(ctypes.Structure):
    _fields_ = [("type", ctypes.c_uint32), ("fmt", _format_union)]


class v4l2_captureparm(ctypes.Structure):
    _fields_ = [
        ("capability", ctypes.c_uint32),
        ("capturemode", ctypes.c_uint32),
        ("timeperframe", v4l2_fract),
        ("extendedmode", ctypes.c_uint32),
        ("readbuffers", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 4),
    ]


class _parm_union(ctypes.Union):
    _fields_ = [("capture", v4l2_captureparm), ("raw_data", ctypes.c_uint8 * 200)]


class v4l2_streamparm(ctypes.Structure):
    _fields_ = [("type", ctypes.c_uint32), ("parm", _parm_union)]


class v4l2_requestbuffers(ctypes.Structure):
    _fields_ = [
        ("count", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("memory", ctypes.c_uint32),
        ("capabilities", ctypes.c_uint32),
        ("flags", ctypes.c_uint8),
        ("reserved", ctypes.c_uint8 * 3),
    ]


class timeval(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_usec", ctypes.c_long)]


class v4l2_timecode(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("frames", ctypes.c_uint8),
        ("seconds", ctypes.c_uint8),
        ("minutes", ctypes.c_uint8),
        ("hours", ctypes.c_uint8),
        ("userbits", ctypes.c_uint8 * 4),
    ]


class _buffer_m(ctypes.Union):
    _fields_ = [
        ("offset", ctypes.c_uint32),
        ("userptr", ctypes.c_ulong),
        ("planes", ctypes.c_void_p),
        ("fd", ctypes.c_int32),
    ]


class v4l2_buffer(ctypes.Structure):
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("bytesused", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("field", ctypes.c_uint32),
        ("timestamp", timeval),
        ("timecode", v4l2_timecode),
        ("sequence", ctypes.c_uint32),
        ("memory", ctypes.c_uint32),
        ("m", _buffer_m),
        ("length", ctypes.c_uint32),
        ("reserved2", ctypes.c_uint32),
        ("request_fd", ctypes.c_int32),
    ]


class v4l2_queryctrl(ctypes.Structure):
    _fields_ = [
        ("id", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("name", ctypes.c_char * 32),
        ("minimum", ctypes.c_int32),
        ("maximum", ctypes.c_int32),
        ("step", ctypes.c_int32),
        ("default_value", ctypes.c_int32),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 2),
    ]


class v4l2_control(ctypes.Structure):
    _fields_ = [("id", ctypes.c_uint32), ("value", ctypes.c_int32)]


VIDIOC_QUERYCAP = _ior(0, v4l2_capability)
VIDIOC_ENUM_FMT = _iowr(2, v4l2_fmtdesc)
VIDIOC_G_FMT = _iowr(4, v4l2_format)
VIDIOC_S_FMT = _iowr(5, v4l2_format)
VIDIOC_REQBUFS = _iowr(8, v4l2_requestbuffers)
VIDIOC_QUERYBUF = _iowr(9, v4l2_buffer)
VIDIOC_QBUF = _iowr(15, v4l2_buffer)
VIDIOC_DQBUF = _iowr(17, v4l2_buffer)
VIDIOC_STREAMON = _iow(18, ctypes.c_int)
VIDIOC_STREAMOFF = _iow(19, ctypes.c_int)
VIDIOC_G_PARM = _iowr(21, v4l2_streamparm)
VIDIOC_S_PARM = _iowr(22, v4l2_streamparm)
VIDIOC_G_CTRL = _iowr(27, v4l2_control)
VIDIOC_S_CTRL = _iowr(28, v4l2_control)
VIDIOC_QUERYCTRL = _iowr(36, v4l2_queryctrl)
VIDIOC_ENUM_FRAMESIZES = _iowr(74, v4l2_frmsizeenum)
VIDIOC_ENUM_FRAMEINTERVALS = _iowr(75, v4l2_frmivalenum)

STRUCTS: dict[str, type[ctypes.Structure]] = {
    "v4l2_capability": v4l2_capability,
    "v4l2_fmtdesc": v4l2_fmtdesc,
    "v4l2_frmsizeenum": v4l2_frmsizeenum,
    "v4l2_frmivalenum": v4l2_frmivalenum,
    "v4l2_format": v4l2_format,
    "v4l2_streamparm": v4l2_streamparm,
    "v4l2_requestbuffers": v4l2_requestbuffers,
    "v4l2_buffer": v4l2_buffer,
    "v4l2_queryctrl": v4l2_queryctrl,
    "v4l2_control": v4l2_control,
}
REQUESTS: dict[str, int] = {
    name: value for name, value in globals().items() if name.startswith("VIDIOC_")
}
