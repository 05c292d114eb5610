"""Byte transports to a Novint Falcon, and discovery of the Falcons plugged in.

This file owns the ``Transport`` protocol (the FTDI operations the Falcon driver needs: purge,
modem control, raw baud divisor, line property, flow control, latency timer, bulk write, bulk read
with timeout) and its real implementations:

- ``PyFtdiTransport``: pyftdi over pyusb/libusb-1.0, every platform where libusb can claim the
  device (Linux with a udev rule for 0403:cb48, macOS, Windows with a WinUSB driver);
- ``Ftd2xxTransport``: FTDI's own D2XX driver through the ``ftd2xx`` package, the natural choice
  on Windows where Novint's installer binds D2XX; imported only when ``ftd2xx`` is installed.

The emulator (``falcon_emulator.FalconEmulator``) implements the same protocol at the byte level.

Why not hidapi: the Falcon is an FTDI FT232 USB-serial bridge (VID 0x0403, PID 0xCB48, vendor
class), not a HID device. hidapi only opens HID-class interfaces (its libusb back end filters on
bInterfaceClass == HID; on Windows and macOS it goes through the OS HID stack), so **hidapi cannot
open a Falcon**; hidapi is used for the SpaceMouse family only (``spacemouse.py``).

Errors: every failure surfaces as ``TransportError`` (or ``DeviceNotFoundError`` when opening),
so ``FalconDevice`` can turn any of them into the LOST state.
"""
from __future__ import annotations

import sys
import time
from typing import List, Optional, Protocol, runtime_checkable

from .device import ConfigError, DeviceNotFoundError, HapticError, TransportError

__all__ = [
    "FALCON_VID",
    "FALCON_PID",
    "BAUD_DIVISOR_9600",
    "BAUD_DIVISOR_FIRMWARE",
    "BAUD_DIVISOR_NORMAL",
    "Transport",
    "PyFtdiTransport",
    "Ftd2xxTransport",
    "list_falcons",
    "open_transport",
]

FALCON_VID = 0x0403
FALCON_PID = 0xCB48
FALCON_DESCRIPTION = "FALCON HAPTIC"

# Raw FTDI baud divisors (not baud rates: the Falcon's boot loader and firmware expect these
# exact divisors, and pyftdi's rate -> divisor search would not reproduce 0x15).
BAUD_DIVISOR_9600 = 0x4138  # boot loader handshake
BAUD_DIVISOR_FIRMWARE = 0x15  # 3 MHz / 21 ≈ 142 857 baud: firmware upload
BAUD_DIVISOR_NORMAL = 0x2  # 1.5 Mbaud: the 1 kHz packet loop

# FTDI vendor control requests (bmRequestType 0x40 = host-to-device, vendor, device).
_REQ_OUT = 0x40
_SIO_RESET = 0
_SIO_MODEM_CTRL = 1
_SIO_SET_FLOW_CTRL = 2
_SIO_SET_BAUDRATE = 3
_SIO_SET_DATA = 4
_SIO_SET_LATENCY = 9
_PURGE_RX = 1
_PURGE_TX = 2
# Modem control wValue: high byte = which lines change, low byte = their new level.
_DTR_HIGH = 0x0101
_DTR_LOW = 0x0100
_RTS_HIGH = 0x0202
_RTS_LOW = 0x0200
_LINE_8N1 = 0x0008  # 8 data bits; parity none and 1 stop bit are the zero fields
_BULK_IN = 0x81
_USB_PACKET = 64  # full-speed bulk packet: 2 modem-status bytes + up to 62 payload bytes


@runtime_checkable
class Transport(Protocol):
    """What ``FalconDevice`` needs from a link. All methods raise ``TransportError`` on failure.

    ``read`` contract: return as soon as at least one byte is available (up to ``max_bytes``), or
    ``b""`` once ``timeout_s`` has elapsed with nothing. Callers treat ``b""`` as "timed out", so
    an emulator may return it immediately instead of really waiting."""

    serial: str

    def purge(self, rx: bool = True, tx: bool = True) -> None: ...

    def set_modem_control(self, *, dtr: Optional[bool] = None, rts: Optional[bool] = None) -> None: ...

    def set_baud_divisor(self, divisor: int) -> None: ...

    def set_line_property_8n1(self) -> None: ...

    def set_flow_control_none(self) -> None: ...

    def set_latency_timer(self, ms: int) -> None: ...

    def write(self, data: bytes) -> int: ...

    def read(self, max_bytes: int, timeout_s: float) -> bytes: ...

    def close(self) -> None: ...


