"""Kill-and-resume equality on the T-shirt (issue 12, defect 5; collision with the walking
mannequin and tearing on), from the CLI, always in subprocesses:

* an uninterrupted ``tearcloth bake`` of frames 1-84 (the hands grab the hem at frame 73 and the
  first tear opens at frame 80) is the reference;
* the same command stopped by SIGTERM once frame 81 is in the cache (a tear is running: tips,
  scan position, collision tracks on the torn rims), then run again: it resumes after the last
  complete frame;
* a copy of that stopped bake resumed and killed by SIGKILL (no handler runs: no .blend saved,
  the state file and the cache are what a crash leaves) once frame 82 is in, then run again;
* another copy resumed by the OPERATOR's path (the modal bake's worker thread, ticked without a
  window), cancelled (Esc) a frame later and resumed by the Bake operator;
* every frame of the three equals the reference's: the same topology and positions to the bit
  (the tolerance 1e-9 m of the issue, met exactly: the state is the session's whole state).

Runtime: two 84-frame bakes (~100 s each on a free core) plus five short runs (Blender start-up
and a few frames each): about 4 to 5 minutes.
"""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")
from tearcloth import cache  # noqa: E402

from test_bake_resume_cli import frames_of, signal_at  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHIRT = REPO / "example_blends" / "tshirt.blend"
LAST = 84       # frames 1-84: the first tear opens at frame 80
TERM_AT = 81    # a tear is running when SIGTERM comes
KILL_AT = 82


def command(out: Path) -> list:
    return [sys.executable, "-m", "tearcloth.cli", "bake", str(SHIRT), "--out", str(out), "--frames", f"1-{LAST}"]


def root(out: Path) -> Path:
    return out / "tearcloth_cache" / "tshirt" / "TShirt.usda"


def run_until(out: Path, frame: int, sig: int) -> subprocess.CompletedProcess:
    """Start (or resume) the bake, send ``sig`` once ``frame`` is in the cache, wait for the end."""
    return signal_at(command(out), out, f"tshirt/TShirt_frames/frame_{frame:06d}.usdc", sig, timeout=600)


def resume(out: Path, after) -> dict:
    """Run the bake again; it must resume after one of the frames ``after`` (an int or a tuple)."""
    allowed = (after,) if isinstance(after, int) else tuple(after)
    again = subprocess.run(command(out), capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert any(f"resuming the partial bake after frame {a}" in again.stderr for a in allowed), again.stderr[-3000:]
    info = cache.cache_info(root(out))
    assert info["complete"] and info["frames"] == list(range(1, LAST + 1))
    return frames_of(root(out))


def assert_same(got: dict, want: dict, label: str) -> None:
    worst = 0.0
    for f, (positions, triangles, _uv) in want.items():
        p, t, _ = got[f]
        assert t.shape == triangles.shape and np.array_equal(t, triangles), f"{label}, frame {f}: topology"
        assert p.shape == positions.shape, f"{label}, frame {f}: vertices"
        worst = max(worst, float(np.abs(p - positions).max()))
    print(f"{label}: largest difference over {len(want)} frames {worst:.3g} m")
    assert worst <= 1e-9, f"{label}: {worst} m"


def test_tshirt_killed_cancelled_and_resumed_equals_the_uninterrupted_bake(tmp_path):
    whole = tmp_path / "whole"
    proc = subprocess.run(command(whole), capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    reference = frames_of(root(whole))
    first_torn = min(f for f, (p, _, _) in reference.items() if len(p) > len(reference[1][0]))
    assert first_torn <= TERM_AT, f"the shirt must tear before the stop (first torn frame {first_torn})"

    termed = tmp_path / "term"
    stopped = run_until(termed, TERM_AT, signal.SIGTERM)
    assert stopped.returncode == 143, stopped.stderr[-3000:]
    last = cache.cache_info(root(termed))["frames"][-1]
    assert TERM_AT <= last < LAST
    killed, operated = tmp_path / "kill", tmp_path / "operator"
    shutil.copytree(termed, killed)  # the stopped bake, resumed below and killed mid-way
    shutil.copytree(termed, operated)  # ... and resumed by the operator, cancelled, resumed

    assert_same(resume(termed, last), reference, "SIGTERM at frame %d" % last)

    crashed = run_until(killed, KILL_AT, signal.SIGKILL)
    assert crashed.returncode == -signal.SIGKILL
    after = cache.cache_info(root(killed))["frames"][-1]
    # the kill lands once frame 82's file exists; the root lists a frame only after its file is
    # complete, so a kill between the two leaves 81 as the last listed frame (seen on a loaded
    # machine). The resume repairs such a root: it takes frame 82's file when that file is whole
    # (seen twice under load), else it continues after 81; either must equal the reference.
    assert KILL_AT - 1 <= after < LAST
    assert_same(resume(killed, (after, after + 1)), reference, "SIGKILL at frame %d" % after)

    # the operator's path (the modal bake's worker thread, ticked here without a window) on the
    # torn state: Bake with resume, Esc once a frame more is baked, Bake with resume again
    script = tmp_path / "cancel_and_resume.py"
    script.write_text(OPERATOR)
    proc = subprocess.run([sys.executable, str(script), str(operated / "tshirt.blend"), str(last + 1), str(LAST)],
                          capture_output=True, text=True, timeout=900, cwd=tmp_path)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1].split()
    state, stopped, resumed, path = line[1], int(line[2]), line[3], line[4]
    assert state == "cancelled" and last < stopped < LAST and resumed == "['FINISHED']", line
    assert Path(path) == root(operated)
    info = cache.cache_info(path)
    assert info["complete"] and info["frames"] == list(range(1, LAST + 1))
    assert_same(frames_of(Path(path)), reference, f"operator: resumed after {last}, cancelled at {stopped}")


OPERATOR = """
import sys, time
import bpy
import tearcloth
from tearcloth.blender import bake

blend, stop_at, last = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
tearcloth.register()
bpy.ops.wm.open_mainfile(filepath=blend)
obj = bpy.data.objects["TShirt"]
obj.tearcloth.frame_end = last  # the range the CLI baked (--frames 1-84)
ctx = bpy.context
run = bake.BakeRun(ctx, obj, resume=True)
run.start_thread(ctx)
while run.tick(ctx):
    time.sleep(0.005)
    p = run.progress
    if p.frame is not None and p.frame >= stop_at and p.state == "running":
        run.stop()  # what Esc does
state = run.finish(ctx)
stopped = run.job.writer.frames[-1]
with ctx.temp_override(object=obj, active_object=obj, selected_objects=[obj]):
    resumed = bpy.ops.tearcloth.bake(resume=True)
print("RESULT", state, stopped, sorted(resumed), run.plan.cache_path, flush=True)
"""


