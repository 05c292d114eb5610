"""How step time and memory grow with the mesh (issue 8, part 2).

This file owns the scaling part of ``tearcloth bench``: the meshes of each size (``make_scene``),
one child process per point (``_child_point``, run as ``python -m tearcloth.bench.scaling``), the
fitted exponent, the plot and the console table. Dev-only (not in the extension zip).

    from tearcloth.bench.scaling import scaling, plot_scaling
    r = scaling()                      # ~1K .. 100K triangles, tearing off/on, collision off/on
    r["exponent"], r["peak_mb_100k"]   # step_ms ~ triangles ** exponent; MB at 100K triangles
    plot_scaling(r, "scaling.png")

Meshes: two families, each made at a base size between 1K and 4K triangles and refined 1-to-4
(``examples.refine``) up to the target: the paper's square cloth (``examples.square_cloth``, laid
horizontal at z = 1 m) and the T-shirt (``examples.tshirt``). Targets 1e3, 3e3, 1e4, 3e4, 1e5 give
1000, 3000, 2500 x 4, 1875 x 16 and 1562 x 64 triangles (the T-shirt family alike, within the
mesher's ~2 %).

What steps: each point is one cloth, cotton, grasped by two hands that pull apart along X at
2 cm/s (the square by its ``handle_left`` / ``handle_right`` corners, the shirt by its front hem),
stepped at dt = 1 ms (the haptic rate of ``table1.py``) through ``Session.step``; a step's time is
its wall time (collision + FEM + tearing + Python glue).
- tearing on: ``set_tearing(True)`` with a threshold out of reach (1e12 Pa), so every step scans
  every vertex (Table I's "before" column) and the mesh keeps its size; a running tear's cost is
  ``table1.py``'s after-cuts figure, not a function of size.
- collision on: ``Session(cloth, CollisionSettings())`` (relative cluster measure, self-collision
  on), with one static closed body: under the square a sphere (radius 0.2 m, 1280 triangles,
  its top 1.5 mm below the cloth, so contacts start at once and the cloth drapes over it); for
  the T-shirt its mannequin in the bind pose (7.6K triangles). The body keeps its size at every
  cloth size, so the curve is the cloth's.

Timing: median of ``steps`` steps after ``warmup`` steps (the first detection and allocations);
fewer steps at large sizes (``default_steps``, at least 5) so the whole default run stays around
3.5 minutes on two cores. Without collision, below 50K triangles and with block Jacobi (a snapshot rebuilds the
multigrid's hierarchy, which the first window did not) the window is replayed from a snapshot of its
first state until the point has ``REPLAY_CPU_S`` of steps (``replays``; ``timed_steps`` counts
them all, the medians are over them; ``replay_exact`` says each replay made the window's CG
iterations again): the same steps, timed more often, so a short window at 1K is not one clock
ramp's worth of noise. The replays run in a second child (its memory figures are not used).
Each point has the wall time (``step_ms``) and the child's CPU time (``step_cpu_ms``,
all its threads): on a machine shared with other jobs the wall time stretches and the CPU time
much less, so both get an exponent (``exponents`` / ``exponents_cpu``); the load average at the
end of the run is recorded with the result.

Memory: every point runs in a fresh subprocess (peaks never accumulate). The child imports
everything (numpy, the native core, the session and the collision package, used or not) and loads
the mesh arrays, reads its resident set (``VmRSS``), resets its peak (``/proc/self/clear_refs``),
builds the cloth and steps it, then reads its peak (``VmHWM``). ``peak_mb`` (MB = 2^20 bytes) is
that peak minus the resident set just before the cloth was built: what the cloth, its solver
(the multigrid hierarchy included), the session and the detector added at their peak, in the same
process; ``bytes_per_triangle`` = that / triangles, the figure the target (<= 1 KB per triangle at
100K) is about. ``peak_rss_mb`` is the absolute peak of the child; ``peak_mb_vs_idle`` the older
figure, the peak minus an idle child's (same imports, no mesh). Where the peak cannot be reset (no
/proc), the idle child's figure is used and ``memory_method`` says so.

Convergence: a step whose solve the core accepted short of its tolerance (after the sub-step
splits) is counted per point (``unconverged_steps``, timed steps; ``unconverged_warmup_steps``);
the exponent is fitted on the points with none (``exponent_sizes`` lists them, ``excluded`` the
others), and ``unconverged_steps`` at the top is the exponent configuration's total.

Exponent: least squares of log(step_ms) on log(triangles) per configuration (``fit_exponent``);
``exponent`` is the square cloth's with tearing and collision off, ``exponents`` has all.
"""
from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .machine import loadavg
from .table1 import DT, PULL_SPEED  # the same step and pull as Table I
UNREACHABLE_TEAR_STRESS = 1e12
SPHERE_RADIUS = 0.2
SPHERE_GAP = 0.0015
SQUARE_HEIGHT = 1.0
BASE_RANGE = (1000, 4000)
DEFAULT_TARGETS = (1e3, 3e3, 1e4, 3e4, 1e5)
FAMILIES = ("square", "tshirt")
MB = float(2**20)
# A point's timed window is replayed from a snapshot of its first state until the point has this much
# CPU time of steps (at most REPLAY_MAX times): a 1K window of 30 steps is ~20 ms, short enough that
# the clock's ramp or one preemption moved its median by 50 % between runs and the fitted exponent by
# +-0.05. Only without collision (the detector's state is not in the cloth's snapshot, so a replay
# would not be the same steps), with block Jacobi, and below REPLAY_MAX_TRIANGLES (a 30K window
# already takes ~0.2 s).
REPLAY_CPU_S = 0.3
REPLAY_MAX = 20
REPLAY_MAX_TRIANGLES = 50000


