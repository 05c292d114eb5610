"""The example scenes (``example_blends/*.blend``) bake headless with ``tearcloth bake``
(``addon/cli.py``), always in a subprocess; their renders show the tear; the T-shirt never
enters the walking body; the committed files are what the generator makes; and every bad input
to ``tearcloth bake`` ends with one error line and a non-zero exit.

How a render "shows the tear": the renders have a transparent background, so their alpha is the
exact silhouette of what the camera sees. An intact sheet seen from the front has no gap across
any image row (a rectangle, a square sagging between two hands); a tear that opens lets the
background through between cloth on both sides. The torn frame must have such see-through rows
over at least 30 % more of its height than the first frame of the same bake (the hands' rows
count in both). Checked against a control: the square cloth with tearing switched off, pulled the
same way, gains 1 % (the row where the two hands rise above the sheet); torn, it gains ~85 %.
"""
from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bpy")  # Blender runs in the children only
pytest.importorskip("pxr")
from tearcloth import cache, examples  # noqa: E402

from test_blender_bake import PRELUDE, find_cache  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "example_blends"
SUMMARY = re.compile(r"^(?P<name>\S+): baked frames (?P<a>-?\d+)-(?P<b>-?\d+): (?P<tears>\d+) tears?, "
                     r"(?P<vertices>\d+) vertices, (?P<seconds>[\d.]+) s \((?P<spf>[\d.]+) s/frame\)", re.M)


def bake(blend: Path, out: Path, *args, timeout: float = 240.0) -> dict:
    """`tearcloth bake` in a subprocess; returns {object name: summary} parsed from its output."""
    proc = subprocess.run([sys.executable, "-m", "tearcloth.cli", "bake", str(blend), "--out", str(out),
                           *map(str, args)], capture_output=True, text=True, timeout=timeout)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-4000:]
    found = {m["name"]: {"frames": (int(m["a"]), int(m["b"])), "tears": int(m["tears"]),
                         "vertices": int(m["vertices"]), "s_per_frame": float(m["spf"])}
             for m in SUMMARY.finditer(proc.stdout)}
    assert found, log[-4000:]
    for name, s in found.items():
        print(f"{blend.name}: {name} frames {s['frames'][0]}-{s['frames'][1]}: {s['s_per_frame']:.3f} s/frame, "
              f"{s['tears']} tears")
    return found


def silhouette(path: Path) -> np.ndarray:
    """What the camera sees of the scene's objects: the alpha of a render with a transparent
    background (tearcloth bake --transparent)."""
    from PIL import Image

    with Image.open(path) as im:
        assert im.mode == "RGBA", f"{path.name} has no alpha: render it with --transparent"
        return np.asarray(im)[..., 3] > 127


def see_through_rows(mask: np.ndarray, min_gap: int = 2) -> float:
    """Fraction of the silhouette's rows that see the background between two of its pixels
    (gaps of at least ``min_gap`` pixels, so antialiasing does not count)."""
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return 0.0
    hits = 0
    for r in rows:
        xs = np.flatnonzero(mask[r])
        inside = mask[r, xs[0]:xs[-1] + 1]
        gap = np.diff(np.flatnonzero(inside))  # distance between consecutive covered pixels
        hits += bool(len(gap) and gap.max() > min_gap)
    return hits / len(rows)


def check_tear_in_renders(first: Path, torn: Path, min_gain: float = 0.30) -> None:
    a, b = silhouette(first), silhouette(torn)
    rows_a, rows_b = see_through_rows(a), see_through_rows(b)
    print(f"{torn.name}: the cloth covers {a.mean():.1%} -> {b.mean():.1%} of the image; rows seeing the "
          f"background through it {rows_a:.0%} -> {rows_b:.0%}")
    assert a.mean() > 0.03 and b.mean() > 0.03, "the cloth is missing from a render"
    assert rows_b > rows_a + min_gain, (
        f"no visible tear: {rows_b:.0%} of the rows see through the torn frame, {rows_a:.0%} the first")


