"""A study run in seed chunks gets one report: every job over the union of its chunks' seeds, the pooled
numbers recomputed, the same bytes each time; a seed finished in two chunks, or chunks of other settings, is
a one-line error."""

from __future__ import annotations

import json
from pathlib import Path

import study_fakes as fakes

from highway_srl.cli import main
from highway_srl.study import chunks
from highway_srl.study import stats as S
from highway_srl.study.jobs import OURS
from highway_srl.study.runner import reproduce

QUIET = {"log": lambda s: None, "report": False}
JOB = "two-lane/moe-rm-srl"


def _chunk(root: Path, seeds: tuple[int, ...], numbers: dict | None = None) -> Path:
    """One chunk of the study in root, MoE-RM-SRL on two-lane only; numbers: this chunk's job numbers."""
    folder = root / f"seeds-{'-'.join(map(str, seeds))}"
    if numbers:
        Path(f"{folder}.numbers.json").write_text(json.dumps({JOB: numbers}))
    reproduce("smoke", folder, jobs=1, work=fakes.fake_work, methods=(OURS,), scenes=("two-lane",), seeds=seeds,
              **QUIET)
    return folder


def _written(root: Path) -> dict[str, bytes]:
    """Every file of the merged report (the chunks' own folders left out)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.relative_to(root).parts[0] in ("tables", "figures", "report.md", "report.html")}


def test_report_only_merges_the_chunks_seeds_and_rebuilds_the_same_bytes(tmp_path, capsys):
    root = tmp_path / "paper"
    first = _chunk(root, (0, 1))
    _chunk(root, (2,), {"C_r": 0.5})  # seed 2 deploys collision-free in 2 of its 4 episodes
    before = (first / "study.json").read_bytes()
    assert main(["reproduce", "--budget", "smoke", "--out", str(root), "--report-only"]) == 0
    assert capsys.readouterr().out.strip() == f"report: {root / 'report.md'}"
    res = chunks.load_study(root).get(OURS, "two-lane")
    assert res.job.seeds == (0, 1, 2) and len(res.episodes()) == 60
    level = res.evaluation["levels"]["C"]
    assert list(level["per_seed"]) == ["0", "1", "2"] and level["episodes"] == 12
    wilson = S.wilson(10, 12)  # 4 + 4 + 2 collision-free episodes of 12
    assert (level["C_r"]["value"], level["C_r"]["low"], level["C_r"]["high"]) == (wilson.mean, wilson.low,
                                                                                  wilson.high)
    assert list(res.metrics["per_seed"]) == ["0", "1", "2"]
    report = (root / "report.md").read_text()
    assert "`seeds-0-1/` (seeds 0, 1; commit" in report and "`seeds-2/` (seeds 2; commit" in report
    assert "seeds 0, 1, 2 (3 run(s) per method and scene, batched in one process per chunk)" in report
    seeds = (root / "tables" / "seeds.csv").read_text().splitlines()
    assert len([s for s in seeds if s.startswith("Two-lane,MoE-RM-SRL,")]) == 3
    assert "(3 seeds, 12 episodes; budget smoke, paper profile)" in report
    # the budget's whole plan with each job's finished seeds (smoke: one seed a job, so 3 of 1 here)
    progress = (root / "tables" / "progress.csv").read_text().splitlines()
    assert progress[0] == "profile,scene,method,job,seeds,target,finished,chunks"
    assert "paper,Two-lane,MoE-RM-SRL,two-lane/moe-rm-srl,3,1,0 1 2,seeds-0-1 seeds-2" in progress
    assert "paper,Merging,RL,merge/rl,0,1,," in progress and len(progress) == 1 + 43
    assert "- **Progress:** paper profile: 1 of 43 jobs have a finished seed, 1 have 3 or more, 1 all 1; 3 of 43 " in report
    written = _written(root)
    assert "report.html" in written and "figures/deployment_pareto.png" in written
    assert main(["reproduce", "--out", str(root), "--report-only"]) == 0
    assert _written(root) == written  # byte for byte: nothing in it changes from one writing to the next
    assert (first / "study.json").read_bytes() == before  # the chunks are only read


def test_the_summary_goes_between_the_pages_marker_lines_and_nowhere_else(tmp_path, capsys):
    from highway_srl.study.report import PAGE_BEGIN, PAGE_END

    root = tmp_path / "paper"
    _chunk(root, (0, 1))
    page = tmp_path / "results.md"
    page.write_text(f"# Results\n\nmine, kept\n\n{PAGE_BEGIN}\nold summary\n{PAGE_END}\n\nalso kept\n")
    assert main(["reproduce", "--out", str(root), "--report-only", "--page", str(page)]) == 0
    summary = (root / "summary.md").read_text()
    assert summary.startswith("- **Budget:** `smoke`") and "Verdict: **" in summary
    text = page.read_text()
    assert text == f"# Results\n\nmine, kept\n\n{PAGE_BEGIN}\n\n{summary.rstrip()}\n\n{PAGE_END}\n\nalso kept\n"
    assert main(["reproduce", "--out", str(root), "--report-only", "--page", str(page)]) == 0
    assert page.read_text() == text  # written again: the same bytes
    capsys.readouterr()
    plain = tmp_path / "plain.md"
    plain.write_text("no markers here\n")
    err = _error(capsys, root, "--page", str(plain))
    assert len(err) == 1 and "needs one line '<!-- begin:" in err[0] and plain.read_text() == "no markers here\n"
    err = _error(capsys, root, "--page", str(tmp_path / "missing.md"))
    assert len(err) == 1 and "is not a file" in err[0]
    assert main(["reproduce", "--out", str(root), "--page", str(page)]) == 2
    assert "--page goes with --report-only" in capsys.readouterr().err


def test_a_job_not_finished_in_one_chunk_counts_the_seeds_of_the_others_and_is_listed(tmp_path):
    # the unfinished chunk may even repeat a finished seed (say, a chunk started again elsewhere): it holds
    # no result of it, so nothing is counted twice
    root = tmp_path / "paper"
    _chunk(root, (0, 1))
    late = _chunk(root, (1, 2))
    state = json.loads((late / "study.json").read_text())
    state["jobs"][JOB]["status"] = "pending"
    (late / "study.json").write_text(json.dumps(state))
    (late / "runs/two-lane/moe-rm-srl/eval.json").unlink()
    res = chunks.load_study(root).get(OURS, "two-lane")
    assert res.done and res.job.seeds == (0, 1)
    assert main(["reproduce", "--out", str(root), "--report-only"]) == 0
    assert f"`seeds-1-2/{JOB}`: pending" in (root / "report.md").read_text()


def _error(capsys, root: Path, *argv) -> list[str]:
    assert main(["reproduce", "--out", str(root), "--report-only", *argv]) == 2
    return capsys.readouterr().err.strip().splitlines()


def test_a_seed_in_two_chunks_or_chunks_of_other_settings_are_one_line_errors(tmp_path, capsys):
    root = tmp_path / "paper"
    _chunk(root, (0, 1))
    other = _chunk(root, (1, 2))
    err = _error(capsys, root)
    assert len(err) == 1 and f"seed 1 of job {JOB} is in two chunks, 'seeds-0-1' and 'seeds-1-2'" in err[0]
    err = _error(capsys, root, "--budget", "quick")
    assert len(err) == 1 and "chunk 'seeds-0-1' holds a study of budget 'smoke', not 'quick'" in err[0]
    state = json.loads((other / "study.json").read_text())
    state["budget_config"]["steps"] = 99
    (other / "study.json").write_text(json.dumps(state))
    err = _error(capsys, root)
    assert len(err) == 1 and "chunks 'seeds-0-1' and 'seeds-1-2' differ in steps" in err[0]
    assert not (root / "report.md").exists()


def test_a_chunk_continued_from_another_commit_names_both(tmp_path):
    # a chunk whose later call ran from another worktree (a method re-pinned there) names every commit it ran
    root = tmp_path / "paper"
    folder = _chunk(root, (0, 1))
    state = json.loads((folder / "study.json").read_text())
    first = state.get("commit") or "aaaaaaa"
    state["commit"] = first
    state["invocations"].append({**state["invocations"][-1], "commit": "bbbbbbb"})
    (folder / "study.json").write_text(json.dumps(state))
    assert chunks.load_study(root).state["chunks"][0]["commit"] == f"{first}, bbbbbbb"


def _verdicts(seeds: dict[str, tuple[int, int]]) -> dict:
    """metrics.json's collision_verdicts from {seed: (ego-avoidable, unavoidable)}."""
    per_seed = {s: {"collisions": a + u, "ego_avoidable": a, "unavoidable": u, "not_judged": 0}
                for s, (a, u) in seeds.items()}
    keys = ("collisions", "ego_avoidable", "unavoidable", "not_judged")
    return {"per_seed": per_seed, "all": {k: sum(v[k] for v in per_seed.values()) for k in keys}}


