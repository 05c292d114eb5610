"""`tearcloth bake` stopped by SIGTERM or SIGINT and run again (issue 12, defects 5 and 6), always
in a subprocess, on the repository's square cloth (tearing on, no collider):

* a signal mid-bake: the frame being simulated is dropped, every complete frame is kept, the
  .blend is saved pointing at them, ONE line on stderr says so, exit status 143 (SIGTERM) or
  130 (SIGINT);
* the same command again resumes after the last complete frame, says so, keeps the frames
  already on disk byte for byte, and ends with the topology and the positions (to the bit) of an
  uninterrupted bake (the T-shirt, with collision, and SIGKILL: test_bake_resume_tshirt.py);
* ``--restart`` bakes from the first frame.
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")
from tearcloth import cache  # noqa: E402

from test_blender_bake import find_cache  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SQUARE = REPO / "example_blends" / "square_cloth.blend"
FRAMES = "1-14"


def command(out: Path, *extra) -> list:
    return [sys.executable, "-m", "tearcloth.cli", "bake", str(SQUARE), "--out", str(out), "--frames", FRAMES,
            *extra]


def root(out: Path) -> Path:
    return Path(find_cache(out / "tearcloth_cache", "SquareCloth", "square_cloth"))


def signal_at(cmd: list, out: Path, pattern: str, sig: int, timeout: float = 200) -> subprocess.CompletedProcess:
    """Start ``cmd``, send ``sig`` once a file matching ``pattern`` is in ``out/tearcloth_cache``,
    wait for the end."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout
    while not list((out / "tearcloth_cache").glob(pattern)):
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() < deadline, "the bake did not reach the frame"
        time.sleep(0.02)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def stop_mid_bake(out: Path, sig: int, after_frame: int = 5) -> subprocess.CompletedProcess:
    """Start the bake, send ``sig`` once frame ``after_frame`` is in the cache, wait for the end."""
    # the final frames folder, not the hidden staging
    return signal_at(command(out), out, f"square_cloth/SquareCloth_frames/frame_{after_frame:06d}.usdc", sig)


def frames_of(path: Path) -> dict:
    info = cache.cache_info(path)
    return {f: cache.read_frame(path, f) for f in info["frames"]}


