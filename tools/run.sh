#!/usr/bin/env bash
# One entry point for the README's Quick start: set up everything this project needs on a fresh
# Debian machine with Python 3.11 (a virtual environment in .venv, the native extension built by
# pip, Blender's bpy from PyPI), then run the main job or the tests.
#   bash tools/run.sh demo    - tear the paper's square cloth, write pictures to out/demo
#   bash tools/run.sh test    - sanitizer build of the native tests and the pytest suite, on
#                               Python 3.11 with bpy 5.0.1 (Blender 4.2-5.0), side by side; the Blender
#                               tests again in .venv42 with bpy 4.2 LTS (BPY42 below) and, when a Python
#                               3.13 is found, the suite again in .venv313 with bpy 5.3.0 (Blender 5.1+)
#                               but for CORE_ONLY below (both set up while the first half runs,
#                               then run side by side);
#                               pytest runs one worker per core; logs of the side jobs in out/
#   bash tools/run.sh bench   - tearcloth bench --json out/bench.json
# PYTHON picks the first interpreter (default python3), PYTHON313 the second;
# TEARCLOTH_REQUIRE_313=1 makes a missing Python 3.13 a failure (CI) instead of a notice.
set -euo pipefail
cd "$(dirname "$0")/.."
job=${1:-demo}
PY=${PYTHON:-python3}
VENV=${TEARCLOTH_VENV:-.venv}
VENV313=${TEARCLOTH_VENV313:-.venv313}
VENV42=${TEARCLOTH_VENV42:-.venv42}
# Blender 4.2 LTS, the oldest the manifest allows, as a module (Python 3.11), with numpy 1.x as the
# real Blender 4.2 bundles; TEARCLOTH_SKIP_42=1 leaves this half out
BPY42=${TEARCLOTH_BPY42:-bpy==4.2.23}
# the Blender tests run on it: add-on, bake, re-bake, the installed extension, the example files
# (saved by 4.2) and stock Blender playing our cache: 55 tests, ~5.5 min on the 2-core development
# machine at load 12 (80 s of CPU; ~110 s of it is test_extension building the four zips again)
TESTS42=(test_blender_addon.py test_blender_bake.py test_blender_rebake.py test_extension.py test_examples.py
         test_cache.py)

apt_install() {
    # only where we may (root with apt): a fresh Debian lacks venv, headers or a compiler
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
        echo "installing Debian packages: $*" >&2
        DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
    else
        echo "missing system packages ($*): install them (e.g. sudo apt-get install $*)" >&2
        exit 1
    fi
}

apt_try() {
    # like apt_install, for what only some tests need: without root or apt they skip, saying why
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
        apt_install "$@"
    else
        echo "tools/run.sh: not installed ($*): the tests that need it will skip" >&2
    fi
}

