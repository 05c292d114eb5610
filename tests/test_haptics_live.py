"""Live bimanual tearing (haptics/live.py): two emulated Falcons tear the square cloth and the force
log shows the paper's Fig. 6; the clamp holds; an unplugged device, a stalled simulation and a
stop button all end in zero force; the recorder sees the torn mesh; bad set-ups fail clearly.

Each of these runs twice: with the servo threads in this process ("thread") and with the servo
process of its own ("process", haptics/servo_process.py: the emulated Falcons live there and are
reached through RemoteEmulator).

Timing: the hands of the Fig. 6 test follow the *simulated* time (``pace="simulation"``), so the
cloth is pulled the same way on a fast or a loaded machine; the other tests use wall-time hands.
Wall-clock bounds are generous safety nets only; the servo's guarantees are checked on its own
clock (the force log's time stamps)."""
import math
import threading
import time

import numpy as np
import pytest

from tearcloth import examples
from tearcloth.cloth import Cloth
from tearcloth.haptics import (
    ConfigError,
    DeviceNotFoundError,
    DeviceState,
    FalconDevice,
    FalconEmulator,
    FirmwareError,
    HandCoupling,
    NotHomedError,
    VirtualDevice,
    Workspace,
)
from tearcloth.haptics.live import (
    FALCON_CENTRE_BUTTON,
    LiveSession,
    emulated_falcon,
    falcon_coupling,
    stall_timeout_rule,
)
from tearcloth.bench.servo import emulated_session, measure_live_servo
from tearcloth.materials import material

TEAR_STRESS = 2.0e6  # Pa: a quarter of cotton's, so the square tears within ~0.3 s of simulated time
WALL_CAP = 60.0  # s: safety cap for runs that stop on simulated time


SERVOS = pytest.mark.parametrize("servo", ["thread", "process"])


def square_session(**kw):
    kw.setdefault("tear_stress", TEAR_STRESS)
    # A servo that publishes no proxy for proxy_timeout_s (0.5 s by default) is a lost device. In CI
    # the 3.13 half runs beside the 4.2 half (four workers and their Blenders on two cores), and once
    # a servo process published nothing for 500 ms there: the session ended as 'device lost' halfway
    # through Fig. 6. These tests are about forces, tears and unplugged cables, not that rule.
    kw.setdefault("proxy_timeout_s", 5.0)
    kw.setdefault("hold_s", 0.05)
    kw.setdefault("pull_s", 0.5)
    kw.setdefault("pull_distance", 0.015)
    return emulated_session("cloth", **kw)


def no_live_threads():
    names = [t.name for t in threading.enumerate()]
    return not [n for n in names if n.startswith("tearcloth-servo") or n.startswith("tearcloth-live")]


def device_force_norms(live, hand):
    """|force sent to the device| at every servo tick, from the rendered log (scene frame)."""
    _, f = live.force_log.series(hand)
    return np.linalg.norm(f, axis=1) * live.coupling(hand).force_scale


def unplug(emu):
    """Unplug an emulated Falcon; returns when: an in-process emulator at once, one in the servo
    process reports when the command reached it (over a pipe, a few ms later)."""
    t = time.perf_counter()
    return emu.unplug() or t


def rel(a, b):
    return abs(a - b) / max(abs(a), abs(b))


