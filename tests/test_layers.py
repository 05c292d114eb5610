"""The house's layering, read from the source itself (``docs/architecture.md``):

- only ``addon/blender/`` imports ``bpy`` (everything else imports without Blender);
- no module of the package imports, directly or through others, one that imports it back;
- what ships in the extension never needs what only measures or generates (``tearcloth.bench``,
  ``tearcloth.examples``) at import time;
- in the native core no two source files call each other, through any chain (read from the
  symbols each compiled file defines and needs, so a call hidden behind a header still counts).

Imports are read with ``ast`` from every ``.py`` file under ``addon/``, at any depth (an import
inside a function is still a dependency, it only happens later), so the test needs no build.
"""
from __future__ import annotations

import ast
import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ADDON = REPO / "addon"
PACKAGE = "tearcloth"
DEV_ONLY = ("tearcloth.bench", "tearcloth.examples", "tearcloth.blender.race")


def _module_name(path: Path) -> str:
    rel = path.relative_to(ADDON).with_suffix("")
    parts = [PACKAGE, *rel.parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(ADDON.rglob("*.py")) if "__pycache__" not in p.parts}


MODULES = _modules()


def _resolve(module: str, node: ast.ImportFrom, path: Path) -> str:
    if node.level == 0:
        return node.module or ""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for _ in range(node.level - 1):
        package = package.rpartition(".")[0]
    return f"{package}.{node.module}" if node.module else package


def _imports(module: str, path: Path, top_level_only: bool = False) -> set[str]:
    """Every module name this module imports (``from .x import y`` counts ``.x.y`` when that is a
    module of the package, else ``.x``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    nodes = tree.body if top_level_only else ast.walk(tree)
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, node, path)
            # `from . import sibling` inside a package names the package that is already being
            # imported (it holds this module): only the sibling is a dependency
            if not module.startswith(base + "."):
                found.add(base)
            for alias in node.names:
                if f"{base}.{alias.name}" in MODULES:
                    found.add(f"{base}.{alias.name}")
    return found


def _package_edges(top_level_only: bool = False) -> dict[str, set[str]]:
    edges = {}
    for module, path in MODULES.items():
        targets = set()
        for name in _imports(module, path, top_level_only):
            # an import of a.b.c also runs a.b's and a's __init__; only the named module is an edge
            while name and name not in MODULES:
                name = name.rpartition(".")[0]
            # The root package is every import's first stop (its __init__ is lazy by design and
            # only register() reaches down into the Blender layer): it is not an edge.
            if name and name != module and name.startswith(PACKAGE + "."):
                targets.add(name)
        edges[module] = targets
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan, iterative)."""
    index, low, on_stack, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def test_the_reader_sees_the_package():
    # guards the rest: a reader that found nothing would pass every rule below
    assert {"tearcloth", "tearcloth.cloth", "tearcloth.blender", "tearcloth.session"} <= set(MODULES)
    assert "tearcloth.cloth" in _package_edges()["tearcloth.session"]


def test_only_the_blender_layer_imports_bpy():
    offenders = {
        module: sorted(n for n in _imports(module, path) if n.split(".")[0] == "bpy")
        for module, path in MODULES.items()
        if not module.startswith("tearcloth.blender")
    }
    assert {m: n for m, n in offenders.items() if n} == {}


def test_no_module_imports_one_that_imports_it_back():
    assert _cycles(_package_edges()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_what_ships_does_not_need_what_measures():
    shipped = {m: t for m, t in _package_edges(top_level_only=True).items() if not m.startswith(DEV_ONLY)}
    needs = {m: sorted(x for x in t if x.startswith(DEV_ONLY)) for m, t in shipped.items()}
    assert {m: x for m, x in needs.items() if x} == {}


# ------------------------------------------------------------------------------------------------
# The native core: which file calls which, from the compiled objects' symbol tables.

def _native_call_graph(sources: list[Path], include: list[Path], tmp: Path) -> dict[str, set[str]]:
    defined, needed = {}, {}
    for source in sources:
        name = str(source.relative_to(REPO / "native"))
        obj = tmp / (name.replace("/", "_") + ".o")
        built = subprocess.run(["cc", "-std=c17", "-O0", "-c", str(source), "-o", str(obj),
                                *[f"-I{p}" for p in include], "-DTC_NO_CLONES",
                                f"-I{_python_include()}", "-DPy_LIMITED_API=0x030B0000"],
                               capture_output=True, text=True)
        assert built.returncode == 0, built.stderr[-2000:]
        table = subprocess.run(["nm", "-P", str(obj)], check=True, capture_output=True, text=True).stdout
        rows = [line.split() for line in table.splitlines() if len(line.split()) >= 2]
        defined[name] = {r[0] for r in rows if r[1] in "TDBR"}
        needed[name] = {r[0] for r in rows if r[1] == "U"}
    owner = {sym: f for f, syms in defined.items() for sym in syms}
    return {f: {owner[s] for s in syms if s in owner and owner[s] != f} for f, syms in needed.items()}


def _python_include() -> str:
    import sysconfig

    return sysconfig.get_paths()["include"]


@pytest.mark.skipif(not (shutil.which("cc") and shutil.which("nm")), reason="needs a C compiler and nm")
@pytest.mark.parametrize("module", ["native", "native/collide"])
def test_no_two_native_files_call_each_other(module, tmp_path):
    # each Python module's sources as setup.py builds them: its own folder plus the shared
    # Python-boundary helpers (native/py/), compiled into both
    folder = REPO / module
    sources = sorted(folder.glob("*.c")) + sorted((REPO / "native" / "py").glob("*.c"))
    include = [REPO / "native", REPO / "native" / "py", folder]
    graph = _native_call_graph(sources, include, tmp_path)
    assert sum(len(v) for v in graph.values()) > 0, "read no calls between files"
    assert _cycles(graph) == [], graph
