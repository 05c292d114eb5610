"""Build the Blender extension package of Tear Cloth: ``dist/tearcloth-<version>.zip``.

    python tools/build_extension.py                     # build, package, validate
    python tools/build_extension.py --out /tmp/dist --keep-build
    python tools/build_extension.py --wheels-from DIR   # take the wheels DIR has from there, fetch the rest

The manifest (``addon/blender_manifest.toml``) is the one source of truth: its ``wheels = [...]``
list names every wheel file the package carries, and this script makes exactly those files,
failing loudly if a built or downloaded file name differs (a version bump, a new tag), so the
manifest and the package cannot drift apart. Steps, all inside a temporary build folder (nothing
is written into the source tree but the final zip):

1. Our wheel: the sources the build needs (``setup.py``, ``pyproject.toml``, ``README.md``,
   ``native/``, ``addon/`` without in-place build products) are copied to the build folder and
   ``pip wheel <copy> --no-deps`` builds ``tearcloth-<version>-cp311-abi3-<platform>.whl``: the
   native core compiled against the CPython limited API 3.11, so the one wheel serves every
   Blender from 4.2 (Python 3.11) to 5.x (Python 3.13). Building a copy keeps setuptools'
   ``build/`` and ``*.egg-info`` out of the repository.
2. Dependency wheels: every other manifest wheel is fetched for Blender's Python and platform,
   read from its file name: ``pip download --only-binary=:all: --no-deps --platform <tags>
   --python-version 3.11 --implementation cp --abi cp311 <name>==<version>``. ``--no-deps``
   because the manifest lists every wheel needed (numpy ships with Blender; pyftdi's pyserial is
   left out on purpose).
3. The extension folder: a copy of ``addon/`` without the dev-only ``bench/``, ``examples/`` and
   ``blender/race.py`` (also left out of our wheel), ``__pycache__``, in-place native builds
   (``*.so``/``*.pyd``), ``data/`` (example .blend files), tests and caches; plus the wheels under
   ``wheels/`` and, for each compiled module the wheel carries (``_native``, ``_collide``), a
   two-line ``<module>.py`` that makes ``from . import _native`` (``cloth.py``) or
   ``from .. import _collide`` (``collision/``) find it where our wheel installs it,
   ``tearcloth.<module>`` in Blender's extension site-packages (the extension itself is imported
   as ``bl_ext.<repo>.tearcloth``, where no compiled module sits).
4. Packaging and validation with Blender's own tool: ``blender --command extension build`` and
   ``... validate`` when a ``blender`` binary is on PATH (or given with ``--blender``);
   otherwise the same code run from the PyPI ``bpy`` (``bpy/<ver>/scripts/addons_core/bl_pkg/
   cli/blender_ext.py``, the module behind ``blender --command extension``); and only if neither
   exists, a plain zip and the manifest checks of ``check_manifest`` below.

Platforms: one zip per platform in the manifest's ``platforms`` (Blender's ``--split-platforms``:
``tearcloth-<v>-windows_x64.zip``, ``-macos_arm64``, ``-macos_x64``, ``-linux_x64``), each with
only the wheels for its platform (Blender picks them by the wheel file names):

* Our wheel for the machine this runs on is built by pip (step 1, Linux x86-64 here). The others
  are cross-compiled by ``tools/cross/native.py`` (``zig cc`` from the ``ziglang`` package; the
  Python files come from the wheel pip built). Any of them that ``--wheels-from`` holds, under the
  manifest's file name, is taken from there instead (e.g. wheels built natively by the release
  workflow's cibuildwheel jobs, or those an earlier build of the same sources made).
* Blender 4.2-5.0 embed Python 3.11, 5.1+ Python 3.13: the embreex and hidapi wheels (built per
  Python version) are listed for both, and Blender installs the ones for its own Python; our abi3
  wheel and the pure-Python ones serve both.
* The Falcon's transports: pyusb needs a libusb-1.0 library, which ``libusb-package`` carries for
  every platform (used when the system has none: haptics/falcon_transport.py; it imports
  ``importlib_resources``, listed too); ``ftd2xx``
  (pure Python, FTDI's D2XX driver through ctypes) is the Windows transport where Novint's
  installer bound the D2XX driver. Being a pure wheel, Blender puts it in every zip.
"""
from __future__ import annotations

