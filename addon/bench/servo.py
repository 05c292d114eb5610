"""Servo timing for ``tearcloth bench``: the 1 kHz loop measured over emulated Falcons, alone or
while one of the paper's scenes is simulated flat out on the calling thread.

This file owns ``measure_servo`` (run a ``ServoLoop`` over given devices for a while, return its
timing), ``measure_loaded_servo`` (what the bench reports as ``servo.loaded.*``: the servo while
the machine is as busy as an artist's Blender makes it), ``emulated_session`` (the square cloth, the banknote or the T-shirt from
``tearcloth.examples`` grasped by two emulated Falcons whose scripted hands pull apart: a
``LiveSession`` ready to run) and ``measure_live_servo`` (what the bench reports as
``servo.*``). The emulator and its scripted hands are a user feature and stay in
``tearcloth.haptics``; what lives here needs the example geometry, so it is dev-only (not in the
extension zip). SI units; times reported in ms and Hz.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Callable, Dict, Mapping, Optional, Tuple

import numpy as np

from .. import examples
from ..cloth import Cloth
from ..haptics.device import ConfigError
from ..haptics.falcon import FALCON_MAX_FORCE
from ..haptics.falcon_emulator import FalconEmulator
from ..haptics.live import LiveSession, emulated_falcon, falcon_coupling
from ..haptics.servo import HandCoupling, ServoLoop
from ..haptics.servo_process import DeviceSpec
from ..materials import material
from ..session import CollisionSettings, Session


def measure_servo(
    duration_s: float,
    devices,
    couplings: Optional[Mapping[str, HandCoupling]] = None,
    *,
    while_running: Optional[Callable[[ServoLoop], None]] = None,
    open_devices: bool = True,
    **servo_kwargs,
) -> dict:
    """Run a servo loop over ``devices`` for ``duration_s`` and return its timing:
    ``{"rate_hz", "p50_ms", "p99_ms", "per_hand"}`` (worst hand first-level figures).

    ``while_running(loop)`` runs on the calling thread while the servo threads run (the bench
    steps the simulation there and publishes to ``loop.publish``); the call lasts at least
    ``duration_s``. Devices that are not open are opened (and closed afterwards)."""
    loop = ServoLoop(devices, couplings, **servo_kwargs)
    opened = []
    try:
        for hand in loop.hands:
            dev = loop.device(hand)
            if open_devices and not dev.is_open:
                dev.open()
                opened.append(dev)
        end = time.perf_counter() + duration_s
        loop.start()
        try:
            if while_running is not None:
                while_running(loop)
            remaining = end - time.perf_counter()
            if remaining > 0.0:
                time.sleep(remaining)
        finally:
            loop.stop()
        return loop.stats()
    finally:
        for dev in opened:
            dev.close()


_SCENARIO_GROUPS = {
    # hand -> vertex group. Hands are the user's, facing the cloth's front (-y): the left hand
    # grasps the -x side. On the T-shirt that is the wearer's right hem.
    "cloth": {"left": "handle_left", "right": "handle_right"},
    "banknote": {"left": "handle_left", "right": "handle_right"},
    "tshirt": {"left": "hem_right", "right": "hem_left"},
}


def emulated_session(
    scenario: str = "cloth",
    *,
    material_name: Optional[str] = None,
    tear_stress: Optional[float] = None,
    material_changes: Optional[Mapping[str, float]] = None,
    collision: bool = False,
    pull_distance: float = 0.02,
    hold_s: float = 0.3,
    pull_s: float = 2.0,
    pace: str = "wall",
    hand_stiffness: float = 1500.0,
    hand_damping: float = 15.0,
    emulator_substeps: int = 1,
    max_force: float = FALCON_MAX_FORCE,
    scene_radius: float = 0.08,
    force_scale: float = 0.1,
    k_position: float = 2000.0,
    k_velocity: float = 20.0,
    max_force_rate: float = 1000.0,
    servo: str = "thread",
    **live_kwargs,
) -> Tuple[LiveSession, Dict[str, FalconEmulator]]:
    """One of the paper's scenes ("cloth" = the square, "banknote", "tshirt") grasped by two
    emulated Falcons whose scripted hands pull the grips apart along the device x axis (scene x
    through ``FALCON_TO_SCENE``), each toward its own side, by ``pull_distance`` (device m) over
    ``pull_s`` after ``hold_s``. ``pace``: "wall" (the hands move in real time, like a user) or
    "simulation" (they follow the simulated time: reproducible on any machine). Returns
    (session, {hand: emulator}).

    Coupling: each Falcon's 4 cm workspace maps onto ``scene_radius`` (scale 2 by default); the
    scene force times ``force_scale`` (0.1: the square cloth's tearing peak of a few tens of N
    stays inside the Falcon's 8 N) reaches the device. Felt stiffness 0.1·2000·2 = 400 N/m,
    damping 4 N·s/m, inside the Falcon's 3000 N/m and 20 N·s/m.

    The T-shirt is pinned along its ``shoulders`` group: without collision nothing else would
    hold it up; with ``collision=True`` it also collides with the mannequin (slower).

    ``servo``: "thread" (the devices and their servo threads in this process; the emulators
    returned are the objects themselves) or "process" (``DeviceSpec``s: the emulated Falcons and
    the servo live in a servo process of their own; the emulators returned are
    ``RemoteEmulator``s that reach them there)."""
    if scenario not in _SCENARIO_GROUPS:
        raise ConfigError(f"unknown scenario {scenario!r}; scenarios: {', '.join(_SCENARIO_GROUPS)}")
    if servo not in ("thread", "process"):
        raise ConfigError(f"servo must be 'thread' or 'process', got {servo!r}")
    if pace not in ("wall", "simulation"):
        raise ConfigError(f"pace must be 'wall' or 'simulation', got {pace!r}")
    body = None
    if scenario == "cloth":
        mesh, mat_name = examples.square_cloth(), "cotton"
    elif scenario == "banknote":
        mesh, mat_name = examples.banknote(), "banknote"
    else:
        body = examples.mannequin()
        mesh, mat_name = examples.tshirt(body), "cotton"
    changes = dict(material_changes or {})
    if tear_stress is not None:
        changes["tear_stress"] = float(tear_stress)
    mat = material(material_name or mat_name, **changes)
    cloth = Cloth(mesh.vertices, mesh.triangles, mat, uv=mesh.loop_uv(), groups=mesh.groups)
    cloth.set_tearing(True)
    if scenario == "tshirt":
        cloth.pin("shoulders")
    session = Session(cloth, CollisionSettings() if collision else None)
    if collision and body is not None:
        session.add_body("mannequin", body.vertices, body.triangles)
    clock = (lambda: session.time) if pace == "simulation" else None
    hands = {}
    emulators = {}
    for i, (hand, group) in enumerate(_SCENARIO_GROUPS[scenario].items()):
        side = float(np.sign(mesh.vertices[mesh.groups[group] >= 0.5, 0].mean())) or (1.0 if hand == "right" else -1.0)
        args = dict(serial=f"EMU-{hand.upper()}-{i}", hand=hand, direction=(side, 0.0, 0.0), distance=pull_distance, hold_s=hold_s,
                    pull_s=pull_s, stiffness=hand_stiffness, damping=hand_damping, substeps=emulator_substeps, max_force=max_force)
        if servo == "process":
            # the simulated time reaches the servo process through the shared header
            dev = DeviceSpec("tearcloth.haptics.live:emulated_falcon", args, sim_clock_arg="clock" if pace == "simulation" else None)
        else:
            dev, emulators[hand] = emulated_falcon(clock=clock, **args)
        coupling = falcon_coupling(scene_radius, k_position=k_position, k_velocity=k_velocity, force_scale=force_scale, max_force_rate=max_force_rate)
        hands[hand] = (group, dev, coupling)
    live = LiveSession(session, hands, **live_kwargs)
    if servo == "process":
        emulators = {hand: live.servo_process.emulator(hand) for hand in hands}
    return live, emulators


def measure_live_servo(
    duration_s: float = 10.0,
    scenario: str = "tshirt",
    *,
    collision: bool = False,
    emulator_substeps: int = 1,
    **session_kwargs,
) -> dict:
    """Servo timing with two emulated Falcons while the ``scenario``'s simulation (T-shirt by
    default: ``tshirt()``, cotton, hands on hem_left/hem_right, shoulders pinned, no collision
    unless ``collision=True``) runs as fast as it can on the calling thread for ``duration_s``.

    Returns ``rate_hz``, ``p50_ms``, ``p99_ms`` (servo, worst hand; what ``tearcloth bench``
    reports as ``servo.*``), ``sim_steps_per_s``, ``sim_p50_ms``, ``sim_p99_ms``,
    ``stall_timeout_s``, ``watchdog_trips``, ``overruns``, ``servo_realtime``, ``per_hand`` and
    the scenario settings. The hands pull apart (in wall time) over 80 % of the run, so the cloth
    is under load, and may tear, while it is measured."""
    session_kwargs.setdefault("pull_s", max(0.8 * duration_s, 0.1))
    session_kwargs.setdefault("hold_s", min(0.3, 0.1 * duration_s))
    live, _emus = emulated_session(scenario, collision=collision, emulator_substeps=emulator_substeps, **session_kwargs)
    try:
        live.run_for(duration_s)
    finally:
        live.stop()
    out = live.stats()
    out.update(scenario=scenario, collision=bool(collision), emulator_substeps=int(emulator_substeps), duration_s=float(duration_s),
               servo=session_kwargs.get("servo", "thread"))
    return out


# A pure-Python CPU hog for the other core (its own interpreter: it competes for the CPU, not
# for our GIL).
_HOG = "while True:\n    pass\n"

# What the machine gives any unprivileged 1 kHz sleeper at the same moment: a bare loop with the
# servo process's own measures (own session, 1 ns timer slack, short slice, absolute deadlines)
# and no work, in a process of its own, run beside the loaded measurement. The servo cannot be
# steadier than this; on a machine shared with other jobs it tells their share from ours.
_FLOOR = """
import json, os, sys, time, ctypes
import numpy as np
from tearcloth.haptics import servo_process as sp
os.setsid()
lib = sp._libc()
sp._set_timer_slack(lib)
sp._set_short_slice(lib, 0.0001)
end = time.perf_counter() + float(sys.argv[1])
nxt = time.perf_counter()
last = None
periods = []
while True:
    now = time.perf_counter()
    if last is not None:
        periods.append(now - last)
    last = now
    if now > end:
        break
    nxt += 0.001
    if now - nxt > 0.001:
        nxt = now
    ts = sp._Timespec(int(nxt), int((nxt - int(nxt)) * 1e9))
    lib.clock_nanosleep(1, 1, ctypes.byref(ts), None)
