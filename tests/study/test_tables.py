"""Tables and figures from synthetic job results (real files written by the project's own writers)."""

from __future__ import annotations

import csv

import pytest
import study_fakes as fakes

from highway_srl.study import paper_numbers as paper
from highway_srl.study.report import write_report
from highway_srl.study.runner import reproduce
from highway_srl.study.jobs import (ABLATIONS, GROUP1_METHODS, METHOD_LABELS, SCENES, TABLE5_METHODS,
                                           TABLE5_SCENES)


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The smoke study's job list with synthetic results, tables, figures and report."""
    root = tmp_path_factory.mktemp("tables") / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, log=lambda s: None)
    return root


def test_every_artefact_is_written_as_csv_and_markdown_and_figures_as_png_and_svg(study):
    for name in ("group1_deployment", "group2", "multilane", "group3", "table5", "table6", "collisions",
                 "collision_verdicts"):
        assert (study / "tables" / f"{name}.csv").stat().st_size > 0
        assert (study / "tables" / f"{name}.md").read_text().startswith("## ")
    figures = ["deployment_pareto", "training_pareto"] + [f"training_curves_{s}" for s in SCENES]
    for name in figures:
        assert (study / "figures" / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
        assert "<svg" in (study / "figures" / f"{name}.svg").read_text()[:500]
    for name in ("deployment_pareto", "training_pareto", "training_curves"):
        assert (study / "figures" / f"{name}.csv").exists() and (study / "figures" / f"{name}.md").exists()
    html = (study / "report.html").read_text()
    assert html.count("data:image/png;base64,") == len(figures)


def test_table5_has_a_row_per_scene_metric_and_method_with_the_papers_number_beside_ours(study):
    rows = _rows(study / "tables" / "table5.csv")
    assert list(rows[0]) == ["scene", "scene_key", "metric", "method", "method_key", "status", "ours", "ours_sd",
                             "paper"]
    # the paper's metrics, and T_r_rm (the RM return, one scale for every method) beside its T_r
    expected = {(s, m, k) for s in TABLE5_SCENES for m in (*paper.TABLE5[s], "T_r_rm") for k in TABLE5_METHODS}
    assert {(r["scene_key"], r["metric"], r["method_key"]) for r in rows} == expected
    assert all(r["paper"] == "" for r in rows if r["metric"] == "T_r_rm")  # the paper prints no such row
    ours = {(r["scene_key"], r["metric"], r["method_key"]): r for r in rows}
    r = ours[("exit", "R_s", "moe-rm-srl")]
    assert float(r["ours"]) == pytest.approx(fakes.GOOD["R_s"], abs=0.13) and float(r["paper"]) == 0.802
    assert float(ours[("merge", "C_r", "rl")]["ours"]) == pytest.approx(fakes.POOR["C_r"], abs=0.13)
    assert float(ours[("two-lane", "T_c", "sr-rl")]["ours"]) == pytest.approx(fakes.POOR["T_c"])
    md = (study / "tables" / "table5.md").read_text()
    assert "| Two-lane | T_c |" in md and "1.000 / 1.000" in md  # ours / paper in one cell


def test_group1_has_every_method_at_every_level_of_the_budget(study):
    rows = _rows(study / "tables" / "group1_deployment.csv")
    assert {(r["method_key"], r["level"]) for r in rows} == {(m, lv) for m in GROUP1_METHODS for lv in ("A", "C", "F")}
    assert {"C_r", "C_r_low", "C_r_high", "avg_speed", "R_r"} <= set(rows[0])
    a = next(r for r in rows if r["method_key"] == "moe-rm-srl" and r["level"] == "A")
    f = next(r for r in rows if r["method_key"] == "moe-rm-srl" and r["level"] == "F")
    assert float(a["avg_speed"]) > float(f["avg_speed"])  # the fake slows down with density


def test_group_tables_multilane_and_ablation_rows(study):
    g2 = _rows(study / "tables" / "group2.csv")
    assert {(r["scene_key"], r["method_key"]) for r in g2} == (
        {("multi-lane", "moe-rm-srl"), ("adv-multi-lane", "moe-rm-srl")}
        | {(s, m) for s in ("merge", "exit") for m in TABLE5_METHODS})
    assert {"runs", "episodes_per_run", "C_r", "C_r_sd", "avg_speed_sd", "R_s"} <= set(g2[0])
    g3 = _rows(study / "tables" / "group3.csv")
    assert {r["scene_key"] for r in g3} == {"adv-two-lane", "adv-merge", "adv-exit"}
    ml = _rows(study / "tables" / "multilane.csv")
    assert [r["metric_key"] for r in ml] == ["avg_speed", "collision_rate", "R_r"]
    assert float(ml[1]["adversarial_paper"]) == 0.134 and float(ml[1]["normal"]) == 0.0
    t6 = _rows(study / "tables" / "table6.csv")
    assert [r["variant_key"] for r in t6] == ["full", *ABLATIONS]
    assert float(t6[0]["C_r"]) == 1.0 and float(t6[1]["C_r_paper"]) == 0.377


def test_collisions_table_lists_each_job_and_level_that_had_any_by_kind(study):
    rows = _rows(study / "tables" / "collisions.csv")
    # the fakes: MoE-RM-SRL (full) never collides, every other job does at every level, all "front" contacts
    assert rows and not any(r["method_key"] == "moe-rm-srl" and r["method"] == "MoE-RM-SRL" for r in rows)
    assert {(r["scene_key"], r["method_key"]) for r in rows if r["method_key"] == "rl"} == {
        (s, "rl") for s in TABLE5_SCENES}
    for r in rows:
        assert int(r["collisions"]) == int(r["front"]) > 0 and int(r["rear"]) == int(r["side"]) == int(r["road"]) == 0
        assert int(r["collisions"]) == round(0.3 * int(r["episodes"]))  # POOR's C_r 0.7
        assert int(r["decision_creep"]) == int(r["collisions"])  # the fakes' decision trace: all creep
        assert int(r["decision_forbidden"]) == int(r["decision_lane_change_r1"]) == int(r["decision_other"]) == 0
    assert "## What the deployment collisions were" in (study / "report.md").read_text()
    md = (study / "tables" / "collisions.md").read_text()
    n = rows[0]["collisions"]
    assert "forbidden / lane change at R*1 = 0 / creep / other" in md and f"| 0 / 0 / {n} / 0 |" in md


def test_collision_verdicts_table_has_every_finished_job_in_training_and_at_each_level(study):
    rows = _rows(study / "tables" / "collision_verdicts.csv")
    # the fakes write no verdicts (as runs before them): counts without a split, never a 0 in its place
    rl = [(r["phase"], r["level"]) for r in rows if r["scene_key"] == "two-lane" and r["method_key"] == "rl"]
    assert rl[0] == ("training", "C") and sorted(rl[1:]) == [("deployment", lv) for lv in ("A", "C", "F")]
    assert all(r["ego_avoidable"] == r["unavoidable"] == r["not_judged"] == "" for r in rows)
    assert all(int(r["collisions"]) == round(0.3 * int(r["episodes"])) for r in rows
               if r["method_key"] == "rl" and r["phase"] == "deployment")
    report = (study / "report.md").read_text()
    assert "## Collisions the ego could have avoided, in training and deployment" in report
    assert "| Two-lane | RL | 10: – / – / – |" in report  # POOR: half of 20 training episodes


def test_training_figure_data_has_every_non_ablation_run_and_curves_have_bins(study):
    tp = _rows(study / "figures" / "training_pareto.csv")
    assert len(tp) == 8 + 5 * 6 + 2
    ours = next(r for r in tp if r["scene_key"] == "two-lane" and r["method_key"] == "moe-rm-srl")
    assert float(ours["T_c"]) == 1.0 and int(ours["collisions"]) == 0
    assert 0 < float(ours["rise_time"]) <= 1600
    curves = _rows(study / "figures" / "training_curves.csv")
    rl = [r for r in curves if r["scene_key"] == "two-lane" and r["method_key"] == "rl"]
    assert len(rl) == 20 and float(rl[-1]["collisions_mean"]) == 10  # POOR: half of 20 episodes collide
    assert METHOD_LABELS["rl"] in (study / "figures" / "training_curves.md").read_text()


def test_report_rewritten_from_the_same_files_is_identical(study):
    before = (study / "tables" / "table5.csv").read_text()
    write_report(study)
    assert (study / "tables" / "table5.csv").read_text() == before