# ------------------------------------------------------------------------------------------------
# Fitting
# ------------------------------------------------------------------------------------------------


def fit_exponent(triangles, step_ms) -> float:
    """Slope of the least-squares line through (log triangles, log step_ms): the p of
    step_ms ~ c * triangles ** p. Needs two or more distinct positive sizes."""
    x = np.asarray(triangles, dtype=np.float64).reshape(-1)
    y = np.asarray(step_ms, dtype=np.float64).reshape(-1)
    if x.shape != y.shape:
        raise ValueError(f"triangles and step_ms differ in length ({x.size} vs {y.size})")
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    x, y = np.log(x[ok]), np.log(y[ok])
    if x.size < 2 or np.ptp(x) == 0:
        raise ValueError("need at least two distinct positive sizes to fit an exponent")
    slope, _intercept = np.polyfit(x, y, 1)
    return float(slope)


# ------------------------------------------------------------------------------------------------
# Meshes
# ------------------------------------------------------------------------------------------------


def base_and_levels(target: float, lo: int = BASE_RANGE[0], hi: int = BASE_RANGE[1]) -> tuple[int, int]:
    """(base triangle count, refinement levels) with base * 4**levels ~ target and base in
    [lo, hi) when the target allows (smaller targets are made directly)."""
    target = float(target)
    if not target > 0:
        raise ValueError(f"triangle target must be > 0, got {target}")
    levels = 0
    while target / 4**levels >= hi:
        levels += 1
    return max(50, int(round(target / 4**levels))), levels


