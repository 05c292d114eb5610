"""The four platform zips (windows-x64, macos-arm64, macos-x64, linux-x64) and every native binary in
them, checked structurally: the Windows and macOS modules are cross-compiled here and cannot be
run here, so what can be proven without running them is proven.

Per zip: Blender's own validator accepted it; it carries exactly its platform's wheels (ours,
embreex and hidapi for both Python 3.11 and 3.13, libusb-package with importlib_resources, pyftdi,
pyusb, ftd2xx). Per wheel of ours: a proper abi3 wheel (WHEEL tag = file name, RECORD hashes and
sizes right). Per compiled module (tools/cross/binfmt.py reads the headers): file format and CPU, the exported
``PyInit_<name>``, and imports of nothing but the CPython stable ABI (what the limited API 3.11
headers declare, the same set the Linux build links) and the system's C runtime.
"""
from __future__ import annotations

import base64
import csv
import hashlib
import io
import re
import tomllib
import zipfile
from pathlib import Path

import pytest

from extension_build import REPO, load_tool, packages, wheels_for

pytest.importorskip("bpy")  # Blender's own builder and validator come with the PyPI bpy

binfmt = load_tool("tearcloth_binfmt", "tools/cross/binfmt.py")
cross = load_tool("tearcloth_cross_native", "tools/cross/native.py")

MANIFEST = tomllib.loads((REPO / "addon" / "blender_manifest.toml").read_text())
PLATFORMS = ["linux-x64", "windows-x64", "macos-arm64", "macos-x64"]
# platform -> (file format, CPU, file suffix of a compiled module, wheel platform tag)
EXPECTED = {
    "linux-x64": ("ELF", "x86-64", ".abi3.so", "linux_x86_64"),
    "windows-x64": ("PE32+", "x86-64", ".pyd", "win_amd64"),
    "macos-arm64": ("Mach-O", "arm64", ".abi3.so", "macosx_11_0_arm64"),
    "macos-x64": ("Mach-O", "x86-64", ".abi3.so", "macosx_10_13_x86_64"),
}
PYTHON_NAME = cross.PYTHON_NAME
# The C runtimes: Universal CRT API sets and KERNEL32 on Windows, libSystem on macOS, glibc.
WINDOWS_RUNTIME = re.compile(r"^(KERNEL32\.dll|api-ms-win-crt-[a-z]+-l1-1-0\.dll)$", re.I)
# the dynamic loader is glibc's too: thread-local storage in a shared object (util.c's culprits) binds
# __tls_get_addr from it
LINUX_RUNTIME = {"libc.so.6", "libm.so.6", "libpthread.so.0", "libdl.so.2", "ld-linux-x86-64.so.2", "ld-linux-aarch64.so.1"}


@pytest.fixture(scope="module")
def built():
    return packages()


@pytest.fixture(scope="module")
def stable_abi(tmp_path_factory):
    """{symbol: kind} of the stable ABI, from the limited API 3.11 headers (zig cc -E)."""
    if not cross.have_zig():
        pytest.fail("the ziglang package (a test dependency) is not installed")
    return cross.stable_abi(tmp_path_factory.mktemp("abi"))


def _own_wheel(zip_path: Path) -> tuple[str, bytes]:
    with zipfile.ZipFile(zip_path) as z:
        (name,) = [n for n in z.namelist() if n.startswith("wheels/tearcloth-")]
        return name[len("wheels/"):], z.read(name)


@pytest.fixture(scope="module")
def binaries(built, tmp_path_factory):
    """{(platform, module): binfmt.Binary} for every compiled module in every zip."""
    found = {}
    for platform, zip_path in built["zips"].items():
        folder = tmp_path_factory.mktemp(platform)
        name, data = _own_wheel(zip_path)
        with zipfile.ZipFile(io.BytesIO(data)) as wheel:
            for entry in wheel.namelist():
                if entry.startswith("tearcloth/") and entry.endswith((".so", ".pyd")):
                    target = folder / entry.rpartition("/")[2]
                    target.write_bytes(wheel.read(entry))
                    found[(platform, target.name.split(".")[0])] = (target.name, binfmt.read(target))
    return found