# ---------------------------------------------------------------------------------------------
# The paper's Fig. 6 with two emulated Falcons
# ---------------------------------------------------------------------------------------------
@SERVOS
def test_two_emulated_falcons_tear_the_square_like_fig6(tmp_path, servo):
    live, emus = square_session(pace="simulation", pull_s=0.6, pull_distance=0.02, servo=servo)
    try:
        deadline = time.perf_counter() + WALL_CAP
        # Until 190 steps after the first tear: the drop, then 150 steps of propagation.
        while time.perf_counter() < deadline and (live.first_tear_step is None or live.steps < live.first_tear_step + 190):
            live.run_for(0.2, until_time=0.8)
            assert live.session.time < 0.8 - 1e-9, "no tear within 0.8 s of simulated time"
        assert live.error is None and not live.ended, live.end_reason
        stats = live.stats()
        mailbox = {h: live.servo.mailbox(h).latest for h in live.hands}
    finally:
        live.stop()
    assert live.steps >= live.first_tear_step + 190, "the wall-time cap ended the run early"
    assert stats["tears_started"] >= 1 and live.first_tear_step is not None
    # SCHED_FIFO for the servo threads where the OS grants it; either way it is reported.
    assert set(stats["servo_realtime"]) == {"left", "right"}
    assert all(v in (True, False) for v in stats["servo_realtime"].values())

    ph = live.phases(pull_start=0.05)
    k0, kp, kd = ph["first_tear_step"], ph["peak_step"], ph["drop_step"]
    peak, mean = ph["peak"], ph["mean_tension"]
    left, right = ph["per_hand"]["left"], ph["per_hand"]["right"]
    # Elastic rise: nothing before the pull, then a rise that reaches the peak at the first tear.
    for hand in (left, right):
        assert abs(hand["before_pull"]) < 0.05 * peak
    mid = (ph["pull_step"] + k0) // 2
    assert mean[ph["pull_step"] + 5] < mean[mid] < mean[k0 - 5]
    assert mean[k0 - 5] > 0.5 * peak
    # The hands alike in the rise (the mean of steps k0-15..k0-5, where the force climbs fastest):
    # within 10 % in quiet runs; 19.6 % once in a fresh-clone CI run (18.7 / 23.2 N, process servo,
    # the suite's two workers on both cores), where one hand's late exchange rendered an older,
    # lower sample of the climb. A hand coupled wrongly (its stiffness or axis off) differs by far
    # more than 25 %; a starved servo, by its lag times the climb's slope.
    assert rel(left["elastic"], right["elastic"]) <= 0.25
    # The peak comes with the first tear (tears_started turning 1), and nothing before it is higher.
    # Quiet runs: first tear at step 265-267, peak 2-6 steps later (also beside two CPU hogs: first
    # tear 266-270, peak 1-4 later, both servos). Under the CI's load (the suite's two workers, the
    # sanitizer build and the other halves' set-up on two cores) the process servo's late exchange
    # can start a short tear early: fresh-clone CI runs saw first tear 236, peak 260, and first tear
    # 238, peak 276 (the main tear's peak at the quiet runs' step). The peak must still follow
    # within 45 steps, and the drop within 40 of the peak (below).
    assert -10 <= kp - k0 <= 45, (k0, kp)
    assert mean[ph["pull_step"] : kp].max() <= peak
    # The hands' own peaks: within 1 % in 3 quiet runs and in 5 runs beside two CPU hogs;
    # 11.4 % once in a fresh-clone CI run (61.3 / 54.3 N, thread servo, both cores busy with the
    # suite's two workers and the sanitizer build), where one hand's servo thread rendered the peak
    # late. The peak is one smoothed sample of the force a device rendered, so a starved servo moves
    # it; a hand coupled wrongly moves it by far more than 15 %.
    assert rel(left["peak"], right["peak"]) <= 0.15
    # Then the force drops and the tear propagates at a fraction of the peak, hands alike.
    assert kd is not None and kd - kp <= 40
    start, stop = ph["propagation_range"]
    assert stop - start >= 100
    assert 0.02 * peak < ph["propagation"] < 0.5 * peak
    # The hands alike while the tear runs (their mean over 100+ steps): 12.7 % once in a fresh-clone
    # CI run (13.0 / 14.9 N, process servo) while other test runs shared its two cores, the same
    # starved-servo lag as the rise's and the peak's above; a hand coupled wrongly differs by far more.
    assert rel(left["propagation"], right["propagation"]) <= 0.20
    # The tear force itself (simulation side) tells the same story.
    tear = live.phases("tear", pull_start=0.05)
    assert abs(tear["first_tear_step"] - tear["peak_step"]) <= 20
    assert tear["propagation"] < 0.5 * tear["peak"]
    # The devices never got more than their clamp.
    for hand in live.hands:
        assert device_force_norms(live, hand).max() <= live.device(hand).max_force + 1e-9
    # The linearisation published last is a restoring stiffness inside the device's budget.
    for hand, sample in mailbox.items():
        k = sample.stiffness
        c, dev = live.coupling(hand), live.device(hand)
        np.testing.assert_allclose(k, k.T, atol=1e-9)
        assert np.linalg.eigvalsh(k).max() <= 1e-9
        assert np.linalg.norm(k) <= dev.max_stiffness / (c.force_scale * c.scale) + 1e-6
    # Log files: CSV + a Fig. 6 plot.
    csv_path, png_path = live.save_force_log(tmp_path / "forces.csv", tmp_path / "forces.png")
    with open(csv_path) as fh:
        assert fh.readline().strip() == "time_s,hand,fx_N,fy_N,fz_N"
    with open(png_path, "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    assert no_live_threads()
    for emu in emus.values():
        assert emu.efforts == (0, 0, 0)  # stop() left every motor at zero effort


@SERVOS
def test_device_force_never_exceeds_a_binding_clamp(servo):
    live, _ = square_session(max_force=1.5, servo=servo)  # far below what the pull asks for
    try:
        live.run_for(1.5)
    finally:
        live.stop()
    for hand in live.hands:
        norms = device_force_norms(live, hand)
        assert len(norms) > 500
        assert norms.max() <= 1.5 + 1e-9
        assert norms.max() >= 1.5 - 1e-6  # the clamp was reached: it was really tested


# ---------------------------------------------------------------------------------------------
# Ending: device loss, simulation stall, stop button
# ---------------------------------------------------------------------------------------------
@SERVOS
def test_unplugged_falcon_zeroes_its_force_and_ends_the_session(servo):
    live, emus = square_session(servo=servo)
    live.run_for(0.5)
    assert device_force_norms(live, "right")[-50:].max() > 0.05  # the hand feels the cloth
    t_unplug = unplug(emus["right"])
    live.run_for(5.0)  # returns as soon as the session notices; no exception escapes
    assert live.ended and live.error is None
    assert live.lost_hands == ["right"] and "right" in live.end_reason
    t, f = live.force_log.series("right")
    after = t > t_unplug
    assert after.any() and not np.abs(f[after]).any()  # every tick after the unplug renders zero
    assert not np.abs(f[-1]).any()  # the LOST tick, the right hand's last one, rendered zero
    latency = t[after][0] - t_unplug
    assert latency < 0.1, f"zero force {latency * 1e3:.1f} ms after the unplug"  # 1 servo period nominal
    # The other hand was stopped too, with zero force sent, and every thread is gone.
    assert emus["left"].efforts == (0, 0, 0)
    assert all(live.device(h).state is DeviceState.CLOSED for h in live.hands)
    assert no_live_threads()


@SERVOS
def test_unplugged_falcon_can_leave_the_other_hand_running(servo):
    live, emus = square_session(on_device_lost="continue", servo=servo)
    try:
        live.run_for(0.4)
        t_unplug = unplug(emus["right"])
        live.run_for(0.4)
        assert not live.ended and live.lost_hands == ["right"]
        t, f = live.force_log.series("left")
        assert np.abs(f[t > t_unplug + 0.1]).max() > 0.0  # the left hand still feels the cloth
        t, f = live.force_log.series("right")
        assert not np.abs(f[t > t_unplug]).any()
    finally:
        live.stop()
    assert live.end_reason == "stopped" and no_live_threads()


def test_a_servo_thread_that_stops_answering_is_a_lost_device():
    # The rule these tests otherwise relax (square_session's proxy_timeout_s): a servo thread whose
    # device I/O hangs publishes no proxy; after proxy_timeout_s the hand counts as lost and the
    # session ends with zero force on the other hand. The hung thread cannot be joined while its I/O
    # blocks: that is said in shutdown_errors, and the thread ends once the I/O returns.
    # 1 s, not the default 0.5 s: under CI load an answering servo once went 500 ms without a proxy
    live, emus = square_session(proxy_timeout_s=1.0)
    hang, release = threading.Event(), threading.Event()
    dev = live.device("right")
    poll = dev.poll

    def hanging_poll():
        if hang.is_set():
            release.wait(30.0)
        return poll()

    dev.poll = hanging_poll
    try:
        live.run_for(0.4)
        assert not live.ended, live.end_reason
        assert device_force_norms(live, "left")[-50:].max() > 0.0  # the hands feel the cloth
        hang.set()
        t_hang = time.perf_counter()
        live.run_for(10.0)  # returns once the session has noticed
        noticed = time.perf_counter() - t_hang
        assert live.ended and live.error is None
        assert live.lost_hands == ["right"], live.lost_hands
        assert "device lost on the right hand" in live.end_reason and "has not answered" in live.end_reason, live.end_reason
        # within the timeout plus a step or two (and the servo stop's 1 s join of the hung thread)
        assert 1.0 <= noticed < 6.0, noticed
        assert emus["left"].efforts == (0, 0, 0)  # the answering hand was sent zero force
        assert any("right" in str(e) and "did not stop" in str(e) for e in live.shutdown_errors), live.shutdown_errors
    finally:
        release.set()
        live.stop()
    deadline = time.perf_counter() + 10.0
    while not no_live_threads() and time.perf_counter() < deadline:
        time.sleep(0.05)
    assert no_live_threads()


@SERVOS
def test_simulation_stall_zeroes_the_force_within_the_stall_timeout(servo):
    live, _ = square_session(servo=servo)
    try:
        live.run_for(0.6)
        timeout = live.servo.stall_timeout_s
        period = live.servo.period_s
        assert 0.010 <= live.stall_timeout_s <= 0.100
        stamps = {h: live.servo.mailbox(h).latest.stamp for h in live.hands}
        time.sleep(timeout + 0.1)  # the caller stops stepping
        for hand, stamp in stamps.items():
            # at least 20 servo ticks past the guarantee: a loaded machine may give the servo only
            # part of a 1 kHz clock (18 ticks in 0.2 s once under CI), so wait for them (up to 5 s)
            # rather than for a fixed time; every one of them must be zero force
            deadline = time.perf_counter() + 5.0
            while True:
                t, f = live.force_log.series(hand)
                if (t >= stamp + timeout - period).sum() >= 20 or time.perf_counter() > deadline:
                    break
                time.sleep(0.02)
            # force was on while the caller stepped (a window of the whole pull, not only the last
            # 50 ms: on a loaded machine one late step may already have stalled the servo there)
            assert np.abs(f[(t > stamp - 0.4) & (t < stamp)]).max() > 0.0
            late = t >= stamp + timeout - period  # the servo clock's own guarantee
            assert late.sum() >= 20 and not np.abs(f[late]).any()
        resumed = time.perf_counter()
        live.run_for(0.3)  # stepping again brings the force back
        for hand in live.hands:
            t, f = live.force_log.series(hand)
            assert np.abs(f[t > resumed + 0.05]).max() > 0.0
        assert not live.ended
    finally:
        live.stop()


def test_stall_timeout_rule():
    assert stall_timeout_rule([0.002] * 200) == pytest.approx(0.010)  # fast simulation: the floor
    assert stall_timeout_rule([0.020] * 200) == pytest.approx(0.060)  # 3 periods
    assert stall_timeout_rule([0.010] * 197 + [0.030] * 3) == pytest.approx(0.090)  # p99, not median
    assert stall_timeout_rule([0.200] * 10) == pytest.approx(0.100)  # the ceiling
    assert stall_timeout_rule([0.020] * 50, factor=2.0, minimum=0.005, maximum=1.0) == pytest.approx(0.040)


@SERVOS
def test_stop_button_ends_a_threaded_session(servo):
    live, emus = square_session(stop_buttons=FALCON_CENTRE_BUTTON, servo=servo)
    emus["left"].buttons = FALCON_CENTRE_BUTTON  # held while grasping: must not stop the session
    live.start()
    try:
        time.sleep(0.4)
        assert not live.ended and live.steps > 0
        emus["left"].buttons = 0  # released...
        time.sleep(0.3)
        emus["left"].buttons = FALCON_CENTRE_BUTTON  # ...and pressed: stop
        assert live.wait(10.0)
    finally:
        live.stop()
    assert live.ended and "stop button" in live.end_reason and "left" in live.end_reason
    assert live.error is None
    for hand, emu in emus.items():
        assert emu.efforts == (0, 0, 0)
        assert live.device(hand).state is DeviceState.CLOSED
    assert no_live_threads()
    live.stop()  # idempotent


# ---------------------------------------------------------------------------------------------
# Recorder hook
# ---------------------------------------------------------------------------------------------
def test_recorder_sees_the_vertex_count_grow_after_the_tear():
    mesh = examples.square_cloth()
    cloth = Cloth(mesh.vertices, mesh.triangles, material("cotton", tear_stress=TEAR_STRESS), uv=mesh.loop_uv(), groups=mesh.groups)
    cloth.set_tearing(True)
    n0 = cloth.num_vertices
    frames = []
    holder = {}

    def script(sign):
        def position(_t):  # follows the simulated time: 5 cm/s per hand after 0.02 s
            t = holder["live"].session.time if "live" in holder else 0.0
            return (sign * 0.05 * max(t - 0.02, 0.0), 0.0, 0.0)

        return position

    ws = Workspace((0.0, 0.0, 0.0), 0.2)
    coupling = HandCoupling(k_position=2000.0, k_velocity=0.0, force_scale=0.05)
    hands = {
        "left": ("handle_left", VirtualDevice("L", script=script(-1.0), workspace=ws), coupling),
        "right": ("handle_right", VirtualDevice("R", script=script(1.0), workspace=ws), coupling),
    }
    live = LiveSession(cloth, hands, recorder=lambda *frame: frames.append(frame), record_every=5)
    holder["live"] = live
    try:
        deadline = time.perf_counter() + WALL_CAP
        while time.perf_counter() < deadline and (live.first_tear_step is None or live.steps < live.first_tear_step + 40):
            live.run_for(0.2)
        assert live.first_tear_step is not None
    finally:
        live.stop()
    assert len(frames) == math.ceil(live.steps / 5)
    times = [f[0] for f in frames]
    assert all(b > a for a, b in zip(times, times[1:]))
    for t, positions, triangles, corner_uv, velocities in frames:
        n, m = len(positions), len(triangles)
        assert positions.shape == (n, 3) and velocities.shape == (n, 3)
        assert triangles.shape == (m, 3) and corner_uv.shape == (m, 3, 2)
        assert triangles.max() < n
    assert len(frames[0][1]) == n0
    assert len(frames[-1][1]) > n0  # the tear added vertices
    frames[-1][1][:] = 0.0  # copies: the recorder may keep or change them freely
    assert np.abs(cloth.positions).max() > 0.1


# ---------------------------------------------------------------------------------------------
# Clear errors
# ---------------------------------------------------------------------------------------------
def small_cloth():
    mesh = examples.square_cloth(target_triangles=200)
    return Cloth(mesh.vertices, mesh.triangles, material("cotton"), groups=mesh.groups)


def ready_falcon(serial, hand, **kw):
    emu = FalconEmulator(serial, firmware_loaded=True, homed=True, **kw)
    return FalconDevice(transport=emu, hand=hand), emu


def test_missing_group_unknown_handle_and_no_devices_are_clear_errors():
    cloth = small_cloth()
    dev, _ = ready_falcon("A", "left")
    with pytest.raises(ConfigError, match=r"no vertex group 'sleeve'.*handle_left"):
        LiveSession(cloth, {"left": ("sleeve", dev, None)})
    with pytest.raises(ConfigError, match="no handle 42"):
        LiveSession(cloth, {"left": (42, dev, None)})
    with pytest.raises(ConfigError, match="no devices"):
        LiveSession(cloth, {})
    with pytest.raises(ConfigError, match="same device"):
        LiveSession(cloth, {"left": ("handle_left", dev, None), "right": ("handle_right", dev, None)})
    with pytest.raises(ConfigError, match="HapticDevice"):
        LiveSession(cloth, {"left": ("handle_left", object(), None)})
    with pytest.raises(ConfigError, match="on_device_lost"):
        LiveSession(cloth, {"left": ("handle_left", dev, None)}, on_device_lost="ignore")
    assert dev.state is DeviceState.ABSENT  # nothing was opened


def test_devices_that_cannot_serve_are_clear_errors_and_nothing_stays_open():
    cases = [
        (dict(firmware_loaded=False, homed=False), FirmwareError, "firmware"),
        (dict(firmware_loaded=True, homed=False), NotHomedError, "not homed"),
    ]
    for emu_kw, error, words in cases:
        good, good_emu = ready_falcon("GOOD", "left")
        bad = FalconDevice(transport=FalconEmulator("BAD", **emu_kw), hand="right")
        live = LiveSession(small_cloth(), {"left": ("handle_left", good, None), "right": ("handle_right", bad, None)})
        with pytest.raises(error, match=f"hand 'right'.*{words}"):
            live.open()
        assert good.state is DeviceState.CLOSED and good_emu.efforts == (0, 0, 0)
        assert bad.state is DeviceState.CLOSED
        assert no_live_threads()

    def nothing_plugged(serial):
        raise DeviceNotFoundError(f"no Novint Falcon with serial {serial!r}")

    absent = FalconDevice("NOPE", transport_factory=nothing_plugged, hand="left")
    live = LiveSession(small_cloth(), {"left": ("handle_left", absent, None)})
    with pytest.raises(DeviceNotFoundError, match="hand 'left'.*NOPE"):
        live.open()
    # A coupling stiffer than the Falcon renders is refused before any thread starts.
    dev, _ = ready_falcon("STIFF", "left")
    live = LiveSession(small_cloth(), {"left": ("handle_left", dev, falcon_coupling(0.08, k_position=50000.0))})
    with pytest.raises(ConfigError, match="3000 N/m"):
        live.open()
    assert dev.state is DeviceState.CLOSED and no_live_threads()


def test_scripted_emulated_falcon_pulls_along_its_direction():
    dev, emu = emulated_falcon("S", "right", (1.0, 0.0, 0.0), distance=0.02, hold_s=0.05, pull_s=0.2)
    dev.open()
    try:
        for _ in range(400):  # 0.4 s of emulated time, no force
            dev.poll()
        np.testing.assert_allclose(emu.true_position, (0.02, 0.0, 0.13), atol=2e-3)
        assert dev.state is DeviceState.READY
    finally:
        dev.close()


# ---------------------------------------------------------------------------------------------
# Bench probe
# ---------------------------------------------------------------------------------------------
def test_measure_live_servo_reports_what_the_bench_needs():
    out = measure_live_servo(1.0, "cloth")
    assert {"rate_hz", "p50_ms", "p99_ms", "sim_steps_per_s", "stall_timeout_s", "per_hand"} <= set(out)
    assert set(out["per_hand"]) == {"left", "right"}
    assert out["scenario"] == "cloth" and out["collision"] is False
    # Generous: a loaded machine may be slow, but not ten times slow.
    assert out["rate_hz"] > 100.0 and out["sim_steps_per_s"] > 5.0
    assert no_live_threads()


@pytest.mark.parametrize("cpus, thread", [(2, False), (3, False), (8, True)])
def test_a_live_session_leaves_the_collision_worker_a_core_only_when_there_is_one(monkeypatch, cpus, thread):
    # the detector's swept stage runs on a worker thread when the process has a second CPU; a live
    # session also has a simulation thread and two servo threads (or a servo process), so the worker
    # is kept only from 4 CPUs on: a servo tick must not wait behind the collision
    from tearcloth.collision import detector as det_mod

    monkeypatch.setattr(det_mod, "usable_cpus", lambda: cpus)
    live, _ = emulated_session("cloth", collision=True)
    try:
        assert live.session.detector.swept_thread is thread
    finally:
        live.stop()
