"""BENCHMARKS.md from one ``tearcloth bench`` run: Table I beside the paper's figures, the collision
experiment, the servo loop, the race against Blender's cloth, scaling, and the issues' targets met
or missed with where the time goes.

This file owns ``benchmarks_markdown`` (the whole report) and ``targets_markdown`` (the targets
table and the note on the misses). It only formats a results dict (the one ``suite.run``
returns and writes as JSON); it measures nothing. Dev-only (not in the extension zip).
"""
from __future__ import annotations

from .collision import MOTIONS, PAPER_COLLISION
from .table1 import PAPER_TABLE1


def benchmarks_markdown(r: dict) -> str:
    """BENCHMARKS.md from one run's results."""
    m = r["machine"]
    lines = ["# Benchmarks", "",
             "Measured by `tearcloth bench --json out/bench.json --markdown BENCHMARKS.md --plots docs/images` "
             "(or `bash tools/run.sh bench`) in one run on one machine: every figure is a median over many "
             "steps of that run. Speed is never asserted by a test.", "",
             f"Machine: {m['platform']}, {m['cpus']} CPUs, Python {m['python']}, 1-minute load at start "
             f"{m['load_1min_at_start']}.", ""]
    if r.get("table1"):
        lines += ["## Table I, ours beside the paper's (ms per step)", "",
                  "| scenario | triangles | collision | FEM | tearing before | tearing after | total before | total after |",
                  "|---|---|---|---|---|---|---|---|"]
        for name, x in r["table1"].items():
            p = PAPER_TABLE1[name]
            col = f"{x['collision_ms']:.3f} ({p['collision_ms']})" if "collision_ms" in x else f"- ({p['collision_ms']})"
            after = "not measured" if x["tearing_after_ms"] is None else f"{x['tearing_after_ms']:.4f}"
            total_after = "not measured" if x["total_after_ms"] is None else f"{x['total_after_ms']:.3f}"
            lines.append(
                f"| {name} | {x['triangles']} | {col} | {x['fem_ms']:.3f} ({p['fem_ms']}) | "
                f"{x['tearing_before_ms']:.4f} ({p['tearing_before_ms']}) | {after} "
                f"({p['tearing_after_ms']}) | {x['total_before_ms']:.3f} ({p['total_before_ms']}) | "
                f"{total_after} ({p['total_after_ms']}) |")
        lines += ["", "Paper's figures in parentheses (Xeon E5-2620, SOFA). Steps of 1 ms; the hands pull "
                  "apart at 2 cm/s each; 'after' means a tear tip is running: a 1 cm cut at the most stressed "
                  "free rim vertex, the tear stress at 1/2 of the disc stress at its tip and a crack of one "
                  "edge per 200 steps keep it running (`addon/bench/table1.py`); only steps that begin with a "
                  "tip running are timed:", ""]
        lines += ["| scenario | steps timed | cuts in them | tears started | tearing after: median | mean | max |",
                  "|---|---|---|---|---|---|---|"]
        for name, x in r["table1"].items():
            if "tearing_after_note" in x:
                lines.append(f"| {name} | - | - | - | not measured: {x['tearing_after_note']} | | |")
            if "tearing_after_steps" in x:
                lines.append(f"| {name} | {x['tearing_after_steps']} | {x['tearing_after_cuts']} | "
                             f"{x['tearing_after_tears_started']} | {x['tearing_after_ms']:.4f} ms | "
                             f"{x['tearing_after_mean_ms']:.4f} ms | {x['tearing_after_max_ms']:.3f} ms |")
        lines.append("")
        lines += ["| scenario | CG iterations (median) | step after 50 cuts / before | per CG iteration |",
                  "|---|---|---|---|"]
        for name, x in r["table1"].items():
            lines.append(f"| {name} | {x['cg_iterations_median']:.0f} | {x['step_ratio_after_50_cuts']:.3f} | "
                         f"{x['step_ratio_per_cg_iteration_after_50_cuts']:.3f} |")
        lines.append("")
    if "collision" in r:
        c = r["collision"]["simulated"]
        lines += ["## Collision: the paper's experiment (T-shirt simulated on a walking character)", "",
                  "| | full every step | absolute measure | relative measure | absolute / relative | share of pairs fully detected |",
                  "|---|---|---|---|---|---|"]
        for case, name in ((case, name) for case in ("dt1ms", "frame10") for name in MOTIONS if name in c[case]):
            x = c[case][name]
            lines.append(f"| {case} {name} | {x['full_ms']:.2f} | {x['absolute_ms']:.2f} ({PAPER_COLLISION[name]['absolute_ms']}) | "
                         f"{x['relative_ms']:.2f} ({PAPER_COLLISION[name]['relative_ms']}) | "
                         f"{x['absolute_over_relative']:.2f} | {x['full_share']:.3f} |")
        lines.append("")
        for case, name in ((case, name) for case in ("dt1ms", "frame10") for name in MOTIONS if name in c[case]):
            st = c[case][name].get("stopped")
            if st:  # the simulated shirt blew up: say so beside the figures it leaves
                lines.append(f"- {case} {name}: **the simulation stopped** at recorded step {st['step']} of "
                             f"{st['of']} ({st['error']}); the figures cover the steps before.")
        lines.append("")
    if "servo" in r:
        s = r["servo"]
        lines += ["## Servo loop", "", f"{s['rate_hz']:.1f} Hz, period p50 {s['p50_ms']:.3f} ms, "
                  f"p99 {s['p99_ms']:.3f} ms (two emulated Falcons, T-shirt simulation on the main thread, 10 s).", ""]
        if "loaded" in s:
            x = s["loaded"]
            lines += [f"Loaded (servo process; T-shirt with collision on its own thread, a GIL-heavy pure-Python loop on "
                      f"the main thread, a CPU hog, no real-time priority, 10 s): {x['rate_hz']:.1f} Hz, period p50 "
                      f"{x['p50_ms']:.3f} ms, p99 {x['p99_ms']:.3f} ms, max {x['max_ms']:.2f} ms."
                      + (f" The same load with the servo threads in the simulating process: {s['loaded_threads']['rate_hz']:.1f} Hz, "
                         f"p99 {s['loaded_threads']['p99_ms']:.2f} ms, max {s['loaded_threads']['max_ms']:.2f} ms." if "loaded_threads" in s else ""), ""]
        if "kill_zero_ms" in s:
            k = s["kill_zero_ms"]
            lines += [f"SIGKILL of the simulating process to zero force on both emulated Falcons (the servo process's "
                      f"peer check): median {k['median_ms']:.2f} ms, max {k['max_ms']:.2f} ms over {k['runs']} kills.", ""]
    if "blender_cloth" in r:
        b = r["blender_cloth"]
        lines += ["## Against Blender's cloth (T-shirt, same body, 10 sub-steps per frame)", "",
                  f"Ours {b['ours_s_per_frame']:.3f} s per frame (tearing), Blender {b['blender_s_per_frame']:.3f} s "
                  f"per frame; ratio ours / Blender {b['ratio']:.2f}. Settings: `addon/bench/race.py`.", ""]
    if "multigrid_contacts" in r and "error" not in r["multigrid_contacts"]:
        m = r["multigrid_contacts"]
        c, u = m["corrected"], m["uncorrected"]
        lines += ["## Multigrid with contacts (issue 14)", "",
                  f"The race's T-shirt at {m['triangles']} triangles on the walking body (the solver's auto picks the "
                  f"multigrid), {m['frames']} frames of {m['substeps']} sub-steps, {c['contacts']:.0f} contacts, the two "
                  "stepped in turn. Per sub-step (medians), with amg.c's contact correction / without:", "",
                  "| | corrected | uncorrected | ratio |", "|---|---|---|---|",
                  f"| CG iterations | {c['cg_iterations']:.1f} | {u['cg_iterations']:.1f} | {m['cg_iterations_ratio']:.2f} |",
                  f"| FEM ms | {c['fem_ms']:.1f} | {u['fem_ms']:.1f} | {m['fem_ms_ratio']:.2f} |",
                  f"| of it multigrid setup ms | {c['setup_ms']:.1f} | {u['setup_ms']:.1f} | |", "",
                  "Scenario: `multigrid_contacts` in `addon/bench/race.py`.", ""]
    if "slivers" in r:
        from .slivers import sheet_summary, table_lines

        lines += ["## Slivers (issue 14)", "", f"The sheet: {sheet_summary(r['slivers'])}. Each step solved by auto "
                  "(block Jacobi with the slivers' corners inverted together, `native/stiff.c`) and by the "
                  "Gauss-Seidel sweeps alone (auto's pick on this sheet before the stiff groups). "
                  "Scenario: `addon/bench/slivers.py`.", ""] + table_lines(r["slivers"]) + [""]
    if "scaling" in r:
        sc = r["scaling"]
        lines += ["## Scaling", "", f"Fitted time exponent (square, no tearing, no collision): {sc['exponent']:.2f}; "
                  f"peak memory of the 100K-triangle run: {sc['peak_mb_100k']:.0f} MB.", "",
                  "![scaling](docs/images/scaling.png)", ""]
    if "materials" in r:
        x, d = r["materials"], r["materials"]["denim_bias"]
        lines += ["## Woven materials (issue 19)", "",
                  f"Denim pulled {d['grain_deg']:.0f} degrees off its warp tore along {d['tear_angle_deg']:.1f} degrees "
                  f"from the pull, {d['tear_angle_error_deg']:.2f} degrees from the weft ({d['tears_started']} tears, "
                  f"{d['cut_m']:.3f} m cut); isotropic cotton under the same load along {d['cotton_tear_angle_deg']:.1f} "
                  f"degrees ({d['cotton_error_deg']:.2f} from the perpendicular to the pull). Scenario: "
                  "`addon/bench/materials.py`.", "",
                  f"FEM step of the T-shirt ({x['triangles']} triangles), orthotropic + plastic against isotropic "
                  f"elastic with the same moduli, stepped alternately: {x['fem_ms']['general']:.3f} / "
                  f"{x['fem_ms']['isotropic']:.3f} ms = {x['cost_ratio']:.3f}; with triangles yielding every step "
                  f"({x['yield_events_per_step_median']:.0f} yield events per step) {x['cost_ratio_yielding']:.3f}. "
                  f"Per CG iteration: {x['cost_ratio_per_cg_iteration']:.3f} / {x['cost_ratio_yielding_per_cg_iteration']:.3f}.", ""]
    lines += targets_markdown(r)
    return "\n".join(lines) + "\n"