import argparse
import fnmatch
import glob
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ADDON = REPO / "addon"
MANIFEST = ADDON / "blender_manifest.toml"
OWN = "tearcloth"
# The platform this script builds our wheel for with pip; the others are cross-compiled.
HOST_PLATFORM = "linux-x64"

# Left out of the package (relative to addon/): build products, example scenes, caches.
EXCLUDE_DIRS = {"__pycache__", "data", "tests", "tearcloth_cache", "wheels", "build"}
EXCLUDE_FILES = ("*.so", "*.pyd", "*.dylib", "*.pyc", "*.zip", ".*")
# What only measures or generates, never runs inside Blender (relative to addon/): left out of
# the add-on folder AND of our wheel inside the zip. The pip package keeps them (`tearcloth
# bench`, `tearcloth demo`); tests/test_layers.py checks that nothing shipped imports them.
DEV_ONLY = ("bench", "examples", os.path.join("blender", "race.py"))

SHIM = '''"""A native module, inside Blender: this extension is imported as ``bl_ext.<repo>.tearcloth`` and
carries no compiled module; the wheel ``tearcloth-*-abi3-*.whl`` listed in blender_manifest.toml
installs it into Blender's extension site-packages as ``tearcloth.{name}``. Written into the
package by tools/build_extension.py (the source tree builds ``{name}`` in place instead)."""
import sys

from tearcloth import {name} as _compiled

sys.modules[__name__] = _compiled
'''

# Blender's manifest rules (schema 1.0.0) for the fallback check; Blender's own validator is
# preferred whenever it can be found.
PLATFORMS = {"windows-x64", "windows-arm64", "macos-arm64", "macos-x64", "linux-x64", "linux-arm64"}
PERMISSIONS = {"files", "network", "clipboard", "camera", "microphone"}
WHEEL_NAME = re.compile(r"^(?P<name>[^-]+)-(?P<version>[^-]+)(-\d[^-]*)?-(?P<python>[^-]+)-(?P<abi>[^-]+)-"
                        r"(?P<platform>[^-]+)\.whl$")


class BuildError(Exception):
    """One line saying what failed and what to do."""


def say(message: str) -> None:
    print(f"build_extension: {message}", flush=True)


# ------------------------------------------------------------------------------------------------
# Manifest


def read_manifest(path: Path = MANIFEST) -> dict:
    with open(path, "rb") as f:
        return tomllib.load(f)


def parse_wheel(path: str) -> dict:
    name = os.path.basename(path)
    m = WHEEL_NAME.match(name)
    if m is None:
        raise BuildError(f"manifest wheel {path!r} is not a wheel file name (name-version-python-abi-platform.whl)")
    info = m.groupdict()
    info["file"] = name
    info["name"] = info["name"].replace("_", "-").lower()
    return info


