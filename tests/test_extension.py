"""The Blender extension package: ``tools/build_extension.py`` builds one zip per platform (our abi3
wheel, the embreex and device wheels, the add-on without build products; tests/extension_build.py
builds them once per session, test_platforms.py checks all four), Blender's own validator accepts
the Linux one, and a FRESH Blender session installs it exactly the way Blender's "Install from
Disk" does and bakes with it; on every bpy the suite runs with (5.0.1 on Python 3.11, 5.3.0 on
3.13; 4.2.23 LTS in tools/run.sh's 4.2 half; see the 4.2 branch in the child script).

The install is not emulated: the child process runs the operator behind "Install from Disk"
(``bpy.ops.extensions.package_install_files``, from Blender's bundled Extensions add-on), which
unpacks the zip into the "User Default" repository of a temporary user folder
(``BLENDER_USER_RESOURCES``), installs the manifest's wheels into the extensions site-packages and
enables ``bl_ext.user_default.tearcloth``. Before that the child removes every path from which the
source tree's ``tearcloth`` could be imported, so what runs is what the zip carries: the add-on
from the repository folder, the native core, embreex, the device libraries and the bundled
libusb from the installed wheels. Only ``pxr`` comes from the test environment (usd-core), where a
full Blender would use its bundled one.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def package():
    """The Linux zip of the per-platform build (tests/extension_build.py builds all four once)."""
    from extension_build import packages

    built = packages()
    return built["zips"]["linux-x64"], built["validation"]["linux-x64"]


def test_the_package_builds_and_validates(package):
    zip_path, validation = package
    manifest = tomllib.loads((REPO / "addon" / "blender_manifest.toml").read_text())
    assert zip_path.name == f"tearcloth-{manifest['version']}-linux_x64.zip"
    print(f"{zip_path.name}: {zip_path.stat().st_size / 1e6:.1f} MB; {validation}")
    # Blender's own validator whenever PyPI bpy is installed (this test requires it)
    assert validation.startswith("validated by Blender")
    with zipfile.ZipFile(zip_path) as z:
        names = z.namelist()
        packed = tomllib.loads(z.read("blender_manifest.toml").decode())
    # Blender's --split-platforms appends the zip's platform and its wheels as [build.generated]
    from extension_build import wheels_for

    linux = wheels_for(manifest, "linux-x64")
    generated = packed["build"].pop("generated")
    assert generated == {"platforms": ["linux-x64"], "wheels": linux}
    assert packed == manifest
    for wheel in linux:
        assert wheel[2:] in names, f"{wheel} missing from the package"
    assert any(n.startswith("wheels/tearcloth-") and n.endswith("-cp311-abi3-linux_x86_64.whl") for n in names)
    assert "__init__.py" in names and "blender/__init__.py" in names
    own = next(n for n in names if n.startswith("wheels/tearcloth-"))
    with zipfile.ZipFile(zip_path) as z, zipfile.ZipFile(z.open(own)) as wheel:
        compiled = [n.split("/")[-1].split(".")[0] for n in wheel.namelist()
                    if n.startswith("tearcloth/") and n.endswith(".so")]
    # the wheel carries the compiled modules; the add-on folder a two-line module for each
    assert "_native" in compiled and all(f"{m}.py" in names for m in compiled), compiled
    junk = [n for n in names if "__pycache__" in n or n.endswith((".so", ".pyc", ".blend")) or n.startswith("tests/")]
    assert not junk, junk
    # what only measures or generates stays out, of the add-on folder and of our wheel alike
    with zipfile.ZipFile(zip_path) as z, zipfile.ZipFile(z.open(own)) as wheel:
        in_wheel = [n[len("tearcloth/"):] for n in wheel.namelist() if n.startswith("tearcloth/")]
        sources = {n: z.read(n).decode() for n in names if n.endswith(".py")}
    from extension_build import packages

    dev = packages()["tool"].DEV_ONLY
    assert dev and all((REPO / "addon" / d).exists() for d in dev), dev  # the list names real places
    for listing in (names, in_wheel):
        shipped_dev = [n for n in listing if any(n == d or n.startswith(d + "/") for d in dev)]
        assert not shipped_dev, shipped_dev
    test_code = [n for n, text in sources.items()
                 if n.rsplit("/", 1)[-1].startswith(("test_", "conftest"))
                 or re.search(r"^\s*(import|from)\s+(pytest|hypothesis)\b", text, re.M)]
    assert not test_code, test_code
    assert zip_path.stat().st_size < 40e6  # embreex (Embree's libraries) is most of it


# Both children start by making the source tree unimportable: only what the package installs runs.
ISOLATE = r"""
import importlib.abc, importlib.machinery, importlib.util, json, os, shutil, sys
# Hide every tearcloth the test environment has (a source tree on the path, or the copy pip
# installed next to bpy in site-packages) while keeping those folders on sys.path for bpy & co:
# only a tearcloth that Blender's extension install adds later may be found.
_hidden = [p for p in sys.path if os.path.exists(os.path.join(p or ".", "tearcloth"))]


class _HideTestTearcloth(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name != "tearcloth":
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, [p for p in sys.path if p not in _hidden])
        if spec is None:
            raise ModuleNotFoundError("no tearcloth outside the test environment", name=name)
        return spec


sys.meta_path.insert(0, _HideTestTearcloth())
try:
    importlib.import_module("tearcloth")
    raise AssertionError("the test environment's tearcloth is still importable")
except ModuleNotFoundError:
    pass