def test_one_validated_zip_per_platform(built):
    assert sorted(built["zips"]) == sorted(PLATFORMS) == sorted(MANIFEST["platforms"])
    for platform, zip_path in sorted(built["zips"].items()):
        verdict = built["validation"][platform]
        print(f"{zip_path.name}: {zip_path.stat().st_size / 1e6:.1f} MB; {verdict}")
        assert verdict.startswith("validated by Blender"), verdict
        assert zip_path.stat().st_size < 40e6


@pytest.mark.parametrize("platform", PLATFORMS)
def test_each_zip_carries_its_platforms_wheels(built, platform):
    with zipfile.ZipFile(built["zips"][platform]) as z:
        wheels = sorted(n[len("wheels/"):] for n in z.namelist() if n.startswith("wheels/"))
        packed = tomllib.loads(z.read("blender_manifest.toml").decode())
    # what Blender's --split-platforms wrote for this zip ([build.generated] of its manifest)
    generated = packed["build"]["generated"]
    assert generated["platforms"] == [platform]
    assert sorted(w[len("./wheels/"):] for w in generated["wheels"]) == wheels
    assert wheels == sorted(w[len("./wheels/"):] for w in wheels_for(MANIFEST, platform))
    tag = EXPECTED[platform][3]
    assert f"tearcloth-{MANIFEST['version']}-cp311-abi3-{tag}.whl" in wheels
    # the per-Python-version wheels, for Blender 4.2-5.0 (3.11) and 5.1+ (3.13)
    for name in ("embreex", "hidapi"):
        pythons = sorted(w.split("-")[2] for w in wheels if w.startswith(name + "-"))
        assert pythons == ["cp311", "cp313"], (name, wheels)
    # the Falcon's transports and the pure-Python device libraries
    for name in ("libusb_package", "importlib_resources", "pyftdi", "pyusb", "ftd2xx"):
        assert sum(w.startswith(name + "-") for w in wheels) == 1, (name, wheels)
    tool = built["tool"]
    for w in wheels:
        tags = tool.parse_wheel(w)["platform"].split(".")
        assert tags == ["any"] or any(tool._blender_platform(t) == platform for t in tags), w


def _record_hash(data: bytes) -> str:
    return "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


@pytest.mark.parametrize("platform", PLATFORMS)
def test_our_wheel_is_a_proper_abi3_wheel(built, platform):
    name, data = _own_wheel(built["zips"][platform])
    _, version, py, abi, plat = name[:-4].split("-")
    assert (py, abi, plat) == ("cp311", "abi3", EXPECTED[platform][3])
    dist_info = f"tearcloth-{version}.dist-info"
    with zipfile.ZipFile(io.BytesIO(data)) as wheel:
        files = {n: wheel.read(n) for n in wheel.namelist() if not n.endswith("/")}
    meta = dict(line.split(": ", 1) for line in files[f"{dist_info}/WHEEL"].decode().splitlines() if ": " in line)
    assert meta["Tag"] == f"{py}-{abi}-{plat}" and meta["Root-Is-Purelib"] == "false"
    rows = list(csv.reader(io.StringIO(files[f"{dist_info}/RECORD"].decode())))
    assert sorted(r[0] for r in rows) == sorted(files)
    for path, digest, size in rows:
        if path == f"{dist_info}/RECORD":
            assert digest == size == ""
        else:
            assert digest == _record_hash(files[path]) and int(size) == len(files[path]), path
    suffix = EXPECTED[platform][2]
    compiled = sorted(n for n in files if n.endswith((".so", ".pyd")))
    assert compiled == [f"tearcloth/_collide{suffix}", f"tearcloth/_native{suffix}"]
    # the Python files are the same in every platform's wheel (the cross wheels reuse Linux's)
    _, linux = _own_wheel(built["zips"]["linux-x64"])
    with zipfile.ZipFile(io.BytesIO(linux)) as wheel:
        py_linux = {n: wheel.read(n) for n in wheel.namelist() if n.endswith(".py")}
    assert {n: d for n, d in files.items() if n.endswith(".py")} == py_linux


MODULES = [(p, m) for p in PLATFORMS for m in ("_native", "_collide")]