def check_manifest(manifest: dict, root: Path | None = None) -> list[str]:
    """Problems with a manifest by Blender's schema 1.0.0 rules (the fallback when Blender's own
    validator is not available); ``root``: a staged package whose wheel files must exist."""
    problems = []
    required = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
                "blender_version_min", "license")
    for key in required:
        if not isinstance(manifest.get(key), (str, list)) or not manifest.get(key):
            problems.append(f"{key} is missing")
    if manifest.get("schema_version") != "1.0.0":
        problems.append("schema_version must be \"1.0.0\"")
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", str(manifest.get("id", ""))):
        problems.append("id must be an identifier")
    if not re.fullmatch(r"\d+\.\d+\.\d+([-+][0-9A-Za-z.-]+)?", str(manifest.get("version", ""))):
        problems.append("version must be semantic (X.Y.Z)")
    tagline = str(manifest.get("tagline", ""))
    if len(tagline) > 64 or tagline[-1:] in (".", "!", "?"):
        problems.append("tagline must be at most 64 characters without final punctuation")
    if manifest.get("type") not in ("add-on", "theme"):
        problems.append("type must be \"add-on\" or \"theme\"")
    versions = [manifest.get("blender_version_min", "0")]
    if "blender_version_max" in manifest:
        versions.append(manifest["blender_version_max"])
    parsed = []
    for v in versions:
        if not re.fullmatch(r"\d+\.\d+\.\d+", str(v)):
            problems.append(f"Blender version {v!r} must be X.Y.Z")
        else:
            parsed.append(tuple(int(x) for x in str(v).split(".")))
    if parsed and parsed[0] < (4, 2, 0):
        problems.append("blender_version_min must be 4.2.0 or later")
    if len(parsed) == 2 and parsed[1] <= parsed[0]:
        problems.append("blender_version_max must be above blender_version_min")
    licenses = manifest.get("license", [])
    if not isinstance(licenses, list) or not licenses or not all(str(x).startswith("SPDX:") for x in licenses):
        problems.append("license must be a list of \"SPDX:...\" identifiers")
    for p in manifest.get("platforms", []):
        if p not in PLATFORMS:
            problems.append(f"unknown platform {p!r}")
    for key in manifest.get("permissions", {}):
        if key not in PERMISSIONS:
            problems.append(f"unknown permission {key!r} (Blender knows {', '.join(sorted(PERMISSIONS))})")
    for path in manifest.get("wheels", []):
        if not path.startswith("./wheels/"):
            problems.append(f"wheel {path!r} should live in ./wheels/")
        try:
            info = parse_wheel(path)
        except BuildError as exc:
            problems.append(str(exc))
            continue
        tail = info["platform"].split(".")[-1]
        if manifest.get("platforms") and tail != "any" and not any(
                _blender_platform(tag) in manifest["platforms"] for tag in info["platform"].split(".")):
            problems.append(f"wheel {info['file']} is for none of the platforms {manifest['platforms']}")
        if root is not None and not (root / path).is_file():
            problems.append(f"wheel {path} is not in the package")
    return problems


def _blender_platform(tag: str) -> str:
    """A wheel platform tag as Blender names platforms: linux_x86_64 and manylinux_2_28_x86_64 ->
    linux-x64, macosx_11_0_arm64 -> macos-arm64, win_amd64 -> windows-x64."""
    system, _, rest = tag.partition("_")
    for prefix, name in (("manylinux", "linux"), ("musllinux", "linux"), ("macosx", "macos"), ("win", "windows")):
        if system.startswith(prefix):
            system = name
            break
    for machine, name in (("x86_64", "x64"), ("amd64", "x64"), ("aarch64", "arm64"), ("arm64", "arm64")):
        if rest == machine or rest.endswith("_" + machine):
            return f"{system}-{name}"
    return f"{system}-{rest.rpartition('_')[2]}"


# ------------------------------------------------------------------------------------------------
# Steps


def _ignore(folder: str, names: list[str]) -> set[str]:
    skipped = set()
    for n in names:
        full = os.path.join(folder, n)
        if os.path.relpath(full, ADDON) in DEV_ONLY:
            skipped.add(n)
        elif os.path.isdir(full) and n in EXCLUDE_DIRS:
            skipped.add(n)
        elif any(fnmatch.fnmatch(n, pattern) for pattern in EXCLUDE_FILES):
            skipped.add(n)
    return skipped


def copy_sources(build: Path) -> Path:
    """What ``pip wheel`` needs, without the in-place build products of the checkout."""
    src = build / "src"
    src.mkdir()
    for name in ("setup.py", "pyproject.toml", "README.md", "LICENSE"):
        if (REPO / name).exists():
            shutil.copy2(REPO / name, src / name)
    shutil.copytree(REPO / "native", src / "native", ignore=shutil.ignore_patterns("build", "*.o", "*.a", "*.so"))
    shutil.copytree(ADDON, src / "addon", ignore=_ignore)
    return src


