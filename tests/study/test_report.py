"""The report's verdicts on the paper's claims follow the numbers: they flip when the numbers flip.

The study has three seeds a job (identical numbers each): the verdicts take the seed as the unit, and an
ablation's difference is judged by a bootstrap over seeds, which needs two seeds a side."""

from __future__ import annotations

import shutil

import pytest
import study_fakes as fakes

from highway_srl.study.report import write_report
from highway_srl.study.verdicts import Check, Claim, claims, dominates
from highway_srl.study.runner import reproduce
from highway_srl.study.jobs import OURS
from highway_srl.study.results import load_results

WORSE = {"T_c": 0.2, "rise": 0.95, "C_r": 0.4, "speed": 4.0, "R_r": 20.0, "R_s": 0.1}
BETTER = {"T_c": 1.0, "rise": 0.1, "C_r": 1.0, "speed": 9.5, "R_r": 300.0, "R_s": 0.95}


@pytest.fixture
def study(tmp_path):
    root = tmp_path / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, seeds=(0, 1, 2), log=lambda s: None, report=False)
    return root


def _rewrite(root, numbers_of) -> None:
    """Overwrite every job whose (method, scene, options) numbers_of maps to numbers."""
    for res in load_results(root):
        numbers = numbers_of(res.job)
        if numbers is not None:
            shutil.rmtree(res.folder)
            fakes.write_fake_job(root, res.job, numbers)


def _verdicts(root) -> dict[str, str]:
    return {c.key: c.verdict for c in claims(load_results(root))}


def test_every_claim_is_confirmed_when_ours_wins_everywhere(study):
    assert _verdicts(study) == {"collision_free_training": "confirmed", "pareto": "confirmed",
                                "merge_success": "confirmed", "exit_success": "confirmed", "ablation": "confirmed"}


def test_every_claim_flips_to_not_confirmed_when_ours_loses_everywhere(study):
    _rewrite(study, lambda j: WORSE if j.method == OURS and not j.options else
             (BETTER if j.method == OURS else None))
    assert _verdicts(study) == {c: "not confirmed" for c in
                                ("collision_free_training", "pareto", "merge_success", "exit_success", "ablation")}
    text = write_report(study).read_text()
    assert text.count("Verdict: **not confirmed**") == 5 and "Verdict: **confirmed**" not in text


def test_one_scene_with_collisions_makes_the_training_claim_partial(study):
    _rewrite(study, lambda j: {**fakes.GOOD, "T_c": 0.9} if (j.method, j.scene, j.options) == (OURS, "adv-exit", ())
             else None)
    results = load_results(study)
    claim = next(c for c in claims(results) if c.key == "collision_free_training")
    assert claim.verdict == "partly confirmed (5 of 6 checks)"
    failed = [c for c in claim.checks if c.ok is False]
    assert [c.what for c in failed] == ["Adv. exiting"] and "T_c 0.9000 [0.9000, 0.9000]" in failed[0].detail
    assert "(3 seeds, 60 training episodes; budget smoke, paper profile)" in failed[0].detail


def test_a_baseline_faster_and_as_safe_breaks_the_deployment_front_and_names_itself(study):
    _rewrite(study, lambda j: BETTER if (j.method, j.scene) == ("sr-rl", "two-lane") else None)
    claim = next(c for c in claims(load_results(study)) if c.key == "pareto")
    deployment = [c for c in claim.checks if c.what.startswith("deployment")]
    assert deployment and all(c.ok is False and "SR-RL" in c.detail for c in deployment)
    assert claim.verdict.startswith("partly confirmed")


def test_exit_success_is_not_confirmed_when_a_baseline_succeeds_more(study):
    _rewrite(study, lambda j: {**fakes.POOR, "R_s": 1.0} if (j.method, j.scene) == ("mp-rl", "exit") else None)
    claim = next(c for c in claims(load_results(study)) if c.key == "exit_success")
    assert [c.ok for c in claim.checks] == [False, True] and "MP-RL 100.0%" in claim.checks[0].detail
    assert "above its interval: MP-RL" in claim.checks[0].detail