def icosphere(radius: float = SPHERE_RADIUS, center=(0.0, 0.0, 0.0), subdivisions: int = 3):
    """Closed sphere mesh, outward counter-clockwise triangles: 20 * 4**subdivisions of them."""
    p = (1.0 + 5.0**0.5) / 2.0
    v = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p), (0, -1, -p), (0, 1, -p),
         (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
         (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
         (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = np.array(v, dtype=np.float64)
    verts /= np.linalg.norm(verts, axis=1, keepdims=True)
    tris = np.array(f, dtype=np.int64)
    for _ in range(int(subdivisions)):
        n = len(verts)
        e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
        key = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
        uniq, inv = np.unique(key, return_inverse=True)
        mids = verts[uniq // n] + verts[uniq % n]
        mids /= np.linalg.norm(mids, axis=1, keepdims=True)
        verts = np.concatenate([verts, mids])
        m = n + inv.reshape(3, -1).T  # midpoint of sides (0,1), (1,2), (2,0)
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        tris = np.concatenate([np.stack([a, m[:, 0], m[:, 2]], 1), np.stack([m[:, 0], b, m[:, 1]], 1),
                               np.stack([m[:, 2], m[:, 1], c], 1), np.stack([m[:, 0], m[:, 1], m[:, 2]], 1)])
    return verts * float(radius) + np.asarray(center, dtype=np.float64), tris.astype(np.int32)


def make_scene(family: str, target: float, seed: int = 0) -> dict:
    """Arrays of one point's scene: vertices, triangles, the two hands' vertex weights (``hand_a``
    at -X, ``hand_b`` at +X: they move apart), the body (vertices, triangles) used when collision is
    on, and how the mesh was made."""
    from .. import examples

    base, levels = base_and_levels(target)
    if family == "square":
        mesh = examples.square_cloth(target_triangles=base, seed=seed)
        v = mesh.vertices
        # lay it flat: (x, 0, z) -> (x, z - 1, 1), the grip edge (top) becomes the +Y edge
        v = np.stack([v[:, 0], v[:, 2] - SQUARE_HEIGHT, np.full(len(v), SQUARE_HEIGHT)], axis=1)
        mesh.vertices = v
        hands = ("handle_left", "handle_right")
        body = icosphere(SPHERE_RADIUS, (0.0, 0.0, SQUARE_HEIGHT - SPHERE_RADIUS - SPHERE_GAP), 3)
        body_name = "sphere r 0.2 m (1280 triangles) under the cloth's centre"
    elif family == "tshirt":
        man = examples.mannequin()
        mesh = examples.tshirt(man, target_triangles=base, seed=seed)
        hands = ("hem_right", "hem_left")  # hem_right is the one at -X
        body = (man.vertices, man.triangles)
        body_name = f"mannequin, bind pose ({len(man.triangles)} triangles)"
    else:
        raise ValueError(f"unknown mesh family {family!r}; families: {', '.join(FAMILIES)}")
    if levels:
        mesh = examples.refine(mesh, levels)
    return {
        "vertices": mesh.vertices, "triangles": mesh.triangles,
        "hand_a": mesh.groups[hands[0]], "hand_b": mesh.groups[hands[1]],
        "body_vertices": np.asarray(body[0], dtype=np.float64), "body_triangles": np.asarray(body[1], np.int32),
        "made": f"{family} at {base} triangles, refined x4 {levels} time(s)", "body": body_name,
    }


# ------------------------------------------------------------------------------------------------
# Steps and memory budget
# ------------------------------------------------------------------------------------------------


def default_steps(triangles: int) -> int:
    """Steps measured per point: 30 up to 3K triangles, ~10 at 10K, 5 from 30K on (a 100K step
    takes a quarter to half a second; the default run of 40 points then stays near 3.5 minutes on
    two cores). Not fewer than 5: with 2 timed steps at 100K (this rule before) the median was one
    step's luck (a multigrid refresh of 37 or 58 ms in it), and the fitted exponent moved 1.22 ->
    1.39 between two runs of the same build an hour apart."""
    return int(np.clip(round(30.0 * (3000.0 / max(triangles, 1)) ** 0.9), 5, 30))


def default_warmup(triangles: int) -> int:
    """Unmeasured first steps (first full collision detection, first allocations): 3 at every
    size, so every point times the same phase of the pull (1 above 20K before: the large points
    timed the first, lighter steps of the pull that the small ones skipped)."""
    return 3


# ------------------------------------------------------------------------------------------------
# The child process
# ------------------------------------------------------------------------------------------------


def _status_bytes(key: str) -> int | None:
    """A size line of /proc/self/status (VmHWM, VmRSS) in bytes; None without /proc."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _peak_rss_bytes() -> int:
    """This process's peak resident set: VmHWM from /proc, else ru_maxrss."""
    peak = _status_bytes("VmHWM")
    if peak is not None:
        return peak
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(r if sys.platform == "darwin" else r * 1024)


def _import_all():
    """What every child imports, used or not, so the idle baseline matches."""
    from .. import cloth, materials, session  # noqa: F401
    from .. import collision  # noqa: F401

    return cloth, materials, session


def _rss_bytes() -> int | None:
    """This process's resident set now (VmRSS), None without /proc."""
    return _status_bytes("VmRSS")


def _reset_peak() -> bool:
    """Resets VmHWM to the current resident set (Linux >= 4.0); False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _child_idle() -> dict:
    _import_all()
    return {"peak_rss_bytes": _peak_rss_bytes()}


def _child_point(spec: dict) -> dict:
    cloth_mod, materials, session_mod = _import_all()
    d = np.load(spec["npz"])
    V, T = d["vertices"], d["triangles"]
    hand_a, hand_b = d["hand_a"], d["hand_b"]
    body_v, body_t = d["body_vertices"], d["body_triangles"]
    import gc
    import warnings

    warnings.simplefilter("ignore", UserWarning)  # the unreachable tear stress is meant
    gc.collect()
    rss_before = _rss_bytes()
    reset = rss_before is not None and _reset_peak()
    mat = materials.material("cotton", tear_stress=UNREACHABLE_TEAR_STRESS)
    c = cloth_mod.Cloth(V, T, mat, groups={"hand_a": hand_a, "hand_b": hand_b})
    hands = (c.add_handle("hand_a"), c.add_handle("hand_b"))
    c.set_tearing(bool(spec["tearing"]))
    if spec["collision"]:
        s = session_mod.Session(c, session_mod.CollisionSettings())
        s.add_body("body", body_v, body_t)
    else:
        s = session_mod.Session(c, None)
    times, cpu, iters, contacts, setup = [], [], [], [], []
    unconverged = unconverged_warmup = 0
    levels = amg_bytes = sgs_solves = 0
    parts = {"collision": [], "fem": [], "tearing": []}
    error = None
    n = int(spec["warmup"]) + int(spec["steps"])
    # in a child of its own (the parent's second one for the point): a snapshot's bytes, and the
    # buffers its making leaves resident, must not reach the first child's memory figure
    replay = bool(spec.get("replay")) and not spec["collision"]
    blob = None

    def timed_step(i):
        """Step i of the pull (the hands moved to where step i puts them): its report, wall and CPU seconds."""
        off = PULL_SPEED * (i + 1) * DT
        c.move_handle(hands[0], (-off, 0.0, 0.0))
        c.move_handle(hands[1], (off, 0.0, 0.0))
        c0 = time.process_time()
        t0 = time.perf_counter()
        rep = s.step(DT)
        return rep, time.perf_counter() - t0, time.process_time() - c0

    for i in range(n):
        if replay and i == int(spec["warmup"]):
            blob = c.snapshot()  # the window's first state, replayed below
        try:
            rep, wall, used = timed_step(i)
        except cloth_mod.SimulationError as e:  # reported with the point; the steps so far stand
            error = f"step {i + 1}: {e}"
            break
        st = c.stats()
        if i < int(spec["warmup"]):
            unconverged_warmup += rep.unconverged_substeps > 0
        else:
            times.append(wall)
            cpu.append(used)
            iters.append(st["cg_iterations"])
            setup.append(st["amg_setup_seconds"])
            levels = max(levels, int(st["amg_levels"]))
            sgs_solves += int(st["sgs_solves"])
            amg_bytes = max(amg_bytes, int(st.get("amg_bytes", 0)))
            contacts.append(rep.contacts)
            unconverged += rep.unconverged_substeps > 0
            parts["collision"].append(rep.collision_s)
            parts["fem"].append(rep.fem_s)
            parts["tearing"].append(rep.tearing_s)
    peak = _peak_rss_bytes()
    st = c.stats()
    replays, replay_exact = 0, None
    first = list(iters)
    replay_s, replay_cpu = [], []
    while blob is not None and error is None and sum(cpu) + sum(replay_cpu) < REPLAY_CPU_S and replays < REPLAY_MAX:
        c.restore(blob)
        its, kept = [], len(replay_s)
        for i in range(int(spec["warmup"]), n):
            try:
                _, wall, used = timed_step(i)
            except cloth_mod.SimulationError:  # cannot happen for the same steps: said by replay_exact
                its = None
                break
            replay_s.append(wall)
            replay_cpu.append(used)
            its.append(c.stats()["cg_iterations"])
        replays += 1
        # a replay is the same steps (the snapshot restores the warm start too): the same iterations
        replay_exact = its == first
        if not replay_exact:  # not the same steps: its times are left out, and the point says so
            del replay_s[kept:], replay_cpu[kept:]
            break
    return {"step_s": times, "step_cpu_s": cpu, "replays": replays, "replay_exact": replay_exact,
            "replay_step_s": replay_s, "replay_step_cpu_s": replay_cpu,
            "cg_iterations_median": statistics.median(iters) if iters else None,
            "cg_iterations": iters, "amg_levels": levels, "amg_bytes": amg_bytes, "sgs_solves": sgs_solves,
            "amg_setup_ms_median": 1e3 * statistics.median(setup) if setup else None,
            "amg_setup_ms_mean": 1e3 * statistics.fmean(setup) if setup else None,
            "unconverged_warmup_steps": int(unconverged_warmup),
            "rss_before_bytes": rss_before if reset else None,
            "contacts_median": statistics.median(contacts) if contacts else None, "cuts": int(st.get("cuts", 0)),
            "triangles_end": int(c.num_triangles), "error": error, "unconverged_steps": int(unconverged),
            "parts_ms": {k: 1e3 * statistics.median(v) if v else None for k, v in parts.items()},
            "peak_rss_bytes": peak}


def _run_child(args: list[str], timeout: float) -> dict:
    """Run ``python -m <package>.bench.scaling ARGS`` in a fresh interpreter; its last JSON line."""
    env = dict(os.environ)
    name = (__package__ or "tearcloth.bench").split(".")[0]
    here = Path(__file__).absolute().parent.parent  # the package's folder; not resolved: keep its name
    if here.name == name:
        root = str(here.parent)
    else:  # a source tree whose folder is not named like the package (addon/): link it
        shim = Path(tempfile.gettempdir()) / f"{name}_bench_path_{os.getuid() if hasattr(os, 'getuid') else 0}"
        shim.mkdir(exist_ok=True)
        link = shim / name
        if not link.exists():
            link.symlink_to(here, target_is_directory=True)
        root = str(shim)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    cmd = [sys.executable, "-m", f"{name}.bench.scaling", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"scaling child failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    return json.loads(lines[-1])


def idle_baseline_bytes(timeout: float = 120.0) -> int:
    """Peak resident set of an idle interpreter that imported what every point imports."""
    return int(_run_child(["--idle"], timeout)["peak_rss_bytes"])


# ------------------------------------------------------------------------------------------------
# The run
# ------------------------------------------------------------------------------------------------


def config_label(family: str, tearing: bool, collision: bool) -> str:
    return f"{family}, tearing {'on' if tearing else 'off'}, collision {'on' if collision else 'off'}"


def scaling(triangle_targets=DEFAULT_TARGETS, with_tearing=(False, True), with_collision=(False, True),
            steps=None, *, families=FAMILIES, warmup=None, timeout: float = 600.0, out=None) -> dict:
    """Step time (median ms) and peak memory per triangle count, per configuration.

    triangle_targets  sizes to make (see ``base_and_levels``); with_tearing / with_collision the
    settings to cross; steps: None (``default_steps`` by size), an int, or a callable of the
    triangle count; families: "square" and/or "tshirt". Returns points (one dict per run: mesh,
    triangles, vertices, tearing, collision, step_ms, peak_mb, bytes_per_triangle, steps, ...),
    exponent (square, tearing off, collision off; the first family's when the square is not run),
    exponents (per configuration label), peak_mb_100k (that baseline configuration at its
    largest size, 100K triangles by default), peak_mb_largest (every configuration at its largest
    size), baseline_mb (the idle child), and the settings used.
    """
    say = out or (lambda *_: None)
    wall0 = time.perf_counter()
    targets = [float(t) for t in triangle_targets]
    if not targets:
        raise ValueError("no triangle targets")
    with tempfile.TemporaryDirectory(prefix="tearcloth_scaling_") as tmp:
        baseline = idle_baseline_bytes()
        say(f"idle interpreter with tearcloth imported: {baseline / MB:.1f} MB")
        points = []
        for family in families:
            for target in targets:
                sc = make_scene(family, target)
                npz = os.path.join(tmp, f"{family}_{int(target)}.npz")
                np.savez(npz, **{k: v for k, v in sc.items() if isinstance(v, np.ndarray)})
                tri = int(len(sc["triangles"]))
                n_steps = int(steps(tri) if callable(steps) else (steps if steps is not None else default_steps(tri)))
                n_warm = int(warmup if warmup is not None else default_warmup(tri))
                for tearing in with_tearing:
                    for collision in with_collision:
                        spec = {"npz": npz, "tearing": bool(tearing), "collision": bool(collision),
                                "steps": max(1, n_steps), "warmup": max(0, n_warm)}
                        t0 = time.perf_counter()
                        res = _run_child(["--point", json.dumps(spec)], timeout)
                        res["replays"], res["replay_exact"] = 0, None
                        # points without the multigrid only: a snapshot makes the multigrid build its hierarchy
                        # afresh (amg.c), so a replayed window would time a build the first one did not
                        if (not collision and tri < REPLAY_MAX_TRIANGLES and not res["error"]
                                and res["amg_levels"] < 2):
                            again = _run_child(["--point", json.dumps({**spec, "replay": True})], timeout)
                            res["replays"], res["replay_exact"] = again["replays"], again["replay_exact"]
                            if again["cg_iterations"] != res["cg_iterations"]:
                                res["replay_exact"] = False  # the second child's window differed from the first's
                            if res["replay_exact"]:
                                # the replays' times join the first window's: the same steps, more samples
                                res["step_s"] = res["step_s"] + again["replay_step_s"]
                                res["step_cpu_s"] = res["step_cpu_s"] + again["replay_step_cpu_s"]
                        vs_idle = max(0, int(res["peak_rss_bytes"]) - baseline)
                        # the target's figure: this process's peak over its own resident set just
                        # before the cloth was built (the idle child's where the peak cannot be reset)
                        before = res.get("rss_before_bytes")
                        peak = max(0, int(res["peak_rss_bytes"]) - int(before)) if before is not None else vs_idle
                        p = {
                            "mesh": family, "target": target, "made": sc["made"],
                            "body": sc["body"] if collision else None,
                            "triangles": tri, "vertices": int(len(sc["vertices"])),
                            "tearing": bool(tearing), "collision": bool(collision),
                            "step_ms": 1e3 * statistics.median(res["step_s"]) if res["step_s"] else float("nan"),
                            # CPU seconds of the child per step (all its threads): what a step costs
                            # when other processes compete for the cores and stretch the wall time
                            "step_cpu_ms": (1e3 * statistics.median(res["step_cpu_s"]) if res["step_cpu_s"]
                                            else float("nan")),
                            "step_ms_min": 1e3 * min(res["step_s"], default=float("nan")),
                            "step_ms_max": 1e3 * max(res["step_s"], default=float("nan")),
                            # the window's steps; timed_steps counts its replays' too (the medians are over those)
                            "steps": len(res["cg_iterations"]), "warmup": n_warm,
                            "timed_steps": len(res["step_s"]), "replays": int(res.get("replays", 0)),
                            "replay_exact": res.get("replay_exact"),
                            "peak_mb": peak / MB, "bytes_per_triangle": peak / tri,
                            "peak_rss_mb": int(res["peak_rss_bytes"]) / MB,
                            "peak_mb_vs_idle": vs_idle / MB,
                            "rss_before_mb": before / MB if before is not None else None,
                            "memory_method": "peak minus RSS before the cloth" if before is not None else "peak minus idle child",
                            "cg_iterations_median": res["cg_iterations_median"],
                            "cg_iterations": res["cg_iterations"],
                            # what the timed steps' solves ran (auto: the sweeps below the multigrid bar)
                            "preconditioner": ("amg" if res["amg_levels"] >= 2
                                               else "sgs" if res["sgs_solves"] > 0 else "jacobi"),
                            "amg_levels": res["amg_levels"],
                            # what the hierarchy holds after its builds (the core's own count): part of peak_mb
                            "amg_mb": res.get("amg_bytes", 0) / MB,
                            "amg_setup_ms_median": res["amg_setup_ms_median"],
                            "amg_setup_ms_mean": res["amg_setup_ms_mean"],
                            # timed steps whose solve the core accepted short of cg_tolerance
                            "unconverged_steps": int(res.get("unconverged_steps", 0)),
                            "unconverged_warmup_steps": int(res["unconverged_warmup_steps"]),
                            "contacts_median": res["contacts_median"], "cuts": res["cuts"],
                            "ms_per_cg_iteration": (1e3 * statistics.median(res["step_s"]) / res["cg_iterations_median"]
                                                    if res["step_s"] and res["cg_iterations_median"] else None),
                            "error": res["error"],
                            # where a step's time goes: medians of Session.step's own report
                            "collision_ms": res["parts_ms"]["collision"], "fem_ms": res["parts_ms"]["fem"],
                            "tearing_ms": res["parts_ms"]["tearing"],
                            "wall_s": time.perf_counter() - t0,
                        }
                        points.append(p)
                        say(f"{config_label(family, tearing, collision):<45} {tri:>7} tris  "
                            f"{p['step_ms']:9.2f} ms  {p['peak_mb']:8.1f} MB  {p['bytes_per_triangle']:7.0f} B/tri  "
                            f"({p['steps']} steps, {p['wall_s']:.1f} s)")
    exponents, exponents_cpu, fitted, excluded = {}, {}, {}, {}
    largest = {}
    for family in families:
        for tearing in with_tearing:
            for collision in with_collision:
                every = [p for p in points if (p["mesh"], p["tearing"], p["collision"]) == (family, tearing, collision)]
                label = config_label(family, tearing, collision)
                # the exponent of converged solves only: a point with a step accepted short of the
                # tolerance (or one that failed) is left out of the fit, and listed
                pts = [p for p in every if p["unconverged_steps"] == 0 and not p["error"] and p["steps"]]
                fitted[label] = [p["triangles"] for p in pts]
                excluded[label] = [p["triangles"] for p in every if p not in pts]
                pts_all = every
                if len({p["triangles"] for p in pts}) >= 2:
                    exponents[label] = fit_exponent([p["triangles"] for p in pts], [p["step_ms"] for p in pts])
                    exponents_cpu[label] = fit_exponent([p["triangles"] for p in pts],
                                                        [p["step_cpu_ms"] for p in pts])
                if pts_all:
                    big = max(pts_all, key=lambda p: p["triangles"])
                    largest[label] = {"triangles": big["triangles"], "peak_mb": big["peak_mb"],
                                      "bytes_per_triangle": big["bytes_per_triangle"]}
    base_family = "square" if "square" in families else families[0]
    base_label = config_label(base_family, False, False)
    if base_label not in largest and largest:  # the plain configuration was not run
        base_label = next(iter(largest))
    result = {
        "points": points,
        "exponent": exponents.get(base_label, float("nan")),
        "exponent_of": base_label,
        "exponents": exponents,
        "exponent_sizes": fitted.get(base_label, []),
        "excluded": excluded.get(base_label, []),
        "exponent_sizes_all": fitted, "excluded_all": excluded,
        "exponent_cpu": exponents_cpu.get(base_label, float("nan")),
        # steps of the exponent's configuration the core accepted unconverged (0: the exponent
        # is of converged solves only), and of every point
        "unconverged_steps": sum(p["unconverged_steps"] for p in points
                                 if config_label(p["mesh"], p["tearing"], p["collision"]) == base_label),
        "unconverged_steps_all": sum(p["unconverged_steps"] for p in points),
        "unconverged_steps_by_size": {str(p["triangles"]): p["unconverged_steps"] for p in points
                                      if config_label(p["mesh"], p["tearing"], p["collision"]) == base_label},
        # the exponent configuration, one row per size: what the exponent and the memory target read
        "per_size": [{k: p[k] for k in ("triangles", "vertices", "step_ms", "step_cpu_ms", "cg_iterations_median",
                                        "ms_per_cg_iteration", "preconditioner", "amg_setup_ms_mean", "amg_mb", "peak_mb",
                                        "bytes_per_triangle", "peak_rss_mb", "unconverged_steps")}
                     for p in points if config_label(p["mesh"], p["tearing"], p["collision"]) == base_label],
        "exponents_cpu": exponents_cpu,
        "load_average": loadavg(),
        "peak_mb_100k": largest.get(base_label, {}).get("peak_mb", float("nan")),
        "peak_mb_100k_triangles": largest.get(base_label, {}).get("triangles"),
        "bytes_per_triangle_100k": largest.get(base_label, {}).get("bytes_per_triangle", float("nan")),
        "peak_mb_largest": largest,
        "baseline_mb": baseline / MB,
        "settings": {"dt_s": DT, "pull_speed_m_per_s": PULL_SPEED, "material": "cotton",
                     "tear_stress_when_tearing": UNREACHABLE_TEAR_STRESS, "targets": targets,
                     "families": list(families), "collision": "CollisionSettings() defaults",
                     "memory": ("peak_mb: VmHWM of a fresh child per point minus its VmRSS just before the cloth "
                                "is built (peak reset there; mesh arrays and imports excluded); the target "
                                "(<= 1 KB per triangle at 100K) reads bytes_per_triangle = that / triangles; "
                                "peak_rss_mb: the absolute peak; peak_mb_vs_idle: the peak minus an idle "
                                "child's (same imports)"),
                     "cpus": os.cpu_count()},
        "wall_s": time.perf_counter() - wall0,
    }
    return result


# ------------------------------------------------------------------------------------------------
# Plot
# ------------------------------------------------------------------------------------------------


def plot_scaling(result: dict, png_path) -> str:
    """Log-log step time against triangles, one line per configuration, with each fitted
    exponent in the legend; the largest baseline point's memory in the title. Returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5))
    configs = []
    for p in result["points"]:
        key = (p["mesh"], p["tearing"], p["collision"])
        if key not in configs:
            configs.append(key)
    styles = {"square": "-", "tshirt": "--"}
    for key in configs:
        pts = sorted((p for p in result["points"] if (p["mesh"], p["tearing"], p["collision"]) == key),
                     key=lambda p: p["triangles"])
        label = config_label(*key)
        exp = result.get("exponents", {}).get(label)
        ax.plot([p["triangles"] for p in pts], [p["step_ms"] for p in pts], styles.get(key[0], "-"),
                marker="o" if key[2] else "s", label=label + (f"  (p = {exp:.2f})" if exp is not None else ""))
    # slope-1 guide through the first baseline point
    if result["points"]:
        p0 = min(result["points"], key=lambda p: (p["triangles"], p["step_ms"]))
        xs = np.array([p0["triangles"], max(p["triangles"] for p in result["points"])], dtype=float)
        ax.plot(xs, p0["step_ms"] * xs / xs[0], ":", color="grey", label="linear (p = 1)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("triangles")
    ax.set_ylabel("step time, median (ms)")
    peak = result.get("peak_mb_100k")
    title = "Tear Cloth: step time against mesh size"
    if peak is not None and math.isfinite(peak):
        title += (f"\npeak {peak:.0f} MB at {result.get('peak_mb_100k_triangles')} triangles "
                  f"({result.get('exponent_of')})")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    path = str(png_path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def format_scaling(result: dict) -> str:
    def ms(x):
        return f"{x:9.2f}" if x is not None else f"{'-':>9}"

    rows = [f"{'configuration':<45} {'tris':>7} {'step ms':>9} {'CPU ms':>9} {'FEM ms':>9} {'tear ms':>9} "
            f"{'coll ms':>9} {'CG it':>6} {'peak MB':>8} {'B/tri':>7} {'steps':>5} {'unconv':>6}"]
    for p in result["points"]:
        rows.append(f"{config_label(p['mesh'], p['tearing'], p['collision']):<45} {p['triangles']:>7} "
                    f"{ms(p['step_ms'])} {ms(p.get('step_cpu_ms'))} {ms(p.get('fem_ms'))} "
                    f"{ms(p.get('tearing_ms'))} {ms(p.get('collision_ms'))} "
                    f"{p['cg_iterations_median'] or 0:>6.0f} {p['peak_mb']:>8.1f} {p['bytes_per_triangle']:>7.0f} "
                    f"{p['steps']:>5} {p.get('unconverged_steps', 0):>6}"
                    + (f"  ERROR {p['error']}" if p.get("error") else ""))
    for label, e in result["exponents"].items():
        e_cpu = result.get("exponents_cpu", {}).get(label, float("nan"))
        rows.append(f"exponent {label}: {e:.3f} (wall), {e_cpu:.3f} (CPU)")
    rows.append(f"exponent fitted on the converged points {result.get('exponent_sizes')} "
                f"(left out: {result.get('excluded') or 'none'}); unconverged steps {result.get('unconverged_steps')}")
    rows.append(f"peak at {result['peak_mb_100k_triangles']} triangles ({result['exponent_of']}): "
                f"{result['peak_mb_100k']:.1f} MB over the RSS before the cloth "
                f"({result.get('bytes_per_triangle_100k', float('nan')):.0f} B/triangle); "
                f"idle baseline {result['baseline_mb']:.1f} MB")
    return "\n".join(rows)


def _main(argv) -> int:
    if argv[:1] == ["--idle"]:
        print(json.dumps(_child_idle()))
        return 0
    if argv[:1] == ["--point"] and len(argv) == 2:
        print(json.dumps(_child_point(json.loads(argv[1]))))
        return 0
    res = scaling(out=print)
    print(format_scaling(res))
    if argv:
        Path(argv[0]).write_text(json.dumps(res, indent=2))
        plot_scaling(res, str(Path(argv[0]).with_suffix(".png")))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
