"""The study's job list: every artefact's jobs at every budget, and which jobs can run now."""

from __future__ import annotations

import pytest

from highway_srl.agents import registry as methods_mod
from highway_srl.constants import TRAFFIC_LEVELS
from highway_srl.study import paper_numbers as paper
from highway_srl.study.jobs import (ABLATIONS, ARTEFACTS, BUDGETS, GROUP1_METHODS, GROUP2_SCENES, GROUP3_SCENES,
                                           METHOD_LABELS, OURS, SCENES, TABLE5_METHODS, TABLE5_SCENES, Job,
                                           job_availability, study_jobs)


@pytest.mark.parametrize("budget", list(BUDGETS))
def test_every_artefact_has_all_its_jobs_at_every_budget(budget):
    b = BUDGETS[budget]
    every = study_jobs(budget)
    assert len(every) == len({j.id for j in every}) == len({j.folder for j in every})
    jobs = [j for j in every if j.profile == "paper"]
    by = {(j.method, j.scene, j.options): j for j in jobs}
    assert len(by) == len(jobs)
    assert {a for j in jobs for a in j.artefacts} == set(ARTEFACTS)
    for m in GROUP1_METHODS:  # group 1: every method on two-lane, deployed at the budget's levels
        j = by[(m, "two-lane", ())]
        assert "group1_deployment" in j.artefacts and set(b.group1_levels) <= set(j.eval_levels)
    for scene in TABLE5_SCENES:
        for m in TABLE5_METHODS:
            j = by[(m, scene, ())]
            assert {"table5", "training_pareto", "training_curves"} <= set(j.artefacts)
            assert "C" in j.eval_levels
    for scene in GROUP2_SCENES:
        assert "group2" in by[(OURS, scene, ())].artefacts
    for scene in GROUP3_SCENES:
        assert all("group3" in by[(m, scene, ())].artefacts for m in TABLE5_METHODS)
    assert "multilane" in by[(OURS, "multi-lane", ())].artefacts and by[(OURS, "adv-multi-lane", ())].scene
    for option in ABLATIONS:
        assert by[(OURS, "adv-two-lane", (option,))].artefacts == ("table6",)
    assert "table6" in by[(OURS, "adv-two-lane", ())].artefacts
    # 8 methods on two-lane, 6 on the five other Table 5 scenes, ours on two multi-lane scenes, 3 ablations
    assert len(jobs) == 8 + 5 * 6 + 2 + 3
    for j in jobs:
        assert (j.steps, j.envs, j.seeds, j.eval_episodes) == (b.steps, b.envs, b.seeds, b.eval_episodes)
    # each further profile repeats the reproduction's jobs in its own folders, beyond the paper
    assert b.profiles[0] == "paper" and len(every) == len(jobs) * len(b.profiles)
    for j in every:
        assert j.adversary == "paper" and j.folder.startswith("runs/" if j.profile == "paper" else f"runs/{j.profile}/")
    # the reproduction's jobs come first: a study stopped half-way has the paper profile's set, not ours
    profiles = [j.profile for j in every]
    assert profiles == sorted(profiles, key=b.profiles.index)


def test_quick_and_paper_budgets_add_the_safe_profile_beyond_the_paper_and_smoke_does_not():
    assert BUDGETS["smoke"].profiles == ("paper",)
    assert BUDGETS["quick"].profiles == BUDGETS["paper"].profiles == ("paper", "safe")
    job = next(j for j in study_jobs("quick") if j.profile == "safe" and j.method == "rl" and j.scene == "two-lane")
    assert job.id == "safe:two-lane/rl" and job.folder == "runs/safe/two-lane/rl" and job.beyond_the_paper
    cfg = job.train_config("cpu")
    assert (cfg.profile, cfg.adversary, cfg.replay_ratio) == ("safe", "paper", BUDGETS["quick"].replay_ratio)


def test_a_job_written_before_profiles_reads_as_safe_mild_with_its_update_count_in_its_old_folder():
    job = Job.from_dict({"method": "rl", "scene": "two-lane", "seeds": [0], "updates_per_step": 1})
    assert (job.profile, job.adversary, job.replay_ratio, job.legacy_updates_per_step) == ("safe", "mild", None, 1)
    assert job.folder == "runs/two-lane/rl" and not job.beyond_the_paper
    cfg = job.train_config("cpu")
    assert (cfg.replay_ratio, cfg.profile) == (1 / 16, "safe")  # 1 step per 16-env vector step of its network


def test_paper_budget_is_the_papers():
    b = BUDGETS["paper"]
    assert (b.steps, len(b.seeds), b.eval_episodes, b.batch_size) == (500_000, 10, 100, 256)
    assert b.group1_levels == tuple(TRAFFIC_LEVELS)
    assert BUDGETS["smoke"].steps // BUDGETS["smoke"].envs >= 320  # every env finishes an episode


def test_train_config_of_a_job_carries_scene_budget_and_ablation():
    job = next(j for j in study_jobs("quick") if j.options == ("no_moe",))
    cfg = job.train_config("cpu")
    assert (cfg.method, cfg.scenario, cfg.adversarial, cfg.traffic) == (OURS, "two-lane", True, "C")
    assert cfg.options == {"no_moe": True} and cfg.dqn.total_steps == cfg.steps == BUDGETS["quick"].steps
    assert Job.from_dict(job.to_dict()) == job


def test_methods_filter_keeps_ablations_with_ours_and_names_unknown_methods():
    jobs = study_jobs("smoke", methods=(OURS,))
    assert {j.method for j in jobs} == {OURS}
    assert len(jobs) == 1 + 5 + 2 + 3
    with pytest.raises(ValueError, match="'dqn-x'"):
        study_jobs("smoke", methods=("dqn-x",))
    with pytest.raises(ValueError, match="unknown budget 'huge'; choose one of smoke, quick, paper"):
        study_jobs("huge")


def test_job_of_an_unregistered_method_is_unavailable_with_the_reason(monkeypatch):
    monkeypatch.setattr(methods_mod, "METHODS", {k: v for k, v in methods_mod.METHODS.items() if k != "rl"})
    job = next(j for j in study_jobs("smoke") if j.method == "rl")
    assert "'rl' is not registered" in job_availability(job)
    assert job_availability(next(j for j in study_jobs("smoke") if j.method == OURS and not j.options)) is None


def test_ablation_is_unavailable_while_the_method_ignores_unknown_options(monkeypatch):
    job = next(j for j in study_jobs("smoke") if j.options == ("no_rm",))
    monkeypatch.setattr(methods_mod, "make_method", lambda *a, **k: object())
    assert "cannot be told apart from the full method" in job_availability(job)


def test_paper_numbers_cover_every_scene_metric_and_method():
    assert set(paper.TABLE5) == set(TABLE5_SCENES)
    for scene, metrics in paper.TABLE5.items():
        expected = {"T_c", "T_r", "C_r", "R_r"} | ({"R_s"} if SCENES[scene].scenario in ("merge", "exit") else set())
        assert set(metrics) == expected
        assert all(set(v) == set(TABLE5_METHODS) for v in metrics.values())
    assert paper.TABLE5["adv-exit"]["R_s"]["moe-rm-srl"] == 0.815 and paper.TABLE5["two-lane"]["C_r"]["rl"] == 0.086
    assert set(paper.TABLE6) == {"full", *ABLATIONS} and paper.TABLE6["no_moe"]["C_r"] == 0.388
    assert paper.MULTILANE["adv-multi-lane"]["collision_rate"] == 0.134
    assert set(METHOD_LABELS) >= set(TABLE5_METHODS)