@pytest.mark.parametrize("platform,module", MODULES)
def test_native_binary_format_and_exports(binaries, platform, module):
    filename, b = binaries[(platform, module)]
    fmt, arch, suffix, tag = EXPECTED[platform]
    assert filename == module + suffix
    assert (b.format, b.arch) == (fmt, arch)
    assert b.kind == {"ELF": "shared object", "PE32+": "dll", "Mach-O": "dylib"}[fmt]
    # the init function is exported, and no Python API name is defined here (no private copy)
    assert [e for e in b.exports if PYTHON_NAME.match(e)] == [f"PyInit_{module}"]
    if fmt == "Mach-O":
        major, minor = tag.split("_")[1:3]
        assert b.min_os == f"{major}.{minor}"  # the wheel tag promises no older macOS than the binary
        if arch == "arm64":
            assert b.signed  # macOS kills unsigned arm64 code: the linker's ad-hoc signature
    if fmt == "PE32+":
        assert not b.notes  # no delay-load imports


@pytest.mark.parametrize("platform,module", MODULES)
def test_native_binary_imports_only_the_stable_abi_and_the_c_runtime(binaries, stable_abi, platform, module):
    _, b = binaries[(platform, module)]
    python = sorted(s for s in b.imported() if PYTHON_NAME.match(s))
    outside = [s for s in python if s not in stable_abi]
    assert not outside, f"not in the stable ABI: {outside}"
    # the same Python symbols as the Linux build of the same sources (built by the system's gcc
    # with CPython's own pyconfig.h): the cross builds' headers and libraries change nothing
    _, linux = binaries[("linux-x64", module)]
    assert python == sorted(s for s in linux.imported() if PYTHON_NAME.match(s))
    if b.format == "PE32+":
        assert [lib for lib in b.libraries if lib.lower().startswith("python")] == ["python3.dll"]
        assert all(PYTHON_NAME.match(s) for s in b.imports["python3.dll"])
        others = [lib for lib in b.libraries if lib != "python3.dll"]
        assert all(WINDOWS_RUNTIME.match(lib) for lib in others), others
        assert not [s for lib in others for s in b.imports[lib] if PYTHON_NAME.match(s)]
    elif b.format == "Mach-O":
        assert b.libraries == ["/usr/lib/libSystem.B.dylib"]
        # Python symbols bound at load time to whichever image defines them (the interpreter);
        # everything else to libSystem
        assert sorted(b.imports[binfmt.DYNAMIC_LOOKUP]) == python
        assert set(b.imports) == {binfmt.DYNAMIC_LOOKUP, "/usr/lib/libSystem.B.dylib"}, set(b.imports)
    else:
        assert set(b.libraries) <= LINUX_RUNTIME, b.libraries  # no libpython: abi3 binds late


def test_the_stable_abi_read_from_the_headers_is_plausible(stable_abi):
    """The reference of the test above must be neither empty nor the whole C library: core
    functions and data are in, C runtime functions and CPython internals are out."""
    for name in ("PyLong_FromLong", "PyType_FromSpec", "PyObject_GetBuffer", "PyEval_SaveThread"):
        assert stable_abi[name] == "func"
    for name in ("_Py_NoneStruct", "PyExc_ValueError"):
        assert stable_abi[name] == "data"
    for name in ("malloc", "snprintf", "timespec_get", "_PyObject_GC_Calloc"):
        assert name not in stable_abi
    # not in the limited API 3.11 (added to it in 3.12 / 3.13, or never limited)
    for name in ("PyType_FromMetaclass", "PyLong_AsInt", "_PyObject_GetDictPtr", "PyFrame_GetBack"):
        assert name not in stable_abi


@pytest.mark.skipif(not __import__("shutil").which("llvm-objdump"), reason="needs llvm-objdump to disassemble")
@pytest.mark.parametrize("platform", [p for p in PLATFORMS if EXPECTED[p][1] == "x86-64"])
def test_x86_binaries_carry_the_avx2_product_and_choose_it_by_cpuid(binaries, platform, tmp_path):
    """The solver's AVX2/FMA product is compiled into every x86-64 build, and the build asks the
    CPU itself (CPUID, XGETBV) whether to run it: a runtime's CPU-model table is not filled on
    every target (mingw), where the fast kernel would otherwise never run."""
    import subprocess

    name, _ = binaries[(platform, "_native")]
    zip_path = packages()["zips"][platform]
    with zipfile.ZipFile(io.BytesIO(_own_wheel(zip_path)[1])) as wheel:
        (entry,) = [n for n in wheel.namelist() if n.endswith("/" + name)]
        target = tmp_path / name
        target.write_bytes(wheel.read(entry))
    text = subprocess.run(["llvm-objdump", "-d", "--no-show-raw-insn", str(target)], capture_output=True, text=True,
                          check=True).stdout
    assert len(re.findall(r"vfmadd\w*pd\s.*%ymm", text)) >= 6, "no AVX2/FMA product in the build"
    assert re.search(r"\bcpuid\b", text) and re.search(r"\bxgetbv\b", text), "the build never asks the CPU"


