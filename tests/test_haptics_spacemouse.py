"""SpaceMouse HID reports (split and combined layouts) and the rate-controlled grasp."""
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fakes import FakeHid  # tests/ is on sys.path (conftest.py)
from tearcloth.haptics import DeviceState, ServoLoop, SpaceMouseDevice, Workspace, list_spacemice
from tearcloth.haptics.device import ConfigError, ProtocolError
from tearcloth.haptics.spacemouse import (
    COMBINED,
    SPACEMOUSE_MODELS,
    SPLIT,
    buttons_report,
    combined_report,
    parse_report,
    rotation_report,
    translation_report,
)


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_model_table_matches_the_notes():
    split = [(0x046D, p) for p in (0xC626, 0xC627, 0xC625, 0xC629, 0xC62B)] + [(0x256F, 0xC635), (0x256F, 0xC641)]
    combined = [(0x256F, p) for p in (0xC62E, 0xC63A, 0xC632, 0xC638, 0xC633, 0xC652)]
    for key in split:
        assert SPACEMOUSE_MODELS[key][1] == SPLIT
    for key in combined:
        assert SPACEMOUSE_MODELS[key][1] == COMBINED


def test_split_layout_reports_by_hand():
    # Literal bytes: x = 300 (0x012C), y = -2 (0xFFFE), z = 0x0100.
    rep = parse_report(bytes([0x01, 0x2C, 0x01, 0xFE, 0xFF, 0x00, 0x01]), SPLIT)
    assert rep.translation == (300, -2, 256) and rep.rotation is None and rep.buttons is None
    rep = parse_report(bytes([0x02, 0x9C, 0xFF, 0x05, 0x00, 0x00, 0x80]), SPLIT)
    assert rep.rotation == (-100, 5, -32768) and rep.translation is None
    rep = parse_report(bytes([0x03, 0x05, 0x00]), SPLIT)
    assert rep.buttons == 0b101


def test_combined_layout_report_by_hand():
    data = bytes([0x01]) + struct.pack("<6h", 10, -20, 30, -40, 50, -60)
    assert len(data) == 13
    rep = parse_report(data, COMBINED)
    assert rep.translation == (10, -20, 30) and rep.rotation == (-40, 50, -60)


@given(st.tuples(*[st.integers(-32768, 32767)] * 6), st.integers(0, 2**32 - 1))
def test_report_builders_round_trip(v, mask):
    assert parse_report(translation_report(*v[:3]), SPLIT).translation == v[:3]
    assert parse_report(rotation_report(*v[3:]), SPLIT).rotation == v[3:]
    rep = parse_report(combined_report(*v), COMBINED)
    assert rep.translation == v[:3] and rep.rotation == v[3:]
    assert parse_report(buttons_report(mask), SPLIT).buttons == mask


def test_malformed_and_unknown_reports():
    with pytest.raises(ProtocolError, match="13 bytes"):
        parse_report(translation_report(1, 2, 3), COMBINED)
    with pytest.raises(ProtocolError):
        parse_report(b"\x01\x00", SPLIT)
    with pytest.raises(ProtocolError):
        parse_report(b"", SPLIT)
    assert parse_report(b"\x17\x01\x02", SPLIT) == (None, None, None)


def make(reports=(), pid=0xC635, **kw):
    clock = Clock()
    hid = FakeHid(reports)
    dev = SpaceMouseDevice(vid=0x256F, pid=pid, hid_device=hid, clock=clock, **kw)
    assert dev.open() is DeviceState.READY
    return dev, hid, clock


def test_velocity_mode_integrates_translation_inside_the_workspace():
    dev, hid, clock = make(max_speed=0.2, deadzone=0.0, workspace=Workspace((0, 0, 0), 0.1))
    assert dev.layout == SPLIT and hid.opened == ("vidpid", 0x256F, 0xC635) and hid.nonblocking
    hid.feed(translation_report(350, 0, 0))
    for _ in range(100):  # 0.1 s at full deflection: 2 cm along +x
        clock.t += 0.001
        dev.poll()
    np.testing.assert_allclose(dev.position, (0.02, 0, 0), atol=1e-9)
    np.testing.assert_allclose(dev.velocity, (0.2, 0, 0), atol=1e-9)
    # HID y (toward the user) and z (down) map to -y, -z in the grasp frame.
    hid.feed(translation_report(0, 175, 175))
    clock.t += 0.1
    dev.poll()
    np.testing.assert_allclose(dev.position, (0.02, -0.01, -0.01), atol=1e-9)
    # Held at full deflection for long, the grasp stops at the workspace boundary.
    hid.feed(translation_report(350, 0, 0))
    for _ in range(50):
        clock.t += 0.1
        dev.poll()
    assert np.linalg.norm(dev.position) == pytest.approx(0.1)
    # Releasing the puck stops the grasp where it is.
    hid.feed(translation_report(0, 0, 0))
    p = dev.position
    clock.t += 0.5
    dev.poll()
    np.testing.assert_allclose(dev.position, p)


def test_deadzone_ignores_puck_drift():
    dev, hid, clock = make(deadzone=0.05)
    hid.feed(translation_report(12, -15, 17))  # under 5% of 350
    clock.t += 1.0
    dev.poll()
    np.testing.assert_allclose(dev.position, (0, 0, 0))


def test_position_mode_and_combined_layout():
    dev, hid, clock = make(pid=0xC652, mode="position", deadzone=0.0, workspace=Workspace((0, 0, 0.5), 0.1))
    assert dev.layout == COMBINED
    hid.feed(combined_report(175, 0, 0, 7, 8, 9))
    clock.t += 0.01
    assert dev.poll()
    np.testing.assert_allclose(dev.position, (0.05, 0, 0.5), atol=1e-12)
    assert dev.raw_rotation == (7, 8, 9)


def test_buttons_led_no_force_and_unplug():
    dev, hid, clock = make()
    hid.feed(buttons_report(0b10))
    dev.poll()
    assert dev.buttons == 0b10 and dev.button_set == {1}
    assert not dev.has_force
    assert dev.set_force([5.0, 0, 0]).tolist() == [0, 0, 0]
    dev.set_led(True)
    assert hid.written[-1] == [0x04, 0x01]
    hid.feed(b"\x01\x00")  # a short report is counted, not fatal
    dev.poll()
    assert dev.bad_reports == 1 and dev.state is DeviceState.READY
    hid.unplug()
    assert dev.poll() is False
    assert dev.state is DeviceState.LOST and "HID read failed" in dev.message
    dev.close()
    assert hid.closed and dev.state is DeviceState.CLOSED


def test_spacemouse_in_the_servo_loop_publishes_a_proxy_without_force():
    dev, hid, clock = make(deadzone=0.0)
    loop = ServoLoop([dev], clock=clock)
    hid.feed(translation_report(350, 0, 0))
    for _ in range(10):
        clock.t += 0.001
        loop.publish("right", (3.0, 0, 0), (0, 0, 0))
        p = loop.tick("right")
    assert p.position[0] > 0 and p.force.tolist() == [0, 0, 0]


def test_bad_parameters_and_discovery():
    with pytest.raises(ConfigError):
        SpaceMouseDevice(hid_device=FakeHid(), mode="joystick")
    with pytest.raises(ConfigError):
        SpaceMouseDevice(hid_device=FakeHid(), deadzone=1.5)
    assert isinstance(list_spacemice(), list)  # never raises, even without devices or permissions
