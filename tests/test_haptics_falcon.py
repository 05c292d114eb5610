"""FalconDevice against the byte-level emulator: firmware upload, homing, the I/O loop, and every
failure path (no file, wrong size, handshake, echo, garbage, not homed, unplug, stall), plus two
Falcons told apart by serial."""
import numpy as np
import pytest

from tearcloth.haptics import (
    DeviceNotFoundError,
    DeviceState,
    DeviceStateError,
    EchoMismatchError,
    FalconDevice,
    FalconEmulator,
    FirmwareFileError,
    FirmwareNotRunningError,
    HandshakeError,
    HapticError,
    NotHomedError,
    Transport,
    assign_hands,
    list_falcons,
    open_falcons,
)
from tearcloth.haptics.falcon_emulator import free_hand, homing_gesture, spring_hand
from tearcloth.haptics.falcon_packets import HOMING_MODE, LED_GREEN, LED_RED
from tearcloth.haptics.falcon_transport import BAUD_DIVISOR_9600, BAUD_DIVISOR_FIRMWARE, BAUD_DIVISOR_NORMAL


@pytest.fixture
def firmware(tmp_path):
    def make(size=8492, seed=1):
        p = tmp_path / f"fw_{size}.bin"
        p.write_bytes(np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8).tobytes())
        return p

    return make


def make_device(emu, **kw):
    kw.setdefault("clock", lambda: emu.time)
    return FalconDevice(transport=emu, **kw)


def ready_device(hand=None, **emu_kw):
    emu = FalconEmulator(firmware_loaded=True, homed=True, hand=hand or spring_hand((0, 0, 0.13), 400, 6), **emu_kw)
    dev = make_device(emu)
    assert dev.open() is DeviceState.READY
    return emu, dev


def test_emulator_implements_the_transport_protocol():
    assert isinstance(FalconEmulator(), Transport)


def test_firmware_upload_follows_the_load_sequence(firmware):
    path = firmware(8492)
    emu = FalconEmulator(hand=free_hand())
    dev = make_device(emu, firmware_path=path)
    assert dev.open() is DeviceState.HOMING
    assert bytes(emu.firmware) == path.read_bytes()
    log = emu.control_log
    hs = log.index(("latency", 16))
    # Notes, section 3: 16 ms latency, 9600 baud 8N1, no flow control, RTS low, DTR low -> high...
    assert log[hs : hs + 7] == [
        ("latency", 16),
        ("baud", BAUD_DIVISOR_9600),
        ("line", "8N1"),
        ("flow", "none"),
        ("rts", False),
        ("dtr", False),
        ("dtr", True),
    ]
    assert log[hs - 1][0] == "purge"
    # ... then DTR low and divisor 0x15 for the upload, then 1 ms latency, divisor 0x2, purge.
    assert log[hs + 7 : hs + 9] == [("dtr", False), ("baud", BAUD_DIVISOR_FIRMWARE)]
    assert log[hs + 9 : hs + 12] == [("latency", 1), ("baud", BAUD_DIVISOR_NORMAL), ("purge", (True, True))]
    assert "homing" in dev.message and "push it" in dev.message


def test_handshake_without_leading_zero_and_with_dropped_attempts(firmware):
    emu = FalconEmulator(handshake_leading_zero=False, drop_handshakes=3)
    dev = make_device(emu, firmware_path=firmware(7914), firmware_sizes=(7914, 8492))
    assert dev.open() is DeviceState.HOMING
    assert emu.handshakes_seen == 4  # three ignored, the fourth answered


def test_firmware_already_running_skips_the_upload(firmware):
    emu = FalconEmulator(firmware_loaded=True)
    dev = make_device(emu, firmware_path=firmware())
    assert dev.open() is DeviceState.HOMING
    assert ("latency", 16) not in emu.control_log and len(emu.firmware) == 0


