"""The native core's C tests (native/tests/test_core.c) on arm64: cross-built here for aarch64 Linux
(zig cc, static musl, undefined behaviour trapping) and run under qemu-user once per kernel of the
solver's product it picks there (NEON). The run checks that every kernel the build has gives the scalar
kernel's product to 1e-12 of its largest component and the scalar kernel's CG iterates to 1e-12 after
1, 2, 3 and 10 iterations, that arm64 has and picks NEON, and that the compiler-vectorised batched
element pass (isotropic, and woven plastic) equals its reference loops to 1e-12 around tears.
It runs test_core with --kernels: everything but test_strip_and_tear, whose 400 steps and snapshot
fuzz (kernel-blind but for their batch checks, which --kernels makes on a short woven sheet) were 80 %
of the ~170 s of CPU qemu took for the whole file; the full file runs natively under ASan/UBSan once
per x86-64 kernel (run_sanitizers.sh). A second whole run with TEARCLOTH_SIMD=scalar was dropped:
those in-run comparisons cover the scalar kernel on arm64, the rest of the core is kernel-blind, and
the scalar path itself runs under ASan/UBSan on x86-64; the second run cost 4-10 minutes of qemu per
suite. Skipped, saying why, where qemu-aarch64 is absent (tools/run.sh installs Debian's qemu-user,
13 MB, when it runs as root with apt)."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
NATIVE = REPO / "native"
QEMU = shutil.which("qemu-aarch64") or shutil.which("qemu-aarch64-static")

pytestmark = pytest.mark.skipif(QEMU is None, reason="qemu-aarch64 is not installed (Debian: apt-get install "
                                                     "qemu-user): the arm64 build cannot be run here")


@pytest.fixture(scope="module")
def arm64_tests(tmp_path_factory) -> Path:
    try:
        import ziglang  # noqa: F401
    except ImportError:
        pytest.fail("the ziglang package (a test dependency) is not installed")
    out = tmp_path_factory.mktemp("arm64") / "test_core"
    core = sorted(str(p) for p in NATIVE.glob("*.c") if p.name != "pymodule.c")
    # run_sanitizers.sh's set of files and flags, with setup.py's optimisation (-O3 -ffp-contract=fast,
    # what the wheels run); ASan has no musl runtime, so undefined behaviour traps instead
    cmd = [sys.executable, "-m", "ziglang", "cc", "-target", "aarch64-linux-musl", "-mcpu=baseline", "-static",
           "-std=c17", "-O3", "-ffp-contract=fast", "-fno-math-errno", "-fsanitize=undefined",
           "-fsanitize-trap=undefined", "-DTC_NO_CLONES", "-Wall", "-Wextra", "-Wno-unused-parameter",
           f"-I{NATIVE}", *core, str(NATIVE / "tests" / "test_core.c"), "-lm", "-o", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


def test_the_core_tests_pass_on_arm64_with_neon(arm64_tests):
    kernel = "neon"
    env = dict(os.environ, TEARCLOTH_SIMD=kernel)
    proc = subprocess.run([QEMU, str(arm64_tests), "--kernels"], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    out = proc.stdout
    assert re.search(rf"^kernel {kernel}$", out, re.M), out[:500]
    assert re.search(r"^kernel checks only \(--kernels\)", out, re.M), out[:500]
    passed = re.search(r"^(\d+) passed, 0 failed$", out, re.M)
    assert passed and int(passed.group(1)) > 900, out[-500:]
    # the NEON product was compared with the scalar one in this run (test_core.c checks the 1e-12)
    diff = re.search(r"^neon vs scalar: largest difference (\S+) of (\S+)$", out, re.M)
    assert diff and float(diff.group(1)) <= 1e-12 * float(diff.group(2)), out[-500:]
    # and its CG iterates, update pass included (test_core.c's test_cg_iterations_agree_across_kernels)
    # one line per preconditioner whose iterations have SIMD kernels (block Jacobi, symmetric Gauss-Seidel
    # with and without contact rows, the multigrid's cycle)
    cg = {m.group(1): (float(m.group(2)), float(m.group(3))) for m in
          re.finditer(r"^(\w+(?: \+ contacts)?), neon after 10 CG iterations: off the scalar kernel by (\S+) of (\S+)$", out, re.M)}
    assert {"jacobi", "sgs", "sgs + contacts", "amg"} <= set(cg), out[-500:]
    for name, (off, scale) in cg.items():
        assert off <= 1e-12 * scale, (name, off, scale)
