"""Cross-compile Tear Cloth's native modules (``tearcloth._native``, ``tearcloth._collide``) on Linux
for Windows x64 and macOS (arm64, x86-64), and package each platform's pair as an abi3 wheel.

    python tools/cross/native.py --target windows-x64 --from-wheel dist/tearcloth-0.1.0-cp311-abi3-linux_x86_64.whl --out DIR

Owns: the cross-build recipe (compiler, flags, Python headers, import library) and the wheel
re-tagging; tools/build_extension.py calls ``cross_wheel`` for every non-Linux platform in the
extension manifest, and tests/test_platforms.py checks the products.

How:

* Compiler: ``zig cc`` from the ``ziglang`` package on PyPI (clang plus the C libraries and
  linkers of every target: MinGW-w64 with the Universal CRT for Windows, libSystem stubs for
  macOS), run as ``python -m ziglang cc -target <triple>``.
* What to compile: setup.py itself is read (run with a stand-in ``setuptools.setup``), so the
  sources, include folders, macros and flags are the ones the native build uses on Linux, whatever
  files native/ holds at the time.
* Python headers: the building interpreter's headers, copied WITHOUT their pyconfig.h (it
  describes the Linux build machine) and preceded by ``tools/cross/pyconfig/<os>/pyconfig.h``,
  written for the target (``posix``: every LP64 Unix target, macOS and Linux arm64). The modules use the limited API 3.11 only (``Py_LIMITED_API`` from
  setup.py), so the headers' Python version does not matter beyond that.
* Windows: the modules import from ``python3.dll`` (the stable ABI's DLL, which every CPython
  3.x for Windows ships) through an import library made by ``zig dlltool`` from a .def file: the
  functions and data the limited API 3.11 headers declare (``stable_abi`` below), so nothing
  outside the stable ABI can even link.
* macOS: Python symbols stay undefined and are bound at load time to the running interpreter
  (``-undefined dynamic_lookup``, as every macOS extension module does); C runtime symbols bind
  to ``/usr/lib/libSystem.B.dylib``.
* SIMD: native/core.h adds GCC ``target_clones`` (an ifunc) only for GCC on Linux x86-64; zig cc
  is clang, so none of these targets gets a clone (PE and Mach-O have no ifunc). The x86-64
  builds are for the baseline x86-64 CPU (SSE2), the arm64 builds for the baseline arm64 CPU
  (NEON is part of it: native/fem_neon.c is the product there): nothing can trap on an older CPU.
* Linux arm64 (``linux-arm64``): not shipped (the manifest has no such platform), built to check
  the arm64 product in a second object format (ELF beside Mach-O); glibc 2.28 as manylinux_2_28.
"""
from __future__ import annotations

import argparse
import base64
import csv
import hashlib
import io
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]

# Blender's platform name -> how to build for it. ``cpu`` pins the instruction set (zig's
# "baseline" of each architecture); ``min_os`` is the oldest macOS the binary declares (Blender
# 4.2 needs macOS 11.2 on arm64 and x86-64, so the wheel tags are no stricter than Blender).
TARGETS = {
    "windows-x64": dict(triple="x86_64-windows-gnu", cpu="baseline", pyconfig="windows",
                        wheel_platform="win_amd64", suffix=".pyd"),
    "macos-arm64": dict(triple="aarch64-macos.11.0", cpu="baseline", pyconfig="posix",
                        wheel_platform="macosx_11_0_arm64", suffix=".abi3.so"),
    "macos-x64": dict(triple="x86_64-macos.10.13", cpu="baseline", pyconfig="posix",
                      wheel_platform="macosx_10_13_x86_64", suffix=".abi3.so"),
    # not in the extension manifest (no Blender release for it is tested here): built so the
    # arm64 NEON product can be checked on a second arm64 system (tests/test_platforms.py)
    "linux-arm64": dict(triple="aarch64-linux-gnu.2.28", cpu="baseline", pyconfig="posix",
                        wheel_platform="linux_aarch64", suffix=".abi3.so"),
}