def test_no_firmware_file_leaves_needs_firmware(firmware, tmp_path):
    emu = FalconEmulator()
    dev = make_device(emu, probe_loops=5)
    assert dev.open() is DeviceState.NEEDS_FIRMWARE
    assert "nvent_firmware.bin" in dev.message
    with pytest.raises(FirmwareFileError, match="no Falcon firmware file"):
        dev.load_firmware()
    missing = tmp_path / "nope.bin"
    with pytest.raises(FirmwareFileError, match="not found"):
        dev.load_firmware(missing)
    assert dev.state is DeviceState.NEEDS_FIRMWARE and "not found" in dev.message
    # Supplying the file later brings it up.
    assert dev.load_firmware(firmware()) is DeviceState.HOMING


def test_wrong_firmware_size_is_refused_before_touching_the_device(firmware):
    emu = FalconEmulator()
    dev = make_device(emu, firmware_path=firmware(1000), probe_loops=5)
    with pytest.raises(FirmwareFileError, match="1000 bytes.*8492"):
        dev.open()
    assert dev.state is DeviceState.NEEDS_FIRMWARE
    assert emu.handshakes_seen == 0


def test_handshake_failure_after_retries(firmware):
    emu = FalconEmulator(drop_handshakes=10**9)
    dev = make_device(emu, firmware_path=firmware(), handshake_retries=7, probe_loops=5)
    with pytest.raises(HandshakeError, match="7 attempts.*power supply"):
        dev.open()
    assert emu.handshakes_seen == 7
    assert dev.state is DeviceState.NEEDS_FIRMWARE and "power supply" in dev.message


def test_echo_mismatch_is_detected(firmware):
    emu = FalconEmulator(corrupt_echo_block=7)
    dev = make_device(emu, firmware_path=firmware(), probe_loops=5)
    with pytest.raises(EchoMismatchError, match="block 7 "):
        dev.open()
    assert dev.state is DeviceState.NEEDS_FIRMWARE


def test_firmware_that_never_starts(firmware):
    emu = FalconEmulator(accepted_firmware_sizes=(8492,))  # this DSP rejects the 7914-byte image
    dev = make_device(emu, firmware_path=firmware(7914), probe_loops=5, start_loops=50)
    with pytest.raises(FirmwareNotRunningError, match="power-cycle"):
        dev.open()
    assert dev.state is DeviceState.NEEDS_FIRMWARE


def test_homing_with_led_feedback_then_io_loop(firmware):
    emu = FalconEmulator(hand=spring_hand(homing_gesture(t0=0.05), 800, 8))
    dev = make_device(emu, firmware_path=firmware())
    dev.open()
    for _ in range(20):
        dev.poll()
    assert dev.state is DeviceState.HOMING
    assert emu.control == LED_RED | HOMING_MODE  # red + homing mode while homing
    assert dev.set_force([0, 0, 3.0]).tolist() == [0, 0, 0]  # no force before homing
    assert emu.efforts == (0, 0, 0)
    dev.wait_until_homed(timeout_s=2.0, period_s=0)
    assert dev.state is DeviceState.READY and dev.homed_flags == 0b111
    dev.poll()
    assert emu.control == LED_GREEN
    # After homing the driver's position is the true grip position (within encoder quantisation).
    emu.hand = spring_hand((0.01, -0.01, 0.12), 400, 6)
    for _ in range(600):
        dev.poll()
    assert np.linalg.norm(dev.position - emu.true_position) < 1e-4
    assert np.linalg.norm(dev.position - [0.01, -0.01, 0.12]) < 1e-3


def test_not_homed_times_out_and_renders_no_force(firmware):
    emu = FalconEmulator(firmware_loaded=True, hand=spring_hand((0, 0, 0.13)))
    dev = make_device(emu)
    dev.open()
    with pytest.raises(NotHomedError, match="Pull the grip"):
        dev.wait_until_homed(timeout_s=0.2, period_s=0)
    dev.set_force([2.0, 0, 0])
    dev.poll()
    assert emu.efforts == (0, 0, 0) and dev.state is DeviceState.HOMING


