"""Novint Falcon driver: ``FalconDevice`` over any ``Transport`` (pyftdi, D2XX, emulator).

This file owns the Falcon's life cycle and its per-tick exchange:

- open: connect, switch to normal mode, probe whether firmware is already running (the device
  keeps none across power cycles);
- firmware upload from a file the *user* supplies (Novint's image is under a non-commercial
  licence: Tear Cloth never ships it): size check, boot-loader handshake with retries, ``41``
  echo, 62-byte blocks each echoed and compared, normal mode, wait for the first valid packet;
- homing with LED feedback: red + homing mode until the three homed flags are set, then green;
- ``poll()``: one 16-byte command out, report(s) in, forward kinematics, filtered velocity;
- loss: any transport error, or no valid report for ``loss_timeout_s``, sets LOST with zero force;
- several Falcons: told apart by USB serial number and assigned to hands (``assign_hands``,
  ``open_falcons``).

Every failure is a ``HapticError`` subclass with a message the UI can show as is, and leaves the
device in a state (``NEEDS_FIRMWARE``, ``LOST``, ``ABSENT``) whose ``message`` says what to do.
"""
from __future__ import annotations

import os
import time
from typing import Callable, Dict, Iterable, List, Optional, Sequence

import numpy as np

from .device import (
    DeviceNotFoundError,
    DeviceState,
    DeviceStateError,
    EchoMismatchError,
    FirmwareError,
    FirmwareFileError,
    FirmwareNotRunningError,
    HandshakeError,
    HapticDevice,
    KinematicsError,
    NotHomedError,
    TransportError,
    Workspace,
)
from .falcon_kinematics import DEFAULT_EFFORT_CLAMP, WORKSPACE_CENTRE, WORKSPACE_RADIUS, FalconKinematics
from .falcon_packets import HOMING_MODE, LED_GREEN, LED_RED, FrameParser, decode_report, encode_command
from .falcon_transport import (
    BAUD_DIVISOR_9600,
    BAUD_DIVISOR_FIRMWARE,
    BAUD_DIVISOR_NORMAL,
    Transport,
    list_falcons,
    open_transport,
)

__all__ = [
    "FalconDevice",
    "KNOWN_FIRMWARE_SIZES",
    "FALCON_MAX_FORCE",
    "FALCON_MAX_STIFFNESS",
    "FALCON_MAX_DAMPING",
    "read_firmware",
    "assign_hands",
    "open_falcons",
]

# nvent_firmware.bin is 8492 bytes; an older image is 7914. Anything else is most likely the
# wrong file (a driver DLL, a truncated download), and streaming it would leave the DSP dead.
KNOWN_FIRMWARE_SIZES = (7914, 8492)
FIRMWARE_BLOCK = 62
HANDSHAKE_REQUEST = b"\x0a\x43\x0d"
HANDSHAKE_REPLIES = (b"\x00\x0a\x44\x2c\x0d", b"\x0a\x44\x2c\x0d")

# chai3d's model of the Falcon.
FALCON_MAX_FORCE = 8.0  # N
FALCON_MAX_STIFFNESS = 3000.0  # N/m
FALCON_MAX_DAMPING = 20.0  # N·s/m


def read_firmware(path, sizes: Iterable[int] = KNOWN_FIRMWARE_SIZES) -> bytes:
    """Read and size-check a user-supplied firmware image; raises ``FirmwareFileError``."""
    sizes = tuple(sizes)
    if path is None or str(path) == "":
        raise FirmwareFileError(
            "no Falcon firmware file given. The Falcon needs its firmware after every power-up; "
            "Tear Cloth cannot ship it (Novint licence): select nvent_firmware.bin from your Novint "
            "driver/SDK installation in the add-on preferences."
        )
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FirmwareFileError(f"Falcon firmware file not found: {path!r}. Select nvent_firmware.bin from your Novint driver/SDK installation.")
    try:
        with open(path, "rb") as fh:
            image = fh.read()
    except OSError as exc:
        raise FirmwareFileError(f"cannot read Falcon firmware file {path!r}: {exc}") from exc
    if len(image) not in sizes:
        expected = " or ".join(str(s) for s in sizes)
        raise FirmwareFileError(
            f"{path!r} is {len(image)} bytes, but a Falcon firmware image is {expected} bytes "
            "(nvent_firmware.bin is 8492): this is not the right file."
        )
    return image