# every name of CPython's C API (functions, data, private ABI helpers such as _Py_Dealloc)
PYTHON_NAME = re.compile(r"^_?Py")


class CrossError(Exception):
    """One line saying what failed."""


def zig(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "ziglang", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    if proc.returncode != 0:
        text = (proc.stderr or proc.stdout).strip()
        raise CrossError(f"zig {args[0]} failed: {text[-2000:]}")
    return proc


def have_zig() -> bool:
    try:
        import ziglang  # noqa: F401
    except ImportError:
        return False
    return True


# ------------------------------------------------------------------------------------------------
# What setup.py builds


def extensions(src: Path = REPO) -> list:
    """setup.py's Extension objects (names, sources, include dirs, macros, flags): setup.py is run
    with ``setuptools.setup`` replaced by a function that only keeps its arguments, so nothing is
    built and whatever sources setup.py finds (it globs native/) are the ones compiled here."""
    import runpy

    import setuptools

    captured: dict = {}
    real = setuptools.setup
    setuptools.setup = lambda **kwargs: captured.update(kwargs)
    try:
        runpy.run_path(str(src / "setup.py"), run_name="__main__")
    finally:
        setuptools.setup = real
    if not captured.get("ext_modules"):
        raise CrossError(f"{src / 'setup.py'} declares no ext_modules")
    return list(captured["ext_modules"])


def limited_api_version(exts) -> str:
    values = {dict(e.define_macros).get("Py_LIMITED_API") for e in exts}
    if len(values) != 1 or None in values:
        raise CrossError(f"setup.py's extensions must all define one Py_LIMITED_API, found {values}")
    return values.pop()


# ------------------------------------------------------------------------------------------------
# Python headers and the stable ABI


def staged_headers(work: Path, os_name: str) -> list[str]:
    """Include flags: the target's pyconfig.h first, then the build Python's headers without its
    own pyconfig.h (Python.h includes "pyconfig.h" from its own folder first, so it must be gone)."""
    include = Path(sysconfig.get_paths()["include"])
    copy = work / "python-include"
    if not copy.exists():
        shutil.copytree(include, copy, ignore=shutil.ignore_patterns("pyconfig.h"))
    return ["-I", str(HERE / "pyconfig" / os_name), "-I", str(copy)]


def _strip_attributes(text: str) -> str:
    """Drop ``__attribute__((...))`` and ``__declspec(...)`` groups (balanced parentheses)."""
    out, i = [], 0
    pattern = re.compile(r"__attribute__\s*\(|__declspec\s*\(")
    while True:
        m = pattern.search(text, i)
        if m is None:
            out.append(text[i:])
            return "".join(out)
        out.append(text[i:m.start()])
        depth, j = 1, m.end()
        while depth and j < len(text):
            depth += {"(": 1, ")": -1}.get(text[j], 0)
            j += 1
        i = j


def stable_abi(work: Path, limited: str = "0x030B0000") -> dict[str, str]:
    """The stable ABI as the limited API headers declare it: {symbol: "func" or "data"}.

    Python.h is preprocessed for Windows, where every API declaration carries
    ``__declspec(dllimport)`` (PyAPI_FUNC / PyAPI_DATA), with ``Py_LIMITED_API`` set to the
    modules' version: what is declared there is what a limited-API module may use, and exactly
    what python3.dll exports for that version. Inline functions (Py_INCREF & co.) carry no
    dllimport and are not symbols."""
    work.mkdir(parents=True, exist_ok=True)
    flags = staged_headers(work, "windows")
    # twice: with PY_SSIZE_T_CLEAN (3.11's headers then rename PyArg_ParseTuple & co. to their
    # _SizeT forms, which the ABI exports as well) and without
    text = ""
    for clean in ("#define PY_SSIZE_T_CLEAN\n", ""):
        probe = work / "stable_abi_probe.c"
        probe.write_text(clean + "#include <Python.h>\n")
        text += zig("cc", "-target", TARGETS["windows-x64"]["triple"], "-E", "-P",
                    f"-DPy_LIMITED_API={limited}", *flags, str(probe)).stdout + ";"
    symbols: dict[str, str] = {}
    # top-level declarations end at ';' (bodies of inline functions contain none with dllimport
    # in front of them); keep those with the dllimport marker
    for decl in re.split(r";", text):
        if "dllimport" not in decl:
            continue
        decl = decl[decl.rfind("}") + 1:]  # what follows a preceding inline body or struct
        plain = _strip_attributes(decl)
        plain = re.sub(r"\[[^\]]*\]", "", plain).strip()
        if "(" in plain:
            m = re.search(r"([A-Za-z_]\w*)\s*\(", plain)
            kind = "func"
        else:
            m = re.search(r"([A-Za-z_]\w*)\s*$", plain)
            kind = "data"
        # the C library's headers (stdio.h, time.h, ... which Python.h includes) declare their
        # functions dllimport as well; CPython's API names all start with Py or _Py
        if m and PYTHON_NAME.match(m.group(1)):
            symbols[m.group(1)] = kind
    if len(symbols) < 300 or "PyLong_FromLong" not in symbols or symbols.get("_Py_NoneStruct") != "data":
        raise CrossError(f"reading the stable ABI from the headers found {len(symbols)} symbols")
    return symbols


def python3_import_library(work: Path, symbols: dict[str, str]) -> Path:
    """``libpython3.a``: an import library for python3.dll with every stable-ABI symbol."""
    lines = ["LIBRARY python3.dll", "EXPORTS"]
    lines += [f"    {name}{' DATA' if kind == 'data' else ''}" for name, kind in sorted(symbols.items())]
    deffile = work / "python3.def"
    deffile.write_text("\n".join(lines) + "\n")
    lib = work / "libpython3.a"
    zig("dlltool", "-d", str(deffile), "-l", str(lib), "-m", "i386:x86-64", "-D", "python3.dll")
    return lib


# ------------------------------------------------------------------------------------------------
# Compile and link


def build_modules(target: str, work: Path, src: Path = REPO, only: tuple[str, ...] = ()) -> dict[str, Path]:
    """Compile and link setup.py's extensions for ``target`` (those named in ``only``, when given);
    {"_native": path, ...}."""
    if target not in TARGETS:
        raise CrossError(f"unknown target {target!r} (known: {', '.join(TARGETS)})")
    spec = TARGETS[target]
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    exts = extensions(src)
    limited = limited_api_version(exts)
    headers = staged_headers(work, spec["pyconfig"])
    link: list[str] = []
    if spec["pyconfig"] == "windows":
        lib = python3_import_library(work, stable_abi(work, limited))
        link = ["-L", str(lib.parent), "-lpython3"]
    elif "macos" in spec["triple"]:
        link = ["-Wl,-undefined,dynamic_lookup"]
    else:
        link = []  # ELF shared objects may leave symbols undefined: the interpreter defines them
    made = {}
    for ext in exts:
        short = ext.name.rpartition(".")[2]
        if only and short not in only:
            continue
        # one folder per module: the linker may leave a .pdb and the DLL's own import library
        # beside a Windows DLL, which are cleared away below
        folder = work / target / short
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        out = folder / f"{short}{spec['suffix']}"
        macros = [f"-D{k}" if v is None else f"-D{k}={v}" for k, v in ext.define_macros]
        includes = [f"-I{src / d}" for d in ext.include_dirs]
        # setup.py's Unix flags (-std=c17 -O3 -fno-math-errno, warnings) are clang's as well
        flags = [f for f in ext.extra_compile_args if not f.startswith("/")]
        cmd = ["cc", "-target", spec["triple"], f"-mcpu={spec['cpu']}", "-shared", "-o", str(out),
               *flags, *macros, *headers, *includes, *[str(src / s) for s in ext.sources], *link]
        zig(*cmd, cwd=folder)
        for leftover in folder.iterdir():
            if leftover != out:
                leftover.unlink()
        made[short] = out
    return made


# ------------------------------------------------------------------------------------------------
# Wheels


def _record_hash(data: bytes) -> str:
    return "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def retag_wheel(linux_wheel: Path, target: str, modules: dict[str, Path], out_dir: Path) -> Path:
    """Our abi3 wheel for ``target``: the Python files of the Linux wheel (the same sources), its
    compiled modules replaced by the cross-built ones, WHEEL's tag and RECORD rewritten."""
    spec = TARGETS[target]
    name = Path(linux_wheel).name
    m = re.match(r"^(?P<dist>[^-]+)-(?P<version>[^-]+)-(?P<py>[^-]+)-(?P<abi>[^-]+)-(?P<plat>[^-]+)\.whl$", name)
    if m is None or m["abi"] != "abi3":
        raise CrossError(f"{name} is not an abi3 wheel")
    dist_info = f"{m['dist']}-{m['version']}.dist-info"
    out = Path(out_dir) / f"{m['dist']}-{m['version']}-{m['py']}-abi3-{spec['wheel_platform']}.whl"
    entries: list[tuple[str, bytes]] = []
    replaced = set()
    with zipfile.ZipFile(linux_wheel) as z:
        for info in z.infolist():
            entry = info.filename
            if entry.endswith("/") or entry == f"{dist_info}/RECORD":
                continue
            folder, _, file = entry.rpartition("/")
            if file.endswith((".so", ".pyd")):
                short = file.split(".")[0]
                if short not in modules:
                    raise CrossError(f"{name} carries {entry}, not built for {target}")
                entries.append((f"{folder}/{short}{spec['suffix']}", Path(modules[short]).read_bytes()))
                replaced.add(short)
                continue
            data = z.read(entry)
            if entry == f"{dist_info}/WHEEL":
                lines = [ln for ln in data.decode().splitlines() if not ln.startswith(("Tag:", "Generator:"))]
                lines.insert(1, "Generator: tearcloth tools/cross/native.py")
                lines.append(f"Tag: {m['py']}-abi3-{spec['wheel_platform']}")
                data = ("\n".join(lines) + "\n").encode()
            entries.append((entry, data))
    if replaced != set(modules):
        raise CrossError(f"{name} has compiled modules {sorted(replaced)}, built {sorted(modules)}")
    record = io.StringIO()
    writer = csv.writer(record, lineterminator="\n")
    for entry, data in entries:
        writer.writerow([entry, _record_hash(data), len(data)])
    writer.writerow([f"{dist_info}/RECORD", "", ""])
    entries.append((f"{dist_info}/RECORD", record.getvalue().encode()))
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for entry, data in entries:
            info = zipfile.ZipInfo(entry, date_time=(2020, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if entry.endswith((".so", ".pyd")) else 0o644) << 16
            z.writestr(info, data)
    return out


def cross_wheel(target: str, linux_wheel: Path, out_dir: Path, work: Path | None = None,
                src: Path = REPO) -> Path:
    """Build the native modules for ``target`` and package them as our abi3 wheel in ``out_dir``."""
    if not have_zig():
        raise CrossError("the ziglang package is not installed (pip install ziglang): it is the C "
                         "compiler for the Windows and macOS builds")
    own = work is None
    work = Path(tempfile.mkdtemp(prefix=f"tearcloth-cross-{target}-")) if own else Path(work)
    try:
        return retag_wheel(Path(linux_wheel), target, build_modules(target, work, src), Path(out_dir))
    finally:
        if own:
            shutil.rmtree(work, ignore_errors=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--target", required=True, choices=sorted(TARGETS))
    p.add_argument("--from-wheel", required=True, help="our Linux abi3 wheel (pip wheel . --no-deps)")
    p.add_argument("--out", default=str(REPO / "dist"))
    args = p.parse_args(argv)
    try:
        made = cross_wheel(args.target, Path(args.from_wheel), Path(args.out))
    except CrossError as exc:
        print(f"cross: error: {exc}", file=sys.stderr)
        return 1
    print(f"cross: wrote {made}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
