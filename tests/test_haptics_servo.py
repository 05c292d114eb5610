"""Servo loop and coupling (eq. 5): sign convention, clamp, rate limit, watchdog in emulated time,
linearisation, device loss, threads (start/stop, LOST ends one hand only) and measure_servo."""
import math
import sys
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tearcloth.haptics import (
    ConfigError,
    DeviceState,
    FalconDevice,
    FalconEmulator,
    ForceLog,
    HandCoupling,
    HapticError,
    ServoLoop,
    VirtualDevice,
    Workspace,
)
from tearcloth.bench.servo import measure_servo
from tearcloth.haptics.falcon_emulator import spring_hand


class Clock:
    """Emulated time, advanced by the test."""

    def __init__(self, t=0.0):
        self.t = t

    def __call__(self):
        return self.t


def virtual(clock, **kw):
    kw.setdefault("workspace", Workspace((0.0, 0.0, 0.0), 0.1))
    dev = VirtualDevice(clock=clock, record_forces=True, **kw)
    dev.open()
    return dev


def loop_for(dev, clock, coupling=None, **kw):
    return ServoLoop({"right": dev}, {"right": coupling or HandCoupling(k_position=300.0, k_velocity=0.0, max_force_rate=1e9)}, clock=clock, **kw)


def run_ticks(loop, clock, n, hand="right", publish=None):
    out = []
    for _ in range(n):
        if publish:
            publish(clock.t)
        out.append(loop.tick(hand))
        clock.t += loop.period_s
    return out


def test_spring_pulls_the_hand_toward_the_handle():
    clock = Clock()
    dev = virtual(clock)
    dev.set_position((0.01, 0.0, 0.0))
    loop = loop_for(dev, clock)
    # Handle 1 cm further along +x than the proxy, no tear force: 300 N/m * 0.01 m = 3 N toward +x.
    loop.publish("right", (0, 0, 0), (0.02, 0.0, 0.0))
    p = loop.tick("right")
    np.testing.assert_allclose(p.position, (0.01, 0, 0))
    np.testing.assert_allclose(dev.force, (3.0, 0, 0), atol=1e-9)
    np.testing.assert_allclose(p.force, (3.0, 0, 0), atol=1e-9)
    # The cloth pulling the handle toward -y (F_tear) is felt as such.
    clock.t += 0.001
    loop.publish("right", (0, -1.5, 0), (0.01, 0.0, 0.0))
    loop.tick("right")
    np.testing.assert_allclose(dev.force, (0, -1.5, 0), atol=1e-9)


def test_damping_opposes_velocity():
    clock = Clock()
    dev = virtual(clock)
    loop = loop_for(dev, clock, HandCoupling(k_position=0.0, k_velocity=5.0, max_force_rate=1e9))
    for i in range(200):  # move at +0.1 m/s along z
        dev.set_position((0, 0, 0.1 * clock.t))
        loop.publish("right", (0, 0, 0), (0, 0, 0))
        loop.tick("right")
        clock.t += 0.001
    assert dev.force[2] == pytest.approx(-0.5, rel=0.02)


def test_affine_proxy_map_and_force_back_to_device_frame():
    clock = Clock()
    rot = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])  # 90° about z, device -> scene
    ws = Workspace((0.0, 0.0, 0.13), 0.04)
    c = HandCoupling.fit(ws, scene_centre=(1.0, 2.0, 3.0), scene_radius=0.2, rotation=rot, k_position=100.0, k_velocity=0.0, max_force_rate=1e9, force_scale=0.5)
    assert c.scale == pytest.approx(5.0)
    np.testing.assert_allclose(c.proxy((0, 0, 0.13)), (1.0, 2.0, 3.0))
    np.testing.assert_allclose(c.proxy((0.01, 0, 0.13)), (1.0, 2.05, 3.0))
    dev = virtual(clock, workspace=ws)
    dev.set_position((0.0, 0.0, 0.13))
    loop = ServoLoop({"left": dev}, {"left": c}, clock=clock, check_stiffness=False)
    loop.publish("left", (0, 0, 0), (1.0, 2.01, 3.0))  # handle 1 cm along scene +y
    loop.tick("left")
    # Scene force 1 N along +y -> device frame +x (Rᵀ), times force_scale 0.5.
    np.testing.assert_allclose(dev.force, (0.5, 0, 0), atol=1e-9)
    assert c.felt_stiffness == pytest.approx(0.5 * 100 * 5)


