"""`tearcloth farm` on real Dask clusters on 127.0.0.1: a LocalCluster of two workers, and a
`dask scheduler` with two `dask worker` processes started here, one of them SIGKILLed mid-task.

What is checked: a 2x2 wedge of the square cloth bakes into four folders (four caches) that play
in a fresh Blender without the add-on (a stock Mesh Sequence Cache modifier, vertex counts per
frame against the USD files read with usd-core); the manifest and the contact sheet (four labelled
cells); a killed worker's task is retried and the run completes; a scene's text block registered
to run on load never runs; bad input is one line and starts nothing. Bakes are short (frames 1-6)
so the file runs in a few minutes on two cores.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")
pytest.importorskip("bpy")  # the tasks' subprocesses need Blender

REPO = Path(__file__).resolve().parents[1]
SQUARE = REPO / "example_blends" / "square_cloth.blend"
BIN = Path(sys.executable).parent
WEDGE = ["--set", "tear_stress=1e6,4e6", "--set", "bending=5e-6,5e-3", "--frames", "1-6"]
OBJECT = "SquareCloth"


def _farm(*args, timeout=300, **kw):
    t0 = time.perf_counter()
    proc = subprocess.run([str(BIN / "tearcloth"), "farm", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, **kw)
    return proc, time.perf_counter() - t0


def _farm_inline(capsys, *args) -> tuple[int, list]:
    """`tearcloth farm` in this process (bad input never gets as far as a cluster): (status,
    stderr lines)."""
    from tearcloth import cli

    capsys.readouterr()
    code = cli.main(["farm", *map(str, args)])
    return code, capsys.readouterr().err.strip().splitlines()


def _manifest(out: Path) -> dict:
    return json.loads((out / "manifest.json").read_text())


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs: list) -> None:
    """Workers first, then the scheduler; a process that does not stop in 20 s is killed."""
    for p in reversed(procs):
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()


@pytest.fixture(scope="module")
def local_two(tmp_path_factory):
    out = tmp_path_factory.mktemp("local2")
    proc, wall = _farm(SQUARE, *WEDGE, "--workers", 2, "--out", out)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, wall, proc


@pytest.fixture(scope="module")
def blends(tmp_path_factory):
    """trap.blend: the square cloth with a text block registered to run on load (it writes a
    marker file); plain.blend: the square cloth with its Tear Cloth modifier removed."""
    folder = tmp_path_factory.mktemp("blends")
    marker = folder / "the_trap_ran.txt"
    script = folder / "make.py"
    script.write_text(f"""