def check_cache_torn(path: Path, first: int, last: int) -> None:
    v0, _, _ = cache.read_frame(path, first)
    v1, t1, uv1 = cache.read_frame(path, last)
    assert len(v1) > len(v0), "no vertex was added: nothing tore"
    info = examples.validate_mesh(v1, t1)
    assert info["is_edge_manifold"] and info["is_consistently_wound"] and info["n_degenerate"] == 0, info
    assert uv1 is not None and uv1.shape == (len(t1), 3, 2)  # the grid stays on the torn pieces


def test_square_cloth_bakes_and_the_render_shows_the_tear(tmp_path):
    source = EXAMPLES / "square_cloth.blend"
    before = source.read_bytes()
    baked = bake(source, tmp_path, "--frames", "1-24", "--render", tmp_path / "frame_##.png",
                 "--render-frame", "1,24", "--resolution-percent", "25", "--transparent")
    assert source.read_bytes() == before, "the input .blend was written"
    assert (tmp_path / "square_cloth.blend").is_file() and not (tmp_path / "square_cloth.blend1").exists()
    s = baked["SquareCloth"]
    assert s["frames"] == (1, 24) and s["tears"] >= 1
    root = find_cache(tmp_path / "tearcloth_cache", "SquareCloth", "square_cloth")
    info = cache.cache_info(root)
    assert info["frames"] == list(range(1, 25)) and info["complete"]
    check_cache_torn(root, 1, 24)
    check_tear_in_renders(tmp_path / "frame_01.png", tmp_path / "frame_24.png")


def test_banknote_bakes_and_the_render_shows_the_tear(tmp_path):
    baked = bake(EXAMPLES / "banknote.blend", tmp_path, "--frames", "1-20", "--render", tmp_path / "frame_##.png",
                 "--render-frame", "1,20", "--resolution-percent", "25", "--transparent")
    s = baked["Banknote"]
    assert s["frames"] == (1, 20) and s["tears"] >= 1
    root = find_cache(tmp_path / "tearcloth_cache", "Banknote", "banknote")
    check_cache_torn(root, 1, 20)
    v, t, _ = cache.read_frame(root, 20)
    assert examples.validate_mesh(v, t)["n_components"] >= 2, "the note is not torn in two by frame 20"
    check_tear_in_renders(tmp_path / "frame_01.png", tmp_path / "frame_20.png")


def test_demo_bakes_the_square_cloth_and_plots_the_hand_forces(tmp_path):
    """`tearcloth demo` (cli.demo): the example baked end to end, a picture of the torn
    cloth, and the force each hand feels: both pull inward (towards each other), rise while the
    cloth stretches and drop when it tears."""
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-c", "import sys; from tearcloth.cli import demo; demo(sys.argv[1])",
                           str(out)], capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    for name in ("torn_cloth.png", "forces.png", "forces.csv", "square_cloth.blend"):
        assert (out / name).is_file(), name
    from tearcloth.haptics.forcelog import ForceLog

    log = ForceLog.from_csv(out / "forces.csv")
    t, left = log.along_axis("left", (1.0, 0.0, 0.0))
    _, right = log.along_axis("right", (1.0, 0.0, 0.0))
    assert len(t) > 500  # every simulation step, not every frame
    peak = int(np.argmax(left))
    assert left[peak] > 5.0 and right.min() < -5.0  # newtons: the cloth pulls each hand inward
    assert left[-1] < 0.6 * left[peak]  # the tear releases the pull
    from PIL import Image

    with Image.open(out / "torn_cloth.png") as im:  # the scene's own settings: an opaque background
        rgb = np.asarray(im.convert("RGB"), dtype=np.int16)
    assert (np.abs(rgb - rgb[0, 0]) > 30).any(axis=2).mean() > 0.05  # the cloth, not just background


