"""Parameter values on the wire: PARAM_SET and PARAM_VALUE carry every value in one float.

How an integer parameter fits in that float differs by autopilot:

- ArduPilot casts (C-style): the INT8 parameter 3 travels as the float 3.0.
- PX4 copies the integer's bytes into the float (byte-wise, like a C union): the INT32 5
  travels as the float whose bit pattern is the integer 5. Writing 5.0 to a PX4 integer
  parameter would set it to 1084227584.

``encode``/``decode`` hide the difference; the link picks byte-wise for PX4.
"""

from __future__ import annotations

import struct

from fleet.mavlink.wire import mavlink

# MAV_PARAM_TYPE -> struct format of the integer types that fit in 4 bytes.
_INTEGER_FORMATS: dict[int, str] = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink.MAV_PARAM_TYPE_INT8: "<b",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink.MAV_PARAM_TYPE_INT16: "<h",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink.MAV_PARAM_TYPE_INT32: "<i",
}
REAL32 = int(mavlink.MAV_PARAM_TYPE_REAL32)


def is_integer_type(param_type: int) -> bool:
    """Whether a MAV_PARAM_TYPE is an integer type of at most 32 bits."""
    return param_type in _INTEGER_FORMATS


def encode(value: float, param_type: int, *, bytewise: bool) -> float:
    """The float to put in PARAM_SET.param_value for ``value`` of ``param_type``.

    Integer types are rounded to the nearest integer. Raises ValueError when the value does
    not fit the integer type.
    """
    fmt = _INTEGER_FORMATS.get(param_type)
    if fmt is None:
        return float(value)
    number = round(value)
    try:
        packed = struct.pack(fmt, number)
    except struct.error:
        raise ValueError(f"{value!r} does not fit parameter type {param_type}") from None
    if not bytewise:
        return float(number)
    return float(struct.unpack("<f", packed.ljust(4, b"\0"))[0])


def decode(wire: float, param_type: int, *, bytewise: bool) -> float:
    """The value a PARAM_VALUE.param_value stands for (integers as whole floats)."""
    fmt = _INTEGER_FORMATS.get(param_type)
    if fmt is None or not bytewise:
        return float(wire)
    raw = struct.pack("<f", wire)[: struct.calcsize(fmt)]
    return float(struct.unpack(fmt, raw)[0])


def as_float32(value: float) -> float:
    """The value rounded to the float32 the wire carries (for comparing an echo)."""
    return float(struct.unpack("<f", struct.pack("<f", value))[0])
