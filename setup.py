"""Build of the native core: one abi3 extension (CPython limited API 3.11) so a single wheel per
platform serves every Blender from 4.2 (Python 3.11) to 5.x (Python 3.13)."""
import os
import sys

from setuptools import Extension, setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))


def _packages():
    # The folder addon/ is installed as the package `tearcloth`; its sub-folders follow.
    found = []
    for root, dirs, files in os.walk(os.path.join(HERE, "addon")):
        dirs[:] = [d for d in dirs if not d.startswith((".", "__"))]
        if "__init__.py" in files:
            rel = os.path.relpath(root, os.path.join(HERE, "addon"))
            found.append("tearcloth" if rel == "." else "tearcloth." + rel.replace(os.sep, "."))
    return sorted(found)


class BuildPyWithExamples(build_py):
    """Ships example_blends/square_cloth.blend as tearcloth/data/ (one copy in the repo), so the
    installed `tearcloth demo` finds the scene it bakes."""

    def run(self):
        super().run()
        src = os.path.join(HERE, "example_blends", "square_cloth.blend")
        if os.path.exists(src):  # absent in tools/build_extension.py's copy: Blender needs no demo
            target = os.path.join(self.build_lib, "tearcloth", "data")
            self.mkpath(target)
            self.copy_file(src, target)


def _c_files(*parts):
    return sorted(os.path.join(*parts, f) for f in os.listdir(os.path.join(HERE, *parts)) if f.endswith(".c"))


# Both modules link the shared argument tables of native/py/ (pyarg.c).
PY_HELPER_SOURCES = _c_files("native", "py")
NATIVE_SOURCES = _c_files("native") + PY_HELPER_SOURCES
# The collision kernels (clustered ray-traced detection): a second abi3 module, same flags.
COLLIDE_SOURCES = _c_files("native", "collide") + PY_HELPER_SOURCES

if sys.platform == "win32":
    compile_args = ["/O2", "/std:c17"]
else:
    # -fno-math-errno lets sqrt inline; no -ffast-math because the solver relies on NaN checks.
    # -std=c17 turns floating-point contraction off; -ffp-contract=fast gives it back, so the AVX2
    # clones (core.h's TC_HOT) and arm64 fuse multiply-adds (the x86-64 baseline has no FMA).
    # -fno-trapping-math (nothing reads the floating-point exception flags; NaN and Inf still flow
    # as IEEE says) lets the compiler turn selects into blends: fem.c's loops over batches of
    # triangles vectorise only with it.
    compile_args = ["-std=c17", "-ffp-contract=fast", "-O3", "-fno-math-errno", "-fno-trapping-math", "-Wall",
                    "-Wextra", "-Wno-unused-parameter"]

setup(
    packages=_packages(),
    package_dir={"tearcloth": "addon"},
    package_data={"tearcloth": ["blender_manifest.toml", "data/*"]},
    ext_modules=[
        Extension(
            "tearcloth._native",
            sources=NATIVE_SOURCES,
            include_dirs=["native", os.path.join("native", "py")],
            define_macros=[("Py_LIMITED_API", "0x030B0000")],
            py_limited_api=True,
            extra_compile_args=compile_args,
        ),
        Extension(
            "tearcloth._collide",
            sources=COLLIDE_SOURCES,
            # native/: the shared vecmath.h; native/py/: the argument tables
            include_dirs=[os.path.join("native", "collide"), "native", os.path.join("native", "py")],
            define_macros=[("Py_LIMITED_API", "0x030B0000")],
            py_limited_api=True,
            extra_compile_args=compile_args,
        ),
    ],
    options={"bdist_wheel": {"py_limited_api": "cp311"}},
    cmdclass={"build_py": BuildPyWithExamples},
)
