"""Novint Falcon packet format (Novint SDK firmware): encode/decode and a stream parser.

This file owns the 16-byte ``<...>`` frames exchanged once per servo tick:

- host -> device (``encode_command``/``decode_command``): byte 0 ``<``, bytes 1-4 / 5-8 / 9-12 the
  signed 16-bit effort of motors 1/2/3, one nibble per byte (low nibble first) offset by 0x41
  (``A``), byte 13 the control nibble (0x01 homing mode, 0x02 green, 0x04 blue, 0x08 red LED),
  byte 14 ``A``, byte 15 ``>``;
- device -> host (``encode_report``/``decode_report``): the same framing, bytes 1-12 the three
  signed 16-bit encoder counts, byte 13 = 0x41 + (homed flags << 4) + buttons. Byte 13 is the
  one byte that can leave the ``A``..``P`` range (up to 0x41 + 0x7F) because it carries 7 bits;
- ``FrameParser``: USB reads arrive in arbitrary chunks (64-byte FTDI packets, partial frames,
  line noise after a power glitch), so frames are found by scanning, keeping the partial tail
  and skipping garbage.

Pure functions of bytes: no I/O, no numpy, fast enough for 1 kHz from Python.
"""
from __future__ import annotations

from typing import List, NamedTuple, Sequence, Tuple

from .device import ConfigError, ProtocolError

__all__ = [
    "FRAME_LEN",
    "HOMING_MODE",
    "LED_GREEN",
    "LED_BLUE",
    "LED_RED",
    "BUTTON_PLUS",
    "BUTTON_FORWARD",
    "BUTTON_CENTER",
    "BUTTON_MINUS",
    "Command",
    "Report",
    "encode_command",
    "decode_command",
    "encode_report",
    "decode_report",
    "FrameParser",
]

FRAME_LEN = 16
START = 0x3C  # '<'
END = 0x3E  # '>'
BASE = 0x41  # 'A': every nibble is sent as BASE + nibble, so payload bytes are 'A'..'P'

HOMING_MODE = 0x01
LED_GREEN = 0x02
LED_BLUE = 0x04
LED_RED = 0x08

BUTTON_PLUS = 0x1
BUTTON_FORWARD = 0x2
BUTTON_CENTER = 0x4
BUTTON_MINUS = 0x8

INT16_MIN, INT16_MAX = -32768, 32767

# Byte sets for validation with bytes.translate (deletes allowed bytes; empty result = all valid).
_NIBBLE_BYTES = bytes(range(BASE, BASE + 16))
_STATUS_BYTES = bytes(range(BASE, BASE + 0x80))


class Command(NamedTuple):
    """Host -> device content. ``efforts`` in motor counts (int16), ``control`` = LED/homing bits."""

    efforts: Tuple[int, int, int]
    control: int

    @property
    def homing(self) -> bool:
        return bool(self.control & HOMING_MODE)

    @property
    def leds(self) -> int:
        return self.control & (LED_GREEN | LED_BLUE | LED_RED)


class Report(NamedTuple):
    """Device -> host content: encoder counts, homed flags (bit i = motor i+1), grip buttons."""

    encoders: Tuple[int, int, int]
    homed: int
    buttons: int

    @property
    def all_homed(self) -> bool:
        return self.homed == 0b111


def _put_int16(out: bytearray, value: int) -> None:
    # The reference driver masks to 16 bits, so 40000 silently becomes -25536 and the motor jumps
    # the other way. Refuse instead: clamping is the caller's job (falcon_kinematics does it).
    if not INT16_MIN <= value <= INT16_MAX:
        raise ConfigError(f"value {value} does not fit a signed 16-bit field; clamp it before encoding")
    v = value & 0xFFFF
    out += bytes((BASE + (v & 0xF), BASE + (v >> 4 & 0xF), BASE + (v >> 8 & 0xF), BASE + (v >> 12)))


def _get_int16(frame: bytes, i: int) -> int:
    v = (frame[i] - BASE) | (frame[i + 1] - BASE) << 4 | (frame[i + 2] - BASE) << 8 | (frame[i + 3] - BASE) << 12
    return v - 0x10000 if v & 0x8000 else v


def _frame(three: Sequence[int], byte13: int) -> bytes:
    out = bytearray(b"<")
    for v in three:
        _put_int16(out, int(v))
    out.append(byte13)
    out += b"A>"
    return bytes(out)


