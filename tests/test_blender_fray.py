"""Frayed torn edges (blender/fray.py): the Geometry Nodes group grows threads along the warp and
the weft, outward from the torn edge, and a .blend holding it renders them in a FRESH Blender that
never imports the add-on.

The torn frame is made by hand until the cache carries the attributes itself: a 30 x 30 cm sheet
(31 x 31 vertices, normal -Y) slit from its middle to its top edge, the two lips separate vertices
pulled 7.5 mm apart at the top, with the point attributes a cache carries: ``torn`` = 1 on both lips,
``torn_time`` and ``warp`` = 30 degrees off vertical in the sheet's plane (in world space: the
first test turns the object, the threads must follow the warp in the object's space). About 4 s for both tests.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("bpy")
from test_blender_bake import run_blender  # noqa: E402

DISTANCE = 0.4  # m from the camera to the sheet
WARP = (math.sin(math.radians(30.0)), 0.0, math.cos(math.radians(30.0)))

SLIT_SHEET = '''
    import math
    import tearcloth
    from tearcloth.blender import fray

    def slit_sheet(n=31, size=0.3, opening=0.05, warp=(0.5, 0.0, 0.866)):
        """The torn sheet of the file head, Tear Cloth enabled; returns (object, torn-point mask)."""
        bpy.ops.wm.read_factory_settings(use_empty=True)
        tearcloth.register()
        scene = bpy.context.scene
        xs = np.linspace(-size / 2, size / 2, n)
        zs = np.linspace(1.0 - size / 2, 1.0 + size / 2, n)
        mid = n // 2
        idx = lambda i, j: i * n + j
        verts = [(x, 0.0, z) for x in xs for z in zs]
        lip = {}
        for j in range(mid + 1, n):  # the right lip: copies of the slit's vertices above its tip
            lip[j] = len(verts)
            verts.append((xs[mid], 0.0, zs[j]))
        faces = []
        for i in range(n - 1):
            for j in range(n - 1):
                q = [idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)]
                if i == mid:
                    q = [lip.get(j, q[0]), q[1], q[2], lip.get(j + 1, q[3])]
                faces.append(q)
        v = np.array(verts)
        torn = np.zeros(len(v))
        for j in range(mid + 1, n):
            gap = opening * (zs[j] - zs[mid])
            v[idx(mid, j), 0] -= gap
            v[lip[j], 0] += gap
            torn[idx(mid, j)] = torn[lip[j]] = 1.0
        mesh = bpy.data.meshes.new("Sheet")
        mesh.from_pydata(v.tolist(), [], faces)
        mesh.attributes.new("torn", "FLOAT", "POINT").data.foreach_set("value", torn)
        mesh.attributes.new("torn_time", "FLOAT", "POINT").data.foreach_set("value", 0.5 * torn)
        mesh.attributes.new("warp", "FLOAT_VECTOR", "POINT").data.foreach_set(
            "vector", np.tile(warp, (len(v), 1)).ravel())
        cloth = bpy.data.materials.new("Cloth")
        cloth.diffuse_color = (0.85, 0.85, 0.85, 1.0)
        mesh.materials.append(cloth)
        obj = bpy.data.objects.new("Sheet", mesh)
        scene.collection.objects.link(obj)
        bpy.context.view_layer.objects.active = obj
        assert op("enable", obj) == {"FINISHED"}
        return obj, torn > 0.5

    def set_inputs(md, **values):
        for name, value in values.items():
            fray.set_input(md, name, value)
        md.node_group.interface_update(bpy.context)
'''


def test_threads_run_along_warp_and_weft_out_of_the_tear(tmp_path):
    got = run_blender(tmp_path, textwrap.dedent(SLIT_SHEET) + textwrap.dedent('''
        # the object turned 90 degrees about Z: the cache's warp is in world space, the threads in the object's
        warp = json.loads(sys.argv[1])
        obj, torn = slit_sheet(warp=[-warp[1], warp[0], warp[2]])
        obj.rotation_euler = (0.0, 0.0, math.pi / 2)
        bpy.context.scene.unit_settings.scale_length = 0.01  # 1 Blender unit = 1 cm: the defaults convert
        assert op("add_frayed_edges", obj) == {"FINISHED"}
        assert op("add_frayed_edges", obj) == {"CANCELLED"}  # once is enough
        md = fray.find_modifier(obj)
        defaults = {item.name: fray.input_value(md, item.name) for item in md.node_group.interface.items_tree
                    if item.item_type == "SOCKET" and item.in_out == "INPUT" and item.name not in ("Geometry",
                                                                                                "Material")}
        material = fray.input_value(md, "Material")
        order = [m.name for m in obj.modifiers]
        set_inputs(md, Jitter=0.0, **{"Thread Radius": 1e-6, "Length": 0.01, "Density": 200.0})
        n_cloth = len(obj.data.vertices)
        with evaluated_mesh(obj) as m:
            co = positions(m).reshape(-1, 3)
        cloth = np.array([v.co for v in obj.data.vertices])  # object space, as the evaluated mesh
        # thread vertices: those that are not the cloth's (12 per thread: a ring of 6 at each end)
        from scipy.spatial import cKDTree
        far = cKDTree(cloth).query(co)[0] > 1e-7
        rings = co[far].reshape(-1, 2, 6, 3).mean(axis=2)
        result(dict(defaults=defaults, material=material.name, order=order, cloth=n_cloth, total=len(co), start=rings[:, 0].tolist(),
                    end=rings[:, 1].tolist(), lips=cloth[torn].tolist()))
    '''), json.dumps(list(WARP)))
    assert got["order"] == ["Tear Cloth", "Tear Cloth Frayed Edges"]
    # the table's defaults in a centimetre scene (lengths in Blender units, density per unit)
    assert got["defaults"] == pytest.approx({"Length": 0.6, "Density": 10.0, "Jitter": 0.5, "Thread Radius": 0.015,
                                             "Seed": 0}, rel=1e-6)
    assert got["material"] == "Cloth"  # the cloth's own material
    start, end = np.array(got["start"]), np.array(got["end"])
    d = end - start
    length = np.linalg.norm(d, axis=1)
    # density 200 /m on two lips of ~15 cm: ~60 threads
    assert 45 <= len(d) <= 80, len(d)
    np.testing.assert_allclose(length, 0.01, rtol=1e-4)
    u = d / length[:, None]
    warp = np.array(WARP)
    weft = np.cross([0.0, -1.0, 0.0], warp)  # normal x warp (the sheet faces -Y)
    along_warp = np.abs(u @ warp) > 1.0 - 1e-6
    along_weft = np.abs(u @ weft) > 1.0 - 1e-6
    assert np.all(along_warp | along_weft)
    assert 0.3 < along_warp.mean() < 0.7  # half and half
    # every thread starts on a lip and leaves the cloth: left lip (x < 0) to +x, right lip to -x
    lips = np.array(got["lips"])
    assert np.min(np.linalg.norm(start[:, None] - lips[None], axis=2), axis=1).max() < 0.02
    # (the lips' top vertices are corners of the sheet too, where "out" is diagonal: left out)
    outward = -np.sign(start[:, 0])
    bad = (u[:, 0] * outward <= 0.0) & (start[:, 2] < lips[:, 2].max() - 1e-6)
    assert not bad.any(), (bad.sum(), len(bad), start[bad], u[bad])


# The fresh Blender: no tearcloth import, no add-on registered; renders with and without the group.
RENDER = '''
    import sys, json
    import numpy as np
    import bpy
    from bpy_extras.object_utils import world_to_camera_view
    blend, out = sys.argv[1], sys.argv[2]
    bpy.ops.wm.open_mainfile(filepath=blend)
    assert "tearcloth" not in sys.modules and not hasattr(bpy.types.Object, "tearcloth")
    scene = bpy.context.scene
    obj = bpy.data.objects["Sheet"]
    md = obj.modifiers["Tear Cloth Frayed Edges"]
    counts = {}
    for on in (True, False):
        md.show_render = md.show_viewport = on
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        counts[str(on)] = len(ev.to_mesh().vertices)
        ev.to_mesh_clear()
        scene.render.filepath = out + ("_with.png" if on else "_without.png")
        bpy.ops.render.render(write_still=True)
    torn = np.zeros(len(obj.data.vertices))
    obj.data.attributes["torn"].data.foreach_get("value", torn)
    lips = [tuple(world_to_camera_view(scene, scene.camera, obj.matrix_world @ v.co))
            for v, t in zip(obj.data.vertices, torn) if t > 0.5]
    print("RESULT " + json.dumps(dict(counts=counts, lips=lips, size=[scene.render.resolution_x,
                                                                        scene.render.resolution_y])))
'''


def _load(path):
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"), dtype=np.int16)


def test_frayed_edges_render_in_blender_without_the_add_on(tmp_path):
    pytest.importorskip("PIL")
    run_blender(tmp_path, textwrap.dedent(SLIT_SHEET) + f"DISTANCE = {DISTANCE}\n" + textwrap.dedent('''
        obj, torn = slit_sheet()
        assert op("add_frayed_edges", obj) == {"FINISHED"}
        red = bpy.data.materials.new("Threads")
        red.diffuse_color = (0.8, 0.1, 0.05, 1.0)
        set_inputs(fray.find_modifier(obj), Material=red, **{"Thread Radius": 6e-4, "Length": 0.012,
                                                              "Density": 300.0})
        scene = bpy.context.scene
        cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        scene.collection.objects.link(cam)
        cam.location = (0.0, -DISTANCE, 1.05)
        cam.rotation_euler = (math.pi / 2, 0.0, 0.0)
        scene.camera = cam
        render = scene.render
        render.engine = "BLENDER_WORKBENCH"
        render.resolution_x, render.resolution_y, render.resolution_percentage = 400, 300, 100
        scene.display.shading.light = "STUDIO"
        scene.display.shading.color_type = "MATERIAL"
        scene.display.render_aa = "OFF"
        bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])
        result(True)
    '''), tmp_path / "frayed.blend")
    script = tmp_path / "render.py"
    script.write_text(textwrap.dedent(RENDER))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, str(script), str(tmp_path / "frayed.blend"), str(tmp_path / "frame")],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    got = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    got = json.loads(got[-1][7:])
    assert got["counts"]["True"] > got["counts"]["False"]  # the group made threads
    with_, without = _load(tmp_path / "frame_with.png"), _load(tmp_path / "frame_without.png")
    changed = np.abs(with_ - without).sum(axis=2) > 60
    w, h = got["size"]
    lips = np.array([(x * w, (1.0 - y) * h) for x, y, _ in got["lips"]])  # pixel coordinates
    rows, cols = np.nonzero(changed)
    pixels = np.stack([cols + 0.5, rows + 0.5], axis=1)
    distance = np.min(np.linalg.norm(pixels[:, None] - lips[None], axis=2), axis=1)
    px_per_m = w / 2 / (DISTANCE * math.tan(math.radians(39.6) / 2))  # 50 mm lens, 36 mm sensor
    reach = 0.012 * 1.3 * px_per_m + 2  # the longest thread, jittered, plus a pixel of edge
    # the threads show (hundreds of pixels), all of them near the tear, all along it
    assert changed.sum() > 300, changed.sum()
    assert (distance <= reach).mean() > 0.99, (distance.max(), reach)
    covered = np.min(np.linalg.norm(lips[:, None] - pixels[None], axis=2), axis=1) < 3.0
    assert covered.mean() > 0.8, covered.mean()
    pictures = os.environ.get("TEARCLOTH_FRAY_PICTURES")
    if pictures:  # the README's pair: python -m pytest test_blender_fray.py with this set to a folder
        for name in ("with", "without"):
            shutil.copy(tmp_path / f"frame_{name}.png", os.path.join(pictures, f"fray_{name}.png"))
