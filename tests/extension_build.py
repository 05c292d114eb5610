"""The extension zips (one per platform), built by tools/build_extension.py at most once per test
session and shared by test_extension.py (install into a fresh Blender) and test_platforms.py
(structure of every zip and native binary). A build that fails for want of the package index
skips those tests with the reason; any other failure fails them."""
from __future__ import annotations

import atexit
import fcntl
import importlib.util
import json
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
NETWORK_TROUBLE = re.compile(r"(Could not find a version|No matching distribution|Connection|Max retries|"
                             r"Temporary failure|Name or service not known|timed out|Network is unreachable)", re.I)
ZIP_NAME = re.compile(r"^(?P<id>[^-]+)-(?P<version>[^-]+)-(?P<platform>[a-z]+_[a-z0-9]+)\.zip$")

_outcome: dict = {}


def load_tool(name: str = "build_extension", path: str = "tools/build_extension.py"):
    """A module of tools/ (not a package), loaded once under ``name``."""
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, REPO / path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # before running it: dataclasses look their module up
        spec.loader.exec_module(module)
    return sys.modules[name]


def _wheels_build(tool, out_dir: Path) -> dict:
    """tool.build into ``out_dir``, sharing the wheels between the pytest runs of one tools/run.sh
    test (its halves on bpy 5.0.1, 4.2 and 5.3): TEARCLOTH_TEST_WHEELS names a folder; the first
    run fills it with the wheels it built, cross-compiled and downloaded, later runs take them
    from there (``--wheels-from``). Those are the same bytes whichever interpreter builds them
    (our abi3 wheel and zig cross builds of the same sources, fixed downloads: Blender 5.1+
    installs the very cp311-abi3 wheels 4.2 does); what depends on the session still happens in
    each: packaging and validation by its Blender's own extension tool."""
    shared = os.environ.get("TEARCLOTH_TEST_WHEELS")  # tools/run.sh empties it when a run starts
    if not shared:
        return tool.build(out_dir=out_dir)
    shared = Path(shared)
    complete = shared / "complete"
    if complete.is_file():
        return tool.build(out_dir=out_dir, wheels_from=shared)
    shared.mkdir(parents=True, exist_ok=True)
    # tools/run.sh runs the 4.2 and 3.13 halves side by side: should neither find the wheels, one
    # builds and fills the folder while the other waits here, then takes them
    with open(shared / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if complete.is_file():
            return tool.build(out_dir=out_dir, wheels_from=shared)
        build_dir = Path(tempfile.mkdtemp(prefix="tearcloth-test-build-"))
        try:
            result = tool.build(out_dir=out_dir, build_dir=build_dir)
            for wheel in (build_dir / "wheels").glob("*.whl"):
                shutil.copy2(wheel, shared / wheel.name)
            complete.write_text("\n".join(sorted(p.name for p in shared.glob("*.whl"))) + "\n")
        finally:
            shutil.rmtree(build_dir, ignore_errors=True)
        return result


def _build(tool) -> dict:
    """tool.build's result. Under pytest-xdist the workers of one run share one build: the first
    to get the lock builds into a folder named after the run, the others wait and read its result
    (the build is ~2 minutes of CPU; a second one would be the same zips)."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if not run:
        out = Path(tempfile.mkdtemp(prefix="tearcloth-test-dist-"))
        atexit.register(shutil.rmtree, out, True)
        return _wheels_build(tool, out)
    shared = Path(tempfile.gettempdir()) / f"tearcloth-test-dist-{run}"
    # no worker may delete the zips at exit (another may still install them): earlier runs' folders
    # go here instead, those whose lock nobody holds
    for old in Path(tempfile.gettempdir()).glob("tearcloth-test-dist-*"):
        if old != shared and (old / "lock").exists():
            with open(old / "lock") as held:
                try:
                    fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    continue
                shutil.rmtree(old, ignore_errors=True)
    shared.mkdir(exist_ok=True)
    with open(shared / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also if this worker dies
        done = shared / "result.json"
        if done.exists():
            result = json.loads(done.read_text())
            if "error" in result:
                raise tool.BuildError(result["error"])
            return result
        try:
            result = _wheels_build(tool, shared / "zips")
        except tool.BuildError as exc:  # the other workers fail (or skip) the same way, not rebuild
            done.write_text(json.dumps({"error": str(exc)}))
            raise
        done.write_text(json.dumps(result))
        return result


def packages() -> dict:
    """{'zips': {blender platform: zip path}, 'validation': {platform: verdict}, 'tool': module}."""
    if not _outcome:
        tool = load_tool()
        try:
            result = _build(tool)
        except Exception as exc:  # kept, so the next module's tests fail the same way, not rebuild
            _outcome["error"] = exc
            _outcome["skip"] = isinstance(exc, tool.BuildError) and bool(NETWORK_TROUBLE.search(str(exc)))
        else:
            zips, checks = {}, {}
            for z, check in zip(result["zips"], result["validation"]):
                m = ZIP_NAME.match(Path(z).name)
                assert m, z
                platform = m["platform"].replace("_", "-")
                zips[platform], checks[platform] = Path(z), check
            _outcome.update(zips=zips, validation=checks, tool=tool)
    if "error" in _outcome:
        if _outcome["skip"]:
            pytest.skip(f"the package index is unreachable: {_outcome['error']}")
        raise _outcome["error"]
    return _outcome


def wheels_for(manifest: dict, platform: str) -> list[str]:
    """The manifest's wheels that Blender's --split-platforms puts in ``platform``'s zip: those
    with a platform tag of it, and the pure ones (``any``)."""
    tool = load_tool()
    chosen = []
    for path in manifest["wheels"]:
        tags = tool.parse_wheel(path)["platform"].split(".")
        if tags == ["any"] or any(tool._blender_platform(t) == platform for t in tags):
            chosen.append(path)
    return chosen
