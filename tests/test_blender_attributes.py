"""The user's attributes and the torn-edge attributes in the cache, played by STOCK Blender (issue
12 defect 8, issue 19 "torn edges that look torn"). PyPI bpy, every Blender run in a subprocess.

The sheet of test_blender_bake (20 x 20 vertices, pinned, pulled until it tears) gets:
* two UV maps: ``UVMap`` (two islands: the right half shifted by 1 in u, so a seam runs down the
  middle column) and ``Second`` (active; u, v linear in the rest position, no seam);
* ``pcol``: a float point colour = (u, v, 0.5, 1) of ``Second``: interpolating it with the tear's
  weights keeps it equal to ``Second`` at every corner, new vertices included;
* ``ccol``: a float corner colour (u, v, polygon parity, 1): sharp across every edge;
* ``face_id``: a float face attribute, the polygon index: a new triangle must lie inside it;
* ``bcol``: a byte point colour (u, v, 0.25, 1): plays as a float colour of its name (a stock
  Geometry Nodes modifier removes the byte layer from the reader's input);
* ``ccol`` is the active colour: it stays active and becomes the render colour;
* ``edge_w``: an edge attribute, which USD cannot carry: reported once, by name.

Baked by the operator and by ``tearcloth bake``, then played in a fresh Blender without the add-on
(Mesh Sequence Cache) and checked attribute by attribute, on untorn parts and across the tear.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")
from tearcloth import cache  # noqa: E402

from test_blender_bake import find_cache, run_blender  # noqa: E402

N = 20
FRAMES = 20
FPS = 24.0

DECORATE = '''
    def decorate(obj):
        """The attributes of the module docstring on the test sheet."""
        me = obj.data
        n = 20
        corner = np.empty(len(me.loops), np.int32)
        me.loops.foreach_get("vertex_index", corner)
        co = np.empty(3 * len(me.vertices)); me.vertices.foreach_get("co", co); co = co.reshape(-1, 3)
        u, v = (co[:, 0] + 0.25) / 0.5, (co[:, 2] - 1.0) / 0.5
        poly = np.repeat(np.arange(len(me.polygons)), 4)
        second = me.uv_layers.new(name="Second")
        second.data.foreach_set("uv", np.stack([u, v], 1)[corner].ravel())
        shift = (poly // (n - 1) >= (n // 2)).astype(float)  # polygons of columns 10.. : the right island
        me.uv_layers["UVMap"].data.foreach_set("uv", np.stack([u[corner] + shift, v[corner]], 1).ravel())
        me.uv_layers.active = second
        second.active_render = True
        pcol = me.color_attributes.new("pcol", "FLOAT_COLOR", "POINT")
        pcol.data.foreach_set("color", np.stack([u, v, np.full_like(u, 0.5), np.ones_like(u)], 1).ravel())
        ccol = me.color_attributes.new("ccol", "FLOAT_COLOR", "CORNER")
        ccol.data.foreach_set("color", np.stack([u[corner], v[corner], (poly % 2).astype(float),
                                                  np.ones(len(corner))], 1).ravel())
        face = me.attributes.new("face_id", "FLOAT", "FACE")
        face.data.foreach_set("value", np.arange(len(me.polygons), dtype=float))
        bcol = me.color_attributes.new("bcol", "BYTE_COLOR", "POINT")
        bcol.data.foreach_set("color", np.stack([u, v, np.full_like(u, 0.25), np.ones_like(u)], 1).ravel())
        me.color_attributes.active_color_name = "ccol"
        me.attributes.new("edge_w", "FLOAT", "EDGE")
'''

# Plays a baked .blend with stock Blender only (the add-on is never imported here).
PLAY = '''
    blend, name = sys.argv[1], sys.argv[2]
    bpy.ops.wm.open_mainfile(filepath=blend)
    assert "tearcloth" not in sys.modules and not hasattr(bpy.types.Object, "tearcloth")
    obj = bpy.data.objects[name]
    scene = bpy.context.scene
    frames = {}
    for frame in range(1, 21):
        scene.frame_set(frame)
        with evaluated_mesh(obj) as m:
            got = dict(co=positions(m).tolist(), uv=[(u.name, u.active, u.active_render) for u in m.uv_layers],
                       active_colour=m.color_attributes.active_color_name,
                       render_colour=m.color_attributes[m.color_attributes.render_color_index].name,
                       stack=[md.name for md in obj.modifiers])
            cv = np.empty(len(m.loops), np.int32); m.loops.foreach_get("vertex_index", cv)
            got["corner_vert"] = cv.tolist()
            attrs = {}
            for a in m.attributes:
                if a.name.startswith(".") or a.name in ("position", "sharp_face"):
                    continue
                key = {"FLOAT": "value", "INT": "value", "BOOLEAN": "value", "FLOAT_VECTOR": "vector",
                       "FLOAT2": "vector", "FLOAT_COLOR": "color", "BYTE_COLOR": "color"}.get(a.data_type)
                if key is None:
                    continue
                k = {"value": 1, "vector": 3 if a.data_type == "FLOAT_VECTOR" else 2, "color": 4}[key]
                buf = np.empty(len(a.data) * k, np.float32 if a.data_type != "BOOLEAN" else bool)
                a.data.foreach_get(key, buf)
                attrs[a.name] = dict(domain=a.domain, type=a.data_type, values=buf.astype(float).tolist())
            got["attributes"] = attrs
            frames[frame] = got
    result(frames)
'''


def _decorated_scene(tmp_path: Path) -> Path:
    made = run_blender(tmp_path, textwrap.dedent(DECORATE) + textwrap.dedent('''
        folder = sys.argv[1]
        obj = build_scene(folder)
        decorate(obj)
        bpy.ops.wm.save_mainfile()
        result(dict(blend=bpy.data.filepath))
    '''), tmp_path, name="decorate.py")
    return Path(made["blend"])


def _played(tmp_path: Path, blend: Path, name="Sheet") -> dict:
    got = run_blender(tmp_path, PLAY, blend, name, name="play.py", timeout=300)
    return {int(k): v for k, v in got.items()}


def _boundary_edges(tris: np.ndarray) -> np.ndarray:
    edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    return uniq[counts == 1]


def check_playback(path: str, played: dict) -> dict:
    """Every attribute by name in stock Blender's playback, against the cache and the rules."""
    info = cache.cache_info(path)
    assert info["frames"] == list(range(1, FRAMES + 1))
    assert {"UVMap", "pcol", "ccol", "face_id", "torn", "torn_time", "warp"} <= set(info["primvars"])
    assert "bcol" in info["primvars"] and "edge_w" not in info["primvars"]
    first_torn = {}
    torn_counts = []
    for frame in info["frames"]:
        got = played[frame]
        attrs = got["attributes"]
        co = np.array(got["co"]).reshape(-1, 3)
        tris = np.array(got["corner_vert"]).reshape(-1, 3)
        n, m = len(co), len(tris)
        # the active UV map stays active and render-active; the other one is there by its name
        uv_state = {name: (active, render) for name, active, render in got["uv"]}
        assert uv_state["Second"] == (True, True) and "UVMap" in uv_state, got["uv"]
        for name in ("UVMap", "Second", "pcol", "ccol", "bcol", "face_id", "torn", "torn_time", "warp"):
            assert name in attrs, f"frame {frame}: {name} missing from {sorted(attrs)}"
        assert got["active_colour"] == got["render_colour"] == "ccol"
        assert got["stack"] == ["Tear Cloth Colours", "Tear Cloth"], got["stack"]
        assert attrs["bcol"]["type"] == "FLOAT_COLOR" and attrs["bcol"]["domain"] == "POINT"
        # Blender shows exactly what the cache holds
        stored = cache.read_primvars(path, frame)
        for name in ("UVMap", "pcol", "ccol", "bcol", "face_id", "torn", "torn_time", "warp"):
            np.testing.assert_array_equal(np.array(attrs[name]["values"], np.float32),
                                          np.asarray(stored[name], np.float32).ravel(), err_msg=f"{frame} {name}")
        assert attrs["pcol"]["domain"] == "POINT" and attrs["ccol"]["domain"] == "CORNER"
        assert attrs["face_id"]["domain"] == "FACE" and attrs["torn"]["domain"] == "POINT"
        assert attrs["warp"]["type"] == "FLOAT_VECTOR"
        second = np.array(attrs["Second"]["values"]).reshape(m, 3, 2)
        first = np.array(attrs["UVMap"]["values"]).reshape(m, 3, 2)
        pcol = np.array(attrs["pcol"]["values"]).reshape(n, 4)
        ccol = np.array(attrs["ccol"]["values"]).reshape(m, 3, 4)
        face = np.rint(np.array(attrs["face_id"]["values"])).astype(int)
        # point colour: interpolated with the tear's weights, so still (u, v) of Second everywhere
        np.testing.assert_allclose(pcol[tris][..., :2], second, atol=2e-5, err_msg=f"frame {frame}: pcol")
        np.testing.assert_allclose(pcol[:, 2:], np.tile([0.5, 1.0], (n, 1)), atol=1e-6)
        # the byte colour likewise, within its 8-bit sRGB steps (at most 0.009 in linear)
        bcol = np.array(attrs["bcol"]["values"]).reshape(n, 4)
        np.testing.assert_allclose(bcol[tris][..., :2], second, atol=0.01, err_msg=f"frame {frame}: bcol")
        np.testing.assert_allclose(bcol[:, 2], 0.25, atol=0.01)
        # face attribute: each triangle lies in the polygon it came from (in the seamless UV)
        i, j = face // (N - 1), face % (N - 1)
        centre = second.mean(axis=1) * (N - 1)
        assert np.all((centre[:, 0] > i - 1e-4) & (centre[:, 0] < i + 1 + 1e-4)
                      & (centre[:, 1] > j - 1e-4) & (centre[:, 1] < j + 1 + 1e-4)), f"frame {frame}: face_id"
        # corner attributes follow the corners: the first UV map's seam and the parity stay sharp
        shift = (i >= N // 2).astype(float)
        np.testing.assert_allclose(first[..., 0], second[..., 0] + shift[:, None], atol=2e-5)
        np.testing.assert_allclose(first[..., 1], second[..., 1], atol=2e-5)
        np.testing.assert_allclose(ccol[..., :2], second, atol=2e-5)
        np.testing.assert_array_equal(ccol[..., 2], np.repeat((face % 2)[:, None], 3, axis=1).astype(float))
        # torn: exactly the points of boundary edges that were interior at rest
        torn = np.array(attrs["torn"]["values"])
        rest_uv = np.zeros((n, 2))
        rest_uv[tris.ravel()] = second.reshape(-1, 2)
        edges = _boundary_edges(tris)
        mid = 0.5 * (rest_uv[edges[:, 0]] + rest_uv[edges[:, 1]])
        outer = np.any((np.abs(mid) < 1e-5) | (np.abs(mid - 1.0) < 1e-5), axis=1)
        expect = np.zeros(n)
        expect[edges[~outer].ravel()] = 1.0
        np.testing.assert_array_equal(torn, expect, err_msg=f"frame {frame}: torn")
        torn_counts.append(int(torn.sum()))
        # torn_time: -1 where never torn, the frame it first tore at (s since frame 1), never changing
        tt = np.array(attrs["torn_time"]["values"])
        t_now = (frame - 1) / FPS
        assert np.all(tt[torn == 0] == -1.0) and np.all((tt[torn == 1] >= 0) & (tt[torn == 1] <= t_now + 1e-6))
        for v in np.flatnonzero(torn):
            first_torn.setdefault(int(v), float(tt[v]))
            assert abs(tt[v] - first_torn[int(v)]) < 1e-6, f"frame {frame}: torn_time of {v} changed"
        # warp: unit, tangent to the surface, along +u of the active map (the sheet's x at rest)
        warp = np.array(attrs["warp"]["values"]).reshape(n, 3)
        np.testing.assert_allclose(np.linalg.norm(warp, axis=1), 1.0, atol=1e-5)
        fn = np.cross(co[tris[:, 1]] - co[tris[:, 0]], co[tris[:, 2]] - co[tris[:, 0]])
        vn = np.zeros((n, 3))
        for k in range(3):
            np.add.at(vn, tris[:, k], fn)
        vn /= np.linalg.norm(vn, axis=1)[:, None]
        assert np.max(np.abs((warp * vn).sum(1))) < 1e-4, f"frame {frame}: warp not tangent"
        if frame == 1:
            assert np.min(warp[:, 0]) > 0.999
    assert torn_counts[0] == 0 and torn_counts[-1] > 0, torn_counts
    # the torn points lie along the tear: the points of the last frame that tore are torn there
    return dict(torn_points=torn_counts[-1], vertices=len(played[FRAMES]["co"]) // 3)


def test_operator_bake_carries_every_attribute_into_stock_playback(tmp_path):
    blend = _decorated_scene(tmp_path)
    baked = run_blender(tmp_path, '''
        bpy.ops.wm.open_mainfile(filepath=sys.argv[1])
        import tearcloth
        tearcloth.register()
        logged = collect_log()
        obj = bpy.data.objects["Sheet"]
        state = op("bake", obj)
        bpy.ops.wm.save_mainfile()
        result(dict(state=sorted(state), log=logged))
    ''', blend, name="bake.py", timeout=300)
    assert baked["state"] == ["FINISHED"]
    warned = [m for level, m in baked["log"] if level == "WARNING"]
    about = [m for m in warned if "'edge_w'" in m]
    assert len(about) == 1 and "edge attributes" in about[0], warned
    assert not [m for m in warned if "'bcol'" in m or "'pcol'" in m or "'ccol'" in m], warned
    assert not [m for m in warned if "UV map" in m and "only the active" in m]
    path = find_cache(tmp_path / "tearcloth_cache", "Sheet", "scene")
    seen = check_playback(path, _played(tmp_path, blend))
    print(f"operator bake: {seen['torn_points']} torn points of {seen['vertices']}")


def test_cli_bake_carries_every_attribute_into_stock_playback(tmp_path):
    blend = _decorated_scene(tmp_path)
    out = tmp_path / "baked"
    proc = subprocess.run([sys.executable, "-m", "tearcloth.cli", "bake", str(blend), "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    # the headless log names the attribute that is not carried, once
    assert proc.stderr.count("'edge_w'") == 1 and "edge attributes" in proc.stderr, proc.stderr[-3000:]
    assert "'bcol'" not in proc.stderr
    path = find_cache(out / "tearcloth_cache", "Sheet", "scene")
    seen = check_playback(path, _played(tmp_path, out / "scene.blend"))
    print(f"CLI bake: {seen['torn_points']} torn points of {seen['vertices']}")