def test_losing_homing_returns_to_homing_with_zero_force():
    emu, dev = ready_device()
    dev.set_force([0, 0, 2.0])
    dev.poll()
    assert emu.efforts != (0, 0, 0)
    emu.homed = 0
    dev.poll()
    assert dev.state is DeviceState.HOMING
    dev.poll()
    assert emu.efforts == (0, 0, 0)


def test_commanded_force_moves_the_grip_the_right_way():
    for axis in range(3):
        emu, dev = ready_device(hand=spring_hand((0, 0, 0.13), 300, 5))
        for _ in range(200):
            dev.poll()
        start = emu.true_position
        f = np.zeros(3)
        f[axis] = 2.0
        for _ in range(400):
            dev.poll()
            dev.set_force(f)
        shift = emu.true_position - start
        # Against a 300 N/m hand, 2 N moves the grip ~6.7 mm along the force.
        assert shift[axis] == pytest.approx(2.0 / 300.0, rel=0.1)
        assert abs(shift[(axis + 1) % 3]) < 5e-4


def test_set_force_is_clamped_to_max_force():
    emu, dev = ready_device()
    dev.poll()
    out = dev.set_force([100.0, 0, 0])
    assert np.linalg.norm(out) == pytest.approx(dev.max_force)
    assert max(abs(e) for e in dev.efforts) <= dev.kinematics.effort_clamp


def test_garbage_and_truncated_packets_are_skipped():
    emu, dev = ready_device(garbage_every=3, truncate_every=5)
    emu.hand = spring_hand(lambda t: (0.01 * np.sin(3 * t), 0.0, 0.13), 600, 8)
    for _ in range(600):
        dev.poll()
        assert np.linalg.norm(dev.position - emu.true_position) < 2e-4
    stats = dev.link_stats
    assert stats["garbage_bytes"] > 100 and stats["rejected"] > 0
    assert dev.state is DeviceState.READY


def test_unplug_mid_session_is_lost_with_zero_force():
    emu, dev = ready_device(unplug_at=0.2)
    for _ in range(150):
        assert dev.poll()
        dev.set_force([0, 0, 2.0])
    assert emu.efforts != (0, 0, 0)
    for _ in range(100):
        dev.poll()
    assert dev.state is DeviceState.LOST
    assert "connection lost" in dev.message and "No such device" in dev.message
    assert dev.force.tolist() == [0, 0, 0] and dev.efforts == (0, 0, 0)
    assert dev.poll() is False  # no exception on a lost device
    assert dev.set_force([1, 0, 0]).tolist() == [0, 0, 0]
    dev.close()
    assert dev.state is DeviceState.CLOSED


def test_stall_is_detected_as_lost_after_the_loss_timeout():
    emu, dev = ready_device(stall_at=0.1)
    n = 0
    while dev.state is DeviceState.READY and n < 1000:
        dev.poll()
        n += 1
    assert dev.state is DeviceState.LOST
    # Last answer at t = 0.099 s; loss_timeout_s = 50 ms of (emulated) silence later -> LOST.
    assert 0.099 + 0.05 <= emu.time + 1e-9 and emu.time <= 0.1 + 0.05 + 0.003
    assert "no answer" in dev.message


def test_close_sends_zero_force_and_turns_leds_off():
    emu, dev = ready_device()
    dev.poll()
    dev.set_force([0, 0, 3.0])
    dev.poll()
    assert emu.efforts != (0, 0, 0)
    dev.close()
    assert emu.efforts == (0, 0, 0) and emu.control == 0 and emu.closed
    dev.close()  # idempotent
    with pytest.raises(DeviceStateError):
        dev.poll()


def test_assign_hands_by_serial():
    assert assign_hands(["B2", "A1"]) == {"left": "A1", "right": "B2"}
    assert assign_hands(["B2", "A1"], left="B2") == {"left": "B2", "right": "A1"}
    assert assign_hands(["B2", "A1"], right="A1") == {"left": "B2", "right": "A1"}
    assert assign_hands(["A1"]) == {"right": "A1"}
    assert assign_hands(["A1"], left="A1") == {"left": "A1"}
    with pytest.raises(DeviceNotFoundError, match="not connected"):
        assign_hands(["A1", "B2"], left="C3")
    with pytest.raises(DeviceNotFoundError):
        assign_hands(["A1", "B2"], left="A1", right="A1")


