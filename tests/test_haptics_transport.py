"""PyFtdiTransport at the USB level: a fake pyusb device checks every control request against the
notes (bmRequestType 0x40, wIndex 0, values) and bridges them to the Falcon emulator, so a full
firmware upload and I/O loop run through the real transport code, status bytes included."""
import numpy as np
import pytest
import usb.core

import pyftdi.ftdi

from tearcloth.haptics import DeviceState, FalconDevice, FalconEmulator, TransportError
from tearcloth.haptics import falcon_transport as ft
from tearcloth.haptics.falcon_emulator import spring_hand


class FakeUsbDevice:
    """Speaks FTDI vendor requests and bulk transfers; forwards them to a FalconEmulator."""

    def __init__(self, emu):
        self.emu = emu
        self.requests = []
        self.extra_packets = []  # raw IN packets to deliver before the emulator's data
        self.fail = False

    def ctrl_transfer(self, bm_request_type, b_request, w_value=0, w_index=0, data=None, timeout=None):
        if self.fail:
            raise usb.core.USBError("[Errno 19] No such device")
        assert bm_request_type == 0x40 and w_index == 0, (bm_request_type, b_request, w_value, w_index)
        self.requests.append((b_request, w_value))
        e = self.emu
        if b_request == 0:
            if w_value in (1, 2):
                e.purge(rx=w_value == 1, tx=w_value == 2)
        elif b_request == 1:
            mask, level = w_value >> 8, w_value & 0xFF
            e.set_modem_control(dtr=bool(level & 1) if mask & 1 else None, rts=bool(level & 2) if mask & 2 else None)
        elif b_request == 2:
            assert w_value == 0
            e.set_flow_control_none()
        elif b_request == 3:
            e.set_baud_divisor(w_value)
        elif b_request == 4:
            assert w_value == 0x0008  # 8N1
            e.set_line_property_8n1()
        elif b_request == 9:
            e.set_latency_timer(w_value)
        else:
            raise AssertionError(f"unexpected request {b_request}")
        return 0

    def read(self, endpoint, size, timeout):
        assert endpoint == 0x81 and size == 64
        if self.fail:
            raise usb.core.USBError("[Errno 19] No such device")
        if self.extra_packets:
            return self.extra_packets.pop(0)
        data = self.emu.read(62, 0.0)
        if not data:
            raise usb.core.USBTimeoutError("timeout")
        return b"\x01\x60" + data  # modem status, then payload


class FakeFtdi:
    """Only what PyFtdiTransport uses of pyftdi.ftdi.Ftdi."""

    devices = {}

    @classmethod
    def add_custom_product(cls, vid, pid, name=""):
        pass

    def open(self, vendor, product, serial=None, interface=1):
        assert (vendor, product) == (0x0403, 0xCB48) and interface == 1
        if serial not in self.devices:
            raise usb.core.USBError(f"device {serial} not found")
        self.usb_dev = self.devices[serial]

    def write_data(self, data):
        if self.usb_dev.fail:
            raise usb.core.USBError("[Errno 19] No such device")
        return self.usb_dev.emu.write(data)

    def close(self):
        self.usb_dev.emu.close()


@pytest.fixture
def fake_usb(monkeypatch):
    monkeypatch.setattr(pyftdi.ftdi, "Ftdi", FakeFtdi)
    FakeFtdi.devices = {}

    def add(serial, **emu_kw):
        dev = FakeUsbDevice(FalconEmulator(serial, **emu_kw))
        FakeFtdi.devices[serial] = dev
        return dev

    return add


def test_firmware_upload_and_io_loop_through_pyftdi_transport(fake_usb, tmp_path):
    usbdev = fake_usb("FT123", hand=spring_hand((0.0, 0.01, 0.12), 400, 6), homed=False)
    fw = tmp_path / "nvent_firmware.bin"
    fw.write_bytes(bytes(range(256)) * 33 + bytes(44))  # 8492 bytes
    t = ft.PyFtdiTransport("FT123")
    dev = FalconDevice(transport=t, firmware_path=fw, clock=lambda: usbdev.emu.time)
    assert dev.open() is DeviceState.HOMING
    assert bytes(usbdev.emu.firmware) == fw.read_bytes()
    req = usbdev.requests
    # Values from the notes: 16 ms latency, divisor 0x4138, 8N1, no flow control, RTS low,
    # DTR low, DTR high, DTR low, divisor 0x15, then latency 1 ms and divisor 0x2.
    i = req.index((9, 16))
    assert req[i : i + 7] == [(9, 16), (3, 0x4138), (4, 8), (2, 0), (1, 0x0200), (1, 0x0100), (1, 0x0101)]
    assert req[i + 7 : i + 11] == [(1, 0x0100), (3, 0x15), (9, 1), (3, 0x2)]
    assert (0, 1) in req and (0, 2) in req
    usbdev.emu.homed = 0b111  # homing done
    for _ in range(400):
        dev.poll()
    assert dev.state is DeviceState.READY
    assert np.linalg.norm(dev.position - usbdev.emu.true_position) < 1e-4