def _metrics(seeds: dict[str, tuple[int, int]], verdicts: bool = True) -> dict:
    m = {"per_seed": {s: {"episodes": 10, "collisions": a + u, "T_c": 0.9} for s, (a, u) in seeds.items()},
         "mean": {"T_c": 0.9}}
    return {**m, "collision_verdicts": _verdicts(seeds)} if verdicts else m


def test_the_training_verdicts_of_chunks_merge_seed_by_seed_and_vanish_if_a_chunk_lacks_them():
    merged = chunks.merge_metrics([_metrics({"0": (1, 2), "1": (0, 3)}), _metrics({"2": (4, 0)})])
    assert merged["collision_verdicts"]["all"] == {"collisions": 10, "ego_avoidable": 5, "unavoidable": 5,
                                                   "not_judged": 0}
    assert list(merged["collision_verdicts"]["per_seed"]) == ["0", "1", "2"]
    older = chunks.merge_metrics([_metrics({"0": (1, 2)}), _metrics({"2": (4, 0)}, verdicts=False)])
    assert "collision_verdicts" not in older  # chunk 0's split alone would pass for the job's


def test_the_deployment_verdicts_of_chunks_add_up_and_vanish_if_a_chunk_lacks_them():
    judged = [{"collisions": 3, "ego_avoidable": 1, "unavoidable": 2, "by_reason": {"a": 1, "b": 2}},
              {"collisions": 2, "ego_avoidable": 0, "unavoidable": 2, "by_reason": {"b": 2}}]
    merged = chunks.merge_census(judged)
    assert (merged["collisions"], merged["ego_avoidable"], merged["unavoidable"]) == (5, 1, 4)
    assert merged["by_reason"] == {"b": 4, "a": 1}
    older = chunks.merge_census([judged[0], {"collisions": 2}])
    assert older["collisions"] == 5 and "ego_avoidable" not in older and "by_reason" not in older