@pytest.fixture(scope="module")
def whole(tmp_path_factory) -> Path:
    """The output folder of one uninterrupted bake (the saved .blend and its cache)."""
    out = tmp_path_factory.mktemp("whole")
    proc = subprocess.run(command(out), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def uninterrupted(whole):
    return frames_of(root(whole))


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_keeps_frames_saves_and_resume_matches(tmp_path, uninterrupted, sig, code):
    out = tmp_path / "out"
    stopped = stop_mid_bake(out, sig)
    assert stopped.returncode == code, stopped.stderr[-3000:]
    name = signal.Signals(sig).name
    lines = [line for line in stopped.stderr.splitlines() if "stopped by" in line]
    assert len(lines) == 1 and name in lines[0] and "kept" in lines[0] and "saved" in lines[0], stopped.stderr
    assert "Traceback" not in stopped.stderr
    info = cache.cache_info(root(out))
    last = info["frames"][-1]
    assert not info["complete"] and info["frames"] == list(range(1, last + 1)) and last >= 5
    assert (out / "square_cloth.blend").exists()
    kept_bytes = {f: Path(file).read_bytes() for f, file in zip(info["frames"], info["frame_files"])}

    again = subprocess.run(command(out), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-3000:]
    assert f"resuming the partial bake after frame {last}" in again.stderr, again.stderr
    info = cache.cache_info(root(out))
    assert info["complete"] and info["frames"] == list(range(1, 15))
    for f, file in zip(info["frames"], info["frame_files"]):
        if f in kept_bytes:
            assert Path(file).read_bytes() == kept_bytes[f], f"frame {f} was rewritten"
    resumed = frames_of(root(out))
    for f, (positions, triangles, uv) in uninterrupted.items():
        got = resumed[f]
        assert got[1].shape == triangles.shape and np.array_equal(got[1], triangles), f"frame {f}: topology"
        # before the stop and after it: the resumed bake continues the whole saved state
        assert np.array_equal(got[0], positions), f"frame {f}"


def test_restart_bakes_from_the_first_frame(tmp_path):
    out = tmp_path / "out"
    stopped = stop_mid_bake(out, signal.SIGTERM, after_frame=3)
    assert stopped.returncode == 143
    first = Path(cache.cache_info(root(out))["frame_files"][0]).stat().st_mtime_ns
    again = subprocess.run(command(out, "--restart"), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "resuming" not in again.stderr
    info = cache.cache_info(root(out))
    assert info["complete"] and info["frames"] == list(range(1, 15))
    assert Path(info["frame_files"][0]).stat().st_mtime_ns != first  # baked again
    stem = root(out).stem
    assert sorted(os.listdir(root(out).parent)) == [f"{stem}.state.npz", f"{stem}.usda", f"{stem}_frames"]


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_a_stopped_rebake_resumes_beside_the_previous_bake(tmp_path, whole, uninterrupted, sig):
    """A re-bake (``--restart`` over a complete bake) killed with SIGKILL (a crash: no chance to
    tidy up) or stopped by SIGTERM (a farm manager's preemption: kept on purpose, and said) midway
    leaves the previous bake as it was and its own frames and state beside it; the same command
    again resumes that re-bake there, says so, and replaces the previous bake once complete,
    ending bit for bit as an uninterrupted bake, with nothing left beside it."""
    out = tmp_path / "out"
    shutil.copytree(whole, out, symlinks=True)  # a complete bake to re-bake over
    before = {f: Path(file).read_bytes() for f, file in
              zip(cache.cache_info(root(out))["frames"], cache.cache_info(root(out))["frame_files"])}
    staged = Path(cache.staging_path_for(root(out)))
    killed = signal_at(command(out, "--restart"), out, f"square_cloth/{staged.stem}_frames/frame_000005.usdc", sig)
    if sig == signal.SIGKILL:
        assert killed.returncode == -9
    else:
        lines = [line for line in killed.stderr.splitlines() if "stopped by SIGTERM" in line]
        assert killed.returncode == 143 and len(lines) == 1, killed.stderr[-3000:]
        assert "SquareCloth's previous bake (its re-bake's frames 1-" in lines[0] and "wait beside it" in lines[0] \
            and "run the same command again to resume" in lines[0] and "starts over" not in lines[0], lines[0]
    info = cache.cache_info(root(out))
    assert info["complete"] and {f: Path(file).read_bytes() for f, file in
                                 zip(info["frames"], info["frame_files"])} == before  # as it was
    left = cache.interrupted_rebake(root(out))
    assert left is not None and left["frames"][-1] >= 4, left
    last = left["frames"][-1]

    again = subprocess.run(command(out), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-3000:]
    # (after the root's last frame, or the one after it: a kill between a frame file's rename and
    # the root's rewrite leaves a complete frame the root does not name yet, which resume adopts)
    said = re.search(r"resuming the interrupted re-bake \(the previous bake stays until it is complete\) "
                     r"after frame (\d+)", again.stderr)
    assert said and int(said.group(1)) in (last, last + 1), (last, again.stderr[-3000:])
    info = cache.cache_info(root(out))
    assert info["complete"] and info["frames"] == list(range(1, 15))
    resumed = frames_of(root(out))
    for f, (positions, triangles, uv) in uninterrupted.items():
        assert np.array_equal(resumed[f][1], triangles) and np.array_equal(resumed[f][0], positions), f"frame {f}"
    stem = root(out).stem
    assert sorted(os.listdir(root(out).parent)) == [f"{stem}.state.npz", f"{stem}.usda", f"{stem}_frames"]


SIGNAL_IN_SAVE = '''
import os, signal, sys
from tearcloth import cli
from tearcloth.blender import headless
real = headless._save
def save_under_a_signal(path, compress, copy_to=False):
    if not copy_to:  # the save after the bake (the first one copies the input to --out)
        os.kill(os.getpid(), signal.SIGTERM)  # the farm manager's SIGTERM, as the .blend is written
    return real(path, compress, copy_to)
headless._save = save_under_a_signal
sys.exit(cli.main(sys.argv[1:]))
'''


def test_a_signal_while_the_blend_is_saved_lets_the_save_finish(tmp_path):
    """SIGTERM that comes after the last frame, while the .blend is written (a farm manager's
    preemption; a fresh-clone CI run hit it at random): the handlers covered the bake only, so the
    signal's default action killed the process half-way through its end (status -15, no summary).
    Now the save finishes, the file points at the complete bake, and the one line says the run
    stopped after every bake was complete (status 143)."""
    out = tmp_path / "out"
    script = tmp_path / "child.py"
    script.write_text(SIGNAL_IN_SAVE)
    done = subprocess.run([sys.executable, str(script), "bake", str(SQUARE), "--out", str(out), "--frames", "1-3"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 143, (done.returncode, done.stderr[-3000:])
    lines = [line for line in done.stderr.splitlines() if "stopped by SIGTERM" in line]
    assert len(lines) == 1 and "after every bake was complete" in lines[0] and "saved" in lines[0], done.stderr
    assert "Traceback" not in done.stderr
    assert (out / "square_cloth.blend").exists()
    info = cache.cache_info(root(out))
    assert info["complete"] and info["frames"] == [1, 2, 3]


def test_another_input_baked_into_the_same_output_never_resumes_the_first_ones_bake(tmp_path, uninterrupted):
    """Two shot files of one name (A/square_cloth.blend, B/square_cloth.blend) baked with the
    same --out: A stopped by SIGTERM, then B. B's copy replaced A's in --out, and B resumed A's
    partial bake (the mesh and settings agree; the animation need not: 37 of 40 frames mixed in a
    probe). The cache now records the input it was made from: B's run says it cannot resume A's
    bake, bakes from the start, and ends as a bake of B alone."""
    out = tmp_path / "out"
    inputs = {}
    for name in ("A", "B"):
        (tmp_path / name).mkdir()
        inputs[name] = tmp_path / name / SQUARE.name
        shutil.copy(SQUARE, inputs[name])
    cmd = lambda src: [sys.executable, "-m", "tearcloth.cli", "bake", str(src), "--out", str(out), "--frames", FRAMES]
    stopped = signal_at(cmd(inputs["A"]), out, "square_cloth/SquareCloth_frames/frame_000005.usdc", signal.SIGTERM)
    assert stopped.returncode == 143, stopped.stderr[-3000:]
    again = subprocess.run(cmd(inputs["B"]), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "cannot be resumed" in again.stderr and f"made from {inputs['A'].resolve()}" in again.stderr, \
        again.stderr[-3000:]
    assert "resuming" not in again.stderr
    info = cache.cache_info(root(out))
    assert info["complete"] and info["frames"] == list(range(1, 15))
    assert info["owner"]["source"] == str(inputs["B"].resolve())
    baked = frames_of(root(out))
    for f, (positions, triangles, uv) in uninterrupted.items():  # B is a copy of the square: its own bake
        assert np.array_equal(baked[f][1], triangles) and np.array_equal(baked[f][0], positions), f"frame {f}"