is_313() { [ -n "$1" ] && "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))' >/dev/null 2>&1; }
is_311() { [ -n "$1" ] && "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; }

find_python313() {
    # the first CPython 3.13 that runs: $PYTHON313, python3.13 on PATH (a pyenv shim too),
    # pyenv's newest 3.13, any 3.13 under ~/.pyenv or the usual prefixes
    local candidates=("${PYTHON313:-}" "$(command -v python3.13 || true)")
    if command -v pyenv >/dev/null 2>&1; then
        candidates+=("$(pyenv prefix 3.13 2>/dev/null | tail -n 1)/bin/python")
    fi
    local found
    for found in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.13*/bin/python /usr/local/bin/python3.13 /usr/bin/python3.13; do
        candidates+=("$found")
    done
    for found in "${candidates[@]}"; do
        if is_313 "$found"; then echo "$found"; return 0; fi
    done
    return 1
}

# Our package's wheel, built once per run (own_wheel) and installed into every environment: its native
# core is compiled against the limited API 3.11, so the one abi3 wheel serves Python 3.11 and 3.13;
# building it in each environment compiled the same sources three times (~30 s of CPU each, two of
# them beside the first half's tests)
OWN_WHEEL_DIR=out/own-wheel

built_wheel() {
    # the wheel this run built so far, or nothing (|| true: ls of an empty folder fails, and
    # pipefail would end a background caller here)
    ls "$OWN_WHEEL_DIR"/tearcloth-*.whl 2>/dev/null | head -n 1 || true
}

own_wheel() {
    # own_wheel VENV: the path of this run's wheel, built by VENV's pip the first time (the folder is
    # emptied when a run starts, so a wheel of older sources is never installed)
    local found
    found=$(built_wheel)
    if [ -z "$found" ]; then
        mkdir -p "$OWN_WHEEL_DIR"
        "$1/bin/python" -m pip wheel -q --no-deps --wheel-dir "$OWN_WHEEL_DIR" . >&2 || return 1
        found=$(built_wheel)
        [ -n "$found" ] || { echo "tools/run.sh: pip wheel made no tearcloth wheel in $OWN_WHEEL_DIR" >&2; return 1; }
    fi
    echo "$PWD/$found"
}

setup() {
    # setup PYTHON VENV: the virtual environment with the package (this run's wheel, own_wheel: tests
    # run against what users get, native module included) and the test extras, whose bpy
    # pin follows the Python version (pyproject.toml)
    local py=$1 venv=$2
    if [ ! -f "$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')/Python.h" ]; then
        apt_install python3-dev
    fi
    if [ ! -x "$venv/bin/python" ]; then
        "$py" -m venv "$venv" 2>/dev/null || { rm -rf "$venv"; apt_install python3-venv; "$py" -m venv "$venv"; }
    fi
    "$venv/bin/python" -m pip install -q --upgrade pip
    # this run's wheel compiles (on every core, setup.py) while pip fetches and unpacks the
    # requirements beside it: one after the other, the first set-up waited ~30 s for the compile
    # with the network idle, then ~40 s for pip with a core idle
    local building=""
    if [ -z "$(built_wheel)" ]; then
        own_wheel "$venv" >/dev/null &
        building=$!
    fi
    # the project's requirements and the test extra's (pyproject.toml), but for the extra's bpy
    # when the caller names another ($3: a list of requirements)
    local reqs
    mapfile -t reqs < <("$venv/bin/python" -c 'import sys, tomllib
p = tomllib.load(open("pyproject.toml", "rb"))["project"]
test = [r for r in p["optional-dependencies"]["test"] if not (sys.argv[1] and r.startswith("bpy"))]
print("\n".join(p["dependencies"] + test))' "${3:+other-bpy}")
    # shellcheck disable=SC2086  # $3 is a list of requirements, split on purpose
    "$venv/bin/python" -m pip install -q "${reqs[@]}" ${3:-}
    if [ -n "$building" ]; then wait "$building"; fi
    local wheel
    wheel=$(own_wheel "$venv")
    # --force-reinstall: pip keeps an installed tearcloth of the same version as the wheel
    "$venv/bin/python" -m pip install -q --no-deps --force-reinstall "$wheel"
    # bpy from PyPI needs a few X/GL client libraries even headless
    if ! "$venv/bin/python" -c "import bpy" >/dev/null 2>&1; then
        apt_install libxrender1 libxxf86vm1 libxfixes3 libxi6 libxkbcommon0 libsm6 libgl1 libegl1
    fi
}

# The test files the 3.13 half leaves to the 3.11 half: the native core driven through numpy (the
# same C sources, the same abi3 build), heavy and blind to the interpreter: physics studies, the
# long scenes, the cross and arm64 builds, the FEM, solver, stiff-group, SIMD-kernel, snapshot and tearing
# tests, the collision kernels, CCD and clustering (C and numpy/scipy only), and the layering
# (test_layers.py reads the sources and the compiled objects' symbols, imports nothing). Everything that
# touches bpy, the add-on, the extension, caches, haptics, the farm or the CLI runs on both, and so
# do test_native_defaults.py (the C modules' messages through 3.13's C API) and the two collision
# files that go through embreex, whose binary wheel is built per Python version
# (test_collision_detect.py, test_collision_bvh.py). Single tests of mixed files are marked
# core_only instead (tests/conftest.py).
CORE_ONLY=(test_native_arm64.py test_platforms.py test_bake_resume_tshirt.py test_tearing_physics.py
           test_collision_session.py test_collision_recall.py test_solver_amg.py test_scenes.py
           test_orthotropic.py test_plasticity.py test_fragments.py
           test_fem.py test_solver.py test_solver_simd.py test_stiff_groups.py test_snapshot.py test_tearing.py
           test_collision_kernels.py test_collision_ccd.py test_collision_clusters.py
           test_collision_impact.py test_contact_friction.py test_layers.py)
# pytest workers (pytest-xdist): one per core, at most 4; files stay whole on one worker
# (--dist loadfile) so module fixtures are built once; the extension zips are built once per run
# for all workers (tests/extension_build.py). TEARCLOTH_TEST_WORKERS=1: serial.
WORKERS=${TEARCLOTH_TEST_WORKERS:-$(nproc 2>/dev/null || echo 1)}
[ "$WORKERS" -le 4 ] || WORKERS=4

suite() {
    # suite VENV [PYTEST ARG...]: the pytest suite (or those files of it), run from tests/ so the
    # package under test is the installed one
    local venv=$1
    shift
    echo "== pytest on $("$venv/bin/python" -c 'import sys, bpy; print(f"Python {sys.version.split()[0]}, bpy {bpy.app.version_string}")'), $WORKERS worker(s)" >&2
    local par=()
    if [ "$WORKERS" -gt 1 ] && "$venv/bin/python" -c "import xdist" >/dev/null 2>&1; then
        par=(-n "$WORKERS" --dist loadfile)  # in the order of tests/conftest.py: the slow files first
    fi
    (cd tests && "../$venv/bin/python" -m pytest -q -p no:cacheprovider "${par[@]}" "${@:-.}")
}

command -v cc >/dev/null 2>&1 || apt_install gcc libc6-dev
rm -rf "$OWN_WHEEL_DIR"
sanitizers=""
if [ "$job" = test ]; then
    # the sanitizer build and run of the native tests (one process, ~90 s of CPU; it needs only
    # cc) from the start: the set-up below is mostly pip, one core, and left the other idle for
    # about a minute; started with the first half instead, the two competed for both cores
    mkdir -p out
    bash native/tests/run_sanitizers.sh >out/sanitizers.log 2>&1 &
    sanitizers=$!
    # a failed set-up ends the script and with it this job's script (a test binary it runs then ends
    # on its own, writing only to out/sanitizers.log)
    trap '[ -z "$sanitizers" ] || kill "$sanitizers" 2>/dev/null || true' EXIT
fi
setup "$PY" "$VENV"

case "$job" in
    demo) "$VENV/bin/tearcloth" demo --out out/demo ;;
    test)
        # qemu-user (13 MB from Debian) runs the arm64 build of the native tests (test_native_arm64.py)
        command -v qemu-aarch64 >/dev/null 2>&1 || command -v qemu-aarch64-static >/dev/null 2>&1 || apt_try qemu-user
        mkdir -p out
        # the halves share the extension's cross-compiled and downloaded wheels (tests/extension_build.py)
        export TEARCLOTH_TEST_WHEELS=$PWD/out/test-wheels
        rm -rf "$TEARCLOTH_TEST_WHEELS"
        # the other halves' environments (pip: mostly download and unpacking, one compile each) are
        # set up in the background while the sanitizers and the first half run, one after the
        # other (one apt or pip at a time); their logs are shown with their half's results
        want42=""
        if [ -n "${TEARCLOTH_SKIP_42:-}" ]; then
            echo "tools/run.sh: NOT RUN: the bpy 4.2 LTS half (TEARCLOTH_SKIP_42 is set)" >&2
        elif is_311 "$VENV/bin/python"; then
            want42=1
        else
            echo "tools/run.sh: NOT RUN: the bpy 4.2 LTS half: $PY is not Python 3.11 (Blender 4.2's)" >&2
        fi
        PY313=""
        if is_313 "$VENV/bin/python"; then
            echo "tools/run.sh: $PY is Python 3.13 already: the suite ran once, on it" >&2
        elif ! PY313=$(find_python313); then
            PY313=""
            echo "tools/run.sh: NOT RUN: the Python 3.13 / bpy 5.3.0 half (Blender 5.1+): no Python 3.13 found (set PYTHON313=/path/to/python3.13)" >&2
        fi
        rm -f out/setup42.rc out/setup313.rc out/test42.rc
        (
            # errexit must hold inside setup, so no `|| rc=$?` around it (that would switch it off)
            set +e
            if [ -n "$want42" ]; then
                (set -e; setup "$PY" "$VENV42" "$BPY42 numpy<2") >out/setup42.log 2>&1; echo $? >out/setup42.rc
            fi
            if [ -n "$PY313" ]; then
                (set -e; setup "$PY313" "$VENV313") >out/setup313.log 2>&1; echo $? >out/setup313.rc
            fi
        ) &
        others=$!
        status=0
        suite "$VENV" || status=$?
        san=0
        wait "$sanitizers" || san=$?
        sanitizers=""  # (waited for: nothing for the exit trap to stop)
        echo "== the sanitizer build of the native tests (out/sanitizers.log)" >&2
        cat out/sanitizers.log >&2
        if [ "$san" != 0 ]; then echo "tools/run.sh: the sanitizer run FAILED (status $san)" >&2; status=1; fi
        wait "$others" || true  # each setup left its status in out/setup*.rc
        # the 4.2 half (six Blender files: on two workers its last file ran alone) runs beside the
        # 3.13 half, its output in out/test42.log, shown when both are done
        half42=""
        if [ -n "$want42" ]; then
            if [ "$(cat out/setup42.rc)" = 0 ]; then
                (set +e; suite "$VENV42" "${TESTS42[@]}" >out/test42.log 2>&1; echo $? >out/test42.rc) &
                half42=$!
            else
                cat out/setup42.log >&2
                echo "tools/run.sh: setting up $VENV42 failed (out/setup42.log above)" >&2; status=1
            fi
        fi
        if [ -n "$PY313" ]; then
            cat out/setup313.log >&2
            if [ "$(cat out/setup313.rc)" = 0 ]; then
                ignores=()
                for f in "${CORE_ONLY[@]}"; do ignores+=(--ignore "$f"); done
                suite "$VENV313" "${ignores[@]}" -m "not core_only" . || status=$?
            else
                echo "tools/run.sh: setting up $VENV313 failed (out/setup313.log above)" >&2; status=1
            fi
        elif ! is_313 "$VENV/bin/python"; then
            [ -z "${TEARCLOTH_REQUIRE_313:-}" ] || status=1  # CI must test both Blender lines
        fi
        if [ -n "$half42" ]; then
            wait "$half42" || true
            echo "== the bpy 4.2 LTS half (out/setup42.log, out/test42.log)" >&2
            cat out/setup42.log out/test42.log >&2
            [ "$(cat out/test42.rc)" = 0 ] || status=1
        fi
        exit "$status"
        ;;
    bench) "$VENV/bin/tearcloth" bench --json out/bench.json --markdown BENCHMARKS.md --plots docs/images ;;
    *) echo "usage: bash tools/run.sh [demo|test|bench]" >&2; exit 2 ;;
esac