def test_coupling_stiffer_than_the_device_is_refused():
    emu = FalconEmulator(firmware_loaded=True, homed=True)
    dev = FalconDevice(transport=emu)
    with pytest.raises(ConfigError, match="3000 N/m"):
        ServoLoop([dev], {"right": HandCoupling(k_position=5000.0)})
    with pytest.raises(ConfigError, match="rotation"):
        HandCoupling(rotation=[[1, 0, 0], [0, 1, 0], [0, 0, -1]])
    with pytest.raises(ConfigError, match="unknown hands"):
        ServoLoop([dev], {"left": HandCoupling()})


@settings(max_examples=150, deadline=None)
@given(
    st.tuples(*[st.floats(-1e5, 1e5)] * 3),
    st.tuples(*[st.floats(-10.0, 10.0)] * 3),
    st.floats(0.1, 20.0),
    st.floats(1.0, 1e5),
)
def test_device_force_never_exceeds_max_force_nor_the_rate_limit(f_tear, handle, max_force, rate):
    clock = Clock()
    dev = virtual(clock, max_force=max_force)
    loop = loop_for(dev, clock, HandCoupling(k_position=300.0, k_velocity=1.0, max_force_rate=rate))
    prev = np.zeros(3)
    for i in range(5):
        loop.publish("right", f_tear, handle)
        loop.tick("right")
        f = dev.force
        assert np.linalg.norm(f) <= max_force * (1 + 1e-12)
        assert np.linalg.norm(f - prev) <= rate * loop.period_s * (1 + 1e-9) + 1e-12
        prev = f
        clock.t += 0.001


def test_rate_limit_ramps_a_force_step():
    clock = Clock()
    dev = virtual(clock)
    loop = loop_for(dev, clock, HandCoupling(k_position=0.0, k_velocity=0.0, max_force_rate=1000.0))
    seen = []
    for _ in range(8):
        loop.publish("right", (5.0, 0, 0), (0, 0, 0))
        loop.tick("right")
        seen.append(dev.force[0])
        clock.t += 0.001
    np.testing.assert_allclose(seen, [1.0, 2.0, 3.0, 4.0, 5.0, 5.0, 5.0, 5.0], atol=1e-9)


def test_watchdog_zeroes_force_within_10_ms_of_the_last_update():
    clock = Clock()
    dev = virtual(clock)
    loop = loop_for(dev, clock, stall_timeout_s=0.010)
    for _ in range(5):
        loop.publish("right", (2.0, 0, 0), (0, 0, 0))
        loop.tick("right")
        clock.t += 0.001
    # Last update between two ticks (ticks at whole ms, update at 4.3 ms), so no tick falls
    # exactly on the deadline and the test does not depend on float rounding.
    clock.t -= 0.0007
    last_update = clock.t
    loop.publish("right", (2.0, 0, 0), (0, 0, 0))
    clock.t += 0.0007
    ticks = []
    for _ in range(20):
        loop.tick("right")
        ticks.append((clock.t - last_update, dev.force[0]))
        clock.t += 0.001
    assert ticks[4][1] == pytest.approx(2.0)  # 4.7 ms after the update: still rendering
    # The force in effect 10 ms after the update is the one set by the last tick before then.
    in_effect = [f for age, f in ticks if age <= 0.010][-1]
    assert in_effect == 0.0
    assert all(f == 0.0 for age, f in ticks if age >= 0.010)
    assert loop.stats("right")["watchdog_trips"] == 1
    # The simulation comes back: the force returns, rate-limited from zero (no jolt).
    loop.coupling("right").max_force_rate = 500.0
    loop.publish("right", (2.0, 0, 0), (0, 0, 0))
    loop.tick("right")
    assert dev.force[0] == pytest.approx(0.5)