def test_a_chunk_of_the_safe_profile_alone_runs_only_its_jobs_and_merges_beside_the_paper_chunks(tmp_path, capsys):
    root = tmp_path / "paper"
    _chunk(root, (0,))
    safe = root / "safe-seeds-0"  # sorts before the paper chunks: the merged study still puts paper first
    reproduce("smoke", safe, jobs=1, work=fakes.fake_work, methods=(OURS,), scenes=("two-lane",), seeds=(0,),
              profiles=("safe",), **QUIET)
    assert [p.name for p in (safe / "runs").iterdir()] == ["safe"]  # no paper-profile job in the chunk
    study = chunks.load_study(root)
    assert study.state["budget_config"]["profiles"] == ["paper", "safe"]
    assert study.get(OURS, "two-lane").job.seeds == (0,)
    assert [r.get(OURS, "two-lane").job.id for r in study.beyond()] == ["safe:two-lane/moe-rm-srl"]
    assert main(["reproduce", "--out", str(root), "--report-only"]) == 0
    report = (root / "report.md").read_text()
    assert "No collision the ego could have avoided, in training or deployment (safe profile;" in report
    for bad in ("safe,paper", "paper,paper", "fast"):
        assert main(["reproduce", "--budget", "smoke", "--profiles", bad, "--out", str(tmp_path / bad)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--profiles takes distinct names of paper, safe, paper (if named) first" in err[0]
