"""The servo process (haptics/servo_process.py): a simulating process killed with SIGKILL leaves the
emulated Falcons at zero force within 10 ms; the shared-memory exchange round-trips; the servo
reports which unprivileged measures it got; bad device specs fail clearly in this process.

The devices' side is read from the servo's shared memory (what each emulated Falcon was last sent
and when it first got a zero command), on CLOCK_MONOTONIC, which every process shares."""
import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tearcloth.haptics import ConfigError
from tearcloth.haptics.live import falcon_coupling
from tearcloth.haptics.servo_process import _P_EFF, _P_ZERO, DeviceSpec, ServoProcess, _read, _Shared

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the servo process's peer check is tested on Linux")

# The simulating process: the square cloth held by two emulated Falcons in a servo process, the
# simulation on its own thread. The stall timeout is fixed at 0.5 s so that what zeroes the force
# within 10 ms can only be the servo noticing its peer is gone, not the stall watchdog.
SIMULATOR = r"""
import json, sys, time
from tearcloth.bench.servo import emulated_session
live, emus = emulated_session("cloth", servo="process", tear_stress=2e6, hold_s=0.05, pull_s=3.0, pull_distance=0.015,
                              servo_priority=None, stall_timeout_s=0.5)
live.start()
deadline = time.perf_counter() + 30.0
while time.perf_counter() < deadline and not all(any(e.efforts) for e in emus.values()):
    time.sleep(0.01)
print(json.dumps({"shm": live.servo_process.shm_name, "servo_pid": live.servo_process.pid, "steps": live.steps}), flush=True)
time.sleep(600)
"""


def _alive(pid):
    try:
        with open(f"/proc/{pid}/status") as fh:
            return "State:\tZ" not in fh.read()  # a zombie has exited
    except FileNotFoundError:
        return False


def test_killing_the_simulating_process_zeroes_the_devices_within_10_ms():
    sim = subprocess.Popen([sys.executable, "-c", SIMULATOR], stdout=subprocess.PIPE, text=True)
    shared = None
    servo_pid = None
    try:
        line = sim.stdout.readline()
        assert line, "the simulating process died before its session ran"
        info = json.loads(line)
        servo_pid = info["servo_pid"]
        shared = _Shared(2, info["shm"])
        # Force on both devices, as the emulators see it, just before the kill.
        before = [_read(p) for p in shared.prox]
        assert all(np.any(b[_P_EFF : _P_EFF + 3]) and math.isnan(b[_P_ZERO]) for b in before), before
        t_kill = time.perf_counter()
        os.kill(sim.pid, signal.SIGKILL)
        sim.wait(5.0)
        deadline = time.perf_counter() + 2.0
        while time.perf_counter() < deadline:
            blocks = [_read(p) for p in shared.prox]
            if all(not math.isnan(b[_P_ZERO]) for b in blocks) and not _alive(servo_pid):
                break
            time.sleep(0.005)
        for b in blocks:
            assert not np.any(b[_P_EFF : _P_EFF + 3]), "a device was left with a force"
            latency = b[_P_ZERO] - t_kill
            assert latency <= 0.010, f"zero force reached the device {latency * 1e3:.1f} ms after SIGKILL"
        assert not _alive(servo_pid), "the servo process outlived its simulating process"
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
        if servo_pid is not None and _alive(servo_pid):
            os.kill(servo_pid, signal.SIGKILL)
        if shared is not None:
            shared.close()


def _specs():
    return {h: DeviceSpec(".haptics.live:emulated_falcon", dict(serial=f"EMU-{h}", hand=h, direction=(1.0, 0.0, 0.0))) for h in ("left", "right")}


def test_exchange_round_trip_and_unprivileged_measures_reported():
    sp = ServoProcess(_specs(), stall_timeout_s=0.5, priority=None)
    try:
        infos = sp.open()
        assert set(infos) == {"left", "right"} and all(i["state"] == "ready" for i in infos.values())
        sp.start({h: falcon_coupling(0.08, k_position=2000.0, k_velocity=0.0, force_scale=0.1) for h in sp.hands})
        deadline = time.perf_counter() + 5.0
        while time.perf_counter() < deadline and not all(sp.proxy(h) for h in sp.hands):
            time.sleep(0.01)
        p = sp.proxy("left")
        assert p is not None and p.state.value == "ready"
        # A handle 1 cm from the proxy along scene +x: 2000 N/m * 0.01 m = 20 N in the scene.
        sp.publish("left", (0.0, 0.0, 0.0), p.position + np.array([0.01, 0.0, 0.0]))
        time.sleep(0.3)  # the rate limit (1000 N/s) takes 20 ms to reach it
        q = sp.proxy("left")
        assert q.seq > p.seq
        np.testing.assert_allclose(q.force, 2000.0 * (p.position + [0.01, 0, 0] - q.position), atol=0.5)
        assert any(sp.emulator("left").efforts)
        # what this process sees of the device is in the device's own frame, as for a local one
        c, q = sp.coupling("left"), sp.proxy("left")
        np.testing.assert_allclose(c.proxy(sp.device("left").position), q.position, atol=1e-3)
        assert sp.device("left").state.value == "ready" and np.linalg.norm(sp.device("left").force) > 0.5
        st = sp.stats()
        priv = st["privileges"]
        assert priv["process"] is True and priv["sched_fifo"] == {"left": None, "right": None}  # not asked
        for key in ("own_session", "autogroup", "affinity", "nice", "clock_nanosleep", "timer_slack_ns", "slice_ns", "gc"):
            assert key in priv, key
        assert st["per_hand"]["left"]["ticks"] > 100 and st["rate_hz"] > 0.0
    finally:
        sp.stop()
    # stop zeroed both devices; what they were left with stays readable after the shared memory is gone
    for h in ("left", "right"):
        assert sp.emulator(h).efforts == (0, 0, 0)
        assert sp.emulator(h).zero_since is not None
        assert sp.device(h).state.value == "closed"


def test_bad_device_specs_are_clear_errors():
    with pytest.raises(ConfigError, match="DeviceSpec"):
        ServoProcess({"left": object()})
    with pytest.raises(ConfigError, match="module:function"):
        ServoProcess({"left": DeviceSpec("no colon here")})
    with pytest.raises(ConfigError, match="at least one device"):
        ServoProcess({})
