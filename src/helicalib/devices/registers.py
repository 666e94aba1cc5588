"""``PLANT_INTERFACE.md`` (version 1): helicalib's own states, commands and fault codes, and the
default register layout as constants.

The enumerations (:class:`HeliostatState`, :class:`HeliostatCommand`, :class:`FaultCode`,
:class:`FieldCommand`, :class:`FieldState`) are the names the whole controller speaks; a register
map (:mod:`helicalib.devices.regmap`) maps a plant's own codes to them. The client and the
simulated plant's server read the layout from a map: the shipped ``plant-interface-1`` map
reproduces the addresses below (a test holds them equal). f32 and f64 are IEEE-754, high word first.
"""

from __future__ import annotations

import struct
from enum import IntEnum

INTERFACE_VERSION = 1

# --- field block ------------------------------------------------------------------------
REG_VERSION = 0
REG_HELIOSTAT_COUNT = 1
REG_TARGET_COUNT = 2
REG_FIELD_COMMAND = 3          # W
REG_FIELD_STATE = 4            # R
REG_PLANT_TIME = 8             # f64, 8-11
REG_PLANT_TIME_RATE = 12       # f32, 12-13

# --- weather block ------------------------------------------------------------------------
REG_WIND_SPEED = 100           # f32 m/s
REG_WIND_DIRECTION = 102       # f32 deg from north clockwise
REG_DNI = 104                  # f32 W/m2
REG_TEMPERATURE = 106          # f32 degC
REG_PRESSURE = 108             # f32 hPa
WEATHER_BLOCK = (100, 10)      # (start, count)

# --- heliostat block i at 1000 + 32*i ------------------------------------------------------
HELIOSTAT_BASE = 1000
HELIOSTAT_STRIDE = 32
OFF_COMMAND = 0                # W u16
OFF_SEQUENCE = 1               # W u16
OFF_STATE = 2                  # R u16
OFF_SEQUENCE_DONE = 3          # R u16
OFF_FAULT = 4                  # R u16
OFF_STROKE_CMD_1 = 6           # W f32 mm
OFF_STROKE_CMD_2 = 8           # W f32 mm
OFF_STROKE_ACT_1 = 10          # R f32 mm
OFF_STROKE_ACT_2 = 12          # R f32 mm
OFF_TRACK_CORR_1 = 14          # W f32 mm
OFF_TRACK_CORR_2 = 16          # W f32 mm
OFF_CLEANLINESS = 18           # R f32 0..1
HELIOSTAT_USED = 20            # registers of a block that carry data

# registers a client may write (everything else is read-only: a write is refused whole)
WRITABLE_FIELD = frozenset({REG_FIELD_COMMAND})
WRITABLE_HELIOSTAT_OFFSETS = frozenset(
    {OFF_COMMAND, OFF_SEQUENCE, OFF_STROKE_CMD_1, OFF_STROKE_CMD_1 + 1, OFF_STROKE_CMD_2, OFF_STROKE_CMD_2 + 1,
     OFF_TRACK_CORR_1, OFF_TRACK_CORR_1 + 1, OFF_TRACK_CORR_2, OFF_TRACK_CORR_2 + 1}
)


class HeliostatCommand(IntEnum):
    NONE = 0
    TRACK = 1
    MOVE = 3
    STOW = 4


class HeliostatState(IntEnum):
    IDLE = 0
    TRACKING = 1
    MOVING = 2
    HOLDING = 3
    STOWED = 4
    FAULT = 5
    OFFLINE = 6


class FaultCode(IntEnum):
    NONE = 0
    STROKE_OUT_OF_RANGE = 1
    REFUSED_DURING_STOW = 2
    UNKNOWN_COMMAND = 3


class FieldCommand(IntEnum):
    NONE = 0
    STOW_ALL = 1
    RESUME_TRACKING = 2


class FieldState(IntEnum):
    TRACKING = 0
    STOWING = 1
    STOWED = 2


def heliostat_address(index: int, offset: int = 0) -> int:
    """Protocol address of register ``offset`` of heliostat block ``index`` (0-based)."""
    return HELIOSTAT_BASE + HELIOSTAT_STRIDE * index + offset


def encode_f32(value: float) -> list[int]:
    """float → two registers, high word first."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", float(value)))
    return [hi, lo]


def decode_f32(regs) -> float:
    return struct.unpack(">f", struct.pack(">HH", int(regs[0]), int(regs[1])))[0]


def encode_f64(value: float) -> list[int]:
    """float → four registers, high word first."""
    return list(struct.unpack(">HHHH", struct.pack(">d", float(value))))


def decode_f64(regs) -> float:
    return struct.unpack(">d", struct.pack(">HHHH", *(int(r) for r in regs[:4])))[0]