# Opens the baked T-shirt scene with STOCK Blender (the add-on is not imported): the body as the
# Armature modifier deforms it, at each frame asked for, plus a render of the last one.
BODY_DUMP = '''
blend, out, png = sys.argv[1], sys.argv[2], sys.argv[3]
frames = [int(f) for f in sys.argv[4:]]
bpy.ops.wm.open_mainfile(filepath=blend)
assert "tearcloth" not in sys.modules
scene = bpy.context.scene
body = bpy.data.objects["Mannequin"]
data = {}
for f in frames:
    scene.frame_set(f)
    with evaluated_mesh(body) as m:
        co = positions(m)
        tri = np.empty(3 * len(m.polygons), np.int32)
        m.polygons.foreach_get("vertices", tri)
    mw = np.array(body.matrix_world)
    co = co.reshape(-1, 3).astype(np.float64) @ mw[:3, :3].T + mw[:3, 3]
    data[f"v{f}"], data["triangles"] = co, tri.reshape(-1, 3)
np.savez(out, **data)
scene.render.resolution_percentage = 25
scene.render.film_transparent = True
scene.render.image_settings.color_mode = "RGBA"
scene.render.filepath = png
bpy.ops.render.render(write_still=True)
'''


def test_tshirt_bakes_and_stays_outside_the_walking_body(tmp_path):
    frames = 12  # half a stride: the legs and the arms (in the sleeves) swing through their widest
    source = EXAMPLES / "tshirt.blend"
    baked = bake(source, tmp_path, "--frames", f"1-{frames}", timeout=400)
    assert baked["TShirt"]["frames"] == (1, frames)
    root = find_cache(tmp_path / "tearcloth_cache", "TShirt", "tshirt")
    script = tmp_path / "dump_body.py"
    script.write_text(PRELUDE + BODY_DUMP)  # the shared helpers (bpy only: the add-on stays out)
    dump, png = tmp_path / "body.npz", tmp_path / "tshirt.png"
    proc = subprocess.run([sys.executable, str(script), str(tmp_path / "tshirt.blend"), str(dump), str(png),
                           *map(str, range(1, frames + 1))], capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    import trimesh

    data = np.load(dump)
    triangles = data["triangles"]
    body = examples.mannequin()
    worst = {}
    for f in range(1, frames + 1):
        posed = data[f"v{f}"]
        # the rig in the file is the body of examples.body_pose (float32 round-off apart)
        assert np.abs(posed - examples.body_pose(body, (f - 1) / 24.0)).max() < 1e-4
        cloth, _, _ = cache.read_frame(root, f)
        inside = trimesh.Trimesh(posed, triangles, process=False).contains(cloth)
        _, distance, _ = examples.closest_points(posed, triangles, cloth)  # > 0 outside
        worst[f] = float(distance.min())
        assert not inside.any() and distance.min() > 0.0, (
            f"frame {f}: {int(inside.sum())} shirt vertices inside the body, deepest {-distance.min() * 1e3:.1f} mm")
        if f == 1:
            # at rest the shirt fits without touching: 12 mm clearance, never under 1 cm
            assert distance.min() > 0.010
    print("closest approach per frame (mm):", {f: round(d * 1e3, 1) for f, d in worst.items()})
    assert silhouette(png).mean() > 0.05  # the render shows the mannequin in its shirt


def test_denim_knee_tears_at_the_knee_and_keeps_its_frayed_edges(tmp_path):
    """The whole animation (the knee bent to 75 degrees by frame 36): the panel tears, and where: the
    new boundary (torn edges: in the cache, boundary points whose UV is inside the flat panel, not on
    its outline) lies around the knee. The baked copy still carries the frayed-edge modifier, after
    the cache's. Since friction is judged on the contact's reaction (a held vertex slides once its
    pull passes mu times the normal force) the panel slides over the kneecap and first tears near
    frame 26 (~50 degrees), no longer by frame 20, where the knee used to hold it whatever the pull."""
    end = 36  # example_blends/make_examples.py: DENIM_END
    baked = bake(EXAMPLES / "denim_knee.blend", tmp_path, "--frames", f"1-{end}")
    assert baked["DenimKnee"]["tears"] >= 1
    root = find_cache(tmp_path / "tearcloth_cache", "DenimKnee", "denim_knee")
    check_cache_torn(root, 1, end)
    v, t, uv = cache.read_frame(root, end)
    corner = uv.reshape(-1, 2)
    edges = np.sort(np.stack([t, np.roll(t, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    keys, counts = np.unique(edges[:, 0] * len(v) + edges[:, 1], return_counts=True)
    boundary = np.unique(np.r_[keys[counts == 1] // len(v), keys[counts == 1] % len(v)])
    point_uv = np.zeros((len(v), 2))
    point_uv[t.reshape(-1)] = corner
    panel = point_uv[boundary] * 0.25  # metres on the flat panel
    width, height = math.pi * (examples.LEG["radius"] + 0.012), 0.85 - 0.27
    inside = ((panel[:, 0] > 1e-4) & (panel[:, 0] < width - 1e-4) & (panel[:, 1] > 1e-4)
              & (panel[:, 1] < height - 1e-4))
    assert inside.sum() >= 10, "no torn edge inside the panel"
    knee = examples.LEG["knee"] - 0.27
    assert np.median(np.abs(panel[inside, 1] - knee)) < 0.05  # torn at the knee
    code = ("import sys, bpy\nbpy.ops.wm.open_mainfile(filepath=sys.argv[1])\n"
            "print('MODS', [m.name for m in bpy.data.objects['DenimKnee'].modifiers])\n")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "denim_knee.blend")], capture_output=True,
                          text=True, timeout=120)
    assert "MODS ['Tear Cloth', 'Tear Cloth Frayed Edges']" in proc.stdout, proc.stdout + proc.stderr


def test_the_committed_examples_are_what_the_generator_makes(tmp_path):
    """Regenerate all four files and compare every object, mesh (at rest and as posed by the rig),
    Tear Cloth setting and animated position with the committed ones: a change to the generator or
    to ``tearcloth.examples`` fails here until the examples are generated again. (The bytes of two
    saves differ anyway: Blender writes memory addresses.)"""
    dump = textwrap.dedent('''
        import json, sys, numpy as np, bpy
        import tearcloth
        tearcloth.register()
        out = {}
        for path in sys.argv[2:]:
            bpy.ops.wm.open_mainfile(filepath=path)
            d = {}
            for obj in bpy.data.objects:
                item = {"type": obj.type, "location": [round(c, 6) for c in obj.location]}
                if obj.type == "MESH":
                    co = np.empty(3 * len(obj.data.vertices), np.float32)
                    obj.data.vertices.foreach_get("co", co)
                    item["vertices"] = len(obj.data.vertices)
                    item["co_sum"] = round(float(np.abs(co).sum()), 3)
                    item["groups"] = sorted(g.name for g in obj.vertex_groups)
                    bpy.context.scene.frame_set(60)
                    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
                    m = ev.to_mesh()
                    co = np.empty(3 * len(m.vertices), np.float32)
                    m.vertices.foreach_get("co", co)
                    item["posed_co_sum"] = round(float(np.abs(co).sum()), 2)
                    ev.to_mesh_clear()
                if "Tear Cloth" in obj.modifiers:
                    s = obj.tearcloth
                    item["settings"] = {k: (round(v, 9) if isinstance(v, float) else v) for k, v in
                                        ((p.identifier, getattr(s, p.identifier)) for p in s.bl_rna.properties)
                                        if isinstance(v, (int, float, str, bool))}
                    item["handles"] = [(h.vertex_group, h.follow.name if h.follow else None) for h in s.handles]
                if obj.animation_data and obj.animation_data.action:
                    keys = []
                    for f in (1, 5, 12, 24, 36, 48, 80, 97):
                        bpy.context.scene.frame_set(f)
                        keys.append([round(c, 6) for c in obj.matrix_world.translation])
                    item["keys"] = keys
                d[obj.name] = item
            out[path] = d
        json.dump(out, open(sys.argv[1], "w"))
    ''')
    proc = subprocess.run([sys.executable, str(EXAMPLES / "make_examples.py"), "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    script = tmp_path / "dump.py"
    script.write_text(dump)
    names = ("square_cloth", "banknote", "tshirt", "denim_knee")
    files = [folder / f"{name}.blend" for name in names for folder in (EXAMPLES, tmp_path)]
    proc = subprocess.run([sys.executable, str(script), str(tmp_path / "dump.json"), *map(str, files)],
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    got = json.loads((tmp_path / "dump.json").read_text())
    for committed, fresh in zip(files[::2], files[1::2]):
        assert got[str(committed)] == got[str(fresh)], (
            f"{committed.name} is not what make_examples.py makes now: run example_blends/make_examples.py")
        assert committed.stat().st_size < 1_000_000  # small enough to commit


# ------------------------------------------------------------------------------------------------
# Bad input: one line, non-zero exit, no traceback


@pytest.fixture(scope="module")
def plain_blend(tmp_path_factory):
    """A saved .blend without any Tear Cloth object."""
    folder = tmp_path_factory.mktemp("plain")
    path = folder / "plain.blend"
    code = ("import sys, bpy\nbpy.ops.wm.read_factory_settings(use_empty=True)\n"
            "bpy.ops.mesh.primitive_plane_add()\nbpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])\n")
    proc = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return path


def run_cli(*args, timeout: float = 120.0):
    return subprocess.run([sys.executable, "-m", "tearcloth.cli", "bake", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


def bad_input_cases(tmp: Path, plain: Path):
    square = EXAMPLES / "square_cloth.blend"
    text = tmp / "notes.blend"
    text.write_text("not a blend file\n")
    a_file = tmp / "a_file"
    a_file.write_text("x")
    return {
        "missing file": ([tmp / "nowhere.blend"], "no such file"),
        "a folder": ([tmp], "is a folder"),
        "not a .blend": ([text], "not a .blend file"),
        "no Tear Cloth object": ([plain, "--out", tmp / "o1"], "has no Tear Cloth object"),
        "unknown object": ([square, "--objects", "Nope", "--out", tmp / "o2"], "no object named 'Nope'"),
        "not a Tear Cloth object": ([square, "--objects", "Camera", "--out", tmp / "o3"],
                                    "'Camera' is not a Tear Cloth object"),
        "frames reversed": ([square, "--frames", "30-10"], "must come before"),
        "frames not numbers": ([square, "--frames", "one-ten"], "--frames wants A-B"),
        "frames without a range": ([square, "--frames", "12"], "--frames wants A-B"),
        "frames beyond Blender's": ([square, "--frames", "1-99999999999999999999"], "beyond Blender's frames"),
        "output is a file": ([square, "--out", a_file], "is a file, not a folder"),
        "output under a file": ([square, "--out", a_file / "sub"], "cannot create the output folder"),
        "output is the input": ([square, "--out", EXAMPLES], "is the input file"),
        "render to a non-PNG": ([square, "--render", tmp / "x.jpg"], "does not end in .png"),
        "several frames, one name": ([square, "--render", tmp / "x.png", "--render-frame", "1,2"], "need # in"),
        "render frame not a number": ([square, "--render", tmp / "x.png", "--render-frame", "last"],
                                      "--render-frame wants frame numbers"),
        "transparent without render": ([square, "--transparent"], "--transparent needs --render"),
        "unknown option": ([square, "--fast"], "unrecognized arguments: --fast"),
    }


def test_bad_input_gives_one_error_line_and_a_non_zero_exit(tmp_path, plain_blend):
    cases = bad_input_cases(tmp_path, plain_blend)
    failures = []
    for label, (args, expected) in cases.items():
        proc = run_cli(*args)
        errors = [line for line in proc.stderr.splitlines() if "error" in line.lower()]
        ok = (proc.returncode == 2 and len(errors) == 1 and errors[0].startswith("tearcloth bake: error: ")
              and expected in errors[0] and "Traceback" not in proc.stderr + proc.stdout)
        if not ok:
            failures.append(f"{label}: exit {proc.returncode}, stderr {proc.stderr[-600:]!r}")
    assert not failures, "\n".join(failures)
    # nothing was left behind by the refused runs
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()
    assert not (EXAMPLES / "square_cloth_baked").exists()


def test_overwrite_bakes_into_the_given_file_only(tmp_path):
    work = tmp_path / "shot.blend"
    shutil.copy2(EXAMPLES / "square_cloth.blend", work)
    before = work.read_bytes()
    proc = run_cli(work, "--overwrite", "--frames", "1-3", timeout=240)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    assert work.read_bytes() != before and (tmp_path / "shot.blend1").exists()  # Blender's usual backup
    assert cache.cache_info(find_cache(tmp_path / "tearcloth_cache", "SquareCloth", "shot"))["frames"] == [1, 2, 3]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shot.blend", "shot.blend1", "tearcloth_cache"]