import bpy
bpy.ops.wm.open_mainfile(filepath={str(SQUARE)!r}, load_ui=False)
text = bpy.data.texts.new("trap.py")
text.from_string("open({str(marker)!r}, 'w').write('ran')\\n")
text.use_module = True
bpy.ops.wm.save_as_mainfile(filepath={str(folder / 'trap.blend')!r})
obj = bpy.data.objects[{OBJECT!r}]
obj.modifiers.remove(obj.modifiers["Tear Cloth"])
bpy.data.texts.remove(text)
bpy.ops.wm.save_as_mainfile(filepath={str(folder / 'plain.blend')!r})
""")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return folder, marker


# ------------------------------------------------------------------------------------------------
# bad input: one line each, nothing started


@pytest.mark.parametrize("args, expected", [
    (["--set", "no_such_thing=1,2"], "--set no_such_thing: unknown parameter"),
    (["--set", "tear_stress=-1,2e6"], "outside its hard bounds"),
    (["--set", "thickness=0.001"], "ambiguous, say which: material.thickness, collision.thickness"),
    (["--set", "time_step=0.001"], "cannot be wedged"),
])
def test_bad_settings_are_one_line_and_start_nothing(tmp_path, capsys, args, expected):
    out = tmp_path / "never"
    code, lines = _farm_inline(capsys, SQUARE, *args, "--out", out)
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith("tearcloth farm: error: ") and expected in lines[0], lines
    assert not out.exists()


def test_unreachable_scheduler_is_one_line(tmp_path, capsys):
    out = tmp_path / "never"
    code, lines = _farm_inline(capsys, SQUARE, "--scheduler", f"tcp://127.0.0.1:{_free_port()}", "--out", out)
    assert code == 2
    assert len(lines) == 1 and "cannot reach a scheduler there" in lines[0], lines
    assert not out.exists()


def test_a_file_without_tear_cloth_objects_is_one_line(tmp_path, capsys, blends):
    folder, _ = blends
    out = tmp_path / "never"
    code, lines = _farm_inline(capsys, SQUARE, folder / "plain.blend", "--out", out)
    assert code == 2
    assert lines == ["tearcloth farm: error: plain.blend has no Tear Cloth object in scene 'Scene' "
                     "(enable it on a mesh: Properties > Physics > Tear Cloth)"], lines
    assert not out.exists()


# ------------------------------------------------------------------------------------------------
# the wedge on a LocalCluster


def test_a_2x2_wedge_bakes_four_variations_into_four_caches(local_two):
    out, wall, proc = local_two
    m = _manifest(out)
    tasks = m["tasks"]
    assert m["workers"] == 2 and m["scheduler"] == "local" and len(tasks) == 4
    assert [t["status"] for t in tasks] == ["done"] * 4
    combos = {(t["settings"]["material.tear_stress"], t["settings"]["material.bending"]) for t in tasks}
    assert combos == {(1e6, 5e-6), (1e6, 5e-3), (4e6, 5e-6), (4e6, 5e-3)}
    caches = {t["cache"] for t in tasks}
    assert len(caches) == 4 and all(Path(c).is_file() for c in caches)
    for t in tasks:
        assert t["frames"] == [1, 6] and t["object"] == OBJECT and t["auto_execute"] is False
        assert Path(t["cache"]).is_relative_to(t["folder"]) and Path(t["folder"]).name == t["label"].replace(", ", ",")
        assert t["seconds"] > 0 and t["vertices"] > 0 and t["attempts"] == 1
        assert t["worker"].startswith("tcp://127.0.0.1:")  # the local cluster listens on the loopback only
    assert m["scheduler_address"].startswith("tcp://127.0.0.1:")
    # each baked copy carries its own variation's settings on the object
    script = ("import bpy, json, sys\nfrom tearcloth.blender import register\nregister()\nout = {}\n"
              "for path in sys.argv[1:]:\n"
              "    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)\n"
              f"    s = bpy.data.objects[{OBJECT!r}].tearcloth\n"
              "    out[path] = [s.tear_stress, s.bending, bpy.context.scene.render.engine]\n"
              "print(json.dumps(out))\n")
    read = subprocess.run([sys.executable, "-c", script, *[t["blend"] for t in tasks]], capture_output=True,
                          text=True, timeout=120)
    assert read.returncode == 0, read.stderr[-2000:]
    stored = json.loads(read.stdout.strip().splitlines()[-1])
    for t in tasks:
        tear, bending, engine = stored[t["blend"]]
        assert tear == pytest.approx(t["settings"]["material.tear_stress"], rel=1e-6)
        assert bending == pytest.approx(t["settings"]["material.bending"], rel=1e-6)
        assert engine == "BLENDER_WORKBENCH"
    print(f"\n2x2 wedge on a LocalCluster of 2 workers: {wall:.1f} s wall (command), "
          f"{m['wall_seconds']:.1f} s in the run; per task {[round(t['seconds'], 1) for t in tasks]} s")


def test_the_contact_sheet_has_four_labelled_cells(local_two):
    from tearcloth.farm.sheet import _layout, label

    out, _, _ = local_two
    m = _manifest(out)
    sheet = Path(m["contact_sheet"])
    assert sheet.is_file()
    rows, cols, cells = _layout(m["tasks"])
    assert (rows, cols) == (2, 2) and sorted((r, c) for r, c, _ in cells) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    labels = {label(t, False) for _, _, t in cells}
    assert labels == {"tear_stress=1e+06\nbending=5e-06", "tear_stress=1e+06\nbending=0.005",
                      "tear_stress=4e+06\nbending=5e-06", "tear_stress=4e+06\nbending=0.005"}
    import matplotlib.image as mpimg

    image = mpimg.imread(sheet)
    assert image.shape[0] > 600 and image.shape[1] > 600  # four cells of 3.6 x 3.4 in at 100 dpi
    for t in m["tasks"]:
        render = mpimg.imread(t["render"])
        assert render.std() > 0.01  # a picture, not a blank frame


_PLAY = """
import json, sys
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
out = {}
for path in sys.argv[1:]:
    bpy.ops.mesh.primitive_plane_add()
    obj = bpy.context.object
    md = obj.modifiers.new("cache", "MESH_SEQUENCE_CACHE")
    before = set(bpy.data.cache_files)
    bpy.ops.cachefile.open(filepath=path, relative_path=False)  # there is no cache_files.new()
    (md.cache_file,) = [cf for cf in bpy.data.cache_files if cf not in before]
    md.object_path = "/SquareCloth"
    counts = {}
    for frame in (6, 1, 3, 2, 5, 4):  # scrub out of order
        bpy.context.scene.frame_set(frame)
        counts[frame] = len(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.vertices)
    out[path] = counts
    bpy.data.objects.remove(obj)