def test_watchdog_on_the_wire_with_an_emulated_falcon():
    emu = FalconEmulator(firmware_loaded=True, homed=True, hand=spring_hand((0, 0, 0.13), 300, 5))
    dev = FalconDevice(transport=emu, clock=lambda: emu.time)
    dev.open()
    loop = ServoLoop([dev], {"right": HandCoupling(k_position=0.0, k_velocity=0.0)}, clock=lambda: emu.time)
    for _ in range(50):
        loop.publish("right", (0, 0, 2.0), loop.proxy("right").position if loop.proxy("right") else (0, 0, 0.13))
        loop.tick("right")
    last_update = emu.time
    for _ in range(30):
        loop.tick("right")
    sent = [(t, e) for t, e, _ in emu.commands if t >= last_update]
    assert any(e != (0, 0, 0) for t, e in sent if t < last_update + 0.005)
    late = [e for t, e in sent if t >= last_update + 0.010 - 1e-9]
    assert late and all(e == (0, 0, 0) for e in late)


def test_linearised_force_between_simulation_updates():
    clock = Clock()
    dev = virtual(clock)
    loop = loop_for(dev, clock, HandCoupling(k_position=0.0, k_velocity=0.0, max_force_rate=1e9))
    k = -200.0 * np.eye(3)
    loop.publish("right", (9.0, 9.0, 9.0), (0, 0, 0), f0=(1.0, 0, 0), stiffness=k, x0=(0, 0, 0))
    loop.tick("right")
    np.testing.assert_allclose(dev.force, (1.0, 0, 0), atol=1e-9)  # f0 replaces F_tear
    dev.set_position((0.002, 0, 0))  # no new simulation sample: K is felt at servo rate
    clock.t += 0.001
    loop.tick("right")
    np.testing.assert_allclose(dev.force, (1.0 - 0.4, 0, 0), atol=1e-9)
    with pytest.raises(ConfigError, match="all of f0"):
        loop.publish("right", (0, 0, 0), (0, 0, 0), f0=(1, 0, 0))


def test_linearised_stiffness_is_limited_to_what_the_device_renders():
    emu = FalconEmulator(firmware_loaded=True, homed=True, hand=spring_hand((0, 0, 0.13), 300, 5))
    dev = FalconDevice(transport=emu, clock=lambda: emu.time)
    dev.open()
    c = HandCoupling(k_position=1000.0, k_velocity=0.0, max_force_rate=1e9)
    loop = ServoLoop([dev], {"right": c}, clock=lambda: emu.time)
    loop.publish("right", (0, 0, 0), (0, 0, 0.13), f0=(0, 0, 0), stiffness=-1e5 * np.eye(3), x0=(0, 0, 0.13))
    loop.tick("right")
    k = loop._hands["right"].k_lin
    assert np.linalg.norm(k) == pytest.approx(3000.0 - 1000.0)


def pulling():
    """A virtual device whose proxy is pulled 1 m away: after one tick it feels a force."""
    clock = Clock()
    dev = virtual(clock)
    loop = loop_for(dev, clock)
    loop.publish("right", (1.0, 0, 0), (0, 0, 0))
    loop.tick("right")
    assert dev.force[0] > 0
    return dev, loop


def test_lost_device_zeroes_force_and_ends_its_tick_loop():
    dev, loop = pulling()
    dev.unplug()
    p = loop.tick("right")
    assert p.state is DeviceState.LOST
    assert dev.force.tolist() == [0, 0, 0] and p.force.tolist() == [0, 0, 0]
    assert loop._hands["right"].alive is False


def test_a_cable_pulled_during_a_tick_logs_its_zero_force_after_the_pull():
    # The race CI met once: the tick takes its stamp, the cable is pulled (another thread), then
    # the tick's poll sees the loss. Its zero-force entry must not be dated before the pull.
    clock = Clock(1.0)
    dev = virtual(clock)
    log = ForceLog()
    loop = loop_for(dev, clock, force_log=log)
    loop.publish("right", (1.0, 0, 0), (0, 0, 0))
    loop.tick("right")
    t_stamp = clock.t = 1.001
    real_poll = dev.poll

    def poll_after_the_pull():
        clock.t = t_pull = 1.0013  # pulled 0.3 ms into the tick
        dev.unplug()
        dev.poll = real_poll
        real_poll()
        clock.t = t_pull + 1e-5  # the poll's USB error takes a little time too
        return None

    dev.poll = poll_after_the_pull
    p = loop.tick("right", t_stamp)
    assert p.state is DeviceState.LOST and loop._hands["right"].alive is False
    t, f = log.series("right")
    assert t[-1] > 1.0013 and not np.abs(f[-1]).any()
    assert np.all(np.diff(t) > 0)