p = np.asarray(periods)
print(json.dumps({"rate_hz": float(1.0 / p.mean()), "p50_ms": float(np.percentile(p, 50) * 1e3),
                  "p99_ms": float(np.percentile(p, 99) * 1e3), "max_ms": float(p.max() * 1e3)}))
"""


_TICKS = None


def _thread_cpu(pid: int) -> Dict[int, Tuple[float, int, int]]:
    """{tid: (CPU seconds, voluntary, involuntary context switches)} of every thread of ``pid``
    (Linux /proc; empty elsewhere or once it has gone)."""
    import os

    global _TICKS
    if _TICKS is None:
        _TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    out = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
            with open(f"/proc/{pid}/task/{tid}/status") as fh:
                status = dict(line.split(":", 1) for line in fh if ":" in line)
        except OSError:
            continue
        cpu = (int(fields[11]) + int(fields[12])) / _TICKS  # utime + stime
        out[int(tid)] = (cpu, int(status.get("voluntary_ctxt_switches", 0)), int(status.get("nonvoluntary_ctxt_switches", 0)))
    return out


def _cpu_use(before: Dict[int, tuple], after: Dict[int, tuple], names: Mapping[int, str], wall: float) -> dict:
    """Per named thread: CPU share of ``wall`` and context switches per second between two
    ``_thread_cpu`` samples; unnamed threads are summed as "other"."""
    out: Dict[str, Dict[str, float]] = {}
    for tid, (cpu, vol, invol) in after.items():
        c0, v0, i0 = before.get(tid, (0.0, 0, 0))
        name = names.get(tid, "other")
        d = out.setdefault(name, {"cpu": 0.0, "voluntary_per_s": 0.0, "involuntary_per_s": 0.0})
        d["cpu"] += (cpu - c0) / wall
        d["voluntary_per_s"] += (vol - v0) / wall
        d["involuntary_per_s"] += (invol - i0) / wall
    out["total"] = {"cpu": sum(v["cpu"] for v in out.values())}
    return out


def measure_loaded_servo(
    duration_s: float = 10.0,
    scenario: str = "tshirt",
    *,
    servo: str = "process",
    collision: bool = True,
    gil_loop: bool = True,
    cpu_hog: bool = True,
    floor: bool = True,
    hog_session: bool = False,
    **session_kwargs,
) -> dict:
    """Servo timing under the load of an artist's Blender, without real-time priority: two
    emulated Falcons, the ``scenario`` (T-shirt) simulating with collision on its own thread
    (``LiveSession.start``), the calling thread busy with a GIL-heavy pure-Python loop (standing
    in for Blender's UI: panels, timers, handlers) and a CPU hog process on the other core.

    ``servo``: "process" (the servo process of ``haptics.servo_process``) or "thread" (the
    in-process servo threads, for the before/after comparison). Returns ``live.stats()`` (``rate_hz``,
    ``p50_ms``, ``p99_ms``, ``max_ms``: worst hand; ``privileges``: what the unprivileged servo
    got), plus ``gil_loop_iterations``, the set-up and, with ``floor``, ``floor_{rate_hz,p50_ms,
    p99_ms,max_ms}``: a bare unprivileged 1 kHz sleeper measured beside it (``_FLOOR``).

    ``hog_session``: the hog in a session (hence, Linux autogroup, a scheduling group) of its own,
    as another program would be, rather than in the simulating process's.

    ``cpu``: where the CPU went meanwhile (Linux), per thread of the simulating process
    (``sim``: the simulation thread, ``main``: the GIL-heavy loop, ``log``: the force-log drain,
    ``servo-<hand>``: the in-process servo threads) and the servo process's total (``servo
    process``), each as a share of one core with its context switches per second; ``sim_cpu_per_step_ms``
    is the simulation thread's CPU per step, so a slower simulation can be told apart as less CPU
    given (the scheduler) or more CPU spent (work) per step."""
    session_kwargs.setdefault("pull_s", max(0.8 * duration_s, 0.1))
    session_kwargs.setdefault("hold_s", min(0.3, 0.1 * duration_s))
    session_kwargs.setdefault("servo_priority", None)  # no SCHED_FIFO: what an artist's Blender gets
    live, _emus = emulated_session(scenario, collision=collision, servo=servo, **session_kwargs)
    hog = subprocess.Popen([sys.executable, "-c", _HOG], start_new_session=hog_session) if cpu_hog else None
    loops = 0
    probe = None
    import os
    import threading

    try:
        live.start()
        if floor:
            probe = subprocess.Popen([sys.executable, "-c", _FLOOR, str(duration_s)], stdout=subprocess.PIPE, text=True)
        servo_pid = live.servo_process.pid if live.servo_process is not None else None
        t_cpu0, steps0 = time.perf_counter(), live.steps
        cpu0 = _thread_cpu(os.getpid())
        servo0 = _thread_cpu(servo_pid) if servo_pid else {}
        hog0 = _thread_cpu(hog.pid) if hog is not None else {}
        end = time.perf_counter() + duration_s
        while time.perf_counter() < end and not live.ended:
            if gil_loop:
                x = 0
                for i in range(20000):  # ~1 ms of bytecode between two checks of the clock
                    x += i * i
                loops += 1
            else:
                time.sleep(0.01)
        cpu1 = _thread_cpu(os.getpid())
        servo1 = _thread_cpu(servo_pid) if servo_pid else {}
        hog1 = _thread_cpu(hog.pid) if hog is not None else {}
        wall, steps = time.perf_counter() - t_cpu0, live.steps - steps0
        names = {threading.main_thread().native_id: "main"}
        for t in threading.enumerate():  # while they run (the servo threads are gone after stop)
            if t.name.startswith("tearcloth-"):
                names[t.native_id] = {"tearcloth-live-sim": "sim", "tearcloth-live-log": "log"}.get(t.name, t.name[len("tearcloth-"):])
    finally:
        live.stop()
        if hog is not None:
            hog.kill()
            hog.wait()
    out = live.stats()
    cpu = _cpu_use(cpu0, cpu1, names, wall)
    if servo_pid:
        cpu["servo process"] = _cpu_use(servo0, servo1, {}, wall)["total"]
    if hog is not None:
        cpu["hog"] = _cpu_use(hog0, hog1, {}, wall)["total"]
    out["cpu"] = cpu
    out["sim_steps_per_s_measured"] = steps / wall if wall > 0 else 0.0
    out["sim_cpu_per_step_ms"] = 1e3 * cpu.get("sim", {}).get("cpu", 0.0) * wall / steps if steps else float("nan")
    if probe is not None:
        try:
            got, _ = probe.communicate(timeout=duration_s + 30.0)
            out.update({f"floor_{k}": v for k, v in json.loads(got).items()})
        except (subprocess.TimeoutExpired, ValueError):
            probe.kill()
            probe.wait()
    if "max_ms" not in out and out.get("per_hand"):
        out["max_ms"] = max(v["max_ms"] for v in out["per_hand"].values())
    out.update(scenario=scenario, servo=servo, collision=bool(collision), gil_loop=bool(gil_loop), cpu_hog=bool(cpu_hog),
               gil_loop_iterations=loops, duration_s=float(duration_s), error=None if live.error is None else repr(live.error))
    return out


# The simulating process of ``kill_simulating_process``: the square cloth held by two emulated
# Falcons in a servo process, the simulation on its own thread; it prints what the killer needs
# once both devices feel a force, then waits to be killed.
_SIMULATOR = r"""
import json, sys, time
from tearcloth.bench.servo import emulated_session
live, emus = emulated_session("cloth", servo="process", tear_stress=2e6, hold_s=0.05, pull_s=3.0, pull_distance=0.015,
                              servo_priority=None, stall_timeout_s=float(sys.argv[1]))