def test_two_emulated_falcons_are_told_apart_and_assigned(firmware):
    emus = {
        # The upload resets the DSP (homing lost), so both hands do the homing gesture.
        "FTA1": FalconEmulator("FTA1", hand=spring_hand(homing_gesture(t0=0.01), 800, 8)),
        "FTB2": FalconEmulator("FTB2", hand=spring_hand(homing_gesture(t0=0.01), 800, 8)),
    }
    devices = open_falcons(firmware(), right="FTA1", serials=list(emus), transport_factory=lambda s: emus[s])
    assert set(devices) == {"left", "right"}
    assert devices["right"].serial == "FTA1" and devices["left"].serial == "FTB2"
    assert devices["left"].hand == "left" and devices["right"].hand == "right"
    for emu in emus.values():
        assert len(emu.firmware) == 8492
    for dev in devices.values():
        dev.wait_until_homed(timeout_s=2.0, period_s=0)
        assert dev.state is DeviceState.READY
    for emu in emus.values():
        emu.hand = spring_hand((0, 0, 0.13), 300, 5)
    # A force on the left hand reaches only the left Falcon.
    for _ in range(300):
        for dev in devices.values():
            dev.poll()
        devices["left"].set_force([2.0, 0, 0])
    assert emus["FTB2"].true_position[0] > 5e-3
    assert abs(emus["FTA1"].true_position[0]) < 1e-4
    for dev in devices.values():
        dev.close()


def test_open_falcons_without_devices_says_so():
    with pytest.raises(DeviceNotFoundError, match="no Novint Falcon"):
        open_falcons(serials=[])


def test_discovery_never_raises():
    found = list_falcons()
    assert isinstance(found, list) and all(isinstance(s, str) for s in found)


@pytest.mark.skipif(bool(list_falcons()), reason="a real Falcon is connected")
def test_opening_a_missing_falcon_is_absent_with_a_clear_error():
    dev = FalconDevice("NO-SUCH-SERIAL")
    with pytest.raises(DeviceNotFoundError, match="Falcon"):
        dev.open()
    assert dev.state is DeviceState.ABSENT and dev.message


def test_ftd2xx_transport_explains_missing_package():
    if _has_ftd2xx():
        pytest.skip("ftd2xx installed")
    from tearcloth.haptics.falcon_transport import Ftd2xxTransport

    with pytest.raises(DeviceNotFoundError, match="pip install ftd2xx"):
        Ftd2xxTransport()


def _has_ftd2xx():
    import importlib.util

    return importlib.util.find_spec("ftd2xx") is not None


def test_error_family():
    for exc in (DeviceNotFoundError, HandshakeError, EchoMismatchError, FirmwareFileError, NotHomedError):
        assert issubclass(exc, HapticError)


def test_reopen_after_unplug_and_replug_uploads_firmware_again(firmware):
    emu = FalconEmulator(hand=spring_hand((0, 0, 0.13)))
    dev = make_device(emu, firmware_path=firmware())
    dev.open()
    emu.unplug()
    dev.poll()
    assert dev.state is DeviceState.LOST
    with pytest.raises(HapticError):
        dev.open()  # still unplugged: a clear error, not a hang
    assert dev.state is DeviceState.ABSENT
    emu.replug()
    assert dev.open() is DeviceState.HOMING
    assert len(emu.firmware) == 8492


def test_grip_buttons_reach_the_device():
    emu, dev = ready_device(buttons=lambda t: 0b0100 if t > 0.01 else 0)
    dev.poll()
    assert dev.buttons == 0
    for _ in range(15):
        dev.poll()
    assert dev.buttons == 0b0100 and dev.button_set == {2}
