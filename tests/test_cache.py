"""The USD bake cache: round trips through value clips, Blender's Mesh Sequence Cache modifier
(PyPI bpy, in a subprocess), crash safety under SIGKILL, resume, and clear errors for bad files."""
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import textwrap
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import tearcloth.cache as cache
from tearcloth.cache import CacheError, CacheOwnerError, CacheWriter

pxr = pytest.importorskip("pxr")
from pxr import Usd, UsdGeom  # noqa: E402

TESTS_DIR = os.path.dirname(os.path.abspath(__file__))
FPS = 24.0


# ---------------------------------------------------------------------------------------------
# A tearing sheet, deterministic per frame: frame k splits the fans of the first k tear vertices
# (each torn vertex gets a twin on its +x side, pulled open by 2 mm) and splits the first k
# triangles at their centroids, so both the vertex and the triangle counts grow every frame,
# like a tear with remeshing. Corner UVs come from the rest sheet, so they stay continuous
# across the tear, as in a real cloth.


def tear_frame(frame, nx=12, ny=8, size=0.3):
    xs, ys = np.meshgrid(np.linspace(0.0, size, nx), np.linspace(0.0, size, ny), indexing="ij")
    rest = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    rest_uv = rest[:, :2] / size
    q = np.arange(nx - 1)[:, None] * ny + np.arange(ny - 1)[None, :]
    a = q.ravel()
    tris = np.concatenate([np.stack([a, a + ny, a + ny + 1], 1), np.stack([a, a + ny + 1, a + 1], 1)])
    corner_uv = rest_uv[tris]
    pos = rest.copy()

    k = min(max(frame, 0), nx * ny // 2)
    tear_vertices = (np.arange(k) * 7) % (nx * ny)  # a fixed, scattered order of torn vertices
    for v in tear_vertices:
        centroid_x = pos[tris].mean(axis=1)[:, 0]
        right = (tris == v).any(axis=1) & (centroid_x > pos[v, 0] + 1e-12)
        if not right.any():
            continue
        tris[right] = np.where(tris[right] == v, len(pos), tris[right])
        pos = np.concatenate([pos, pos[v] + [[0.002, 0.0, 0.0]]])

    s = min(max(frame, 0), len(tris))
    centroids = pos[tris[:s]].mean(axis=1)
    centroid_uv = corner_uv[:s].mean(axis=1)
    p = len(pos) + np.arange(s)
    a, b, c = tris[:s, 0].copy(), tris[:s, 1].copy(), tris[:s, 2].copy()
    uva, uvb, uvc = corner_uv[:s, 0].copy(), corner_uv[:s, 1].copy(), corner_uv[:s, 2].copy()
    tris[:s] = np.stack([a, b, p], 1)
    corner_uv[:s] = np.stack([uva, uvb, centroid_uv], 1)
    tris = np.concatenate([tris, np.stack([b, c, p], 1), np.stack([c, a, p], 1)])
    corner_uv = np.concatenate([corner_uv, np.stack([uvb, uvc, centroid_uv], 1), np.stack([uvc, uva, centroid_uv], 1)])
    pos = np.concatenate([pos, centroids])

    t = frame / FPS
    pos[:, 2] = 0.02 * np.sin(2.0 * np.pi * (pos[:, 0] / size + t))
    vel = np.zeros_like(pos)
    vel[:, 2] = 0.02 * 2.0 * np.pi * np.cos(2.0 * np.pi * (pos[:, 0] / size + t))
    return pos, tris.astype(np.int32), corner_uv, vel


def write_tear_cache(path, frames, **kw):
    with CacheWriter(path, "Cloth", FPS, object_name="Cloth Object", **kw) as w:
        for f in frames:
            w.write_frame(f, *tear_frame(f))
    return w


def assert_frame_equal(got, frame):
    pos, tris, uv, _ = tear_frame(frame)
    g_pos, g_tris, g_uv = got
    assert g_pos.shape == pos.shape and g_tris.shape == tris.shape
    # stored as float32: equal to float32 rounding, which is what Blender holds anyway
    np.testing.assert_array_equal(g_pos, pos.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(g_tris, tris)
    np.testing.assert_array_equal(g_uv, uv.astype(np.float32).astype(np.float64))


# ---------------------------------------------------------------------------------------------
# Blender, in a subprocess: a bpy crash cannot take pytest down and no bpy state leaks.

BLENDER_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import bpy

    jobs, frames, out = json.loads(sys.argv[1]), json.loads(sys.argv[2]), sys.argv[3]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = int(sys.argv[4])
    result = {}
    objects = []
    for i, (path, prim_path) in enumerate(jobs):
        mesh = bpy.data.meshes.new(f"m{i}")
        ob = bpy.data.objects.new(f"o{i}", mesh)
        scene.collection.objects.link(ob)
        # bpy 5.0.1 has no bpy.data.cache_files.load/new: the operator is the way to add one.
        before = set(bpy.data.cache_files)
        assert bpy.ops.cachefile.open(filepath=path) == {"FINISHED"}
        (cache_file,) = set(bpy.data.cache_files) - before
        mod = ob.modifiers.new("TearCloth", "MESH_SEQUENCE_CACHE")
        mod.cache_file = cache_file
        mod.object_path = prim_path
        # what the add-on asks for (modifier.READ_DATA), as far as this Blender offers it: 4.2 has
        # no 'ATTRIBUTES' (stock Blender here: the add-on is not imported)
        offered = {item.identifier for item in mod.bl_rna.properties["read_data"].enum_items}
        mod.read_data = {"VERT", "POLY", "UV", "ATTRIBUTES"} & offered
        objects.append(ob)
    for frame in frames:
        scene.frame_set(frame)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        for i, ob in enumerate(objects):
            m = ob.evaluated_get(depsgraph).to_mesh()
            co = np.empty(3 * len(m.vertices), np.float32)
            m.vertices.foreach_get("co", co)
            sizes = np.empty(len(m.polygons), np.int32)
            m.polygons.foreach_get("loop_total", sizes)
            corner_vert = np.empty(len(m.loops), np.int32)
            m.loops.foreach_get("vertex_index", corner_vert)
            uv_layers = [layer.name for layer in m.uv_layers]
            uv = None
            if uv_layers:
                uv = np.empty(2 * len(m.loops), np.float32)
                m.uv_layers[0].data.foreach_get("uv", uv)
                uv = uv.tolist()
            vel = None
            if "velocity" in m.attributes:
                vel = np.empty(3 * len(m.vertices), np.float32)
                m.attributes["velocity"].data.foreach_get("vector", vel)
                vel = vel.tolist()
            result[f"{i}:{frame}"] = dict(
                co=co.tolist(), sizes=sizes.tolist(), corner_vert=corner_vert.tolist(),
                uv_layers=uv_layers, uv=uv, velocity=vel,
                reads_attributes="ATTRIBUTES" in ob.modifiers["TearCloth"].read_data,
            )
            ob.evaluated_get(depsgraph).to_mesh_clear()
    with open(out, "w") as f:
        json.dump(result, f)
    print("BLENDER_OK", bpy.app.version_string)
    """
)


def run_blender(tmp_path, jobs, frames):
    """Evaluate each (root, prim_path) through a stock Mesh Sequence Cache modifier at the given
    frames, in that order; returns {(job, frame): evaluated mesh data}."""
    pytest.importorskip("bpy")  # only checks that it is installed; it is imported in the child
    script = tmp_path / "blender_check.py"
    script.write_text(BLENDER_SCRIPT)
    out = tmp_path / "blender_result.json"
    proc = subprocess.run(
        [sys.executable, str(script), json.dumps(jobs), json.dumps(frames), str(out), str(int(FPS))],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0 and "BLENDER_OK" in proc.stdout, proc.stdout[-3000:] + proc.stderr[-3000:]
    raw = json.loads(out.read_text())
    return {(int(k.split(":")[0]), int(k.split(":")[1])): v for k, v in raw.items()}


def assert_blender_frame(got, frame):
    pos, tris, uv, vel = tear_frame(frame)
    co = np.array(got["co"]).reshape(-1, 3)
    assert len(co) == len(pos), f"frame {frame}: Blender has {len(co)} vertices, the cache {len(pos)}"
    np.testing.assert_array_equal(co, pos.astype(np.float32))
    assert got["sizes"] == [3] * len(tris)
    # the same corners in the same order: UVs per corner line up with the written triangles
    np.testing.assert_array_equal(np.array(got["corner_vert"]), tris.ravel())
    assert got["uv_layers"] == ["st"]
    np.testing.assert_array_equal(np.array(got["uv"]).reshape(-1, 2), uv.reshape(-1, 2).astype(np.float32))
    # velocities (m/s) arrive as Blender's 'velocity' point attribute, unscaled (Blender 4.2's
    # modifier offers no 'ATTRIBUTES' to read, yet bpy 4.2.23 reads the velocities all the same)
    assert got["velocity"] is not None or not got["reads_attributes"]
    if got["velocity"] is not None:
        np.testing.assert_array_equal(np.array(got["velocity"]).reshape(-1, 3), vel.astype(np.float32))


# ---------------------------------------------------------------------------------------------
# Round trips through USD value clips


def test_value_clips_resolve_each_frames_topology(tmp_path):
    path = str(tmp_path / "cloth.usda")
    frames = list(range(1, 9))
    write_tear_cache(path, frames)

    sizes = [len(tear_frame(f)[0]) for f in frames]
    assert sizes == sorted(sizes) and len(set(sizes)) == len(sizes)  # the mesh grows every frame
    order = frames[:]
    random.Random(3).shuffle(order)
    for f in order:
        assert_frame_equal(cache.read_frame(path, f), f)
    np.testing.assert_array_equal(cache.read_velocities(path, 5), tear_frame(5)[3].astype(np.float32))

    # What any USD reader sees: one Mesh, per-time topology, a faceVarying st, fps time codes.
    stage = Usd.Stage.Open(path)
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1, 8)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Cloth"))
    assert mesh and stage.GetDefaultPrim().GetPath() == "/Cloth"
    st_primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st_primvar.GetInterpolation() == UsdGeom.Tokens.faceVarying
    assert str(st_primvar.GetTypeName()) == "texCoord2f[]"
    clips = Usd.ClipsAPI(mesh.GetPrim())
    assert len(clips.GetClipAssetPaths()) == len(frames)
    assert clips.GetClipManifestAssetPath().path.endswith("cloth_frames/manifest.usda")
    for f in frames:
        pos, tris, uv, vel = tear_frame(f)
        assert len(mesh.GetPointsAttr().Get(f)) == len(pos)
        assert len(mesh.GetFaceVertexIndicesAttr().Get(f)) == tris.size
        assert len(st_primvar.Get(f)) == tris.size
        assert len(mesh.GetVelocitiesAttr().Get(f)) == len(pos)
        np.testing.assert_allclose(np.array(mesh.GetExtentAttr().Get(f)), [pos.min(0), pos.max(0)], atol=1e-6)
        # a motion-blur sub-frame holds this frame's mesh: topology is never interpolated
        assert len(mesh.GetPointsAttr().Get(f + 0.5)) == len(pos)
    assert len(mesh.GetPointsAttr().Get(-10)) == len(tear_frame(1)[0])
    assert len(mesh.GetPointsAttr().Get(100)) == len(tear_frame(8)[0])

    info = cache.cache_info(path)
    assert info["frames"] == frames and info["prim_path"] == "/Cloth" and info["fps"] == FPS
    assert info["complete"] and info["has_uv"] and info["has_velocities"]
    assert sorted(os.listdir(info["frames_dir"])) == [f"frame_{f:06d}.usdc" for f in frames] + ["manifest.usda"]


@pytest.mark.parametrize("root", ["cache.usdc", "cache.usd"])
def test_binary_roots_and_frames_with_gaps(tmp_path, root):
    path = str(tmp_path / root)
    frames = [-3, 0, 2, 7, 130]  # negative frames and gaps are allowed; a frame is a scene frame
    write_tear_cache(path, frames)
    assert cache.cache_info(path)["frames"] == frames
    for f in frames:
        assert_frame_equal(cache.read_frame(path, f), f)
    with pytest.raises(CacheError, match=r"frame 3 is not in the cache"):
        cache.read_frame(path, 3)


def test_metres_and_z_up_at_the_api_whatever_the_stage_units(tmp_path):
    path = str(tmp_path / "y.usda")
    pos, tris, uv, vel = tear_frame(4)
    with CacheWriter(path, "Cloth", 30.0, up_axis="Y", meters_per_unit=0.01) as w:
        w.write_frame(4, pos, tris, uv, vel)
    g_pos, g_tris, g_uv = cache.read_frame(path, 4)
    np.testing.assert_allclose(g_pos, pos, atol=1e-7)
    np.testing.assert_array_equal(g_tris, tris)
    np.testing.assert_allclose(cache.read_velocities(path, 4), vel, atol=1e-6)

    stage = Usd.Stage.Open(path)
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    raw = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/Cloth")).GetPointsAttr().Get(4))
    # centimetres, and Blender's +Z is the stage's +Y, Blender's +Y the stage's -Z
    np.testing.assert_allclose(raw, np.stack([pos[:, 0], pos[:, 2], -pos[:, 1]], 1) * 100.0, rtol=1e-6, atol=1e-5)
    info = cache.cache_info(path)
    assert (info["up_axis"], info["meters_per_unit"], info["fps"]) == ("Y", 0.01, 30.0)


def test_cache_without_uv_or_velocities(tmp_path):
    path = str(tmp_path / "plain.usda")
    with CacheWriter(path, "Plain", FPS, durable=True) as w:  # fsync path too
        for f in (1, 2):
            pos, tris, _, _ = tear_frame(f)
            w.write_frame(f, pos, tris)
    got_pos, got_tris, got_uv = cache.read_frame(path, 2)
    assert got_uv is None and cache.read_velocities(path, 2) is None
    assert len(got_pos) == len(tear_frame(2)[0])
    stage = Usd.Stage.Open(path)
    assert not stage.GetPrimAtPath("/Plain").GetAttribute("primvars:st")


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.integers(1, 40), st.integers(0, 60), st.integers(0, 2**31 - 1)), min_size=1, max_size=4))
def test_any_sequence_of_topologies_round_trips(shapes):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "h.usda")
        expected = []
        with CacheWriter(path, "H", FPS) as w:
            for frame, (n, m, seed) in enumerate(shapes, start=1):
                rng = np.random.default_rng(seed)
                pos = rng.uniform(-5.0, 5.0, (n, 3))
                tris = rng.integers(0, n, (m, 3))
                uv = rng.uniform(0.0, 1.0, (m, 3, 2))
                w.write_frame(frame, pos, tris, uv)
                expected.append((pos, tris, uv))
        for frame in reversed(range(1, len(shapes) + 1)):
            pos, tris, uv = expected[frame - 1]
            g_pos, g_tris, g_uv = cache.read_frame(path, frame)
            np.testing.assert_array_equal(g_pos, pos.astype(np.float32))
            np.testing.assert_array_equal(g_tris, tris)
            np.testing.assert_array_equal(g_uv, uv.astype(np.float32))


# ---------------------------------------------------------------------------------------------
# The key verification: stock Blender plays the cache


def test_blender_mesh_sequence_cache_plays_the_value_clips(tmp_path):
    frames = list(range(1, 7))
    usda, usdc = str(tmp_path / "tear.usda"), str(tmp_path / "tear.usdc")
    write_tear_cache(usda, frames)
    write_tear_cache(usdc, frames)
    order = [4, 1, 6, 2, 5, 3, 6]  # scrubbing back and forth, a frame twice
    got = run_blender(tmp_path, [[usda, "/Cloth"], [usdc, "/Cloth"]], order)
    counts = []
    for job in (0, 1):
        for f in order:
            assert_blender_frame(got[job, f], f)
        counts.append([len(got[job, f]["co"]) // 3 for f in frames])
    assert counts[0] == counts[1] and counts[0] == sorted(counts[0]) and len(set(counts[0])) == len(frames)


# ---------------------------------------------------------------------------------------------
# Crash safety and resume

KILLED_WRITER = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, sys.argv[2])
    from test_cache import tear_frame, FPS
    from tearcloth.cache import CacheWriter
    w = CacheWriter(sys.argv[1], "Cloth", FPS, object_name="Cloth Object")
    for frame in range(1, 100000):
        w.write_frame(frame, *tear_frame(frame))
        print(frame, flush=True)
    """
)


def kill_writer_mid_bake(tmp_path, path, min_frames, delay):
    """Start a writer, SIGKILL it ``delay`` s after it reports ``min_frames`` frames; returns
    how many frames it reported. The writer spends ~2 ms making a frame and ~4 ms writing it,
    so delays of a few ms land the kill inside a frame or root write, not only between frames."""
    script = tmp_path / "writer.py"
    script.write_text(KILLED_WRITER)
    proc = subprocess.Popen([sys.executable, str(script), path, TESTS_DIR], stdout=subprocess.PIPE, text=True)
    try:
        reported = 0
        for line in proc.stdout:
            reported = int(line)
            if reported >= min_frames:
                break
        time.sleep(delay)
        os.kill(proc.pid, signal.SIGKILL)  # no chance to close anything
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL and reported >= min_frames
    return reported


def test_sigkill_mid_bake_keeps_every_frame_and_resume_completes(tmp_path):
    for trial, delay in enumerate([0.0, 0.003, 0.005, 0.007]):
        path = str(tmp_path / f"killed{trial}.usda")
        reported = kill_writer_mid_bake(tmp_path, path, 5, delay)
        info = cache.cache_info(path)
        last = info["frames"][-1]
        assert info["frames"] == list(range(1, last + 1)) and last >= reported
        assert not info["complete"]
        for f in info["frames"]:
            assert_frame_equal(cache.read_frame(path, f), f)

        if trial == 0:  # Blender plays what a killed bake left (one bpy run is enough)
            check = sorted({1, last // 2, last})
            got = run_blender(tmp_path, [[path, "/Cloth"]], check[::-1])
            for f in check:
                assert_blender_frame(got[0, f], f)

        with CacheWriter(path, "Cloth", FPS, object_name="Cloth Object", resume=True) as w:
            # the root may lag one frame behind the files: a frame renamed just before the kill counts
            assert w.last_frame in (last, last + 1)
            end = w.last_frame + 3
            for f in range(w.last_frame + 1, end + 1):
                w.write_frame(f, *tear_frame(f))
        info = cache.cache_info(path)
        assert info["frames"] == list(range(1, end + 1)) and info["complete"]
        for f in info["frames"]:
            assert_frame_equal(cache.read_frame(path, f), f)
        # resume sweeps this cache's half-written temporaries (frames and root)
        base = os.path.basename(path)
        leftovers = [n for n in os.listdir(info["frames_dir"]) if n.startswith(".tmp-")]
        leftovers += [n for n in os.listdir(tmp_path) if n.startswith(".tmp-") and n.endswith("-" + base)]
        assert not leftovers, leftovers


def test_resume_repairs_every_crash_state(tmp_path):
    path = str(tmp_path / "crash.usda")
    frames_dir = cache.frames_dir_for(path)
    write_tear_cache(path, [1, 2, 3])
    root_after_3 = open(path, "rb").read()

    # 1. killed between the frame's rename and the root's rewrite: frame 4 exists, root names 1-3;
    #    plus half-written temporaries of frame 5 and of the root
    write_tear_cache(path, [1, 2, 3, 4])
    open(path, "wb").write(root_after_3)
    open(os.path.join(frames_dir, f".tmp-999-{'frame_000005.usdc'}"), "wb").write(b"PXR-USDC half")
    open(os.path.join(tmp_path, ".tmp-999-crash.usda"), "wb").write(b"#usda 1.0\n(")
    assert cache.cache_info(path)["frames"] == [1, 2, 3]  # readers only see what the root names
    with CacheWriter(path, "Cloth", FPS, object_name="Cloth Object", resume=True) as w:
        assert w.frames == [1, 2, 3, 4]
        w.write_frame(5, *tear_frame(5))
    assert cache.cache_info(path)["frames"] == [1, 2, 3, 4, 5]
    assert not [n for n in os.listdir(frames_dir) + os.listdir(tmp_path) if n.startswith(".tmp-")]

    # 2. a frame file lost or damaged (not by us): keep the run before it, rewrite from there
    os.remove(os.path.join(frames_dir, "frame_000004.usdc"))
    with pytest.raises(CacheError, match=r"frames missing.*frames 4"):
        cache.cache_info(path)
    open(os.path.join(frames_dir, "frame_000002.usdc"), "wb").write(os.urandom(300))
    with CacheWriter(path, "Cloth", FPS, object_name="Cloth Object", resume=True) as w:
        assert w.last_frame == 1 and w.frames == [1]
        for f in (2, 3):
            w.write_frame(f, *tear_frame(f))
    assert cache.cache_info(path)["frames"] == [1, 2, 3]
    assert sorted(os.listdir(frames_dir)) == ["frame_000001.usdc", "frame_000002.usdc", "frame_000003.usdc", "manifest.usda"]
    for f in (1, 2, 3):
        assert_frame_equal(cache.read_frame(path, f), f)

    # 3. resume where nothing was baked yet starts from scratch
    fresh = str(tmp_path / "fresh.usda")
    with CacheWriter(fresh, "Cloth", FPS, resume=True) as w:
        assert w.last_frame is None
        w.write_frame(1, *tear_frame(1))
    assert cache.cache_info(fresh)["frames"] == [1]


def test_resume_refuses_other_settings_or_owner(tmp_path):
    path = str(tmp_path / "c.usda")
    write_tear_cache(path, [1, 2])
    with pytest.raises(CacheError, match="fps 24.0"):
        CacheWriter(path, "Cloth", 25.0, object_name="Cloth Object", resume=True)
    with pytest.raises(CacheError, match="prim path '/Cloth'"):
        CacheWriter(path, "Other", FPS, object_name="Cloth Object", resume=True)
    with pytest.raises(CacheOwnerError, match="'Cloth Object'"):
        CacheWriter(path, "Cloth", FPS, object_name="Someone else", resume=True)
    assert cache.cache_info(path)["frames"] == [1, 2]  # refusing changed nothing


def test_writer_closed_on_error_marks_the_bake_incomplete(tmp_path):
    path = str(tmp_path / "c.usda")
    with pytest.raises(RuntimeError):
        with CacheWriter(path, "Cloth", FPS) as w:
            w.write_frame(1, *tear_frame(1))
            raise RuntimeError("solver blew up")
    info = cache.cache_info(path)
    assert info["frames"] == [1] and not info["complete"]
    with pytest.raises(CacheError, match="closed"):
        w.write_frame(2, *tear_frame(2))


# ---------------------------------------------------------------------------------------------
# Ownership, deletion, bad input


def test_owner_is_recorded_and_checked(tmp_path):
    path = str(tmp_path / "c.usda")
    pos, tris, uv, _ = tear_frame(0)
    fp = cache.mesh_fingerprint(pos, tris)
    with CacheWriter(path, "Cloth", FPS, object_name="Shirt.001", fingerprint=fp) as w:
        w.write_frame(1, *tear_frame(1))
    info = cache.cache_info(path)
    assert (info["object"], info["fingerprint"]) == ("Shirt.001", fp)
    assert cache.check_owner(path, "Shirt.001", fp)["frames"] == [1]
    with pytest.raises(CacheOwnerError, match=r"baked for object 'Shirt.001', not 'Banknote'"):
        cache.check_owner(path, "Banknote")
    other = cache.mesh_fingerprint(pos[:-1], tris[:-1])
    assert other != fp
    with pytest.raises(CacheOwnerError, match="different mesh"):
        cache.check_owner(path, "Shirt.001", other)
    # the fingerprint reads the mesh, not its memory layout
    assert cache.mesh_fingerprint(pos.tolist(), tris.astype(np.int64)) == fp
    # without an explicit one, the first frame's fingerprint is recorded
    default = str(tmp_path / "d.usda")
    write_tear_cache(default, [3])
    assert cache.cache_info(default)["fingerprint"] == cache.mesh_fingerprint(*tear_frame(3)[:2])


def test_delete_cache_removes_root_and_frames_only(tmp_path):
    path = str(tmp_path / "c.usda")
    write_tear_cache(path, [1, 2, 3])
    frames_dir = cache.frames_dir_for(path)
    keep = tmp_path / "notes.txt"
    keep.write_text("mine")
    # what a run killed while it rewrote the root leaves: our temporary, and the one USD's own
    # export writes it through (the extension replaced by a random suffix)
    temps = [tmp_path / ".tmp-7990-c.usda", tmp_path / ".tmp-7990-c.1W06ry"]
    for t in temps:
        t.write_text("half a root")
    other = tmp_path / ".tmp-7990-d.1W06ry"  # another cache's
    other.write_text("not ours")
    cache.delete_cache(path)
    assert not os.path.exists(path) and not os.path.exists(frames_dir) and keep.read_text() == "mine"
    assert not any(t.exists() for t in temps) and other.exists()
    cache.delete_cache(path)  # nothing left: no error

    # a frames folder with the user's own files in it is emptied of ours but kept
    write_tear_cache(path, [1])
    (tmp_path / "c_frames" / "readme.txt").write_text("mine")
    cache.delete_cache(path)
    assert os.listdir(frames_dir) == ["readme.txt"]

    foreign = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(foreign))
    UsdGeom.Cube.Define(stage, "/Cube")
    stage.Save()
    with pytest.raises(CacheError, match="no Tear Cloth mesh prim"):
        cache.delete_cache(str(foreign))
    assert foreign.exists()


def test_a_fresh_bake_replaces_an_old_cache_but_never_a_foreign_file(tmp_path):
    path = str(tmp_path / "c.usda")
    write_tear_cache(path, [1, 2, 3, 4])
    with CacheWriter(path, "Cloth", FPS) as w:
        w.write_frame(10, *tear_frame(10))
    assert cache.cache_info(path)["frames"] == [10]
    assert sorted(os.listdir(cache.frames_dir_for(path))) == ["frame_000010.usdc", "manifest.usda"]

    foreign = tmp_path / "important.usda"
    foreign.write_text('#usda 1.0\ndef Xform "Set" {}\n')
    with pytest.raises(CacheError, match="important.usda: no Tear Cloth mesh prim"):
        CacheWriter(str(foreign), "Cloth", FPS)
    assert "Set" in foreign.read_text()


def test_bad_files_give_clear_cache_errors(tmp_path):
    rng = np.random.default_rng(0)
    for name in ("noise.usda", "noise.usdc", "noise.usd"):
        bad = tmp_path / name
        bad.write_bytes(rng.integers(0, 256, 4096, dtype=np.uint8).tobytes())
        with pytest.raises(CacheError, match=rf"{name}: not a USD file"):
            cache.cache_info(str(bad))
        with pytest.raises(CacheError, match=rf"{name}: not a USD file"):
            cache.read_frame(str(bad), 1)

    foreign = tmp_path / "cube.usda"
    stage = Usd.Stage.CreateNew(str(foreign))
    UsdGeom.Cube.Define(stage, "/Cube")
    stage.Save()
    with pytest.raises(CacheError, match=r"cube.usda: no Tear Cloth mesh prim .*root prims: /Cube"):
        cache.cache_info(str(foreign))
    with pytest.raises(CacheError, match="no Tear Cloth mesh prim"):
        cache.check_owner(str(foreign), "Cloth")

    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(CacheError, match=r"empty: is an empty folder, not a Tear Cloth cache"):
        cache.cache_info(str(empty))
    with pytest.raises(CacheError, match="no such file"):
        cache.read_frame(str(empty / "cloth.usda"), 1)

    # the frames folder emptied behind the root's back
    path = str(tmp_path / "gone.usda")
    write_tear_cache(path, [1, 2, 3])
    for name in os.listdir(cache.frames_dir_for(path)):
        os.remove(os.path.join(cache.frames_dir_for(path), name))
    with pytest.raises(CacheError, match=r"gone.usda: frames missing: 3 of 3 frame files are gone"):
        cache.read_frame(path, 2)

    # a frame file damaged in place: reading it names the file
    path = str(tmp_path / "damaged.usda")
    write_tear_cache(path, [1, 2])
    frame_file = os.path.join(cache.frames_dir_for(path), "frame_000002.usdc")
    open(frame_file, "wb").write(b"PXR-USDC" + bytes(200))
    with pytest.raises(CacheError, match=r"frame 2 has no 'points' .*frame_000002.usdc"):
        cache.read_frame(path, 2)
    assert_frame_equal(cache.read_frame(path, 1), 1)


def test_write_frame_rejects_bad_input(tmp_path):
    w = CacheWriter(str(tmp_path / "c.usda"), "Cloth", FPS)
    pos, tris, uv, vel = tear_frame(2)
    w.write_frame(2, pos, tris, uv, vel)
    with pytest.raises(ValueError, match="must come after"):
        w.write_frame(2, pos, tris, uv, vel)
    with pytest.raises(TypeError):
        w.write_frame(3.0, pos, tris, uv, vel)
    bad_tris = tris.copy()
    bad_tris[0, 0] = len(pos)
    with pytest.raises(ValueError, match="indices"):
        w.write_frame(3, pos, bad_tris, uv, vel)
    nan = pos.copy()
    nan[1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        w.write_frame(3, nan, tris, uv, vel)
    with pytest.raises(ValueError, match="corner_uv"):
        w.write_frame(3, pos, tris, uv[:-1], vel)
    with pytest.raises(ValueError, match="has UVs"):
        w.write_frame(3, pos, tris, None, vel)
    with pytest.raises(ValueError, match="has velocities"):
        w.write_frame(3, pos, tris, uv, None)
    with pytest.raises(ValueError, match="triangles"):
        w.write_frame(3, pos, tris.astype(float), uv, vel)
    assert w.frames == [2]  # nothing half-added
    w.write_frame(3, *tear_frame(3))
    w.close()
    assert cache.cache_info(w.path)["frames"] == [2, 3]
    with pytest.raises(ValueError, match="identifier"):
        CacheWriter(str(tmp_path / "d.usda"), "My Cloth.001", FPS)
    with pytest.raises(ValueError, match=r"\.usda, \.usdc or \.usd"):
        CacheWriter(str(tmp_path / "d.abc"), "Cloth", FPS)


def test_imports_without_usd_core():
    code = textwrap.dedent(
        """
        import sys
        sys.modules["pxr"] = None  # as if usd-core were not installed
        import tearcloth.cache as c
        try:
            c.CacheWriter("/tmp/never.usda", "Cloth", 24.0)
        except ImportError as e:
            assert "usd-core" in str(e), e
            print("OK")
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == "OK", proc.stderr


def test_bench_reports_time_and_size(tmp_path):
    from tearcloth.bench.cache import cache_bench

    result = cache_bench(tmp_path, frames=3, triangles=200)
    assert result["frames"] == 3 and result["triangles"] >= 200
    assert result["ms_per_frame"] > 0 and result["bytes_per_frame"] > 1000
    assert os.listdir(tmp_path) == []  # the benchmark cleans up after itself


def test_a_promotion_cut_short_is_rebuilt_from_its_frames(tmp_path, monkeypatch):
    """A staged re-bake killed inside its promotion (found by tests/test_blender_user_actions.py's
    SIGKILLs): the old root deleted and the frame files moved in, the new root not yet written.
    The frames are intact, so the cache counts as damaged and ``repair_root`` rebuilds it (and
    drops the spent staging root)."""
    path = str(tmp_path / "Cloth.usda")
    with CacheWriter(path, "Cloth", FPS, object_name="Cloth Object") as w:  # the old bake
        for f in (1, 2, 3):
            w.write_frame(f, *tear_frame(f)[:2])
    new = CacheWriter(path, "Cloth", FPS, object_name="Cloth Object", stage=True)
    for f in (1, 2):
        new.write_frame(f, *tear_frame(10 + f)[:2])

    def killed(self, complete):
        raise KeyboardInterrupt("killed")
    monkeypatch.setattr(CacheWriter, "_write_root", killed)
    with pytest.raises(KeyboardInterrupt):
        new.promote()
    monkeypatch.undo()
    assert not os.path.exists(path) and os.path.exists(cache.staging_path_for(path))
    assert cache.damaged_root(path)
    assert cache.repair_root(path, "Cloth Object") == [1, 2]
    assert not os.path.exists(cache.staging_path_for(path))
    for f in (1, 2):
        assert np.array_equal(cache.read_frame(path, f)[0], np.asarray(tear_frame(10 + f)[0], np.float32))
    assert not cache.damaged_root(str(tmp_path / "Other.usda"))  # no root and nothing staged: not ours
