"""The smoke budget end to end: real training and evaluation, every artefact, resume, and the Ray executor.

Only MoE-RM-SRL (with its ablations, 11 jobs) so that the test stays within a few minutes on 2 cores; the
full smoke study (43 jobs with every baseline) is the same code with more jobs.
"""

from __future__ import annotations

import shutil
import time

import pytest

from highway_srl.agents.registry import METHODS
from highway_srl.study.runner import reproduce
from highway_srl.study.jobs import OURS, SCENES

pytestmark = pytest.mark.slow

TABLES = ("group1_deployment", "group2", "multilane", "group3", "table5", "table6")
FIGURES = ("deployment_pareto", "training_pareto", *(f"training_curves_{s}" for s in SCENES))


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    assert OURS in METHODS
    root = tmp_path_factory.mktemp("smoke") / "results"
    t0 = time.perf_counter()
    state = reproduce("smoke", root, jobs=2, methods=(OURS,), log=lambda s: None)
    return root, state, time.perf_counter() - t0


def test_smoke_budget_trains_evaluates_and_writes_every_artefact(smoke):
    root, state, wall = smoke
    bad = {k: v["message"] for k, v in state["jobs"].items() if v["status"] != "done"}
    assert not bad, bad
    assert len(state["jobs"]) == 11
    for name in TABLES:
        assert (root / "tables" / f"{name}.csv").exists() and (root / "tables" / f"{name}.md").exists()
    for name in FIGURES:
        assert (root / "figures" / f"{name}.png").exists() and (root / "figures" / f"{name}.svg").exists()
    report = (root / "report.md").read_text()
    for words in ("**Budget:** `smoke`", "**Machine:**", "**Wall time:**", "commit", "Verdict:",
                  "MoE-RM-SRL trains without collisions", "Each ablated part matters"):
        assert words in report
    assert "data:image/png;base64," in (root / "report.html").read_text()
    table5 = (root / "tables" / "table5.csv").read_text()
    assert "two-lane,T_c,MoE-RM-SRL,moe-rm-srl,done," in table5
    for job in state["jobs"].values():  # every run folder is complete
        folder = root / f"runs/{job['job']['scene']}/{'-'.join([job['job']['method'], *job['job']['options']])}"
        assert {"config.json", "episodes.jsonl", "metrics.json", "eval.json", "job.json", "model"} <= {
            p.name for p in folder.iterdir()}
    print(f"smoke study (11 jobs, 2 workers): {wall:.0f} s")


def test_running_the_finished_study_again_runs_nothing(smoke):
    root, state, _ = smoke
    stamps = {p: p.stat().st_mtime_ns for p in root.glob("runs/*/*/metrics.json")}
    again = reproduce("smoke", root, jobs=2, methods=(OURS,), log=lambda s: None, report=False)
    assert again["invocations"][-1]["ran"] == 0
    assert {p: p.stat().st_mtime_ns for p in root.glob("runs/*/*/metrics.json")} == stamps


def test_ray_executor_finishes_the_smoke_study_on_a_local_two_cpu_ray(smoke, tmp_path):
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'highway-srl[ray]')")
    root, _, _ = smoke
    copy = tmp_path / "results"
    shutil.copytree(root, copy)
    for gone in ("runs/exit/moe-rm-srl", "runs/adv-two-lane/moe-rm-srl-no_rm"):
        shutil.rmtree(copy / gone)
    (copy / "report.md").unlink()  # the Ray invocation must write its own
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        state = reproduce("smoke", copy, executor="ray", methods=(OURS,), log=lambda s: None)
    finally:
        ray.shutdown()
    last = state["invocations"][-1]
    assert (last["executor"], last["ran"], last["skipped_done"]) == ("ray", 2, 9)
    assert all(v["status"] == "done" for v in state["jobs"].values())
    assert (copy / "runs/exit/moe-rm-srl/eval.json").exists() and (copy / "report.md").exists()
