"""Test-wide settings. Hypothesis runs derandomized so CI sees the same examples on every machine
(a property that fails on some example is then a reproducible failure, not a flake); set
HYPOTHESIS_PROFILE=explore to search new examples locally."""
import os
import sys

from hypothesis import settings

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

sys.path.insert(0, os.path.dirname(__file__))  # tests/meshes.py


# The files that take longest, longest first (seconds of test time, serial, at load 10-19 on the
# 2-core development machine; out of date numbers only cost balance, never a result). Under
# pytest-xdist (tools/run.sh: --dist loadfile) a worker takes the next whole file when it is
# free, so starting the long ones first keeps both workers busy to the end: xdist's own order
# (by test count, since 3.5) started the one-test ~5-minute T-shirt file after every many-test
# file, and it ran alone while the other worker idled.
# test_platforms.py comes first because it builds the extension zips that test_extension.py, a
# few files later, then finds ready (tests/extension_build.py: one build per run; a worker that
# needs it meanwhile waits).
SLOW_FIRST = [
    "test_platforms.py",              # 507 (with the build of the four zips)
    "test_native_arm64.py",           # ~115 s of CPU (cold zig cross build ~57, test_core --kernels under qemu ~56)
    "test_collision_session.py",      # 549
    "test_tearing_physics.py",        # 406
    "test_blender_user_actions.py",   # 316
    "test_bake_resume_tshirt.py",     # 294
    "test_blender_rebake.py",         # 166
    "test_extension.py",              # 202 taking the shared wheels, 674 building them
    "test_examples.py",               # ~130
    "test_bench_parts.py",            # 124
    "test_collision_ccd.py",          # 106
    "test_blender_bake.py",           # 98
    "test_blender_haptics.py",        # 95
    "test_blender_fragments.py",      # 94
    "test_orthotropic.py",            # 80
    "test_collision_recall.py",       # 79
    "test_cache.py",                  # 70
    "test_tearing.py",                # 69
    "test_blender_attributes.py",     # 67
    "test_scenes.py",                 # 64
    "test_blender_addon.py",          # 61
    "test_collision_detect.py",       # 58
    "test_bake_resume_cli.py",        # 55
    "test_bake_unconverged.py",       # 47
]


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):  # xdist >= 3.8 (--no-loadscope-reorder): keep our order
        config.option.loadscopereorder = False
    config.addinivalue_line(
        "markers", "core_only: drives only the native core through numpy (the same C sources and abi3 build "
        "on every interpreter), or only prints a figure whose behaviour another test checks on both: "
        "tools/run.sh's Python 3.13 half leaves it to the 3.11 half (-m 'not core_only'), as it leaves the "
        "files of its CORE_ONLY list")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    # stable: the tests of one file keep their order, the other files theirs
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))

