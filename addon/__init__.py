"""Tear Cloth: stress-driven tearing of cloth and paper (Le Gouis et al., WHC 2017) for Blender.

This folder is both the pip package ``tearcloth`` and the Blender extension. It imports without
Blender and without touching the native core: the heavy names load on first use, and only
``register()`` pulls in ``tearcloth.blender`` (the one place that imports ``bpy``).
"""
from importlib import import_module

__version__ = "0.1.0"

# name -> submodule that defines it; resolved lazily so `import tearcloth.haptics` in a servo
# thread or a test never pays for (or requires) the native build.
_LAZY = {
    "Cloth": ".cloth",
    "ClothError": ".cloth",
    "Material": ".materials",
    "MATERIALS": ".materials",
    "material": ".materials",
}


def __getattr__(name):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'tearcloth' has no attribute {name!r}")
    return getattr(import_module(module, __name__), name)


def register():
    from .blender import register as _register

    _register()


def unregister():
    from .blender import unregister as _unregister

    _unregister()