def build_own_wheel(src: Path, wheels: Path, expected: str, python: str, source: Path | None = None) -> Path:
    """Our wheel for this machine: taken from ``source`` when it has it (the same abi3 bytes from the
    same sources whichever pip built it: tests/extension_build.py shares one build between the
    pytest runs of tools/run.sh), else built by pip from the copied sources."""
    if source is not None and (source / expected).is_file():
        say(f"taking {expected} from {source}")
        shutil.copy2(source / expected, wheels / expected)
        return wheels / expected
    say(f"building {expected} (pip wheel --no-deps)")
    cmd = [python, "-m", "pip", "wheel", str(src), "--no-deps", "--wheel-dir", str(wheels), "--quiet"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"pip wheel failed: {_tail(proc)}")
    made = sorted(p.name for p in wheels.glob(f"{OWN}-*.whl"))
    if made != [expected]:
        raise BuildError(f"pip wheel made {made}, the manifest lists {expected}: update `wheels` in "
                         f"{MANIFEST.relative_to(REPO)} (version or platform tag changed?)")
    return wheels / expected


def own_wheels(manifest: dict, listed: list[dict]) -> dict[str, dict]:
    """Our wheels in the manifest, one per platform: {Blender platform: parsed file name}."""
    own: dict[str, dict] = {}
    for info in listed:
        if info["name"] != OWN:
            continue
        if info["version"] != manifest["version"] or info["abi"] != "abi3":
            raise BuildError(f"the manifest's {info['file']} must be an abi3 wheel of version {manifest['version']}")
        platform = _blender_platform(info["platform"])
        if platform in own:
            raise BuildError(f"the manifest lists two {OWN} wheels for {platform}")
        own[platform] = info
    platforms = set(manifest.get("platforms", [HOST_PLATFORM]))
    if set(own) != platforms:
        raise BuildError(f"the manifest's {OWN} wheels are for {sorted(own)}, its platforms are {sorted(platforms)}")
    if HOST_PLATFORM not in own:
        raise BuildError(f"the manifest must list our {HOST_PLATFORM} wheel: the others are made from it")
    return own


def other_own_wheel(info: dict, platform: str, host_wheel: Path, wheels: Path, source: Path | None,
                    src: Path, build: Path) -> Path:
    """Our wheel for another platform: taken from ``source`` when it has it, else cross-compiled
    (tools/cross/native.py) from the sources and the host wheel's Python files."""
    if source is not None and (source / info["file"]).is_file():
        shutil.copy2(source / info["file"], wheels / info["file"])
        return wheels / info["file"]
    cross = _cross_module()
    spec = cross.TARGETS.get(platform)
    if spec is None:
        raise BuildError(f"no cross build for {platform} (tools/cross/native.py knows {', '.join(cross.TARGETS)})")
    say(f"cross-compiling {info['file']} (zig cc, target {spec['triple']})")
    try:
        made = cross.cross_wheel(platform, host_wheel, wheels, work=build / f"cross-{platform}", src=src)
    except cross.CrossError as exc:
        raise BuildError(f"cross build for {platform} failed: {exc}") from exc
    if made.name != info["file"]:
        raise BuildError(f"the cross build made {made.name}, the manifest lists {info['file']}")
    return made


