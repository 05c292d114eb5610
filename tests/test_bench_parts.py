"""The scaling bench and the race against Blender's cloth (issue 8): they run on tiny inputs and
return the documented keys with finite positive values; the exponent fit and the mapping of our
material onto Blender's units are right. Nothing here asserts a speed."""
import math

import numpy as np
import pytest

from tearcloth.bench import scaling as bs
from tearcloth.bench.race import blender_cloth_settings, hand_offsets, mean_edge_length
from tearcloth.materials import material
from tearcloth.session import CollisionSettings


def _finite_positive(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


# ---- exponent fit ------------------------------------------------------------------------------


def test_fit_exponent_exact_on_power_laws():
    n = np.array([1e3, 3e3, 1e4, 3e4, 1e5])
    assert bs.fit_exponent(n, 0.002 * n**2) == pytest.approx(2.0, abs=1e-12)
    assert bs.fit_exponent(n, 7.0 * n) == pytest.approx(1.0, abs=1e-12)
    assert bs.fit_exponent(n, 5.0 * n**1.5) == pytest.approx(1.5, abs=1e-12)
    # least squares, not end points: a symmetric wobble around n**2 leaves the slope at 2
    wobble = np.array([1.1, 1 / 1.1, 1.0, 1.1, 1 / 1.1])
    assert bs.fit_exponent(n, n**2 * wobble) == pytest.approx(2.0, abs=0.05)


def test_fit_exponent_ignores_failed_points_and_needs_two_sizes():
    assert bs.fit_exponent([1e3, 1e4, 1e5], [1.0, float("nan"), 100.0]) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        bs.fit_exponent([1e3], [1.0])
    with pytest.raises(ValueError):
        bs.fit_exponent([1e3, 1e3], [1.0, 2.0])


def test_base_and_levels_reach_the_targets():
    for target in (1e3, 3e3, 1e4, 3e4, 1e5):
        base, levels = bs.base_and_levels(target)
        assert 1000 <= base < 4000
        assert base * 4**levels == pytest.approx(target, rel=0.002)
    assert bs.base_and_levels(500) == (500, 0)


def test_icosphere_is_closed_and_outward():
    v, t = bs.icosphere(0.2, (0.0, 0.0, 1.0), 2)
    assert len(t) == 20 * 4**2
    assert len(v) - 3 * len(t) // 2 + len(t) == 2  # Euler characteristic of a sphere
    a, b, c = v[t[:, 0]] - (0, 0, 1), v[t[:, 1]] - (0, 0, 1), v[t[:, 2]] - (0, 0, 1)
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    assert volume == pytest.approx(4 / 3 * math.pi * 0.2**3, rel=0.05)


@pytest.mark.parametrize("family", bs.FAMILIES)
def test_scenes_hands_pull_apart_and_body_stays_clear(family):
    sc = bs.make_scene(family, 500)
    v = sc["vertices"]
    a, b = v[sc["hand_a"] > 0.5], v[sc["hand_b"] > 0.5]
    assert len(a) and len(b)
    assert a[:, 0].mean() < 0 < b[:, 0].mean()  # hand_a moves to -X, hand_b to +X: apart
    assert len(sc["body_triangles"]) > 0


# ---- scaling on tiny inputs --------------------------------------------------------------------


@pytest.mark.core_only  # the native core and numpy only: the 3.11 half runs it (conftest.py)
def test_scaling_tiny_runs_every_configuration(tmp_path):
    r = bs.scaling(triangle_targets=(500, 2000), families=("square",), steps=3)
    assert len(r["points"]) == 2 * 2 * 2
    for p in r["points"]:
        for key in ("triangles", "tearing", "collision", "step_ms", "peak_mb", "bytes_per_triangle"):
            assert key in p
        assert p["error"] is None
        assert _finite_positive(p["step_ms"]) and _finite_positive(p["step_cpu_ms"])
        assert p["peak_mb"] >= 0 and math.isfinite(p["peak_mb"])
        assert p["bytes_per_triangle"] >= 0 and math.isfinite(p["bytes_per_triangle"])
    every = {(a, b) for a in (False, True) for b in (False, True)}
    assert {(p["tearing"], p["collision"]) for p in r["points"]} == every
    # collision adds the detector (clusters, Embree scenes): it cannot take less memory than none
    by = {(p["triangles"], p["tearing"], p["collision"]): p for p in r["points"]}
    big = max(p["triangles"] for p in r["points"])
    assert by[(big, False, True)]["peak_mb"] > by[(big, False, False)]["peak_mb"]
    assert math.isfinite(r["exponent"]) and len(r["exponents"]) == 4
    assert all(math.isfinite(e) for e in r["exponents"].values())
    assert all(math.isfinite(e) for e in r["exponents_cpu"].values())
    assert math.isfinite(r["peak_mb_100k"]) and r["peak_mb_100k_triangles"] == big
    assert _finite_positive(r["baseline_mb"])
    png = bs.plot_scaling(r, tmp_path / "scaling.png")
    assert (tmp_path / "scaling.png").stat().st_size > 1000 and png.endswith(".png")
    assert "exponent" in bs.format_scaling(r)


# ---- Blender mapping and race ------------------------------------------------------------------


def _flat_grid(n=6, h=0.02):
    xs, ys = np.meshgrid(np.arange(n) * h, np.arange(n) * h)
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)
    t = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            t += [(a, a + 1, a + n + 1), (a, a + n + 1, a + n)]
    return v, np.array(t)


