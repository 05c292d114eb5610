"""Messages to the user: one list that an operator turns into ``self.report`` calls and the headless
bake turns into log lines, so every problem reads the same in the UI and in a farm log.

This file owns the ``Reports`` collector and the ``tearcloth`` logger used by the Blender layer.
It imports no bpy: validation code fills a ``Reports`` and never needs to know who will show it.
"""
from __future__ import annotations

import logging
import re

log = logging.getLogger("tearcloth")

# Blender's report levels and the logging level each maps to.
_LEVELS = {"ERROR": logging.ERROR, "WARNING": logging.WARNING, "INFO": logging.INFO}


class BakeError(ValueError):
    """A bake (or another Tear Cloth action) that cannot go ahead; the message says why and what
    to do. The scene is left as it was."""


class Reports:
    """An ordered list of (level, message); levels are Blender's 'ERROR', 'WARNING' and 'INFO'.

    Every message is logged the moment it is added, so a headless run shows it even if nothing
    else reads the list.
    """

    def __init__(self):
        self.items: list[tuple[str, str]] = []

    def add(self, level: str, message: str) -> None:
        if level not in _LEVELS:
            raise ValueError(f"report level must be one of {sorted(_LEVELS)}, not {level!r}")
        if (level, message) in self.items:
            return  # the same check reached twice (the plan's and the core's): said once
        self.items.append((level, message))
        log.log(_LEVELS[level], message)

    def error(self, message: str) -> None:
        self.add("ERROR", message)

    def warning(self, message: str) -> None:
        self.add("WARNING", message)

    def info(self, message: str) -> None:
        self.add("INFO", message)

    @property
    def errors(self) -> list[str]:
        return [m for level, m in self.items if level == "ERROR"]

    @property
    def warnings(self) -> list[str]:
        return [m for level, m in self.items if level == "WARNING"]

    def raise_if_errors(self) -> None:
        """Stop here if anything was an error (all errors, not only the first, are in the list)."""
        if self.errors:
            raise BakeError("; ".join(self.errors))

    def to_operator(self, operator) -> None:
        """Show every message through ``operator.report`` (the status bar and the Info editor)."""
        for level, message in self.items:
            operator.report({level}, message)


def object_kind(type_name: str) -> str:
    """'an empty', 'a curve', ... for an object's ``type`` (e.g. 'EMPTY', 'GREASEPENCIL')."""
    word = type_name.lower().replace("_", " ")
    return ("an " if word[:1] in "aeiou" else "a ") + word


def not_a_mesh(obj) -> str:
    return f"{obj.name!r} is {object_kind(obj.type)}, not a mesh: Tear Cloth works on mesh objects"


def linked_from(obj) -> str | None:
    """Why Tear Cloth cannot bake or free a linked object (None for a local one): its data is the
    library's, read-only here, and a local object may have the same name (the add-on finds objects
    by name: the bake went to the local one, replacing its bake)."""
    lib = getattr(obj, "library", None)
    if lib is None:
        return None
    return (f"{obj.name!r} is linked from {lib.filepath}: its bake is made and freed in that file "
            "(or make it local here: Object > Relations > Make Local)")


# ---------------------------------------------------------------------------------------------
# The solver's element indices in the user's terms

_NUMBERS = r"(\d+(?:(?:, | and )\d+)*)"


def user_geometry_message(text: str, polygons, vertices, culprits: tuple | None = None) -> str:
    """A message of the core about the mesh it was given, with its triangle and vertex indices
    replaced by the user's polygon and vertex indices.

    ``polygons`` (m,): the user's polygon of each solver triangle; ``vertices`` (n,): the user's
    vertex of each solver vertex (loose vertices are left out of the solver, so the two numberings
    differ). Valid only for the mesh as it was handed to the core, before any tear. The core names
    elements as 'triangle(s) N[, N and N]', 'vertices N, N, N', 'vertex N', 'a vertex (N, N, N)' and
    'edge (N, N)' (native/mesh.c, native/cloth.c). ``culprits``: the user's (polygons, vertices)
    the core's error named (``user_culprits``): a message worded otherwise gets them appended, so
    it names the user's elements whatever the wording.
    """
    if polygons is None or vertices is None:
        return text

    def mapped(numbers: str, table) -> str:
        def one(m):
            i = int(m.group(0))
            return str(int(table[i])) if 0 <= i < len(table) else m.group(0)
        return re.sub(r"\d+", one, numbers)

    def triangles(m):
        plural = m.group(1) == "triangles"
        parts = [int(x) for x in re.findall(r"\d+", m.group(2))]
        polys = list(dict.fromkeys(int(polygons[i]) if 0 <= i < len(polygons) else i for i in parts))
        if len(polys) == 1:
            return f"polygon {polys[0]}"
        listed = ", ".join(str(p) for p in polys[:-1]) + f" and {polys[-1]}"
        return ("polygons " if plural or len(polys) > 1 else "polygon ") + listed

    before = text
    text = re.sub(r"\b(triangles?) " + _NUMBERS, triangles, text)
    text = re.sub(r"\b(vertices|vertex) \(?" + _NUMBERS, lambda m: m.group(0)[: -len(m.group(2))]
                  + mapped(m.group(2), vertices), text)
    text = re.sub(r"\bedge \((\d+), (\d+)\)", lambda m: f"edge between vertices "
                  f"{mapped(m.group(1), vertices)} and {mapped(m.group(2), vertices)}", text)
    if text == before and culprits is not None and (culprits[0] or culprits[1]):
        # worded otherwise than the patterns above: name the elements from the core's own list
        polys, verts = culprits
        named = ([f"polygon{'s' if len(polys) > 1 else ''} {', '.join(map(str, polys))}"] if polys else []) + \
                ([f"{'vertices' if len(verts) > 1 else 'vertex'} {', '.join(map(str, verts))}"] if verts else [])
        text = f"{text} (in your mesh: {'; '.join(named)})"
    return text


def user_culprits(exc, polygons, vertices) -> tuple[list, list] | None:
    """The user's polygons and vertices a refusal of the core names (its ``.triangles`` and
    ``.vertices``, solver numbering, mapped through the same tables as the message), or None when
    the error carries none."""
    tris, verts = getattr(exc, "triangles", None), getattr(exc, "vertices", None)
    if tris is None or verts is None or polygons is None or vertices is None:
        return None
    polys = list(dict.fromkeys(int(polygons[t]) for t in tris if 0 <= t < len(polygons)))
    users = list(dict.fromkeys(int(vertices[v]) for v in verts if 0 <= v < len(vertices)))
    return polys, users