def targets_markdown(r: dict) -> list:
    """The issues' targets against this run, and for each miss where the time goes."""
    rows = []

    def add(what, value, target, ok):
        rows.append(f"| {what} | {value} | {target} | {'met' if ok else '**missed**'} |")

    t1 = r.get("table1", {})
    if "tshirt" in t1:
        x = t1["tshirt"]
        add("FEM step, T-shirt (3.3K triangles)", f"{x['fem_ms']:.2f} ms", "<= 0.7 ms", x["fem_ms"] <= 0.7)
        add("tearing before a tear, T-shirt", f"{x['tearing_before_ms']:.3f} ms", "<= 0.3 ms", x["tearing_before_ms"] <= 0.3)
        add(f"tearing after (a tip running, {x.get('tearing_after_steps', '?')} steps), T-shirt",
            f"{x['tearing_after_ms']:.3f} ms", "<= 0.05 ms", x["tearing_after_ms"] <= 0.05)
    for name, x in t1.items():
        add(f"step after 50 cuts / before, {name}", f"{x['step_ratio_after_50_cuts']:.2f}", "<= 1.10",
            x["step_ratio_after_50_cuts"] <= 1.10)
        if x["total_after_ms"] is not None:
            add(f"total step after the tear started, {name}", f"{x['total_after_ms']:.2f} ms", "<= 1 ms", x["total_after_ms"] <= 1.0)
        add(f"total step before, {name}", f"{x['total_before_ms']:.2f} ms", "<= 1.5 ms", x["total_before_ms"] <= 1.5)
    if "collision" in r:
        c = r["collision"]["simulated"]["dt1ms"]["moving"]
        add("collision, relative measure, moving", f"{c['relative_ms']:.3f} ms", "<= 0.3 ms", c["relative_ms"] <= 0.3)
        add("collision, absolute / relative, moving", f"{c['absolute_over_relative']:.1f}", ">= 4", c["absolute_over_relative"] >= 4)
        w = r["collision"]["simulated"]["dt1ms"].get("walking")
        if w is not None:  # the moving case with root travel (collision.MOTIONS), beside the one in place
            add("collision, relative measure, walking forward", f"{w['relative_ms']:.3f} ms", "<= 0.3 ms",
                w["relative_ms"] <= 0.3)
            add("collision, absolute / relative, walking forward", f"{w['absolute_over_relative']:.1f}", ">= 4",
                w["absolute_over_relative"] >= 4)
    if "servo" in r:
        s = r["servo"]
        add("servo rate", f"{s['rate_hz']:.1f} Hz", ">= 995 Hz", s["rate_hz"] >= 995)
        add("servo period p99", f"{s['p99_ms']:.2f} ms", "<= 1.5 ms", s["p99_ms"] <= 1.5)
        if "kill_zero_ms" in s:
            k = s["kill_zero_ms"]
            add("SIGKILL of the simulation to zero force, median", f"{k['median_ms']:.2f} ms", "<= 10 ms", k["median_ms"] <= 10.0)
        if "loaded" in s:
            x = s["loaded"]
            add("servo rate, loaded", f"{x['rate_hz']:.1f} Hz", ">= 999 Hz", x["rate_hz"] >= 999)
            add("servo period p99, loaded", f"{x['p99_ms']:.2f} ms", "<= 1.1 ms", x["p99_ms"] <= 1.1)
            add("servo period max, loaded", f"{x['max_ms']:.2f} ms", "<= 2 ms", x["max_ms"] <= 2.0)
    if "blender_cloth" in r:
        b = r["blender_cloth"]
        add("ours / Blender cloth per frame", f"{b['ratio']:.2f}", "<= 0.5", b["ratio"] <= 0.5)
        d = b.get("detail", {})
        if "cpu_ratio" in d:  # not a target: the steadier figure beside the wall ratio
            rows.append(f"| ours / Blender cloth, CPU seconds per frame | {d['cpu_ratio']:.2f} | (<= 0.5 on wall) | |")
        if "ours_collision_share_of_substep" in d:
            share = d["ours_collision_share_of_substep"]
            add("collision share of our sub-step in the race", f"{share:.2f}", "<= 0.20", share <= 0.20)
        if "ours_penetration_max_m" in b:
            depth, inside = b["ours_penetration_max_m"], b["ours_vertices_inside"]
            add("our deepest vertex in the body, race", f"{depth * 1e3:.1f} mm ({inside} inside)",
                "<= 5 mm, <= 4 inside", depth <= 0.005 and inside <= 4)
    if "scaling" in r:
        sc = r["scaling"]
        add("scaling exponent", f"{sc['exponent']:.2f}", "<= 1.1", sc["exponent"] <= 1.1)
        add("peak memory at 100K triangles", f"{sc['peak_mb_100k']:.0f} MB", "<= 300 MB", sc["peak_mb_100k"] <= 300)
        if "bytes_per_triangle_100k" in sc:
            bpt = sc["bytes_per_triangle_100k"]
            add("peak memory per triangle at 100K", f"{bpt:.0f} B", "<= 1000 B", bpt <= 1000)
        if "unconverged_steps" in sc:
            add("unconverged steps in the scaling run", f"{sc['unconverged_steps']}", "0", sc["unconverged_steps"] == 0)
    if "slivers" in r:
        for key, x in r["slivers"].items():
            if isinstance(x, dict) and "auto" in x:
                a = x["auto"]
                add(f"sliver sheet at {key[2:]}, auto: sub-steps unconverged / halved", f"{a['unconverged_substeps']} / {a['halvings']}",
                    "0 / 0", a["unconverged_substeps"] == 0 and a["halvings"] == 0)
    if "materials" in r:
        x = r["materials"]
        err = x["denim_bias"]["tear_angle_error_deg"]
        add("denim 30 deg off the warp: tear from a thread", f"{err:.2f} deg", "<= 5 deg", err <= 5.0)
        add("FEM step, orthotropic + plastic / isotropic", f"{x['cost_ratio']:.3f}", "<= 1.15", x["cost_ratio"] <= 1.15)
    if not rows:
        return []
    tshirt = t1.get("tshirt", {})
    roof = (f"{tshirt['product_vs_roofline']:.1f}x its memory roofline on the T-shirt"
            if tshirt.get("product_vs_roofline") else "several times its memory roofline")
    its = {k: t1.get(k, {}).get("cg_iterations_median") for k in ("cloth", "tshirt")}
    its_text = (f"{its['cloth']:.0f} for the square cloth, {its['tshirt']:.0f} for the T-shirt"
                if None not in its.values() else "see Table I")
    race = r.get("blender_cloth", {}).get("detail", {})
    contact_text = (f" Solves with contacts (a shirt on a body) take the same sweeps, the contact rows "
                    f"filtered: {race['ours_cg_iterations_median']:.0f} CG iterations per race "
                    f"sub-step in this run (median); there the "
                    f"collision is {race['ours_collision_share_of_substep']:.2f} of the sub-step."
                    if race.get("ours_cg_iterations_median") is not None
                    and race.get("ours_collision_share_of_substep") is not None else "")
    return ["## Targets", "", "| figure | this run | target | |", "|---|---|---|---|", *rows, "",
            "Where the time goes when a target is missed: the FEM solve. One step is an element pass "
            "(co-rotation, stress, forces), an assembly of 3x3 blocks into rows, and a conjugate-gradient "
            "solve. On soft, coarse or small sheets at short steps (stiffness ratio dt^2 k / m, weighted "
            "by the size, below TC_AMG_AUTO_STIFFNESS) it is preconditioned by symmetric block Gauss-Seidel "
            "sweeps of the filtered system (Eisenstat's form): a cotton sheet is stiff (E h = 2e4 N/m) against "
            f"its areal mass, so that takes ten or more iterations at 1 ms steps ({its_text}), each a "
            f"forward and a backward sweep that cost about two matrix products (a product runs at {roof}; "
            "block Jacobi needs 2.5x the iterations at half the cost each). Above it the smoothed-aggregation "
            "multigrid of amg.c keeps the iterations near ten from 10K to 100K triangles (1.4-4x faster than "
            "block Jacobi at 10K, 2-30x at 30K), but each of its iterations costs about eight Jacobi ones plus "
            "a refresh of its coarse operators every few sub-steps; on the T-shirt in cotton it is slower, and "
            "auto keeps the sweeps there. On meshes with slivers (an edge block of strength 0.94 or more at "
            "a triangle with a corner under 2 degrees, `native/stiff.c`) auto takes block Jacobi with the slivers' corners inverted together instead "
            "of either: the sweeps cannot take a sliver's stiff mode out (the Slivers section)."
            + contact_text + " After 50 cuts the per-iteration "
            "cost moves little; the step grows because a torn cloth moves more and the solver iterates "
            "more.", ""]