def encode_command(efforts: Sequence[int], control: int = 0) -> bytes:
    """Frame a motor command: three int16 efforts and the control nibble (LEDs | HOMING_MODE)."""
    if len(efforts) != 3:
        raise ConfigError(f"need 3 motor efforts, got {len(efforts)}")
    if not 0 <= control <= 0xF:
        raise ConfigError(f"control is a 4-bit field (homing 0x1, green 0x2, blue 0x4, red 0x8), got {control:#x}")
    return _frame(efforts, BASE + control)


def encode_report(encoders: Sequence[int], homed: int = 0, buttons: int = 0) -> bytes:
    """Frame a device report (used by the emulator)."""
    if len(encoders) != 3:
        raise ConfigError(f"need 3 encoder counts, got {len(encoders)}")
    if not 0 <= homed <= 7 or not 0 <= buttons <= 0xF:
        raise ConfigError(f"homed is 3 bits and buttons 4 bits, got homed={homed}, buttons={buttons}")
    return _frame(encoders, BASE + (homed << 4 | buttons))


def is_command_frame(frame: bytes) -> bool:
    return (
        len(frame) == FRAME_LEN
        and frame[0] == START
        and frame[15] == END
        and not frame[1:15].translate(None, _NIBBLE_BYTES)
    )


def is_report_frame(frame: bytes) -> bool:
    # Byte 14 of a report is not interpreted (its meaning is undocumented) and is not checked.
    return (
        len(frame) == FRAME_LEN
        and frame[0] == START
        and frame[15] == END
        and not frame[1:13].translate(None, _NIBBLE_BYTES)
        and not frame[13:14].translate(None, _STATUS_BYTES)
    )


def decode_command(frame: bytes) -> Command:
    """Inverse of ``encode_command``; raises ``ProtocolError`` on a malformed frame."""
    frame = bytes(frame)
    if not is_command_frame(frame):
        raise ProtocolError(f"not a Falcon command frame: {frame!r}")
    return Command((_get_int16(frame, 1), _get_int16(frame, 5), _get_int16(frame, 9)), frame[13] - BASE)


def decode_report(frame: bytes) -> Report:
    """Inverse of ``encode_report``; raises ``ProtocolError`` on a malformed frame."""
    frame = bytes(frame)
    if not is_report_frame(frame):
        raise ProtocolError(f"not a Falcon report frame: {frame!r}")
    status = frame[13] - BASE
    return Report((_get_int16(frame, 1), _get_int16(frame, 5), _get_int16(frame, 9)), status >> 4 & 7, status & 0xF)


class FrameParser:
    """Finds complete frames in a byte stream delivered in arbitrary chunks.

    ``feed(chunk)`` returns the frames completed by this chunk, in order. Bytes before a ``<``
    are garbage; a ``<`` whose 16-byte window is not a valid frame is skipped (resync on the next
    ``<``); an incomplete window at the end is kept for the next call. Because a valid frame
    contains no ``<`` after byte 0, a truncated frame followed by a good one never hides the good
    one. Counters (``frames``, ``garbage_bytes``, ``rejected``) let the device report link quality.

    ``kind`` is ``"report"`` (device -> host, what the driver reads) or ``"command"``
    (host -> device, what the emulator reads).
    """

    def __init__(self, kind: str = "report"):
        if kind == "report":
            self._valid = is_report_frame
        elif kind == "command":
            self._valid = is_command_frame
        else:
            raise ConfigError(f"kind must be 'report' or 'command', got {kind!r}")
        self.kind = kind
        self._buf = bytearray()
        self.frames = 0
        self.garbage_bytes = 0
        self.rejected = 0

    def reset(self) -> None:
        """Drop any partial frame (after a purge the tail belongs to a stream that is gone)."""
        self._buf.clear()

    @property
    def pending(self) -> int:
        """Bytes held back as the possible start of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> List[bytes]:
        buf = self._buf
        buf += data
        out: List[bytes] = []
        i, n = 0, len(buf)
        valid = self._valid
        while True:
            j = buf.find(b"<", i)
            if j < 0:
                self.garbage_bytes += n - i
                i = n
                break
            self.garbage_bytes += j - i
            if n - j < FRAME_LEN:
                # Early reject of a partial window that already contains a '<' past byte 0:
                # it cannot become valid, so resync now instead of waiting for 16 bytes.
                k = buf.find(b"<", j + 1)
                if k < 0:
                    i = j
                    break
                self.rejected += 1
                self.garbage_bytes += k - j
                i = k
                continue
            cand = bytes(buf[j : j + FRAME_LEN])
            if valid(cand):
                out.append(cand)
                i = j + FRAME_LEN
            else:
                self.rejected += 1
                self.garbage_bytes += 1
                i = j + 1
        del buf[:i]
        self.frames += len(out)
        return out