def test_threads_one_hand_lost_other_keeps_running_and_stop_zeroes():
    emu_l = FalconEmulator("L", firmware_loaded=True, homed=True, hand=spring_hand((0, 0, 0.13), 300, 5))
    emu_r = FalconEmulator("R", firmware_loaded=True, homed=True, hand=spring_hand((0, 0, 0.13), 300, 5), unplug_at=0.15)
    left, right = FalconDevice(transport=emu_l, hand="left"), FalconDevice(transport=emu_r, hand="right")
    left.open()
    right.open()
    log = ForceLog()
    loop = ServoLoop([left, right], force_log=log, stall_timeout_s=0.5)
    before = sys.getswitchinterval()
    loop.start()
    try:
        assert sys.getswitchinterval() <= 0.0005 + 1e-12
        t_end = time.perf_counter() + 0.6
        while time.perf_counter() < t_end:
            for hand in ("left", "right"):
                p = loop.proxy(hand)
                if p is not None:
                    loop.publish(hand, (0, 0, 1.0), p.position)
            time.sleep(0.002)
        assert loop.stats("right")["state"] == "lost"
        assert loop._hands["right"].thread is not None and not loop._hands["right"].thread.is_alive()
        assert loop._hands["left"].thread.is_alive()
        assert emu_l.efforts != (0, 0, 0)  # the other hand still feels the cloth
    finally:
        loop.stop()
    assert sys.getswitchinterval() == before
    assert not [t for t in threading.enumerate() if t.name.startswith("tearcloth-servo")]
    assert right.state is DeviceState.LOST and right.force.tolist() == [0, 0, 0]
    assert emu_l.efforts == (0, 0, 0)  # stop() flushed a zero force to the device
    t, f = log.series("left")
    assert len(t) > 100 and np.max(f[:, 2]) > 0.5


def test_stop_without_threads_zeroes_forces():
    dev, loop = pulling()
    loop.stop()
    assert dev.force.tolist() == [0, 0, 0]


def test_start_refuses_a_device_that_is_not_open():
    dev = VirtualDevice()
    with pytest.raises(HapticError, match="not open"):
        ServoLoop([dev]).start()


def test_measure_servo_with_two_emulated_falcons():
    devices = {}
    for hand in ("left", "right"):
        emu = FalconEmulator(hand, firmware_loaded=True, homed=True, hand=spring_hand((0, 0, 0.13), 300, 5))
        devices[hand] = FalconDevice(transport=emu, hand=hand)

    def simulation(loop):  # stands in for the simulation on the calling thread
        end = time.perf_counter() + 0.4
        while time.perf_counter() < end:
            for hand in loop.hands:
                p = loop.proxy(hand)
                if p is not None:
                    loop.publish(hand, (0.2, 0, 0), p.position)
            time.sleep(0.004)

    stats = measure_servo(0.4, devices, while_running=simulation)
    assert set(stats) >= {"rate_hz", "p50_ms", "p99_ms", "per_hand"}
    assert set(stats["per_hand"]) == {"left", "right"}
    # Generous bounds: a loaded CI machine may be slow, but not 10x slow.
    assert stats["rate_hz"] > 100.0
    assert 0.0 < stats["p50_ms"] < 10.0
    for dev in devices.values():
        assert dev.state is DeviceState.CLOSED  # measure_servo opened them, so it closed them


def test_simulation_mailbox_validates_in_the_writer_thread():
    clock = Clock()
    loop = loop_for(virtual(clock), clock)
    with pytest.raises(ConfigError, match="f_tear"):
        loop.publish("right", (math.nan, 0, 0), (0, 0, 0))
    with pytest.raises(ConfigError, match="stiffness"):
        loop.publish("right", (0, 0, 0), (0, 0, 0), f0=(0, 0, 0), stiffness=np.eye(2), x0=(0, 0, 0))
    with pytest.raises(ConfigError, match="unknown hand"):
        loop.publish("left", (0, 0, 0), (0, 0, 0))