class FalconDevice(HapticDevice):
    """One Novint Falcon. See the module docstring for the life cycle.

    Parameters (SI units):
    - ``serial``: USB serial number; None = the first Falcon found;
    - ``transport``: an already open ``Transport`` (e.g. ``FalconEmulator``); otherwise
      ``transport_factory(serial)`` (default ``open_transport``) is called by ``open()``;
    - ``firmware_path``: user-supplied image, uploaded by ``open()`` when the device has none;
    - ``effort_clamp``: motor effort limit in counts (default ±4096);
    - ``loss_timeout_s``: no valid report for this long -> LOST;
    - ``io_timeout_s``: how long one poll waits for a report.
    """

    def __init__(
        self,
        serial: Optional[str] = None,
        *,
        transport: Optional[Transport] = None,
        transport_factory: Optional[Callable[[Optional[str]], Transport]] = None,
        firmware_path=None,
        hand: Optional[str] = None,
        name: Optional[str] = None,
        effort_clamp: int = DEFAULT_EFFORT_CLAMP,
        preserve_direction: bool = True,
        firmware_sizes: Iterable[int] = KNOWN_FIRMWARE_SIZES,
        handshake_retries: int = 100,
        handshake_timeout_s: float = 0.05,
        echo_timeout_s: float = 0.1,
        io_timeout_s: float = 0.002,
        loss_timeout_s: float = 0.05,
        probe_loops: int = 50,
        start_loops: int = 1000,
        max_force: float = FALCON_MAX_FORCE,
        clock: Callable[[], float] = time.perf_counter,
        velocity_cutoff_hz: float = 40.0,
    ):
        if transport is not None and serial is None:
            serial = getattr(transport, "serial", None)
        super().__init__(
            name or f"Falcon {serial or '(first found)'}",
            max_force=max_force,
            workspace=Workspace(WORKSPACE_CENTRE, WORKSPACE_RADIUS),
            has_force=True,
            max_stiffness=FALCON_MAX_STIFFNESS,
            max_damping=FALCON_MAX_DAMPING,
            hand=hand,
            clock=clock,
            velocity_cutoff_hz=velocity_cutoff_hz,
        )
        self.serial = serial
        self._auto_name = name is None
        self.firmware_path = firmware_path
        self.firmware_sizes = tuple(firmware_sizes)
        self.handshake_retries = int(handshake_retries)
        self.handshake_timeout_s = handshake_timeout_s
        self.echo_timeout_s = echo_timeout_s
        self.io_timeout_s = io_timeout_s
        self.loss_timeout_s = loss_timeout_s
        self.probe_loops = probe_loops
        self.start_loops = start_loops
        self._transport = transport
        self._injected = transport
        self._factory = transport_factory
        self.kinematics = FalconKinematics(effort_clamp, preserve_direction)
        self._parser = FrameParser("report")
        self._efforts = (0, 0, 0)
        self._homed = 0
        self._last_rx = 0.0
        self._last_report = None  # the report that proved the firmware runs
        self.encoders = (0, 0, 0)
        self.kinematics_errors = 0
        self.polls = 0
        self.missed_polls = 0

    # ---- information ------------------------------------------------------------------------
    @property
    def efforts(self):
        """Motor efforts (counts) sent at the next poll."""
        return self._efforts

    @property
    def homed_flags(self) -> int:
        return self._homed

    @property
    def control(self) -> int:
        """LED/homing bits sent with every command: red + homing until homed, then green."""
        return LED_GREEN if self._state is DeviceState.READY else (LED_RED | HOMING_MODE)

    @property
    def link_stats(self) -> Dict[str, int]:
        """Link quality counters (garbage bytes and rejected frames say a cable is flaky)."""
        p = self._parser
        return {
            "frames": p.frames,
            "garbage_bytes": p.garbage_bytes,
            "rejected": p.rejected,
            "polls": self.polls,
            "missed_polls": self.missed_polls,
            "kinematics_errors": self.kinematics_errors,
        }

    # ---- life cycle ---------------------------------------------------------------------------
    def _connect(self) -> Transport:
        if self._factory is not None:
            return self._factory(self.serial)
        if self._injected is not None:
            return self._injected
        return open_transport(self.serial)

    def _drop_transport(self) -> None:
        # A dead link is not reused: a replugged USB device is a new device. An injected
        # transport (emulator) is kept for the next _connect, which hands it out again.
        old, self._transport = self._transport, None
        if old is not None and old is not self._injected:
            try:
                old.close()
            except TransportError:
                pass

    def _open(self) -> None:
        if self._state is DeviceState.LOST:
            self._drop_transport()
        if self._transport is None:
            try:
                self._transport = self._connect()
            except DeviceNotFoundError as exc:
                self._transport = None
                self._set_state(DeviceState.ABSENT, str(exc))
                raise
        self.serial = getattr(self._transport, "serial", self.serial)
        if self._auto_name:
            self.name = f"Falcon {self.serial}"
        try:
            self._enter_normal_mode()
            if self._firmware_running(self.probe_loops):
                self._after_firmware()
                return
        except TransportError as exc:
            self._drop_transport()
            self._set_state(DeviceState.ABSENT, f"{self.name}: {exc}")
            raise
        if self.firmware_path is not None:
            self.load_firmware(self.firmware_path)
        else:
            self._set_state(
                DeviceState.NEEDS_FIRMWARE,
                f"{self.name} has no firmware loaded (it keeps none across power cycles). Select "
                "nvent_firmware.bin from your Novint driver/SDK installation; Tear Cloth cannot ship it.",
            )

    def load_firmware(self, path=None) -> DeviceState:
        """Upload a firmware image (``path`` or ``firmware_path``) and start it.

        Raises ``FirmwareFileError``, ``HandshakeError``, ``EchoMismatchError`` or
        ``FirmwareNotRunningError``; the state is then NEEDS_FIRMWARE with the same message."""
        if self._transport is None:
            raise DeviceStateError(f"{self.name}: open() the device before loading firmware")
        path = self.firmware_path if path is None else path
        try:
            image = read_firmware(path, self.firmware_sizes)
            self._boot_loader_handshake()
            self._stream_firmware(image)
            self._enter_normal_mode()
            if not self._firmware_running(self.start_loops):
                raise FirmwareNotRunningError(
                    f"{self.name}: firmware sent but the device never answered a packet; power-cycle "
                    "the Falcon (unplug its power supply) and try again."
                )
        except FirmwareError as exc:
            self._set_state(DeviceState.NEEDS_FIRMWARE, str(exc))
            raise
        except TransportError as exc:
            self.mark_lost(str(exc))
            raise
        self.firmware_path = path
        self._after_firmware()
        return self._state

    def _enter_normal_mode(self) -> None:
        t = self._transport
        t.set_latency_timer(1)
        t.set_baud_divisor(BAUD_DIVISOR_NORMAL)
        t.purge(True, True)
        self._parser.reset()

    def _boot_loader_handshake(self) -> None:
        t = self._transport
        received = b""
        for _attempt in range(max(1, self.handshake_retries)):
            t.purge(True, True)
            t.set_latency_timer(16)
            t.set_baud_divisor(BAUD_DIVISOR_9600)
            t.set_line_property_8n1()
            t.set_flow_control_none()
            # DTR low -> high resets the DSP into its boot loader.
            t.set_modem_control(rts=False)
            t.set_modem_control(dtr=False)
            t.set_modem_control(dtr=True)
            t.write(HANDSHAKE_REQUEST)
            received = self._read_until(lambda b: b.endswith(HANDSHAKE_REPLIES[1]) or len(b) >= 5, 5, self.handshake_timeout_s)
            if received in HANDSHAKE_REPLIES:
                break
        else:
            raise HandshakeError(
                f"{self.name}: the boot loader did not answer after {self.handshake_retries} attempts "
                f"(last reply {received.hex(' ') or 'nothing'}). Check the Falcon's power supply (the "
                "USB cable alone does not power the motors) and reconnect it."
            )
        t.set_modem_control(dtr=False)
        t.set_baud_divisor(BAUD_DIVISOR_FIRMWARE)
        t.write(b"\x41")
        ack = self._read_until(lambda b: len(b) >= 1, 1, self.handshake_timeout_s)
        if ack != b"\x41":
            raise HandshakeError(f"{self.name}: the boot loader did not acknowledge the upload (got {ack.hex(' ') or 'nothing'} instead of 41)")

    def _stream_firmware(self, image: bytes) -> None:
        t = self._transport
        for offset in range(0, len(image), FIRMWARE_BLOCK):
            block = image[offset : offset + FIRMWARE_BLOCK]
            t.write(block)
            echo = self._read_until(lambda b, n=len(block): len(b) >= n, len(block), self.echo_timeout_s)
            if echo != block:
                raise EchoMismatchError(
                    f"{self.name}: firmware block {offset // FIRMWARE_BLOCK} (bytes {offset}-{offset + len(block) - 1}) "
                    f"was echoed back wrong ({len(echo)} of {len(block)} bytes, first difference at byte "
                    f"{_first_difference(block, echo)}). Use a direct USB port or another cable and retry."
                )

    def _read_until(self, done: Callable[[bytes], bool], max_bytes: int, timeout_s: float) -> bytes:
        buf = b""
        deadline = time.perf_counter() + timeout_s
        while not done(buf):
            chunk = self._transport.read(max_bytes - len(buf), timeout_s)
            if not chunk or time.perf_counter() > deadline:
                buf += chunk
                break
            buf += chunk
        return buf

    def _firmware_running(self, loops: int) -> bool:
        """Exchange zero-force packets until a valid report arrives (then keep it)."""
        t = self._transport
        pkt = encode_command((0, 0, 0), 0)
        for _ in range(loops):
            t.write(pkt)
            chunk = t.read(64, self.io_timeout_s)
            frames = self._parser.feed(chunk) if chunk else []
            if frames:
                self._last_report = decode_report(frames[-1])
                return True
        return False

    def _after_firmware(self) -> None:
        self.kinematics.reset()
        self._velocity_filter.reset()
        self._efforts = (0, 0, 0)
        self._force = np.zeros(3)
        self._last_rx = self.clock()
        report = self._last_report
        self._set_state(DeviceState.HOMING, self._homing_message())
        self._apply_report(report, self._last_rx)

    def _homing_message(self) -> str:
        return (
            f"{self.name}: homing (red LED). Pull the grip all the way out toward you, then push it "
            "straight in; the LED turns green when done."
        )

    def _close(self) -> None:
        t, self._transport = self._transport, None
        if t is not None:
            try:
                t.close()
            except TransportError:
                pass

    def _send_force(self) -> None:
        # Final packet on close: zero efforts and LEDs off.
        if self._transport is not None:
            self._transport.write(encode_command((0, 0, 0), 0))

    # ---- the 1 kHz exchange -------------------------------------------------------------------
    def _on_force(self, force: np.ndarray) -> None:
        if self._state is DeviceState.READY and force.any():
            self._efforts = self.kinematics.efforts_for_force(force)
        else:
            self._efforts = (0, 0, 0)

    def _poll(self) -> bool:
        if self._transport is None:
            raise DeviceStateError(f"{self.name}: not connected")
        self.polls += 1
        frames: List[bytes] = []
        try:
            self._transport.write(encode_command(self._efforts, self.control))
            # Drain what has arrived (a backlog would add a period of lag per stale frame) and
            # keep the newest frame; a short read means the queue is empty. Bounded, so a line
            # spewing garbage cannot hold the servo tick hostage.
            for _ in range(8):
                chunk = self._transport.read(64, self.io_timeout_s)
                if not chunk:
                    break
                frames += self._parser.feed(chunk)
                if frames and len(chunk) < 64:
                    break
        except TransportError as exc:
            self.mark_lost(str(exc))
            return False
        now = self.clock()
        if not frames:
            self.missed_polls += 1
            if now - self._last_rx > self.loss_timeout_s:
                self.mark_lost(
                    f"no answer for {1000.0 * (now - self._last_rx):.0f} ms: USB cable unplugged, power lost or firmware stalled"
                )
            return False
        self._last_rx = now
        self._apply_report(decode_report(frames[-1]), now)  # the newest frame is the freshest
        return True

    def _apply_report(self, report, now: float) -> None:
        self._buttons = report.buttons
        self._homed = report.homed
        self.encoders = report.encoders
        if report.all_homed and self._state is DeviceState.HOMING:
            self._set_state(DeviceState.READY, f"{self.name}: ready (homed, green LED)")
        elif not report.all_homed and self._state is DeviceState.READY:
            # Homing lost (power glitch reset the DSP's counters): positions are wrong again.
            self._efforts = (0, 0, 0)
            self._force = np.zeros(3)
            self._set_state(DeviceState.HOMING, self._homing_message())
        try:
            pos = self.kinematics.update(report.encoders)
        except KinematicsError:
            # Unhomed counts are relative to power-up and may not describe a reachable pose;
            # after homing this means a corrupted frame. Keep the last good position either way.
            self.kinematics_errors += 1
            return
        self._update_motion(pos, now)

    def wait_until_homed(self, timeout_s: float = 30.0, period_s: float = 0.001) -> None:
        """Poll until READY (for scripts and the Blender operator's setup step, not the servo).

        ``timeout_s`` is measured on the device clock. Raises ``NotHomedError`` on timeout and
        ``TransportError`` if the device is lost meanwhile."""
        if self._state is DeviceState.READY:
            return
        if self._state is not DeviceState.HOMING:
            raise DeviceStateError(f"{self.name}: cannot home in state {self._state.value}: {self.message}")
        start = self.clock()
        while self._state is DeviceState.HOMING:
            self.poll()
            if self._state is DeviceState.LOST:
                raise TransportError(self.message)
            if self.clock() - start > timeout_s:
                raise NotHomedError(f"{self.name}: not homed after {timeout_s:.0f} s. " + self._homing_message())
            if period_s > 0.0:
                time.sleep(period_s)


