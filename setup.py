"""Build of the native core: one abi3 extension (CPython limited API 3.11) so a single wheel per
platform serves every Blender from 4.2 (Python 3.11) to 5.x (Python 3.13)."""
import os
import sys

from concurrent.futures import ThreadPoolExecutor

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
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


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


class BuildExtOnEveryCore(build_ext):
    """Compiles an extension's C files side by side, one per core, largest first: setuptools compiles
    them one after the other, and that build (~23 s of CPU at -O3, fem.c alone ~6 s) is what a fresh
    set-up waits for with the other core idle. Uses the compiler's per-file steps (_setup_compile,
    _get_cc_args, _compile: distutils' own split of compile(), as numpy.distutils used them); a
    compiler without them, or one core, compiles as setuptools does."""

    def build_extension(self, ext):
        cc = self.compiler
        steps = ("_setup_compile", "_get_cc_args", "_compile")
        if _cores() > 1 and all(hasattr(cc, s) for s in steps) and not getattr(cc, "_on_every_core", False):
            def compile(sources, output_dir=None, macros=None, include_dirs=None, debug=0, extra_preargs=None,
                        extra_postargs=None, depends=None):
                macros, objects, extra_postargs, pp_opts, build = cc._setup_compile(
                    output_dir, macros, include_dirs, sources, depends, extra_postargs)
                cc_args = cc._get_cc_args(pp_opts, debug, extra_preargs)
                todo = sorted((o for o in objects if o in build), key=lambda o: -os.path.getsize(build[o][0]))
                with ThreadPoolExecutor(_cores()) as pool:  # each job waits on its compiler process
                    for done in [pool.submit(cc._compile, o, *build[o], cc_args, extra_postargs, pp_opts) for o in todo]:
                        done.result()  # a compile error is raised here, as in the serial build
                return objects

            cc.compile = compile
            cc._on_every_core = True
        super().build_extension(ext)


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
    cmdclass={"build_py": BuildPyWithExamples, "build_ext": BuildExtOnEveryCore},
)
