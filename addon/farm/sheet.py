"""The wedge contact sheet: one rendered frame per variation in a labelled grid (one PNG).

What this file owns: ``contact_sheet`` (matplotlib, no Blender: the frames were rendered by
each task's ``tearcloth bake --render`` with the scene's camera, Workbench unless kept). A wedge
of exactly two parameters on one object is laid out as a table, rows the first parameter's
values and columns the second's, so the eye reads one parameter down and one across; anything
else fills a near-square grid in task order.

``python -m tearcloth.farm.sheet DIR`` gathers the manifests of several farm runs below DIR (one
per task of the Open Job Description template, ``farm/openjd/``) into ``DIR/contact_sheet.png``.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def _layout(results: list) -> tuple[int, int, list]:
    """(rows, columns, [(row, column, result)])."""
    keys = list(results[0]["settings"]) if results else []
    if len(keys) == 2 and all(list(r["settings"]) == keys for r in results):
        a = list(dict.fromkeys(r["settings"][keys[0]] for r in results))
        b = list(dict.fromkeys(r["settings"][keys[1]] for r in results))
        if len(a) * len(b) == len(results):
            return len(a), len(b), [(a.index(r["settings"][keys[0]]), b.index(r["settings"][keys[1]]), r)
                                    for r in results]
    cols = max(1, math.ceil(math.sqrt(len(results))))
    rows = max(1, math.ceil(len(results) / cols))
    return rows, cols, [(i // cols, i % cols, r) for i, r in enumerate(results)]


def label(result: dict, with_object: bool) -> str:
    head = f"{Path(result['file']).stem} / {result['object']}\n" if with_object else ""
    return head + result["label"].replace(", ", "\n")


def contact_sheet(results: list, path: Path, with_object: bool = False, frame: int | None = None) -> Path:
    """Write the grid of ``results``' renders (each a manifest record with ``render``,
    ``settings``, ``label``, ``status``) to ``path``; returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt

    rows, cols, cells = _layout(results)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for r, c, result in cells:
        ax = axes[r][c]
        ax.imshow(mpimg.imread(result["render"]))
        status = "" if result["status"] == "done" else f" [{result['status']}]"
        tears = f"\n{result.get('tears', 0)} tears" if result["status"] == "done" else ""
        ax.set_title(label(result, with_object) + status + tears, fontsize=9)
    shown = f"frame {frame}" if frame is not None else "last baked frame"
    fig.suptitle(f"Tear Cloth wedge: {len(cells)} variations, {shown}", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def gather(folder: Path) -> Path:
    """The contact sheet of every run whose manifest lies in a folder right below ``folder``."""
    results = []
    for manifest in sorted(folder.glob("*/manifest.json")):
        results += [r for r in json.loads(manifest.read_text())["tasks"]
                    if r.get("render") and Path(r["render"]).is_file()]
    if not results:
        raise FileNotFoundError(f"no farm run with rendered frames below {folder}")
    several = len({(r["file"], r["object"]) for r in results}) > 1
    return contact_sheet(results, folder / "contact_sheet.png", several)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m tearcloth.farm.sheet DIR")
    print(f"wrote {gather(Path(sys.argv[1]))}")