import bpy
"""

# Session 1: "Install from Disk", then save the preferences (the add-on is enabled in them).
INSTALL = ISOLATE + r"""
zip_path = sys.argv[1]
extensions = bpy.utils.user_resource("EXTENSIONS")
assert extensions.startswith(os.environ["BLENDER_USER_RESOURCES"]), extensions
state = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
enabled = "bl_ext.user_default.tearcloth" in bpy.context.preferences.addons
bpy.ops.wm.save_userpref()
print("RESULT " + json.dumps(dict(install=sorted(state), enabled=enabled, extensions=extensions)), flush=True)
"""

# Session 2: Blender started again. Its start-up puts the extensions' site-packages before the
# others (session 1 only appended it, behind the test environment's own embreex); the PyPI bpy
# starts from factory preferences, so the saved ones are read as Blender's start-up would.
BAKE = ISOLATE + r"""
blend, folder = sys.argv[1], sys.argv[2]
module = "bl_ext.user_default.tearcloth"
if bpy.app.version >= (4, 3, 0):
    bpy.ops.wm.read_userpref()
else:
    # the PyPI bpy 4.2 crashes in read_userpref, in Blender itself (wm_userpref_read_exec ->
    # UI_icons_reload_internal_textures -> GPU_texture_create_2d with no GPU context, even with
    # nothing registered): the saved preference (the add-on enabled) is applied as Blender's
    # start-up applies it, by enabling the module
    import addon_utils

    addon_utils.enable(module, default_set=True, handle_error=None)
assert module in bpy.context.preferences.addons and module in sys.modules, "not enabled after a restart"
ext = sys.modules[module]
work = os.path.join(folder, "scene.blend")
shutil.copy2(blend, work)  # saved by bpy 4.2: every supported Blender opens it
bpy.ops.wm.open_mainfile(filepath=work)
cloth = bpy.data.objects["SquareCloth"]
# a collider close behind the sheet, so the bake runs the collision code (embreex) as well
bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.06, 1.0))
wall = bpy.context.object
wall.scale = (0.8, 0.05, 0.8)
settings = cloth.tearcloth
settings.use_collision = True
settings.use_self_collision = False
settings.colliders.add().object = wall
settings.steps_per_frame = 40
settings.frame_start, settings.frame_end = 1, 6
bpy.ops.wm.save_mainfile()
with bpy.context.temp_override(object=cloth, active_object=cloth, selected_objects=[cloth]):
    baked = bpy.ops.tearcloth.bake()
bpy.ops.wm.save_mainfile()
md = cloth.modifiers["Tear Cloth"]
import embreex, hid, pyftdi.ftdi, tearcloth, usb.core  # the haptic devices' modules load too
# the Falcon's libusb where the system has none: the system lookup made to fail, the copy that the
# libusb-package wheel carries is what pyusb (and so pyftdi) then loads
import ctypes.util, importlib, usb.backend.libusb1
_system_lookup = ctypes.util.find_library
ctypes.util.find_library = lambda name: None if "usb" in name else _system_lookup(name)
importlib.import_module(module + ".haptics.falcon_transport")._prime_libusb()
ctypes.util.find_library = _system_lookup
libusb = usb.backend.libusb1._lib._name if usb.backend.libusb1.get_backend() is not None else None
print("RESULT " + json.dumps(dict(
    ext_file=ext.__file__, native=sys.modules[module + "._native"].__file__, embreex=embreex.__file__,
    devices=[hid.__file__, pyftdi.ftdi.__file__, usb.core.__file__], libusb=libusb,
    wheel_package=tearcloth.__file__, baked=sorted(baked), cache=md.cache_file.filepath if md.cache_file else None,
    collision=module + ".collision.narrow" in sys.modules,
)), flush=True)
"""


def run_child(tmp_path: Path, name: str, code: str, *args, env: dict) -> dict:
    script = tmp_path / name
    script.write_text(code)
    proc = subprocess.run([sys.executable, str(script), *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path, env=env)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, out[-4000:]
    return json.loads(lines[-1][len("RESULT "):])


def test_a_fresh_blender_installs_the_package_and_bakes_with_it(package, tmp_path):
    zip_path, _ = package
    user = tmp_path / "user"
    user.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(user), PYTHONNOUSERSITE="1")
    got = run_child(tmp_path, "install.py", INSTALL, zip_path, env=env)
    assert got["install"] == ["FINISHED"] and got["enabled"]
    extensions = Path(got["extensions"])
    assert (extensions / "user_default" / "tearcloth" / "blender_manifest.toml").is_file()
    site = str(extensions / ".local")

    got = run_child(tmp_path, "bake.py", BAKE, REPO / "example_blends" / "square_cloth.blend", tmp_path, env=env)
    assert got["ext_file"].startswith(str(extensions / "user_default" / "tearcloth"))
    # the native core and embreex come from the wheels Blender installed, not from anywhere else
    assert got["native"].startswith(site) and got["native"].endswith(".abi3.so"), got["native"]
    assert got["embreex"].startswith(site), got["embreex"]
    assert all(path.startswith(site) for path in got["devices"]), got["devices"]
    assert got["libusb"] and got["libusb"].startswith(site), got["libusb"]
    assert got["wheel_package"].startswith(site)
    assert got["collision"]
    assert got["baked"] == ["FINISHED"] and got["cache"] == "//tearcloth_cache/scene/SquareCloth.usda"
    from tearcloth import cache

    info = cache.cache_info(tmp_path / "tearcloth_cache" / "scene" / "SquareCloth.usda")
    assert info["frames"] == [1, 2, 3, 4, 5, 6] and info["complete"]