def test_blender_mapping_follows_the_documented_formulas():
    v, t = _flat_grid()
    mat = material("cotton")
    s = blender_cloth_settings(mat, v, t, fps=25, substeps=7, collision=CollisionSettings(friction=0.4))
    L = mean_edge_length(v, t)
    cloth = s["cloth"]
    assert cloth["quality"] == 7
    assert cloth["mass"] * len(v) == pytest.approx(mat.areal_mass * 0.1 * 0.1)  # total mass kept
    k = math.sqrt(3) / 2 * mat.young * mat.thickness
    assert cloth["tension_stiffness"] == pytest.approx(k * L / 25**2)
    assert cloth["compression_stiffness"] == cloth["tension_stiffness"]
    assert cloth["bending_stiffness"] == pytest.approx(40 * mat.bending / (L * L * 25**2))
    assert s["scene"]["gravity"][2] * 0.001 == pytest.approx(-9.81 / 25**2)
    assert s["collision"]["distance_min"] + s["body_collision"]["thickness_outer"] == pytest.approx(0.002)
    assert s["body_collision"]["cloth_friction"] == pytest.approx(40.0)
    assert s["collision"]["use_self_collision"] is True
    left, right = hand_offsets(0.5, 0.1)
    assert left[0] == pytest.approx(0.05) and right[0] == pytest.approx(-0.05)


def test_blender_gravity_mapping_gives_a_free_fall_at_9_81():
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    fps = 24
    scene = bpy.context.scene
    scene.render.fps = fps
    v, t = _flat_grid(3, 0.05)
    s = blender_cloth_settings(material("cotton"), v, t, fps=fps, substeps=5)
    scene.gravity = s["scene"]["gravity"]
    me = bpy.data.meshes.new("drop")
    me.from_pydata(v.tolist(), [], t.tolist())
    ob = bpy.data.objects.new("drop", me)
    scene.collection.objects.link(ob)
    cm = ob.modifiers.new("Cloth", "CLOTH")
    cm.settings.air_damping = 0.0
    cm.collision_settings.use_collision = False
    for f in range(1, fps + 2):  # one second
        scene.frame_set(f)
    dg = bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(dg)
    z = np.mean([p.co.z for p in ev.to_mesh().vertices])
    ev.to_mesh_clear()
    assert -z == pytest.approx(0.5 * 9.81, rel=0.03)


def test_race_tiny_returns_the_documented_keys():
    pytest.importorskip("bpy")
    from tearcloth.bench.race import format_race, race_blender_cloth

    r = race_blender_cloth(frames=2, substeps=3, target_triangles=600)
    assert r["ours_error"] is None and r["frames_raced"] == 2
    for key in ("ours_s_per_frame", "blender_s_per_frame", "ratio", "blender_replay_s_per_frame"):
        assert _finite_positive(r[key]), key
    assert r["ratio"] == pytest.approx(r["ours_s_per_frame"] / r["blender_s_per_frame"])
    bl = r["settings"]["blender"]
    assert bl["cloth"]["quality"] == 3
    assert bl["collision"]["use_self_collision"] is True
    assert bl["cloth"]["vertex_group_mass"] == "pin"
    assert r["settings"]["ours"]["tearing"] is True
    # Blender's armature reproduces body_pose (float32 round-off), and its cloth really moved
    assert r["body_pose_error_m"] < 1e-4
    assert r["blender_shirt_moved_m"] > 0
    assert len(r["ours_per_frame_s"]) == len(r["blender_per_frame_s"]) == 2
    assert "ratio" in format_race(r)


# ---- Table I's "after" column (issue 13) -------------------------------------------------------

@pytest.mark.core_only  # the native core and numpy only: the 3.11 half runs it (conftest.py)
def test_table1_after_column_times_steps_with_a_tip_running():
    """The bench times only steps that begin with a tip running, counts them, and refuses to report
    a column where the tip did not run (measure_scenario raises)."""
    from tearcloth.bench.table1 import measure_scenario

    r = measure_scenario("cloth", steps=40)
    assert r["tearing_after_steps"] >= 20 and r["tips_running"] >= 1
    assert r["tearing_after_cuts"] >= 0 and _finite_positive(r["tearing_after_ms"])
    assert r["tearing_after_max_ms"] >= r["tearing_after_ms"]