# The arm64 product (native/fem_neon.c) in fused two-lane form: 2 for the diagonal block, 6 per pair
# of edge blocks, 3 for an odd one, 1 per flap. Counted inside the kernel's own function: other
# loops are vectorised by the compiler anyway (the linux-arm64 build before the kernel had 100
# vector fmla in all, 5 of them in the portable product).
NEON_FMLA = re.compile(r"\bfmla(\s+v\d+\.2d|\.2d\s+v\d+)")  # GNU syntax on ELF, Apple's on Mach-O


def _arm64_native(platform: str, tmp_path: Path) -> Path:
    """The arm64 ``_native`` module: the shipped one from the macos-arm64 zip; for linux-arm64 (no
    zip: no Blender for it is tested here) a cross build by tools/cross/native.py."""
    if platform in PLATFORMS:
        with zipfile.ZipFile(io.BytesIO(_own_wheel(packages()["zips"][platform])[1])) as wheel:
            (entry,) = [n for n in wheel.namelist() if n.rpartition("/")[2].startswith("_native.")]
            target = tmp_path / entry.rpartition("/")[2]
            target.write_bytes(wheel.read(entry))
        return target
    if not cross.have_zig():
        pytest.fail("the ziglang package (a test dependency) is not installed")
    return cross.build_modules(platform, tmp_path, only=("_native",))["_native"]


@pytest.mark.skipif(not __import__("shutil").which("llvm-objdump"), reason="needs llvm-objdump to disassemble")
@pytest.mark.parametrize("platform", ["macos-arm64", "linux-arm64"])
def test_arm64_binaries_carry_the_neon_product(platform, tmp_path):
    """Every arm64 build has the NEON kernel of the solver's product (vector fmla on .2d lanes);
    the Linux one is also an arm64 ELF module importing nothing but the C runtime and Python."""
    import subprocess

    target = _arm64_native(platform, tmp_path)
    b = binfmt.read(target)
    assert b.arch == "arm64"
    if b.format == "ELF":
        assert set(b.libraries) <= LINUX_RUNTIME, b.libraries
        assert [e for e in b.exports if PYTHON_NAME.match(e)] == ["PyInit__native"]
    text = subprocess.run(["llvm-objdump", "-d", "--no-show-raw-insn", str(target)], capture_output=True, text=True,
                          check=True).stdout
    # a function's listing runs from its label to the next one (Mach-O names carry a leading _)
    m = re.search(r"^[0-9a-f]+ <_?tc_matvec_neon>:\n(.*?)(?=^[0-9a-f]+ <|\Z)", text, re.S | re.M)
    assert m, "no NEON product (tc_matvec_neon) in the build"
    assert len(NEON_FMLA.findall(m.group(1))) >= 12, f"{len(NEON_FMLA.findall(m.group(1)))} vector fmla in the product"


def test_our_host_wheel_is_taken_from_wheels_from_when_it_is_there(tmp_path):
    """tools/run.sh's pytest runs share one build (tests/extension_build.py): the second and third take
    our host wheel from the shared folder instead of compiling the same abi3 wheel again. A folder
    without it still builds it (here with an interpreter that cannot run: the build is attempted)."""
    tool = load_tool()
    expected = next(w for w in MANIFEST["wheels"] if Path(w).name.startswith("tearcloth-")
                    and tool.parse_wheel(w)["platform"] == "linux_x86_64")
    name = Path(expected).name
    shared, wheels = tmp_path / "shared", tmp_path / "wheels"
    shared.mkdir()
    wheels.mkdir()
    (shared / name).write_bytes(b"the shared build")
    no_python = str(tmp_path / "no-python")  # taking the wheel must not run pip
    got = tool.build_own_wheel(tmp_path / "src", wheels, name, no_python, shared)
    assert got == wheels / name and got.read_bytes() == b"the shared build"
    (shared / name).unlink()
    (wheels / name).unlink()
    with pytest.raises(Exception) as raised:  # no wheel there: pip is run (and cannot be here)
        tool.build_own_wheel(tmp_path / "src", wheels, name, no_python, shared)
    assert not (wheels / name).exists(), raised.value