def test_status_only_packets_are_skipped_and_leftovers_kept(fake_usb):
    usbdev = fake_usb("FT9")
    t = ft.PyFtdiTransport("FT9")
    usbdev.extra_packets = [b"\x01\x60", b"\x01\x60abcdef"]
    assert t.read(4, 0.05) == b"abcd"  # status-only packet skipped, status bytes stripped
    assert t.read(64, 0.05) == b"ef"  # the rest of the packet is not lost
    assert t.read(64, 0.0) == b""  # timeout -> empty
    t.purge()
    usbdev.extra_packets = [b"\x01\x60xyz"]
    assert t.read(2, 0.05) == b"xy"
    t.purge(rx=True, tx=False)
    assert t.read(64, 0.0) == b""  # purge RX also drops the leftover


def test_usb_errors_become_transport_errors_and_lost(fake_usb):
    usbdev = fake_usb("FT7", firmware_loaded=True, homed=True)
    dev = FalconDevice(transport=ft.PyFtdiTransport("FT7"))
    assert dev.open() is DeviceState.READY
    usbdev.fail = True
    with pytest.raises(TransportError, match="No such device"):
        dev._transport.read(64, 0.001)
    assert dev.poll() is False
    assert dev.state is DeviceState.LOST and "No such device" in dev.message


def test_open_unknown_serial_is_device_not_found(fake_usb):
    fake_usb("FT1")
    with pytest.raises(ft.DeviceNotFoundError, match="udev"):
        ft.PyFtdiTransport("NOPE")


class FakeD2xxDevice:
    """The subset of ftd2xx.FTD2XX that Ftd2xxTransport uses, over a FalconEmulator."""

    def __init__(self, emu):
        self.emu = emu
        self.rx = b""

    def _pull(self):
        self.rx += self.emu.read(4096, 0.0)

    def purge(self, mask):
        self.emu.purge(rx=bool(mask & 1), tx=bool(mask & 2))
        if mask & 1:
            self.rx = b""

    def setDtr(self):
        self.emu.set_modem_control(dtr=True)

    def clrDtr(self):
        self.emu.set_modem_control(dtr=False)

    def setRts(self):
        self.emu.set_modem_control(rts=True)

    def clrRts(self):
        self.emu.set_modem_control(rts=False)

    def setDivisor(self, div):
        self.emu.set_baud_divisor(div)

    def setDataCharacteristics(self, bits, stop, parity):
        assert (bits, stop, parity) == (8, 0, 0)
        self.emu.set_line_property_8n1()

    def setFlowControl(self, flow, xon=-1, xoff=-1):
        assert flow == 0
        self.emu.set_flow_control_none()

    def setLatencyTimer(self, ms):
        self.emu.set_latency_timer(ms)

    def write(self, data):
        return self.emu.write(data)

    def getQueueStatus(self):
        self._pull()
        return len(self.rx)

    def read(self, n):
        out, self.rx = self.rx[:n], self.rx[n:]
        return out

    def close(self):
        self.emu.close()


def test_ftd2xx_transport_with_a_fake_driver(monkeypatch, tmp_path):
    import sys
    import types

    emu = FalconEmulator("D2XX1")
    fake = types.ModuleType("ftd2xx")
    fake.createDeviceInfoList = lambda: 2
    fake.getDeviceInfoDetail = lambda i, update=True: [
        {"id": 0x04036001, "serial": b"OTHER"},
        {"id": 0x0403CB48, "serial": b"D2XX1"},
    ][i]
    fake.openEx = lambda serial: FakeD2xxDevice(emu) if serial == b"D2XX1" else (_ for _ in ()).throw(OSError("DEVICE_NOT_FOUND"))
    monkeypatch.setitem(sys.modules, "ftd2xx", fake)
    t = ft.Ftd2xxTransport()  # no serial: the Falcon is picked by VID:PID, not the other FTDI device
    assert t.serial == "D2XX1"
    fw = tmp_path / "fw.bin"
    fw.write_bytes(bytes(7914))
    dev = FalconDevice(transport=t, firmware_path=fw, clock=lambda: emu.time)
    assert dev.open() is DeviceState.HOMING
    assert len(emu.firmware) == 7914
    with pytest.raises(ft.DeviceNotFoundError, match="D2XX"):
        ft.Ftd2xxTransport("MISSING")
