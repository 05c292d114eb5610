"""The bench's target table (BENCHMARKS.md): each issue's figure read from the run's JSON, met or
missed by the issue's own bound, and parts a run did not include simply absent."""
from tearcloth.bench.report import targets_markdown


def rows(table):
    """{figure: (value, verdict)} of the markdown target table."""
    out = {}
    for line in table:
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 4 and cells[0] not in ("figure", "---"):
            out[cells[0]] = (cells[1], cells[3])
    return out


def race(ratio, cpu_ratio, share, depth_m, inside):
    return {"blender_cloth": {"ratio": ratio, "ours_penetration_max_m": depth_m, "ours_vertices_inside": inside,
                              "detail": {"cpu_ratio": cpu_ratio, "ours_collision_share_of_substep": share}}}


def test_the_race_rows_say_met_or_missed_by_the_issue_bounds():
    r = rows(targets_markdown(race(1.62, 1.38, 0.24, 0.0042, 1)))
    assert r["ours / Blender cloth per frame"] == ("1.62", "**missed**")
    assert r["ours / Blender cloth, CPU seconds per frame"][0] == "1.38"
    assert r["collision share of our sub-step in the race"] == ("0.24", "**missed**")
    assert r["our deepest vertex in the body, race"] == ("4.2 mm (1 inside)", "met")
    r = rows(targets_markdown(race(0.45, 0.40, 0.18, 0.006, 0)))
    assert r["ours / Blender cloth per frame"][1] == "met"
    assert r["collision share of our sub-step in the race"][1] == "met"
    assert r["our deepest vertex in the body, race"][1] == "**missed**"  # 6 mm is deeper than 5
    r = rows(targets_markdown(race(0.45, 0.40, 0.18, 0.001, 5)))
    assert r["our deepest vertex in the body, race"][1] == "**missed**"  # 5 vertices inside, more than 4


def test_scaling_rows_count_bytes_per_triangle_and_unconverged_steps():
    sc = {"exponent": 1.33, "peak_mb_100k": 118.0, "bytes_per_triangle_100k": 1190.0, "unconverged_steps": 0}
    r = rows(targets_markdown({"scaling": sc}))
    assert r["scaling exponent"] == ("1.33", "**missed**")
    assert r["peak memory per triangle at 100K"] == ("1190 B", "**missed**")
    assert r["unconverged steps in the scaling run"] == ("0", "met")
    r = rows(targets_markdown({"scaling": dict(sc, bytes_per_triangle_100k=990.0, unconverged_steps=3)}))
    assert r["peak memory per triangle at 100K"][1] == "met"
    assert r["unconverged steps in the scaling run"] == ("3", "**missed**")


def test_an_empty_run_has_no_table_and_the_roofline_sentence_reads_the_run():
    assert targets_markdown({}) == []
    tshirt = {"fem_ms": 3.17, "tearing_before_ms": 0.011, "tearing_after_ms": 0.007, "tearing_after_steps": 200,
              "step_ratio_after_50_cuts": 1.06, "total_after_ms": 2.69, "total_before_ms": 3.18,
              "product_vs_roofline": 4.79}
    table = targets_markdown({"table1": {"tshirt": tshirt}})
    assert rows(table)["FEM step, T-shirt (3.3K triangles)"] == ("3.17 ms", "**missed**")
    assert "4.8x its memory roofline" in table[-2]


def test_sliver_rows_say_unconverged_and_halved_sub_steps_and_the_section_lists_both_solvers():
    from tearcloth.bench.report import benchmarks_markdown

    def run(unconverged, halvings):
        return {"steps": 30, "step_ms": 9.0, "cg_iterations_per_step": 109, "halvings": halvings,
                "unconverged_substeps": unconverged, "stiff_groups": 331, "worst_residual": 1e-4, "tolerance": 1e-4}

    sl = {"vertices": 756, "triangles": 1378, "min_angle_deg": 0.23, "simulated_s": 0.06,
          "dt2ms": {"auto": run(0, 0), "sweeps": run(0, 90), "time_ratio": 30.0},
          "dt10ms": {"auto": run(2, 5), "sweeps": run(36, 42), "time_ratio": 42.0}}
    r = rows(targets_markdown({"slivers": sl}))
    assert r["sliver sheet at 2ms, auto: sub-steps unconverged / halved"] == ("0 / 0", "met")
    assert r["sliver sheet at 10ms, auto: sub-steps unconverged / halved"] == ("2 / 5", "**missed**")
    md = benchmarks_markdown({"machine": {"platform": "p", "cpus": 2, "python": "3.11", "load_1min_at_start": 0.1},
                              "slivers": sl})
    assert "## Slivers (issue 14)" in md and "756 vertices, smallest angle 0.23 degrees" in md
    assert "| 10 ms | sweeps | 9.00 | 109 | 42 | 36 | 331 |" in md


def test_the_multigrid_contacts_section_shows_both_sides_and_skips_a_stopped_run():
    from tearcloth.bench.report import benchmarks_markdown

    side = lambda it, fem, setup: {"cg_iterations": it, "fem_ms": fem, "setup_ms": setup, "contacts": 310.0, "amg_fallbacks": 0}
    m = {"triangles": 20010, "vertices": 10045, "frames": 3, "substeps": 10, "dt_s": 1 / 240, "amg_levels": {"corrected": 3},
         "corrected": side(47.9, 212.6, 53.4), "uncorrected": side(65.1, 245.7, 36.6),
         "cg_iterations_ratio": 47.9 / 65.1, "fem_ms_ratio": 212.6 / 245.7}
    machine = {"platform": "p", "cpus": 2, "python": "3.11", "load_1min_at_start": 0.1}
    text = benchmarks_markdown({"machine": machine, "multigrid_contacts": m})
    assert "## Multigrid with contacts" in text
    assert "| CG iterations | 47.9 | 65.1 | 0.74 |" in text
    assert "| FEM ms | 212.6 | 245.7 | 0.87 |" in text
    assert "Multigrid with contacts" not in benchmarks_markdown({"machine": machine, "multigrid_contacts": {"error": "stopped"}})
