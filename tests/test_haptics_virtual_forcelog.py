"""VirtualDevice, the device base contract, the velocity filter, and the force log (CSV, PNG)."""
import math

import numpy as np
import pytest

from tearcloth.haptics import (
    ConfigError,
    DeviceState,
    DeviceStateError,
    ForceLog,
    HandCoupling,
    ServoLoop,
    VelocityFilter,
    VirtualDevice,
    Workspace,
)


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_virtual_device_follows_its_script_with_buttons():
    clock = Clock()
    dev = VirtualDevice(script=lambda t: ((0.05 * t, 0.0, 0.0), 1 if t > 0.05 else 0), clock=clock)
    with pytest.raises(DeviceStateError, match="open"):
        dev.poll()
    dev.open()
    for _ in range(100):
        clock.t += 0.001
        dev.poll()
    np.testing.assert_allclose(dev.position, (0.005, 0, 0), atol=1e-12)
    assert dev.velocity[0] == pytest.approx(0.05, rel=0.02)  # filter has converged on a ramp
    assert dev.buttons == 1


def test_setters_clamp_to_workspace_and_readers_get_copies():
    clock = Clock()
    dev = VirtualDevice(workspace=Workspace((0, 0, 0), 0.1), clock=clock)
    dev.open()
    dev.set_position((1.0, 0, 0))
    dev.poll()
    np.testing.assert_allclose(dev.position, (0.1, 0, 0))
    dev.move_by((-0.05, 0.0, 0.0))
    dev.press(3)
    dev.poll()
    np.testing.assert_allclose(dev.position, (0.05, 0, 0))
    assert dev.button_set == {3}
    dev.release(3)
    dev.poll()
    assert dev.buttons == 0
    p = dev.position
    p[0] = 99.0
    assert dev.position[0] == pytest.approx(0.05)
    with pytest.raises(ConfigError):
        dev.set_position((math.inf, 0, 0))


def test_force_recording_clamp_and_zero_on_close():
    clock = Clock()
    dev = VirtualDevice(record_forces=True, max_force=4.0, clock=clock)
    dev.open()
    out = dev.set_force([0, 30.0, 40.0])
    np.testing.assert_allclose(out, [0, 2.4, 3.2])  # norm clamped, direction kept
    clock.t = 0.5
    dev.set_force([1.0, 0, 0])
    dev.close()
    t, f = dev.recorded_forces
    assert len(t) == 3 and f[-1].tolist() == [0, 0, 0]  # close sends zero first
    assert dev.state is DeviceState.CLOSED
    with pytest.raises(ConfigError):
        VirtualDevice().set_force([math.nan, 0, 0])


def test_velocity_filter_suppresses_encoder_quantisation():
    rng = np.random.default_rng(3)
    f = VelocityFilter(cutoff_hz=40.0)
    q = 50e-6  # one Falcon count at the grip
    raw, filt = [], []
    prev = None
    for i in range(2000):
        t = i * 0.001
        x = 0.02 * t + rng.uniform(-0.5, 0.5) * q  # 20 mm/s plus quantisation-sized noise
        p = np.array([q * round(x / q), 0, 0])
        v = f.update(p, t)
        if prev is not None and i > 200:
            raw.append((p[0] - prev) / 0.001)
            filt.append(v[0])
        prev = p[0]
    assert np.mean(filt) == pytest.approx(0.02, rel=0.1)
    assert np.std(filt) < 0.2 * np.std(raw)
    assert f.update(p, t)[0] == filt[-1]  # same timestamp: no new information, no spike


def test_forcelog_csv_round_trip_axis_and_plot(tmp_path):
    log = ForceLog()
    axis = np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    for i in range(300):
        t = i * 0.001
        mag = min(t, 0.15) * 20  # elastic ramp then a tearing plateau (Fig. 6 shape)
        log.record("right", t, mag * axis + (0, 0, 0.01))
        log.record("left", t + 0.0005, -0.9 * mag * axis)
    np.testing.assert_allclose(log.tear_axis(), axis, atol=5e-3)  # the small z bias tilts it slightly
    _, fr = log.along_axis("right")
    _, fl = log.along_axis("left")
    assert fr.max() == pytest.approx(3.0, rel=1e-3) and fl.min() == pytest.approx(-2.7, rel=1e-3)
    csv_path = log.to_csv(tmp_path / "forces.csv")
    back = ForceLog.from_csv(csv_path)
    for hand in ("left", "right"):
        t0, f0 = log.series(hand)
        t1, f1 = back.series(hand)
        np.testing.assert_array_equal(t0, t1)
        np.testing.assert_array_equal(f0, f1)
    png = log.plot(tmp_path / "fig6.png")
    data = open(png, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(ConfigError, match="force log"):
        ForceLog.from_csv(tmp_path / "bad.csv")


def test_servo_records_rendered_scene_forces():
    clock = Clock()
    dev = VirtualDevice(clock=clock)
    dev.open()
    log = ForceLog(("right",))
    loop = ServoLoop([dev], {"right": HandCoupling(k_position=100.0, k_velocity=0.0, force_scale=0.5, max_force_rate=1e9)}, clock=clock, force_log=log)
    for _ in range(10):
        loop.publish("right", (2.0, 0, 0), (0, 0, 0))
        loop.tick("right")
        clock.t += 0.001
    t, f = log.series("right")
    assert len(t) == 10
    np.testing.assert_allclose(f[-1], (2.0, 0, 0))  # scene frame: force_scale undone
    np.testing.assert_allclose(dev.force, (1.0, 0, 0))  # device frame: halved


def test_forcelog_keeps_every_sample_across_chunk_boundaries():
    log = ForceLog(("left",))
    n = 3 * 4096 + 17
    for i in range(n):
        log.record("left", i * 1e-3, (i, -i, 0.5 * i))
    t, f = log.series("left")
    assert len(t) == n
    np.testing.assert_array_equal(t, np.arange(n) * 1e-3)
    np.testing.assert_array_equal(f[:, 1], -np.arange(n))
    log.record("extra", 0.0, (1, 2, 3))  # a hand not declared up front is accepted
    assert log.hands == ["left", "extra"]
    log.clear()
    assert len(log.series("left")[0]) == 0
