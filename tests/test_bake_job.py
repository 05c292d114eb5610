"""The bpy-free bake job (``tearcloth.bake``), the Session's step listeners it is built on, its one
progress reporter, and the `tearcloth` argparse tree's checks that run before Blender would start.
No Blender here: a plan is made by hand, as ``blender/inputs.py`` would make it from a scene."""
import io
import subprocess
import sys

import numpy as np
import pytest

from meshes import sheet
from tearcloth import cli
from tearcloth.bake import BakeJob, BakePlan, FrameInputs, Progress, ProgressLine, duration, make_session
from tearcloth.cloth import Cloth, SimulationError
from tearcloth.materials import material
from tearcloth.session import Session

pytest.importorskip("pxr")  # the job writes a USD cache

STEPS = 4


def plan_for(tmp_path, frames=(1, 4)) -> BakePlan:
    """A 10 x 10 cm sheet pinned along one edge and pulled by a handle on the other, in SI."""
    v, t = sheet(0.1, 0.1, 11, 11)
    pin = (v[:, 0] < 1e-9).astype(np.float64)
    pull = (v[:, 0] > 0.1 - 1e-9).astype(np.float64)
    return BakePlan(
        object_name="Sheet", prim_name="Sheet", cache_path=str(tmp_path / "Sheet.usda"), fps=24.0,
        frame_start=frames[0], frame_end=frames[1], steps_per_frame=STEPS, scale=1.0,
        material=material("cotton"), solver={"gravity": (0.0, 0.0, -9.81)}, tearing={"enabled": True},
        collision=None, vertices=v, triangles=t, corner_uv=None, groups={"pin": pin, "pull": pull},
        fingerprint="test", pin_group="pin", handle_groups=["pull"])


def inputs(frame: int, plan: BakePlan) -> FrameInputs:
    """The follow object of the handle moves 1 cm along x per frame."""
    follow = np.eye(4)
    follow[0, 3] = 0.01 * (frame - plan.frame_start)
    return FrameInputs(frame, np.eye(4), [follow], {})


def bake(plan: BakePlan, on_event=None) -> BakeJob:
    job = BakeJob(plan, on_event=on_event)
    job.begin(inputs(plan.frame_start, plan))
    while not job.done:
        assert job.advance(inputs(job.next_frame, plan))
    job.close()
    return job


def test_events_come_in_order_and_listening_changes_nothing(tmp_path):
    plan = plan_for(tmp_path / "a")
    (tmp_path / "a").mkdir()
    events = []
    job = bake(plan, lambda e: events.append((e.kind, e.frame, None if e.report is None else e.job.session.time)))
    quiet = plan_for(tmp_path / "b")
    (tmp_path / "b").mkdir()
    silent = bake(quiet)
    assert np.array_equal(job.session.cloth.positions, silent.session.cloth.positions)  # bit for bit
    kinds = [k for k, _, _ in events]
    assert kinds[:2] == ["begin", "frame"] and events[0][1] == events[1][1] == plan.frame_start
    frames = [f for k, f, _ in events if k == "frame"]
    assert frames == list(range(plan.frame_start, plan.frame_end + 1))
    steps = [t for k, _, t in events if k == "step"]
    assert len(steps) == STEPS * (plan.frame_end - plan.frame_start)
    # every step event sees the session at the end of that step, and each frame's steps come before it
    assert np.allclose(steps, plan.dt * np.arange(1, len(steps) + 1))
    assert kinds[-1] == "frame" and kinds[2:2 + STEPS] == ["step"] * STEPS and kinds[2 + STEPS] == "frame"
    assert job.progress.steps == len(steps) and job.progress.frame == plan.frame_end
    assert job.handles == [0]