def _first_difference(a: bytes, b: bytes) -> int:
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return i
    return min(len(a), len(b))


def assign_hands(serials: Sequence[str], left: Optional[str] = None, right: Optional[str] = None) -> Dict[str, str]:
    """Map hands to Falcon serial numbers.

    Explicit ``left``/``right`` serials win (they come from the user's preferences, so the same
    physical Falcon stays on the same hand across sessions); a hand left unspecified takes the
    remaining device in sorted-serial order. With a single Falcon and no preference it goes to
    the right hand. Raises ``DeviceNotFoundError`` when a requested serial is not plugged in."""
    available = sorted(set(serials))
    for hand, s in (("left", left), ("right", right)):
        if s is not None and s not in available:
            raise DeviceNotFoundError(f"the Falcon chosen for the {hand} hand ({s!r}) is not connected; connected: {available or 'none'}")
    if left is not None and left == right:
        raise DeviceNotFoundError(f"the same Falcon ({left!r}) cannot be assigned to both hands")
    remaining = [s for s in available if s not in (left, right)]
    out: Dict[str, str] = {}
    if left is None and right is None and len(remaining) == 1:
        return {"right": remaining[0]}
    if left is None and remaining:
        left = remaining.pop(0)
    if right is None and remaining:
        right = remaining.pop(0)
    if left is not None:
        out["left"] = left
    if right is not None:
        out["right"] = right
    return out


def open_falcons(
    firmware_path=None,
    left: Optional[str] = None,
    right: Optional[str] = None,
    *,
    serials: Optional[Sequence[str]] = None,
    transport_factory: Optional[Callable[[Optional[str]], Transport]] = None,
    **device_kwargs,
) -> Dict[str, FalconDevice]:
    """Discover, assign and open the Falcons: returns {hand: FalconDevice} (READY or HOMING).

    ``serials`` defaults to ``list_falcons()``. If one device fails to open, the others are
    closed again and the error is raised."""
    found = list_falcons() if serials is None else list(serials)
    if not found:
        raise DeviceNotFoundError("no Novint Falcon found (check USB, power and, on Linux, the udev rule for 0403:cb48)")
    hands = assign_hands(found, left, right)
    devices: Dict[str, FalconDevice] = {}
    try:
        for hand, serial in hands.items():
            dev = FalconDevice(serial, hand=hand, firmware_path=firmware_path, transport_factory=transport_factory, **device_kwargs)
            dev.open()
            devices[hand] = dev
    except Exception:
        for dev in devices.values():
            dev.close()
        raise
    return devices