class PyFtdiTransport:
    """Falcon link through pyftdi (libusb). ``serial=None`` opens the first Falcon found.

    pyftdi only knows FTDI's own PIDs; the Falcon's 0xCB48 is registered once with
    ``Ftdi.add_custom_product``. pyftdi strips the two modem-status bytes that start every FTDI
    IN packet, so ``read`` returns payload only."""

    _registered = False

    def __init__(self, serial: Optional[str] = None, write_timeout_s: float = 0.1):
        try:
            from pyftdi.ftdi import Ftdi, FtdiError
            from usb.core import USBError
        except ImportError as exc:  # pragma: no cover - pyftdi is a declared dependency
            raise DeviceNotFoundError(f"pyftdi/pyusb are not installed ({exc}); install them to use a Falcon") from exc
        try:
            from usb.core import USBTimeoutError
        except ImportError:  # pragma: no cover - pyusb < 1.2
            USBTimeoutError = ()
        self._errors = (FtdiError, USBError, OSError, ValueError)
        self._timeout_error = USBTimeoutError
        _register_pyftdi_pid()
        self._ftdi = Ftdi()
        self._write_timeout_ms = max(1, int(write_timeout_s * 1000))
        try:
            self._ftdi.open(FALCON_VID, FALCON_PID, serial=serial, interface=1)
        except Exception as exc:  # pyusb NoBackendError, USBError (permissions), "not found"...
            which = f"with serial {serial!r}" if serial else "(any)"
            raise DeviceNotFoundError(
                f"cannot open Novint Falcon {which} through libusb: {exc}. Check the cable and power; "
                "on Linux add a udev rule for 0403:cb48 (MODE=0666); on Windows use Ftd2xxTransport "
                "with Novint's driver, or bind WinUSB to the device."
            ) from exc
        self.serial = serial or _usb_serial(self._ftdi) or "?"
        # pyftdi's default write timeout is 5 s: a wedged device would freeze the servo tick.
        self._ftdi.timeouts = (1000, self._write_timeout_ms)
        self._rx = b""

    def _call(self, what: str, fn, *args):
        try:
            return fn(*args)
        except self._errors as exc:
            raise TransportError(f"Falcon {self.serial}: {what} failed: {exc}") from exc

    def _ctrl(self, request: int, value: int) -> None:
        # Raw vendor requests with wIndex 0, exactly as the Falcon's load sequence specifies.
        # (pyftdi's own helpers would put the port number, 1, in wIndex; on the FT232 the baud
        # request's wIndex carries extra divisor bits, which the Falcon's divisors must not have.)
        self._call(
            f"control request {request} (value {value:#06x})",
            self._ftdi.usb_dev.ctrl_transfer,
            _REQ_OUT,
            request,
            value,
            0,
            b"",
            self._write_timeout_ms,
        )

    def purge(self, rx: bool = True, tx: bool = True) -> None:
        if rx:
            self._ctrl(_SIO_RESET, _PURGE_RX)
            self._rx = b""
        if tx:
            self._ctrl(_SIO_RESET, _PURGE_TX)

    def set_modem_control(self, *, dtr: Optional[bool] = None, rts: Optional[bool] = None) -> None:
        if dtr is not None:
            self._ctrl(_SIO_MODEM_CTRL, _DTR_HIGH if dtr else _DTR_LOW)
        if rts is not None:
            self._ctrl(_SIO_MODEM_CTRL, _RTS_HIGH if rts else _RTS_LOW)

    def set_baud_divisor(self, divisor: int) -> None:
        self._ctrl(_SIO_SET_BAUDRATE, int(divisor))

    def set_line_property_8n1(self) -> None:
        self._ctrl(_SIO_SET_DATA, _LINE_8N1)

    def set_flow_control_none(self) -> None:
        self._ctrl(_SIO_SET_FLOW_CTRL, 0)

    def set_latency_timer(self, ms: int) -> None:
        if not 1 <= int(ms) <= 255:
            raise ConfigError(f"latency timer is 1..255 ms, got {ms}")
        self._ctrl(_SIO_SET_LATENCY, int(ms))

    def write(self, data: bytes) -> int:
        return self._call("bulk write", self._ftdi.write_data, bytes(data))

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        # One bulk IN transfer per USB packet, straight through pyusb: pyftdi's read_data_bytes
        # keeps reading until it has ``size`` bytes or sees an empty packet, which costs one
        # extra latency period (1 ms) per call, a full servo period. Each IN packet starts with
        # the two modem-status bytes; with the latency timer at 1 ms the chip sends one every
        # millisecond even when idle, so a transfer returns within ~1 ms.
        if self._rx:
            out, self._rx = self._rx[:max_bytes], self._rx[max_bytes:]
            return bytes(out)
        deadline = time.perf_counter() + timeout_s
        while True:
            remaining_ms = max(1, int(round((deadline - time.perf_counter()) * 1000.0)))
            try:
                packet = self._ftdi.usb_dev.read(_BULK_IN, _USB_PACKET, remaining_ms)
            except self._timeout_error:
                return b""
            except self._errors as exc:
                raise TransportError(f"Falcon {self.serial}: bulk read failed: {exc}") from exc
            payload = bytes(packet[2:])
            if payload:
                out, self._rx = payload[:max_bytes], payload[max_bytes:]
                return out
            if time.perf_counter() >= deadline:
                return b""

    def close(self) -> None:
        try:
            self._ftdi.close()
        except self._errors:
            pass


