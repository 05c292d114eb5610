"""Sub-steps whose solve stopped at the iteration cap even after splitting are said to the user
(issue 14): a bake of the square cloth with a cap of 2 CG iterations, headless; the
``tearcloth bake`` output warns with the count, and the physics panel of the saved .blend shows
the same count (every Blender run in a subprocess)."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")
from test_blender_bake import run_blender  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SQUARE = REPO / "example_blends" / "square_cloth.blend"

PANEL = '''
    import tearcloth
    from tearcloth.blender import bake, ui
    tearcloth.register()
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False, use_scripts=False)
    obj = bpy.data.objects["SquareCloth"]
    labels = []
    class Layout:
        def __getattr__(self, name):
            def call(*args, **kwargs):
                if name == "label":
                    labels.append(kwargs.get("text", ""))
                return self
            return call
    class Holder: pass
    holder = Holder(); holder.layout = Layout()
    with bpy.context.temp_override(object=obj, active_object=obj):
        ui.TEARCLOTH_PT_main.draw(holder, bpy.context)
    result(dict(labels=labels, recorded=list(bake.last_convergence(obj) or [])))
'''


def capped_blend(tmp_path: Path, cap: int) -> Path:
    run_blender(tmp_path, '''
        import tearcloth
        tearcloth.register()
        bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False, use_scripts=False)
        bpy.data.objects["SquareCloth"].tearcloth.cg_max_iterations = int(sys.argv[2])
        bpy.ops.wm.save_as_mainfile(filepath=sys.argv[3], copy=True)
        result(True)
    ''', SQUARE, cap, tmp_path / "capped.blend", name="cap.py")
    return tmp_path / "capped.blend"


def test_capped_solves_are_counted_in_the_bake_log_and_the_panel(tmp_path):
    blend = capped_blend(tmp_path, 2)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "tearcloth.cli", "bake", str(blend), "--out", str(out),
                           "--frames", "1-3"], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    warning = [line for line in proc.stderr.splitlines() if "stopped at the CG iteration cap (2)" in line]
    assert len(warning) == 1 and warning[0].startswith("tearcloth bake: warning: SquareCloth: "), proc.stderr
    n, steps = (int(x) for x in re.search(r"(\d+) sub-steps? in (\d+) steps?", warning[0]).groups())
    assert n >= steps >= 1
    # the progress lines say it too
    assert re.search(rf"\b{n} sub-steps? unconverged", proc.stderr), proc.stderr
    got = run_blender(tmp_path, PANEL, out / "capped.blend", name="panel.py")
    assert got["recorded"][:2] == [n, steps]
    line = [t for t in got["labels"] if "CG cap" in t]
    assert line and line[0].startswith(f"{n} sub-step") and f"in {steps} of " in line[0], got["labels"]


def test_a_converged_bake_says_so_in_the_panel(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "tearcloth.cli", "bake", str(SQUARE), "--out", str(out),
                           "--frames", "1-2"], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "iteration cap" not in proc.stderr and "unconverged" not in proc.stderr
    got = run_blender(tmp_path, PANEL, out / "square_cloth.blend", name="panel.py")
    assert got["recorded"][:2] == [0, 0]
    assert any(t.startswith("Every solve converged") for t in got["labels"]), got["labels"]