def test_session_step_listeners_run_in_order_and_can_be_removed():
    v, t = sheet(0.05, 0.05, 6, 6)
    calls = []
    first = lambda s, rep: calls.append(("first", s.time))
    session = Session(Cloth(v, t, material("cotton")), on_step=first)
    session.add_step_listener(lambda s, rep: calls.append(("second", rep.total_s >= 0.0)))
    session.step(1e-3)
    assert calls == [("first", pytest.approx(1e-3)), ("second", True)]
    session.remove_step_listener(first)
    session.step(1e-3)
    assert calls[2:] == [("second", True)]
    with pytest.raises(ValueError):
        session.remove_step_listener(first)


def test_make_session_holds_handles_still_at_the_grasp(tmp_path):
    plan = plan_for(tmp_path)
    session, handles = make_session(plan, {}, 0.0)
    before = np.array(session.cloth.positions)
    session.step(plan.dt)
    pulled = plan.groups["pull"] >= 0.5
    assert handles == [0] and np.abs(session.cloth.positions[pulled] - before[pulled]).max() < 1e-9


def test_resume_continues_where_the_first_run_stopped(tmp_path):
    """A bake stopped after frame 2 and resumed writes frames 3-4 into the same cache, from the
    saved state (no UV map: the resumed frames have none either), and ends bit for bit where the
    bake run in one go ends: the state is the whole session's (native snapshot, keyframes)."""
    (tmp_path / "whole").mkdir()
    whole = plan_for(tmp_path / "whole", (1, 4))
    straight = bake(whole)
    (tmp_path / "parts").mkdir()
    first = plan_for(tmp_path / "parts", (1, 2))
    bake(first)
    # a run killed while it wrote its state (SIGKILL between the temporary's write and its rename)
    # leaves the temporary: the resumed bake clears it (a fresh-clone CI run found one left)
    killed_temp = tmp_path / "parts" / ".tmp-99999-Sheet.state.npz"
    killed_temp.write_bytes(b"half a state")
    rest = plan_for(tmp_path / "parts", (1, 4))
    rest.resume = True
    resumed = BakeJob(rest)
    assert resumed.start_frame == 2 and resumed.next_frame == 3
    resumed.begin(inputs(2, rest))
    while not resumed.done:
        resumed.advance(inputs(resumed.next_frame, rest))
    resumed.close()
    assert resumed.writer.frames == [1, 2, 3, 4]
    assert not killed_temp.exists()
    for name in ("positions", "velocities", "triangles", "rest_positions"):
        assert np.array_equal(getattr(straight.session.cloth, name), getattr(resumed.session.cloth, name)), name
    assert straight.session.time == resumed.session.time
    # the bake reads the core's fallback counters after each frame's steps: none here
    assert straight.progress.preconditioner_fallbacks == 0 and straight.progress.fallback_text() is None


def test_progress_line_prints_every_tenth_to_a_pipe():
    p = Progress("Sheet", 1, 11)
    out = io.StringIO()
    line = ProgressLine(out)
    for frame in range(1, 12):
        p.frame = frame
        line.update(p, 1, 2)
    line.update(p, 1, 2, final=True)
    lines = out.getvalue().splitlines()
    assert len(lines) == 11 and lines[0].startswith("[------------------------] 1/2 Sheet: frame 1/11")
    assert lines[-1].startswith("[########################] 1/2 Sheet: frame 11/11") and "ETA" in lines[-1]
    assert p.text().startswith("Sheet: frame 11/11, 0 steps/s, 0 tears")
    assert p.fallback_text() is None
    p.preconditioner_fallbacks = 3
    assert p.fallback_text().startswith("3 solves fell back from the chosen preconditioner to block Jacobi")
    p.preconditioner_fallbacks, p.swept_thread_fallbacks = 0, 1
    assert p.fallback_text().startswith("1 collision step ran the self-collision sweep on the baking thread")
    p.preconditioner_fallbacks = 2
    both = p.fallback_text()  # both, one after the other
    assert both.startswith("2 solves fell back") and both.endswith("1 collision step ran the self-collision sweep on "
                                                                    "the baking thread because the system would not "
                                                                    "start another (its thread limit): same result, slower")
    # removed small pieces: said at the end; a warning once they took a quarter of the cloth's area
    assert p.fragment_text() is None
    p.fragments_removed, p.fragment_triangles_removed, p.start_triangles, p.min_fragment_area = 2, 3, 100, 1e-4
    p.start_area, p.fragment_area_removed = 0.25, 0.0005
    assert p.fragment_text() == ("2 small pieces set free by tears (3 triangles) removed, each below Min Fragment "
                                 "(1 cm^2), 0.2 % of the cloth's area", False)
    # many triangles, little area (an n-gon's fan of slivers shed 222 of 510 triangles, 0.18 % of the
    # disc, and was told the cloth was small against Min Fragment): no warning
    p.fragment_triangles_removed = 60
    assert not p.fragment_text()[1]
    p.fragment_area_removed = 0.0625
    text, warn = p.fragment_text()
    assert warn and text.endswith("(60 triangles) removed, each below Min Fragment (1 cm^2), 25 % of the cloth's area: "
                                  "the cloth is small against Min Fragment; lower it (0 keeps every piece)")
    assert [duration(s) for s in (None, float("inf"), 42.4, 187, 3900)] == ["?", "?", "42 s", "3 min 07 s",
                                                                           "1 h 05 min"]