def _cross_module():
    import importlib.util

    name = "tearcloth_cross_native"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, REPO / "tools" / "cross" / "native.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def download_wheel(info: dict, wheels: Path, python: str, source: Path | None) -> Path:
    target = wheels / info["file"]
    if source is not None and (source / info["file"]).is_file():
        shutil.copy2(source / info["file"], target)
        return target
    # Blender's Python is the target: a cpXY tag names it, a pure wheel (py3-none-any) fits any,
    # and pip then only needs some valid target, Blender 4.2-5.0's (CPython 3.11, linux x64).
    cp = [t for t in info["python"].split(".") if re.fullmatch(r"cp3\d+", t)]
    version = f"3.{cp[0][3:]}" if cp else "3.11"
    abi = info["abi"].split(".")[0]
    abi = abi if abi != "none" else f"cp{version.replace('.', '')}"
    platforms = info["platform"].split(".") if info["platform"] != "any" else ["manylinux2014_x86_64"]
    cmd = [python, "-m", "pip", "download", "--only-binary=:all:", "--no-deps", "--dest", str(wheels),
           "--python-version", version, "--implementation", "cp", "--abi", abi, "--quiet"]
    for tag in platforms:
        cmd += ["--platform", tag]
    cmd.append(f"{info['name']}=={info['version']}")
    say(f"downloading {info['file']}")
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"pip download of {info['name']}=={info['version']} failed: {_tail(proc)}")
    if not target.is_file():
        got = sorted(p.name for p in wheels.glob(f"{info['name'].replace('-', '_')}-*.whl"))
        raise BuildError(f"pip download gave {got}, the manifest lists {info['file']}")
    return target


def compiled_modules(wheel: Path) -> list[str]:
    """Names of the compiled modules at the top of our package in a wheel (``_native``, ...)."""
    names = []
    with zipfile.ZipFile(wheel) as z:
        for entry in z.namelist():
            folder, _, file = entry.rpartition("/")
            if folder == OWN and file.endswith((".so", ".pyd")):
                names.append(file.split(".")[0])
    if not names:
        raise BuildError(f"{wheel.name} carries no compiled module")
    return sorted(set(names))


def stage_extension(build: Path, wheel_files: list[Path], modules: list[str]) -> Path:
    ext = build / "extension"
    shutil.copytree(ADDON, ext, ignore=_ignore)
    for name in modules:
        (ext / f"{name}.py").write_text(SHIM.format(name=name))
    (ext / "wheels").mkdir()
    for w in wheel_files:
        shutil.copy2(w, ext / "wheels" / w.name)
    return ext