def test_scaling_fits_converged_points_only_and_reports_memory_precisely(monkeypatch):
    """Issue 14: a point with a step accepted unconverged is left out of the exponent (and
    counted); every point says how its memory was measured and its per-step CG iterations."""
    real = bs._run_child

    def flagged(args, timeout):
        res = real(args, timeout)
        if args[0] == "--point" and "_1200" in args[1]:
            res["unconverged_steps"] = 1  # as if the core had accepted one solve short of its tolerance
        return res

    monkeypatch.setattr(bs, "_run_child", flagged)
    r = bs.scaling(triangle_targets=(300, 600, 1200), families=("square",), with_tearing=(False,),
                   with_collision=(False,), steps=2, warmup=1)
    tris = [p["triangles"] for p in r["points"]]
    big = max(tris)
    assert r["excluded"] == [big] and sorted(r["exponent_sizes"]) == sorted(t for t in tris if t != big)
    assert r["unconverged_steps"] == 1 and r["unconverged_steps_by_size"][str(big)] == 1
    kept = [p for p in r["points"] if p["triangles"] != big]
    assert r["exponent"] == pytest.approx(bs.fit_exponent([p["triangles"] for p in kept], [p["step_ms"] for p in kept]))
    assert [row["triangles"] for row in r["per_size"]] == tris
    for p in r["points"]:
        assert len(p["cg_iterations"]) == p["steps"] == 2 and p["preconditioner"] == "sgs"
        # the short window was replayed from its snapshot, the same steps (same CG iterations), and
        # the medians are over every replay: ~1 ms of steps is too few to time on its own
        assert p["replays"] >= 1 and p["replay_exact"] is True
        assert p["timed_steps"] == p["steps"] * (1 + p["replays"])
        assert p["memory_method"] == "peak minus RSS before the cloth"
        # the peak over the RSS before the cloth, in the same process: below the absolute peak by
        # at least the interpreter, numpy and the core (tens of MB)
        assert 0 < p["peak_mb"] < p["peak_rss_mb"] - 20 and p["rss_before_mb"] > 20
        assert p["bytes_per_triangle"] == pytest.approx(p["peak_mb"] * 2**20 / p["triangles"])
    assert "bytes_per_triangle_100k" in r and "VmRSS just before the cloth" in r["settings"]["memory"]


@pytest.mark.core_only  # the native core and numpy only: the 3.11 half runs it (conftest.py)
def test_a_simulated_shirt_that_blows_up_ends_its_run_and_says_so(monkeypatch):
    """The collision experiment's simulated shirt: a step the core rolls back even at its finest
    sub-steps ends the run where it is (the frame10 scene blew up at its step ~100 in 2026-12), and
    the bench keeps the steps before it and the error instead of failing as a whole."""
    from tearcloth.bench import collision as bc
    from tearcloth.cloth import SimulationError
    from tearcloth.session import Session

    calls = {"n": 0}
    real = Session.step

    def step(self, dt):
        calls["n"] += 1
        if calls["n"] == 8:  # as a real blow-up: detected first, then the cloth's step rolls back
            self.detector.detect(self.cloth.positions, self.cloth.triangles, self.cloth.velocities, dt)
            raise SimulationError("step rolled back: exploding strain (test)")
        return real(self, dt)

    monkeypatch.setattr(Session, "step", step)
    body, shirt, rec, ms, share, tears = bc.simulate_worn_shirt(1 / 240, 20, True, settle_s=1 / 240)
    assert len(rec) == len(ms) == len(share) == 6  # steps 2..7 recorded; the 8th rolled back, dropped
    assert bc.LAST_STOP["step"] == 6 and bc.LAST_STOP["of"] == 20 and "exploding" in bc.LAST_STOP["error"]
    calls["n"] = -10**9  # a run that completes leaves no stop behind
    bc.simulate_worn_shirt(1 / 240, 3, False, settle_s=1 / 240)
    assert bc.LAST_STOP == {}


@pytest.mark.core_only
def test_the_walking_case_carries_the_shirt_forward():
    """The collision experiment's 'walking' motion (issue 15: the paper's moving character): the
    root accelerates uniformly to WALK_SPEED over WALK_RAMP_S (no jump in position or speed), the
    recording starts at that speed, and the simulated shirt goes along with the body."""
    from tearcloth.bench import collision as bc

    r = bc.WALK_RAMP_S
    assert np.allclose(bc.root_travel(0.0), 0.0)
    h = 1e-6
    speed = lambda t: -(bc.root_travel(t + h)[1] - bc.root_travel(t - h)[1]) / (2 * h)  # noqa: E731
    assert speed(r - 1e-3) == pytest.approx(bc.WALK_SPEED, rel=1e-2) and speed(r + 0.5) == pytest.approx(bc.WALK_SPEED)
    assert bc.MOTIONS["walking"] == (True, True) and bc.MOTIONS["moving"] == (True, False)
    dt = 1 / 240
    body, shirt, rec, ms, share, tears = bc.simulate_worn_shirt(dt, 6, True, settle_s=dt, travel=True)
    assert len(rec) == 6
    body_y = [fr.body[:, 1].mean() for fr in rec]
    cloth_y = [fr.cloth[:, 1].mean() for fr in rec]
    # keyed once per 24 fps frame and interpolated: the body moves at the walking speed
    assert (body_y[0] - body_y[-1]) / (5 * dt) == pytest.approx(bc.WALK_SPEED, rel=0.1)
    assert (cloth_y[0] - cloth_y[-1]) / (5 * dt) == pytest.approx(bc.WALK_SPEED, rel=0.3)