def test_one_tree_one_error_line_before_blender(tmp_path, capsys):
    assert cli.main(["bench", "--steps", "3"]) == 2
    assert cli.main(["clusters", "--cluster-size", "2"]) == 2
    assert cli.main(["bake", str(tmp_path / "nowhere.blend")]) == 2
    assert cli.main(["bake", str(tmp_path), "--fast"]) == 2
    assert cli.main([]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == ["tearcloth bench: error: --steps must be at least 10",
                   "tearcloth clusters: error: --cluster-size must be at least 4",
                   f"tearcloth bake: error: {tmp_path / 'nowhere.blend'}: no such file",
                   "tearcloth bake: error: unrecognized arguments: --fast",
                   "tearcloth: error: the following arguments are required: {bake,demo,bench,clusters,farm}"]
    # a refused bake never starts Blender
    code = ("import sys; from tearcloth.cli import main; rc = main(['bake', sys.argv[1], '--frames', '9-1']); "
            "assert rc == 2 and 'bpy' not in sys.modules, (rc, 'bpy' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_help_lists_every_sub_command(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in ("bake", "demo", "bench", "clusters"):
        assert f"\n    {command} " in out


def test_eta_follows_the_recent_frames():
    """Frames at 0.1 s each, then 0.3 s each once 'a tear started' (the banknote: ~690 -> ~230
    steps/s): the ETA at frame 12 of 20 is 8 frames at the recent pace, not at the average."""
    now = [0.0]
    p = Progress("Banknote", 1, 20, clock=lambda: now[0])
    for frame in range(1, 13):
        now[0] += 0.1 if frame <= 6 else 0.3
        p.frame_done(frame)
    assert p.eta_seconds == pytest.approx(8 * 0.3)
    average = (now[0] / (12 - 1)) * 8
    assert average < 0.8 * p.eta_seconds  # what a whole-run average would have promised
    assert "ETA 2 s" in p.text()


@pytest.mark.parametrize("groups", [["pin"], ["pin", "pull"]])  # one group came back flat from the core
def test_the_saved_state_rebuilds_the_cloth_exactly(tmp_path, groups):
    """What the resume state carries comes back bit for bit in a torn cloth: positions,
    velocities, rest shape, triangles, UVs, vertex-group weights, tear strengths, and the rest
    of the core's state: the restored session steps on exactly as the saved one."""
    from tearcloth.bake import load_state, save_state_file

    plan = plan_for(tmp_path)
    plan.groups = {g: plan.groups[g] for g in groups}
    plan.handle_groups = ["pull"] if "pull" in groups else []
    plan.corner_uv = np.random.default_rng(1).random((len(plan.triangles), 3, 2))
    plan.seam_group, plan.seam_factor = "pin", 0.5
    session, _ = make_session(plan, {}, 0.0)
    cloth = session.cloth
    for _ in range(3):
        session.step(plan.dt)
    cloth.scripted_tear(60, (0.0, 1.0, 0.0), 0.03)
    session.step(plan.dt)
    assert cloth.num_vertices > len(plan.vertices)  # torn
    path = str(tmp_path / "Sheet.state.npz")
    save_state_file(path, 3, plan, session, 1, True, [np.eye(4)] * len(plan.handle_groups))
    state = load_state(path)
    again, _ = make_session(plan, {}, 0.0, state)
    assert again.time == session.time
    for _ in range(3):
        session.step(plan.dt)
        again.step(plan.dt)
    for name in ("positions", "velocities", "rest_positions", "triangles", "corner_uv", "groups", "tear_strength"):
        assert np.array_equal(getattr(again.cloth, name), getattr(cloth, name)), name
    # the user's groups, then the columns the cache's attributes ride in (tearcloth.attributes)
    from tearcloth.attributes import REST_GROUPS
    assert again.cloth.group_names == cloth.group_names == groups + list(REST_GROUPS)


def test_a_bake_of_a_mesh_with_slivers_says_so_naming_the_thinnest_polygon(tmp_path):
    """The solver converges on slivers (stiff groups) but more slowly than on a well-shaped mesh:
    the end of the bake says so, with the thinnest corner and the user's polygon holding it; a
    well-shaped sheet's bake says nothing."""
    from meshes import sliver_sheet

    from tearcloth.cloth import smallest_angles_deg

    v, t = sliver_sheet()
    top = (v[:, 1] > v[:, 1].max() - 1e-9).astype(np.float64)
    polygons = np.arange(len(t), dtype=np.int32) // 2 + 100  # two triangles a quad, numbered from 100
    plan = BakePlan(
        object_name="Slivers", prim_name="Slivers", cache_path=str(tmp_path / "Slivers.usda"), fps=24.0,
        frame_start=1, frame_end=2, steps_per_frame=4, scale=1.0, material=material("cotton"),
        solver={"gravity": (0.0, 0.0, -9.81)}, tearing={"enabled": False}, collision=None, vertices=v,
        triangles=t, corner_uv=None, groups={"top": top}, fingerprint="test", pin_group="top",
        triangle_polygons=polygons)
    job = BakeJob(plan)
    job.begin(FrameInputs(1, np.eye(4), [], {}))
    while not job.done:
        assert job.advance(FrameInputs(job.next_frame, np.eye(4), [], {}))
    job.close()
    p = job.progress
    assert p.stiff_groups > 0 and p.convergence_text() is None
    k = int(np.argmin(smallest_angles_deg(v, t)))
    text = p.sliver_text()
    assert text.startswith("the mesh has sliver triangles (the thinnest has a 0.23 degree corner, in polygon "
                           f"{polygons[k]}): the solver took {p.stiff_groups} groups of their corners together")
    (tmp_path / "w").mkdir()
    assert bake(plan_for(tmp_path / "w")).progress.sliver_text() is None
    # stiff groups on a mesh with no sliver of its own (made by tears, or a stiff material): the
    # text does not send the user to remesh a well-shaped mesh
    p.thinnest_angle_deg, p.thinnest_polygon = 45.0, 7
    text = p.sliver_text()
    assert "the mesh you made has none" in text and "polygon" not in text and "remesh" not in text.lower(), text


def test_a_grained_material_on_faces_without_a_warp_is_said_naming_their_polygons(tmp_path):
    """Denim's warp follows the UV map's u: faces collapsed in the UV map, or a mesh with no UV map,
    give it none, and the warp runs along world X there. The end of the bake says so, naming the
    user's polygons (or the missing map); cotton (no grain) and a whole UV map say nothing."""
    def begun(name, mat, corner_uv):
        plan = plan_for(tmp_path / name, frames=(1, 2))
        plan.material, plan.corner_uv = mat, corner_uv
        plan.triangle_polygons = np.arange(len(plan.triangles), dtype=np.int32) // 2 + 100  # quads from 100
        job = BakeJob(plan)
        job.begin(inputs(1, plan))
        assert job.advance(inputs(2, plan))
        job.close()
        return job.progress

    v, t = sheet(0.1, 0.1, 11, 11)
    uv = v[t][:, :, :2] * 10.0
    assert begun("whole", material("denim"), uv).warp_text() is None
    assert begun("cotton", material("cotton"), None).warp_text() is None
    holes = uv.copy()
    holes[[6, 7, 30]] = 0.25  # the two triangles of polygon 103 and one of 115 collapsed to a point
    p = begun("holes", material("denim"), holes)
    assert p.warp_fallback_triangles == 3 and p.warp_fallback_polygons == [103, 115]
    assert p.warp_text() == (
        "3 triangles (polygons 103, 115) are collapsed in the UV map, so denim's warp runs along the world X axis "
        "there instead of the UV map's u: unwrap the mesh (UV > Unwrap) so its threads follow the pattern pieces, "
        "or give those faces room in the UV map")
    text = begun("none", material("denim"), None).warp_text()
    assert text.startswith("the mesh has no UV map, so denim's warp runs along the world X axis"), text


def test_a_swept_stage_without_its_thread_is_said_at_the_end_of_the_bake(tmp_path, monkeypatch):
    """A bake with self-collision whose detector could not start the swept stage's thread (the
    system's thread limit; forced here by reporting every step as run without it): the bake counts
    those steps from the detector and says so at the end - same result, slower - never silently."""
    from dataclasses import replace

    from tearcloth.collision import detector as det_mod
    from tearcloth.collision.swept import SweptSelf
    from tearcloth.session import CollisionSettings

    monkeypatch.setattr(det_mod, "usable_cpus", lambda: 2)  # the stage gets its thread
    real = SweptSelf.finish

    def without_thread(self, job):
        seconds, _, live = real(self, job)
        return seconds, False, live

    monkeypatch.setattr(SweptSelf, "finish", without_thread)
    plan = replace(plan_for(tmp_path, (1, 2)), collision=CollisionSettings())
    job = bake(plan)
    assert job.progress.swept_thread_fallbacks == STEPS  # every collision step from frame 1 to 2
    assert f"{STEPS} collision steps ran the self-collision sweep on the baking thread" in job.progress.fallback_text()


def moving_inputs(frame: int, plan: BakePlan) -> FrameInputs:
    """The cloth object (say, parented to a walking character) carried from frame 2: 2 cm along y
    and 4 degrees about z per frame, about the world's origin, and the handle's follow object
    with it (parented to the same character): the sheet is carried, not pulled."""
    base = inputs(frame, plan)
    k = max(0, frame - 2)
    a = np.radians(4.0 * k)
    obj = np.eye(4)
    obj[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    obj[1, 3] = 0.02 * k
    return FrameInputs(frame, obj, [obj], base.bodies)


def bake_with(plan: BakePlan, frame_inputs, stop: int | None = None) -> BakeJob:
    job = BakeJob(plan)
    job.begin(frame_inputs(job.start_frame, plan))
    while not job.done and (stop is None or job.next_frame <= stop):
        assert job.advance(frame_inputs(job.next_frame, plan))
    job.close()
    return job


def world_pins(patch) -> None:
    """The build before pins followed the object: a session that follows no mesh (its state then
    holds none, as a state of that build)."""
    patch.setattr(Session, "follow_pins", lambda self, rest, triangles: None)
    patch.setattr(Session, "set_pin_keyframe", lambda self, vertices, t: None)


def test_pinned_vertices_move_with_the_object(tmp_path, monkeypatch):
    """Pins hold their vertices on the object, as Blender's cloth pins do: a cloth object carried
    along (its transform or a parent's) carries its pinned vertices, which the cache then holds
    still in the object's space. A still object's pins step bit for bit as world pins did."""
    (tmp_path / "still").mkdir()
    still = bake(plan_for(tmp_path / "still"))
    (tmp_path / "world").mkdir()
    with monkeypatch.context() as m:
        world_pins(m)  # the pins as they were: in the world
        world = bake(plan_for(tmp_path / "world"))
    for name in ("positions", "velocities", "triangles"):
        assert np.array_equal(getattr(still.session.cloth, name), getattr(world.session.cloth, name)), name
    assert still.progress.pins_text() is None

    (tmp_path / "moving").mkdir()
    plan = plan_for(tmp_path / "moving", (1, 6))
    job = bake_with(plan, moving_inputs)
    pinned = plan.groups["pin"] >= 0.5
    last = moving_inputs(plan.frame_end, plan).object_matrix
    expected = plan.vertices[pinned] @ last[:3, :3].T + last[:3, 3]
    assert np.abs(job.session.cloth.positions[:len(pinned)][pinned] - expected).max() < 1e-9
    # in the cache (float32), in the object's space, the pinned vertices have not moved (BU = m here)
    from tearcloth.cache import read_frame
    for frame in (1, 3, 6):
        local = read_frame(plan.cache_path, frame)[0]
        assert np.abs(local[:len(pinned)][pinned] - plan.vertices[pinned]).max() < 1e-7, frame  # float32
    assert job.progress.pins_text() is None
    # carried along whole: pins and handle move together, nothing pulls the sheet apart
    st = job.session.cloth.stats()
    assert st["tears_started"] == 0 and st["grips_released"] == 0


def test_a_bake_with_following_pins_resumes_exactly(tmp_path):
    """A bake of a moving pinned cloth stopped after frame 3 and resumed ends bit for bit where the
    bake run in one go ends: the mesh the pins follow, its keyframes and the first frame's matrix
    live in the state."""
    (tmp_path / "whole").mkdir()
    straight = bake_with(plan_for(tmp_path / "whole", (1, 6)), moving_inputs)
    (tmp_path / "parts").mkdir()
    bake_with(plan_for(tmp_path / "parts", (1, 6)), moving_inputs, stop=3)
    rest = plan_for(tmp_path / "parts", (1, 6))
    rest.resume = True
    resumed = bake_with(rest, moving_inputs)
    assert resumed.start_frame == 3 and resumed.writer.frames == [1, 2, 3, 4, 5, 6]
    for name in ("positions", "velocities", "triangles"):
        assert np.array_equal(getattr(straight.session.cloth, name), getattr(resumed.session.cloth, name)), name


def test_a_state_from_before_pins_followed_keeps_them_in_the_world_and_says_so(tmp_path, monkeypatch):
    """A bake resumed from a state saved before pins followed the object (its session follows no
    mesh) goes on as it began, pins in the world, and says at the end that the object moved away from
    them, with the frame and what to do."""
    (tmp_path / "old").mkdir()
    with monkeypatch.context() as m:
        world_pins(m)
        bake_with(plan_for(tmp_path / "old", (1, 6)), moving_inputs, stop=2)
    rest = plan_for(tmp_path / "old", (1, 6))
    rest.resume = True
    job = bake_with(rest, moving_inputs)
    assert not job.session.pins_follow  # restored from the state: following nothing
    text = job.progress.pins_text()
    assert job.progress.pins_left_at == 3 and "from frame 3" in text and "bake again" in text, text


def bent_inputs(frame: int, plan: BakePlan) -> FrameInputs:
    """The object stands still, the handle holds still, and the stack above Tear Cloth (say, an
    Armature) bends the pinned edge: from frame 2 its vertices rise by 5 mm per frame times
    (y / 10 cm)^2."""
    source = np.array(plan.vertices)
    source[:, 2] += 0.005 * max(0, frame - 2) * (source[:, 1] / 0.1) ** 2 * (source[:, 0] < 1e-9)
    return FrameInputs(frame, np.eye(4), [np.eye(4)], {}, pin_source=source)


def test_pinned_vertices_follow_the_deformation_above(tmp_path):
    """Pins follow the mesh the stack above Tear Cloth deforms (pin_source of the frame inputs),
    vertex by vertex: at each frame's end every pinned vertex is where that mesh puts it."""
    plan = plan_for(tmp_path, (1, 5))
    job = bake_with(plan, bent_inputs)
    pinned = plan.groups["pin"] >= 0.5
    goal = bent_inputs(plan.frame_end, plan).pin_source[pinned]
    assert np.ptp(goal[:, 2]) > 0.01  # bent, not moved rigidly
    assert job.session.cloth.stats()["grips_released"] == 0
    assert np.abs(job.session.cloth.positions[:len(pinned)][pinned] - goal).max() < 1e-9


def test_a_split_pinned_vertex_follows_its_point_of_the_mesh():
    """A tear's split of two pinned vertices sits at rest on the line between them (native
    remesh.c); its goal is the same point of the moved mesh: the same barycentric weights of the
    same triangle, so an affine motion carries it exactly and a bend by the weights."""
    from tearcloth.session import _PinSource

    v, t = sheet(0.1, 0.1, 3, 3)
    source = _PinSource(v, t, 0.0)
    a, b = 0, 1
    points = np.array([v[a], 0.3 * v[a] + 0.7 * v[b], v[t[2]].mean(axis=0)])
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = v @ rot.T + (0.1, 0.2, 0.3)
    source.add(moved, 1.0)
    key = np.array([a, 100, 101], np.int64)  # the first the cloth was made with, then two made by tears
    goals = source.goals(key, points, 1.0)
    np.testing.assert_allclose(goals, points @ rot.T + (0.1, 0.2, 0.3), atol=1e-15)
    assert source.moved


def test_frame_ranges_read_as_ranges():
    """Negative frames (a bake from before the scene's start) read as a range, not a typo."""
    from tearcloth.bake import frame_span

    assert frame_span(1, 24) == "1-24"
    assert frame_span(-8, -2) == "-8 to -2" and frame_span(-3, 5) == "-3 to 5"


def test_unmerged_vertices_at_one_place_follow_their_own_motion():
    """Two vertices of the mesh at one place (an unmerged seam: each side skinned to its own
    bone) are two pins, each following its own vertex, not whichever the place names last."""
    from tearcloth.session import _PinSource

    v, t = sheet(0.1, 0.1, 3, 3)
    v = np.vstack([v, v[4]])           # vertex 9: a second vertex where vertex 4 is
    t = np.vstack([t, [[9, 5, 8]]])
    source = _PinSource(v, t, 0.0)
    moved = np.array(v)
    moved[4, 0] += 0.01
    moved[9, 0] -= 0.01
    source.add(moved, 1.0)
    pinned = np.array([4, 9])
    np.testing.assert_array_equal(source.goals(pinned, v[pinned], 1.0), moved[pinned])


def test_a_blown_up_bake_gives_one_piece_of_advice_in_the_artists_terms(tmp_path):
    """The core's rollback message advises 'Reduce the time step or raise sub-steps.'; the bake
    added 'Try more steps per frame or a gentler pull' after it: two wordings of one advice. The
    bake keeps the core's diagnosis and gives the advice once, in the panel's terms."""
    plan = plan_for(tmp_path)
    plan.solver["max_stretch"] = 1.5

    def far(frame: int, plan: BakePlan) -> FrameInputs:  # the handle jumps 1 m a frame
        follow = np.eye(4)
        follow[0, 3] = 1.0 * (frame - plan.frame_start)
        return FrameInputs(frame, np.eye(4), [follow], {})

    job = BakeJob(plan)
    job.begin(far(plan.frame_start, plan))
    with pytest.raises(SimulationError) as info:
        while not job.done:
            job.advance(far(job.next_frame, plan))
    message = str(info.value)
    assert "blew up between frames" in message and "exploding strain" in message, message
    assert "Reduce the time step" not in message and message.count("Try more steps per frame") == 1, message
    assert ".)" not in message, message