def test_missing_results_cannot_be_checked_and_say_so(study):
    for res in load_results(study):
        if res.job.method == OURS and res.job.options:
            shutil.rmtree(res.folder)
    claim = next(c for c in claims(load_results(study)) if c.key == "ablation")
    assert claim.verdict == "cannot be checked" and all(c.ok is None for c in claim.checks)


def test_verdict_and_dominance_rules():
    assert dominates((1.0, 2.0), (1.0, 1.0)) and not dominates((1.0, 1.0), (1.0, 1.0))
    assert not dominates((2.0, 0.0), (1.0, 1.0))
    claim = Claim("k", "s", "c", [Check("a", True, ""), Check("b", None, "")])
    assert claim.verdict == "confirmed where checked (1 of 2)"
    assert Claim("k", "s", "c", []).verdict == "cannot be checked"


def test_a_study_of_both_profiles_judges_the_claims_on_the_paper_profile_and_reports_safe_beside_it(tmp_path):
    # issue 12: the paper profile is the reproduction; the safe profile's set is written beside it, labelled,
    # and never decides a verdict. Ours loses under the paper profile here and wins under the safe one.
    root = tmp_path / "study"
    worse = {"T_c": 0.2, "rise": 0.95, "C_r": 0.4, "speed": 4.0, "R_r": 20.0, "R_s": 0.1}
    state = reproduce("smoke", root, jobs=1, work=fakes.fake_work, profiles=("paper", "safe"), methods=(OURS,),
                      log=lambda s: None, report=False)
    ids = list(state["jobs"])
    assert len(ids) == 22 and sum(i.startswith("safe:") for i in ids) == 11
    assert (root / "runs/safe/two-lane/moe-rm-srl/eval.json").exists()
    _rewrite(root, lambda job: worse if (job.profile == "paper" and not job.options) else None)
    assert _verdicts(root)["collision_free_training"] == "not confirmed"  # load_results: the paper set
    write_report(root)
    report = (root / "report.md").read_text()
    assert "Beyond the paper: the same study under the `safe` control profile" in report
    assert "MoE-RM-SRL trains without collisions" in report and "**not confirmed**" in report
    for name in ("table5", "table6", "group1_deployment", "seed_intervals", "seeds"):
        assert (root / "tables" / f"{name}.csv").exists() and (root / "tables" / f"{name}_safe.csv").exists()
    paper_t5 = (root / "tables" / "table5.csv").read_text()
    safe_t5 = (root / "tables" / "table5_safe.csv").read_text()
    assert "Two-lane,two-lane,T_c,MoE-RM-SRL,moe-rm-srl,done,0.2," in paper_t5
    assert "Two-lane,two-lane,T_c,MoE-RM-SRL,moe-rm-srl,done,1," in safe_t5
    side = (root / "tables" / "side_by_side.md").read_text()
    assert "| Ours (paper profile) | Ours (safe profile) |" in side
    # Table 5, two-lane T_c of ours: paper 1.000, ours 0.200 under the paper profile, 1.000 under safe
    assert "| Table 5 | Two-lane | T_c | MoE-RM-SRL | 1.000 | 0.200 (n=1) | 1.000 (n=1) |" in side
    assert "| Table 6 | Adv. two-lane | C_r | w/o MAP | 37.7% |" in side
    assert "| Multi-lane | Multi-lane (normal) | Collision rate | MoE-RM-SRL | 0.0% |" in side
    assert "side_by_side" in report and "Every cell of Tables 5, 6 and the multi-lane table" in report