def _prime_libusb() -> None:
    """pyusb looks for libusb-1.0 on the system's library path; where there is none (Windows, a
    Mac without Homebrew's) the copy the ``libusb-package`` wheel carries is loaded instead.
    pyusb keeps the first library it loads, so pyftdi's own back-end lookup finds it too."""
    import usb.backend.libusb1 as libusb1

    if libusb1.get_backend() is not None:
        return
    try:
        import libusb_package
    except ImportError:
        return  # the open below then names the missing back end
    libusb1.get_backend(find_library=libusb_package.find_library)


def _register_pyftdi_pid() -> None:
    if PyFtdiTransport._registered:
        return
    _prime_libusb()
    from pyftdi.ftdi import Ftdi

    try:
        Ftdi.add_custom_product(FALCON_VID, FALCON_PID, "falcon")
    except ValueError:
        pass  # already registered (by us in another module instance, or by the user)
    PyFtdiTransport._registered = True


def _usb_serial(ftdi) -> Optional[str]:
    try:
        dev = ftdi.usb_dev
        import usb.util

        return usb.util.get_string(dev, dev.iSerialNumber)
    except Exception:
        return None


class Ftd2xxTransport:
    """Falcon link through FTDI's D2XX driver (``pip install ftd2xx``), mainly for Windows.

    The ``ftd2xx`` module is imported here, on first use, so that importing this file never
    requires it."""

    def __init__(self, serial: Optional[str] = None, write_timeout_s: float = 0.1):
        try:
            import ftd2xx  # noqa: F401
        except ImportError as exc:
            raise DeviceNotFoundError("the ftd2xx package is not installed; `pip install ftd2xx` (Windows, FTDI D2XX driver)") from exc
        self._ftd2xx = ftd2xx
        self._write_timeout_ms = max(1, int(write_timeout_s * 1000))
        try:
            if serial is None:
                found = _ftd2xx_falcon_serials(ftd2xx)
                if not found:
                    raise DeviceNotFoundError("no Novint Falcon found through the FTDI D2XX driver")
                serial = found[0]
            self._dev = ftd2xx.openEx(serial.encode("ascii"))
        except HapticError:
            raise
        except Exception as exc:
            raise DeviceNotFoundError(f"cannot open Novint Falcon {serial!r} through D2XX: {exc}") from exc
        self.serial = serial
        self._read_timeout_ms = -1

    def _call(self, what: str, fn, *args):
        try:
            return fn(*args)
        except Exception as exc:  # ftd2xx.DeviceError carries the FT_STATUS name
            raise TransportError(f"Falcon {self.serial}: {what} failed: {exc}") from exc

    def purge(self, rx: bool = True, tx: bool = True) -> None:
        mask = (_PURGE_RX if rx else 0) | (_PURGE_TX if tx else 0)
        if mask:
            self._call("purge", self._dev.purge, mask)

    def set_modem_control(self, *, dtr: Optional[bool] = None, rts: Optional[bool] = None) -> None:
        if dtr is not None:
            self._call("set DTR", self._dev.setDtr if dtr else self._dev.clrDtr)
        if rts is not None:
            self._call("set RTS", self._dev.setRts if rts else self._dev.clrRts)

    def set_baud_divisor(self, divisor: int) -> None:
        # FT_SetDivisor writes the raw divisor, exactly what the Falcon expects.
        self._call("set baud divisor", self._dev.setDivisor, int(divisor))

    def set_line_property_8n1(self) -> None:
        self._call("set line property", self._dev.setDataCharacteristics, 8, 0, 0)  # 8 bits, 1 stop, no parity

    def set_flow_control_none(self) -> None:
        self._call("set flow control", self._dev.setFlowControl, 0)

    def set_latency_timer(self, ms: int) -> None:
        self._call("set latency timer", self._dev.setLatencyTimer, int(ms))

    def write(self, data: bytes) -> int:
        return self._call("write", self._dev.write, bytes(data))

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        deadline = time.perf_counter() + timeout_s
        while True:
            # Read only what is queued so FT_Read never blocks past our deadline.
            queued = self._call("queue status", self._dev.getQueueStatus)
            if queued:
                return bytes(self._call("read", self._dev.read, min(int(max_bytes), queued)))
            if time.perf_counter() >= deadline:
                return b""
            time.sleep(0.0001)

    def close(self) -> None:
        try:
            self._dev.close()
        except Exception:
            pass