assert not any(name.split(".")[0] == "tearcloth" for name in sys.modules)  # stock Blender only
print(json.dumps(out))
"""


def _usd_counts(path: str) -> dict:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(path)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/SquareCloth"))
    return {f: len(mesh.GetPointsAttr().Get(f)) for f in range(1, 7)}


def _play(caches: list, tmp_path: Path) -> dict:
    script = tmp_path / "play.py"
    script.write_text(_PLAY)
    env = dict(os.environ, PYTHONNOUSERSITE="1")
    proc = subprocess.run([sys.executable, "-I", str(script), *caches], capture_output=True, text=True, timeout=120,
                          env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return {path: {int(f): n for f, n in counts.items()}
            for path, counts in json.loads(proc.stdout.strip().splitlines()[-1]).items()}


def test_all_four_caches_play_in_blender_without_the_add_on(local_two, tmp_path):
    pytest.importorskip("pxr")
    out, _, _ = local_two
    caches = [t["cache"] for t in _manifest(out)["tasks"]]
    played = _play(caches, tmp_path)
    for cache in caches:
        expected = _usd_counts(cache)
        assert played[cache] == expected and min(expected.values()) > 0


# ------------------------------------------------------------------------------------------------
# a scheduler and workers started separately; a worker SIGKILLed mid-task


@pytest.fixture
def dask_cluster(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = tmp_path / "logs"
    logs.mkdir()
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], stdout=subprocess.DEVNULL,
                              stderr=open(logs / "scheduler.log", "w"), cwd=tmp_path)]
    for i in range(2):
        procs.append(subprocess.Popen([str(BIN / "dask"), "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                                       "--nworkers", "1", "--no-dashboard", "--name", f"w{i}"],
                                      stdout=subprocess.DEVNULL, stderr=open(logs / f"worker{i}.log", "w"), cwd=tmp_path))
    from distributed import Client

    client = None
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                client = client or Client(address, timeout="5s")
                if len(client.scheduler_info(n_workers=-1)["workers"]) == 2:
                    break
            except OSError:
                pass
            assert time.monotonic() < deadline, "the workers did not join"
            time.sleep(0.5)
        yield address, client
    finally:
        if client is not None:
            client.close()
        _stop(procs)


def test_a_wedge_on_a_separate_scheduler_survives_a_killed_worker(dask_cluster, tmp_path):
    address, client = dask_cluster
    out = tmp_path / "remote"
    farm = subprocess.Popen([str(BIN / "tearcloth"), "farm", str(SQUARE), *WEDGE, "--scheduler", address,
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    t0 = time.perf_counter()
    try:
        # mid-task: once the second frame of some variation is on disk, kill a worker that is baking
        deadline = time.monotonic() + 120
        while killed is None and time.monotonic() < deadline and farm.poll() is None:
            if list(out.glob("*/*/*/tearcloth_cache/**/*_frames/frame_000002.usdc")):
                busy = [addr for addr, keys in client.processing().items() if keys]
                if busy:
                    pids = client.run(os.getpid, workers=[busy[0]])
                    killed = pids[busy[0]]
                    os.kill(killed, signal.SIGKILL)
            time.sleep(0.2)
        stdout, stderr = farm.communicate(timeout=300)
    finally:
        if farm.poll() is None:
            farm.kill()
    wall = time.perf_counter() - t0
    assert killed is not None, "no task was caught mid-bake"
    assert farm.returncode == 0, stderr[-3000:]
    m = _manifest(out)
    assert m["scheduler"] == address and [t["status"] for t in m["tasks"]] == ["done"] * 4
    retried = [t for t in m["tasks"] if t["attempts"] > 1]
    assert retried and all(t["pid"] != killed for t in m["tasks"])
    assert "attempt 2" in stderr
    assert all(t["frames"] == [1, 6] for t in m["tasks"])
    played = _play([t["cache"] for t in m["tasks"]], tmp_path)
    pytest.importorskip("pxr")
    for t in m["tasks"]:
        assert played[t["cache"]] == _usd_counts(t["cache"])
    print(f"\n2x2 wedge on a dask scheduler + 2 dask workers, worker pid {killed} SIGKILLed mid-task: "
          f"{wall:.1f} s wall, retried: {[t['label'] for t in retried]}")


# ------------------------------------------------------------------------------------------------
# safety and speed


def test_a_text_block_registered_to_run_on_load_never_runs(blends, tmp_path):
    folder, marker = blends
    # the trap is armed: opened trusting the file, Blender runs it
    probe = subprocess.run([sys.executable, "-c", "import bpy, sys; "
                            "bpy.ops.wm.open_mainfile(filepath=sys.argv[1], use_scripts=True)", str(folder / "trap.blend")],
                           capture_output=True, text=True, timeout=120)
    assert probe.returncode == 0 and marker.exists(), probe.stderr[-2000:]
    marker.unlink()
    out = tmp_path / "trap"
    proc, _ = _farm(folder / "trap.blend", "--frames", "1-3", "--workers", 1, "--out", out)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (task,) = _manifest(out)["tasks"]
    assert task["status"] == "done" and task["auto_execute"] is False
    assert not marker.exists()


@pytest.mark.core_only  # a printed figure (~16 s of bakes): the two-worker wedge is tested on both halves
def test_wall_time_of_four_bakes_on_two_workers_against_one(local_two, tmp_path):
    out, two, _ = local_two
    proc, one = _farm(SQUARE, *WEDGE, "--workers", 1, "--out", tmp_path / "one")
    assert proc.returncode == 0, proc.stderr[-3000:]
    m1, m2 = _manifest(tmp_path / "one"), _manifest(out)
    assert [t["status"] for t in m1["tasks"]] == ["done"] * 4
    print(f"\nfour bakes (frames 1-6): one worker {m1['wall_seconds']:.1f} s, two workers {m2['wall_seconds']:.1f} s "
          f"(ratio {m1['wall_seconds'] / m2['wall_seconds']:.2f}); commands {one:.1f} s vs {two:.1f} s")


# ------------------------------------------------------------------------------------------------
# the Open Job Description template


OPENJD = REPO / "farm" / "openjd" / "tearcloth_bake.yaml"


def test_the_open_job_description_template_is_valid_and_wedges_four_tasks():
    from openjd.model import DocumentType, decode_job_template, document_string_to_object

    check = subprocess.run([str(BIN / "openjd"), "check", str(OPENJD)], capture_output=True, text=True, timeout=60)
    assert check.returncode == 0 and "passes validation" in check.stdout, check.stdout + check.stderr
    template = decode_job_template(template=document_string_to_object(document=OPENJD.read_text(),
                                                                       document_type=DocumentType.YAML))
    assert [s.name for s in template.steps] == ["Bake", "ContactSheet"]
    summary = subprocess.run([str(BIN / "openjd"), "summary", str(OPENJD), "-p", f"BlendFile={SQUARE}",
                              "-p", f"Object={OBJECT}", "-p", "OutDir=/tmp/unused"],
                             capture_output=True, text=True, timeout=60)
    assert summary.returncode == 0 and "'Bake' (4 total Tasks)" in summary.stdout, summary.stdout + summary.stderr


def test_one_task_of_the_template_bakes_its_variation(tmp_path):
    out = tmp_path / "wedge"
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    proc = subprocess.run([str(BIN / "openjd"), "run", str(OPENJD), "--step", "Bake", "-tp", "A=4e6", "-tp", "B=5e-3",
                           "-p", f"BlendFile={SQUARE}", "-p", f"Object={OBJECT}", "-p", f"OutDir={out}",
                           "-p", "Frames=1-3"], capture_output=True, text=True, timeout=240, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    (task,) = _manifest(out / "tear_stress=4e6,bending=5e-3")["tasks"]
    assert task["status"] == "done" and task["settings"] == {"material.tear_stress": 4e6, "material.bending": 5e-3}
    assert task["frames"] == [1, 3]
    from tearcloth.farm.sheet import gather

    assert gather(out).is_file()


# ------------------------------------------------------------------------------------------------
# nobody gets in: TLS to a remote scheduler


def _certificates(folder: Path) -> dict:
    """A CA and one certificate it signed (for 127.0.0.1), made with openssl for this test."""
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.skip("needs openssl to make test certificates")
    run = lambda *a: subprocess.run([openssl, *a], cwd=folder, check=True, capture_output=True, timeout=60)  # noqa: E731
    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=tearcloth test CA",
        "-keyout", "ca.key", "-out", "ca.pem")
    run("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1", "-keyout", "key.pem", "-out", "cert.csr")
    (folder / "san.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    run("x509", "-req", "-in", "cert.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-days", "1",
        "-extfile", "san.ext", "-out", "cert.pem")
    return {k: str(folder / f) for k, f in (("ca", "ca.pem"), ("cert", "cert.pem"), ("key", "key.pem"))}


def test_a_tls_scheduler_is_reached_with_the_certificates(tmp_path):
    pem = _certificates(tmp_path)
    port = _free_port()
    address = f"tls://127.0.0.1:{port}"
    tls = ["--tls-ca-file", pem["ca"], "--tls-cert", pem["cert"], "--tls-key", pem["key"]]
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--protocol", "tls", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard", *tls], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, cwd=tmp_path)]
    procs.append(subprocess.Popen([str(BIN / "dask"), "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                                   "--no-dashboard", *tls], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  cwd=tmp_path))
    try:
        deadline = time.monotonic() + 60
        while True:  # the scheduler listens
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "the TLS scheduler did not start"
                time.sleep(0.3)
        # without certificates a tls:// scheduler is refused before anything starts
        proc, _ = _farm(SQUARE, "--scheduler", address, "--out", tmp_path / "never", timeout=60)
        assert proc.returncode == 2 and "needs --tls-ca, --tls-cert and --tls-key" in proc.stderr, proc.stderr
        out = tmp_path / "tls"
        proc, _ = _farm(SQUARE, "--scheduler", address, "--tls-ca", pem["ca"], "--tls-cert", pem["cert"],
                        "--tls-key", pem["key"], "--frames", "1-3", "--out", out, timeout=240)
        assert proc.returncode == 0, proc.stderr[-3000:]
        m = _manifest(out)
        assert m["scheduler"] == address and m["tasks"][0]["status"] == "done"
        assert m["tasks"][0]["worker"].startswith("tls://127.0.0.1:")
    finally:
        _stop(procs)


def test_ctrl_c_cancels_the_bakes_and_keeps_their_frames(tmp_path):
    out = tmp_path / "stopped"
    # the whole process group gets the SIGINT, as from a terminal's Ctrl-C
    farm = subprocess.Popen([str(BIN / "tearcloth"), "farm", str(SQUARE), "--frames", "1-40", "--workers", "1",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob("*/*/*/tearcloth_cache/**/*_frames/frame_000004.usdc")):
            assert time.monotonic() < deadline and farm.poll() is None, "the bake never reached frame 4"
            time.sleep(0.1)
        os.killpg(farm.pid, signal.SIGINT)
        stdout, stderr = farm.communicate(timeout=120)
    finally:
        if farm.poll() is None:
            os.killpg(farm.pid, signal.SIGKILL)
    assert farm.returncode == 130, stderr[-3000:]
    m = _manifest(out)
    (task,) = m["tasks"]
    assert m["interrupted"] and task["status"] == "cancelled"
    first, last = task["frames"]
    assert first == 1 and 4 <= last < 40
    frames = sorted(Path(task["folder"]).glob("tearcloth_cache/**/*_frames/frame_*.usdc"))
    assert len(frames) == last  # every finished frame is kept on disk
    assert Path(task["blend"]).is_file()  # and the baked copy was saved