def test_side_by_side_cells_take_the_seed_as_the_unit():
    # issue 29: each cell the mean over seeds with its 95 % t interval over them (t_0.975,2 = 4.3027), n stated
    from pathlib import Path

    from highway_srl.study.jobs import Job
    from highway_srl.study.side_by_side import cell
    from highway_srl.study.results import Result

    assert cell(None, "T_c") == (None, "–")

    def seed(c_r, r_r):
        return {"episodes": 100, "C_r": {"value": c_r}, "R_r": {"value": r_r}}

    level = {"episodes": 300, "C_r": {"value": 0.95, "low": 0.92, "high": 0.97},
             "R_r": {"value": 200.0, "low": 195.0, "high": 205.0},
             "per_seed": {"0": seed(0.9, 190.0), "1": seed(0.95, 200.0), "2": seed(1.0, 210.0)}}
    res = Result(Job(OURS, "two-lane", steps=100, seeds=(0, 1, 2)), "done", None, Path("x"),
                 metrics={"mean": {"T_c": 0.9}, "per_seed": {"0": {"T_c": 0.8}, "1": {"T_c": 0.9}, "2": {"T_c": 1.0}}},
                 evaluation={"levels": {"C": level}})
    assert cell(res, "T_c") == (pytest.approx(0.9), "0.900 [0.652, 1.000], n=3")  # 0.9 ± 0.248, cut at 1
    assert cell(res, "C_r") == (pytest.approx(0.95), "95.0% [82.6%, 100.0%], n=3")  # 0.95 ± 0.124
    assert cell(res, "R_r") == (pytest.approx(200.0), "200.00 [175.16, 224.84], n=3")  # 200 ± 24.84
    value, text = cell(res, "collision_rate")
    assert value == pytest.approx(0.05) and text == "5.0% [0.0%, 17.4%], n=3"
    assert cell(res, "R_s") == (None, "–")  # two-lane has no success rate
    one = Result(Job(OURS, "two-lane", steps=100, seeds=(4,)), "done", None, Path("x"),
                 metrics={"mean": {"T_c": 0.7}, "per_seed": {"4": {"T_c": 0.7}}},
                 evaluation={"trained_seeds": [4], "levels": {"C": {"episodes": 100, "C_r": {"value": 0.5}}}})
    assert cell(one, "T_c") == (pytest.approx(0.7), "0.700 (n=1)") and cell(one, "C_r")[1] == "50.0% (n=1)"


def test_the_committed_campaign_report_rebuilds_from_its_committed_records(tmp_path):
    """docs/results/paper: `reproduce --report-only` on the committed records writes the committed report and
    tables again, byte for byte (the figures' PNG/SVG bytes depend on the plotting library's build, so their
    CSV data is compared instead): the results page's numbers are the records' and nothing typed by hand."""
    from pathlib import Path

    committed = Path(__file__).resolve().parents[2] / "docs" / "results" / "paper"
    copy = tmp_path / "paper"
    shutil.copytree(committed, copy)
    write_report(copy)
    kept = lambda p: p.suffix in (".md", ".csv")  # noqa: E731
    for path in sorted(p for p in copy.rglob("*") if p.is_file() and kept(p)):
        name = path.relative_to(copy)
        assert (committed / name).exists(), f"{name} is written by the report but not committed"
        assert path.read_bytes() == (committed / name).read_bytes(), f"{name} differs from the committed one"


def test_the_results_page_carries_the_committed_summary_word_for_word():
    """docs/results.md holds the campaign's summary.md between its marker lines, as `reproduce --report-only
    --page` writes it, so that no count or verdict on the results page is typed by hand or left behind."""
    from pathlib import Path

    from highway_srl.study.report import PAGE_BEGIN, PAGE_END

    docs = Path(__file__).resolve().parents[2] / "docs"
    summary = (docs / "results" / "paper" / "summary.md").read_text()
    page = (docs / "results.md").read_text().split("\n")
    block = "\n".join(page[page.index(PAGE_BEGIN) + 1:page.index(PAGE_END)])
    assert block == f"\n{summary.rstrip()}\n", "docs/results.md's summary is not the committed summary.md: " \
        "run reproduce --budget paper --report-only --out docs/results/paper --page docs/results.md"