def blender_ext_script() -> Path | None:
    """Blender's extension command-line tool as shipped inside the PyPI ``bpy`` (found without
    importing bpy)."""
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return None
    for root in spec.submodule_search_locations:
        found = sorted(glob.glob(os.path.join(root, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")))
        if found:
            return Path(found[-1])
    return None


def blender_tool(blender: str | None) -> tuple[list[str], str] | None:
    """(command prefix, description) for Blender's extension tool, or None."""
    exe = blender or shutil.which("blender")
    if exe:
        return [exe, "--factory-startup", "--command", "extension"], f"Blender ({exe})"
    script = blender_ext_script()
    if script is not None:
        return [sys.executable, str(script)], f"Blender's blender_ext.py from the PyPI bpy ({script})"
    return None


def package(ext: Path, out_zip: Path, tool, split: bool) -> list[Path]:
    out_zip.parent.mkdir(parents=True, exist_ok=True)
    if tool is not None:
        cmd = tool[0] + ["build", "--source-dir", str(ext)]
        if split:
            cmd += ["--split-platforms", "--output-dir", str(out_zip.parent)]
        else:
            cmd += ["--output-filepath", str(out_zip)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0 or (not split and not out_zip.exists()):
            raise BuildError(f"Blender's extension build failed: {_tail(proc)}")
        if split:
            return sorted(out_zip.parent.glob(out_zip.stem + "-*.zip"))
        return [out_zip]
    # No Blender at all: the same layout Blender's builder makes (manifest at the zip root).
    if out_zip.exists():
        out_zip.unlink()
    with zipfile.ZipFile(out_zip, "w", zipfile.ZIP_DEFLATED) as z:
        for path in sorted(ext.rglob("*")):
            if path.is_file():
                z.write(path, path.relative_to(ext).as_posix())
    return [out_zip]


def validate(zip_path: Path, tool) -> str:
    """Validate a built package; returns how it was checked."""
    if tool is not None:
        proc = subprocess.run(tool[0] + ["validate", str(zip_path)], capture_output=True, text=True)
        text = (proc.stdout + proc.stderr).strip()
        if proc.returncode != 0 or "error" in text.lower():
            raise BuildError(f"{zip_path.name} does not validate: {text.splitlines()[-1] if text else proc.returncode}")
        return f"validated by {tool[1]}: {text.splitlines()[-1] if text else 'ok'}"
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(zip_path) as z:
        z.extractall(tmp)
        problems = check_manifest(read_manifest(Path(tmp) / "blender_manifest.toml"), Path(tmp))
    if problems:
        raise BuildError(f"{zip_path.name}: " + "; ".join(problems))
    return "no Blender found: checked the manifest fields and wheel files by Blender's schema rules"


def _tail(proc) -> str:
    lines = [line for line in (proc.stdout + proc.stderr).strip().splitlines() if line.strip()]
    return lines[-1] if lines else f"exit status {proc.returncode}"


def build(out_dir: Path = REPO / "dist", build_dir: Path | None = None, wheels_from: Path | None = None,
          blender: str | None = None, split: bool = False, python: str = sys.executable,
          keep: bool = False) -> dict:
    """Build, package and validate; returns {'zips': [...], 'validation': [...], 'build_dir': ...}."""
    manifest = read_manifest()
    problems = check_manifest(manifest)
    if problems:
        raise BuildError(f"{MANIFEST.relative_to(REPO)}: " + "; ".join(problems))
    wheels_listed = [parse_wheel(w) for w in manifest.get("wheels", [])]
    own = own_wheels(manifest, wheels_listed)
    split = split or len(manifest.get("platforms", [])) > 1
    made_here = build_dir is None
    build_dir = Path(tempfile.mkdtemp(prefix="tearcloth-extension-")) if made_here else Path(build_dir)
    build_dir.mkdir(parents=True, exist_ok=True)
    try:
        wheels = build_dir / "wheels"
        wheels.mkdir(exist_ok=True)
        src = copy_sources(build_dir)
        host = own[HOST_PLATFORM]
        files = [build_own_wheel(src, wheels, host["file"], python, wheels_from)]
        for platform, info in sorted(own.items()):
            if platform != HOST_PLATFORM:
                files.append(other_own_wheel(info, platform, files[0], wheels, wheels_from, src, build_dir))
        for info in wheels_listed:
            if info["name"] != OWN:
                files.append(download_wheel(info, wheels, python, wheels_from))
        ext = stage_extension(build_dir, files, compiled_modules(files[0]))
        tool = blender_tool(blender)
        out_zip = Path(out_dir).resolve() / f"{manifest['id']}-{manifest['version']}.zip"
        zips = package(ext, out_zip, tool, split)
        checks = [validate(z, tool) for z in zips]
        for z, check in zip(zips, checks):
            say(f"wrote {z} ({z.stat().st_size / 1e6:.1f} MB); {check}")
        return {"zips": [str(z) for z in zips], "validation": checks, "build_dir": str(build_dir) if keep else None}
    finally:
        if made_here and not keep:
            shutil.rmtree(build_dir, ignore_errors=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Build the Tear Cloth Blender extension zip.")
    p.add_argument("--out", default=str(REPO / "dist"), help="output folder (default: dist/)")
    p.add_argument("--build-dir", help="build folder (default: a temporary folder, removed afterwards)")
    p.add_argument("--keep-build", action="store_true", help="keep the temporary build folder")
    p.add_argument("--wheels-from", help="take the wheels this folder has (ours, dependencies) "
                                         "from it instead of building or downloading them")
    p.add_argument("--blender", help="Blender executable for packaging and validation (default: blender on PATH)")
    p.add_argument("--split-platforms", action="store_true", help="one zip per platform (Blender's --split-platforms)")
    args = p.parse_args(argv)
    try:
        result = build(Path(args.out), Path(args.build_dir) if args.build_dir else None,
                       Path(args.wheels_from) if args.wheels_from else None, args.blender, args.split_platforms,
                       keep=args.keep_build)
    except BuildError as exc:
        print(f"build_extension: error: {exc}", file=sys.stderr)
        return 1
    if result["build_dir"]:
        say(f"build folder kept: {result['build_dir']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
