#!/usr/bin/env bash
# One entry point for the README's Quick start: set up everything this project needs on a fresh
# Debian machine with Python 3.11 (a virtual environment in .venv, the native extension built by
# pip, Blender's bpy from PyPI), then run the main job or the tests.
#   bash tools/run.sh demo    - tear the paper's square cloth, write pictures to out/demo
#   bash tools/run.sh test    - sanitizer build of the native tests, then the pytest suite
#   bash tools/run.sh bench   - tearcloth bench --json out/bench.json
set -euo pipefail
cd "$(dirname "$0")/.."
job=${1:-demo}
PY=${PYTHON:-python3}
VENV=${TEARCLOTH_VENV:-.venv}

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

command -v cc >/dev/null 2>&1 || apt_install gcc libc6-dev
if [ ! -f "$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')/Python.h" ]; then
    apt_install python3-dev
fi
if [ ! -x "$VENV/bin/python" ]; then
    "$PY" -m venv "$VENV" 2>/dev/null || { rm -rf "$VENV"; apt_install python3-venv; "$PY" -m venv "$VENV"; }
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
# a regular (non-editable) install: tests run against what users get, native module included
"$VENV/bin/python" -m pip install -q ".[test]"
# bpy from PyPI needs a few X/GL client libraries even headless
if ! "$VENV/bin/python" -c "import bpy" >/dev/null 2>&1; then
    apt_install libxrender1 libxxf86vm1 libxfixes3 libxi6 libxkbcommon0 libsm6 libgl1 libegl1
fi

case "$job" in
    demo) "$VENV/bin/tearcloth" demo --out out/demo ;;
    test)
        bash native/tests/run_sanitizers.sh
        # run from tests/ so the package under test is the installed one, not the source folder
        cd tests && "../$VENV/bin/python" -m pytest -q -p no:cacheprovider .
        ;;
    bench) "$VENV/bin/tearcloth" bench --json out/bench.json --markdown BENCHMARKS.md --plots docs/images ;;
    *) echo "usage: bash tools/run.sh [demo|test|bench]" >&2; exit 2 ;;
esac