def _ftd2xx_falcon_serials(ftd2xx) -> List[str]:
    serials = []
    n = ftd2xx.createDeviceInfoList()
    for i in range(n):
        info = ftd2xx.getDeviceInfoDetail(i, update=False)
        if info.get("id") == (FALCON_VID << 16 | FALCON_PID):
            serials.append(info["serial"].decode("ascii", "replace"))
    return serials


def list_falcons() -> List[str]:
    """Serial numbers of the Falcons plugged in, sorted. Never raises: no libusb back end, no
    permission or no device all give ``[]`` (the UI shows "no Falcon found")."""
    found = set()
    try:
        from pyftdi.usbtools import UsbTools

        for desc, _ifcount in UsbTools.find_all([(FALCON_VID, FALCON_PID)], nocache=True):
            if desc.sn:
                found.add(desc.sn)
    except Exception:
        pass
    if not found and sys.platform == "win32":
        try:
            import ftd2xx

            found.update(_ftd2xx_falcon_serials(ftd2xx))
        except Exception:
            pass
    return sorted(found)


def open_transport(serial: Optional[str] = None, backend: str = "auto") -> Transport:
    """Open a Falcon link. ``backend``: ``"pyftdi"``, ``"ftd2xx"`` or ``"auto"`` (D2XX first on
    Windows, where Novint's driver owns the device, then pyftdi)."""
    if backend == "pyftdi":
        return PyFtdiTransport(serial)
    if backend == "ftd2xx":
        return Ftd2xxTransport(serial)
    if backend != "auto":
        raise ConfigError(f"backend must be 'auto', 'pyftdi' or 'ftd2xx', got {backend!r}")
    errors = []
    order = (Ftd2xxTransport, PyFtdiTransport) if sys.platform == "win32" else (PyFtdiTransport,)
    for cls in order:
        try:
            return cls(serial)
        except DeviceNotFoundError as exc:
            errors.append(str(exc))
    raise DeviceNotFoundError("; ".join(errors))
