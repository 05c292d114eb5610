"""`tearcloth bench`: the speed of every part, measured on this machine, as medians and ratios.

This file owns ``run``: one run of the parts ``PARTS`` picks (Table I, the collision experiment,
the servo loop, the race against Blender's cloth, the multigrid with contacts, scaling, woven materials), printed as tables, merged into a JSON
file keyed as the issues ask (``table1.<scenario>.<figure>``, ``slivers``, ``collision``, ``servo``,
``blender_cloth``, ``multigrid_contacts``, ``scaling``, ``materials``, ``machine``) and optionally written as BENCHMARKS.md. Each figure
is a median over many steps of that run; nothing here asserts a speed. Dev-only (not in the
extension zip).
"""
from __future__ import annotations

import json
import os
import platform
from pathlib import Path

from .collision import collision_figures, format_collision
from .machine import loadavg
from .materials import format_materials, materials_figures
from .race import format_multigrid_contacts, multigrid_contacts, race_blender_cloth
from .report import benchmarks_markdown
from .scaling import format_scaling, plot_scaling, scaling
from .slivers import format_slivers, sliver_figures
from .servo import measure_kill_zero, measure_live_servo, measure_loaded_servo
from .table1 import DT, format_table, measure_scenario, tearing_convergence

__all__ = ["PARTS", "run"]

PARTS = ("table1", "slivers", "collision", "servo", "blender", "multigrid", "scaling", "materials")


def run(json_path: str | None = None, scenarios=("cloth", "banknote", "tshirt"), steps: int = 200,
        out=print, collision: bool = True, parts=PARTS, markdown: str | None = None,
        plots_dir: str | None = None) -> dict:
    """Every figure in one run: Table I (FEM, tearing), the collision experiment, the servo loop,
    the race against Blender's cloth, and scaling up to 100K triangles (``parts`` picks)."""
    load = loadavg()
    load = load[0] if load is not None else None
    results: dict = {"machine": {"python": platform.python_version(), "platform": platform.platform(),
                                 "processor": platform.processor() or platform.machine(),
                                 "cpus": os.cpu_count(), "load_1min_at_start": load},
                     "steps": steps, "dt_s": DT, "table1": {}}
    if "table1" not in parts:
        scenarios = ()
    for name in scenarios:
        out(f"... {name}")
        results["table1"][name] = measure_scenario(name, steps)
    if scenarios:
        out(format_table(results))
        results["tearing"] = tearing_convergence(out)
    if "slivers" in parts:
        out("... slivers (a sheet with 0.23-0.46-degree slivers hung by one edge: auto against the sweeps alone)")
        results["slivers"] = sliver_figures()
        out(format_slivers(results["slivers"]))
    if collision and "collision" in parts:
        out("... collision (T-shirt on the mannequin)")
        results["collision"] = collision_figures()
        out(format_collision(results["collision"]))
        for name in results["table1"]:
            if name == "tshirt":  # the paper's T-shirt column includes collision with the body
                r = results["table1"][name]
                r["collision_ms"] = results["collision"]["simulated"]["dt1ms"]["moving"]["relative_ms"]
                r["total_before_ms"] += r["collision_ms"]
                if r["total_after_ms"] is not None:
                    r["total_after_ms"] += r["collision_ms"]
    if "servo" in parts:
        out("... servo loop (two emulated Falcons, T-shirt simulation on the main thread, 10 s)")
        sv = measure_live_servo(10.0, "tshirt", servo="process")
        results["servo"] = {k: sv[k] for k in ("rate_hz", "p50_ms", "p99_ms")}
        results["servo"]["detail"] = {k: v for k, v in sv.items() if isinstance(v, (int, float, str))}
        out(f"servo: {sv['rate_hz']:.1f} Hz, period p50 {sv['p50_ms']:.3f} ms, p99 {sv['p99_ms']:.3f} ms")
        kz = measure_kill_zero(5)
        results["servo"]["kill_zero_ms"] = kz
        out(f"servo: SIGKILL of the simulating process to zero force on both Falcons: median {kz['median_ms']:.2f} ms, "
            f"max {kz['max_ms']:.2f} ms over {kz['runs']} kills")
        keys = ("rate_hz", "p50_ms", "p99_ms", "max_ms")
        for name, mode in (("loaded", "process"), ("loaded_threads", "thread")):
            out(f"... servo loop loaded ({mode}: T-shirt with collision, GIL-heavy main thread, CPU hog, no RT priority, 10 s)")
            ld = measure_loaded_servo(10.0, "tshirt", servo=mode)
            results["servo"][name] = {k: ld[k] for k in keys}
            results["servo"][name]["detail"] = {k: v for k, v in ld.items() if isinstance(v, (int, float, str))}
            results["servo"][name]["detail"]["privileges"] = str(ld.get("privileges"))
            out(f"servo {name}: {ld['rate_hz']:.1f} Hz, period p50 {ld['p50_ms']:.3f} ms, p99 {ld['p99_ms']:.3f} ms, "
                f"max {ld['max_ms']:.2f} ms" + (f"; a bare unprivileged 1 kHz sleeper beside it: p99 {ld['floor_p99_ms']:.3f} ms, "
                                                f"max {ld['floor_max_ms']:.2f} ms" if "floor_p99_ms" in ld else ""))
    if "blender" in parts:
        out("... Blender's cloth against ours on the T-shirt (same mesh, body, sub-steps)")
        race = race_blender_cloth(frames=24, substeps=10)
        results["blender_cloth"] = {k: race[k] for k in ("ours_s_per_frame", "blender_s_per_frame", "ratio",
                                                         "ours_penetration_max_m", "blender_penetration_max_m",
                                                         "ours_vertices_inside", "blender_vertices_inside",
                                                         "ours_cpu_s_per_frame", "blender_cpu_s_per_frame")}
        results["blender_cloth"]["detail"] = {k: v for k, v in race.items() if k not in results["blender_cloth"]}
        out(f"per frame: ours {race['ours_s_per_frame']:.3f} s, Blender {race['blender_s_per_frame']:.3f} s, "
            f"ratio {race['ratio']:.2f}" + (f" ({race['ours_error']})" if race.get("ours_error") else ""))
    if "multigrid" in parts:
        out("... multigrid with contacts (the race's T-shirt at 20K triangles: amg.c's contact correction on and off)")
        results["multigrid_contacts"] = multigrid_contacts()
        out(format_multigrid_contacts(results["multigrid_contacts"]))
    if "scaling" in parts:
        out("... scaling 1K-100K triangles (fresh process per point)")
        sc = scaling()
        results["scaling"] = sc
        out(format_scaling(sc))
        if plots_dir:
            Path(plots_dir).mkdir(parents=True, exist_ok=True)
            plot_scaling(sc, Path(plots_dir) / "scaling.png")
    if "materials" in parts:
        out("... materials (denim pulled 30 degrees off its warp; orthotropic + plastic step cost)")
        results["materials"] = materials_figures(steps)
        out(format_materials(results["materials"]))
    if json_path:
        path = Path(json_path)
        old = {}
        if path.exists():
            try:
                old = json.loads(path.read_text())
            except (OSError, ValueError):
                old = {}
        # merged part by part: a run of some parts keeps the figures of the others (an empty
        # table1 of a run without it must not wipe the last one)
        old.update({k: v for k, v in results.items() if v != {}})
        path.write_text(json.dumps(old, indent=2, sort_keys=True, default=str))
        out(f"wrote {path}")
    if markdown:
        Path(markdown).write_text(benchmarks_markdown(results))
        out(f"wrote {markdown}")
    return results