live.start()
deadline = time.perf_counter() + 30.0
while time.perf_counter() < deadline and not all(any(e.efforts) for e in emus.values()):
    time.sleep(0.01)
print(json.dumps({"shm": live.servo_process.shm_name, "servo_pid": live.servo_process.pid, "steps": live.steps}), flush=True)
time.sleep(600)
"""


def _pid_alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as fh:
            return "State:\tZ" not in fh.read()  # a zombie has exited
    except FileNotFoundError:
        return False


def kill_simulating_process(stall_timeout_s: float = 0.5, wait_s: float = 10.0) -> Dict[str, object]:
    """SIGKILL a simulating process whose two emulated Falcons (in its servo process) push with a
    force, and watch the devices from outside through the servo's shared memory
    (``kill_and_watch``). Returns ``zero_s``, ``efforts``, ``servo_alive`` (see there) and
    ``stall_timeout_s``. Linux only (the peer check)."""
    sim = subprocess.Popen([sys.executable, "-c", _SIMULATOR, repr(float(stall_timeout_s))], stdout=subprocess.PIPE, text=True)
    try:
        line = sim.stdout.readline()
        if not line:
            raise RuntimeError("the simulating process died before its session ran")
        info = json.loads(line)
    except BaseException:
        sim.kill()
        sim.wait()
        raise
    out = kill_and_watch(sim, info["shm"], int(info["servo_pid"]), 2, wait_s=wait_s)
    out["stall_timeout_s"] = float(stall_timeout_s)
    return out


def kill_and_watch(sim: subprocess.Popen, shm_name: str, servo_pid: int, n_hands: int, watched=None,
                   wait_s: float = 10.0) -> Dict[str, object]:
    """SIGKILL ``sim`` (a simulating process whose servo process ``servo_pid`` drives ``n_hands``
    hands through the shared memory ``shm_name``) once the ``watched`` hands (indices; default
    all) feel a force, and watch them from here: what each device was last sent and when it first
    got a zero (CLOCK_MONOTONIC, which every process shares). Returns ``zero_s`` (kill to the
    later zero; inf if one never came within ``wait_s``), ``efforts`` (what each watched device
    was left with) and ``servo_alive`` (after the wait). Whatever happens, ``sim`` and the servo
    process are gone afterwards."""
    import math
    import os
    import signal

    from ..haptics.servo_process import _P_EFF, _P_ZERO, _read, _Shared

    watched = list(range(n_hands)) if watched is None else list(watched)
    shared = None
    try:
        shared = _Shared(n_hands, shm_name)
        # The force the devices feel passes through zero now and then (a proxy that has caught up
        # with its handle, the ramp at the session's start): wait for a moment when every watched
        # device is being pushed, so the zero seen after the kill can only be the kill's.
        deadline = time.perf_counter() + wait_s

        def read(last):
            # _read gives None when the servo was in the middle of writing a block for all its tries
            # (a writer descheduled mid-write on a loaded machine): that hand keeps its last complete read
            return [b if b is not None else old for b, old in zip((_read(shared.prox[i]) for i in watched), last)]

        before = [None] * len(watched)
        while True:
            before = read(before)
            if all(b is not None and np.any(b[_P_EFF : _P_EFF + 3]) and math.isnan(b[_P_ZERO]) for b in before):
                break
            if time.perf_counter() > deadline or sim.poll() is not None:
                raise RuntimeError(f"the devices did not feel a force before the kill (waited {wait_s:.0f} s): {before}")
            time.sleep(0.001)
        t_kill = time.perf_counter()  # CLOCK_MONOTONIC, as the servo's stamps
        os.kill(sim.pid, signal.SIGKILL)
        sim.wait(5.0)
        deadline = time.perf_counter() + wait_s
        blocks = before
        while True:
            blocks = read(blocks)
            done = all(not math.isnan(b[_P_ZERO]) for b in blocks) and not _pid_alive(servo_pid)
            if done or time.perf_counter() > deadline:
                break
            time.sleep(0.002)
        zeros = [b[_P_ZERO] for b in blocks]
        return {
            "zero_s": max(z - t_kill for z in zeros) if not any(math.isnan(z) for z in zeros) else math.inf,
            "efforts": [[int(e) for e in b[_P_EFF : _P_EFF + 3]] for b in blocks],
            "servo_alive": _pid_alive(servo_pid),
        }
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
        if _pid_alive(servo_pid):
            os.kill(servo_pid, signal.SIGKILL)
        if shared is not None:
            shared.close()


def measure_kill_zero(runs: int = 5) -> Dict[str, float]:
    """What ``servo.kill_zero_ms`` reports: SIGKILL of the simulating process to zero force on
    both emulated Falcons, over ``runs`` kills (median and max, ms), with the stall watchdog far
    out of the way (20 s) so that only the servo's peer check can be what zeroed them."""
    lat = [kill_simulating_process(stall_timeout_s=20.0)["zero_s"] * 1e3 for _ in range(runs)]
    return {"median_ms": float(np.median(lat)), "max_ms": float(np.max(lat)), "runs": runs}
